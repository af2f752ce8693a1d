r"""``vtlearn bench pushing`` and ``vtlearn bench articulation``: the manipulation routines of thesis ch. 6
in simulation, against baselines run on identical trials.

**Goal-driven pushing** (thesis 6.2.4, eq. 6.12-6.17; experiments 6.3.3, Table 6.1). Each trial places a
procedural object of :mod:`vtlearn.sim_data.shapes` (standing box, can, jar or tape roll: shapes that slide
without rolling or toppling under the pad) free on the table at the origin with a random yaw, and draws a
goal 0.2-0.35 m away at a random bearing. Every method then pushes the same object from the same pose to
the same goal in a fresh pybullet scene with :class:`~vtlearn.runtime.pushing.GoalPusher`:

* ``thesis_pid``: the thesis's controller, the PID (0.05, 0.0, 0.03) on the bearing, pushing along
  ``+-V_y`` (``face="y"``);
* ``pid_best_face``: the same PID, pushing on the face of the OBB whose normal is closest to the goal
  direction (``face="best"``);
* ``no_correction`` (baseline): ``PushPID(0, 0, 0)``, i.e. always through the centre ``O`` along ``+-V_y``;
* ``no_correction_best_face``: no PID, best face (separates what the face choice and the PID each add).

A trial succeeds when the distance to goal (eq. 6.17) drops below the tolerance (2 cm, the
:class:`GoalPusher` default; the thesis leaves its tolerance ``lambda`` user-specified) within
``max_pushes`` pushes of 3 cm. The object cloud is the noiseless model cloud at the simulated pose.

**Articulation detection** (thesis 6.2.2, experiments 6.3.2). Per category of
:mod:`vtlearn.sim_data.articulated` (dishwasher, glasses: revolute; drawer, blade: prismatic) and a rigid
object (a dishwasher or drawer whose joint is fixed), ``trials`` random instances at a random base pose and
joint value are explored with :class:`~vtlearn.runtime.articulation.KinematicArticulationSim`, the part
poses observed with Gaussian noise. Two methods on the same instance:

* ``relative_motion``: :func:`~vtlearn.runtime.articulation.detect_articulation`, whose evidence is the
  classified change of the relative pose of the two parts (type, axis, pivot);
* ``heuristic`` (baseline): the same loop (same action chooser, same OBB action parameters, same belief and
  3-update stopping rule) with the thesis's push / hold-pull heuristics
  (:func:`~vtlearn.runtime.articulation.push_heuristic`,
  :func:`~vtlearn.runtime.articulation.hold_pull_heuristic`) as the only evidence: "only the pushed part
  moved" is revolute, "all moved together" is rigid-or-prismatic, a hold-pull that changes the relative
  pose is prismatic. It gives the joint type, not an axis.

Reported: joint-type accuracy, actions per detection, and for the relative-motion method the angle between
the estimated and true joint axes and the distance of the estimated pivot from the true hinge line;
:func:`articulation_figure` draws the accuracy and the per-trial errors.
"""

from __future__ import annotations

import argparse
import dataclasses
import time
from pathlib import Path
from typing import Any

import numpy as np

from vtlearn.bench_utils import csv_list
from vtlearn.cli_args import count, with_flag
from vtlearn.validation import as_int, as_real

__all__ = [
    "PUSH_METHODS",
    "PUSH_OBJECTS",
    "ARTICULATION_CATEGORIES",
    "THESIS_PUSHING",
    "THESIS_ARTICULATION",
    "run_pushing_benchmark",
    "pushing_figure",
    "heuristic_articulation",
    "run_articulation_benchmark",
    "articulation_figure",
    "register_bench",
]

# method -> (PID gains (kp, ki, kd), push face); the thesis's gains are those of pushing.PushPID()
PUSH_METHODS: dict[str, tuple[tuple[float, float, float], str]] = {
    "thesis_pid": ((0.05, 0.0, 0.03), "y"),
    "pid_best_face": ((0.05, 0.0, 0.03), "best"),
    "no_correction": ((0.0, 0.0, 0.0), "y"),
    "no_correction_best_face": ((0.0, 0.0, 0.0), "best"),
}
PUSH_BASELINE = "no_correction"
# Standing shapes that slide under a pad at mid height. Lying cans and bottles roll away from the pad and
# tall bottles topple, which the pad-and-OBB controller of the thesis does not address.
PUSH_OBJECTS = ("box", "can", "jar", "tape_roll")
GOAL_RANGE = (0.2, 0.35)
TOPPLE_DEG = 30.0

ARTICULATION_CATEGORIES = ("dishwasher", "glasses", "drawer", "blade", "rigid")
JOINT_TYPE = {
    "dishwasher": "revolute",
    "glasses": "revolute",
    "drawer": "prismatic",
    "blade": "prismatic",
    "rigid": "rigid",
}
TRACKERS = ("noisy-truth", "artreg")
ART_METHODS = ("relative_motion", "heuristic")
ART_BASELINE = "heuristic"

