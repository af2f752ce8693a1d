"""Tests for vtlearn.classical.tiqf (thesis ch.4, eq. 4.1-4.23, Appendix B)."""

import numpy as np
import pytest
from scipy import integrate

from vtlearn.classical.tiqf import (
    TIQF,
    SequentialTIQF,
    _matrix_to_quat,
    _quat_to_matrix,
    all_pairs_moment,
    gaussian_kl,
    make_pairs,
    measurement_noise_covariance,
    pseudo_measurement_matrix,
    tiqf_update,
    tiqf_update_moment,
)


def _random_rotation(rng):
    q = rng.normal(size=4)
    q /= np.linalg.norm(q)
    return q, _quat_to_matrix(q)


def _small_rotation(deg, rng):
    axis = rng.normal(size=3)
    axis /= np.linalg.norm(axis)
    a = np.radians(deg)
    q = np.concatenate([[np.cos(a / 2)], np.sin(a / 2) * axis])
    return _quat_to_matrix(q)


def _rot_err_deg(R_a, R_b):
    return np.degrees(np.arccos(np.clip((np.trace(R_a.T @ R_b) - 1) / 2, -1, 1)))


def test_quaternion_helpers_match_geometry():
    from vtlearn.geometry import matrix_to_quat, quat_to_matrix

    rng = np.random.default_rng(0)
    q = rng.normal(size=(5, 4))
    q /= np.linalg.norm(q, axis=1, keepdims=True)
    np.testing.assert_allclose(_quat_to_matrix(q), quat_to_matrix(q), atol=1e-12)
    for R in _quat_to_matrix(q):
        np.testing.assert_allclose(_matrix_to_quat(R), matrix_to_quat(R), atol=1e-10)


def test_pseudo_measurement_nullspace_eq_4_12():
    rng = np.random.default_rng(1)
    q, R = _random_rotation(rng)
    o_ji = rng.normal(size=(7, 3))
    s_ji = o_ji @ R.T
    H = pseudo_measurement_matrix(s_ji, o_ji)
    assert H.shape == (7, 4, 4)
    np.testing.assert_allclose(H @ q, 0.0, atol=1e-12)
    # a wrong rotation is not in the nullspace
    q_wrong, _ = _random_rotation(rng)
    assert np.abs(H @ q_wrong).max() > 1e-3


def test_pseudo_measurement_hand_computed():
    # s = (1, 0, 0), o = (0, 1, 0): H = [[0, -(s-o)^T], [s-o, [s+o]x]]
    H = pseudo_measurement_matrix([1.0, 0, 0], [0, 1.0, 0])
    expected = np.array([[0, -1, 1, 0], [1, 0, 0, 1], [-1, 0, 0, -1], [0, -1, 1, 0]], dtype=float)
    np.testing.assert_allclose(H, expected)
    # the -90-degree rotation about z maps o to s and is in the nullspace
    q = np.array([np.cos(np.pi / 4), 0, 0, -np.sin(np.pi / 4)])
    np.testing.assert_allclose(H @ q, 0.0, atol=1e-12)


def test_measurement_noise_eq_4_18():
    x = np.array([1.0, 0, 0, 0])
    P = np.diag([0.1, 0.2, 0.3, 0.4])
    Pv = measurement_noise_covariance(x, P, rho=2.0)
    A = np.outer(x, x) + P
    np.testing.assert_allclose(Pv, 0.5 * (np.trace(A) * np.eye(4) - A))
    with pytest.raises(ValueError, match="rho"):
        measurement_noise_covariance(x, P, rho=0.0)


def test_update_matches_literal_kalman_eq_4_19_to_4_21():
    """Information form == eq. 4.19-4.21 with the stacked 4M x 4M measurement (naive reference)."""
    rng = np.random.default_rng(2)
    x = rng.normal(size=4)
    x /= np.linalg.norm(x)
    A = rng.normal(size=(4, 4))
    P = A @ A.T * 0.1 + 0.05 * np.eye(4)
    s_ji, o_ji = rng.normal(size=(5, 3)), rng.normal(size=(5, 3))
    rho = 0.3
    x_fast, P_fast = tiqf_update(x, P, s_ji, o_ji, rho)

    H = pseudo_measurement_matrix(s_ji, o_ji).reshape(-1, 4)  # 20x4
    Pv = measurement_noise_covariance(x, P, rho)
    R_blk = np.kron(np.eye(5), Pv)
    K = P @ H.T @ np.linalg.inv(H @ P @ H.T + R_blk)  # eq. 4.21
    x_ref = x - K @ (H @ x)  # eq. 4.19
    P_ref = (np.eye(4) - K @ H) @ P  # eq. 4.20
    n = np.linalg.norm(x_ref)
    x_ref, P_ref = x_ref / n, P_ref / n**2  # eq. 4.22
    np.testing.assert_allclose(x_fast, x_ref, atol=1e-10)
    np.testing.assert_allclose(P_fast, P_ref, atol=1e-10)


