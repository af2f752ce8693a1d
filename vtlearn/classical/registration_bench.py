"""The sparse-to-dense registration benchmark of thesis ch.5, 5.3.3 (Fig. 5.15, Table 5.1, eq. 5.24-5.25).

Protocol per trial (the same model, scene and initial pose for every method):

* the mesh is normalised into [-1, 1]^3 (centre of its box at the origin, longest side 2 m);
* model cloud O: 1024 points sampled uniformly (by area) from the mesh;
* scene cloud S: N other random surface points, moved by a ground-truth ``T_scene_model`` whose translation is
  uniform in [-5, 5]^3 m and whose rotation is uniform over SO(3);
* every method starts from the identity (the model where it is) and returns ``T_scene_model``;
* error: ADI (eq. 5.24) over the model cloud, in cm.

Besides the plain methods, ``icp_time_matched`` is Open3D ICP with random restarts (the common wrapper of
:func:`vtlearn.classical.registration.register`) for as long as S-TIQF took on that trial, and the Table 5.1
ablation runs the S-TIQF annealing (same schedule) followed by ICP (``sa_icp``) or sparse ICP (``sa_sicp``).
The scale run scales the scene object by a random factor per axis in [0.5, 2] (in the model axes) and
registers with ``estimate_scale=True``; it reports the scale error of eq. 5.25 and the ADI of the scaled
model.
"""

from __future__ import annotations

import os
import time
import warnings
from pathlib import Path

import numpy as np
import trimesh
from scipy.spatial import cKDTree
from tqdm import tqdm

from vtlearn.bench_utils import ratio, sample_std, save_figure, welch_p
from vtlearn.classical.registration import METHODS, _run_icp, available_methods, register
from vtlearn.classical.sparse_icp import sparse_icp
from vtlearn.classical.stiqf import STIQF, annealing_field, simulated_annealing
from vtlearn.classical.tiqf import _quat_to_matrix

__all__ = ["load_benchmark_mesh", "run_registration_benchmark", "normalise_mesh", "THESIS_TABLE_5_1"]

#: thesis Table 5.1, mean ADI (cm) of S-TIQF / SA+ICP / SA+S-ICP on the bunny
THESIS_TABLE_5_1 = {
    20: {"stiqf": 4.36, "sa_icp": 7.65, "sa_sicp": 6.98},
    40: {"stiqf": 3.35, "sa_icp": 6.61, "sa_sicp": 5.11},
    80: {"stiqf": 3.05, "sa_icp": 5.41, "sa_sicp": 4.21},
    120: {"stiqf": 2.85, "sa_icp": 4.28, "sa_sicp": 3.55},
}

DEFAULT_METHODS = ("stiqf", "tiqf", "icp", "icp_plane", "sparse_icp", "ransac_fpfh", "fgr")


def normalise_mesh(mesh: trimesh.Trimesh) -> trimesh.Trimesh:
    """Copy of ``mesh`` with its box centred at the origin and its longest side 2 (into [-1, 1]^3)."""
    m = mesh.copy()
    lo, hi = m.bounds
    side = float((hi - lo).max())
    if side <= 0:
        raise ValueError("mesh: has zero extent")
    m.vertices = (m.vertices - (lo + hi) / 2) * (2.0 / side)
    return m


def load_benchmark_mesh(spec: str) -> tuple[str, trimesh.Trimesh]:
    """``bunny`` (pybullet_data), ``shape:CATEGORY[:SEED]`` (vtlearn.sim_data) or a mesh file path."""
    if spec == "bunny":
        import pybullet_data

        path = os.path.join(pybullet_data.getDataPath(), "bunny.obj")
        return "bunny", normalise_mesh(trimesh.load(path, force="mesh"))
    if spec.startswith("shape:"):
        from vtlearn.sim_data.shapes import generate_shape

        parts = spec.split(":")
        seed = int(parts[2]) if len(parts) > 2 else 0
        mesh, _ = generate_shape(parts[1], seed=seed)
        return f"{parts[1]}{seed}", normalise_mesh(mesh)
    from vtlearn.io import read_mesh

    return Path(spec).stem, normalise_mesh(read_mesh(spec))


def default_meshes() -> list[str]:
    """The bunny plus two procedural shapes when :mod:`vtlearn.sim_data` is available."""
    specs = ["bunny"]
    try:
        from vtlearn.sim_data.shapes import CATEGORIES

        specs += [f"shape:{c}" for c in ("mug", "spray_bottle") if c in CATEGORIES]
    except ImportError:
        pass
    return specs


