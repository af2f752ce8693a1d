"""Bad input to `vtlearn recognize`, `adapt-bn`, `bench crossmodal` and `bench active-learning`: one line
`vtlearn: error: ...` naming the flag, exit code 2, and (where the check can come first) nothing trained or
written before it."""

import os
from pathlib import Path

import pytest
import yaml

from vtlearn.cli import main

os.environ.setdefault("WANDB_MODE", "disabled")
ROOT = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="module")
def qs(tmp_path_factory):
    """A tiny quickstart's xAVTNet and ACTOR checkpoints and crossmodal dataset (3 visual pool clouds)."""
    from vtlearn.pipeline import run_quickstart, tiny_quickstart_config

    out = tmp_path_factory.mktemp("qs")
    run_quickstart(out, tiny_quickstart_config(), stop_after="train")
    return out


@pytest.fixture
def no_training(monkeypatch):
    """Fail the test if a bench starts a training job."""
    import vtlearn.job_progress as jp

    def refuse(*args, **kwargs):
        raise AssertionError("a training started before the bad argument was refused")

    monkeypatch.setattr(jp, "map_jobs", refuse)


def _error(capsys, argv) -> str:
    """The one error line of ``vtlearn argv``, which must exit with code 2."""
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert err.startswith("vtlearn: error: ") and err.count("\n") == 1 and "Traceback" not in err, err
    return err


def _al_config(tmp_path, data_dir, **active) -> Path:
    cfg = {"model": {"class_path": "vtlearn.models.xavtnet.XAVTNet",
                     "init_args": {"global_dim": 16, "fc_dims": [8, 8], "max_points": 32}},
           "data": {"class_path": "vtlearn.datamodules.ActivePoolDataModule",
                    "init_args": {"data_dir": str(data_dir), "modality": "visual", "batch_size": 4}},
           "trainer": {"max_epochs": 1},
           "active": {"strategies": "entropy,random", "n0": 1, "kappa": 1, "rounds": 1, "mc_passes": 2,
                      **active}}
    path = tmp_path / "al.yaml"
    path.write_text(yaml.safe_dump(cfg))
    return path


# 1. a config of the wrong kind is refused naming --config, before the data or a model is built

@pytest.mark.parametrize("bench", ["crossmodal", "active-learning"])
def test_bench_refuses_an_actor_config(qs, tmp_path, capsys, no_training, bench):
    out = tmp_path / "b.json"
    err = _error(capsys, ["bench", bench, "--config", str(ROOT / "configs/quick/actor.yaml"),
                          "--data", str(qs / "data/crossmodal"), "--seeds", "1", "--json", str(out)])
    assert "--config:" in err and "is an ACTOR config" in err and "needs an xAVTNet config" in err
    assert not out.exists()


def test_bench_refuses_the_other_benchs_config_and_unknown_keys(qs, tmp_path, capsys, no_training):
    data = str(qs / "data/crossmodal")
    err = _error(capsys, ["bench", "active-learning", "--config", str(ROOT / "configs/quick/xavtnet.yaml"),
                          "--data", data, "--json", str(tmp_path / "a.json")])
    assert "--config:" in err and "ActivePoolDataModule" in err
    assert "configs/quick/active_learning.yaml" in err
    err = _error(capsys, ["bench", "crossmodal", "--config", str(ROOT / "configs/quick/active_learning.yaml"),
                          "--data", data, "--json", str(tmp_path / "c.json")])
    assert "--config:" in err and "CrossModalDataModule" in err
    bad = tmp_path / "typo.yaml"  # no class paths, one misspelt key
    bad.write_text(yaml.safe_dump({"model": {"init_args": {"dropuot": 0.5}}}))
    err = _error(capsys, ["bench", "crossmodal", "--config", str(bad), "--data", data,
                          "--json", str(tmp_path / "c.json")])
    assert "--config:" in err and "model.init_args ['dropuot']" in err
    bad.write_text(yaml.safe_dump({"trainer": {"max_epochs": "ten"}}))
    err = _error(capsys, ["bench", "crossmodal", "--config", str(bad), "--data", data,
                          "--json", str(tmp_path / "c.json")])
    assert "--config: trainer.max_epochs" in err


