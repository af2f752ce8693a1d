"""End-to-end quickstart: data, quick models, active touching of an unseen object, reconstruction,
recognition and pose (issue 8 part 6; thesis ch.5, 7, 8 in one loop).

``vtlearn quickstart --out runs/quickstart`` runs four steps; each writes its result under ``--out``
and is skipped when that result already exists, so a killed or repeated run resumes:

1. ``data``: a small reconstruction dataset and a small crossmodal dataset (``gen-data``, resumable by
   shard) on a few categories, and the preview figure (``preview.png``).
2. ``train``: quick ACTOR (configs/quick/actor.yaml hyper-parameters) and xAVTNet
   (configs/quick/xavtnet.yaml) trained with a Lightning ``Trainer`` for a few epochs; checkpoints
   ``actor.ckpt`` and ``xavtnet.ckpt`` (written atomically).
3. ``explore``: an unseen transparent instance (held-out seed) on the table in pybullet; touches and
   pinches chosen actively on the occupancy grid (:mod:`vtlearn.active.closed_loop`).
4. ``perceive``: ACTOR reconstruction (Chamfer distance to the true surface, mm), xAVTNet recognition
   from the tactile cloud (category vs truth), and S-TIQF pose (model: the reconstruction in metres,
   scene: the touched points under an unknown random pose; ADI, eq. 5.24, in cm). Writes
   ``summary.png`` (touches, reconstruction, pose overlay) and ``summary.json``.

The default budget is sized for about 10 CPU minutes on 2 cores; the quality that buys is stated in
docs/active_perception.md.
"""

from __future__ import annotations

import json
import logging
import os
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np

from vtlearn.bench_utils import csv_list
from vtlearn.cli_args import count
from vtlearn.io import atomic_path
from vtlearn.validation import as_int

log = logging.getLogger(__name__)

__all__ = [
    "QuickstartConfig",
    "perceive_object",
    "run_quickstart",
    "summary_figure",
    "tiny_quickstart_config",
]

_REPO = Path(__file__).resolve().parents[1]


@dataclass
class QuickstartConfig:
    """Sizes of the quickstart; the defaults are the ~10-minute CPU budget."""

    categories: list[str] = field(default_factory=lambda: ["wineglass", "bottle", "mug", "can"])
    recon_per_category: int = 24
    cross_per_category: int = 12
    sections: int = 32
    image_size: tuple[int, int] = (160, 120)
    actor_epochs: int = 40
    xavtnet_epochs: int = 12
    batch_size: int = 16
    object_category: str = "wineglass"  # the unseen object (must be in categories)
    n_actions: int = 20
    n_candidates: int = 100
    cells: int = 40
    stiqf_restarts: int = 4
    # A narrower ACTOR than the thesis' (which costs ~10 s per CPU batch on a loaded 2-core machine):
    # 512 output points, 256-d global feature. None keeps configs/quick/actor.yaml as it is.
    actor_overrides: dict | None = field(
        default_factory=lambda: {
            "num_points": 512,
            "encoder_channels": [64, 64, 128, 256],
            "fc_channels": 256,
            "deconv_channels": [128, 128, 64, 64],
            "deconv_strides": [4, 4, 4, 4, 2],
        }
    )
    seed: int = 0

    def validate(self) -> None:
        from vtlearn.sim_data.shapes import CATEGORIES

        if len(self.categories) < 2 or any(c not in CATEGORIES for c in self.categories):
            raise ValueError(f"categories: need >= 2 of {CATEGORIES}, got {self.categories}")
        if self.object_category not in self.categories:
            raise ValueError(
                f"object_category: {self.object_category!r} is not in categories {self.categories}"
            )
        for name in ("recon_per_category", "cross_per_category"):  # one instance per split
            as_int(getattr(self, name), name, minimum=3)
        for name in ("actor_epochs", "xavtnet_epochs", "batch_size", "n_actions", "cells"):
            as_int(getattr(self, name), name)
        as_int(self.n_candidates, "n_candidates", minimum=2)


def tiny_quickstart_config() -> QuickstartConfig:
    """A seconds-scale configuration for tests (quality is meaningless at this size)."""
    return QuickstartConfig(
        categories=["wineglass", "mug"],
        recon_per_category=3,
        cross_per_category=3,
        sections=16,
        image_size=(80, 60),
        actor_epochs=1,
        xavtnet_epochs=1,
        batch_size=4,
        n_actions=6,
        n_candidates=8,
        cells=16,
        stiqf_restarts=0,
    )