def test_moment_form_matches_all_pairs():
    rng = np.random.default_rng(3)
    s, o = rng.normal(size=(12, 3)), rng.normal(size=(12, 3))
    x = np.array([0.5, 0.5, 0.5, 0.5])
    P = 0.5 * np.eye(4)
    i, j = make_pairs(12)
    assert len(i) == 12 * 11 // 2
    a = tiqf_update(x, P, s[j] - s[i], o[j] - o[i], 0.2)
    b = tiqf_update_moment(x, P, all_pairs_moment(s, o), 0.2)
    np.testing.assert_allclose(a[0], b[0], atol=1e-10)
    np.testing.assert_allclose(a[1], b[1], rtol=1e-6, atol=1e-10)


def test_update_batched_over_leading_dims():
    rng = np.random.default_rng(4)
    x = np.array([1.0, 0, 0, 0])
    P = np.eye(4)
    s, o = rng.normal(size=(3, 6, 3)), rng.normal(size=(3, 6, 3))
    xb, Pb = tiqf_update(np.broadcast_to(x, (3, 4)), np.broadcast_to(P, (3, 4, 4)), s, o, 0.1)
    for c in range(3):
        xc, Pc = tiqf_update(x, P, s[c], o[c], 0.1)
        np.testing.assert_allclose(xb[c], xc, atol=1e-12)
        np.testing.assert_allclose(Pb[c], Pc, atol=1e-12)


def test_make_pairs_large_uses_shifts():
    i, j = make_pairs(1000, max_all_pairs=100, n_shifts=4, rng=0)
    assert len(i) == 4000 and (i != j).all()
    with pytest.raises(ValueError, match="n"):
        make_pairs(1)


def test_noiseless_known_correspondences_exact():
    rng = np.random.default_rng(5)
    _, R = _random_rotation(rng)
    t = rng.uniform(-5, 5, 3)
    o = rng.normal(size=(25, 3))
    s = o @ R.T + t
    T, q, P = TIQF(tol_rot_deg=1e-10, max_iter=200).solve_known_correspondences(o, s)
    np.testing.assert_allclose(T[:3, :3], R, atol=1e-6)
    np.testing.assert_allclose(T[:3, 3], t, atol=1e-6)
    np.testing.assert_allclose(np.linalg.norm(q), 1.0)
    assert np.all(np.linalg.eigvalsh(P) > 0)


def test_noisy_known_correspondences_bound():
    rng = np.random.default_rng(6)
    _, R = _random_rotation(rng)
    t = rng.uniform(-1, 1, 3)
    o = rng.uniform(-0.5, 0.5, size=(200, 3))
    s = o @ R.T + t + rng.normal(scale=0.005, size=o.shape)
    T, _, _ = TIQF(tol_rot_deg=1e-6).solve_known_correspondences(o, s)
    assert _rot_err_deg(T[:3, :3], R) < 0.5
    assert np.linalg.norm(T[:3, 3] - t) < 0.005


def test_icp_mode_noiseless_exact():
    rng = np.random.default_rng(7)
    model = rng.uniform(-1, 1, size=(400, 3))
    _, R = _random_rotation(rng)
    t = rng.uniform(-1, 1, 3)
    scene = model[:150] @ R.T + t
    T0 = np.eye(4)
    T0[:3, :3] = R @ _small_rotation(8.0, rng)
    T0[:3, 3] = t + 0.03
    res = TIQF(tol_rot_deg=1e-9, tol_trans=1e-10, max_iter=200).register(model, scene, T0)
    np.testing.assert_allclose(res.T_scene_model[:3, :3], R, atol=1e-6)
    np.testing.assert_allclose(res.T_scene_model[:3, 3], t, atol=1e-6)
    assert res.rmse < 1e-6 and res.iterations >= 2


def test_escapes_never_worsen_rmse():
    rng = np.random.default_rng(8)
    model = rng.uniform(-1, 1, size=(300, 3))
    _, R = _random_rotation(rng)
    scene = model[:20] @ R.T
    T0 = np.eye(4)
    T0[:3, :3] = R @ _small_rotation(25.0, rng)
    plain = TIQF(n_escapes=0, seed=1).register(model, scene, T0)
    escaped = TIQF(n_escapes=6, seed=1).register(model, scene, T0)
    assert escaped.rmse <= plain.rmse + 1e-12
    assert len(escaped.history) == 7


