"""The closed-loop benchmark commands on tiny budgets with small untrained networks (outputs, not quality)."""

import json

import pytest
import torch

from vtlearn.cli import main

TINY = ["--objects-per-category", "1", "--candidates", "6", "--cells", "12"]


def _save(model, path):
    torch.save({"state_dict": model.state_dict(), "hyper_parameters": dict(model.hparams)}, path)
    return str(path)


@pytest.fixture(scope="module")
def ckpts(tmp_path_factory):
    from vtlearn.models.actor import ACTOR
    from vtlearn.models.xavtnet import XAVTNet

    torch.manual_seed(0)
    d = tmp_path_factory.mktemp("ckpt")
    actor = ACTOR(
        num_points=64,
        encoder_channels=(16, 16, 32, 32),
        fc_channels=32,
        deconv_channels=(16, 16, 8, 8),
        deconv_strides=(2, 2, 2, 2, 4),
    )
    xav = XAVTNet(num_classes=12, global_dim=32, fc_dims=[16, 8], da_method="none")
    return {"actor": _save(actor, d / "actor.ckpt"), "xavtnet": _save(xav, d / "xavtnet.ckpt")}


def test_active_reconstruction_bench(ckpts, tmp_path):
    out = tmp_path / "rec.json"
    rc = main(
        [
            "bench",
            "active-reconstruction",
            "--ckpt",
            ckpts["actor"],
            "--categories",
            "wineglass",
            "--actions",
            "3",
            "--json",
            str(out),
            *TINY,
        ]
    )
    assert rc == 0 and out.with_suffix(".png").is_file()
    r = json.loads(out.read_text())
    assert set(r["summary"]) == {"active", "active_raycast", "random", "uniform"}
    for s in r["summary"].values():
        assert len(s["cd_mm_mean"]) == 3
    assert r["actions"] == [1, 2, 3] and r["thesis"]["cd_mm_at_20"]["active"] == 20.0
    assert len(r["per_object"]) == 1 and len(r["per_object"][0]["random"]["cd_mm"]) == 3
    assert set(r["paired_at_max_actions"]) == {"active vs random", "active vs uniform"}
    assert r["machine"]["cpu_count"] >= 1 and r["machine"]["torch"]  # what it ran on, as every bench JSON
    # the box-fit criterion (beyond the thesis) on other held-out objects
    rc = main(["bench", "active-reconstruction", "--ckpt", ckpts["actor"], "--categories", "wineglass",
               "--actions", "3", "--gain-mode", "box_fit", "--strategies", "active,random,random_pinch",
               "--object-seed", "5", "--json", str(out), *TINY])
    r2 = json.loads(out.read_text())
    assert rc == 0 and set(r2["summary"]) == {"active", "random", "random_pinch"}
    assert set(r2["paired_at_max_actions"]) == {"active vs random", "active vs random_pinch"}
    assert set(r2["per_object"][0]["random_pinch"]["kinds"][1:]) == {"pinch"}
    assert (r2["gain_mode"], r2["object_seed"]) == ("box_fit", 5) and r2["objects"] != r["objects"]


def test_active_recognition_bench(ckpts, tmp_path):
    out = tmp_path / "recog.json"
    rc = main(
        [
            "bench",
            "active-recognition",
            "--ckpt",
            ckpts["xavtnet"],
            "--categories",
            "mug",
            "--max-actions",
            "10",
            "--gain-mode",
            "raycast",
            "--recognition-gain",
            "--recognition-top-m",
            "2",
            "--recognition-templates",
            "2",
            "--no-novelty-gain",
            "--json",
            str(out),
            *TINY,
        ]
    )
    assert rc == 0 and out.with_suffix(".png").is_file()
    r = json.loads(out.read_text())
    assert set(r["summary"]) == {"active", "random", "uniform", "active_recognition"}
    for s in r["summary"].values():
        assert 1 <= s["actions_mean"] <= 10 and 0 <= s["accuracy_after_10"] <= 1
    assert len(r["per_object"][0]["active"]["confidence"]) == 10
    pairs = {"active vs random", "uniform vs random", "active_recognition vs random", "active vs uniform",
             "active_recognition vs uniform"}
    assert set(r["paired_actions"]) == pairs
    q = r["paired_actions"]["active vs random"]
    a, b = r["per_object"][0]["active"]["actions"], r["per_object"][0]["random"]["actions"]
    assert (q["pairs"], q["lower"], q["higher"]) == (1, int(a < b), int(a > b))
    assert q["wilcoxon_p"] is None  # one object: no test