def _quick_init_args(name: str) -> dict:
    """Model ``init_args`` of configs/quick/<name>.yaml ({} when the repository configs are absent)."""
    import yaml

    path = _REPO / "configs" / "quick" / f"{name}.yaml"
    if not path.is_file():
        # a non-editable install has no configs/: say so, since the full-size defaults train far slower
        log.warning("%s not found (vtlearn not run from its repository); using %s defaults", path, name)
        return {}
    return dict(yaml.safe_load(path.read_text())["model"].get("init_args", {}))


def _trainer(max_epochs: int, log_dir: Path, name: str):
    import lightning as L
    from lightning.pytorch.loggers import CSVLogger

    return L.Trainer(
        max_epochs=int(max_epochs),
        accelerator="cpu",
        devices=1,
        logger=CSVLogger(str(log_dir), name=name),
        enable_checkpointing=False,
        limit_val_batches=0,
        num_sanity_val_steps=0,
        log_every_n_steps=5,
        enable_model_summary=False,
        enable_progress_bar=True,
    )


def _save_atomic(trainer, path: Path) -> None:
    # the full training state (optimizer included), so the checkpoint can also resume training; loading it
    # elsewhere in vtlearn is always torch.load(weights_only=True), which this file satisfies
    with atomic_path(path) as tmp:
        trainer.save_checkpoint(str(tmp), weights_only=False)


# ------------------------------------------------------------------------------------------ steps
def step_data(cfg: QuickstartConfig, out: Path) -> dict:
    """Step 1: the two datasets and the preview; skipped parts are reported as such."""
    from vtlearn.sim_data.preview import write_preview
    from vtlearn.sim_data.writer import GenConfig, generate_dataset

    done = {}
    w, h = cfg.image_size
    common = dict(categories=list(cfg.categories), seed=cfg.seed, sections=cfg.sections, shard_size=8)
    for kind, extra in (
        ("reconstruction", dict(per_category=cfg.recon_per_category, touches=20, pinches=5)),
        (
            "crossmodal",
            dict(
                per_category=cfg.cross_per_category, views=3, image_width=w, image_height=h, tactile_clouds=4
            ),
        ),
    ):
        d = out / "data" / kind
        if (d / "manifest.json").is_file():
            done[kind] = "skipped"
            continue
        generate_dataset(GenConfig(kind=kind, **common, **extra), d, workers=1, progress=True)
        done[kind] = "generated"
    if (out / "preview.png").is_file():
        done["preview"] = "skipped"
    else:
        write_preview(out / "data" / "crossmodal", out / "preview.png", seed=cfg.seed)
        done["preview"] = "written"
    return done


def step_train(cfg: QuickstartConfig, out: Path) -> dict:
    """Step 2: quick ACTOR and xAVTNet checkpoints (skipped when present)."""
    import lightning as L

    from vtlearn.datamodules import CrossModalDataModule, ReconstructionDataModule
    from vtlearn.models.actor import ACTOR
    from vtlearn.models.xavtnet import XAVTNet

    done = {}
    actor_ckpt = out / "actor.ckpt"
    if actor_ckpt.is_file():
        done["actor"] = "skipped"
    else:
        L.seed_everything(cfg.seed, workers=True)
        args = _quick_init_args("actor")
        args.update(cfg.actor_overrides or {})
        args["emd_points"] = 64  # validation is off here; keep any later evaluation cheap
        model = ACTOR(**args)
        dm = ReconstructionDataModule(
            str(out / "data" / "reconstruction"), batch_size=cfg.batch_size, min_points=40, max_points=120
        )
        trainer = _trainer(cfg.actor_epochs, out / "logs", "actor")
        trainer.fit(model, datamodule=dm)
        _save_atomic(trainer, actor_ckpt)
        done["actor"] = f"trained {cfg.actor_epochs} epochs"
    xav_ckpt = out / "xavtnet.ckpt"
    if xav_ckpt.is_file():
        done["xavtnet"] = "skipped"
    else:
        L.seed_everything(cfg.seed, workers=True)
        dm = CrossModalDataModule(
            str(out / "data" / "crossmodal"), batch_size=cfg.batch_size, normalize="center"
        )
        args = _quick_init_args("xavtnet")
        args["num_classes"] = dm.num_classes
        model = XAVTNet(**args)
        trainer = _trainer(cfg.xavtnet_epochs, out / "logs", "xavtnet")
        trainer.fit(model, datamodule=dm)
        _save_atomic(trainer, xav_ckpt)
        done["xavtnet"] = f"trained {cfg.xavtnet_epochs} epochs"
    return done


