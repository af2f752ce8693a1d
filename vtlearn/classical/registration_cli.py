"""Registration CLI: ``vtlearn register``, ``vtlearn hand-eye``, ``vtlearn bench registration``,
``vtlearn bench active-touch``, ``vtlearn bench hand-eye``."""

from __future__ import annotations

import argparse
import json
from pathlib import Path
from typing import Any

from vtlearn.bench_utils import csv_list
from vtlearn.cli_args import count, counts, real

__all__ = ["register", "register_bench"]

# the fewest scene points a registration takes: register() needs 3 non-collinear points (S-TIQF, RANSAC, ...)
MIN_SCENE_POINTS = 3
# the fewest faces of the look-ahead timing mesh: a closed surface (tetrahedron); 1 decimates to no faces
MIN_FACES = 4


def _read_points(path: str, flag: str, n_points: int, seed: int, label: str | None = None):
    """The cloud of a command-line file (a mesh is sampled with ``n_points``), with every error naming
    ``flag``: an unreadable, empty or NaN file, fewer than 3 points, or collinear points (``label``, default
    ``flag``, names the cloud in the last two).

    Shapes: output (N, 3), N >= 3."""
    from vtlearn.io import read_geometry
    from vtlearn.validation import as_points, check_not_collinear, load_named

    label = label or flag
    cloud = load_named(lambda p: read_geometry(p, n_points=n_points, seed=seed), path, flag)
    cloud = as_points(cloud, label, min_points=MIN_SCENE_POINTS)
    check_not_collinear(cloud, label)
    return cloud


def _print_json(out: dict, path) -> None:
    """``--json``: the result to stdout (``--json`` alone) or written to ``path`` (``--json FILE``)."""
    from vtlearn.bench_utils import to_jsonable, write_json

    if path is True:
        print(json.dumps(to_jsonable(out), indent=2))
    else:
        print(f"wrote {write_json(path, out)}")


