import importlib
import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from _interrupt import SIGINT_AS_IN_A_TERMINAL

from vtlearn import __version__
from vtlearn.cli import build_parser, main
from vtlearn.io import write_cloud


def test_help_lists_subcommands():
    text = build_parser().format_help()
    for cmd in ("info", "metrics", "convert", "bench"):
        assert cmd in text


def test_help_does_not_load_torch_or_open3d():
    # building every subcommand's parser must stay light: `vtlearn --help` took ~9 s when it loaded them
    code = (
        "import sys; from vtlearn.cli import build_parser; build_parser(); "
        "print(sorted(m for m in ('torch', 'open3d', 'pybullet', 'lightning') if m in sys.modules))"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "[]"


def test_version_via_console_entry():
    out = subprocess.run([sys.executable, "-m", "vtlearn.cli", "--version"], capture_output=True, text=True)
    assert out.returncode == 0 and __version__ in out.stdout


def test_metrics_command(tmp_path, capsys):
    a = write_cloud(tmp_path / "a.xyz", np.array([[0.0, 0, 0]]))
    b = write_cloud(tmp_path / "b.xyz", np.array([[1.0, 0, 0], [3.0, 0, 0]]))
    assert main(["metrics", str(a), str(b)]) == 0
    out = json.loads(capsys.readouterr().out)
    assert out["chamfer"] == 3.0 and out["hausdorff"] == 3.0


def test_convert_and_clear_errors(tmp_path, capsys):
    a = write_cloud(tmp_path / "a.npy", np.random.default_rng(0).random((10, 3)))
    assert main(["convert", str(a), str(tmp_path / "a.ply")]) == 0
    assert main(["convert", str(tmp_path / "missing.ply"), str(tmp_path / "x.ply")]) == 2
    assert "missing.ply" in capsys.readouterr().err


def test_default_logger_falls_back_to_csv(tmp_path, monkeypatch):
    from lightning.pytorch.loggers import CSVLogger

    from vtlearn.logging_utils import default_logger

    monkeypatch.setenv("WANDB_MODE", "disabled")
    assert isinstance(default_logger(save_dir=str(tmp_path)), CSVLogger)


def test_csv_list_strips_items_and_drops_empty_ones():
    from vtlearn.bench_utils import csv_list

    assert csv_list(" active, random,,uniform ,") == ["active", "random", "uniform"]
    assert csv_list("") == [] and csv_list(" , ") == []


def test_significance_helpers_match_hand_computations_and_say_when_undefined():
    """Welch: [1,2,3] vs [4,5,6] has t = -3 / sqrt(2/3) with 4 degrees of freedom, p = 0.0213. Wilcoxon:
    five positive differences are the most extreme of 2^5 sign patterns, two-sided p = 2/32."""
    from scipy.stats import t

    from vtlearn.bench_utils import welch_p, wilcoxon_p

    assert welch_p([1, 2, 3], [4, 5, 6]) == pytest.approx(2 * t.sf(3 / np.sqrt(2 / 3), 4))
    assert welch_p([1, 2, 3], [4, 5, 6]) == pytest.approx(0.0213, abs=1e-4)
    assert wilcoxon_p([1, 2, 3, 4, 5]) == pytest.approx(2 / 32)
    assert wilcoxon_p([1, -2, 3, -4, 5]) > 0.5
    assert welch_p([1.0], [2.0, 3.0]) is None and welch_p([2, 2], [2, 2]) is None
    assert wilcoxon_p([0, 0, 0]) is None and wilcoxon_p([1.0]) is None


def test_format_table_prints_none_as_a_dash():
    from vtlearn.bench_utils import format_table

    rows = [{"m": "artreg", "p": None}, {"m": "icp", "p": 0.0123}, {"m": "pf"},
            {"m": "fgr", "p": float("nan")}, {"m": "go", "p": float("inf")}]
    text = format_table(rows, ["m", "p"], "t").splitlines()
    assert text[0] == "### t"
    # a value that does not exist is "-" whether it is None or NaN (a mean over no runs), as null in the JSON
    assert [r.split("|")[2].strip() for r in text[3:]] == ["-", "0.012", "", "-", "-"]


def test_sample_std_is_the_ddof1_spread_and_zero_for_one_value():
    from vtlearn.bench_utils import sample_std

    assert sample_std([1.0, 2.0, 3.0]) == pytest.approx(1.0)
    assert sample_std(np.array([4.0, 8.0])) == pytest.approx(np.std([4.0, 8.0], ddof=1))
    assert sample_std([7.5]) == 0.0
    for bad in ([], [[1.0, 2.0]]):
        with pytest.raises(ValueError, match="values: need a non-empty 1-D sample"):
            sample_std(bad)


def test_machine_info_records_the_package_versions_and_none_for_a_missing_one(monkeypatch):
    """A bench JSON records the versions that seeded runs depend on, so figures that drift across
    sessions can be traced to the packages that changed."""
    import vtlearn.bench_utils as bu

    monkeypatch.setattr(bu, "RECORDED_PACKAGES", ("numpy", "no-such-package-vtlearn"))
    info = bu.machine_info()
    assert info["packages"] == {"numpy": np.__version__, "no-such-package-vtlearn": None}
    assert info["torch"] and info["cpu_count"] >= 1
    # the CPU that decides whether a seeded training reproduces bit for bit
    import torch

    assert info["cpu_capability"] == torch.backends.cpu.get_cpu_capability()
    assert isinstance(info["cpu_model"], str) and info["cpu_model"]
    # numpy's SIMD targets: a target numpy is told to leave off is no longer listed
    simd = info["numpy_simd"]
    assert isinstance(simd, list) and all(isinstance(t, str) for t in simd)
    if simd:
        import os

        code = "from vtlearn.bench_utils import numpy_simd; print(','.join(numpy_simd()))"
        env = dict(os.environ, NPY_DISABLE_CPU_FEATURES=simd[0])
        out = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True,
                             check=True)
        assert simd[0] not in out.stdout.strip().split(",")