def step_explore(cfg: QuickstartConfig, out: Path) -> dict:
    """Step 3: active touches and pinches on an unseen transparent instance; ``episode.npz``."""
    from tqdm import tqdm

    from vtlearn.active.closed_loop import TouchWorld, held_out_objects, run_episode

    path = out / "episode.npz"
    if path.is_file():
        return {"explore": "skipped"}
    obj = held_out_objects([cfg.object_category], 1, transparent=True, sections=cfg.sections)[0]
    bar = tqdm(total=cfg.n_actions, desc="active touches")
    with TouchWorld(obj) as world:
        ep = run_episode(
            world,
            "active",
            cfg.n_actions,
            n_candidates=cfg.n_candidates,
            cells=cfg.cells,
            seed=cfg.seed,
            progress=lambda i, n: bar.update(),
        )
    bar.close()
    with atomic_path(path) as tmp:
        np.savez(
            tmp,
            points=ep.points,
            step=ep.step,
            tactile=ep.tactile,
            kinds=np.array(ep.kinds),
            entropy=np.array(ep.entropy),
            T_world_sensor=np.array(ep.T_world_sensor),
            category=obj.category,
            seed=obj.seed,
        )
    return {"explore": f"{ep.n_steps} actions, {len(ep.points)} contact points"}


def _load_episode(out: Path):
    from vtlearn.active.closed_loop import Episode, make_object

    d = np.load(out / "episode.npz")
    ep = Episode(
        "active",
        kinds=[str(k) for k in d["kinds"]],
        points=d["points"],
        step=d["step"],
        tactile=d["tactile"],
        entropy=d["entropy"].tolist(),
        T_world_sensor=list(d["T_world_sensor"]),
    )
    return ep, make_object(str(d["category"]), int(d["seed"]))


def perceive_object(
    actor, xavtnet, class_names: list[str], obj, ep, *, seed: int = 0, stiqf_restarts: int = 4
) -> tuple[dict, dict]:
    """Reconstruct (ACTOR), recognise (xAVTNet) and register (S-TIQF) the object ``obj`` from the points
    of the explored episode ``ep``; shared by the quickstart and the robot runtime.

    The S-TIQF model is the reconstruction in its own metric frame (box centre at the origin); the
    scene is the touched points after an unknown rigid motion of the object (yaw in [-180, 180] deg, a
    few cm), so the ADI (eq. 5.24, cm) measures the pose of the reconstruction, not a known placement.

    Returns:
        the JSON-ready summary, and the arrays of the summary figure (``recon``, ``scene``,
        ``model_pts``, ``T_est``, ``T_gt``).
    """
    from vtlearn.active.closed_loop import classify_prefixes, reconstruct_prefixes
    from vtlearn.classical.registration import register
    from vtlearn.geometry.metrics import adi

    recon, cd = reconstruct_prefixes(actor, obj, ep, [ep.n_steps])
    probs = classify_prefixes(xavtnet, obj, ep, [ep.n_steps])[0]
    if len(class_names) != len(probs):
        raise ValueError(f"class_names: {len(class_names)} names for a classifier of {len(probs)} classes")
    pred = class_names[int(np.nanargmax(probs))] if np.isfinite(probs).all() else None
    if recon[0] is None:
        raise ValueError(
            f"n_actions: {ep.n_steps} actions gave {len(ep.points)} contact points, too few to "
            "reconstruct; use a larger budget"
        )
    rng = np.random.default_rng([seed, 55])
    centre = obj.bounds.mean(0)
    model_pts = recon[0] - centre
    yaw = rng.uniform(-np.pi, np.pi)
    T_scene_world = np.eye(4)
    T_scene_world[:3, :3] = [[np.cos(yaw), -np.sin(yaw), 0], [np.sin(yaw), np.cos(yaw), 0], [0, 0, 1]]
    T_scene_world[:3, 3] = rng.uniform(-0.05, 0.05, 3) * [1, 1, 0]
    T_world_model = np.eye(4)
    T_world_model[:3, 3] = centre
    T_gt = T_scene_world @ T_world_model
    scene = ep.points @ T_scene_world[:3, :3].T + T_scene_world[:3, 3]
    t0 = time.perf_counter()
    res = register(model_pts, scene, "stiqf", restarts=stiqf_restarts, seed=seed)
    true_model = obj.surface_world - centre
    adi_cm = 100.0 * adi(true_model, res.T_scene_model, T_gt)
    summary = {
        "object": {
            "category": obj.category,
            "seed": obj.seed,
            "transparent": obj.transparent,
            "size_m": (obj.bounds[1] - obj.bounds[0]).round(4).tolist(),
        },
        "actions": ep.kinds,
        "contact_points": int(len(ep.points)),
        "chamfer_mm": float(cd[0]),
        "predicted_category": pred,
        "true_category": obj.category,
        "correct": pred == obj.category,
        "class_probabilities": dict(zip(class_names, [float(p) for p in probs], strict=True)),
        "adi_cm": float(adi_cm),
        "stiqf_seconds": time.perf_counter() - t0,
        "T_scene_model_est": np.asarray(res.T_scene_model).tolist(),
        "T_scene_model_true": T_gt.tolist(),
    }
    arrays = {
        "recon": recon[0],
        "scene": scene,
        "model_pts": model_pts,
        "T_est": np.asarray(res.T_scene_model),
        "T_gt": T_gt,
    }
    return summary, arrays