def _random_pose(rng) -> np.ndarray:
    q = rng.normal(size=4)
    T = np.eye(4)
    T[:3, :3] = _quat_to_matrix(q / np.linalg.norm(q))
    T[:3, 3] = rng.uniform(-5.0, 5.0, 3)
    return T


def _adi_cm(model, T_est, T_gt) -> float:
    from vtlearn.geometry.metrics import adi

    return 100.0 * adi(model, T_est, T_gt)


def _sa_pose(model, scene, seed) -> tuple[np.ndarray, float, float]:
    t0, c0 = time.perf_counter(), time.process_time()
    # the same annealing cost as S-TIQF's defaults (tangent-patch distance field)
    st = STIQF()
    tree = cKDTree(model)
    field = annealing_field(model, tree, st.tangent_planes(model, tree))
    T_sa, _ = simulated_annealing(model, scene, cost_fn=field.lookup, rng=seed, restarts=30)
    return T_sa[0], time.perf_counter() - t0, time.process_time() - c0


def _ablation(model, scene, seed) -> dict[str, tuple[np.ndarray, float]]:
    """SA + ICP and SA + sparse ICP (Table 5.1): the local method starts from the annealing pose.

    The annealing is S-TIQF's (same schedule, 10 restarts x 3 chains); returns ``{name: (T, wall s, cpu s)}``.
    """
    T_sa, t_sa, c_sa = _sa_pose(model, scene, seed)
    out = {}
    moved = model @ T_sa[:3, :3].T + T_sa[:3, 3]
    t0, c0 = time.perf_counter(), time.process_time()
    T_icp, _, _ = _run_icp(moved, scene, None, {}, plane=False)
    out["sa_icp"] = (T_icp @ T_sa, t_sa + time.perf_counter() - t0, c_sa + time.process_time() - c0)
    t0, c0 = time.perf_counter(), time.process_time()
    T_ms, _ = sparse_icp(scene, model, T_init=np.linalg.inv(T_sa))
    out["sa_sicp"] = (np.linalg.inv(T_ms), t_sa + time.perf_counter() - t0, c_sa + time.process_time() - c0)
    return out


def _summary(vals) -> dict:
    v = np.asarray(vals, dtype=float)
    return {
        "mean": float(v.mean()),
        "std": sample_std(v),
        "median": float(np.median(v)),
        "n": int(len(v)),
    }