def test_paired_vs_baseline_hand_case():
    from vtlearn.active.experiments_cli import paired_vs_baseline

    q = paired_vs_baseline([1, 2, 3, 4, 5, 6, float("nan")], [2, 3, 4, 5, 6, 6, 1.0])
    assert (q["lower"], q["higher"], q["ties"], q["pairs"]) == (5, 0, 1, 6)  # the NaN pair is left out
    assert q["mean_diff"] == pytest.approx(-5 / 6)
    # scipy drops the zero difference and has five equal ranks of one sign: exact p = 2 / 2**5
    assert q["wilcoxon_p"] == pytest.approx(0.0625)
    assert paired_vs_baseline([1, 2], [1, 2])["wilcoxon_p"] is None
    with pytest.raises(ValueError, match="same length"):
        paired_vs_baseline([1, 2], [1, 2, 3])


def test_shared_exploration_bench(ckpts, tmp_path):
    out = tmp_path / "shared.json"
    rc = main(
        [
            "bench",
            "shared-exploration",
            "--ckpt",
            ckpts["actor"],
            "--opaque",
            "mug",
            "--transparent",
            "wineglass",
            "--views",
            "1",
            "--touches-opaque",
            "1",
            "--touches-transparent",
            "3",
            "--strategies",
            "active,uniform",
            "--gain-mode",
            "probabilistic",
            "--restarts",
            "0",
            "--json",
            str(out),
            *TINY,
        ]
    )
    assert rc == 0 and out.with_suffix(".png").is_file()
    r = json.loads(out.read_text())
    s = r["summary"]["active"]
    assert s["opaque_cd_mm_vision"]["n"] == 1 and s["opaque_cd_mm_visuotactile"]["n"] == 1
    assert s["touch_gain_percent"] is not None and len(s["transparent_cd_mm_curve"]) == 3
    assert r["transparent_gain"] == "box_fit"  # the default on touch-only transparent objects


def test_bench_bad_input(ckpts, tmp_path, capsys):
    assert main(["bench", "active-reconstruction", "--ckpt", ckpts["actor"], "--strategies", "greedy"]) == 2
    assert "strategies" in capsys.readouterr().err
    assert main(["bench", "active-recognition", "--ckpt", ckpts["xavtnet"], "--zeta", "1.5"]) == 2
    assert "zeta" in capsys.readouterr().err
    # random pinches need an action space with pinches and no views
    assert main(["bench", "active-recognition", "--ckpt", ckpts["xavtnet"],
                 "--strategies", "random_pinch"]) == 2
    assert main(["bench", "active-reconstruction", "--ckpt", ckpts["actor"], "--no-pinch",
                 "--strategies", "random_pinch"]) == 2
    assert capsys.readouterr().err.count("random_pinch") == 2
    assert main(["bench", "active-recognition", "--ckpt", ckpts["xavtnet"], "--categories", "teapot"]) == 2
    assert "categories" in capsys.readouterr().err
    assert main(["bench", "active-reconstruction", "--ckpt", ckpts["xavtnet"]]) == 2  # not an ACTOR
    assert "ckpt" in capsys.readouterr().err
    assert main(["bench", "active-recognition", "--ckpt", ckpts["xavtnet"], "--max-actions", "3"]) == 2
    assert "--max-actions: need >= 10 (the table reads the accuracy at 10 actions), got 3" in (
        capsys.readouterr().err)
    for flag in ("--recognition-top-m", "--recognition-templates"):  # refused by argparse, with the flag
        with pytest.raises(SystemExit) as exc:
            main(["bench", "active-recognition", "--ckpt", ckpts["xavtnet"], "--recognition-gain", flag, "0"])
        assert exc.value.code == 2 and f"argument {flag}: must be >= 1" in capsys.readouterr().err
    assert main(["bench", "active-recognition", "--ckpt", ckpts["actor"]]) == 2  # not an xAVTNet
    assert "ckpt" in capsys.readouterr().err
    assert main(["bench", "active-reconstruction", "--ckpt", str(tmp_path / "none.ckpt")]) == 2
