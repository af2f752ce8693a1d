"""``vtlearn runtime``: the two-arm robot runtime on a cluttered pybullet scene (thesis Fig. 5.1-5.2).

Loads ACTOR and xAVTNet checkpoints (``weights_only=True``), declutters an unseen target with the
declutter graph, explores it with IK-checked next-best touches (and views, when it is opaque), and
reconstructs, recognises and registers it. Writes ``runtime.json``, ``declutter.png`` (the first
declutter graph), ``scene.png`` (the overview image before and after decluttering) and, with models,
``summary.png`` (touches, reconstruction, pose overlay).
"""

from __future__ import annotations

import argparse
import json
import logging
import time
from pathlib import Path

from vtlearn.bench_utils import csv_list
from vtlearn.cli_args import count

__all__ = ["register", "register_bench"]

log = logging.getLogger(__name__)


# the files a `vtlearn quickstart --out` directory (``--models``) supplies, and the flag that overrides each
_MODEL_FILES = (("actor", "actor.ckpt", "--actor"), ("xavtnet", "xavtnet.ckpt", "--xavtnet"),
                ("class_names", "data/crossmodal/manifest.json", "--class-names"))


def _model_paths(args) -> tuple[tuple[Path, str] | None, ...]:
    """``(path, flag it came from)`` of the ACTOR checkpoint, the xAVTNet checkpoint and the class-names
    manifest, each None when not given.

    ``--actor``, ``--xavtnet`` and ``--class-names`` take precedence over the files of ``--models``; an
    explicit ``--xavtnet`` also takes its class names from its checkpoint (or ``--class-names``), not from
    ``--models``. Every path is checked here, before any model is loaded, and an error names the flag that
    gave it.
    """
    given = {key: getattr(args, key) for key, _, _ in _MODEL_FILES}
    out = {
        key: (Path(given[key]), flag) for key, _, flag in _MODEL_FILES if given[key] is not None
    }
    if args.models is not None:
        d = Path(args.models)
        if not d.is_dir():
            raise FileNotFoundError(f"--models: no directory {d}")
        for key, rel, flag in _MODEL_FILES:
            if key in out or (key == "class_names" and given["xavtnet"] is not None):
                continue
            if not (d / rel).is_file():
                raise FileNotFoundError(
                    f"--models: {d} has no {rel} (run `vtlearn quickstart --out {d}`, or pass {flag})"
                )
            out[key] = (d / rel, "--models")
    elif (args.actor is None) != (args.xavtnet is None):
        raise ValueError(
            "--actor, --xavtnet: give both (and --class-names unless the xAVTNet checkpoint records them), "
            "or --models, or none (explore only)"
        )
    for path, flag in out.values():
        if flag != "--models" and not path.is_file():
            raise FileNotFoundError(f"{flag}: no file {path}")
    return out.get("actor"), out.get("xavtnet"), out.get("class_names")


def _load_models(paths) -> tuple:
    """The ACTOR model, the xAVTNet model and its class names of :func:`_model_paths` (None where not given);
    a bad checkpoint or manifest is reported under the flag that gave it."""
    from vtlearn.datamodules.shards import read_class_names
    from vtlearn.models.actor import load_actor
    from vtlearn.models.xavtnet import load_xavtnet
    from vtlearn.runtime.robot import check_class_names
    from vtlearn.validation import load_named

    actor_path, xav_path, names_path = paths
    actor = None if actor_path is None else load_named(load_actor, *actor_path)
    xav = None if xav_path is None else load_named(load_xavtnet, *xav_path)
    if xav is None:
        return actor, None, None
    hp = dict(getattr(xav, "hparams", {}))
    if names_path is None:
        names, flag = hp.get("class_names"), xav_path[1]
        if not names:
            raise ValueError(
                "--class-names: the xAVTNet checkpoint records no class names; pass the crossmodal dataset's "
                "manifest.json"
            )
    else:
        path, flag = names_path
        names = read_class_names(path, flag)
    return actor, xav, check_class_names(names, xav, flag)