THESIS_PUSHING = {
    "source": "thesis 6.3.3, Table 6.1: real robot, ArtReg-tracked 3-D printed objects, 5 trials per object",
    "metric": "Euclidean xy error at the goal state, eq. 6.18 (cm, mean +- std)",
    "single_object_cm": [1.908, 0.86],
    "articulated_revolute_cm": [2.302, 0.71],
    "articulated_prismatic_cm": [1.031, 0.96],
    "single_object_varied_com_cm": [3.604, 0.43],
    "single_object_challenging_background_cm": [3.101, 0.24],
    "single_object_low_light_cm": [2.974, 0.92],
    "quote": (
        "The average error at goal-state for all objects (single/ articulated) was < 3 cm. ... resulting "
        "in total 55 repeated trials for this experiment."
    ),
    "not_reported": "success rate, number of pushes, time per push; the tolerance lambda is 'user-specified'",
}
THESIS_ARTICULATION = {
    "source": "thesis 6.3.2, Fig. 6.7-6.9: real robots, 3-D printed objects, ArtReg tracking",
    "quantitative": False,
    "quote": (
        "Five repeated trials were performed for each case: revolute joint, top-revolute joint and "
        "prismatic joint with the corresponding object with rigid joints for comparison."
    ),
    "not_reported": "no accuracy, action count or axis error; the detections are shown qualitatively",
    "actions": {"push_m": 0.10, "pull_m": 0.05, "hold_force_N": 8.0},
}


def _summary_stats(values) -> tuple[float, float]:
    """(median, max) of a possibly empty list; NaN when empty."""
    a = np.asarray(values, dtype=np.float64)
    return (float(np.median(a)), float(a.max())) if a.size else (float("nan"), float("nan"))


def _ratio(a: float, b: float) -> float:
    return float(a / b) if np.isfinite(a) and np.isfinite(b) and b != 0 else float("nan")


# ------------------------------------------------------------------------------------------- pushing
def _pushing_trial(seed: int, index: int, objects: tuple[str, ...]) -> dict:
    """The object, its yaw and the goal of trial ``index`` (identical for every method)."""
    rng = np.random.default_rng([seed, index])
    bearing = float(rng.uniform(-np.pi, np.pi))
    r = float(rng.uniform(*GOAL_RANGE))
    return {
        "object": objects[index % len(objects)],
        "shape_seed": int(rng.integers(2**31)),
        "yaw": float(rng.uniform(-np.pi, np.pi)),
        "goal": [r * np.cos(bearing), r * np.sin(bearing)],
        "goal_range_m": r,
    }


def _push_run(trial: dict, method: str, tolerance: float, max_pushes: int) -> dict:
    from vtlearn.runtime.pushing import GoalPusher, PushPID
    from vtlearn.sim_data.scene import Scene
    from vtlearn.sim_data.shapes import generate_shape

    gains, face = PUSH_METHODS[method]
    mesh, rec = generate_shape(trial["object"], trial["shape_seed"])
    T_world_object = np.eye(4)
    c, s = np.cos(trial["yaw"]), np.sin(trial["yaw"])
    T_world_object[:2, :2] = [[c, -s], [s, c]]
    T_world_object[2, 3] = rec.size_m[2] / 2 + 1e-3  # the canonical mesh is centred on its bounding box
    with Scene() as scene:
        body = scene.add_mesh(mesh, scale=rec.scale_m, T_world_object=T_world_object, fixed=False)
        scene.step(60)
        z0 = scene.T_world_object(body)[:3, 2]
        pusher = GoalPusher(
            scene, body, pid=PushPID(*gains), tolerance=tolerance, max_pushes=max_pushes, face=face
        )
        t0 = time.perf_counter()
        res = pusher.run(trial["goal"])
        seconds = time.perf_counter() - t0
        tilt = float(np.degrees(np.arccos(np.clip(z0 @ scene.T_world_object(body)[:3, 2], -1.0, 1.0))))
        pusher.close()
    return {
        "trial": trial["index"],
        "object": trial["object"],
        "size_m": rec.size_m,
        "method": method,
        "success": res.success,
        "final_mm": 1e3 * res.final_distance,
        "start_mm": 1e3 * (res.records[0].d if res.records else res.final_distance),
        "pushes": res.n_pushes,
        "contact_lost": int(sum(r.contact_lost for r in res.records)),
        "no_contact": int(sum(not r.contact for r in res.records)),
        "toppled": tilt > TOPPLE_DEG,
        "seconds": seconds,
        "seconds_per_push": seconds / max(res.n_pushes, 1),
        "goal": res.target,
        "path": res.path,
    }


