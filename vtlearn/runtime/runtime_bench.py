"""``vtlearn bench runtime``: the whole two-arm pipeline on cluttered pybullet scenes (thesis 5.4.2).

Each scene is an unseen target of one of the classifier's categories (transparent on even scenes when
the category has transparent instances, else opaque) among three clutter objects of other categories,
one of them behind another (:func:`~vtlearn.runtime.robot.clutter_scene`). The runtime declutters it
once, then every exploration strategy explores the same decluttered target with the same budget and
the models perceive it (:meth:`~vtlearn.runtime.robot.TwoArmRuntime.explore_and_perceive`).

A trial succeeds, as in the thesis (5.4.2), when decluttering finished and the pose error of the
target is ADI < 3 cm. The thesis reports an overall success rate of 88 % on the real two-robot
system, ADI < 3 cm for every object whose decluttering succeeded, and CD < 2 cm within 20 actions for
active reconstruction of transparent objects (random: about 3 cm).
"""

from __future__ import annotations

import itertools
import time
from collections.abc import Callable, Sequence
from pathlib import Path

import numpy as np

from vtlearn.active.closed_loop import TOUCH_STRATEGIES
from vtlearn.validation import as_int

__all__ = [
    "THESIS",
    "declutter_figure",
    "run_declutter_benchmark",
    "run_runtime_benchmark",
    "runtime_figure",
    "singulated_within",
]

THESIS = {
    "success_rate": 0.88,
    "adi_cm_bound": 3.0,
    "chamfer_mm_active_transparent_20": 20.0,
    "chamfer_mm_random_transparent_20": 30.0,
}


def _nanmean(v) -> float:
    v = np.asarray(v, dtype=np.float64)
    return float(np.mean(v[np.isfinite(v)])) if np.isfinite(v).any() else float("nan")


def _nanmedian(v) -> float:
    v = np.asarray(v, dtype=np.float64)
    return float(np.median(v[np.isfinite(v)])) if np.isfinite(v).any() else float("nan")


def _target(category: str, transparent: bool, clutter: Sequence[str], seed: int):
    from vtlearn.runtime.robot import clutter_scene

    try:
        return clutter_scene(category, clutter, transparent=transparent, seed=seed)
    except ValueError:  # the category has no instance of that kind (e.g. transparent cans)
        return clutter_scene(category, clutter, transparent=None, seed=seed)