def _scene_categories(args) -> tuple[str, list[str], bool | None]:
    """``--target``, ``--clutter`` and ``--target-kind`` checked against the procedural categories, before
    anything is loaded: the target category, the clutter categories and the target's transparency."""
    from vtlearn.cli_args import category_list
    from vtlearn.sim_data.shapes import CATEGORIES, TRANSPARENT_PROB

    transparent = {"transparent": True, "opaque": False, "any": None}[args.target_kind]
    if args.target not in CATEGORIES:
        raise ValueError(f"--target: unknown category {args.target!r}, expected one of {CATEGORIES}")
    clutter = category_list(args.clutter, "--clutter", transparent=False, empty_ok=True)  # clutter is opaque
    if args.target in clutter:
        rest = ",".join(c for c in clutter if c != args.target)
        raise ValueError(
            f"--clutter: holds the target category {args.target!r} (--target), and the clutter must differ "
            f"from the target (thesis 5.2.2); pass a --clutter without it"
            + (f", e.g. --clutter {rest}" if rest else "")
        )
    p = TRANSPARENT_PROB.get(args.target, 0.0)
    if (transparent is True and p == 0.0) or (transparent is False and p == 1.0):
        raise ValueError(
            f"--target {args.target} --target-kind {args.target_kind}: {args.target} has no "
            f"{args.target_kind} instances; pass --target-kind {'opaque' if transparent else 'transparent'} "
            "or any, or another --target"
        )
    return args.target, clutter, transparent


def _scene_figure(path: Path, before, after, titles: tuple[str, str]) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 2, figsize=(9, 3.8))
    for ax, img, title in zip(axes, (before, after), titles, strict=True):
        ax.imshow(img)
        ax.set_title(title, fontsize=10)
        ax.axis("off")
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


def _warn_unknown_target(target: str, names: list[str] | None, source) -> None:
    """One warning, before the scene is built, when ``--target``'s category is not one of the xAVTNet's
    classes (``names``, from ``source``: ``(path, flag)``): its recognition then cannot be right."""
    if names is None or target in names:
        return
    where = f" ({source[1]} {source[0]})" if source else ""
    log.warning(
        "--target %s is not one of the xAVTNet's %d classes%s: %s; its recognition cannot be right "
        "(pass a --target among them, or models trained with %s)",
        target, len(names), where, ", ".join(names), target,
    )


def _explore_progress(bar):
    """A ``progress(done, total)`` callback of the exploration that keeps ``bar`` at ``done`` of ``total``:
    the episode's own total (a transparent target gets no views), so the bar ends full."""

    def update(done: int, total: int) -> None:
        if bar.total != total:
            bar.total = total
        bar.update(done - bar.n)

    return update


