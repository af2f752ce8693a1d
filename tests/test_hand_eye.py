"""In-situ visuo-tactile hand-eye calibration (thesis 5.2.5, eq. 5.19-5.22)."""

import os

import numpy as np
import pybullet_data
import pytest
import trimesh

from vtlearn.classical.hand_eye import average_transforms, hand_eye_from_registration, in_situ_hand_eye
from vtlearn.geometry import random_pose


def _rz(deg):
    a = np.radians(deg)
    T = np.eye(4)
    T[:2, :2] = [[np.cos(a), -np.sin(a)], [np.sin(a), np.cos(a)]]
    return T


def _errors(T, X):
    R = T[:3, :3].T @ X[:3, :3]
    return np.linalg.norm(T[:3, 3] - X[:3, 3]), np.degrees(np.arccos(np.clip((np.trace(R) - 1) / 2, -1, 1)))


@pytest.fixture(scope="module")
def scene():
    """The Stanford bunny (15 cm) fixed on the table, a true hand-eye matrix X and world-frame samples."""
    mesh = trimesh.load(os.path.join(pybullet_data.getDataPath(), "bunny.obj"), force="mesh")
    mesh.apply_scale(0.15 / mesh.extents.max())
    T_W_O = np.eye(4)
    T_W_O[:3, 3] = [0.5, 0.1, 0.05]
    X = random_pose(seed=3)
    X[:3, 3] = [0.02, -0.03, 0.08]

    def sample(n, seed):
        P_O = np.asarray(trimesh.sample.sample_surface(mesh, n, seed=seed)[0])
        return P_O @ T_W_O[:3, :3].T + T_W_O[:3, 3]

    return X, sample


def _camera_cloud(P_W, T_W_E, X):
    T_W_C = T_W_E @ X
    return (P_W - T_W_C[:3, 3]) @ T_W_C[:3, :3]  # p_C = T_W_C^-1 p_W


def test_noiseless_refinement_recovers_the_calibration_exactly(scene):
    """Tactile contacts on the visual samples and a nominal calibration 1.4 cm off: TIQF solves eq. 5.21
    exactly, and eq. 5.20 gives X."""
    X, sample = scene
    P_W = sample(1500, 1)
    tactile = P_W[np.random.default_rng(0).choice(len(P_W), 60, replace=False)]
    T_W_E = random_pose(seed=10)
    T_W_E[:3, 3] = [0.3, 0.0, 0.5]
    nominal = X.copy()
    nominal[:3, 3] += [0.01, -0.005, 0.008]
    res = in_situ_hand_eye(_camera_cloud(P_W, T_W_E, X), tactile, T_W_E, method="tiqf", T_E_C_init=nominal)
    dt, dr = _errors(res.T_E_C, X)
    assert dt < 1e-6 and dr < 1e-5
    np.testing.assert_allclose(res.T_W_C[0], T_W_E @ X, atol=1e-6)
    assert res.spread_m == 0.0 and res.rmse[0] < 1e-6


def test_global_stiqf_noiseless_and_noisy_multi_view(scene):
    X, sample = scene
    rng = np.random.default_rng(1)
    P_W = sample(1500, 2)
    T_W_E = random_pose(seed=11)
    T_W_E[:3, 3] = [0.3, 0.0, 0.5]
    tactile = P_W[rng.choice(len(P_W), 60, replace=False)]
    res = in_situ_hand_eye(_camera_cloud(P_W, T_W_E, X), tactile, T_W_E)  # no initial guess at all
    dt, dr = _errors(res.T_E_C, X)
    assert dt < 2e-3 and dr < 0.5, (dt, dr)  # measured 0.5-0.7 mm, 0.04-0.12 deg (tangent-plane pairs)
    # noisy: 1 mm noise on both clouds, tactile points not on the visual samples, three views averaged
    tactile = sample(60, 7) + rng.normal(0, 1e-3, (60, 3))
    poses = np.stack([random_pose(seed=20 + v) for v in range(3)])
    poses[:, :3, 3] = [[0.3, 0.1 * v, 0.5] for v in range(3)]
    views = [_camera_cloud(sample(1500, 30 + v) + rng.normal(0, 1e-3, (1500, 3)), poses[v], X)
             for v in range(3)]
    res = in_situ_hand_eye(views, tactile, poses)
    dt, dr = _errors(res.T_E_C, X)
    assert dt < 10e-3 and dr < 3.0, (dt, dr)  # measured 4.1 mm, 1.1 deg
    assert res.T_E_C_views.shape == (3, 4, 4) and res.spread_m > 0