def run_runtime_benchmark(
    actor,
    xavtnet,
    class_names: Sequence[str],
    *,
    scenes: int = 4,
    strategies: Sequence[str] = ("active", "random"),
    n_touches: int = 20,
    n_candidates: int = 40,
    cells: int = 32,
    max_declutter_actions: int = 8,
    seed: int = 0,
    progress: Callable[[int, int], None] | None = None,
) -> dict:
    """Run the scenes; returns ``{"runs": [...], "summary": {strategy: {...}}, "thesis": THESIS}``."""
    from vtlearn.runtime.robot import TwoArmRuntime
    from vtlearn.sim_data.shapes import CATEGORIES

    scenes = as_int(scenes, "scenes")
    strategies = list(strategies)
    bad = [s for s in strategies if s not in TOUCH_STRATEGIES]  # the tactile arm has no pinch
    if not strategies or bad:
        raise ValueError(f"strategies: expected some of {TOUCH_STRATEGIES}, got {strategies}")
    names = [str(c) for c in class_names]
    unknown = [c for c in names if c not in CATEGORIES]
    if unknown:
        raise ValueError(f"class_names: {unknown} are not procedural categories {CATEGORIES}")
    runs = []
    done = 0
    for i in range(int(scenes)):
        rng = np.random.default_rng([int(seed), i, 9])
        category = names[i % len(names)]
        others = [c for c in CATEGORIES if c not in names]
        clutter = list(rng.choice(others, size=3, replace=False))
        target_obj, clutter_objs = _target(category, i % 2 == 0, clutter, int(seed) + i)
        with TwoArmRuntime(actor, xavtnet, names, seed=int(seed) + i) as rt:
            tb = rt.add_object(target_obj, fixed=True)
            for c in clutter_objs:
                rt.add_object(c)
            rt.scene.step(120)
            first = None
            for strategy in strategies:
                t0 = time.perf_counter()
                kw = dict(strategy=strategy, n_touches=n_touches, n_candidates=n_candidates, cells=cells)
                if first is None:
                    rep = first = rt.run(tb, max_declutter_actions=max_declutter_actions, **kw)
                else:
                    rep = rt.explore_and_perceive(tb, first, **kw)
                s = rep.perception or {  # perception failed (too few contacts): a failed trial
                    "chamfer_mm": float("nan"),
                    "predicted_category": None,
                    "correct": False,
                    "adi_cm": float("nan"),
                }
                runs.append(
                    {
                        "scene": i,
                        "category": category,
                        "clutter": clutter,
                        "transparent": bool(target_obj.transparent),
                        "transparent_detected": bool(rep.transparent_detected),
                        "strategy": strategy,
                        "declutter_done": bool(rep.declutter_done),
                        "grasps": sum(a["kind"] == "grasp" for a in rep.declutter_actions),
                        "pushes": sum(a["kind"] == "push" for a in rep.declutter_actions),
                        "actions": rep.episode.n_steps,
                        "points": int(len(rep.episode.points)),
                        "chamfer_mm": s["chamfer_mm"],
                        "predicted": s["predicted_category"],
                        "correct": bool(s["correct"]),
                        "adi_cm": s["adi_cm"],
                        "success": bool(rep.declutter_done and s["adi_cm"] < THESIS["adi_cm_bound"]),
                        "perception_error": rep.perception_error,
                        "ik_queries": rep.ik_queries,
                        "seconds": round(time.perf_counter() - t0, 2) + rep.seconds.get("declutter", 0.0),
                    }
                )
                done += 1
                if progress is not None:
                    progress(done, int(scenes) * len(strategies))
    summary = {}
    for strategy in strategies:
        r = [x for x in runs if x["strategy"] == strategy]
        clear = [x for x in r if x["transparent"]]
        summary[strategy] = {
            "trials": len(r),
            "success_rate": float(np.mean([x["success"] for x in r])),
            "declutter_rate": float(np.mean([x["declutter_done"] for x in r])),
            "transparency_detection_accuracy": float(
                np.mean([x["transparent"] == x["transparent_detected"] for x in r])
            ),
            "recognition_accuracy": float(np.mean([x["correct"] for x in r])),
            "perception_failures": sum(x["perception_error"] is not None for x in r),
            # over the trials that could be perceived
            "chamfer_mm_mean": _nanmean([x["chamfer_mm"] for x in r]),
            "chamfer_mm_transparent_mean": _nanmean([x["chamfer_mm"] for x in clear]),
            "adi_cm_median": _nanmedian([x["adi_cm"] for x in r]),
            "adi_cm_mean": _nanmean([x["adi_cm"] for x in r]),
            "points_mean": float(np.mean([x["points"] for x in r])),
            "seconds_mean": float(np.mean([x["seconds"] for x in r])),
        }
    return {"runs": runs, "summary": summary, "thesis": THESIS}


