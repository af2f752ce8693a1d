"""Bad input to the classical commands (track, bench tracking / registration / active-touch, hand-eye) is
refused up front with one ``vtlearn: error:`` line (or an argparse error) that names the flag, exit code 2."""

import argparse
import json
import warnings
from pathlib import Path

import numpy as np
import pytest

from vtlearn.cli import main
from vtlearn.io import write_cloud

RNG = np.random.default_rng(0)
CLOUD = RNG.normal(scale=0.05, size=(40, 3))


@pytest.fixture
def track_inputs(tmp_path):
    """A one-part model and a folder of two frames (its cloud, slightly moved)."""
    model = write_cloud(tmp_path / "part0.xyz", CLOUD)
    frames = tmp_path / "frames"
    for i in range(2):
        write_cloud(frames / f"f{i}.xyz", CLOUD + 0.001 * i)
    return tmp_path, ["track", "--models", str(model), "--frames", str(frames)]


@pytest.fixture
def hand_eye_inputs(tmp_path):
    """One visual view, its end-effector pose and a tactile cloud: a hand-eye call's files."""
    write_cloud(tmp_path / "v.xyz", CLOUD)
    write_cloud(tmp_path / "t.xyz", CLOUD[:20])
    np.savetxt(tmp_path / "poses.txt", np.eye(4))
    return tmp_path, ["hand-eye", "--visual", str(tmp_path / "v.xyz"), "--poses", str(tmp_path / "poses.txt"),
                      "--tactile", str(tmp_path / "t.xyz")]


def _error(capsys) -> str:
    err = capsys.readouterr().err
    assert err.startswith("vtlearn: error: ") and "Traceback" not in err
    return err


# ---------------------------------------------------------------------------------- 1. bench tracking
def test_bench_tracking_refuses_a_method_whose_extra_is_missing(tmp_path, capsys, monkeypatch):
    import vtlearn.classical.tracking_baselines as baselines

    monkeypatch.setattr(baselines, "HAS_PROBREG", False)
    js = tmp_path / "x.json"
    assert main(["bench", "tracking", "--methods", "artreg", "filterreg", "--trials", "1", "--frames", "3",
                 "--seq-trials", "1", "--seq-frames", "3", "--json", str(js)]) == 2
    assert "--methods: 'filterreg' needs the optional probreg extra" in _error(capsys)
    assert not js.exists()


# ---------------------------------------------------------------------------------- 2. track --tactile
def test_track_refuses_a_missing_tactile_folder(track_inputs, capsys):
    tmp, argv = track_inputs
    assert main([*argv, "--tactile", str(tmp / "nodir")]) == 2
    err = _error(capsys)
    assert "--tactile:" in err and "not a directory" in err


def test_track_refuses_a_tactile_folder_that_matches_no_frame(track_inputs, capsys):
    tmp, argv = track_inputs
    write_cloud(tmp / "tactile" / "other.xyz", CLOUD[:5])
    assert main([*argv, "--tactile", str(tmp / "tactile")]) == 2
    err = _error(capsys)
    assert "--tactile:" in err and "frame names" in err


def test_track_takes_an_empty_tactile_folder(track_inputs, capsys):
    """A sequence in which no frame had contact leaves its tactile folder empty: tracked from vision alone."""
    tmp, argv = track_inputs
    (tmp / "tactile_none").mkdir()
    assert main([*argv, "--tactile", str(tmp / "tactile_none"), "--method", "icp"]) == 0


def test_track_takes_tactile_clouds_for_some_frames(track_inputs, capsys):
    """Contact is intermittent: a frame without a tactile cloud is tracked from vision alone."""
    tmp, argv = track_inputs
    write_cloud(tmp / "tactile" / "f1.xyz", CLOUD[:5] + 0.001)
    assert main([*argv, "--tactile", str(tmp / "tactile"), "--method", "icp"]) == 0
    assert "2 frames" in capsys.readouterr().out


# ---------------------------------------------------------------------------------- 3. integer lists
@pytest.mark.parametrize("argv, flag, what", [
    (["bench", "registration", "--sizes", "20,abc"], "--sizes", "expected an integer, got 'abc'"),
    (["bench", "registration", "--sizes", "0"], "--sizes", "must be >= 3, got 0"),
    (["bench", "registration", "--sizes", "20,2"], "--sizes", "must be >= 3, got 2"),
    (["bench", "registration", "--sizes", ","], "--sizes", "comma-separated list of integers >= 3"),
    (["bench", "active-touch", "--faces", "abc"], "--faces", "expected an integer, got 'abc'"),
    (["bench", "active-touch", "--faces", "1"], "--faces", "must be >= 4, got 1"),
    (["bench", "active-touch", "--candidates", "10,0"], "--candidates", "must be >= 1, got 0"),
])
def test_an_integer_list_is_checked_by_argparse(argv, flag, what, capsys):
    with pytest.raises(SystemExit) as exc:
        main(argv)
    assert exc.value.code == 2
    err = capsys.readouterr().err
    assert f"argument {flag}:" in err and what in err


