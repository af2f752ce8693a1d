"""Closed-loop active-perception benchmarks with the networks in the loop, and the quickstart command.

- ``vtlearn bench active-reconstruction --ckpt ACTOR.ckpt``: thesis Fig. 8.7 analogue. Held-out
  transparent objects are explored with touches and pinches (8.2.3) chosen ``active`` / ``random`` /
  ``uniform``; after every action ACTOR reconstructs the object from the contacts so far, and the
  Chamfer distance (eq. 8.1, mm) to the true surface is recorded.
- ``vtlearn bench active-recognition --ckpt XAVTNET.ckpt``: thesis Fig. 7.5b analogue (7.2.4,
  eq. 7.9-7.12, Algorithm 5). Touches are chosen by the grid's expected information gain; xAVTNet
  classifies the tactile cloud once it holds ``--min-points`` points and stops at confidence ``zeta``.
  ``--recognition-gain`` adds the row ``active_recognition``: touches chosen by the classifier's own
  expected information (:mod:`vtlearn.active.recognition_nbt`, beyond the thesis). The row
  ``active_novelty`` (on by default, ``--no-novelty-gain`` drops it) takes the touches whose contacts,
  predicted on the templates of the most probable classes, land farthest from the points measured so far
  (:mod:`vtlearn.active.recognition_novelty`, beyond the thesis): of the criteria measured, the one that
  beats random and uniform touches (docs/active_perception.md). Every active row is compared with random
  and with uniform, paired over the objects. An action depends
  only on the actions before it, so one episode of ``--max-actions`` is run per object and strategy
  and the stopping rule is applied to its prefixes (the same actions a stopping loop would take).
  Reports actions to the stop (censored at ``--max-actions``), accuracy at the stop and accuracy after
  10 touches.
- ``vtlearn bench shared-exploration --ckpt ACTOR.ckpt``: thesis Fig. 5.13 and 5.18 analogue (5.2.3,
  eq. 5.10). Opaque objects get 3 views and 5 touches, transparent ones 20 touches; CD of ACTOR from
  vision only and from vision + touch (the thesis' +17 % from touch), and the ADI (eq. 5.24, cm) of
  S-TIQF registering the reconstruction (model) to the touched scene under a random pose. On the
  transparent objects (touch only) the ``active`` row uses the box-fit criterion by default
  (``--transparent-gain box_fit``; ``grid`` keeps the occupancy-grid gain, which saturates there).

Every benchmark prints a table and writes JSON and a PNG (default under ``runs/bench/``).
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np

from vtlearn.bench_utils import csv_list, wilcoxon_p
from vtlearn.cli_args import category_list, count, with_flag
from vtlearn.validation import load_named

THESIS = {
    "active-reconstruction": {
        "cd_mm_at_20": {"active": 20.0, "random": 65.0, "uniform": 192.0},
        "figure": "8.7",
    },
    "active-recognition": {
        "actions_to_recognition": {"active": 14, "random": 19, "uniform": 27},
        "figure": "7.5b",
    },
    "shared-exploration": {"touch_gain_percent": 17.0, "figure": "5.13, 5.18"},
}


def _strategies(args, pinches: bool = False) -> list[tuple[str, str, str]]:
    """(label, strategy, gain mode) rows; ``--gain-mode both`` adds the thesis criterion as its own row.
    ``random_pinch`` is allowed only where the episodes have pinches and no views (``pinches``)."""
    from vtlearn.active.closed_loop import STRATEGIES, TOUCH_STRATEGIES

    allowed = STRATEGIES if pinches else TOUCH_STRATEGIES
    modes = ["probabilistic", "raycast"] if args.gain_mode == "both" else [args.gain_mode]
    rows = []
    names = csv_list(args.strategies)
    if not names:
        raise ValueError(f"--strategies: no strategy given; expected some of {allowed}")
    for s in names:
        if s not in allowed:
            raise ValueError(f"--strategies: unknown {s!r} here, expected some of {allowed}")
        if s == "active":
            rows += [("active" if i == 0 else f"active_{m}", s, m) for i, m in enumerate(modes)]
        else:
            rows.append((s, s, modes[0]))
    return rows


def _setup(args):
    import torch

    torch.set_num_threads(max(1, int(args.threads)))
    if args.objects_per_category < 1:
        raise ValueError(f"--objects-per-category: need >= 1, got {args.objects_per_category}")


def _write(args, name: str, result: dict, plot) -> None:
    from vtlearn.bench_utils import machine_info, write_json

    result.setdefault("machine", machine_info())  # as every bench JSON records it
    # atomic, and before the plot: a plot that fails loses no results
    out = write_json(args.json or f"runs/bench/{name.replace('-', '_')}.json", result)
    png = out.with_suffix(".png")
    plot(result, png)
    print(f"wrote {out} and {png}")


def _stats(x: np.ndarray) -> dict:
    x = np.asarray(x, dtype=float)
    ok = np.isfinite(x)
    return {
        "mean": float(np.mean(x[ok])) if ok.any() else None,
        "std": float(np.std(x[ok])) if ok.any() else None,
        "n": int(ok.sum()),
    }


def paired_vs_baseline(values, baseline) -> dict:
    """Per-object comparison of a strategy with a baseline on a lower-is-better figure (CD, actions).

    The objects are the same for every strategy, so the test is paired: the two-sided Wilcoxon signed-rank
    test of the differences (``None`` when all are zero or fewer than two pairs are finite). Pairs with a
    non-finite value on either side (an object the strategy never reconstructed) are left out.

    Shapes:
        values (N,), baseline (N,) -> {"lower", "higher", "ties", "pairs", "mean_diff", "wilcoxon_p"}
    """
    a, b = np.asarray(values, dtype=float), np.asarray(baseline, dtype=float)
    if a.ndim != 1 or a.shape != b.shape:
        raise ValueError(f"values and baseline must be (N,) of the same length, got {a.shape} and {b.shape}")
    ok = np.isfinite(a) & np.isfinite(b)
    diff = a[ok] - b[ok]
    return {"lower": int((diff < 0).sum()), "higher": int((diff > 0).sum()), "ties": int((diff == 0).sum()),
            "pairs": int(diff.size), "mean_diff": float(diff.mean()) if diff.size else None,
            "wilcoxon_p": wilcoxon_p(diff)}


def _print_paired(title: str, paired: dict) -> None:
    print(title)
    for label, q in paired.items():
        p = "n/a" if q["wilcoxon_p"] is None else f"{q['wilcoxon_p']:.3f}"
        d = "n/a" if q["mean_diff"] is None else f"{q['mean_diff']:+.1f}"
        print(f"  {label:<30} lower on {q['lower']:>2}, higher on {q['higher']:>2} of {q['pairs']}; "
              f"mean diff {d}; Wilcoxon p {p}")


# ------------------------------------------------------------------------------ active reconstruction
def run_active_reconstruction(args: argparse.Namespace) -> int:
    from tqdm import tqdm

    from vtlearn.active.closed_loop import TouchWorld, held_out_objects, reconstruct_prefixes, run_episode
    from vtlearn.models.actor import load_actor

    _setup(args)
    categories = category_list(args.categories, "--categories", transparent=True)
    rows = _strategies(args, pinches=not args.no_pinch)
    model = load_named(load_actor, args.ckpt, "--ckpt")
    objs = held_out_objects(categories, args.objects_per_category, transparent=True, **_objects_from(args))
    reconstructor = None
    if any(mode == "box_fit" for _, _, mode in rows):
        from vtlearn.active.reconstruction_nbt import ExpectedBoxFitGain

        reconstructor = ExpectedBoxFitGain(model, max_points=args.max_input)
    ks = list(range(1, args.actions + 1))
    curves = {label: [] for label, _, _ in rows}
    per_object = []
    t0 = time.perf_counter()
    bar = tqdm(total=len(objs) * len(rows), desc="active-reconstruction")
    for oi, obj in enumerate(objs):
        rec = {"category": obj.category, "seed": obj.seed}
        with TouchWorld(obj) as world:
            for label, strategy, mode in rows:
                ep = run_episode(
                    world,
                    strategy,
                    args.actions,
                    pinch=not args.no_pinch,
                    n_candidates=args.candidates,
                    cells=args.cells,
                    gain_mode=mode,
                    seed=args.seed + oi,
                    reconstructor=reconstructor,
                )
                _, cd = reconstruct_prefixes(model, obj, ep, ks, max_points=args.max_input)
                curves[label].append(cd)
                rec[label] = {"cd_mm": [None if not np.isfinite(c) else float(c) for c in cd], **ep.to_dict()}
                bar.update()
        per_object.append(rec)
    bar.close()
    summary = {}
    for label in curves:
        c = np.array(curves[label])  # objects x actions
        summary[label] = {
            "cd_mm_mean": [
                None if not np.isfinite(c[:, i]).any() else float(np.nanmean(c[:, i])) for i in range(len(ks))
            ],
            "cd_mm_std": [
                None if not np.isfinite(c[:, i]).any() else float(np.nanstd(c[:, i])) for i in range(len(ks))
            ],
            "at_max_actions": _stats(c[:, -1]),
        }
    wins, paired = {}, {}
    for base in ("random", "uniform", "random_pinch"):
        if "active" in curves and base in curves:
            a, b = np.array(curves["active"])[:, -1], np.array(curves[base])[:, -1]
            wins[f"active_beats_{base}"] = int(np.sum(a < b))
            paired[f"active vs {base}"] = paired_vs_baseline(a, b)
    result = {
        "benchmark": "active-reconstruction",
        "ckpt": str(args.ckpt),
        "actions": ks,
        "objects": [{"category": o.category, "seed": o.seed} for o in objs],
        "object_seed": args.object_seed,
        "gain_mode": args.gain_mode,
        "pinch": not args.no_pinch,
        "candidates": args.candidates,
        "cells": args.cells,
        "max_input_points": args.max_input,
        "summary": summary,
        "per_object_wins_at_max_actions": wins,
        "paired_at_max_actions": paired,
        "thesis": THESIS["active-reconstruction"],
        "per_object": per_object,
        "seconds": round(time.perf_counter() - t0, 1),
    }
    print(f"\nACTOR Chamfer distance (mm) vs actions, {len(objs)} held-out transparent objects")
    marks = [k for k in (1, 5, 10, 15, 20, args.actions) if k <= args.actions]
    marks = sorted(set(marks))
    print(f"{'strategy':<16}" + "".join(f"{k:>10d}" for k in marks))
    for label, s in summary.items():
        print(
            f"{label:<16}"
            + "".join(
                f"{s['cd_mm_mean'][k - 1]:>10.1f}" if s["cd_mm_mean"][k - 1] is not None else f"{'-':>10}"
                for k in marks
            )
        )
    print(f"per-object wins of active at {args.actions} actions (of {len(objs)}): {wins}")
    if paired:
        _print_paired(f"paired CD (mm) at {args.actions} actions, over the objects:", paired)
    _write(args, "active-reconstruction", result, _plot_reconstruction)
    return 0


def _plot_reconstruction(result: dict, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    ks = np.array(result["actions"])
    fig, ax = plt.subplots(figsize=(6, 4))
    mode = result.get("gain_mode", "both")
    for label, s in result["summary"].items():
        m = np.array([np.nan if v is None else v for v in s["cd_mm_mean"]])
        sd = np.array([np.nan if v is None else v for v in s["cd_mm_std"]])
        ax.plot(ks, m, label=f"active ({mode})" if label == "active" and mode != "both" else label)
        ax.fill_between(ks, m - sd, m + sd, alpha=0.15)
    ax.set_xlabel("actions (touches and pinches)")
    ax.set_ylabel("Chamfer distance (mm)")
    ax.set_title(f"ACTOR on {len(result['objects'])} held-out transparent objects (cf. thesis Fig. 8.7)")
    ax.legend()
    ax.grid(alpha=0.3)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


# ------------------------------------------------------------------------------ active recognition
def run_active_recognition(args: argparse.Namespace) -> int:
    from tqdm import tqdm

    from vtlearn.active.closed_loop import (
        TouchWorld,
        classify_prefixes,
        held_out_objects,
        run_episode,
    )
    from vtlearn.models.xavtnet import load_xavtnet

    _setup(args)
    if not 0 < args.zeta <= 1:
        raise ValueError(f"--zeta: need a confidence in (0, 1], got {args.zeta}")
    if args.min_points < 1:
        raise ValueError(f"--min-points: need >= 1, got {args.min_points}")
    if args.max_actions < 10:
        raise ValueError(f"--max-actions: need >= 10 (the table reads the accuracy at 10 actions), "
                         f"got {args.max_actions}")
    cats = category_list(args.categories, "--categories") if args.categories else None
    rows = _strategies(args)
    data_names = None if args.data is None else _manifest_class_names(args.data)
    model = load_named(load_xavtnet, args.ckpt, "--ckpt")
    class_names = _class_names(data_names, int(model.hparams.num_classes))
    cats = cats or class_names
    unknown = [c for c in cats if c not in class_names]
    if unknown:
        raise ValueError(f"--categories: {unknown} are not classes of the checkpoint ({class_names})")
    objs = held_out_objects(cats, args.objects_per_category, transparent=None, **_objects_from(args))
    recognizers = {}
    if args.recognition_gain:
        from vtlearn.active.recognition_nbt import ExpectedClassEntropyGain

        recognizers["recognition"] = ExpectedClassEntropyGain(
            model, class_names, top_m=args.recognition_top_m, max_points=args.max_input,
            templates_per_class=args.recognition_templates)
        rows.append(("active_recognition", "active", "recognition"))
    if args.novelty_gain:
        from vtlearn.active.recognition_novelty import ExpectedContactNovelty

        recognizers["novelty"] = ExpectedContactNovelty(model, class_names, top_m=args.recognition_top_m,
                                                        max_points=args.max_input,
                                                        library=recognizers.get("recognition"))
        rows.append(("active_novelty", "active", "novelty"))
    ks = list(range(1, args.max_actions + 1))
    res = {
        label: {"actions": [], "correct_at_stop": [], "correct_at_10": [], "stopped": []}
        for label, _, _ in rows
    }
    per_object = []
    t0 = time.perf_counter()
    bar = tqdm(total=len(objs) * len(rows), desc="active-recognition")
    for oi, obj in enumerate(objs):
        truth = class_names.index(obj.category)
        rec = {"category": obj.category, "seed": obj.seed, "transparent": obj.transparent}
        with TouchWorld(obj) as world:
            for label, strategy, mode in rows:
                ep = run_episode(
                    world,
                    strategy,
                    args.max_actions,
                    pinch=False,
                    n_candidates=args.candidates,
                    cells=args.cells,
                    gain_mode=mode,
                    n_init=1,
                    seed=args.seed + oi,
                    recognizer=recognizers.get(mode),
                )
                probs = classify_prefixes(model, obj, ep, ks, max_points=args.max_input)
                npts = ep.n_points()[1:]
                conf = np.nan_to_num(np.nanmax(np.where(np.isfinite(probs), probs, -1), axis=1), nan=-1)
                ready = (npts >= args.min_points) & (conf >= args.zeta)
                stop = int(np.argmax(ready)) if ready.any() else len(ks) - 1
                pred = (
                    probs.argmax(1)
                    if np.isfinite(probs).all()
                    else np.where(np.isfinite(probs).all(1), np.nan_to_num(probs, nan=-1).argmax(1), -1)
                )
                r = res[label]
                r["actions"].append(ks[stop])
                r["stopped"].append(bool(ready.any()))
                r["correct_at_stop"].append(bool(pred[stop] == truth))
                r["correct_at_10"].append(bool(pred[9] == truth))
                rec[label] = {
                    "actions": ks[stop],
                    "stopped": bool(ready.any()),
                    "pred_at_stop": int(pred[stop]),
                    "confidence": [float(c) for c in conf],
                    "n_points": npts.tolist(),
                }
                bar.update()
        per_object.append(rec)
    bar.close()
    summary = {
        label: {
            "actions_mean": float(np.mean(r["actions"])),
            "actions_std": float(np.std(r["actions"])),
            "reached_zeta": float(np.mean(r["stopped"])),
            "accuracy_at_stop": float(np.mean(r["correct_at_stop"])),
            "accuracy_after_10": float(np.mean(r["correct_at_10"])),
        }
        for label, r in res.items()
    }
    paired = {
        f"{label} vs random": paired_vs_baseline(r["actions"], res["random"]["actions"])
        for label, r in res.items() if label != "random" and "random" in res
    }
    paired.update({
        f"{label} vs uniform": paired_vs_baseline(r["actions"], res["uniform"]["actions"])
        for label, r in res.items() if label.startswith("active") and "uniform" in res
    })
    result = {
        "benchmark": "active-recognition",
        "ckpt": str(args.ckpt),
        "class_names": class_names,
        "zeta": args.zeta,
        "min_points": args.min_points,
        "max_actions": args.max_actions,
        "candidates": args.candidates,
        "object_seed": args.object_seed,
        "objects": [{"category": o.category, "seed": o.seed, "transparent": o.transparent} for o in objs],
        "summary": summary,
        "paired_actions": paired,
        "thesis": THESIS["active-recognition"],
        "per_object": per_object,
        "seconds": round(time.perf_counter() - t0, 1),
    }
    print(
        f"\nxAVTNet tactile recognition, zeta {args.zeta}, >= {args.min_points} points, "
        f"{len(objs)} held-out objects"
    )
    print(f"{'strategy':<16}{'actions':>10}{'std':>8}{'reached ζ':>11}{'acc@stop':>10}{'acc@10':>9}")
    for label, s in summary.items():
        print(
            f"{label:<16}{s['actions_mean']:>10.1f}{s['actions_std']:>8.1f}{s['reached_zeta']:>11.2f}"
            f"{s['accuracy_at_stop']:>10.2f}{s['accuracy_after_10']:>9.2f}"
        )
    print(f"(objects that never reach zeta count as {args.max_actions} actions)")
    if paired:
        _print_paired("paired actions to zeta, over the objects (lower is better):", paired)
    _write(args, "active-recognition", result, _plot_recognition)
    return 0


def _manifest_class_names(data: str) -> list[str]:
    """The class names in the ``manifest.json`` of the crossmodal dataset ``--data``."""
    from vtlearn.datamodules.shards import load_manifest

    return list(load_manifest(data, "--data")["class_names"])


def _class_names(data_names: list[str] | None, num_classes: int) -> list[str]:
    from vtlearn.sim_data.shapes import CATEGORIES

    if data_names is not None:
        names = data_names
    elif num_classes == len(CATEGORIES):
        names = list(CATEGORIES)
    else:
        raise ValueError(
            f"--data: the checkpoint has {num_classes} classes; pass --data with the crossmodal "
            "dataset it was trained on (for its class names)"
        )
    if len(names) != num_classes:
        raise ValueError(f"--data: {len(names)} class names but the checkpoint has {num_classes} classes")
    return list(names)


def _plot_recognition(result: dict, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    labels = list(result["summary"])
    fig, axes = plt.subplots(1, 2, figsize=(9, 3.8))
    m = [result["summary"][s]["actions_mean"] for s in labels]
    sd = [result["summary"][s]["actions_std"] for s in labels]
    axes[0].bar(labels, m, yerr=sd, color="tab:blue", alpha=0.7, capsize=4)
    thesis = result["thesis"]["actions_to_recognition"]
    axes[0].scatter(
        [s for s in labels if s in thesis],
        [thesis[s] for s in labels if s in thesis],
        c="k",
        marker="x",
        label="thesis Fig. 7.5b",
        zorder=3,
    )
    axes[0].set_ylabel(f"actions to confidence {result['zeta']}")
    axes[0].legend()
    axes[1].bar(
        labels, [result["summary"][s]["accuracy_after_10"] for s in labels], color="tab:green", alpha=0.7
    )
    axes[1].set_ylabel("accuracy after 10 touches")
    axes[1].set_ylim(0, 1)
    fig.suptitle(f"xAVTNet active tactile recognition, {len(result['objects'])} held-out objects")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


# ------------------------------------------------------------------------------ shared exploration
def run_shared_exploration(args: argparse.Namespace) -> int:
    from tqdm import tqdm

    from vtlearn.active.closed_loop import TouchWorld, held_out_objects, reconstruct_prefixes, run_episode
    from vtlearn.classical.registration import register
    from vtlearn.geometry.metrics import adi
    from vtlearn.models.actor import load_actor

    _setup(args)
    opaque_cats = category_list(args.opaque, "--opaque", transparent=False, empty_ok=True)
    transparent_cats = category_list(args.transparent, "--transparent", transparent=True, empty_ok=True)
    if not opaque_cats and not transparent_cats:
        raise ValueError("--opaque, --transparent: both empty, so there is no object to explore; "
                         "give at least one category")
    rows = _strategies(args)
    model = load_named(load_actor, args.ckpt, "--ckpt")
    opaque = held_out_objects(
        opaque_cats, args.objects_per_category, transparent=False, **_objects_from(args)
    )
    transparent = held_out_objects(
        transparent_cats, args.objects_per_category, transparent=True, **_objects_from(args)
    )
    reconstructor = None
    if args.transparent_gain == "box_fit":
        from vtlearn.active.reconstruction_nbt import ExpectedBoxFitGain

        reconstructor = ExpectedBoxFitGain(model, max_points=args.max_input)
    per = {
        label: {"opaque_vision": [], "opaque_visuotactile": [], "transparent_curve": [], "adi_cm": []}
        for label, _, _ in rows
    }
    per_object = []
    t0 = time.perf_counter()
    bar = tqdm(total=(len(opaque) + len(transparent)) * len(rows), desc="shared-exploration")
    for oi, obj in enumerate(opaque + transparent):
        is_t = obj.transparent
        rec = {"category": obj.category, "seed": obj.seed, "transparent": is_t}
        n_views, n_tac = (0, args.touches_transparent) if is_t else (args.views, args.touches_opaque)
        with TouchWorld(obj) as world:
            for label, strategy, mode in rows:
                if reconstructor is not None and strategy == "active" and mode == "probabilistic":
                    mode = "auto"  # box fit on the touch-only (transparent) objects, the grid gain with views
                ep = run_episode(
                    world,
                    strategy,
                    n_tac,
                    n_views=n_views,
                    pinch=False,
                    n_candidates=args.candidates,
                    cells=args.cells,
                    gain_mode=mode,
                    n_init=1 if is_t else 0,
                    seed=args.seed + oi,
                    reconstructor=reconstructor,
                )
                n = ep.n_steps
                r = {**ep.to_dict()}
                if is_t:
                    recon, cd = reconstruct_prefixes(
                        model, obj, ep, list(range(1, n + 1)), max_points=args.max_input
                    )
                    per[label]["transparent_curve"].append(cd)
                    r["cd_mm"] = [None if not np.isfinite(c) else float(c) for c in cd]
                    scene_pts, model_cloud = ep.prefix(n, "tactile"), recon[-1]
                else:
                    (_, cd_v) = reconstruct_prefixes(
                        model, obj, ep, [n], modality="visual", max_points=args.max_input
                    )
                    recon, cd_vt = reconstruct_prefixes(model, obj, ep, [n], max_points=args.max_input)
                    per[label]["opaque_vision"].append(cd_v[0])
                    per[label]["opaque_visuotactile"].append(cd_vt[0])
                    r["cd_mm_vision"], r["cd_mm_visuotactile"] = float(cd_v[0]), float(cd_vt[0])
                    scene_pts, model_cloud = ep.prefix(n, "all"), recon[0]
                r["adi_cm"] = _pose_adi(obj, model_cloud, scene_pts, args, oi, register, adi)
                per[label]["adi_cm"].append(r["adi_cm"] if r["adi_cm"] is not None else np.nan)
                rec[label] = r
                bar.update()
        per_object.append(rec)
    bar.close()
    summary = {}
    for label, p in per.items():
        v, vt = np.array(p["opaque_vision"], float), np.array(p["opaque_visuotactile"], float)
        ok = np.isfinite(v) & np.isfinite(vt)
        curve = np.array(p["transparent_curve"], float) if p["transparent_curve"] else np.zeros((0, 1))
        summary[label] = {
            "opaque_cd_mm_vision": _stats(v),
            "opaque_cd_mm_visuotactile": _stats(vt),
            "touch_gain_percent": float(100 * (v[ok].mean() - vt[ok].mean()) / v[ok].mean())
            if ok.any()
            else None,
            "transparent_cd_mm_curve": [
                None if not np.isfinite(curve[:, i]).any() else float(np.nanmean(curve[:, i]))
                for i in range(curve.shape[1])
            ]
            if len(curve)
            else [],
            "transparent_cd_mm_at_max": _stats(curve[:, -1]) if len(curve) else None,
            "adi_cm": _stats(np.array(p["adi_cm"], float)),
        }
    result = {
        "benchmark": "shared-exploration",
        "ckpt": str(args.ckpt),
        "views": args.views,
        "touches_opaque": args.touches_opaque,
        "touches_transparent": args.touches_transparent,
        "transparent_gain": args.transparent_gain,
        "objects": [
            {"category": o.category, "seed": o.seed, "transparent": o.transparent}
            for o in opaque + transparent
        ],
        "summary": summary,
        "thesis": THESIS["shared-exploration"],
        "per_object": per_object,
        "seconds": round(time.perf_counter() - t0, 1),
    }
    print(
        f"\nShared exploration: {len(opaque)} opaque ({args.views} views + {args.touches_opaque} touches), "
        f"{len(transparent)} transparent ({args.touches_transparent} touches)"
    )
    print(
        f"{'strategy':<16}{'CD vis mm':>11}{'CD vis+tac':>12}{'touch gain':>12}"
        f"{'CD transp.':>12}{'ADI cm':>9}"
    )
    for label, s in summary.items():

        def f(d):
            return f"{d['mean']:.1f}" if d and d["mean"] is not None else "-"

        g = f"{s['touch_gain_percent']:.1f} %" if s["touch_gain_percent"] is not None else "-"
        print(
            f"{label:<16}{f(s['opaque_cd_mm_vision']):>11}{f(s['opaque_cd_mm_visuotactile']):>12}{g:>12}"
            f"{f(s['transparent_cd_mm_at_max']):>12}{f(s['adi_cm']):>9}"
        )
    _write(args, "shared-exploration", result, _plot_shared)
    return 0


def _pose_adi(obj, model_cloud, scene_pts, args, oi: int, register, adi) -> float | None:
    """S-TIQF of the reconstruction (model, metric frame centred on the box) to the measured points moved by
    a random rigid motion (yaw in [-180, 180] deg, +-5 cm); ADI (eq. 5.24) with the true surface, cm."""
    if model_cloud is None or len(scene_pts) < 3:
        return None
    rng = np.random.default_rng([args.seed, oi, 77])
    yaw = rng.uniform(-np.pi, np.pi)
    T_sw = np.eye(4)
    T_sw[:3, :3] = [[np.cos(yaw), -np.sin(yaw), 0], [np.sin(yaw), np.cos(yaw), 0], [0, 0, 1]]
    T_sw[:3, 3] = rng.uniform(-0.05, 0.05, 3) * [1, 1, 0]
    centre = obj.bounds.mean(0)
    T_wm = np.eye(4)
    T_wm[:3, 3] = centre
    scene = np.asarray(scene_pts) @ T_sw[:3, :3].T + T_sw[:3, 3]
    if len(scene) > args.max_scene:
        scene = scene[rng.choice(len(scene), args.max_scene, replace=False)]
    try:
        res = register(model_cloud - centre, scene, "stiqf", restarts=args.restarts, seed=args.seed)
    except ValueError:  # a collinear or degenerate scene (e.g. one flat touch)
        return None
    return 100.0 * adi(obj.surface_world - centre, res.T_scene_model, T_sw @ T_wm)


def _plot_shared(result: dict, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    labels = list(result["summary"])
    fig, axes = plt.subplots(1, 3, figsize=(14, 4))
    x = np.arange(len(labels))
    for off, key, name in (
        (-0.2, "opaque_cd_mm_vision", "vision"),
        (0.2, "opaque_cd_mm_visuotactile", "vision + touch"),
    ):
        m = [result["summary"][s][key]["mean"] or np.nan for s in labels]
        sd = [result["summary"][s][key]["std"] or 0 for s in labels]
        axes[0].bar(x + off, m, 0.4, yerr=sd, capsize=3, label=name)
    axes[0].set_xticks(x, labels)
    axes[0].set_ylabel("Chamfer distance (mm)")
    axes[0].set_title(f"opaque: {result['views']} views + {result['touches_opaque']} touches (Fig. 5.13a)")
    axes[0].legend()
    for s in labels:
        c = np.array([np.nan if v is None else v for v in result["summary"][s]["transparent_cd_mm_curve"]])
        axes[1].plot(np.arange(1, len(c) + 1), c, label=s)
    axes[1].set_xlabel("touches")
    axes[1].set_ylabel("Chamfer distance (mm)")
    axes[1].set_title("transparent: touch only (Fig. 5.13b)")
    axes[1].legend()
    m = [result["summary"][s]["adi_cm"]["mean"] or np.nan for s in labels]
    sd = [result["summary"][s]["adi_cm"]["std"] or 0 for s in labels]
    axes[2].bar(labels, m, yerr=sd, capsize=3, color="tab:purple", alpha=0.7)
    axes[2].set_ylabel("ADI (cm)")
    axes[2].set_title("S-TIQF, model = reconstruction (Fig. 5.18)")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def _objects_from(args: argparse.Namespace) -> dict:
    """``held_out_objects`` keywords from ``--object-seed`` (the default base seed when it is not given)."""
    return {} if args.object_seed is None else {"base_seed": int(args.object_seed)}


# ------------------------------------------------------------------------------ registration
def _common(p, actions_default: int | None = None, extra_gain_modes: tuple[str, ...] = ()) -> None:
    p.add_argument("--objects-per-category", type=count(1), default=2)
    p.add_argument("--strategies", default="active,random,uniform",
                   help="comma-separated: active, random, uniform, random_pinch (random pinches only; "
                        "active-reconstruction)")
    p.add_argument(
        "--gain-mode",
        choices=("probabilistic", "raycast", "both", *extra_gain_modes),
        default="both",
        help="active criterion; 'both' reports the thesis raycast criterion as active_raycast"
        + ("; box_fit: expected fit of ACTOR's reconstruction to the known box (beyond the thesis)"
           if "box_fit" in extra_gain_modes else ""),
    )
    p.add_argument("--candidates", type=count(1), default=100, help="Monte-Carlo candidates per active step")
    p.add_argument("--cells", type=count(1), default=40, help="occupancy grid cells per axis")
    p.add_argument("--max-input", type=count(1), default=120, help="network input points (voxel subsampling)")
    p.add_argument("--seed", type=count(0), default=0)
    p.add_argument(
        "--object-seed",
        type=count(0),
        default=None,
        help="base seed of the held-out instances (default closed_loop.HELD_OUT_SEED); another value draws "
        "other objects, e.g. to confirm a result on instances it was not tuned on",
    )
    p.add_argument("--threads", type=count(1), default=1, help="torch threads")
    p.add_argument("--json", default=None, help="output JSON (PNG beside it)")


def register_bench(sub) -> None:
    p = sub.add_parser(
        "active-reconstruction", help="ACTOR CD vs touch/pinch actions: active/random/uniform (Fig. 8.7)"
    )
    p.add_argument("--ckpt", required=True, help="ACTOR Lightning checkpoint")
    p.add_argument("--categories", default="wineglass,bottle", help="categories with transparent instances")
    p.add_argument("--actions", type=count(1), default=20)
    p.add_argument("--no-pinch", action="store_true", help="touches only")
    _common(p, extra_gain_modes=("box_fit",))
    p.set_defaults(func=run_active_reconstruction)

    p = sub.add_parser(
        "active-recognition", help="xAVTNet touches to confidence zeta: active/random/uniform (Fig. 7.5b)"
    )
    p.add_argument("--ckpt", required=True, help="xAVTNet Lightning checkpoint")
    p.add_argument(
        "--data", default=None, help="crossmodal dataset the checkpoint was trained on (class names)"
    )
    p.add_argument("--categories", default=None, help="object categories (default: every class)")
    p.add_argument("--zeta", type=float, default=0.8)
    p.add_argument("--min-points", type=count(1), default=10)
    p.add_argument("--max-actions", type=count(1), default=30)
    p.add_argument("--recognition-gain", action="store_true",
                   help="add active_recognition: touches by the classifier's expected information "
                        "(vtlearn.active.recognition_nbt; beyond the thesis)")
    p.add_argument("--novelty-gain", action=argparse.BooleanOptionalAction, default=True,
                   help="the row active_novelty: touches by the expected novelty of their contacts on the "
                        "class templates (vtlearn.active.recognition_novelty; beyond the thesis; default on)")
    p.add_argument("--recognition-top-m", type=count(1), default=4,
                   help="class hypotheses per step (--recognition-gain and --novelty-gain)")
    p.add_argument("--recognition-templates", type=count(1), default=1,
                   help="template shapes per class hypothesis (default 1; the classifier runs top-m x this "
                        "many times per candidate)")
    _common(p)
    p.set_defaults(func=run_active_recognition, max_input=256)

    p = sub.add_parser("shared-exploration", help="views + touches, touch gain, S-TIQF ADI (Fig. 5.13, 5.18)")
    p.add_argument("--ckpt", required=True, help="ACTOR Lightning checkpoint")
    p.add_argument("--opaque", default="mug,can", help="opaque categories ('' for none)")
    p.add_argument("--transparent", default="wineglass",
                   help="categories with transparent instances ('' for none; not both empty)")
    p.add_argument("--views", type=count(1), default=3)
    p.add_argument("--touches-opaque", type=count(0), default=5)
    p.add_argument("--touches-transparent", type=count(0), default=20)
    p.add_argument("--restarts", type=count(0), default=4, help="S-TIQF random restarts")
    p.add_argument("--max-scene", type=count(1), default=400, help="scene points given to S-TIQF")
    p.add_argument("--transparent-gain", choices=("box_fit", "grid"), default="box_fit",
                   help="criterion of the probabilistic active row on transparent objects (touch only): "
                        "box_fit (default; vtlearn.active.reconstruction_nbt, beyond the thesis) or grid "
                        "(the occupancy-grid gain, which saturates there; docs/active_perception.md)")
    _common(p)
    p.set_defaults(func=run_shared_exploration)


def _episode_prefixes(text: str | None, touches: int) -> list[int]:
    """``--prefixes`` as integers; unset, the default 4, 10, 20 cut to those within ``--touches`` (and
    ``--touches`` itself when none is). Given prefixes are kept as given, for the config to check."""
    if text is None:
        return [k for k in (4, 10, 20) if k <= touches] or [touches]
    try:
        return [int(k) for k in csv_list(text)]
    except ValueError:
        raise ValueError(f"--prefixes: need comma-separated integers, got {text!r}") from None


# EpisodeDataConfig fields / generate_episode_dataset arguments -> the `gen-episodes` flags, for the errors
_GEN_EPISODES_FLAGS = {
    "source": "--source", "split": "--split", "strategies": "--strategies", "touches": "--touches",
    "prefixes": "--prefixes", "min_points": "--min-points", "n_candidates": "--candidates",
    "cells": "--cells", "gain_mode": "--gain-mode", "seed": "--seed", "shard_size": "--shard-size",
    "out_dir": "--out", "workers": "--workers",
}


def _cmd_gen_episodes(args: argparse.Namespace) -> int:
    from vtlearn.sim_data.writer import OutDirConfigError

    try:
        return _gen_episodes(args)
    except OutDirConfigError as exc:
        raise exc.with_names(_GEN_EPISODES_FLAGS) from None
    except (ValueError, FileNotFoundError) as exc:
        raise (with_flag(exc, _GEN_EPISODES_FLAGS) or exc) from None


def _gen_episodes(args: argparse.Namespace) -> int:
    from vtlearn.active.episode_data import EpisodeDataConfig, generate_episode_dataset

    cfg = EpisodeDataConfig(
        source=args.source, split=args.split, strategies=csv_list(args.strategies), touches=args.touches,
        prefixes=_episode_prefixes(args.prefixes, args.touches), min_points=args.min_points,
        n_candidates=args.candidates, cells=args.cells, gain_mode=args.gain_mode, seed=args.seed,
        shard_size=args.shard_size,
    )
    manifest = generate_episode_dataset(cfg, args.out, workers=args.workers)
    split = manifest["splits"][args.split]
    print(json.dumps({args.split: {k: v for k, v in split.items() if k != "shards"}}))
    print(f"episode clouds in {args.out} (manifest.json); train with "
          f"--data.target_data_dir {args.out} --data.target_split {args.split}")
    return 0


def register(sub) -> None:
    from vtlearn.pipeline import register as register_quickstart

    register_quickstart(sub)
    p = sub.add_parser(
        "gen-episodes",
        help="tactile clouds from closed-loop episodes on a crossmodal dataset's instances "
        "(an xAVTNet target stream)",
    )
    p.add_argument("--source", required=True, help="a `gen-data crossmodal` dataset folder")
    p.add_argument("--out", required=True)
    p.add_argument("--split", default="train", help="source split whose instances are explored")
    p.add_argument("--strategies", default="active,random", help="closed-loop strategies, one episode each")
    p.add_argument("--touches", type=count(1), default=20, help="actions per episode")
    p.add_argument("--prefixes", default=None,
                   help="prefix lengths that each give one cloud (default 4,10,20, those <= --touches)")
    p.add_argument("--min-points", type=count(1), default=10, help="smaller prefixes give no cloud")
    p.add_argument("--candidates", type=count(1), default=100, help="candidate touches per active step")
    p.add_argument("--cells", type=count(1), default=40, help="occupancy grid cells per axis")
    p.add_argument("--gain-mode", default="probabilistic", help="probabilistic | raycast")
    p.add_argument("--seed", type=count(0), default=0)
    p.add_argument("--shard-size", type=count(1), default=16, help="instances per shard")
    p.add_argument("--workers", type=count(1), default=1)
    p.set_defaults(func=_cmd_gen_episodes)
