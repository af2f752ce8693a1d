"""Tests for the ArtReg tracker (thesis ch.6, Algorithm 4, eq. 6.11)."""

import numpy as np
import pytest

from vtlearn.classical.artreg import ArtRegTracker, se3_phi, se3_phi_inv
from vtlearn.classical.ukf import ManifoldUKF
from vtlearn.geometry import se3_exp, se3_log


def _box_cloud(n=600, size=(0.12, 0.08, 0.05), seed=0):
    """Points on the surface of a box centred at the origin (an asymmetric, trackable shape)."""
    rng = np.random.default_rng(seed)
    s = np.asarray(size) / 2
    pts = rng.uniform(-1, 1, size=(n, 3)) * s
    axis = rng.integers(0, 3, size=n)
    pts[np.arange(n), axis] = np.sign(rng.uniform(-1, 1, size=n)) * s[axis]
    return pts


def _pose(t, rotvec):
    return se3_exp(np.concatenate([t, rotvec]))


def test_static_pose_converges_to_sample_mean_with_1_over_n_covariance():
    # A static pose on SE(3) observed directly in log coordinates with Gaussian noise. With a vague
    # prior and Q = 0 the posterior must approach the sample mean and its covariance must shrink as 1/n.
    rng = np.random.default_rng(0)
    xi_true = np.array([0.3, -0.2, 0.5, 0.05, -0.03, 0.02])
    sig = np.array([0.02, 0.02, 0.02, 0.01, 0.01, 0.01])
    zs = xi_true + rng.normal(size=(200, 6)) * sig
    ukf = ManifoldUKF(
        f=lambda T, u, w: T @ se3_exp(w),
        h=lambda states: np.stack([se3_log(T) for T in states]),
        phi=se3_phi,
        phi_inv=se3_phi_inv,
        Q=np.zeros((6, 6)),
        R=np.diag(sig**2),
        state0=np.eye(4),
        P0=np.eye(6) * 1.0,
    )
    traces = {}
    for k, z in enumerate(zs, start=1):
        ukf.step(z)
        if k in (50, 200):
            np.testing.assert_allclose(se3_log(ukf.state), zs[:k].mean(0), atol=2e-4)
            traces[k] = np.trace(ukf.P)
    # the tangent at the estimate and the log coordinates differ by a Jacobian close to identity here
    assert traces[50] / traces[200] == pytest.approx(4.0, rel=0.05)
    assert traces[200] == pytest.approx(np.sum(sig**2) / 200, rel=0.1)


def _ade(model, T_est, T_gt):
    return np.linalg.norm(
        (model @ T_est[:3, :3].T + T_est[:3, 3]) - (model @ T_gt[:3, :3].T + T_gt[:3, 3]), axis=1
    ).mean()


def test_noiseless_static_object_is_exact():
    model = _box_cloud()
    T0 = _pose([0.4, 0.1, 0.05], [0.0, 0.0, 0.3])
    scene = model @ T0[:3, :3].T + T0[:3, 3]
    # start 1 cm / 2 deg off; on noiseless data the filter must converge onto the true pose
    tracker = ArtRegTracker(
        [model], [T0 @ _pose([0.01, -0.005, 0.0], [0.0, 0.0, 0.035])], max_points_per_part=None
    )
    for _ in range(30):
        (T_est,) = tracker.step(scene)
    assert _ade(model, T_est, T0) < 1e-6


def test_constant_velocity_tracked_with_bounded_lag():
    rng = np.random.default_rng(1)
    model = _box_cloud()
    v = np.array([0.003, 0.0015, 0.0])  # m per frame (9 cm/s at 30 Hz)
    w = np.array([0.0, 0.0, 0.01])  # rad per frame
    T0 = _pose([0.3, 0.0, 0.025], [0, 0, 0])
    tracker = ArtRegTracker([model], [T0])
    errs = []
    for k in range(60):
        T_gt = _pose(T0[:3, 3] + k * v, k * w)
        vis = model[model[:, 2] > -0.02]  # a partial view: the bottom face is never seen
        scene = vis @ T_gt[:3, :3].T + T_gt[:3, 3] + rng.normal(scale=0.002, size=vis.shape)
        (T_est,) = tracker.step(scene)
        errs.append(np.linalg.norm(T_est[:3, 3] - T_gt[:3, 3]))
    assert max(errs) < 0.01  # bounded lag: below 1 cm at every frame
    assert np.mean(errs[20:]) < 0.005


