"""Registration CLI: ``vtlearn register``, ``vtlearn bench registration``, ``vtlearn bench active-touch``."""

from __future__ import annotations

import argparse
import json
from pathlib import Path
from typing import Any

__all__ = ["register", "register_bench"]


def _cmd_register(args: argparse.Namespace) -> int:
    from vtlearn.bench_utils import to_jsonable
    from vtlearn.classical.registration import register as reg
    from vtlearn.io import read_geometry

    model = read_geometry(args.model, n_points=args.model_points, seed=args.seed)
    scene = read_geometry(args.scene, n_points=args.scene_points, seed=args.seed + 1)
    opts: dict[str, Any] = {}
    if args.estimate_scale:
        opts["estimate_scale"] = True
    res = reg(model, scene, args.method, restarts=args.restarts, seed=args.seed, **opts)
    out = res.to_dict()
    out.update(
        {"model": str(args.model), "scene": str(args.scene), "n_model": len(model), "n_scene": len(scene)}
    )
    if args.json:
        print(json.dumps(to_jsonable(out), indent=2))
    else:
        print(f"method {res.method}: rmse {res.rmse:.4g} m, {res.iterations} iterations, {res.time:.3f} s")
        print("T_scene_model =")
        for row in res.T_scene_model:
            print("  " + " ".join(f"{v: .6f}" for v in row))
        print("scale =", " ".join(f"{v:.6f}" for v in res.scale))
    return 0


def register(subparsers: Any) -> None:
    from vtlearn.classical.registration import METHODS

    p = subparsers.add_parser("register", help="register a model to a scene cloud (TIQF, S-TIQF, baselines)")
    p.add_argument(
        "--model", required=True, help="model cloud or mesh (.ply .pcd .xyz .txt .npy .npz .obj .stl .off)"
    )
    p.add_argument("--scene", required=True, help="scene cloud or mesh")
    p.add_argument("--method", default="stiqf", choices=sorted(METHODS))
    p.add_argument(
        "--estimate-scale", action="store_true", help="S-TIQF: estimate a per-axis scale (eq. 5.12)"
    )
    p.add_argument("--restarts", type=int, default=0, help="extra random restarts (common wrapper)")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--model-points", type=int, default=1024, help="points sampled when the model is a mesh")
    p.add_argument("--scene-points", type=int, default=120, help="points sampled when the scene is a mesh")
    p.add_argument("--json", action="store_true", help="print the result as JSON")
    p.set_defaults(func=_cmd_register)


def _cmd_bench_registration(args: argparse.Namespace) -> int:
    from vtlearn.bench_utils import print_table, write_json
    from vtlearn.classical.registration_bench import bar_plot, markdown_report, run_registration_benchmark

    sizes = [int(s) for s in args.sizes.split(",")]
    methods = args.methods.split(",") if args.methods else None
    result = run_registration_benchmark(
        args.meshes,
        sizes=sizes,
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
                    "adi_mean_cm": s["mean"],
                    "adi_std_cm": s["std"],
                    "adi_median_cm": s["median"],
                    "time_s": s["time_mean_s"],
                    "cpu_s": s["cpu_time_mean_s"],
                    "p_vs_stiqf": "-" if s["p_welch_vs_stiqf"] is None else f"{s['p_welch_vs_stiqf']:.2g}",
                }
            )
    print_table(
        rows,
        ["N", "method", "adi_mean_cm", "adi_std_cm", "adi_median_cm", "time_s", "cpu_s", "p_vs_stiqf"],
        "bench registration (thesis 5.3.3; times on a shared CPU are noisy)",
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
        candidates=[int(c) for c in args.candidates.split(",")],
        faces=[int(f) for f in args.faces.split(",")],
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
        ["faces", "candidates", "lookahead_s", "lookahead_median_s", "thesis_s"],
        "one-step look-ahead time (Table 4.1 analogue)",
    )
    names = ("active", "active_entropy", "random")
    print_table(
        result["curve_rows"],
        ["touches"] + [f"{n}_trans_rmse_mm" for n in names] + [f"{n}_rot_rmse_deg" for n in names],
        "active vs random touch (Fig. 4.5 analogue), RMSE over trials",
    )
    write_json(args.json, result)
    print(f"wrote {args.json} and {Path(args.json).with_suffix('.png')}")
    return 0


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
        type=int,
        default=10,
        help="trials per mesh and scene size (3 meshes x 10 = the thesis's 30)",
    )
    p.add_argument("--sizes", default="20,40,80,120", help="scene sizes, comma separated")
    p.add_argument("--methods", default=None, help="comma-separated subset of methods")
    p.add_argument("--scale-trials", type=int, default=4, help="trials per mesh of the scale run (0: skip)")
    p.add_argument("--no-time-matched", action="store_true", help="skip ICP restarts matched to S-TIQF time")
    p.add_argument("--no-ablation", action="store_true", help="skip the Table 5.1 ablation")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--json", default="runs/bench/registration.json", help="output JSON (.md and .png beside)")
    p.set_defaults(func=_cmd_bench_registration)

    p = bench_subparsers.add_parser("active-touch", help="active touch look-ahead time and active vs random")
    p.add_argument("--candidates", default="10,100,1000")
    p.add_argument("--faces", default="1000,5000")
    p.add_argument("--repeats", type=int, default=5, help="timing repeats per configuration")
    p.add_argument("--trials", type=int, default=10, help="active-vs-random trials")
    p.add_argument("--touches", type=int, default=25, help="touches per trial")
    p.add_argument("--mesh", default="bunny", help="mesh for the active-vs-random curves")
    p.add_argument(
        "--init-rot-deg", type=float, default=30.0, help="initial rotation error bound (thesis 30)"
    )
    p.add_argument(
        "--init-trans", type=float, default=0.02, help="initial translation error bound per axis (m)"
    )
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--json", default="runs/bench/active_touch.json", help="output JSON (.png beside)")
    p.set_defaults(func=_cmd_bench_active_touch)