def run_registration_benchmark(
    mesh_specs=None,
    sizes=(20, 40, 80, 120),
    trials: int = 10,
    methods=None,
    seed: int = 0,
    time_matched: bool = True,
    ablation: bool = True,
    scale_trials: int | None = None,
    scale_size: int = 120,
    progress: bool = True,
):
    """Run the protocol; returns a JSON-ready dict with per-trial values and, per scene size and method, a
    summary: ADI mean / std / median (cm), mean wall and CPU seconds, Welch's p against S-TIQF, the mean ADI
    as a multiple of S-TIQF's (``ratio_to_stiqf``) and of thesis Table 5.1 (``thesis_cm``,
    ``ratio_to_thesis``; None for the methods and sizes the table does not have)."""
    mesh_specs = default_meshes() if mesh_specs is None else list(mesh_specs)
    requested = list(methods or DEFAULT_METHODS)
    unknown = [m for m in requested if m not in METHODS]
    if unknown:
        raise ValueError(f"methods: unknown {unknown}; choose from {sorted(METHODS)}")
    usable = available_methods()
    skipped = [m for m in requested if m not in usable]
    if skipped:
        warnings.warn(f"methods: {skipped} need the optional probreg package; skipped", stacklevel=2)
    methods = [m for m in requested if m not in skipped]
    if "stiqf" not in methods:
        methods = ["stiqf"] + methods
    meshes = [load_benchmark_mesh(s) for s in mesh_specs]
    rng = np.random.default_rng(seed)
    names = (
        list(methods)
        + (["icp_time_matched"] if time_matched else [])
        + (["sa_icp", "sa_sicp"] if ablation else [])
    )
    adi = {n: {name: [] for name in names} for n in sizes}
    times = {n: {name: [] for name in names} for n in sizes}
    cpu = {n: {name: [] for name in names} for n in sizes}
    trial_meta = []
    total = len(meshes) * len(sizes) * trials
    bar = tqdm(total=total, desc="bench registration", disable=not progress)
    for mesh_name, mesh in meshes:
        for n in sizes:
            for _ in range(trials):
                s = int(rng.integers(1 << 31))
                model = trimesh.sample.sample_surface(mesh, 1024, seed=s)[0].view(np.ndarray)
                pts = trimesh.sample.sample_surface(mesh, n, seed=s + 1)[0].view(np.ndarray)
                T_gt = _random_pose(rng)
                scene = pts @ T_gt[:3, :3].T + T_gt[:3, 3]
                t_stiqf = None
                for m in methods:
                    r = register(model, scene, m, seed=s)
                    adi[n][m].append(_adi_cm(model, r.T_scene_model, T_gt))
                    times[n][m].append(r.time)
                    cpu[n][m].append(r.cpu_time)
                    if m == "stiqf":
                        t_stiqf = r.time
                if time_matched:
                    r = register(model, scene, "icp", time_budget=t_stiqf, seed=s)
                    adi[n]["icp_time_matched"].append(_adi_cm(model, r.T_scene_model, T_gt))
                    times[n]["icp_time_matched"].append(r.time)
                    cpu[n]["icp_time_matched"].append(r.cpu_time)
                if ablation:
                    for name, (T, dt, dcpu) in _ablation(model, scene, s).items():
                        adi[n][name].append(_adi_cm(model, T, T_gt))
                        times[n][name].append(dt)
                        cpu[n][name].append(dcpu)
                trial_meta.append({"mesh": mesh_name, "n": n, "seed": s})
                bar.update(1)
    bar.close()
    summary = {}
    for n in sizes:
        summary[n] = {}
        for name in names:
            s = _summary(adi[n][name])
            s["time_mean_s"] = float(np.mean(times[n][name]))
            s["cpu_time_mean_s"] = float(np.mean(cpu[n][name]))
            s["p_welch_vs_stiqf"] = None if name == "stiqf" else welch_p(adi[n]["stiqf"], adi[n][name])
            # mean ADI against S-TIQF's on the same trials, and against thesis Table 5.1 where it has one
            s["ratio_to_stiqf"] = ratio(s["mean"], np.mean(adi[n]["stiqf"]))
            s["thesis_cm"] = THESIS_TABLE_5_1.get(n, {}).get(name)
            s["ratio_to_thesis"] = ratio(s["mean"], s["thesis_cm"])
            summary[n][name] = s
    mesh_names = [m for m, _ in meshes]
    per_mesh = {
        mesh: {
            n: {name: _summary(np.asarray(adi[n][name]).reshape(len(meshes), trials)[i]) for name in names}
            for n in sizes
        }
        for i, mesh in enumerate(mesh_names)
    }
    result = {
        "protocol": "thesis 5.3.3: model 1024 uniform surface points, scene N random surface points, both in "
        "[-1,1]^3 m, T_scene_model translation U[-5,5]^3 m, rotation uniform; ADI eq. 5.24 in cm",
        "meshes": [m for m, _ in meshes],
        "sizes": list(sizes),
        "trials_per_mesh_and_size": trials,
        "methods": names,
        "adi_cm": adi,
        "time_s": times,
        "cpu_time_s": cpu,
        "summary": summary,
        "summary_per_mesh": per_mesh,
        "thesis_table_5_1": THESIS_TABLE_5_1,
        "trials": trial_meta,
    }
    if scale_trials:
        result["scale"] = run_scale_benchmark(meshes, scale_trials, scale_size, rng, progress)
    return result


def run_scale_benchmark(meshes, trials: int, n: int, rng, progress: bool = True) -> dict:
    """S-TIQF with ``estimate_scale=True`` on scenes scaled per axis by U[0.5, 2]; eq. 5.25 scale error."""
    from vtlearn.geometry.metrics import scale_error

    errs, adis, times = [], [], []
    bar = tqdm(total=len(meshes) * trials, desc="bench registration (scale)", disable=not progress)
    for _, mesh in meshes:
        for _ in range(trials):
            s = int(rng.integers(1 << 31))
            model = trimesh.sample.sample_surface(mesh, 1024, seed=s)[0].view(np.ndarray)
            pts = trimesh.sample.sample_surface(mesh, n, seed=s + 1)[0].view(np.ndarray)
            s_gt = rng.uniform(0.5, 2.0, 3)
            T_gt = _random_pose(rng)
            scene = (pts * s_gt) @ T_gt[:3, :3].T + T_gt[:3, 3]
            r = register(model, scene, "stiqf", estimate_scale=True, seed=s)
            errs.append(scale_error(r.scale, s_gt))
            gt = (model * s_gt) @ T_gt[:3, :3].T + T_gt[:3, 3]
            est = (model * r.scale) @ r.R.T + r.t
            adis.append(100.0 * float(cKDTree(est).query(gt)[0].mean()))
            times.append(r.time)
            bar.update(1)
    bar.close()
    return {
        "n_scene": n,
        "scale_error": _summary(errs),
        "adi_cm": _summary(adis),
        "time_mean_s": float(np.mean(times)),
        "scale_error_values": errs,
        "adi_values": adis,
    }