def test_cpu_model_reads_proc_cpuinfo_and_falls_back(monkeypatch, tmp_path):
    import builtins

    import vtlearn.bench_utils as bu

    fake = tmp_path / "cpuinfo"
    fake.write_text("processor\t: 0\nvendor_id\t: X\nmodel name\t: Test CPU 9000 @ 3 GHz\n")
    real_open = builtins.open

    def fake_open(path, *a, **k):
        return real_open(fake if path == "/proc/cpuinfo" else path, *a, **k)

    monkeypatch.setattr(builtins, "open", fake_open)
    assert bu.cpu_model() == "Test CPU 9000 @ 3 GHz"
    fake.write_text("processor\t: 0\n")  # no model name: platform.processor(), or "unknown"
    monkeypatch.setattr(bu.platform, "processor", lambda: "")
    assert bu.cpu_model() == "unknown"


def _parser_actions(parser, path=("vtlearn",)):
    import argparse

    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            for name, sub in action.choices.items():
                yield from _parser_actions(sub, (*path, name))
        else:
            yield path, action


def test_every_integer_option_states_its_minimum_and_its_default_meets_it():
    """No option parses a bare int: each says whether 0 means something (a seed, an index, "0: all") or
    the count must be >= 1, so a negative count is refused by argparse before any work starts."""
    found = 0
    for path, action in _parser_actions(build_parser()):
        assert action.type is not int, f"{' '.join(path)} {action.option_strings}: use vtlearn.cli_args.count"
        minimum = getattr(action.type, "minimum", None)
        if minimum is None:
            continue
        found += 1
        default = action.default if isinstance(action.default, list | tuple) else [action.default]
        assert all(v is None or v >= minimum for v in default), (path, action.option_strings)
    assert found > 100  # the walk reaches every subcommand's options


@pytest.mark.parametrize("argv, flag", [
    (["bench", "crossmodal", "--seeds", "-1"], "--seeds"),
    (["bench", "active-learning", "--rounds", "-1"], "--rounds"),
    (["bench", "registration", "--trials", "0"], "--trials"),
    (["metrics", "a.ply", "b.ply", "--points", "-5"], "--points"),
    (["gen-data", "crossmodal", "--out", "x", "--workers", "-1"], "--workers"),
    (["bench", "crossmodal", "--seed", "-2"], "--seed"),
    (["bench", "crossmodal", "--seeds", "two"], "--seeds"),
])
def test_a_bad_count_is_refused_with_the_flag_before_any_work(argv, flag, capsys):
    with pytest.raises(SystemExit) as exc:
        main(argv)
    assert exc.value.code == 2
    err = capsys.readouterr().err
    assert f"argument {flag}:" in err and ("must be >=" in err or "expected an integer" in err)


def test_count_type_parses_and_bounds():
    import argparse

    from vtlearn.cli_args import count

    assert count(0)("0") == 0 and count(1)("7") == 7
    for bad in ("0", "-3", "1.5", ""):
        with pytest.raises(argparse.ArgumentTypeError):
            count(1)(bad)