def test_counts_type_parses_and_bounds():
    from vtlearn.cli_args import counts

    assert counts(3)("20, 40,80,") == [20, 40, 80] and counts(1).minimum == 1
    for bad in ("", ",", "2", "20,x", "1.5"):
        with pytest.raises(argparse.ArgumentTypeError):
            counts(3)(bad)


# ---------------------------------------------------------------------------------- 4. track --init-poses
@pytest.mark.parametrize("name, content, what", [
    ("bad.json", "{bad", "cannot read"),
    ("missing.npy", None, "no file at"),
    ("t24.json", json.dumps(np.eye(4)[:2].tolist()), "got shape (2, 4)"),
    ("two.json", json.dumps([np.eye(4).tolist()] * 2), "need one pose as"),  # one model, two poses
    ("scaled.json", json.dumps(np.diag([2.0, 2.0, 2.0, 1.0]).tolist()), "not a proper rotation"),
])
def test_track_init_poses_errors_name_the_flag(track_inputs, capsys, name, content, what):
    tmp, argv = track_inputs
    if content is not None:
        (tmp / name).write_text(content)
    assert main([*argv, "--init-poses", str(tmp / name)]) == 2
    err = _error(capsys)
    assert "--init-poses" in err and what in err


def test_track_reads_init_poses_as_npy(track_inputs, capsys):
    tmp, argv = track_inputs
    np.save(tmp / "T0.npy", np.eye(4)[None])
    assert main([*argv, "--init-poses", str(tmp / "T0.npy"), "--method", "icp"]) == 0


# ---------------------------------------------------------------------------------- 5. hand-eye
def test_hand_eye_local_method_needs_init(hand_eye_inputs, capsys):
    _, argv = hand_eye_inputs
    assert main([*argv, "--method", "icp"]) == 2
    err = _error(capsys)
    assert "--init: method icp needs an initial T_E_C guess" in err and "T_E_C_init" not in err


def test_hand_eye_init_must_be_one_4x4(hand_eye_inputs, capsys):
    tmp, argv = hand_eye_inputs
    np.save(tmp / "bad.npy", np.eye(3))
    assert main([*argv, "--init", str(tmp / "bad.npy")]) == 2
    err = _error(capsys)
    assert "--init: need one pose as" in err and "got shape (3, 3)" in err


def test_hand_eye_names_a_degenerate_tactile_cloud(hand_eye_inputs, capsys):
    tmp, argv = hand_eye_inputs
    write_cloud(tmp / "col.xyz", np.c_[np.linspace(0, 1, 10), np.zeros(10), np.zeros(10)])
    argv[argv.index("--tactile") + 1] = str(tmp / "col.xyz")
    assert main(argv) == 2
    err = _error(capsys)
    assert "--tactile: points are degenerate" in err and "scene" not in err


def test_hand_eye_needs_one_pose_per_view(hand_eye_inputs, capsys):
    tmp, argv = hand_eye_inputs
    np.savetxt(tmp / "poses2.txt", np.vstack([np.eye(4), np.eye(4)]))
    argv[argv.index("--poses") + 1] = str(tmp / "poses2.txt")
    assert main(argv) == 2
    assert "--poses: need one T_W_E per --visual file (1), got 2" in _error(capsys)


# ---------------------------------------------------------------------------------- 6. empty --poses
def test_hand_eye_empty_poses_file_is_one_line_without_a_numpy_warning(hand_eye_inputs, capsys):
    tmp, argv = hand_eye_inputs
    (tmp / "empty.txt").write_text("")
    argv[argv.index("--poses") + 1] = str(tmp / "empty.txt")
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        assert main(argv) == 2
    assert not [w for w in caught if "loadtxt" in str(w.message)]
    err = _error(capsys)
    assert err.count("\n") == 1 and "--poses:" in err and "holds no numbers" in err