def markdown_report(result: dict) -> str:
    """Markdown tables: ADI per method and N, Welch p-values, Table 5.1 ablation beside the thesis."""
    from vtlearn.bench_utils import format_table

    names = result["methods"]
    rows = []
    for n in result["sizes"]:
        s = result["summary"][n]
        row = {"N": n}
        for name in names:
            row[name] = f"{s[name]['mean']:.2f}±{s[name]['std']:.2f} ({s[name]['median']:.2f})"
        rows.append(row)
    parts = [format_table(rows, ["N"] + names, "ADI (cm): mean±std (median)")]
    rows = []
    for n in result["sizes"]:
        s = result["summary"][n]
        rows.append({"N": n, **{name: s[name]["time_mean_s"] for name in names}})
    parts.append(format_table(rows, ["N"] + names, "wall time per registration (s), noisy shared CPU"))
    rows = []
    for n in result["sizes"]:
        s = result["summary"][n]
        rows.append({"N": n, **{name: s[name]["cpu_time_mean_s"] for name in names}})
    parts.append(
        format_table(rows, ["N"] + names, "CPU time per registration (s, process time, all threads)")
    )
    rows = []
    for mesh, per_n in result["summary_per_mesh"].items():
        for n in result["sizes"]:
            rows.append({"mesh": mesh, "N": n, **{name: f"{per_n[n][name]['mean']:.2f}" for name in names}})
    parts.append(format_table(rows, ["mesh", "N"] + names, "mean ADI (cm) per mesh"))
    rows = []
    for n in result["sizes"]:
        s = result["summary"][n]
        rows.append(
            {
                "N": n,
                **{
                    name: (
                        "-" if s[name]["p_welch_vs_stiqf"] is None else f"{s[name]['p_welch_vs_stiqf']:.2g}"
                    )
                    for name in names
                    if name != "stiqf"
                },
            }
        )
    parts.append(
        format_table(
            rows, ["N"] + [n for n in names if n != "stiqf"], "Welch's t-test p-value, S-TIQF vs each method"
        )
    )
    if "sa_icp" in names:
        rows = []
        for n in result["sizes"]:
            s = result["summary"][n]
            th = THESIS_TABLE_5_1.get(n, {})
            rows.append(
                {
                    "N": n,
                    **{
                        f"{k}": f"{s[k]['mean']:.2f}±{s[k]['std']:.2f} (thesis {th.get(k, '-')})"
                        for k in ("stiqf", "sa_icp", "sa_sicp")
                    },
                }
            )
        parts.append(format_table(rows, ["N", "stiqf", "sa_icp", "sa_sicp"], "Table 5.1 ablation (ADI cm)"))
    if "scale" in result:
        sc = result["scale"]
        parts.append(
            format_table(
                [
                    {
                        "N": sc["n_scene"],
                        "scale_err": sc["scale_error"]["mean"],
                        "scale_err_median": sc["scale_error"]["median"],
                        "adi_cm": sc["adi_cm"]["mean"],
                        "adi_cm_median": sc["adi_cm"]["median"],
                        "time_s": sc["time_mean_s"],
                    }
                ],
                ["N", "scale_err", "scale_err_median", "adi_cm", "adi_cm_median", "time_s"],
                "scale estimation (eq. 5.25), scene scaled per axis by U[0.5, 2]",
            )
        )
    return "\n\n".join(parts) + "\n"


def bar_plot(result: dict, path) -> Path:
    """Grouped bar plot of mean ADI ± std per method and scene size (Fig. 5.15 analogue)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    names = result["methods"]
    sizes = result["sizes"]
    fig, ax = plt.subplots(figsize=(max(6, 1.2 * len(names) * len(sizes) / 3), 4))
    width = 0.8 / len(names)
    for i, name in enumerate(names):
        means = [result["summary"][n][name]["mean"] for n in sizes]
        stds = [result["summary"][n][name]["std"] for n in sizes]
        ax.bar(np.arange(len(sizes)) + i * width, means, width, yerr=stds, label=name, capsize=2)
    ax.set_xticks(np.arange(len(sizes)) + 0.4 - width / 2)
    ax.set_xticklabels([f"{n} points" for n in sizes])
    ax.set_ylabel("ADI (cm)")
    ax.set_yscale("log")
    ax.legend(fontsize=7, ncol=2)
    ax.set_title("Sparse-to-dense registration, thesis 5.3.3 protocol")
    fig.tight_layout()
    return save_figure(fig, path, dpi=120)