def test_lightning_info_lines_are_printed_once():  # a fresh interpreter importing lightning: ~5 s
    code = ("import logging; from vtlearn.cli import main; main(['info']); import lightning.pytorch; "
            "logging.getLogger('lightning.pytorch.utilities.rank_zero').info('once-only-marker')")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert (out.stdout + out.stderr).count("once-only-marker") == 1


def test_info_lists_each_package_once_and_reports_one_that_does_not_import(capsys, monkeypatch):
    import importlib

    real = importlib.import_module

    def fake(name, *a, **k):  # Open3D installed but missing the system's libusb
        if name == "open3d":
            raise OSError("libusb-1.0.so.0: cannot open shared object file")
        return real(name, *a, **k)

    monkeypatch.setattr(importlib, "import_module", fake)
    assert main(["info"]) == 0
    info = json.loads(capsys.readouterr().out)
    wanted = {"numpy", "lightning", "open3d", "pybullet", "pytorch-kinematics", "wandb"}
    assert wanted <= set(info["packages"])
    assert all(isinstance(v, str) for k, v in info["packages"].items() if k != "scikit-learn")
    assert not {"numpy", "open3d", "pybullet"} & set(info)  # versions live under "packages" only
    assert list(info["import_errors"]) == ["open3d"] and "libusb" in info["import_errors"]["open3d"]


def _interrupt(args):
    raise KeyboardInterrupt


@pytest.mark.parametrize("argv, handler, expected", [
    (["gen-data", "crossmodal", "--out", "ds"], ("vtlearn.sim_data.cli", "_cmd_gen_data"),
     "vtlearn gen-data: interrupted; finished shards are kept, run the same command again to resume"),
    (["gen-episodes", "--source", "ds", "--out", "ep"],
     ("vtlearn.active.experiments_cli", "_cmd_gen_episodes"),
     "vtlearn gen-episodes: interrupted; finished shards are kept, run the same command again to resume"),
    (["info"], ("vtlearn.cli", "_cmd_info"), "vtlearn info: interrupted"),
])
def test_ctrl_c_prints_one_line_and_exits_130(argv, handler, expected, capsys, monkeypatch):
    import importlib

    monkeypatch.setattr(importlib.import_module(handler[0]), handler[1], _interrupt)
    assert main(argv) == 130
    captured = capsys.readouterr()
    assert captured.err == expected + "\n" and "Traceback" not in captured.out + captured.err


def _train_until_interrupted(args):
    import lightning as L
    from lightning.pytorch.demos.boring_classes import BoringModel

    class CtrlC(L.Callback):  # what the default SIGINT handler raises, two steps in
        def on_train_batch_end(self, trainer, *_):
            if trainer.global_step == 2:
                raise KeyboardInterrupt

    L.Trainer(max_epochs=1, callbacks=[CtrlC()], logger=False, enable_checkpointing=False,
              enable_progress_bar=False, enable_model_summary=False).fit(BoringModel())
    return 0


def test_ctrl_c_in_a_lightning_training_ends_as_any_other_interrupted_command(capsys, monkeypatch):
    # Lightning shuts the training down and calls sys.exit(1); main used to pass that exit on
    monkeypatch.setattr(importlib.import_module("vtlearn.cli"), "_cmd_info", _train_until_interrupted)
    assert main(["info"]) == 130
    assert capsys.readouterr().err.endswith("vtlearn info: interrupted\n")


def _interrupt_in_a_progress_bar(args):
    from tqdm.auto import tqdm

    bar = tqdm(total=5, desc="work")
    bar.update(2)
    raise KeyboardInterrupt


def test_ctrl_c_closes_the_open_progress_bars_before_its_line(capsys, monkeypatch):
    # the bar's line ended without a newline, and the "interrupted" line was printed on the end of it
    monkeypatch.setattr(importlib.import_module("vtlearn.cli"), "_cmd_info", _interrupt_in_a_progress_bar)
    assert main(["info"]) == 130
    lines = capsys.readouterr().err.splitlines()
    assert lines[-1] == "vtlearn info: interrupted" and "2/5" in lines[-2]


def test_ctrl_c_in_a_bench_names_the_benchmark(tmp_path, capsys, monkeypatch):
    import vtlearn.sim_data.bench as sim_bench

    monkeypatch.setattr(sim_bench, "run", _interrupt)
    assert main(["bench", "sim", "--json", str(tmp_path / "sim.json")]) == 130
    assert capsys.readouterr().err == "vtlearn bench sim: interrupted\n"