def run_pushing_benchmark(
    trials: int = 10,
    seed: int = 0,
    methods=tuple(PUSH_METHODS),
    objects=PUSH_OBJECTS,
    tolerance: float = 0.02,
    max_pushes: int = 30,
    progress: bool = True,
) -> dict:
    """Goal-driven pushing of ``trials`` objects by every method on identical trials (module docstring).

    Args:
        trials: number of trials (object, yaw, goal); trial ``i`` uses ``objects[i % len(objects)]``.
        seed: seed of the trials.
        methods: keys of :data:`PUSH_METHODS`.
        objects: :mod:`vtlearn.sim_data.shapes` categories, placed standing.
        tolerance: success when the final distance to goal is below it (m).
        max_pushes: pushes allowed per trial.
        progress: show a tqdm bar over the trials.

    Returns:
        ``{"runs": [...], "summary": {method: {...}}, "settings": {...}, "thesis": {...}}``.
    """
    from tqdm.auto import tqdm

    from vtlearn.sim_data.shapes import CATEGORIES

    trials = as_int(trials, "trials")
    max_pushes = as_int(max_pushes, "max_pushes")
    tolerance = as_real(tolerance, "tolerance", low=0.0, open_low=True)
    methods, objects = list(methods), tuple(objects)
    if not methods or any(m not in PUSH_METHODS for m in methods):
        raise ValueError(f"methods: need some of {list(PUSH_METHODS)}, got {methods}")
    if not objects or any(o not in CATEGORIES for o in objects):
        raise ValueError(f"objects: need some of {CATEGORIES}, got {list(objects)}")
    runs = []
    for i in tqdm(range(trials), desc="bench pushing", disable=not progress):
        trial = {"index": i, **_pushing_trial(seed, i, objects)}
        runs += [_push_run(trial, m, tolerance, max_pushes) for m in methods]
    summary = {}
    for m in methods:
        r = [x for x in runs if x["method"] == m]
        final = np.array([x["final_mm"] for x in r])
        ok = [x for x in r if x["success"]]
        summary[m] = {
            "pid_gains": PUSH_METHODS[m][0],
            "face": PUSH_METHODS[m][1],
            "success_rate": float(np.mean([x["success"] for x in r])),
            "final_mm_median": float(np.median(final)),
            "final_mm_mean": float(final.mean()),
            "final_mm_std": float(final.std()),
            "pushes_median": float(np.median([x["pushes"] for x in r])),
            "pushes_median_success": float(np.median([x["pushes"] for x in ok])) if ok else float("nan"),
            "seconds_per_push": float(sum(x["seconds"] for x in r) / max(sum(x["pushes"] for x in r), 1)),
            "contact_lost_per_trial": float(np.mean([x["contact_lost"] for x in r])),
            "toppled": int(sum(x["toppled"] for x in r)),
            "success_rate_per_object": {
                o: float(np.mean([x["success"] for x in r if x["object"] == o]))
                for o in dict.fromkeys(x["object"] for x in r)
            },
        }
    base = summary.get(PUSH_BASELINE)
    for s in summary.values():
        s["success_rate_ratio"] = _ratio(s["success_rate"], base["success_rate"]) if base else float("nan")
        s["final_mm_median_ratio"] = (
            _ratio(s["final_mm_median"], base["final_mm_median"]) if base else float("nan")
        )
    settings = {
        "trials": trials,
        "seed": seed,
        "methods": methods,
        "objects": list(objects),
        "tolerance_m": tolerance,
        "max_pushes": max_pushes,
        "goal_range_m": list(GOAL_RANGE),
        "baseline": PUSH_BASELINE,
    }
    return {"runs": runs, "summary": summary, "settings": settings, "thesis": THESIS_PUSHING}