def run_declutter_benchmark(
    *,
    scenes: int = 10,
    n_clutter: int = 4,
    policies: Sequence[str] = ("graph", "nearest", "random"),
    max_actions: int = 10,
    seed: int = 0,
    progress: Callable[[int, int], None] | None = None,
) -> dict:
    """The declutter graph (thesis 5.2.2) against simpler orders on identical cluttered scenes.

    Every scene is :func:`~vtlearn.runtime.robot.clutter_scene` with ``n_clutter`` objects of random
    categories around a random target (transparent on even scenes when the category allows), the last
    one behind another. Each policy of :meth:`~vtlearn.runtime.robot.TwoArmRuntime.declutter` starts from
    the same scene in a fresh simulation and acts until the target is singulated (no object within
    ``mu_d`` of it) or ``max_actions`` actions were spent.

    Returns ``{"runs": [...], "summary": {policy: {...}}, "settings": {...}}``; ``actions_mean`` is over the
    scenes every policy finished, so the policies are compared on the same scenes. :func:`declutter_figure`
    draws it.
    """
    from vtlearn.runtime.robot import DECLUTTER_POLICIES, TwoArmRuntime
    from vtlearn.sim_data.shapes import CATEGORIES, TRANSPARENT_PROB

    scenes = as_int(scenes, "scenes")
    if as_int(n_clutter, "n_clutter") > len(CATEGORIES) - 2:
        raise ValueError(f"n_clutter: need 1..{len(CATEGORIES) - 2}, got {n_clutter}")
    policies = list(policies)
    if not policies or any(p not in DECLUTTER_POLICIES for p in policies):
        raise ValueError(f"policies: expected some of {DECLUTTER_POLICIES}, got {policies}")
    runs = []
    for i in range(int(scenes)):
        rng = np.random.default_rng([int(seed), i, 17])
        target_cat = str(rng.choice(CATEGORIES))
        # clutter is opaque (clutter_scene), and wineglasses never are
        pool = [c for c in CATEGORIES if c != target_cat and TRANSPARENT_PROB.get(c, 0.0) < 1.0]
        cats = [target_cat, *rng.choice(pool, size=int(n_clutter), replace=False)]
        for policy in policies:
            target_obj, clutter = _target(cats[0], i % 2 == 0, cats[1:], int(seed) + i)
            t0 = time.perf_counter()
            with TwoArmRuntime(seed=int(seed) + i) as rt:
                tb = rt.add_object(target_obj, fixed=True)
                for c in clutter:
                    rt.add_object(c)
                rt.scene.step(120)
                actions, done = rt.declutter(tb, int(max_actions), policy=policy)
            runs.append(
                {
                    "scene": i,
                    "target": cats[0],
                    "clutter": cats[1:],
                    "policy": policy,
                    "done": bool(done),
                    "actions": len(actions),
                    "grasps": sum(a["kind"] == "grasp" for a in actions),
                    "pushes": sum(a["kind"] == "push" for a in actions),
                    "unreachable": sum(not a["reachable"] for a in actions),
                    "seconds": round(time.perf_counter() - t0, 2),
                }
            )
            if progress is not None:
                progress(len(runs), int(scenes) * len(policies))
    all_done = {i for i in range(int(scenes)) if all(r["done"] for r in runs if r["scene"] == i)}
    summary = {}
    for policy in policies:
        r = [x for x in runs if x["policy"] == policy]
        both = [x["actions"] for x in r if x["scene"] in all_done]
        summary[policy] = {
            "scenes": len(r),
            "success_rate": float(np.mean([x["done"] for x in r])),
            "actions_mean": float(np.mean(both)) if both else float("nan"),
            "scenes_compared": len(both),
            "grasps": sum(x["grasps"] for x in r),
            "pushes": sum(x["pushes"] for x in r),
            "unreachable": sum(x["unreachable"] for x in r),
            "seconds_mean": float(np.mean([x["seconds"] for x in r])),
        }
    settings = {
        "scenes": int(scenes),
        "n_clutter": int(n_clutter),
        "policies": policies,
        "max_actions": int(max_actions),
        "seed": int(seed),
    }
    return {"runs": runs, "summary": summary, "settings": settings}


def _check_declutter_result(result: dict) -> None:
    """A ValueError naming ``result`` when it lacks what the declutter figures read (a JSON of another bench,
    or one written before ``settings`` was recorded, 2026-12-04)."""
    missing = [k for k in ("runs", "summary", "settings") if k not in result]
    if not missing and "max_actions" not in result["settings"]:
        missing = ["settings.max_actions"]
    if missing:
        raise ValueError(f"result: no {', '.join(missing)}; not a `vtlearn bench declutter` result of this "
                         "version (rerun the bench to draw it)")


def singulated_within(result: dict, policy: str) -> np.ndarray:
    """The fraction of the scenes whose target ``policy`` singulated within ``k`` actions, for
    ``k = 0 .. max_actions`` (index ``k``); the last entry is the policy's success rate.

    Args:
        result: :func:`run_declutter_benchmark`'s result, or its JSON read back.
        policy: one of the result's policies.

    Shapes:
        returns ``(max_actions + 1,)``.
    """
    _check_declutter_result(result)
    runs = [x for x in result["runs"] if x["policy"] == policy]
    if not runs:
        raise ValueError(f"policy: no runs of {policy!r} in the result (policies {list(result['summary'])})")
    done = np.array([x["actions"] for x in runs if x["done"]], dtype=np.int64)
    k = np.arange(int(result["settings"]["max_actions"]) + 1)
    return (done[None, :] <= k[:, None]).sum(axis=1) / len(runs)