def _cmd_runtime(args: argparse.Namespace) -> int:
    from tqdm import tqdm

    from vtlearn.bench_utils import check_output_path

    target_cat, clutter_cats, transparent = _scene_categories(args)  # before pybullet loads and says so
    check_output_path(args.out, "--out", "runtime outputs", folder=True)  # before any model loads
    paths = _model_paths(args)
    from vtlearn.pipeline import summary_figure
    from vtlearn.runtime.robot import TwoArmRuntime, clutter_scene, save_report

    actor, xav, names = _load_models(paths)
    _warn_unknown_target(target_cat, names, paths[2] or paths[1])
    target_obj, clutter = clutter_scene(target_cat, clutter_cats, transparent=transparent, seed=args.seed)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    t0 = time.perf_counter()
    with TwoArmRuntime(actor, xav, names, seed=args.seed) as rt:
        target = rt.add_object(target_obj, fixed=True)
        for c in clutter:
            rt.add_object(c)
        rt.scene.step(120)  # let the free clutter settle
        before = rt.observe().frame.rgb
        # the declutter bar's total is the action limit (it may finish early); the exploration bar's is the
        # episode's own: --n-touches, plus 3 views only for a target detected as opaque
        bars = {"declutter": tqdm(total=args.max_declutter, desc="declutter", unit="action", leave=False)}

        def explore(done: int, total: int) -> None:
            if "explore" not in bars:
                bars["declutter"].close()
                bars["explore"] = tqdm(total=args.n_touches, desc="explore", leave=False)
            _explore_progress(bars["explore"])(done, total)

        report = rt.run(
            target,
            n_touches=args.n_touches,
            max_declutter_actions=args.max_declutter,
            n_candidates=args.n_candidates,
            strategy=args.strategy,
            declutter_figure=out / "declutter.png",
            progress=explore,
            declutter_progress=_explore_progress(bars["declutter"]),
        )
        for bar in bars.values():
            bar.close()
        after = rt.observe().frame.rgb
    _scene_figure(out / "scene.png", before, after, ("before decluttering", "after decluttering"))
    path = save_report(report, out)
    n_push = sum(a["kind"] == "push" for a in report.declutter_actions)
    n_grasp = len(report.declutter_actions) - n_push
    print(
        f"declutter: {n_grasp} grasps, {n_push} pushes, "
        f"{'complete' if report.declutter_done else 'NOT complete'}"
    )
    ep = report.episode
    plural = {"touch": "touches", "view": "views"}
    kinds = ", ".join(f"{ep.kinds.count(k)} {plural.get(k, k)}" for k in sorted(set(ep.kinds)))
    print(
        f"target: {target_obj.category} ({'transparent' if target_obj.transparent else 'opaque'}; detected "
        f"{'transparent' if report.transparent_detected else 'opaque'}); {ep.n_steps} actions ({kinds}), "
        f"{len(ep.points)} points, {report.ik_queries} IK queries"
    )
    s = report.perception
    if s:
        a = report.arrays
        summary_figure(
            out / "summary.png",
            target_obj,
            ep,
            a["recon"],
            a["scene"],
            a["model_pts"],
            a["T_est"],
            a["T_gt"],
            s,
        )
        print(f"reconstruction (ACTOR): Chamfer distance {s['chamfer_mm']:.1f} mm")
        print(f"recognition (xAVTNet):  predicted {s['predicted_category']}, true {s['true_category']}")
        print(f"pose (S-TIQF):          ADI {s['adi_cm']:.2f} cm")
    elif report.perception_error:
        print(f"perception failed: {report.perception_error}")
    else:
        print("no models given: explored only (pass --models DIR or --actor/--xavtnet/--class-names)")
    print(f"seconds: {json.dumps(report.seconds)}  total {time.perf_counter() - t0:.0f} s")
    print(
        f"wrote {path}, {out / 'declutter.png'}, {out / 'scene.png'}"
        + (f", {out / 'summary.png'}" if s else "")
    )
    return 0