def test_two_parts_with_tactile_points_and_empty_frames():
    rng = np.random.default_rng(2)
    a, b = _box_cloud(seed=3), _box_cloud(size=(0.06, 0.06, 0.1), seed=4)
    Ta, Tb = _pose([0.0, 0.0, 0.05], [0, 0, 0]), _pose([0.2, 0.0, 0.05], [0, 0, 0.5])
    tracker = ArtRegTracker([a, b], [Ta, Tb])
    for k in range(20):
        Tb_k = Tb @ _pose([0.002 * k, 0.0, 0.0], [0, 0, 0])
        scene = np.concatenate([a @ Ta[:3, :3].T + Ta[:3, 3], b @ Tb_k[:3, :3].T + Tb_k[:3, 3]])
        scene += rng.normal(scale=0.001, size=scene.shape)
        tactile = b[:5] @ Tb_k[:3, :3].T + Tb_k[:3, 3]
        poses = tracker.step(scene, tactile_cloud=tactile)
    assert np.linalg.norm(poses[0][:3, 3] - Ta[:3, 3]) < 0.003
    assert np.linalg.norm(poses[1][:3, 3] - Tb_k[:3, 3]) < 0.005
    assert tracker.last_counts[1] > 0 and len(tracker.covariances) == 2
    before = [p.copy() for p in tracker.poses]
    P_before = tracker.covariances[1]
    after = tracker.step(np.zeros((0, 3)))
    for p0, p1 in zip(before, after, strict=True):
        np.testing.assert_allclose(p0, p1)
    assert np.trace(tracker.covariances[1]) > np.trace(P_before)  # only predicted: uncertainty grows


def test_bad_input_raises():
    model = _box_cloud(50)
    with pytest.raises(ValueError, match=r"models\[0\]"):
        ArtRegTracker([model[:2]], [np.eye(4)])
    with pytest.raises(ValueError, match="T_world_object0"):
        ArtRegTracker([model], [np.eye(4), np.eye(4)])
    with pytest.raises(ValueError, match="models"):
        ArtRegTracker([], [])
    tracker = ArtRegTracker([model], [np.eye(4)])
    with pytest.raises(ValueError, match="scene_cloud"):
        tracker.step(np.full((10, 3), np.nan))
    with pytest.raises(ValueError, match="scene_cloud"):
        tracker.step(np.zeros((10, 2)))
    with pytest.raises(ValueError, match="scene_cloud is empty"):
        tracker.step(np.zeros((0, 3)), allow_empty=False)
    with pytest.raises(ValueError, match="tactile_cloud"):
        tracker.step(model, tactile_cloud=np.zeros((3, 4)))


def test_clouds_in_millimetres_warn_once_instead_of_silently_standing_still():
    """A user's clouds in mm: every point falls outside the 0.05 m gate, so the filter only predicts. That
    is said once, with the likely cause; clouds in metres with the same motion raise nothing."""
    import warnings

    m = _box_cloud()
    for scale, expect_warning in ((1000.0, True), (1.0, False)):
        tr = ArtRegTracker([m * scale], [np.eye(4)])
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            for k in range(3):
                tr.step((m + [0.005 * (k + 1), 0, 0]) * scale)
        ours = [w for w in caught if "ArtRegTracker" in str(w.message)]
        assert len(ours) == (1 if expect_warning else 0)
        if expect_warning:
            assert "millimetres" in str(ours[0].message) and tr.last_counts == [0]
        else:
            assert tr.last_counts[0] > 0


def test_tracker_arguments_named():
    m = _box_cloud()
    with pytest.raises(ValueError, match=r"models: need a list .* for one object pass \[model\]"):
        ArtRegTracker(m, [np.eye(4)])
    with pytest.raises(ValueError, match=r"T_world_object0: need a list .* pass \[T\]"):
        ArtRegTracker([m], np.eye(4))
    with pytest.raises(ValueError, match=r"process_std: expected two positive numbers \(m, rad\)"):
        ArtRegTracker([m], [np.eye(4)], process_std=0.01)
    with pytest.raises(ValueError, match=r"init_std: expected two positive numbers"):
        ArtRegTracker([m], [np.eye(4)], init_std=(0.01, -1.0))
