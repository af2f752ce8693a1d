"""The ``vtlearn`` command line.

Feature packages add their commands through a module listed in ``COMMAND_MODULES`` that defines
``register(subparsers)`` and/or ``register_bench(bench_subparsers)``. A handler is stored as ``func`` in the
parser defaults; it takes the parsed namespace and returns an exit code.
"""

from __future__ import annotations

import argparse
import importlib
import logging
import sys

from vtlearn import __version__
from vtlearn.cli_args import count
from vtlearn.interrupts import import_trimesh, lightning_interrupt_as_keyboard_interrupt
from vtlearn.torch_threads import keep_torch_threads

# one line per feature package; each module defines register(subparsers) and/or register_bench(subparsers)
COMMAND_MODULES: tuple[str, ...] = (
    "vtlearn.models.xavtnet_cli",
    "vtlearn.classical.registration_cli",
    "vtlearn.classical.tracking_cli",
    "vtlearn.sim_data.cli",
    "vtlearn.active.active_cli",
    "vtlearn.models.actor_cli",
    "vtlearn.active.experiments_cli",
    "vtlearn.runtime.runtime_cli",
    "vtlearn.runtime.manipulation_bench",
)


# the distributions whose module name differs from theirs, for the imports `vtlearn info` tries
MODULE_NAMES = {"pytorch-kinematics": "pytorch_kinematics", "scikit-learn": "sklearn"}


def _cmd_info(args: argparse.Namespace) -> int:
    """Versions (``packages``, from the installed distributions) and, under ``import_errors``, any package
    that is installed but does not import, e.g. Open3D without the system's libusb."""
    import json

    from vtlearn.bench_utils import machine_info

    info = machine_info(extra_packages=("pytorch-kinematics", "wandb"))
    errors = {}
    for dist, version in info["packages"].items():
        if version is None:
            continue
        try:
            importlib.import_module(MODULE_NAMES.get(dist, dist))
        except Exception as exc:  # noqa: BLE001 - report, never crash, an info command
            errors[dist] = f"{type(exc).__name__}: {exc}"
    info["import_errors"] = errors
    info["vtlearn"] = __version__
    print(json.dumps(info, indent=2))
    return 0


def _cmd_metrics(args: argparse.Namespace) -> int:
    import json

    from vtlearn.geometry.metrics import chamfer_distance, earth_movers_distance, hausdorff_distance
    from vtlearn.geometry.sampling import random_subsample
    from vtlearn.io import read_geometry

    a = read_geometry(args.a, n_points=args.points, seed=0)
    b = read_geometry(args.b, n_points=args.points, seed=1)
    out = {
        "chamfer": chamfer_distance(a, b),
        "hausdorff": hausdorff_distance(a, b),
        # EMD is O(n^3): evaluated on at most --emd-points points of each cloud
        "emd": earth_movers_distance(
            random_subsample(a, min(len(a), args.emd_points), 0) if len(a) > args.emd_points else a,
            random_subsample(b, min(len(b), args.emd_points), 1) if len(b) > args.emd_points else b,
        ),
        "n_a": len(a),
        "n_b": len(b),
        "units": "input units (metres for vtlearn data)",
    }
    print(json.dumps(out, indent=2))
    return 0


def _cmd_convert(args: argparse.Namespace) -> int:
    from vtlearn.io import read_cloud_with_normals, read_geometry, write_cloud

    src = args.input
    if src.lower().endswith((".obj", ".stl", ".off")) or args.sample:
        pts, nrm = read_geometry(src, n_points=args.points, seed=args.seed), None
    else:
        pts, nrm = read_cloud_with_normals(src)
    write_cloud(args.output, pts, nrm)
    print(f"wrote {len(pts)} points to {args.output}")
    return 0


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="vtlearn",
        description=(
            "Visuo-tactile perception and learning: registration, tracking, recognition, reconstruction."
        ),
    )
    parser.add_argument("--version", action="version", version=f"vtlearn {__version__}")
    parser.add_argument("-v", "--verbose", action="store_true", help="debug logging")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")

    p = sub.add_parser("info", help="versions of vtlearn and its dependencies, as JSON")
    p.set_defaults(func=_cmd_info)

    p = sub.add_parser(
        "metrics", help="Chamfer / Hausdorff / EMD between two clouds or meshes (eq. 8.1/8.6/8.7)"
    )
    p.add_argument("a", help="cloud or mesh file")
    p.add_argument("b", help="cloud or mesh file")
    p.add_argument("--points", type=count(1), default=2048, help="points sampled from a mesh (default 2048)")
    p.add_argument("--emd-points", type=count(1), default=2048, help="subsample size for EMD (default 2048)")
    p.set_defaults(func=_cmd_metrics)

    p = sub.add_parser("convert", help="convert a cloud between formats, or sample a mesh into a cloud")
    p.add_argument("input")
    p.add_argument("output")
    p.add_argument("--sample", action="store_true", help="treat a .ply input as a mesh and sample it")
    p.add_argument("--points", type=count(1), default=2048)
    p.add_argument("--seed", type=count(0), default=0)
    p.set_defaults(func=_cmd_convert)

    bench = sub.add_parser("bench", help="benchmarks: print a table and write JSON")
    bench_sub = bench.add_subparsers(dest="bench", metavar="BENCHMARK")
    bench.set_defaults(func=lambda a: (bench.print_help(), 2)[1])

    for name in COMMAND_MODULES:
        module = importlib.import_module(name)
        if hasattr(module, "register"):
            module.register(sub)
        if hasattr(module, "register_bench"):
            module.register_bench(bench_sub)
    return parser