def _registration_figure(model, scene, res, path) -> Any:
    """A 3-D scatter of the scene and of the model at the estimated pose (scaled): where one looks to see
    whether the registration found the object.

    Shapes: model (M, 3), scene (N, 3)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import numpy as np

    from vtlearn.bench_utils import save_figure

    moved = (model * res.scale) @ res.R.T + res.t
    fig = plt.figure(figsize=(6, 5))
    ax = fig.add_subplot(projection="3d")
    ax.scatter(*moved.T, s=2, c="0.55", label=f"model at the estimate ({len(model)} points)")
    ax.scatter(*scene.T, s=14, c="tab:red", label=f"scene ({len(scene)} points)")
    both = np.vstack([moved, scene])
    ax.set_box_aspect(np.maximum(np.ptp(both, axis=0), 1e-9))  # metres on every axis alike
    for set_label, axis in ((ax.set_xlabel, "x"), (ax.set_ylabel, "y"), (ax.set_zlabel, "z")):
        set_label(f"{axis} (m)")
    ax.legend(loc="upper left", fontsize=8)
    ax.set_title(f"{res.method}: scene-to-model rmse {1e3 * res.rmse:.2f} mm")
    return save_figure(fig, path)


def _cmd_register(args: argparse.Namespace) -> int:
    import sys

    from vtlearn.bench_utils import check_same_units, cloud_extent
    from vtlearn.classical.registration import register as reg

    model = _read_points(args.model, "--model", args.model_points, args.seed)
    scene = _read_points(args.scene, "--scene", args.scene_points, args.seed + 1)
    if not args.estimate_scale:  # a scale between model and scene is what --estimate-scale solves for
        check_same_units(model, "--model", scene, "--scene")
    if cloud_extent(model) > 10.0:
        print(f"vtlearn: note: --model spans {cloud_extent(model):.4g} m; vtlearn reads metres, so if the "
              "files are in millimetres the rmse and t below are in millimetres too", file=sys.stderr)
    opts: dict[str, Any] = {}
    if args.estimate_scale:
        if args.method != "stiqf":
            raise ValueError(f"--estimate-scale: only --method stiqf estimates a scale, not {args.method}")
        opts["estimate_scale"] = True
    res = reg(model, scene, args.method, restarts=args.restarts, seed=args.seed, **opts)
    out = res.to_dict()
    out.update(
        {"model": str(args.model), "scene": str(args.scene), "n_model": len(model), "n_scene": len(scene)}
    )
    if args.json:
        _print_json(out, args.json)
    else:
        # Open3D's ICP, RANSAC and FGR do not report their iterations (0 in the result)
        its = f", {res.iterations} iterations" if res.iterations else ""
        print(f"method {res.method}: rmse {res.rmse:.4g} m (scene to registered model){its}, "
              f"{res.time:.3f} s")
        print("T_scene_model = (maps model points into the scene frame, metres)")
        for row in res.T_scene_model:
            print("  " + " ".join(f"{v: .6f}" for v in row))
        print("scale (per model axis) =", " ".join(f"{v:.6f}" for v in res.scale))
    if args.figure:
        print(f"wrote {_registration_figure(model, scene, res, args.figure)}")
    return 0


def _check_pose_units(visual: list, tactile, poses) -> None:
    """``--poses`` in the units of the clouds: the camera on the end effector sees the object about as far
    away (the visual cloud's distance from the camera) as the end effector is from it in the world (the
    tactile cloud's distance from ``T_W_E``); the two differ by the hand-eye offset, so a factor of 50 means
    poses in millimetres against clouds in metres.

    Shapes: visual V x (M_v, 3), tactile (N, 3), poses (V, 4, 4)."""
    import numpy as np

    d_cam = float(np.median([np.linalg.norm(v.mean(0)) for v in visual]))
    d_eff = float(np.median(np.linalg.norm(poses[:, :3, 3] - tactile.mean(0), axis=1)))
    if d_eff > 50.0 * max(d_cam, 1e-3):
        raise ValueError(f"--poses: the end effector is {d_eff:.4g} m from the --tactile contacts, but the "
                         f"camera sees the object {d_cam:.3g} m away in --visual: are the poses in "
                         "millimetres? vtlearn reads metres")


def _cmd_hand_eye(args: argparse.Namespace) -> int:
    from vtlearn.bench_utils import check_metres, check_output_path, check_same_units
    from vtlearn.classical.hand_eye import LOCAL_METHODS, in_situ_hand_eye
    from vtlearn.io import read_poses

    if args.init is None and args.method in LOCAL_METHODS:
        raise ValueError(f"--init: method {args.method} needs an initial T_E_C guess (a .npy, JSON or "
                         "4 x 4 text pose file); a global method such as stiqf needs none")
    out_path = check_output_path(args.out, "--out", "T_E_C .npy") if args.out else None  # before the work
    poses = read_poses(args.poses, "--poses")
    if len(poses) != len(args.visual):
        raise ValueError(f"--poses: need one T_W_E per --visual file ({len(args.visual)}), got {len(poses)}")
    init = read_poses(args.init, "--init", n=1)[0] if args.init else None
    visual = [_read_points(v, "--visual", args.visual_points, args.seed + i, label=f"--visual {v}")
              for i, v in enumerate(args.visual)]
    tactile = _read_points(args.tactile, "--tactile", args.tactile_points, args.seed)
    check_metres(tactile, "--tactile")
    for v, cloud in zip(args.visual, visual, strict=True):
        check_metres(cloud, f"--visual {v}")
        check_same_units(cloud, f"--visual {v}", tactile, "--tactile")
    _check_pose_units(visual, tactile, poses)
    res = in_situ_hand_eye(visual, tactile, poses, method=args.method, T_E_C_init=init, seed=args.seed)
    out = {"T_E_C": res.T_E_C, "T_W_C": res.T_W_C, "T_E_C_views": res.T_E_C_views, "rmse_m": res.rmse,
           "spread_m": res.spread_m, "spread_deg": res.spread_deg, "method": args.method,
           "visual": args.visual, "tactile": args.tactile, "poses": args.poses}
    if args.json:
        _print_json(out, args.json)
    else:
        print(f"{len(visual)} view(s), method {args.method}: registration rmse "
              + ", ".join(f"{1e3 * r:.2f}" for r in res.rmse) + " mm; views agree within "
              f"{1e3 * res.spread_m:.1f} mm / {res.spread_deg:.2f} deg")
        print("T_E_C = (the camera in the end-effector frame, metres)")
        for row in res.T_E_C:
            print("  " + " ".join(f"{v: .6f}" for v in row))
    if out_path is not None:
        import numpy as np

        out_path.parent.mkdir(parents=True, exist_ok=True)
        with open(out_path, "wb") as f:  # np.save on a name would append ".npy" to one without it
            np.save(f, res.T_E_C, allow_pickle=False)
        print(f"wrote {out_path}")
    return 0


def register(subparsers: Any) -> None:
    from vtlearn.classical.registration import METHODS

    h = subparsers.add_parser("hand-eye", help="in-situ visuo-tactile hand-eye calibration (thesis 5.2.5)")
    h.add_argument("--visual", nargs="+", required=True,
                   help="the object's visual cloud in the camera frame, one file per view")
    h.add_argument("--poses", required=True,
                   help="T_W_E of the camera arm for each view: .npy (V, 4, 4), JSON, or text of 4x4 "
                        "blocks stacked")
    h.add_argument("--tactile", required=True, help="tactile contacts on the same object, world frame")
    h.add_argument("--method", default="stiqf", choices=sorted(METHODS),
                   help="registration (default stiqf, global); local methods need --init")
    h.add_argument("--init", default=None,
                   help="nominal T_E_C (.npy (4, 4), JSON or 4x4 text), start of every view")
    h.add_argument("--visual-points", type=count(1), default=1024,
                   help="points sampled from a visual mesh input")
    h.add_argument("--tactile-points", type=count(1), default=60,
                   help="points sampled from a tactile mesh input")
    h.add_argument("--seed", type=count(0), default=0)
    h.add_argument("--json", nargs="?", const=True, default=None, metavar="FILE",
                   help="the result as JSON: printed, or written to FILE")
    h.add_argument("--out", default=None, help="save T_E_C as .npy")
    h.set_defaults(func=_cmd_hand_eye)

    p = subparsers.add_parser("register", help="register a model to a scene cloud (TIQF, S-TIQF, baselines)")
    p.add_argument(
        "--model", required=True, help="model cloud or mesh (.ply .pcd .xyz .txt .npy .npz .obj .stl .off)"
    )
    p.add_argument("--scene", required=True, help="scene cloud or mesh")
    p.add_argument("--method", default="stiqf", choices=sorted(METHODS))
    p.add_argument(
        "--estimate-scale", action="store_true", help="S-TIQF: estimate a per-axis scale (eq. 5.12)"
    )
    p.add_argument("--restarts", type=count(0), default=0, help="extra random restarts (common wrapper)")
    p.add_argument("--seed", type=count(0), default=0)
    p.add_argument("--model-points", type=count(1), default=1024,
                   help="points sampled when the model is a mesh")
    p.add_argument("--scene-points", type=count(1), default=120,
                   help="points sampled when the scene is a mesh")
    p.add_argument("--json", nargs="?", const=True, default=None, metavar="FILE",
                   help="the result as JSON: printed, or written to FILE")
    p.add_argument("--figure", default=None,
                   help="write a 3-D plot of the scene and the registered model (.png)")
    p.set_defaults(func=_cmd_register)


def _cmd_bench_registration(args: argparse.Namespace) -> int:
    from vtlearn.bench_utils import print_table, write_json
    from vtlearn.classical.registration_bench import bar_plot, markdown_report, run_registration_benchmark

    methods = csv_list(args.methods) if args.methods else None
    result = run_registration_benchmark(
        args.meshes,
        sizes=args.sizes,
        trials=args.trials,
        methods=methods,
        seed=args.seed,
        time_matched=not args.no_time_matched,
        ablation=not args.no_ablation,
        scale_trials=args.scale_trials,
    )
    rows = []
    for n in result["sizes"]:
        for name in result["methods"]:
            s = result["summary"][n][name]
            rows.append(
                {
                    "N": n,
                    "method": name,
                    "ADI mean cm": s["mean"],
                    "std cm": s["std"],
                    "median cm": s["median"],
                    "x S-TIQF": s["ratio_to_stiqf"],
                    "thesis cm": s["thesis_cm"],
                    "x thesis": s["ratio_to_thesis"],
                    "p vs S-TIQF": "-" if s["p_welch_vs_stiqf"] is None else f"{s['p_welch_vs_stiqf']:.2g}",
                    "wall s": s["time_mean_s"],
                    "CPU s": s["cpu_time_mean_s"],
                }
            )
    print_table(
        rows,
        ["N", "method", "ADI mean cm", "std cm", "median cm", "x S-TIQF", "thesis cm", "x thesis",
         "p vs S-TIQF", "wall s", "CPU s"],
        "bench registration (thesis 5.3.3): N scene points against 1024 model points; ADI (eq. 5.24) in cm; "
        "x S-TIQF = mean ADI / S-TIQF's on the same trials; thesis = Table 5.1 (bunny); p = Welch's t-test "
        "against S-TIQF; seconds per registration (wall clock on a shared CPU is noisy)",
    )
    md = markdown_report(result)
    if "scale" in result:
        sc = result["scale"]
        print(
            f"scale run (N={sc['n_scene']}): scale error mean {sc['scale_error']['mean']:.3f} "
            f"median {sc['scale_error']['median']:.3f}; ADI mean {sc['adi_cm']['mean']:.2f} cm"
        )
    out_json = Path(args.json)
    write_json(out_json, result)
    md_path = out_json.with_suffix(".md")
    md_path.write_text(md)
    png = bar_plot(result, out_json.with_suffix(".png"))
    print(f"wrote {out_json}, {md_path}, {png}")
    return 0


def _cmd_bench_active_touch(args: argparse.Namespace) -> int:
    from vtlearn.bench_utils import print_table, write_json
    from vtlearn.classical.active_touch import run_active_touch_benchmark

    result = run_active_touch_benchmark(
        candidates=args.candidates,
        faces=args.faces,
        repeats=args.repeats,
        trials=args.trials,
        touches=args.touches,
        seed=args.seed,
        mesh_spec=args.mesh,
        init_rot_deg=args.init_rot_deg,
        init_trans=args.init_trans,
        plot_path=Path(args.json).with_suffix(".png"),
    )
    print_table(
        result["lookahead_rows"],
        ["faces", "candidates", "lookahead_s", "lookahead_median_s", "thesis_s", "speedup_vs_thesis"],
        "one-step look-ahead time (Table 4.1 analogue), seconds; speedup_vs_thesis = thesis_s / lookahead_s",
    )
    names = ("active", "active_entropy", "random")
    print_table(
        result["curve_rows"],
        ["touches"] + [f"{n}_trans_rmse_mm" for n in names] + [f"{n}_rot_rmse_deg" for n in names]
        + [f"{n}_over_random_{w}" for w in ("trans", "rot") for n in ("active", "active_entropy")],
        "active vs random touch (Fig. 4.5 analogue), RMSE over trials; *_over_random = strategy / random "
        "(below 1: better than random)",
    )
    write_json(args.json, result)
    print(f"wrote {args.json} and {Path(args.json).with_suffix('.png')}")
    return 0


def _cmd_bench_hand_eye(args: argparse.Namespace) -> int:
    from vtlearn.bench_utils import machine_info, print_table, write_json_and_figure
    from vtlearn.classical.hand_eye_bench import run_hand_eye_benchmark
    from vtlearn.classical.registration_bench import default_meshes, load_benchmark_mesh

    meshes = [load_benchmark_mesh(s) for s in (args.meshes or default_meshes())]
    methods = csv_list(args.methods)
    result = run_hand_eye_benchmark(meshes, trials=args.trials, views=args.views,
                                    n_tactile=args.tactile_points, init_trans=args.init_trans,
                                    init_rot_deg=args.init_rot_deg, methods=methods,
                                    one_sided=not args.full_surface, seed=args.seed)
    from vtlearn.bench_utils import ratio
    from vtlearn.classical.hand_eye_bench import THESIS_BOUNDS

    s = result["summary"]
    ref = s.get("stiqf")
    rows = []
    for name, r in s.items():
        rows.append({"method": name, "start": r["start"], "pos mm (median)": r["position_mm_median"],
                     "rot deg (median)": r["rotation_deg_median"], "pos mm (mean)": r["position_mm_mean"],
                     "pos x S-TIQF": ratio(r["position_mm_median"], ref and ref["position_mm_median"]),
                     "pos x thesis": ratio(r["position_mm_median"], THESIS_BOUNDS["position_mm"]),
                     "rot x thesis": ratio(r["rotation_deg_median"], THESIS_BOUNDS["rotation_deg"]),
                     "share in bounds": r["within_thesis_bounds"], "s per calib": r["seconds_mean"]})
    rows.append({"method": "thesis S-TIQF (real objects)", "start": "none", "pos mm (median)": "< 10",
                 "rot deg (median)": "< 5"})
    print_table(rows, ["method", "start", "pos mm (median)", "rot deg (median)", "pos mm (mean)",
                       "pos x S-TIQF", "pos x thesis", "rot x thesis", "share in bounds", "s per calib"],
                f"Hand-eye calibration error of T_E_C, {len(meshes)} mesh(es) x {args.trials} trial(s), "
                f"{args.views} views ({'whole surface' if args.full_surface else 'one-sided'}), "
                f"{args.tactile_points} tactile points (thesis 5.3.4). start: where a local method starts "
                "(the nominal calibration) or none; x S-TIQF = median position error / S-TIQF's; x thesis = "
                "median / the thesis bound (10 mm, 5 deg); share in bounds = fraction of trials within both; "
                "seconds per calibration (all views)")
    mesh_names = [n for n, _ in meshes]
    print_table([{"method": name, **r["position_mm_median_per_mesh"]} for name, r in s.items()],
                ["method", *mesh_names], "Median position error (mm) per calibration object (a "
                "near-symmetric object leaves the rotation about its axis unobserved)")
    result["machine"] = machine_info()
    png = Path(args.json).with_suffix(".png")
    write_json_and_figure(args.json, result, png, hand_eye_figure)
    print(f"wrote {args.json} and {png}")
    return 0


def hand_eye_figure(result: dict, path) -> Path:
    """Box plots per method of the hand-eye position (mm) and rotation (deg) errors, log scale, with the
    thesis bounds (Fig. 5.20e analogue), from ``bench hand-eye``'s result or JSON."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from vtlearn.bench_utils import save_figure

    fig, axes = plt.subplots(1, 2, figsize=(10, 4))
    names = list(result["summary"])
    for ax, key, unit in ((axes[0], "position_mm", "mm"), (axes[1], "rotation_deg", "deg")):
        data = [[x[key] for x in result["runs"] if x["method"] == n] for n in names]
        ax.boxplot(data, showfliers=True)
        ax.set_xticks(range(1, len(names) + 1), names, rotation=30)
        ax.set_yscale("log")
        ax.axhline(result["thesis"][key], color="r", ls="--", label="thesis bound")
        ax.set_ylabel(f"hand-eye error ({unit})")
        ax.legend()
    fig.suptitle("In-situ visuo-tactile hand-eye calibration (Fig. 5.20e analogue)")
    fig.tight_layout()
    return save_figure(fig, path)


def register_bench(bench_subparsers: Any) -> None:
    p = bench_subparsers.add_parser("registration", help="S-TIQF vs baselines, thesis 5.3.3 / Table 5.1")
    p.add_argument(
        "--meshes",
        nargs="+",
        default=None,
        help="'bunny', 'shape:CATEGORY[:SEED]' or mesh files (default: bunny + 2 procedural shapes)",
    )
    p.add_argument(
        "--trials",
        type=count(1),
        default=10,
        help="trials per mesh and scene size (3 meshes x 10 = the thesis's 30)",
    )
    p.add_argument("--sizes", type=counts(MIN_SCENE_POINTS), default=[20, 40, 80, 120],
                   help=f"scene sizes in points, comma separated, each >= {MIN_SCENE_POINTS} "
                        "(default 20,40,80,120)")
    p.add_argument("--methods", default=None, help="comma-separated subset of methods")
    p.add_argument("--scale-trials", type=count(0), default=4,
                   help="trials per mesh of the scale run (0: skip)")
    p.add_argument("--no-time-matched", action="store_true", help="skip ICP restarts matched to S-TIQF time")
    p.add_argument("--no-ablation", action="store_true", help="skip the Table 5.1 ablation")
    p.add_argument("--seed", type=count(0), default=0)
    p.add_argument("--json", default="runs/bench/registration.json", help="output JSON (.md and .png beside)")
    p.set_defaults(func=_cmd_bench_registration)

    p = bench_subparsers.add_parser("hand-eye", help="in-situ hand-eye calibration, S-TIQF vs peers (5.3.4)")
    p.add_argument("--meshes", nargs="+", default=None,
                   help="'bunny', 'shape:CATEGORY[:SEED]' or mesh files (default: bunny + 2 shapes)")
    p.add_argument("--trials", type=count(1), default=5, help="trials per mesh")
    p.add_argument("--views", type=count(1), default=3, help="camera captures per trial")
    p.add_argument("--tactile-points", type=count(1), default=60)
    p.add_argument("--methods", default="stiqf,ransac_fpfh,fgr,tiqf,icp", help="comma-separated methods")
    p.add_argument("--init-trans", type=float, default=0.02, help="nominal calibration error (m)")
    p.add_argument("--init-rot-deg", type=float, default=5.0, help="nominal calibration error (deg)")
    p.add_argument("--full-surface", action="store_true",
                   help="give every view the whole object surface instead of the side facing the camera")
    p.add_argument("--seed", type=count(0), default=0)
    p.add_argument("--json", default="runs/bench/hand_eye.json", help="output JSON (.png beside)")
    p.set_defaults(func=_cmd_bench_hand_eye)

    p = bench_subparsers.add_parser("active-touch", help="active touch look-ahead time and active vs random")
    p.add_argument("--candidates", type=counts(1), default=[10, 100, 1000],
                   help="candidate actions per look-ahead, comma separated (default 10,100,1000)")
    p.add_argument("--faces", type=counts(MIN_FACES), default=[1000, 5000],
                   help=f"face counts the mesh is decimated to, comma separated, each >= {MIN_FACES} (a "
                        "tetrahedron; default 1000,5000)")
    p.add_argument("--repeats", type=count(1), default=5, help="timing repeats per configuration")
    p.add_argument("--trials", type=count(1), default=10, help="active-vs-random trials")
    p.add_argument("--touches", type=count(1), default=25, help="touches per trial")
    p.add_argument("--mesh", default="bunny", help="mesh for the active-vs-random curves")
    p.add_argument(
        "--init-rot-deg", type=real(0.0, 180.0), default=30.0,
        help="initial rotation error bound, degrees in [0, 180] (thesis 30)"
    )
    p.add_argument(
        "--init-trans", type=real(0.0), default=0.02,
        help="initial translation error bound per axis (m, >= 0)"
    )
    p.add_argument("--seed", type=count(0), default=0)
    p.add_argument("--json", default="runs/bench/active_touch.json", help="output JSON (.png beside)")
    p.set_defaults(func=_cmd_bench_active_touch)