def declutter_figure(result: dict, path) -> Path:
    """Per policy, the targets singulated within a growing action budget, and the actions a scene took by
    kind (grasps, pushes, and those no arm reached), from :func:`run_declutter_benchmark`'s result.

    Args:
        result: :func:`run_declutter_benchmark`'s result, or its JSON read back.
        path: the figure's path (``.png``).

    Returns:
        The path written.
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from vtlearn.bench_utils import save_figure

    _check_declutter_result(result)
    policies, st = list(result["summary"]), result["settings"]
    if not result["runs"]:
        raise ValueError("result: no runs to draw")
    fig, (ax, bx) = plt.subplots(1, 2, figsize=(10, 3.8))
    for policy, style in zip(policies, itertools.cycle(("-o", "--s", ":^", "-.v"))):
        curve = singulated_within(result, policy)  # equal curves stay apart by line style and marker
        ax.step(np.arange(curve.size), curve, style, where="post", ms=4, label=f"{policy} ({curve[-1]:.0%})")
    ax.xaxis.set_major_locator(plt.MaxNLocator(integer=True))
    ax.set_xlabel("action budget")
    ax.set_ylabel("targets singulated (fraction of scenes)")
    ax.set_ylim(-0.02, 1.02)
    ax.set_title("singulated within k actions", fontsize=10)
    ax.legend(fontsize=8, loc="lower right")
    kinds = (("grasps", "grasps"), ("pushes", "pushes"), ("unreachable", "no arm reached"))
    width = 0.8 / len(kinds)
    for j, (key, label) in enumerate(kinds):
        per_scene = [np.mean([x[key] for x in result["runs"] if x["policy"] == p]) for p in policies]
        bx.bar(np.arange(len(policies)) + (j - (len(kinds) - 1) / 2) * width, per_scene, width, label=label)
    bx.set_xticks(range(len(policies)), policies)
    bx.set_ylabel("actions per scene, mean")
    bx.set_title("actions by kind", fontsize=10)
    bx.legend(fontsize=8)
    fig.suptitle(
        f"Decluttering (thesis 5.2.2), {st['scenes']} scenes with {st['n_clutter']} clutter objects, "
        f"at most {st['max_actions']} actions",
        fontsize=11,
    )
    fig.tight_layout(rect=(0, 0, 1, 0.93))
    return save_figure(fig, path)


def runtime_figure(result: dict, path) -> Path:
    """Box plots per strategy of the Chamfer distance (mm) and ADI (cm) of :func:`run_runtime_benchmark`'s
    scenes, with the thesis's bounds (CD < 20 mm on transparent objects, ADI < 3 cm; thesis 5.4.2).

    Args:
        result: :func:`run_runtime_benchmark`'s result, or its JSON read back (``null`` for a value a scene
            has not: a failed perception).
        path: the figure's path (``.png``).

    Returns:
        The path written.
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from vtlearn.bench_utils import save_figure

    strategies = list(result["summary"])
    if not result["runs"]:
        raise ValueError("result: no runs to draw")
    fig, axes = plt.subplots(1, 2, figsize=(9, 3.8))
    for ax, key, bound, unit in (
        (axes[0], "chamfer_mm", 20.0, "Chamfer distance (mm)"),
        (axes[1], "adi_cm", 3.0, "ADI (cm)"),
    ):
        data = [[x[key] for x in result["runs"] if x["strategy"] == n and x[key] is not None
                 and np.isfinite(x[key])] for n in strategies]
        ax.boxplot(data, showfliers=True)
        ax.set_xticks(range(1, len(strategies) + 1), strategies)
        ax.axhline(bound, color="r", ls="--", label="thesis bound")
        ax.set_ylabel(unit)
        ax.legend()
    fig.suptitle("Two-arm runtime on cluttered scenes (thesis 5.4.2 analogue)")
    fig.tight_layout()
    return save_figure(fig, path)