# output options whose meaning is the same in every command: (flag, what is written, is it a folder)
_OUTPUT_OPTIONS = (("json", "JSON", False), ("figure", "figure", False), ("plot", "plot", False),
                   ("plots", "plots", True), ("out_dir", "figures", True))


def _check_output_options(args: argparse.Namespace) -> None:
    """Refuse a ``--json`` that is a folder (and the like), or a ``--figure``/``--plot`` in a format
    matplotlib cannot write, before the command runs, not after a long bench."""
    from vtlearn.bench_utils import check_figure_path, check_output_path

    for attr, what, folder in _OUTPUT_OPTIONS:
        value = getattr(args, attr, None)
        if isinstance(value, str) and value:
            name = "--" + attr.replace("_", "-")
            if attr in ("figure", "plot"):
                check_figure_path(value, name)
            else:
                check_output_path(value, name, what, folder=folder)


# commands that write shards atomically and skip the finished ones on a rerun
_RESUMABLE_COMMANDS = frozenset({"gen-data", "gen-episodes"})


def _interrupted_message(args: argparse.Namespace) -> str:
    """The one line printed for Ctrl-C instead of a KeyboardInterrupt traceback."""
    command = getattr(args, "command", None) or ""
    if command == "bench" and getattr(args, "bench", None):
        command = f"bench {args.bench}"
    name = f"vtlearn {command}".rstrip()
    if command in _RESUMABLE_COMMANDS:
        return f"{name}: interrupted; finished shards are kept, run the same command again to resume"
    return f"{name}: interrupted"


def _close_progress_bars() -> None:
    """Close the progress bars a Ctrl-C left open (most commands' bars are closed after their loop), so that
    the "interrupted" line starts a line of its own. It imports nothing: with tqdm not loaded, no bar is
    open."""
    std = sys.modules.get("tqdm.std")
    if std is not None:
        for bar in list(getattr(std.tqdm, "_instances", ())):
            bar.close()


def main(argv: list[str] | None = None) -> int:
    try:
        # first, so that building the parser (which imports every command module) finds it imported
        import_trimesh()
        parser = build_parser()
    except KeyboardInterrupt:
        print("vtlearn: interrupted", file=sys.stderr)
        return 130
    args = parser.parse_args(argv)
    logging.basicConfig(
        level=logging.DEBUG if args.verbose else logging.INFO, format="%(levelname)s %(name)s: %(message)s"
    )
    # Lightning prints its INFO lines through its own handler on the "lightning" logger; passed on to the root
    # handler as well, each was printed twice
    logging.getLogger("lightning").propagate = False
    if getattr(args, "func", None) is None:
        parser.print_help()
        return 2
    try:
        # a command's --threads sets torch's thread count for itself; a Python caller gets its own back. A
        # Ctrl-C during a Lightning training in this process ends as KeyboardInterrupt, not Lightning's exit 1
        with keep_torch_threads(), lightning_interrupt_as_keyboard_interrupt():
            _check_output_options(args)
            return int(args.func(args) or 0)
    except (ValueError, FileNotFoundError) as exc:
        print(f"vtlearn: error: {exc}", file=sys.stderr)
        return 2
    except (FileExistsError, IsADirectoryError, NotADirectoryError, PermissionError) as exc:
        # a path argument that names the wrong kind of thing (a file where a folder goes, or the reverse)
        reason = (exc.strerror or str(exc)).lower()
        print(f"vtlearn: error: cannot use {exc.filename}: {reason}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        # Ctrl-C: one line, not a traceback; 130 = 128 + SIGINT, as a shell reports it
        _close_progress_bars()
        print(_interrupted_message(args), file=sys.stderr)
        return 130


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