def step_perceive(cfg: QuickstartConfig, out: Path) -> dict:
    """Step 4: reconstruction, recognition and S-TIQF pose; ``summary.json`` and ``summary.png``."""
    from vtlearn.models.actor import load_actor
    from vtlearn.models.xavtnet import load_xavtnet

    ep, obj = _load_episode(out)
    actor = load_actor(out / "actor.ckpt")
    xav = load_xavtnet(out / "xavtnet.ckpt")
    class_names = json.loads((out / "data" / "crossmodal" / "manifest.json").read_text())["class_names"]
    summary, a = perceive_object(
        actor, xav, class_names, obj, ep, seed=cfg.seed, stiqf_restarts=cfg.stiqf_restarts
    )
    summary_figure(
        out / "summary.png", obj, ep, a["recon"], a["scene"], a["model_pts"], a["T_est"], a["T_gt"], summary
    )
    return summary


def summary_figure(path: Path, obj, ep, recon, scene, model_pts, T_est, T_gt, s: dict) -> None:
    """Three 3-D panels saved as ``path``: the touches on the object, the ACTOR reconstruction against
    the true surface, and the S-TIQF pose overlay; ``recon`` ... ``T_gt`` and the summary ``s`` are what
    :func:`perceive_object` returns."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig = plt.figure(figsize=(16, 6))
    surf = obj.surface_world[::4]

    def panel(i, title):
        ax = fig.add_subplot(1, 3, i, projection="3d")
        ax.set_title(title, fontsize=10)
        ax.set_xlabel("x (m)")
        ax.set_ylabel("y (m)")
        ax.set_zlabel("z (m)")
        return ax

    ax = panel(
        1,
        f"{len(ep.kinds)} active actions on an unseen transparent {obj.category}\n"
        f"({s['contact_points']} contact points, colour = action order)",
    )
    ax.scatter(*surf.T, s=2, c="0.55", alpha=0.35, label="true surface")
    sc = ax.scatter(*ep.points.T, s=6, c=ep.step, cmap="viridis", label="contacts")
    starts = np.array([T[:3, 3] for T in ep.T_world_sensor])
    pinch = np.array([k == "pinch" for k in ep.kinds])
    if (~pinch).any():
        ax.scatter(*starts[~pinch].T, marker="o", c="tab:red", s=14, label="touch pad start")
    if pinch.any():
        ax.scatter(*starts[pinch].T, marker="^", c="tab:red", s=18, label="pinch grip centre")
    fig.colorbar(sc, ax=ax, shrink=0.5, pad=0.12, label="action (0 = first)")
    ax.legend(loc="upper left", fontsize=7)
    ax = panel(
        2,
        f"ACTOR reconstruction: CD {s['chamfer_mm']:.1f} mm\n"
        f"xAVTNet: {s['predicted_category']} (true {s['true_category']})",
    )
    ax.scatter(*surf.T, s=2, c="0.55", alpha=0.35, label="true surface")
    ax.scatter(*recon[::2].T, s=1, c="tab:blue", alpha=0.6, label="reconstruction")
    ax.legend(loc="upper left", fontsize=7)
    ax = panel(3, f"S-TIQF pose, ADI {s['adi_cm']:.2f} cm\n(scene: touched points at an unknown pose)")
    est = model_pts @ np.asarray(T_est)[:3, :3].T + np.asarray(T_est)[:3, 3]
    true = (obj.surface_world[::4] - obj.bounds.mean(0)) @ T_gt[:3, :3].T + T_gt[:3, 3]
    ax.scatter(*true.T, s=2, c="0.55", alpha=0.35, label="object at its true pose")
    ax.scatter(*est[::2].T, s=1, c="tab:orange", alpha=0.6, label="model at estimated pose")
    ax.scatter(*scene.T, s=6, c="k", label="scene (touches)")
    ax.legend(loc="upper left", fontsize=7)
    for ax in fig.axes:
        if ax.name == "3d":
            ax.set_box_aspect((1, 1, 1))
    fig.subplots_adjust(left=0.02, right=0.98, top=0.86, bottom=0.04, wspace=0.2)
    with atomic_path(path) as tmp:
        fig.savefig(tmp, dpi=110)
    plt.close(fig)


def run_quickstart(
    out: str | Path, cfg: QuickstartConfig | None = None, stop_after: str | None = None
) -> dict:
    """Run (or resume) every step into ``out``; returns the summary with per-step wall times.

    ``stop_after`` (``data``, ``train``, ``explore``) ends early, for tests and debugging.
    """
    import torch

    from vtlearn.torch_threads import keep_torch_threads

    cfg = cfg or QuickstartConfig()
    cfg.validate()
    steps = ("data", "train", "explore", "perceive")
    if stop_after is not None and stop_after not in steps:
        raise ValueError(f"stop_after: expected one of {steps}, got {stop_after!r}")
    out = Path(out)
    if out.exists() and not out.is_dir():
        raise ValueError(f"out: {out} is a file; the quickstart needs a folder to write into")
    out.mkdir(parents=True, exist_ok=True)
    cfg_path = out / "quickstart_config.json"
    cfg_json = json.loads(json.dumps(asdict(cfg)))
    if cfg_path.is_file() and json.loads(cfg_path.read_text()) != cfg_json:
        raise ValueError(
            f"out: {out} holds a quickstart made with another configuration; use a new directory"
        )
    cfg_path.write_text(json.dumps(cfg_json, indent=2))
    os.environ.setdefault("WANDB_MODE", "offline")
    timings, status = {}, {}
    result: dict = {}
    with keep_torch_threads():  # the caller gets its own thread count back
        torch.set_num_threads(max(1, min(2, os.cpu_count() or 1)))
        for name, fn in (
            ("data", step_data),
            ("train", step_train),
            ("explore", step_explore),
            ("perceive", step_perceive),
        ):
            t0 = time.perf_counter()
            r = fn(cfg, out)
            timings[name] = round(time.perf_counter() - t0, 1)
            log.info("quickstart %s: %.1f s %s", name, timings[name], r if name != "perceive" else "")
            if name == "perceive":
                result = r
            else:
                status[name] = r
            if stop_after == name:
                break
    result = dict(result, steps=status, seconds=timings)
    if "chamfer_mm" in result:
        (out / "summary.json").write_text(json.dumps(result, indent=2))
    return result


# ------------------------------------------------------------------------------------------ CLI
def _cmd_quickstart(args) -> int:
    cfg = tiny_quickstart_config() if args.tiny else QuickstartConfig()
    if args.categories:
        cfg.categories = csv_list(args.categories)
    for name in ("actor_epochs", "xavtnet_epochs", "n_actions", "seed"):
        v = getattr(args, name)
        if v is not None:
            setattr(cfg, name, v)
    t0 = time.perf_counter()
    s = run_quickstart(args.out, cfg)
    print(
        f"object: unseen transparent {s['true_category']} ({s['contact_points']} contact points from "
        f"{len(s['actions'])} active actions)"
    )
    print(f"reconstruction (ACTOR): Chamfer distance {s['chamfer_mm']:.1f} mm")
    print(f"recognition (xAVTNet):  predicted {s['predicted_category']}, true {s['true_category']}")
    print(f"pose (S-TIQF):          ADI {s['adi_cm']:.2f} cm")
    print(f"step seconds: {s['seconds']}  total {time.perf_counter() - t0:.0f} s")
    print(f"wrote {Path(args.out) / 'summary.png'} and {Path(args.out) / 'summary.json'}")
    return 0


def register(sub) -> None:
    p = sub.add_parser(
        "quickstart", help="end-to-end: data, quick models, active touch, reconstruct/recognise/pose"
    )
    p.add_argument(
        "--out", default="runs/quickstart", help="output directory; a rerun resumes (default %(default)s)"
    )
    p.add_argument(
        "--categories", default=None, help="comma-separated categories (default wineglass,bottle,mug,can)"
    )
    p.add_argument("--actor-epochs", type=count(1), default=None)
    p.add_argument("--xavtnet-epochs", type=count(1), default=None)
    p.add_argument("--n-actions", type=count(1), default=None, help="active touch/pinch budget (default 20)")
    p.add_argument("--seed", type=count(0), default=None)
    p.add_argument(
        "--tiny", action="store_true", help="seconds-scale sizes (smoke test; meaningless quality)"
    )
    p.set_defaults(func=_cmd_quickstart)