def test_pose_files_with_four_decimals_are_read_as_exact_rotations(track_inputs, tmp_path, capsys):
    """Robot logs print poses with a few decimals: the rotation is then off by up to 5e-5, which a file may
    be (it is snapped to the nearest rotation); one off by more is refused, naming the flag."""
    from scipy.spatial.transform import Rotation

    from vtlearn.io import read_poses

    T = np.eye(4)
    T[:3, :3] = Rotation.from_rotvec([0.3, -0.2, 0.5]).as_matrix()
    T[:3, 3] = [0.1, 0.2, 0.3]
    (tmp_path / "T.json").write_text(json.dumps(np.round(T, 4).tolist()))
    R = read_poses(str(tmp_path / "T.json"), "--init-poses", n=1)[0, :3, :3]
    assert np.allclose(R.T @ R, np.eye(3), atol=1e-12) and np.allclose(R, T[:3, :3], atol=1e-4)
    T[0, 0] += 0.01
    (tmp_path / "bad.json").write_text(json.dumps(T.tolist()))
    with pytest.raises(ValueError, match=r"--init-poses: the 3x3 block is not a proper rotation"):
        read_poses(str(tmp_path / "bad.json"), "--init-poses", n=1)
    (tmp_path / "bad2.json").write_text(json.dumps([np.eye(4).tolist(), T.tolist()]))
    with pytest.raises(ValueError, match=r"--init-poses \(pose 1\): the 3x3 block is not a proper rotation"):
        read_poses(str(tmp_path / "bad2.json"), "--init-poses")


def test_track_leaves_a_csv_beside_the_frames_alone(track_inputs, capsys):
    """A timestamps.csv beside the frame clouds is metadata, not a frame (.csv is also a cloud format)."""
    tmp, argv = track_inputs
    (tmp / "frames" / "timestamps.csv").write_text("frame,t\n0,0.0\n1,0.1\n")
    assert main([*argv, "--method", "icp"]) == 0
    assert "\n2 frames, " in capsys.readouterr().out


# ---------------------------------------------------------------------------------- 7. track reads once
def test_track_reads_each_frame_file_once(track_inputs, capsys, monkeypatch):
    """.csv is a cloud format: .csv frames are tracked, each read once (the read that tells a cloud from
    metadata is the read that tracks it), and only a .csv that is no cloud is skipped."""
    import vtlearn.io

    tmp, argv = track_inputs
    frames = tmp / "csv_frames"
    for i in range(3):
        write_cloud(frames / f"f{i}.csv", CLOUD + 0.001 * i)
    (frames / "timestamps.csv").write_text("frame,t\n0,0.0\n")
    argv[argv.index("--frames") + 1] = str(frames)
    reads, read_cloud = [], vtlearn.io.read_cloud
    monkeypatch.setattr(vtlearn.io, "read_cloud",
                        lambda p, **kw: reads.append(Path(p).name) or read_cloud(p, **kw))
    assert main([*argv, "--method", "icp"]) == 0
    assert sorted(n for n in reads if n != "part0.xyz") == ["f0.csv", "f1.csv", "f2.csv", "timestamps.csv"]
    out = capsys.readouterr().out
    assert "skipped timestamps.csv" in out and "\n3 frames, " in out


def test_track_keeps_the_estimate_through_a_frame_without_points(track_inputs, capsys):
    """A frame saved as a (0, 3) array (the object out of view) is an empty frame, not an error mid-run."""
    tmp, argv = track_inputs
    np.save(tmp / "frames" / "f2.npy", np.zeros((0, 3)))  # sorted after f0.xyz, f1.xyz
    (tmp / "tactile").mkdir()
    np.save(tmp / "tactile" / "f2.npy", np.zeros((0, 3)))  # no contact either
    js = tmp / "track.json"
    assert main([*argv, "--tactile", str(tmp / "tactile"), "--json", str(js)]) == 0
    res = json.loads(js.read_text())
    assert res["n_frames"] == 3 and res["frames"][2]["frame"] == "f2.npy"
    np.testing.assert_allclose(res["frames"][2]["T_world_object"], res["frames"][1]["T_world_object"])


@pytest.mark.parametrize("what, flag", [("frames", "--frames f0.xyz"), ("models", "--models")])
def test_track_refuses_clouds_in_millimetres(track_inputs, capsys, what, flag):
    tmp, argv = track_inputs
    if what == "frames":
        write_cloud(tmp / "mm" / "f0.xyz", 1000.0 * CLOUD)
        argv[argv.index("--frames") + 1] = str(tmp / "mm")
    else:
        argv[argv.index("--models") + 1] = str(write_cloud(tmp / "mm.xyz", 1000.0 * CLOUD))
    assert main(argv) == 2
    err = capsys.readouterr().err.splitlines()[-1]  # after the progress bar of the frames read so far
    assert err.startswith(f"vtlearn: error: {flag}") and "millimetres" in err


def test_track_figure_shows_the_tracked_path(track_inputs, capsys):
    tmp, argv = track_inputs
    fig = tmp / "figs" / "track.png"
    assert main([*argv, "--method", "icp", "--figure", str(fig)]) == 0
    assert fig.is_file() and f"wrote {fig}" in capsys.readouterr().out