def pushing_figure(result: dict, path, per_method: int = 4) -> Path:
    """Top-down paths of the first ``per_method`` trials of every method and a box plot of final distances."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from vtlearn.bench_utils import save_figure

    methods = list(result["summary"])
    tol = result["settings"]["tolerance_m"]
    fig, axes = plt.subplots(1, len(methods) + 1, figsize=(3.6 * (len(methods) + 1), 3.8))
    colours = plt.rcParams["axes.prop_cycle"].by_key()["color"]
    for ax, m in zip(axes[:-1], methods, strict=True):
        for k, run in enumerate([x for x in result["runs"] if x["method"] == m][:per_method]):
            c = colours[k % len(colours)]
            path_xy, goal = np.asarray(run["path"]), np.asarray(run["goal"])
            ax.plot(path_xy[:, 0], path_xy[:, 1], ".-", ms=3, lw=1, color=c, label=run["object"])
            ax.plot(*goal, "*", ms=10, color=c)
            ax.add_patch(plt.Circle(goal, tol, fill=False, ls="--", color=c, lw=0.8))
        ax.plot(0, 0, "ko", ms=4)
        ax.set_aspect("equal")
        ax.set_title(f"{m}\nsuccess {result['summary'][m]['success_rate']:.0%}", fontsize=9)
        ax.set_xlabel("x (m)")
        ax.legend(fontsize=6, loc="best")
    axes[0].set_ylabel("y (m)")
    ax = axes[-1]
    ax.boxplot([[x["final_mm"] for x in result["runs"] if x["method"] == m] for m in methods])
    ax.set_xticks(range(1, len(methods) + 1), methods, rotation=30, ha="right", fontsize=7)
    ax.axhline(1e3 * tol, color="g", ls="--", lw=1, label="tolerance")
    ax.axhline(
        10 * THESIS_PUSHING["single_object_cm"][0], color="r", ls=":", lw=1, label="thesis single object"
    )
    ax.set_yscale("log")
    ax.set_ylabel("final distance to goal (mm)")
    ax.legend(fontsize=7)
    fig.suptitle(
        "Goal-driven pushing (thesis 6.2.4): object centre paths from the start (black) to the goals"
    )
    fig.tight_layout(rect=(0, 0, 1, 0.92))
    return save_figure(fig, path)


# ------------------------------------------------------------------------------------------- articulation
def heuristic_articulation(observe, execute, parts=(0, 1), max_actions: int = 12, patience: int = 3) -> dict:
    """Articulation detection from the thesis's push / hold-pull heuristics alone (the baseline).

    The loop of :func:`~vtlearn.runtime.articulation.detect_articulation` (same action chooser, same OBB
    action parameters, same :class:`~vtlearn.runtime.articulation.ArticulationBelief`) with the evidence
    of :func:`push_heuristic` / :func:`hold_pull_heuristic`: revolute when only the pushed part moved,
    together when every part moved with the relative poses kept, none when nothing moved or the heuristic
    is inconclusive; a hold-pull reads prismatic or rigid.

    Returns:
        ``{"joint_type", "explored", "n_actions", "actions": [kind, ...], "heuristics": [str, ...]}``.
    """
    from vtlearn.runtime.articulation import (
        ArticulationBelief,
        _hold_part,
        choose_action,
        hold_pull_action,
        hold_pull_heuristic,
        push_action,
        push_heuristic,
    )

    if not (callable(observe) and callable(execute)):
        raise ValueError("observe, execute: need two callables")
    max_actions = as_int(max_actions, "max_actions")
    belief = ArticulationBelief(parts, patience)
    a, b = belief.parts
    clouds, T0 = observe()
    actions, heuristics = [], []
    while len(actions) < max_actions and not belief.explored:
        kind, part = choose_action(belief)
        if kind == "push":
            action = push_action(clouds, part, other=b if part == a else a)
        else:
            action = hold_pull_action(clouds, *_hold_part(clouds, a, b))
        execute(action)
        clouds, T1 = observe()
        if kind == "push":
            h = push_heuristic(T0, T1, part)
            evidence = {"revolute": "revolute", "rigid_or_prismatic": "together"}.get(h, "none")
        else:
            h = evidence = hold_pull_heuristic(T0, T1, action.hold.part, action.pull.part)
        belief.update(evidence, pushed=part if kind == "push" else None)
        actions.append(kind)
        heuristics.append(h)
        T0 = T1
    return {
        "joint_type": belief.state,
        "explored": belief.explored,
        "n_actions": len(actions),
        "actions": actions,
        "heuristics": heuristics,
    }


def _articulation_spec(category: str, seed: int):
    from vtlearn.sim_data.articulated import ArticulatedSpec, make_articulated

    if category != "rigid":
        return make_articulated(category, seed)
    spec = make_articulated("dishwasher" if seed % 2 == 0 else "drawer", seed)
    return ArticulatedSpec("rigid", [spec.links[0], dataclasses.replace(spec.links[1], joint_type="fixed")])


def _axis_errors(axis_a, pivot_a, link) -> tuple[float, float]:
    """(axis angle error in deg, sign-free; pivot distance to the true joint line in mm, revolute only)."""
    u = np.asarray(link.axis, dtype=np.float64)
    u = u / np.linalg.norm(u)
    if axis_a is None:
        return float("nan"), float("nan")
    ang = float(np.degrees(np.arccos(min(1.0, abs(float(np.asarray(axis_a) @ u))))))
    if link.joint_type != "revolute" or pivot_a is None:
        return ang, float("nan")
    v = np.asarray(pivot_a) - np.asarray(link.joint_xyz, dtype=np.float64)
    return ang, float(1e3 * np.linalg.norm(v - (v @ u) * u))


def run_articulation_benchmark(
    trials: int = 5,
    noise_mm: float = 1.0,
    noise_deg: float = 0.3,
    categories=ARTICULATION_CATEGORIES,
    seed: int = 0,
    progress: bool = True,
    tracker: str = "noisy-truth",
) -> dict:
    """Articulation detection per category, relative motion vs the thesis heuristics (module docstring).

    Args:
        trials: instances per category.
        noise_mm, noise_deg: std of the Gaussian translation (mm) and rotation (deg) noise on every
            observed part pose.
        categories: some of :data:`ARTICULATION_CATEGORIES`.
        seed: seed of the instances, poses, joint values and noise.
        progress: show a tqdm bar over the trials.
        tracker: ``"noisy-truth"``: the observed part poses are the true ones plus the noise above;
            ``"artreg"``: the thesis's loop, every action replayed as camera frames and the poses tracked
            by ArtReg (:class:`~vtlearn.runtime.articulation.TrackedArticulationSim`; the noise arguments
            are then unused, the camera has its own).

    Returns:
        ``{"runs": [...], "summary": {category: {method: {...}}}, "overall": {method: {...}},
        "settings": {...}, "thesis": {...}}``.
    """
    from tqdm.auto import tqdm

    from vtlearn.runtime.articulation import (
        KinematicArticulationSim,
        TrackedArticulationSim,
        detect_articulation,
    )
    from vtlearn.sim_data.articulated import ArticulatedObject
    from vtlearn.sim_data.scene import Scene

    trials = as_int(trials, "trials")
    noise_mm = as_real(noise_mm, "noise_mm", low=0.0)
    noise_deg = as_real(noise_deg, "noise_deg", low=0.0)
    categories = list(categories)
    if not categories or any(c not in ARTICULATION_CATEGORIES for c in categories):
        raise ValueError(f"categories: need some of {ARTICULATION_CATEGORIES}, got {categories}")
    if tracker not in TRACKERS:
        raise ValueError(f"tracker: expected one of {TRACKERS}, got {tracker!r}")
    noise = (1e-3 * noise_mm, float(np.deg2rad(noise_deg)))
    runs = []
    bar = tqdm(total=len(categories) * trials, desc="bench articulation", disable=not progress)
    for ci, cat in enumerate(ARTICULATION_CATEGORIES):
        if cat not in categories:
            continue
        for k in range(trials):
            rng = np.random.default_rng([seed, ci, k])
            spec = _articulation_spec(cat, int(rng.integers(2**31)))
            yaw = rng.uniform(-np.pi, np.pi)
            T_base = np.eye(4)
            T_base[:2, :2] = [[np.cos(yaw), -np.sin(yaw)], [np.sin(yaw), np.cos(yaw)]]
            T_base[:2, 3] = rng.uniform(-0.1, 0.1, 2)
            q = rng.uniform(0.2, 0.8, spec.n_joints)
            noise_seed = int(rng.integers(2**31))
            link = spec.links[1]
            with Scene() as scene:
                obj = ArticulatedObject(scene, spec, n_model_points=0.01)
                for method in ART_METHODS:
                    sim = KinematicArticulationSim(obj, T_base, q, pose_noise=noise, seed=noise_seed)
                    t0 = time.perf_counter()
                    tracked = None
                    if tracker == "artreg":
                        tracked = sim = TrackedArticulationSim(sim, seed=noise_seed)
                    if method == "relative_motion":
                        res = detect_articulation(sim.observe, sim.execute)
                        out = {
                            "joint_type": res.joint_type,
                            "explored": res.explored,
                            "n_actions": res.n_actions,
                            "actions": [s.action.kind for s in res.steps],
                        }
                        ang, piv = _axis_errors(res.axis_a, res.pivot_a, link)
                    else:
                        out = heuristic_articulation(sim.observe, sim.execute)
                        ang = piv = float("nan")
                    seconds = time.perf_counter() - t0
                    correct = out["joint_type"] == JOINT_TYPE[cat]
                    runs.append(
                        {
                            "category": cat,
                            "trial": k,
                            "method": method,
                            "truth": JOINT_TYPE[cat],
                            "q": q,
                            **out,
                            "correct": correct,
                            "axis_deg": ang if correct else float("nan"),
                            "pivot_mm": piv if correct else float("nan"),
                            "seconds": seconds,
                            "tracking_mm_median": float("nan")
                            if tracked is None
                            else float(np.median(tracked.errors_mm)),
                        }
                    )
            bar.update()
    bar.close()

    def stats(r: list[dict]) -> dict:
        ang = [x["axis_deg"] for x in r if np.isfinite(x["axis_deg"])]
        piv = [x["pivot_mm"] for x in r if np.isfinite(x["pivot_mm"])]
        predicted: dict[str, int] = {}
        for x in r:
            predicted[x["joint_type"]] = predicted.get(x["joint_type"], 0) + 1
        return {
            "accuracy": float(np.mean([x["correct"] for x in r])),
            "actions_mean": float(np.mean([x["n_actions"] for x in r])),
            "explored_rate": float(np.mean([x["explored"] for x in r])),
            "axis_deg_median": _summary_stats(ang)[0],
            "axis_deg_max": _summary_stats(ang)[1],
            "pivot_mm_median": _summary_stats(piv)[0],
            "pivot_mm_max": _summary_stats(piv)[1],
            "seconds_mean": float(np.mean([x["seconds"] for x in r])),
            "tracking_mm_median": float(np.median([x["tracking_mm_median"] for x in r])),
            "predicted": predicted,
        }

    summary = {
        c: {m: stats([x for x in runs if x["category"] == c and x["method"] == m]) for m in ART_METHODS}
        for c in categories
    }
    overall = {m: stats([x for x in runs if x["method"] == m]) for m in ART_METHODS}
    for block in [*summary.values(), overall]:
        for s in block.values():
            s["accuracy_ratio"] = _ratio(s["accuracy"], block[ART_BASELINE]["accuracy"])
    settings = {
        "trials": trials,
        "noise_mm": noise_mm,
        "noise_deg": noise_deg,
        "tracker": tracker,
        "categories": categories,
        "seed": seed,
        "baseline": ART_BASELINE,
        "joint_value_range": [0.2, 0.8],
    }
    return {
        "runs": runs,
        "summary": summary,
        "overall": overall,
        "settings": settings,
        "thesis": THESIS_ARTICULATION,
    }


def _finite(values) -> np.ndarray:
    """The finite numbers of ``values`` as float64: NaN and None (a JSON null) dropped."""
    a = np.array([np.nan if v is None else v for v in values], dtype=np.float64)
    return a[np.isfinite(a)]


def articulation_figure(result: dict, path) -> Path:
    """Joint-type accuracy per category and method, and the estimated joints' errors: the axis angle and the
    pivot's distance from the true hinge line, one point per correct detection, the bar at their median.

    Args:
        result: :func:`run_articulation_benchmark`'s result, or its JSON read back (nulls for NaN).
        path: the figure's path (``.png``).
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from vtlearn.bench_utils import save_figure

    runs, summary, overall = result["runs"], result["summary"], result["overall"]
    if not runs:
        raise ValueError("result: no runs to draw")
    cats, methods = list(summary), list(overall)
    colours = dict(zip(methods, plt.rcParams["axes.prop_cycle"].by_key()["color"], strict=False))
    width = 0.8 / len(methods)
    fig, axes = plt.subplots(1, 3, figsize=(13, 4))
    ax = axes[0]
    groups = [*cats, "all"]
    for j, m in enumerate(methods):
        acc = [summary[c][m]["accuracy"] for c in cats] + [overall[m]["accuracy"]]
        x = np.arange(len(groups)) + (j - (len(methods) - 1) / 2) * width
        ax.bar(x, acc, width, label=m, color=colours[m])
    ax.set_xticks(range(len(groups)), groups, rotation=30, ha="right")
    ax.set_ylim(0, 1.25)  # room for the legend above the bars
    ax.set_yticks(np.linspace(0, 1, 6))
    ax.set_ylabel("joint-type accuracy")
    ax.set_title("detection accuracy", fontsize=10)
    ax.legend(fontsize=7, loc="upper center", ncol=len(methods))
    for ax, key, label, joints in (
        (axes[1], "axis_deg", "axis angle error (deg)", ("revolute", "prismatic")),
        (axes[2], "pivot_mm", "pivot to true hinge line (mm)", ("revolute",)),
    ):
        shown = [c for c in cats if JOINT_TYPE.get(c) in joints]
        values = {
            (c, m): _finite([x[key] for x in runs if x["category"] == c and x["method"] == m])
            for c in shown
            for m in methods
        }
        # the methods that estimate this (the heuristic gives no axis)
        estimating = [m for m in methods if any(values[c, m].size for c in shown)]
        for j, m in enumerate(estimating):
            legend = f"{m} (bar: median)"  # once per method
            for i, c in enumerate(shown):
                v = values[c, m]
                if not v.size:
                    continue
                x0 = i + (j - (len(estimating) - 1) / 2) * width
                ax.bar(x0, np.median(v), width, color=colours[m], alpha=0.4, label=legend)
                legend = None
                ax.plot(x0 + np.linspace(-width / 4, width / 4, v.size), v, ".", color=colours[m], ms=5)
        if estimating:
            ax.set_xticks(range(len(shown)), shown, rotation=30, ha="right")
            ax.legend(fontsize=7)
        else:
            ax.set_xticks([])
            # no joint of this kind asked for, or no correct detection of one to measure
            why = "no correct detection" if shown else "no such joint in these categories"
            ax.text(0.5, 0.5, why, transform=ax.transAxes, ha="center", va="center")
        ax.set_ylabel(label)
        ax.set_title(f"{label.split(' (')[0]}, per correct detection", fontsize=10)
    st = result["settings"]
    poses = (
        "poses tracked by ArtReg"
        if st["tracker"] == "artreg"
        else f"pose noise {st['noise_mm']} mm / {st['noise_deg']} deg"
    )
    fig.suptitle(
        f"Articulation detection (thesis 6.2.2), {st['trials']} instance{'s' * (st['trials'] != 1)} per "
        f"category, {poses}", fontsize=11
    )
    fig.tight_layout(rect=(0, 0, 1, 0.93))
    return save_figure(fig, path)


