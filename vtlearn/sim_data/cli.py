"""`vtlearn gen-shapes`, `vtlearn gen-data`, `vtlearn preview` and `vtlearn bench sim`."""

from __future__ import annotations

import argparse
import json

from vtlearn.bench_utils import csv_list
from vtlearn.cli_args import count, with_flag


def _cmd_gen_shapes(args: argparse.Namespace) -> int:
    from vtlearn.sim_data.shapes import write_shapes

    recs = write_shapes(args.out, args.categories, args.per_category, args.seed, args.sections)
    print(f"wrote {len(recs)} meshes to {args.out}")
    return 0


# GenConfig fields / generate_dataset arguments -> the `gen-data` flags that set them, for the error messages
_GEN_DATA_FLAGS = {
    "categories": "--categories", "per_category": "--per-category", "split_fractions": "--splits",
    "shard_size": "--shard-size", "sections": "--sections", "sensor": "--sensor", "touches": "--touches",
    "pinches": "--pinches", "views": "--views", "image_width": "--width", "image_height": "--height",
    "visual_crop_margin": "--visual-crop-margin", "tactile_clouds": "--tactile-clouds",
    "tactile_min_points/tactile_max_points": "--tactile-points",
    "mesh_source": "--meshes", "keep_split": "--keep-split", "out_dir": "--out", "workers": "--workers",
    "seed": "--seed", "position_noise": "--position-noise", "dropout": "--dropout",
    "depth_noise": "--no-depth-noise", "transparency": "--opaque",
}
# ... and in the refusal to resume a folder made with other settings, which names each setting that differs
_GEN_DATA_RESUME_NAMES = {**_GEN_DATA_FLAGS, "tactile_min_points": "--tactile-points (min)",
                          "tactile_max_points": "--tactile-points (max)", "kind": "KIND"}


def _cmd_gen_data(args: argparse.Namespace) -> int:
    from vtlearn.sim_data.writer import OutDirConfigError

    try:
        return _gen_data(args)
    except OutDirConfigError as exc:
        raise exc.with_names(_GEN_DATA_RESUME_NAMES) from None
    except (ValueError, FileNotFoundError) as exc:
        raise (with_flag(exc, _GEN_DATA_FLAGS) or exc) from None


def _gen_data(args: argparse.Namespace) -> int:
    from vtlearn.sim_data.writer import GenConfig, generate_dataset

    cfg = GenConfig(
        kind=args.kind,
        categories=args.categories,
        per_category=args.per_category,
        seed=args.seed,
        split_fractions=args.splits,
        shard_size=args.shard_size,
        sections=args.sections,
        sensor=args.sensor,
        touches=args.touches,
        pinches=args.pinches,
        position_noise=args.position_noise,
        dropout=args.dropout,
        views=args.views,
        image_width=args.width,
        image_height=args.height,
        depth_noise=not args.no_depth_noise,
        transparency=not args.opaque,
        visual_crop_margin=None if args.no_visual_crop else args.visual_crop_margin,
        tactile_clouds=args.tactile_clouds,
        tactile_min_points=args.tactile_points[0],
        tactile_max_points=args.tactile_points[1],
        mesh_source=args.meshes or "procedural",
        keep_split=args.keep_split,
    )
    manifest = generate_dataset(cfg, args.out, workers=args.workers)
    print(
        json.dumps({s: {k: v for k, v in d.items() if k != "shards"} for s, d in manifest["splits"].items()})
    )
    print(f"dataset in {args.out} (manifest.json)")
    return 0


def _cmd_preview(args: argparse.Namespace) -> int:
    from vtlearn.sim_data.preview import write_preview

    path = write_preview(args.dataset, args.out, max_categories=args.max_categories, seed=args.seed)
    print(f"wrote {path}")
    return 0


