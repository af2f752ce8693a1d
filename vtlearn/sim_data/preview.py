"""`vtlearn preview DATASET`: a PNG grid, a row per category: mesh, dense, tactile and visual clouds."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from vtlearn.bench_utils import save_figure


def _instance_meshes(dataset: Path, manifest: dict) -> dict[int, object]:
    """instance id -> a loader of its canonical mesh, from the items generation made them from."""
    from vtlearn.sim_data.loaders import load_mesh_item
    from vtlearn.sim_data.shapes import generate_shape
    from vtlearn.sim_data.writer import GenConfig, planned_instances

    cfg = GenConfig(**manifest["config"])
    out = {}
    for inst, it in planned_instances(dataset, cfg).items():
        if "file" in it:
            out[inst] = lambda it=it: load_mesh_item(it)
        else:
            out[inst] = lambda it=it: generate_shape(it["category"], it["seed"], cfg.sections)[0]
    return out


def write_preview(
    dataset: str | Path, out: str | Path | None = None, max_categories: int = 12, seed: int = 0
) -> Path:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from vtlearn.datamodules.shards import load_manifest, load_split, split_clouds

    dataset = Path(dataset)
    manifest = load_manifest(dataset)
    names = manifest["class_names"][:max_categories]
    data = {}
    for split in ("train", "val", "test"):
        if manifest["splits"][split]["instances"]:
            d = load_split(dataset, split, verify=False)
            for k, v in d.items():
                data.setdefault(k, []).append(v if k != "tactile_offsets" else None)
    data = {k: np.concatenate(v) for k, v in data.items() if k != "tactile_offsets"}
    # tactile offsets must be rebuilt per split; reload them consistently
    tac_clouds, tac_inst = [], []
    for split in ("train", "val", "test"):
        if manifest["splits"][split]["instances"]:
            d = load_split(dataset, split, verify=False)
            tac_clouds += split_clouds(d["tactile_points"], d["tactile_offsets"])
            tac_inst += d["tactile_instance"].tolist()
    meshes = _instance_meshes(dataset, manifest)
    cols = ["mesh", "dense (2048)", "tactile", "visual"]
    fig = plt.figure(figsize=(3 * len(cols), 3 * len(names)))
    rng = np.random.default_rng(seed)
    for r, name in enumerate(names):
        label = manifest["class_names"].index(name)
        idx = np.flatnonzero(data["label"] == label)
        if len(idx) == 0:
            continue
        j = int(rng.choice(idx))
        inst = int(data["instance"][j])
        clouds = {"dense (2048)": data["dense"][j]}
        tj = [k for k, t in enumerate(tac_inst) if t == inst]
        if tj:
            clouds["tactile"] = tac_clouds[tj[0]]
        if "visual" in data:
            vj = np.flatnonzero(data["visual_instance"] == inst)
            if len(vj):
                clouds["visual"] = data["visual"][vj[0]]
        for c, col in enumerate(cols):
            ax = fig.add_subplot(len(names), len(cols), r * len(cols) + c + 1, projection="3d")
            if col == "mesh" and inst in meshes:
                m = meshes[inst]()
                ax.plot_trisurf(
                    m.vertices[:, 0],
                    m.vertices[:, 1],
                    m.vertices[:, 2],
                    triangles=m.faces,
                    color="tab:orange",
                    linewidth=0,
                    alpha=0.9,
                )
            elif col in clouds:
                p = clouds[col]
                ax.scatter(p[:, 0], p[:, 1], p[:, 2], s=1 if len(p) > 500 else 6, c=p[:, 2], cmap="viridis")
            else:
                ax.text2D(0.3, 0.5, "n/a", transform=ax.transAxes)
            ax.set_xlim(-0.5, 0.5)
            ax.set_ylim(-0.5, 0.5)
            ax.set_zlim(-0.5, 0.5)
            ax.set_box_aspect((1, 1, 1))
            ax.set_axis_off()
            title = col if c else f"{name}: {col}"
            if col == "tactile" and col in clouds:
                title += f" ({len(clouds[col])})"
            ax.set_title(title, fontsize=9)
    fig.tight_layout()
    path = Path(out) if out else dataset / "preview.png"
    save_figure(fig, path, dpi=80)
    return path