# ------------------------------------------------------------------------------------------- CLI
def _int_at_least_1(text: str) -> int:
    try:
        v = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"need an integer >= 1, got {text!r}") from None
    if v < 1:
        raise argparse.ArgumentTypeError(f"need an integer >= 1, got {v}")
    return v


def _non_negative(text: str) -> float:
    try:
        v = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"need a number >= 0, got {text!r}") from None
    if not (np.isfinite(v) and v >= 0):
        raise argparse.ArgumentTypeError(f"need a finite number >= 0, got {v}")
    return v


def _positive(text: str) -> float:
    v = _non_negative(text)
    if v == 0:
        raise argparse.ArgumentTypeError("need a number > 0, got 0")
    return v


def _not_available(row: dict) -> dict:
    """``row`` with its non-finite numbers as None, which a table prints as "-": a median over no successes,
    an axis error the heuristic does not estimate, a ratio to a baseline of 0."""
    return {k: None if isinstance(v, float) and not np.isfinite(v) else v for k, v in row.items()}


def _cmd_bench_pushing(args: argparse.Namespace) -> int:
    from vtlearn.bench_utils import machine_info, print_table, write_json_and_figure

    try:
        result = run_pushing_benchmark(
            trials=args.trials,
            seed=args.seed,
            methods=csv_list(args.methods),
            objects=csv_list(args.objects),
            tolerance=args.tolerance,
            max_pushes=args.max_pushes,
        )
    except ValueError as exc:  # an unknown method or object: name the flag the user typed
        raise (with_flag(exc, {"methods": "--methods", "objects": "--objects"}) or exc) from None
    rows = []
    for m, s in result["summary"].items():
        rows.append(_not_available(
            {
                "method": m,
                "pid": "0" if not any(s["pid_gains"]) else "0.05/0/0.03",
                "face": s["face"],
                "success": s["success_rate"],
                "final_mm_median": s["final_mm_median"],
                "final_mm_mean": s["final_mm_mean"],
                "pushes_median": s["pushes_median"],
                "pushes_median_ok": s["pushes_median_success"],
                "s_per_push": s["seconds_per_push"],
                "success_x_base": s["success_rate_ratio"],
                "median_mm_x_base": s["final_mm_median_ratio"],
            }
        ))
    th = THESIS_PUSHING
    rows.append(
        {
            "method": "thesis, single object",
            "pid": "0.05/0/0.03",
            "face": "y",
            "final_mm_mean": f"{10 * th['single_object_cm'][0]:.1f} +- {10 * th['single_object_cm'][1]:.1f}",
            "success": "-",
            "pushes_median": "-",
        }
    )
    columns = [
        "method",
        "pid",
        "face",
        "success",
        "final_mm_median",
        "final_mm_mean",
        "pushes_median",
        "pushes_median_ok",
        "s_per_push",
        "success_x_base",
        "median_mm_x_base",
    ]
    print_table(
        rows,
        columns,
        f"Goal-driven pushing, {args.trials} trials ({', '.join(csv_list(args.objects))}), "
        f"goals {GOAL_RANGE[0]}-{GOAL_RANGE[1]} m, tolerance {1e3 * args.tolerance:.0f} mm, "
        f"<= {args.max_pushes} pushes of 3 cm (thesis 6.2.4)",
    )
    print(
        "x_base: ratio to the no_correction baseline. Thesis (Table 6.1, real robot): single object "
        "1.908 +- 0.86 cm, articulated revolute 2.302 +- 0.71 cm, prismatic 1.031 +- 0.96 cm at the goal; "
        "success rates and push counts not reported."
    )
    objs = list(dict.fromkeys(x["object"] for x in result["runs"]))
    print_table(
        [{"method": m, **s["success_rate_per_object"]} for m, s in result["summary"].items()],
        ["method", *objs],
        "Success rate per object",
    )
    figure = Path(args.figure) if args.figure else Path(args.json).with_suffix(".png")
    result["machine"] = machine_info()
    write_json_and_figure(args.json, result, figure, pushing_figure)
    print(f"wrote {args.json} and {figure}")
    return 0


