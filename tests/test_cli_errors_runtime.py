"""Bad input to `vtlearn runtime`, `bench runtime`, `bench declutter` and the active benches: one line that
names the flag, exit code 2, and no model loading or simulation before the check (so no checkpoints here
except where the mix of --models and an explicit file is the point)."""

import json

import pytest

from vtlearn.cli import main


def _err(argv, capsys) -> str:
    """The error of a command refused by ``main`` (exit 2), or by argparse (``SystemExit(2)``)."""
    capsys.readouterr()
    try:
        code = main(argv)
    except SystemExit as exc:
        code = exc.code
    assert code == 2, argv
    err = capsys.readouterr().err
    assert "Traceback" not in err
    return err


@pytest.fixture(scope="module")
def models(tmp_path_factory):
    """A `vtlearn quickstart --out` directory with tiny checkpoints (as tests/test_runtime.py builds)."""
    from vtlearn.pipeline import run_quickstart, tiny_quickstart_config

    out = tmp_path_factory.mktemp("qs")
    run_quickstart(out, tiny_quickstart_config(), stop_after="train")
    return out


# ---------------------------------------------------------------- 1. --models with explicit files
def test_explicit_model_files_take_precedence_over_models_and_are_checked(models, tmp_path, capsys):
    base = ["runtime", "--models", str(models), "--out", str(tmp_path / "rt")]
    err = _err([*base, "--actor", str(models / "xavtnet.ckpt")], capsys)
    assert "--actor: " in err and "not an ACTOR checkpoint" in err
    err = _err([*base, "--xavtnet", str(models / "actor.ckpt")], capsys)
    assert "--xavtnet: " in err and "not an xAVTNet checkpoint" in err
    err = _err([*base, "--actor", str(tmp_path / "none.ckpt")], capsys)
    assert f"--actor: no file {tmp_path / 'none.ckpt'}" in err
    err = _err([*base, "--class-names", str(tmp_path / "nope.json")], capsys)
    assert f"--class-names: no file {tmp_path / 'nope.json'}" in err
    (tmp_path / "bad.json").write_text(json.dumps({"classes": []}))
    err = _err([*base, "--class-names", str(tmp_path / "bad.json")], capsys)
    assert "--class-names: " in err and "has no 'class_names' list" in err
    (tmp_path / "few.json").write_text(json.dumps({"class_names": ["mug"]}))
    err = _err([*base, "--class-names", str(tmp_path / "few.json")], capsys)
    assert "--class-names: 1 class names but the xAVTNet checkpoint has" in err
    assert not (tmp_path / "rt").exists()  # refused before the run wrote anything
    # the bench has the same flags and the same rules
    err = _err(["bench", "runtime", "--models", str(models), "--class-names", str(tmp_path / "nope.json"),
                "--json", str(tmp_path / "b.json")], capsys)
    assert "--class-names: no file" in err


def test_models_directory_without_a_file_suggests_the_flag(tmp_path, capsys):
    (tmp_path / "qs").mkdir()
    err = _err(["runtime", "--models", str(tmp_path / "qs"), "--out", str(tmp_path / "rt")], capsys)
    assert "--models: " in err and "has no actor.ckpt" in err and "--actor" in err


# ---------------------------------------------------------------- 2. --target / --clutter
@pytest.mark.parametrize("extra, expected", [
    (["--target", "nosuch"], "--target: unknown category 'nosuch'"),
    (["--target", "can"], "--clutter: holds the target category 'can' (--target)"),
    (["--target", "can", "--target-kind", "transparent"],
     "pass a --clutter without it, e.g. --clutter box,bowl"),
    (["--clutter", "teapot"], "--clutter: unknown ['teapot']"),
    (["--clutter", "wineglass,box", "--target", "mug"], "--clutter: ['wineglass'] have no opaque instances"),
    (["--target", "can", "--clutter", "box"],
     "--target can --target-kind transparent: can has no transparent"),
    (["--target", "wineglass", "--target-kind", "opaque"], "wineglass has no opaque instances"),
])
def test_runtime_scene_flags(extra, expected, tmp_path, capsys):
    err = _err(["runtime", "--out", str(tmp_path / "rt"), *extra], capsys)
    assert expected in err
    assert "clutter_categories" not in err and not (tmp_path / "rt").exists()


# ---------------------------------------------------------------- 3. --data / --ckpt of the active benches
def test_active_recognition_data_without_a_dataset(tmp_path, capsys):
    err = _err(["bench", "active-recognition", "--ckpt", str(tmp_path / "x.ckpt"),
                "--data", str(tmp_path / "nodir"), "--json", str(tmp_path / "r.json")], capsys)
    assert f"--data: no manifest.json in {tmp_path / 'nodir'} (no such directory)" in err
    (tmp_path / "ds").mkdir()
    (tmp_path / "ds" / "manifest.json").write_text("{not json")
    err = _err(["bench", "active-recognition", "--ckpt", str(tmp_path / "x.ckpt"),
                "--data", str(tmp_path / "ds"), "--json", str(tmp_path / "r.json")], capsys)
    assert "--data: manifest.json in " in err and "is not readable JSON" in err