def test_bench_crossmodal_checks_data_and_model_before_training(qs, tmp_path, capsys, no_training):
    data = str(qs / "data/crossmodal")
    cfg = str(ROOT / "configs/quick/xavtnet.yaml")
    for extra, flag in ((["--source-splits", "train,nope"], "--source-splits:"),
                        (["--target-split", "train", "--target-holdout", "0.5"], "--target-holdout:"),
                        (["--target-data", str(tmp_path / "none")], "--target-data:"),
                        (["--variants", ","], "--variants:")):
        err = _error(capsys, ["bench", "crossmodal", "--config", cfg, "--data", data, *extra,
                              "--json", str(tmp_path / "c.json")])
        assert flag in err, (extra, err)
    # the default figure folder beside --json is a file: refused before the trainings, not after them
    (tmp_path / "c").write_text("")
    err = _error(capsys, ["bench", "crossmodal", "--config", cfg, "--data", data,
                          "--json", str(tmp_path / "c.json")])
    assert "--out-dir:" in err and "is a file" in err
    assert not (tmp_path / "c.json").exists()


# 2. adapt-bn --out: a folder, or below a file, is refused before any work; the write leaves no temp file

def test_adapt_bn_refuses_a_folder_or_a_path_below_a_file_as_out(qs, capsys):
    for out in (qs, qs / "actor.ckpt" / "x.ckpt"):
        before = sorted(p.name for p in qs.iterdir())
        err = _error(capsys, ["adapt-bn", "--ckpt", str(qs / "xavtnet.ckpt"), "--data",
                              str(qs / "data/crossmodal"), "--out", str(out)])
        assert "--out:" in err
        assert sorted(p.name for p in qs.iterdir()) == before  # no temp file left beside it
    assert list(qs.parent.glob(f".{qs.name}.tmp-*")) == []


def test_adapt_bn_names_ckpt_for_an_actor_checkpoint(qs, tmp_path, capsys):
    err = _error(capsys, ["adapt-bn", "--ckpt", str(qs / "actor.ckpt"), "--data", str(qs / "data/crossmodal"),
                          "--out", str(tmp_path / "x.ckpt")])
    assert "--ckpt:" in err and "not an xAVTNet checkpoint" in err
    junk = tmp_path / "junk.ckpt"
    junk.write_text("junk")
    err = _error(capsys, ["adapt-bn", "--ckpt", str(junk), "--data", str(qs / "data/crossmodal"),
                          "--out", str(tmp_path / "x.ckpt")])
    assert "--ckpt:" in err
    assert not (tmp_path / "x.ckpt").exists()


# 3. bench active-learning: n0, kappa and rounds against the pool's size before the full-pool trainings

def test_active_learning_checks_n0_against_the_pool_before_training(qs, tmp_path, capsys, no_training):
    cfg = _al_config(tmp_path, qs / "data/crossmodal")
    out = tmp_path / "a.json"
    err = _error(capsys, ["bench", "active-learning", "--config", str(cfg), "--n0", "4", "--json", str(out)])
    assert "--n0: 4 initial labels" in err and "only 3 clouds" in err
    err = _error(capsys, ["bench", "active-learning", "--config", str(cfg), "--n0", "3", "--json", str(out)])
    assert "--n0:" in err  # nothing left to query
    err = _error(capsys, ["bench", "active-learning", "--config", str(cfg), "--kappa", "3",
                          "--json", str(out)])
    assert "--kappa: 3 queries per round" in err
    err = _error(capsys, ["bench", "active-learning", "--config", str(cfg), "--rounds", "3",
                          "--json", str(out)])
    assert "--rounds: n0 + rounds x kappa = 1 + 3 x 1" in err and "need rounds <= 2" in err
    # the same numbers from the config's active section name their key there
    for key, value, what in (("n0", 5, "--config: active.n0"),
                             ("kappa", "2", "--config: active.kappa: need an integer")):
        bad = _al_config(tmp_path, qs / "data/crossmodal", **{key: value})
        err = _error(capsys, ["bench", "active-learning", "--config", str(bad), "--json", str(out)])
        assert what in err
    assert not out.exists()