def _cmd_bench_articulation(args: argparse.Namespace) -> int:
    from vtlearn.bench_utils import machine_info, print_table, write_json_and_figure

    figure = Path(args.figure) if args.figure else Path(args.json).with_suffix(".png")
    try:
        result = run_articulation_benchmark(
            trials=args.trials,
            noise_mm=args.noise_mm,
            noise_deg=args.noise_deg,
            categories=csv_list(args.categories),
            seed=args.seed,
            tracker=args.tracker,
        )
    except ValueError as exc:  # an unknown category: name the flag the user typed
        raise (with_flag(exc, {"categories": "--categories"}) or exc) from None
    rows = []
    for cat, block in [*result["summary"].items(), ("all", result["overall"])]:
        for m, s in block.items():
            rows.append(_not_available(
                {
                    "category": cat,
                    "truth": JOINT_TYPE.get(cat, "-"),
                    "method": m,
                    "accuracy": s["accuracy"],
                    "acc_x_heur": s["accuracy_ratio"],
                    "actions_mean": s["actions_mean"],
                    "explored": s["explored_rate"],
                    "axis_deg_median": s["axis_deg_median"],
                    "axis_deg_max": s["axis_deg_max"],
                    "pivot_mm_median": s["pivot_mm_median"],
                    "pivot_mm_max": s["pivot_mm_max"],
                    "tracking_mm": s["tracking_mm_median"],
                    "predicted": ", ".join(f"{k} {v}" for k, v in sorted(s["predicted"].items())),
                }
            ))
    print_table(
        rows,
        [
            "category",
            "truth",
            "method",
            "accuracy",
            "acc_x_heur",
            "actions_mean",
            "explored",
            "axis_deg_median",
            "axis_deg_max",
            "pivot_mm_median",
            "pivot_mm_max",
            "tracking_mm",
            "predicted",
        ],
        f"Articulation detection, {args.trials} instances per category, "
        + (
            "poses tracked by ArtReg from simulated depth"
            if args.tracker == "artreg"
            else f"pose noise {args.noise_mm} mm / {args.noise_deg} deg"
        )
        + " (thesis 6.2.2)",
    )
    print(
        "acc_x_heur: accuracy ratio to the heuristic baseline; axis and pivot errors over correct detections "
        "(pivot: distance to the true hinge line). Thesis 6.3.2: qualitative only (5 real trials per joint "
        "type, no accuracy or axis error reported)."
    )
    result["machine"] = machine_info()
    write_json_and_figure(args.json, result, figure, articulation_figure)
    print(f"wrote {args.json} and {figure}")
    return 0