def test_sequential_reaches_batch_result():
    rng = np.random.default_rng(9)
    model = rng.uniform(-0.5, 0.5, size=(500, 3))
    _, R = _random_rotation(rng)
    t = rng.uniform(-0.2, 0.2, 3)
    scene = model[rng.choice(500, 40, replace=False)] @ R.T + t
    T0 = np.eye(4)
    T0[:3, :3] = R @ _small_rotation(5.0, rng)
    T0[:3, 3] = t + 0.01
    batch = TIQF(max_iter=100).register(model, scene, T0)
    seq = SequentialTIQF(model, T_init=T0, inner_iter=20)
    for p in scene:
        seq.add(p[None])
    assert _rot_err_deg(seq.R, batch.T_scene_model[:3, :3]) < 0.5
    assert np.linalg.norm(seq.t - batch.T_scene_model[:3, 3]) < 5e-3
    assert _rot_err_deg(batch.T_scene_model[:3, :3], R) < 1e-3
    # the pairs carry no information along x itself (H x = 0 for any scale of x), so the uncertainty that
    # the touches remove is the one orthogonal to x
    proj = np.eye(4) - np.outer(seq.x, seq.x)
    assert np.trace(proj @ seq.P @ proj) < 0.05


def test_sequential_new_pairs_cover_all_pairs_once():
    pairs = set()
    n_old = 0
    for n_new in (1, 2, 1, 3):
        i, j = SequentialTIQF.new_pairs(n_old, n_new)
        new = set(zip(i.tolist(), j.tolist(), strict=True))
        assert not (new & pairs)
        pairs |= new
        n_old += n_new
    i, j = make_pairs(n_old)
    assert pairs == set(zip(i.tolist(), j.tolist(), strict=True))


def test_kl_1d_matches_numeric_integral():
    mu_p, var_p, mu_q, var_q = 0.3, 0.5, -0.4, 1.7

    def p(x):
        return np.exp(-0.5 * (x - mu_p) ** 2 / var_p) / np.sqrt(2 * np.pi * var_p)

    def q(x):
        return np.exp(-0.5 * (x - mu_q) ** 2 / var_q) / np.sqrt(2 * np.pi * var_q)

    numeric, _ = integrate.quad(lambda x: p(x) * np.log(p(x) / q(x)), -20, 20)
    closed = gaussian_kl([mu_p], [[var_p]], [mu_q], [[var_q]])
    np.testing.assert_allclose(closed, numeric, rtol=1e-7)


def test_kl_4d_matches_naive_formula_and_is_zero_for_equal():
    rng = np.random.default_rng(10)
    A, B = rng.normal(size=(4, 4)), rng.normal(size=(4, 4))
    S1, S2 = A @ A.T + np.eye(4), B @ B.T + np.eye(4)
    m1, m2 = rng.normal(size=4), rng.normal(size=4)
    naive = 0.5 * (
        np.log(np.linalg.det(S2) / np.linalg.det(S1))
        + np.trace(np.linalg.inv(S2) @ S1)
        - 4
        + (m2 - m1) @ np.linalg.inv(S2) @ (m2 - m1)
    )
    np.testing.assert_allclose(gaussian_kl(m1, S1, m2, S2), naive, rtol=1e-10)
    np.testing.assert_allclose(gaussian_kl(m1, S1, m1, S1), 0.0, atol=1e-12)
    batched = gaussian_kl(np.stack([m1, m2]), np.stack([S1, S2]), m2, S2)
    np.testing.assert_allclose(batched, [naive, 0.0], atol=1e-10)


@pytest.mark.parametrize(
    "model, scene, match",
    [
        (np.zeros((10, 3)), np.zeros((2, 3)), "scene"),
        (np.zeros((10, 3)), np.full((5, 3), np.nan), "scene"),
        (np.zeros((10, 2)), np.zeros((5, 3)), "model"),
        (np.zeros((0, 3)), np.zeros((5, 3)), "model"),
    ],
)
def test_register_rejects_bad_input(model, scene, match):
    with pytest.raises(ValueError, match=match):
        TIQF().register(model, scene)


def test_constructor_rejects_bad_parameters():
    with pytest.raises(ValueError, match="rho"):
        TIQF(rho=-1)
    with pytest.raises(ValueError, match="max_iter"):
        TIQF(max_iter=0)
    with pytest.raises(ValueError, match="T_init"):
        TIQF().register(np.random.rand(10, 3), np.random.rand(5, 3), T_init=np.ones((4, 4)))
    assert "TIQF(" in repr(TIQF())


def test_sequential_reassociate_mode_converges_and_validates():
    rng = np.random.default_rng(11)
    model = rng.uniform(-0.5, 0.5, size=(500, 3))
    _, R = _random_rotation(rng)
    scene = model[rng.choice(500, 30, replace=False)] @ R.T
    T0 = np.eye(4)
    T0[:3, :3] = R @ _small_rotation(5.0, rng)
    seq = SequentialTIQF(model, T_init=T0, mode="reassociate", rho=1e-4, inner_iter=30)
    for k in range(0, 30, 3):
        seq.add(scene[k : k + 3])
    assert _rot_err_deg(seq.R, R) < 0.5
    assert np.linalg.norm(seq.t) < 5e-3
    with pytest.raises(ValueError, match="mode"):
        SequentialTIQF(model, mode="nope")