@pytest.mark.parametrize("bench", ["active-reconstruction", "active-recognition", "shared-exploration"])
def test_active_benches_name_ckpt(bench, tmp_path, capsys):
    err = _err(["bench", bench, "--ckpt", str(tmp_path / "none.ckpt"), "--json", str(tmp_path / "b.json")],
               capsys)
    assert err.startswith("vtlearn: error: --ckpt: ") and "none.ckpt" in err


@pytest.mark.parametrize("argv, expected", [
    (["bench", "active-reconstruction", "--categories", "can"], "--categories: ['can'] have no transparent"),
    (["bench", "active-reconstruction", "--categories", ","], "--categories: no category given"),
    (["bench", "active-reconstruction", "--strategies", ""], "--strategies: no strategy given"),
    (["bench", "active-recognition", "--categories", "teapot"], "--categories: unknown ['teapot']"),
    (["bench", "active-recognition", "--zeta", "nan"], "--zeta: need a confidence in (0, 1]"),
    (["bench", "shared-exploration", "--opaque", "teapot"], "--opaque: unknown ['teapot']"),
    (["bench", "shared-exploration", "--transparent", "can"], "--transparent: ['can'] have no transparent"),
])
def test_active_bench_lists_checked_before_the_checkpoint(argv, expected, tmp_path, capsys):
    err = _err([*argv, "--ckpt", str(tmp_path / "none.ckpt"), "--json", str(tmp_path / "b.json")], capsys)
    assert expected in err


# ---------------------------------------------------------------- 4. bench declutter --clutter
def test_bench_declutter_clutter_and_policies(tmp_path, capsys):
    out = ["--json", str(tmp_path / "d.json")]
    assert "argument --clutter: must be >= 1, got 0" in _err(["bench", "declutter", "--clutter", "0", *out],
                                                             capsys)
    assert "--clutter: need 1..10 clutter objects per scene, got 11" in _err(
        ["bench", "declutter", "--clutter", "11", *out], capsys)
    assert "--policies: expected some of" in _err(["bench", "declutter", "--policies", "foo", *out], capsys)
    assert not (tmp_path / "d.json").exists()


def test_bench_runtime_strategies_checked_before_models(tmp_path, capsys):
    err = _err(["bench", "runtime", "--strategies", "random_pinch", "--json", str(tmp_path / "b.json")],
               capsys)
    assert "--strategies: expected some of ('active', 'random', 'uniform')" in err


# ---------------------------------------------------------------- 5. float options
@pytest.mark.parametrize("value, expected", [
    ("-1", "need a finite number > 0, got -1.0"),
    ("0", "need a finite number > 0, got 0.0"),
    ("nan", "need a finite number > 0, got nan"),
    ("inf", "need a finite number > 0, got inf"),
    ("abc", "expected a number, got 'abc'"),
])
def test_active_exploration_coverage_radius(value, expected, tmp_path, capsys):
    out = ["--json", str(tmp_path / "e.json")]
    err = _err(["bench", "active-exploration", "--coverage-radius", value, *out], capsys)
    assert f"argument --coverage-radius: {expected}" in err


def test_active_exploration_touches_and_objects(tmp_path, capsys):
    bench = ["bench", "active-exploration", "--json", str(tmp_path / "e.json")]
    assert "argument --touches: must be >= 2, got 1" in _err([*bench, "--touches", "1"], capsys)
    assert "--objects: unknown ['nosuch']" in _err([*bench, "--objects", "nosuch"], capsys)
    assert "--objects: no category given" in _err([*bench, "--objects", ""], capsys)


def test_real_type():
    import argparse

    from vtlearn.cli_args import real

    assert real(0.0, open_low=True)("0.5") == 0.5 and real(0.0, 1.0)("0") == 0.0
    for bad in ("0", "-1", "nan", "inf", "x"):
        with pytest.raises(argparse.ArgumentTypeError):
            real(0.0, open_low=True)(bad)


# ---------------------------------------------------------------- 6. shared-exploration with no objects
def test_shared_exploration_needs_some_object(tmp_path, capsys):
    err = _err(["bench", "shared-exploration", "--ckpt", str(tmp_path / "none.ckpt"), "--opaque", "",
                "--transparent", "", "--json", str(tmp_path / "s.json")], capsys)
    assert "--opaque, --transparent: both empty" in err
    assert not (tmp_path / "s.json").exists()


# ---------------------------------------------------------------- 7. vtlearn runtime --out
def test_runtime_out_that_is_a_file_is_refused_naming_the_flag(tmp_path, capsys):
    (tmp_path / "taken").write_text("x")
    err = _err(["runtime", "--out", str(tmp_path / "taken"), "--models", str(tmp_path / "none")], capsys)
    # checked before --models (and so before any model loads), under the flag's name
    assert err.startswith(f"vtlearn: error: --out: {tmp_path / 'taken'} is a file; need a folder")
    err = _err(["runtime", "--out", str(tmp_path / "taken" / "rt")], capsys)
    assert err.startswith("vtlearn: error: --out: cannot write the runtime outputs to")