def register_bench(bench_subparsers: Any) -> None:
    p = bench_subparsers.add_parser(
        "pushing", help="goal-driven visuo-tactile pushing vs no correction (6.2.4)"
    )
    p.add_argument("--trials", type=_int_at_least_1, default=10, help="trials (object, goal), default 10")
    p.add_argument("--seed", type=count(0), default=0)
    p.add_argument("--methods", default=",".join(PUSH_METHODS), help="comma-separated subset of methods")
    p.add_argument(
        "--objects",
        default=",".join(PUSH_OBJECTS),
        help="comma-separated shape categories, placed standing; trial i uses the (i mod n)-th",
    )
    p.add_argument("--tolerance", type=_positive, default=0.02, help="success distance to goal (m)")
    p.add_argument("--max-pushes", type=_int_at_least_1, default=30, help="pushes allowed per trial")
    p.add_argument("--json", default="runs/bench/pushing.json", help="output JSON")
    p.add_argument("--figure", default=None, help="output figure (default: the JSON path with .png)")
    p.set_defaults(func=_cmd_bench_pushing)

    p = bench_subparsers.add_parser(
        "articulation", help="articulation detection, relative motion vs thesis heuristics (6.2.2)"
    )
    p.add_argument("--trials", type=_int_at_least_1, default=5, help="instances per category, default 5")
    p.add_argument("--noise-mm", type=_non_negative, default=1.0, help="pose noise std, translation (mm)")
    p.add_argument("--noise-deg", type=_non_negative, default=0.3, help="pose noise std, rotation (deg)")
    p.add_argument("--categories", default=",".join(ARTICULATION_CATEGORIES), help="comma-separated subset")
    p.add_argument(
        "--tracker",
        choices=TRACKERS,
        default="noisy-truth",
        help="part poses: the truth plus --noise-mm/--noise-deg, or tracked by ArtReg from a simulated "
        "depth camera (the thesis's loop); default %(default)s",
    )
    p.add_argument("--seed", type=count(0), default=0)
    p.add_argument("--json", default="runs/bench/articulation.json", help="output JSON")
    p.add_argument("--figure", default=None, help="output figure (default: the JSON path with .png)")
    p.set_defaults(func=_cmd_bench_articulation)