# a child interpreter that sends itself a Ctrl-C the moment trimesh imports its path module, i.e. inside one
# of the `except BaseException` blocks around trimesh's optional imports, runs an entry point's main, and
# prints its exit code and the names in trimesh's modules that hold the KeyboardInterrupt in place of what
# they import
_CTRL_C_IN_TRIMESH_IMPORT = """
import os, signal, sys

class Interrupter:
    def find_spec(self, name, path=None, target=None):
        if name == "trimesh.path":
            sys.meta_path.remove(self)
            os.kill(os.getpid(), signal.SIGINT)
        return None

sys.path.insert(0, {root!r})
sys.meta_path.insert(0, Interrupter())
from {module} import main
rc = main({argv!r})
from trimesh.exceptions import ExceptionWrapper
held = [f"{{name}}.{{key}}" for name, mod in list(sys.modules.items()) if name.startswith("trimesh")
        for key, value in vars(mod).items()
        if type(value) is ExceptionWrapper
        and object.__getattribute__(value, "exception")[0] is KeyboardInterrupt]
print(rc, held)
"""


@pytest.mark.parametrize("module, argv, line", [
    ("vtlearn.cli", ["metrics", "missing_a.ply", "missing_b.ply"], "vtlearn: interrupted"),
    ("train", ["fit", "--config", "missing.yaml"], "train.py: interrupted"),  # imports lightning: ~5 s
])
def test_ctrl_c_during_the_trimesh_import_stops_the_command_and_leaves_trimesh_whole(module, argv, line,
                                                                                      tmp_path):
    # without the hold, trimesh stored the KeyboardInterrupt in place of faces_to_path and the command ran on
    root = str(Path(__file__).resolve().parents[1])
    code = SIGINT_AS_IN_A_TERMINAL + _CTRL_C_IN_TRIMESH_IMPORT.format(root=root, module=module, argv=argv)
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd=tmp_path)
    assert out.stdout.strip() == "130 []", out.stderr
    assert out.stderr.strip().splitlines()[-1] == line


def test_sigint_held_delivers_a_ctrl_c_after_the_block_to_the_handler_before_it():
    import os
    import signal

    from vtlearn.interrupts import sigint_held

    # as in a terminal, whatever this test run inherited (a run started in the background ignores SIGINT)
    mask = signal.pthread_sigmask(signal.SIG_UNBLOCK, {signal.SIGINT})
    previous = signal.signal(signal.SIGINT, signal.default_int_handler)
    try:
        reached_the_end = False
        with pytest.raises(KeyboardInterrupt):
            with sigint_held():
                os.kill(os.getpid(), signal.SIGINT)
                reached_the_end = True
        assert reached_the_end and signal.getsignal(signal.SIGINT) is signal.default_int_handler
        signal.signal(signal.SIGINT, signal.SIG_IGN)
        with sigint_held():  # an ignored Ctrl-C stays ignored
            os.kill(os.getpid(), signal.SIGINT)
        assert signal.getsignal(signal.SIGINT) == signal.SIG_IGN
    finally:
        signal.signal(signal.SIGINT, previous)
        signal.pthread_sigmask(signal.SIG_SETMASK, mask)


def test_sigint_held_off_the_main_thread_runs_the_block_as_it_is():
    import threading

    from vtlearn.interrupts import import_trimesh

    outcome = []

    def work():  # signal.signal raises ValueError outside the main thread
        try:
            import_trimesh()
            outcome.append("imported")
        except Exception as exc:  # noqa: BLE001 - the test reports whatever it was
            outcome.append(repr(exc))

    thread = threading.Thread(target=work)
    thread.start()
    thread.join()
    assert outcome == ["imported"]


def test_gen_data_help_explains_every_option_and_states_its_default(capsys):
    import argparse

    actions = [a for path, a in _parser_actions(build_parser())
               if path == ("vtlearn", "gen-data") and not isinstance(a, argparse._HelpAction)]
    assert len(actions) > 20
    for action in actions:
        assert action.help, f"gen-data {action.option_strings or action.dest}: no help text"
        if action.option_strings and not action.required and action.default is not False:
            assert "default" in action.help, f"gen-data {action.option_strings}: no default in its help"
    with pytest.raises(SystemExit):
        main(["gen-data", "--help"])
    text = " ".join(capsys.readouterr().out.split())
    for shown in ("--sections SECTIONS angular resolution", "(default: 48)", "(default: 0.7,0.15,0.15)",
                  "(default: xela_4x4)", "instances per category (default: 10)"):
        assert shown in text