def test_active_learning_checks_other_options_before_training(qs, tmp_path, capsys, no_training):
    cfg = _al_config(tmp_path, qs / "data/crossmodal")
    out = tmp_path / "a.json"
    err = _error(capsys, ["bench", "active-learning", "--config", str(cfg), "--modality", "sound",
                          "--json", str(out)])
    assert "--modality:" in err
    with pytest.raises(SystemExit) as exc:
        main(["bench", "active-learning", "--config", str(cfg), "--power-beta", "nan", "--json", str(out)])
    assert exc.value.code == 2 and "argument --power-beta" in capsys.readouterr().err
    (tmp_path / "a.png").mkdir()  # the default plot beside --json is a folder
    err = _error(capsys, ["bench", "active-learning", "--config", str(cfg), "--json", str(out)])
    assert "--plot:" in err
    (tmp_path / "x.json").write_text("not json")
    err = _error(capsys, ["bench", "active-learning", "--merge", str(tmp_path / "x.json"),
                          "--json", str(tmp_path / "m.json"), "--plot", str(tmp_path / "m.png")])
    assert "--merge:" in err and "not a JSON file" in err
    assert not out.exists()


# 4. recognize --data needs --index; file-only and data-only options are refused on the other side

def test_recognize_requires_index_with_data(qs, capsys):
    ckpt, data = str(qs / "xavtnet.ckpt"), str(qs / "data/crossmodal")
    err = _error(capsys, ["recognize", "--ckpt", ckpt, "--data", data])
    assert "--index: required with --data" in err
    err = _error(capsys, ["recognize", "--ckpt", ckpt, "--data", data, "--index", "0", "--extent-m", "0.2"])
    assert "--extent-m: only for cloud files" in err
    err = _error(capsys, ["recognize", "--ckpt", ckpt, "--data", data, "--index", "0", "--split", "nope"])
    assert "--split: " in err and "no 'nope' split" in err
    err = _error(capsys, ["recognize", "--ckpt", ckpt, "--data", data, "--index", "0", "--class-names", "a"])
    assert "--class-names: 1 names" in err


def test_recognize_refuses_data_options_with_files_and_bad_numbers(qs, tmp_path, capsys):
    import numpy as np

    ckpt = str(qs / "xavtnet.ckpt")
    cloud = tmp_path / "c.npy"
    np.save(cloud, np.random.default_rng(0).random((40, 3)))
    err = _error(capsys, ["recognize", "--ckpt", ckpt, str(cloud), "--index", "3"])
    assert "--index: only with --data" in err
    err = _error(capsys, ["recognize", "--ckpt", ckpt, str(cloud), "--box-m", "0", "0", "0", "0", "0", "0"])
    assert "--box-m:" in err
    err = _error(capsys, ["recognize", "--ckpt", str(qs / "actor.ckpt"), str(cloud)])
    assert "--ckpt:" in err and "not an xAVTNet checkpoint" in err
    for flag, value in (("--extent-m", "-1"), ("--zeta", "nan"), ("--zeta", "1")):
        with pytest.raises(SystemExit) as exc:
            main(["recognize", "--ckpt", ckpt, str(cloud), flag, value])
        assert exc.value.code == 2 and f"argument {flag}" in capsys.readouterr().err


def test_recognize_names_the_file_of_a_cloud_it_cannot_use(qs, tmp_path, capsys):
    import numpy as np

    ckpt = str(qs / "xavtnet.ckpt")
    good, few, flat = tmp_path / "good.npy", tmp_path / "few.npy", tmp_path / "flat.npy"
    np.save(good, np.random.default_rng(0).random((40, 3)) * 0.1)
    np.save(few, np.zeros((1, 3)))
    np.save(flat, np.full((10, 3), 0.2))
    # before: "clouds[1]: ..." and "clouds[0]: ...", the position in an internal list, not the file
    err = _error(capsys, ["recognize", "--ckpt", ckpt, str(good), str(few)])
    assert f"{few}: " in err and "at least 3 required" in err and "clouds[" not in err
    err = _error(capsys, ["recognize", "--ckpt", ckpt, str(flat)])
    assert f"{flat}: " in err and "coincide" in err and "clouds[" not in err