def _cmd_bench_runtime(args: argparse.Namespace) -> int:
    from tqdm import tqdm

    from vtlearn.active.closed_loop import TOUCH_STRATEGIES
    from vtlearn.bench_utils import machine_info, print_table, ratio, write_json_and_figure
    from vtlearn.runtime.runtime_bench import run_runtime_benchmark, runtime_figure
    from vtlearn.sim_data.shapes import CATEGORIES

    strategies = csv_list(args.strategies)
    bad = [x for x in strategies if x not in TOUCH_STRATEGIES]  # the tactile arm has no pinch
    if not strategies or bad:
        raise ValueError(f"--strategies: expected some of {TOUCH_STRATEGIES}, got {strategies}")
    paths = _model_paths(args)
    if paths[0] is None:
        raise ValueError(
            "--models: the benchmark perceives, so it needs models (or --actor/--xavtnet/--class-names)"
        )
    actor, xav, names = _load_models(paths)
    unknown = [c for c in names if c not in CATEGORIES]
    if unknown:
        flag = (paths[2] or paths[1])[1]
        raise ValueError(f"{flag}: class names {unknown} are not procedural categories {CATEGORIES}")
    bar = tqdm(total=args.scenes * len(strategies), desc="scenes x strategies")
    t0 = time.perf_counter()
    result = run_runtime_benchmark(
        actor,
        xav,
        names,
        scenes=args.scenes,
        strategies=strategies,
        n_touches=args.n_touches,
        n_candidates=args.n_candidates,
        seed=args.seed,
        progress=lambda i, n: bar.update(),
    )
    bar.close()
    s, th = result["summary"], result["thesis"]
    base = s.get("random")
    metrics = [
        "success_rate",
        "declutter_rate",
        "recognition_accuracy",
        "perception_failures",
        "chamfer_mm_mean",
        "chamfer_mm_transparent_mean",
        "adi_cm_median",
        "points_mean",
        "seconds_mean",
    ]
    rows = []
    for name, r in s.items():
        row = {"strategy": name, **{k: r[k] for k in metrics}}
        if base:  # ratios against random exploration in the same run ("-" where random has no value)
            row["adi_ratio_to_random"] = ratio(r["adi_cm_median"], base["adi_cm_median"])
            row["cd_ratio_to_random"] = ratio(r["chamfer_mm_mean"], base["chamfer_mm_mean"])
        rows.append(row)
    rows.append(
        {
            "strategy": "thesis (real robots)",
            "success_rate": th["success_rate"],
            "chamfer_mm_transparent_mean": "< 20 (random ~30)",
            "adi_cm_median": "< 3",
        }
    )
    cols = ["strategy", *metrics, "adi_ratio_to_random", "cd_ratio_to_random"]
    print_table(
        rows,
        cols,
        f"Two-arm runtime, {args.scenes} cluttered scenes, {args.n_touches} touches "
        f"(success: decluttered and ADI < 3 cm, thesis 5.4.2)",
    )
    figure = Path(args.figure) if args.figure else Path(args.json).with_suffix(".png")
    result.update(machine=machine_info(), seconds=round(time.perf_counter() - t0, 1))
    write_json_and_figure(args.json, result, figure, runtime_figure)
    print(f"wrote {args.json} and {figure}")
    return 0


def _cmd_bench_declutter(args: argparse.Namespace) -> int:
    from tqdm import tqdm

    from vtlearn.bench_utils import machine_info, print_table, write_json_and_figure
    from vtlearn.runtime.robot import DECLUTTER_POLICIES
    from vtlearn.runtime.runtime_bench import declutter_figure, run_declutter_benchmark
    from vtlearn.sim_data.shapes import CATEGORIES

    most = len(CATEGORIES) - 2  # categories other than the target's, less the always transparent wineglass
    if not 1 <= args.clutter <= most:
        raise ValueError(f"--clutter: need 1..{most} clutter objects per scene, got {args.clutter}")
    policies = csv_list(args.policies)
    if not policies or any(x not in DECLUTTER_POLICIES for x in policies):
        raise ValueError(f"--policies: expected some of {DECLUTTER_POLICIES}, got {policies}")
    figure = Path(args.figure) if args.figure else Path(args.json).with_suffix(".png")
    bar = tqdm(total=args.scenes * len(policies), desc="scenes x policies")
    t0 = time.perf_counter()
    result = run_declutter_benchmark(
        scenes=args.scenes,
        n_clutter=args.clutter,
        policies=policies,
        max_actions=args.max_actions,
        seed=args.seed,
        progress=lambda i, n: bar.update(),
    )
    bar.close()
    s = result["summary"]
    base = s.get("graph")
    rows = []
    for name, r in s.items():
        row = {"policy": name, **r}
        if base and base["actions_mean"] > 0:
            row["actions_x_graph"] = r["actions_mean"] / base["actions_mean"]
        rows.append(row)
    cols = [
        "policy",
        "success_rate",
        "actions_mean",
        "actions_x_graph",
        "scenes_compared",
        "grasps",
        "pushes",
    ]
    print_table(
        rows,
        [*cols, "unreachable", "seconds_mean"],
        f"Decluttering, {args.scenes} scenes with {args.clutter} clutter objects, at most {args.max_actions} "
        "actions (thesis 5.2.2; actions_mean over the scenes every policy finished)",
    )
    result.update(machine=machine_info(), seconds=round(time.perf_counter() - t0, 1))
    write_json_and_figure(args.json, result, figure, declutter_figure)
    print(f"wrote {args.json} and {figure}")
    return 0