def register(sub) -> None:
    from vtlearn.sim_data.shapes import CATEGORIES

    p = sub.add_parser("gen-shapes", help="procedural category-level meshes (.obj + .json per instance)")
    p.add_argument("--out", required=True)
    p.add_argument(
        "--categories", type=csv_list, default=list(CATEGORIES), help="comma-separated (default: all 12)"
    )
    p.add_argument("--per-category", type=count(1), default=10)
    p.add_argument("--seed", type=count(0), default=0)
    p.add_argument("--sections", type=count(1), default=48, help="angular resolution of revolved parts")
    p.set_defaults(func=_cmd_gen_shapes)

    p = sub.add_parser(
        "gen-data",
        help="sharded synthetic datasets (reconstruction | crossmodal)",
        description="Sharded synthetic datasets, resumable: a rerun with the same settings skips the "
        "finished shards, which a Ctrl-C keeps.",
    )
    p.add_argument("kind", choices=["reconstruction", "crossmodal"],
                   help="reconstruction: dense + tactile clouds (ACTOR); crossmodal: visual + tactile clouds "
                   "(xAVTNet)")
    p.add_argument("--out", required=True, help="dataset folder (a rerun into it resumes)")
    p.add_argument("--categories", type=csv_list, default=None,
                   help=f"comma-separated categories (default: all {len(CATEGORIES)} procedural ones: "
                   f"{', '.join(CATEGORIES)}; with --meshes, every category found there)")
    p.add_argument("--per-category", type=count(1), default=10,
                   help="instances per category (default: %(default)s)")
    p.add_argument("--seed", type=count(0), default=0,
                   help="seed of the shapes and the sensing (default: %(default)s)")
    p.add_argument(
        "--splits",
        type=lambda s: [float(x) for x in s.split(",")],
        default=[0.7, 0.15, 0.15],
        help="train,val,test instance fractions (default: 0.7,0.15,0.15)",
    )
    p.add_argument("--shard-size", type=count(1), default=16,
                   help="instances per shard (default: %(default)s)")
    p.add_argument("--sections", type=count(1), default=48,
                   help="angular resolution of the procedural meshes' revolved parts, in segments per turn "
                   "(default: %(default)s)")
    p.add_argument(
        "--sensor", default="xela_4x4",
        help="tactile sensor: xela_4x4 | xela_6x4 | xela_6x1 | contactile_3x3 | RxC@Pmm "
        "(default: %(default)s)",
    )
    p.add_argument("--touches", type=count(1), default=40,
                   help="reconstruction: touches per instance (default: %(default)s)")
    p.add_argument("--pinches", type=count(0), default=10,
                   help="reconstruction: pinches per instance (default: %(default)s)")
    p.add_argument("--position-noise", type=float, default=0.0,
                   help="tactile position noise std in metres (default: %(default)s)")
    p.add_argument("--dropout", type=float, default=0.0,
                   help="taxel dropout probability (default: %(default)s)")
    p.add_argument("--views", type=count(1), default=4,
                   help="crossmodal: visual clouds per instance (default: %(default)s)")
    p.add_argument("--tactile-clouds", type=count(1), default=4,
                   help="crossmodal: tactile clouds per instance (default: %(default)s)")
    p.add_argument("--tactile-points", type=count(1), nargs=2, metavar=("MIN", "MAX"), default=[30, 120],
                   help="crossmodal: contacts per tactile cloud, drawn uniformly in [MIN, MAX]; each cloud's "
                   "touches stop once it has that many (thesis 7.2.3: 'usually 30-80'; default: 30 120)")
    p.add_argument("--width", type=count(1), default=320,
                   help="crossmodal: depth-camera image width in pixels (default: %(default)s)")
    p.add_argument("--height", type=count(1), default=240,
                   help="crossmodal: depth-camera image height in pixels (default: %(default)s)")
    p.add_argument("--no-depth-noise", action="store_true",
                   help="crossmodal: exact depth images (default: with depth noise)")
    p.add_argument("--opaque", action="store_true",
                   help="crossmodal: no glass: the camera sees every instance as opaque (default: the "
                   "wineglasses, half the bottles and jars and a third of the cups fail as glass does)")
    p.add_argument("--visual-crop-margin", type=float, default=0.05,
                   help="crossmodal: keep visual points inside the object's box grown by this fraction "
                   "(default: %(default)s)")
    p.add_argument("--no-visual-crop", action="store_true",
                   help="crossmodal: keep the whole segmentation mask (transparent see-through returns too)")
    p.add_argument(
        "--meshes",
        default=None,
        help="use real meshes instead of procedural ones: a ShapeNetCore v2, ModelNet40 or "
        "category-per-folder directory, or 'pybullet_data' (default: procedural meshes)",
    )
    p.add_argument("--keep-split", action="store_true",
                   help="with --meshes of a ModelNet40/10 tree: keep its own train/test split (its test "
                   "meshes are the test split, its train meshes are split into train and val in the "
                   "--splits train:val ratio) and take up to --per-category meshes from each "
                   "(default: split all meshes by --splits)")
    p.add_argument("--workers", type=count(1), default=1,
                   help="worker processes writing shards (default: %(default)s)")
    p.set_defaults(func=_cmd_gen_data)

    p = sub.add_parser("preview", help="PNG grid per category: mesh, dense, tactile and visual clouds")
    p.add_argument("dataset", help="a gen-data directory")
    p.add_argument("--out", default=None, help="PNG path (default DATASET/preview.png)")
    p.add_argument("--max-categories", type=count(1), default=12)
    p.add_argument("--seed", type=count(0), default=0)
    p.set_defaults(func=_cmd_preview)


def register_bench(sub) -> None:
    p = sub.add_parser("sim", help="touches/s, camera frame->cloud ms, shapes/s")
    p.add_argument("--json", default="runs/bench/sim.json")
    p.add_argument("--touches", type=count(1), default=2000)
    p.add_argument("--frames", type=count(1), default=30)
    p.add_argument("--shapes", type=count(1), default=48)
    p.set_defaults(func=lambda a: __import__("vtlearn.sim_data.bench", fromlist=["run"]).run(a))
