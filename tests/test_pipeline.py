"""The end-to-end quickstart (vtlearn.pipeline): configuration checks, skip/resume, a tiny full run."""

import json

import numpy as np
import pytest

from vtlearn import pipeline
from vtlearn.pipeline import QuickstartConfig, run_quickstart, tiny_quickstart_config


def test_config_validation():
    tiny_quickstart_config().validate()
    QuickstartConfig().validate()
    with pytest.raises(ValueError, match="object_category"):
        QuickstartConfig(categories=["mug", "can"]).validate()
    with pytest.raises(ValueError, match="categories"):
        QuickstartConfig(categories=["wineglass"]).validate()
    with pytest.raises(ValueError, match="categories"):
        QuickstartConfig(categories=["wineglass", "teapot"]).validate()
    with pytest.raises(ValueError, match="recon_per_category"):
        QuickstartConfig(recon_per_category=2).validate()
    with pytest.raises(ValueError, match="actor_epochs"):
        QuickstartConfig(actor_epochs=0).validate()
    with pytest.raises(ValueError, match="n_candidates"):
        QuickstartConfig(n_candidates=1).validate()


def test_bad_stop_after_and_changed_config(tmp_path):
    with pytest.raises(ValueError, match="stop_after"):
        run_quickstart(tmp_path, tiny_quickstart_config(), stop_after="deploy")
    (tmp_path / "quickstart_config.json").write_text(json.dumps({"categories": ["mug"]}))
    with pytest.raises(ValueError, match="another configuration"):
        run_quickstart(tmp_path, tiny_quickstart_config(), stop_after="data")


def test_steps_skip_what_exists(tmp_path, monkeypatch):
    """Every step returns 'skipped' and touches nothing when its outputs exist (the resume logic)."""
    cfg = tiny_quickstart_config()
    for kind in ("reconstruction", "crossmodal"):
        (tmp_path / "data" / kind).mkdir(parents=True)
        (tmp_path / "data" / kind / "manifest.json").write_text("{}")
    for name in ("preview.png", "actor.ckpt", "xavtnet.ckpt", "episode.npz"):
        (tmp_path / name).write_bytes(b"x")

    def boom(*a, **k):
        raise AssertionError("a skipped step did work")

    monkeypatch.setattr("vtlearn.sim_data.writer.generate_dataset", boom)
    monkeypatch.setattr("vtlearn.sim_data.preview.write_preview", boom)
    assert pipeline.step_data(cfg, tmp_path) == {
        "reconstruction": "skipped",
        "crossmodal": "skipped",
        "preview": "skipped",
    }
    assert pipeline.step_train(cfg, tmp_path) == {"actor": "skipped", "xavtnet": "skipped"}
    assert pipeline.step_explore(cfg, tmp_path) == {"explore": "skipped"}


def test_explore_step_writes_a_resumable_episode(tmp_path):
    cfg = tiny_quickstart_config()
    r = pipeline.step_explore(cfg, tmp_path)
    assert r["explore"].startswith(f"{cfg.n_actions} actions")
    ep, obj = pipeline._load_episode(tmp_path)
    assert obj.transparent and obj.category == cfg.object_category
    assert ep.n_steps == cfg.n_actions and len(ep.entropy) == cfg.n_actions + 1
    assert len(ep.T_world_sensor) == cfg.n_actions
    assert ep.tactile.all() and len(ep.points) == len(ep.step)


@pytest.mark.slow
def test_tiny_quickstart_end_to_end_and_resume(tmp_path):
    out = tmp_path / "qs"
    s = run_quickstart(out, tiny_quickstart_config())
    for name in ("summary.png", "summary.json", "preview.png", "actor.ckpt", "xavtnet.ckpt", "episode.npz"):
        assert (out / name).is_file(), name
    assert s["true_category"] == "wineglass" and s["predicted_category"] in ("wineglass", "mug")
    assert np.isfinite(s["chamfer_mm"]) and s["chamfer_mm"] > 0
    assert np.isfinite(s["adi_cm"]) and s["adi_cm"] >= 0
    assert sum(s["class_probabilities"].values()) == pytest.approx(1.0, abs=1e-5)
    assert json.loads((out / "summary.json").read_text())["chamfer_mm"] == pytest.approx(s["chamfer_mm"])
    stamps = {n: (out / n).stat().st_mtime_ns for n in ("actor.ckpt", "xavtnet.ckpt", "episode.npz")}
    again = run_quickstart(out, tiny_quickstart_config())
    assert again["steps"]["data"] == {
        "reconstruction": "skipped",
        "crossmodal": "skipped",
        "preview": "skipped",
    }
    assert again["steps"]["train"] == {"actor": "skipped", "xavtnet": "skipped"}
    assert again["steps"]["explore"] == {"explore": "skipped"}
    assert {n: (out / n).stat().st_mtime_ns for n in stamps} == stamps
    assert again["chamfer_mm"] == pytest.approx(s["chamfer_mm"])  # same checkpoint, same episode


def test_quickstart_command_is_registered():
    from vtlearn.cli import build_parser

    args = build_parser().parse_args(["quickstart", "--out", "x", "--tiny", "--n-actions", "4"])
    assert args.func is pipeline._cmd_quickstart and args.tiny and args.n_actions == 4
