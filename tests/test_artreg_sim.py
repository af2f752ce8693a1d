"""Tests for the procedural articulated objects, sequences and the tracking CLI (thesis 6.3.4-6.3.5)."""

import json

import numpy as np
import pytest

from vtlearn.classical.artreg import ArtRegTracker
from vtlearn.classical.tracking_cli import _xy_error, run_tracker
from vtlearn.sim_data.articulated import (
    CATEGORIES,
    articulation_sequence,
    look_at_45,
    make_articulated,
    motion_sequence,
    to_urdf,
)


@pytest.mark.parametrize("category", CATEGORIES)
def test_urdf_has_the_thesis_joints(category):
    spec = make_articulated(category, 0)
    urdf = to_urdf(spec)
    expected = {
        "dishwasher": ("revolute", 1),
        "glasses": ("revolute", 2),
        "drawer": ("prismatic", 1),
        "blade": ("prismatic", 1),
    }[category]
    assert urdf.count(f'type="{expected[0]}"') == expected[1] == spec.n_joints
    with pytest.raises(ValueError, match="category"):
        make_articulated("fridge", 0)


def test_look_at_45_is_45_degrees_top_down():
    T = look_at_45(np.array([0.1, 0.2, 0.0]), 1.0)
    z = T[:3, 2]  # optical axis
    assert np.degrees(np.arcsin(-z[2])) == pytest.approx(45.0)
    np.testing.assert_allclose(T[:3, :3] @ T[:3, :3].T, np.eye(3), atol=1e-12)
    # the target is on the optical axis, 1 m ahead
    np.testing.assert_allclose(T[:3, 3] + z, [0.1, 0.2, 0.0], atol=1e-12)


def test_articulation_sequence_clouds_lie_on_the_parts():
    seq = articulation_sequence("drawer", seed=3, n_frames=3, width=160, height=120, noise=False)
    assert seq.T_world_part.shape == (3, 2, 4, 4) and len(seq.scenes) == 3
    # the drawer slides along the cabinet's -y axis by the normalised joint value
    assert seq.joint_values[0, 0] == 0.0 and seq.joint_values[-1, 0] > 0.0
    moved = seq.T_world_part[-1, 1, :3, 3] - seq.T_world_part[0, 1, :3, 3]
    np.testing.assert_allclose(seq.T_world_part[-1, 0], seq.T_world_part[0, 0])
    assert np.linalg.norm(moved) > 0.0
    from scipy.spatial import cKDTree

    model = np.concatenate(
        [m @ T[:3, :3].T + T[:3, 3] for m, T in zip(seq.models, seq.T_world_part[-1], strict=True)]
    )
    d, _ = cKDTree(model).query(seq.scenes[-1])
    assert np.median(d) < 0.005  # noiseless depth lies on the link surfaces (model spacing 5 mm)
    assert seq.scenes[-1][:, 2].min() > -1e-3  # the table is removed


def test_motion_sequence_multiple_with_tactile_and_artreg_tracks_it():
    seq = motion_sequence("multiple", seed=1, n_frames=12, n_objects=3, width=200, height=150)
    assert seq.T_world_part.shape == (12, 3, 4, 4)
    assert any(t is not None and len(t) > 0 for t in seq.tactile)
    est, _ = run_tracker(ArtRegTracker, seq.models, seq.T_world_part[0], seq.scenes, seq.tactile)
    err = _xy_error(est[1:], seq.T_world_part[1:], seq.models)
    assert err.mean() < 0.02  # the thesis' 2 cm bound


def test_track_cli_round_trip(tmp_path, capsys):
    from vtlearn.cli import main
    from vtlearn.io import write_cloud

    rng = np.random.default_rng(0)
    model = rng.uniform(-0.05, 0.05, size=(300, 3)) * [1.0, 0.6, 0.4]
    write_cloud(tmp_path / "model.ply", model)
    frames = tmp_path / "frames"
    frames.mkdir()
    for k in range(5):
        shifted = model + [0.002 * k, 0.0, 0.0]
        write_cloud(frames / f"{k:03d}.ply", shifted)
    out = tmp_path / "track.json"
    rc = main(["track", "--models", str(tmp_path / "model.ply"), "--frames", str(frames), "--json", str(out)])
    assert rc == 0
    res = json.loads(out.read_text())
    assert res["n_frames"] == 5 and len(res["frames"]) == 5
    T_last = np.array(res["frames"][-1]["T_world_object"][0])
    assert abs(T_last[0, 3] - 0.008) < 0.002
    assert main(["track", "--models", str(tmp_path / "model.ply"), "--frames", str(frames),
                 "--max-points", "2", "--json", str(out)]) == 2
    assert "--max-points: need 0 (all points) or >= 3 per part, got 2" in capsys.readouterr().err



def test_track_cli_names_the_extra_a_method_needs(tmp_path, capsys, monkeypatch):
    """--method filterreg without probreg installed: exit 2 and the extra to install, not a KeyError."""
    import vtlearn.classical.tracking_baselines as baselines
    from vtlearn.cli import main

    monkeypatch.setattr(baselines, "HAS_PROBREG", False)
    assert main(["track", "--models", str(tmp_path / "m.ply"), "--frames", str(tmp_path),
                 "--method", "filterreg"]) == 2
    assert "--method: 'filterreg' needs the optional probreg extra" in capsys.readouterr().err


def test_bench_tracking_reports_ratios_and_thesis_and_plots_beside_the_json(tmp_path, capsys, monkeypatch):
    """The tiniest bench: every baseline as a multiple of ArtReg, ArtReg against the thesis's figures, the
    JSON and both plots written (into the JSON's folder unless --plots names another), their paths printed."""
    import vtlearn.classical.tracking_cli as tracking_cli
    from vtlearn.cli import main

    # the 2 x 1000-point speed runs are a fixed cost the tables below do not need
    monkeypatch.setattr(tracking_cli, "_speed", lambda n, cap: {"wall_hz": 1.0, "cpu_hz": 1.0,
                                                                 "points_per_part": n, "cap": cap})
    js = tmp_path / "bench" / "tracking.json"
    assert main(["bench", "tracking", "--methods", "artreg", "icp", "--trials", "1", "--frames", "2",
                 "--seq-trials", "1", "--seq-frames", "3", "--width", "80", "--height", "60",
                 "--json", str(js)]) == 0
    res = json.loads(js.read_text())
    a = res["articulated"]["all"]
    assert a["icp"]["ratio_to_artreg"] == pytest.approx(a["icp"]["mean_cm"] / a["artreg"]["mean_cm"])
    assert a["artreg"]["thesis_mean_cm"] == 7.23
    assert a["artreg"]["ratio_to_thesis"] == pytest.approx(a["artreg"]["mean_cm"] / 7.23)
    seq = res["sequences"]["multiple"]
    assert seq["artreg"]["thesis_cm"] == 1.512 and seq["icp"]["thesis_cm"] is None
    assert seq["icp"]["ratio_to_artreg"] == pytest.approx(
        seq["icp"]["xy_error"]["mean_cm"] / seq["artreg"]["xy_error"]["mean_cm"])
    plots = [js.parent / "tracking_violin.png", js.parent / "tracking_trajectories.png"]
    assert all(p.is_file() for p in plots) and res["plots"] == [str(p) for p in plots]
    out = capsys.readouterr().out
    assert "| x ArtReg |" in out and "| x thesis |" in out and f"wrote {js}, {plots[0]}" in out