def test_average_transforms_and_eq_5_20_hand_cases():
    T = _rz(10)
    T[:3, 3] = [1.0, 2.0, 3.0]
    U = _rz(-10)
    U[:3, 3] = [3.0, 2.0, 1.0]
    mean = average_transforms(np.stack([T, U]))
    np.testing.assert_allclose(mean[:3, :3], np.eye(3), atol=1e-12)  # +-10 deg about z
    np.testing.assert_allclose(mean[:3, 3], [2.0, 2.0, 2.0])
    np.testing.assert_allclose(average_transforms(T[None]), T, atol=1e-12)
    # eq. 5.20: T_E_C = T_W_E^-1 T_W_C
    T_W_E = _rz(30)
    T_W_E[:3, 3] = [0.1, 0.2, 0.3]
    X = _rz(-45)
    X[:3, 3] = [0.0, 0.0, 0.05]
    np.testing.assert_allclose(hand_eye_from_registration(T_W_E @ X, T_W_E), X, atol=1e-12)


def test_bad_input_is_refused_by_name(scene):
    X, sample = scene
    P = sample(100, 3)
    T = np.eye(4)
    with pytest.raises(ValueError, match="method"):
        in_situ_hand_eye(P, P, T, method="icp")
    with pytest.raises(ValueError, match="T_E_C_init"):
        in_situ_hand_eye(P, P, T, method="tiqf")
    with pytest.raises(ValueError, match="tactile_points_W"):
        in_situ_hand_eye(P, np.zeros((0, 3)), T)
    bad = P.copy()
    bad[0, 0] = np.nan
    with pytest.raises(ValueError, match=r"visual_points_C\[0\]"):
        in_situ_hand_eye(bad, P, T)
    with pytest.raises(ValueError, match="T_W_E: need one"):
        in_situ_hand_eye([P, P], P, T)
    with pytest.raises(ValueError, match=r"T_W_E\[0\]"):
        in_situ_hand_eye(P, P, 2.0 * T)
    with pytest.raises(ValueError, match="visual_points_C: no view"):
        in_situ_hand_eye([], P, T)
    with pytest.raises(ValueError, match="T: need shape"):
        average_transforms(np.zeros((0, 4, 4)))


def test_hand_eye_command_and_bench_smoke(tmp_path, scene, capsys):
    import json

    from vtlearn.cli import main
    from vtlearn.io import write_cloud

    X, sample = scene
    P_W = sample(800, 4)
    T_W_E = random_pose(seed=12)
    T_W_E[:3, 3] = [0.3, 0.0, 0.5]
    write_cloud(tmp_path / "v.ply", _camera_cloud(P_W, T_W_E, X))
    write_cloud(tmp_path / "t.ply", P_W[::20])
    np.save(tmp_path / "poses.npy", T_W_E[None], allow_pickle=False)
    np.save(tmp_path / "init.npy", X, allow_pickle=False)
    out = tmp_path / "X.npy"
    assert main(["hand-eye", "--visual", str(tmp_path / "v.ply"), "--poses", str(tmp_path / "poses.npy"),
                 "--tactile", str(tmp_path / "t.ply"), "--method", "tiqf",
                 "--init", str(tmp_path / "init.npy"), "--out", str(out)]) == 0
    assert "T_E_C = (the camera in the end-effector frame, metres)" in capsys.readouterr().out
    np.testing.assert_allclose(np.load(out), X, atol=1e-5)  # tactile on the visual samples: exact
    assert main(["hand-eye", "--visual", str(tmp_path / "v.ply"), "--poses", str(tmp_path / "none.npy"),
                 "--tactile", str(tmp_path / "t.ply")]) == 2
    assert "--poses" in capsys.readouterr().err
    js = tmp_path / "he.json"
    assert main(["bench", "hand-eye", "--meshes", "bunny", "--trials", "1", "--methods", "stiqf,tiqf",
                 "--json", str(js)]) == 0
    res = json.loads(js.read_text())
    assert set(res["summary"]) == {"nominal", "stiqf", "tiqf"}
    printed = capsys.readouterr().out  # the peers against S-TIQF and everything against the thesis bounds
    assert "| pos x S-TIQF |" in printed and "| pos x thesis |" in printed and f"wrote {js}" in printed
    assert res["summary"]["nominal"]["position_mm_median"] == pytest.approx(20.0)
    assert js.with_suffix(".png").is_file()
    assert main(["bench", "hand-eye", "--meshes", "bunny", "--methods", "teaser", "--json", str(js)]) == 2
    assert "methods" in capsys.readouterr().err