def _add_model_args(p) -> None:
    """The model sources that :func:`_model_paths` reads: ``--models DIR``, or the three files."""
    p.add_argument(
        "--models",
        default=None,
        help="a `vtlearn quickstart --out` directory (its checkpoints and class names); --actor, --xavtnet "
        "and --class-names given with it replace its files",
    )
    p.add_argument("--actor", default=None, help="ACTOR checkpoint (.ckpt)")
    p.add_argument("--xavtnet", default=None, help="xAVTNet checkpoint (.ckpt)")
    p.add_argument(
        "--class-names",
        default=None,
        help="crossmodal dataset manifest.json (xAVTNet class names; default: those the checkpoint records, "
        "or with --models and no --xavtnet, its data/crossmodal/manifest.json)",
    )


def register_bench(bench_subparsers) -> None:
    p = bench_subparsers.add_parser(
        "declutter", help="the declutter graph against nearest-first and random orders on the same scenes"
    )
    p.add_argument("--scenes", type=count(1), default=10, help="cluttered scenes (default %(default)s)")
    p.add_argument("--clutter", type=count(1), default=4,
                   help="clutter objects per scene, at most 10 (default %(default)s)")
    p.add_argument(
        "--policies", default="graph,nearest,random", help="declutter policies (default %(default)s)"
    )
    p.add_argument("--max-actions", type=count(1), default=10,
                   help="action limit per scene (default %(default)s)")
    p.add_argument("--seed", type=count(0), default=0)
    p.add_argument("--json", default="runs/bench/declutter.json", help="output JSON")
    p.add_argument("--figure", default=None, help="output figure (default: the JSON path with .png)")
    p.set_defaults(func=_cmd_bench_declutter)

    p = bench_subparsers.add_parser(
        "runtime", help="the two-arm runtime on cluttered scenes: success rate, CD, recognition, ADI"
    )
    _add_model_args(p)
    p.add_argument("--scenes", type=count(1), default=4, help="cluttered scenes (default %(default)s)")
    p.add_argument(
        "--strategies", default="active,random", help="exploration strategies (default %(default)s)"
    )
    p.add_argument("--n-touches", type=count(1), default=20, help="touch budget (default %(default)s)")
    p.add_argument(
        "--n-candidates", type=count(1), default=40, help="candidates per active step (default %(default)s)"
    )
    p.add_argument("--seed", type=count(0), default=0)
    p.add_argument("--json", default="runs/bench/runtime.json", help="output JSON")
    p.add_argument("--figure", default=None, help="output figure (default: the JSON path with .png)")
    p.set_defaults(func=_cmd_bench_runtime)


def register(sub) -> None:
    p = sub.add_parser(
        "runtime",
        help="two-arm robot runtime in pybullet: declutter, explore by touch, reconstruct/recognise/pose",
    )
    _add_model_args(p)
    p.add_argument("--target", default="wineglass", help="target category (default %(default)s)")
    p.add_argument(
        "--target-kind",
        choices=("transparent", "opaque", "any"),
        default="transparent",
        help="draw a transparent, opaque or any held-out instance (default %(default)s)",
    )
    p.add_argument(
        "--clutter",
        default="can,box,bowl",
        help="comma-separated clutter categories, other than --target's ('' for none; default %(default)s)",
    )
    p.add_argument("--n-touches", type=count(1), default=20, help="touch budget (default %(default)s)")
    p.add_argument(
        "--strategy",
        choices=("active", "random", "uniform"),
        default="active",
        help="exploration strategy (default %(default)s; docs/runtime.md compares them)",
    )
    p.add_argument(
        "--max-declutter", type=count(0), default=8, help="declutter action limit (default %(default)s)"
    )
    p.add_argument(
        "--n-candidates",
        type=count(1),
        default=40,
        help="IK-checked candidates per active step (default %(default)s)",
    )
    p.add_argument("--seed", type=count(0), default=0)
    p.add_argument("--out", default="runs/runtime", help="output directory (default %(default)s)")
    p.set_defaults(func=_cmd_runtime)