# ---------------------------------------------------------------------------------- 8. register
@pytest.fixture
def register_inputs(tmp_path):
    write_cloud(tmp_path / "m.xyz", CLOUD)
    write_cloud(tmp_path / "s.xyz", CLOUD[:20])
    return tmp_path, ["register", "--model", str(tmp_path / "m.xyz"), "--scene", str(tmp_path / "s.xyz")]


@pytest.mark.parametrize("name, content, what", [
    ("empty.npy", np.zeros((0, 3)), "point cloud is empty"),
    ("nan.npy", np.where(np.arange(20)[:, None] == 3, np.nan, CLOUD[:20]), "NaN"),
    ("wide.npy", CLOUD[:, :2], "k >= 3 columns"),
    ("missing.xyz", None, "no such file"),
    ("two.xyz", CLOUD[:2], "only 2 points"),
    ("line.xyz", np.outer(np.linspace(0, 0.1, 10), [1.0, 0.0, 0.0]), "degenerate"),
    ("mm.xyz", 1000.0 * CLOUD[:20], "millimetres"),
])
def test_register_errors_name_the_flag(register_inputs, capsys, name, content, what):
    tmp, argv = register_inputs
    if content is not None:
        np.save(tmp / name, content) if name.endswith(".npy") else np.savetxt(tmp / name, content)
    argv[argv.index("--scene") + 1] = str(tmp / name)
    assert main(argv) == 2
    err = _error(capsys)
    assert err.count("\n") == 1 and "--scene" in err and what in err


def test_register_estimate_scale_solves_the_scale_the_unit_check_would_refuse(register_inputs, capsys):
    """A model in millimetres against a scene in metres is a scale of 1000 that S-TIQF estimates (eq. 5.12):
    with --estimate-scale it is solved, not refused as mixed units."""
    tmp, argv = register_inputs
    argv[argv.index("--model") + 1] = str(write_cloud(tmp / "m_mm.xyz", 1000.0 * CLOUD))
    argv[argv.index("--scene") + 1] = str(tmp / "m.xyz")  # all of it: eq. 5.12 compares bounding boxes
    assert main([*argv, "--method", "stiqf", "--estimate-scale", "--json"]) == 0
    scale = np.asarray(json.loads(capsys.readouterr().out)["scale"])
    np.testing.assert_allclose(scale, 1e-3, rtol=0.05)
    assert main([*argv, "--method", "stiqf"]) == 2  # without it, the 1000x is refused
    assert "millimetres" in _error(capsys)


def test_register_writes_json_and_figure_files(register_inputs, capsys):
    tmp, argv = register_inputs
    js, fig = tmp / "out" / "reg.json", tmp / "out" / "reg.png"
    assert main([*argv, "--method", "tiqf", "--json", str(js), "--figure", str(fig)]) == 0
    out = capsys.readouterr().out
    assert f"wrote {js}" in out and f"wrote {fig}" in out and fig.is_file()
    assert json.loads(js.read_text())["n_scene"] == 20
    assert main([*argv, "--method", "tiqf", "--json"]) == 0  # --json alone prints it
    assert json.loads(capsys.readouterr().out)["method"] == "tiqf"


# ---------------------------------------------------------------------------------- 9. hand-eye units, --out
def test_hand_eye_refuses_poses_in_millimetres(hand_eye_inputs, capsys):
    tmp, argv = hand_eye_inputs
    T = np.eye(4)
    T[:3, 3] = [300.0, 0.0, 400.0]  # mm
    np.savetxt(tmp / "poses_mm.txt", T)
    argv[argv.index("--poses") + 1] = str(tmp / "poses_mm.txt")
    assert main(argv) == 2
    err = _error(capsys)
    assert err.count("\n") == 1 and err.startswith("vtlearn: error: --poses:") and "millimetres" in err


def test_hand_eye_refuses_tactile_in_millimetres(hand_eye_inputs, capsys):
    tmp, argv = hand_eye_inputs
    write_cloud(tmp / "t_mm.xyz", 1000.0 * CLOUD[:20])
    argv[argv.index("--tactile") + 1] = str(tmp / "t_mm.xyz")
    assert main(argv) == 2
    err = _error(capsys)
    assert "--tactile" in err and "millimetres" in err


def test_hand_eye_out_goes_into_a_new_folder_and_a_folder_is_refused_first(hand_eye_inputs, capsys):
    tmp, argv = hand_eye_inputs
    out = tmp / "calib" / "T_E_C.npy"
    assert main([*argv, "--out", str(out)]) == 0
    assert np.load(out).shape == (4, 4) and f"wrote {out}" in capsys.readouterr().out
    assert main([*argv, "--out", str(tmp)]) == 2
    assert "--out:" in _error(capsys)
    assert "T_E_C =" not in capsys.readouterr().out  # refused before the calibration ran
