"""Tests for the manifold UKF (thesis eq. 6.1-6.10, A.22)."""

import numpy as np
import pytest

from vtlearn.classical.ukf import ManifoldUKF, sigma_offsets, sigma_weights


def _euclid_phi(x, xi):
    return x + xi


def _euclid_phi_inv(x_ref, x):
    return x - x_ref


def test_sigma_weights_eq_a22_hand_computed():
    # n = 2, alpha = 0.5, beta = 2, kappa = 1: lambda = 0.25 * 3 - 2 = -1.25, n + lambda = 0.75
    w = sigma_weights(2, alpha=0.5, beta=2.0, kappa=1.0)
    assert w.lam == pytest.approx(-1.25)
    assert w.wm0 == pytest.approx(-1.25 / 0.75)
    assert w.wc0 == pytest.approx(-1.25 / 0.75 + 1 - 0.25 + 2)
    assert w.wi == pytest.approx(1 / 1.5)
    assert w.wm.sum() == pytest.approx(1.0)
    assert w.wm.shape == (5,)


def test_sigma_offsets_reproduce_covariance():
    rng = np.random.default_rng(0)
    A = rng.normal(size=(4, 4))
    P = A @ A.T + 0.1 * np.eye(4)
    w = sigma_weights(4, alpha=0.7, beta=2.0, kappa=0.5)
    xis = sigma_offsets(P, w)
    assert xis.shape == (8, 4)
    np.testing.assert_allclose(w.wi * xis.T @ xis, P, atol=1e-12)
    np.testing.assert_allclose(xis.mean(0), 0.0, atol=1e-12)


def test_bad_arguments_raise():
    with pytest.raises(ValueError, match="alpha"):
        sigma_weights(3, alpha=0.0)
    with pytest.raises(ValueError, match="kappa"):
        sigma_weights(3, alpha=1.0, kappa=-5.0)
    with pytest.raises(ValueError, match="P0"):
        ManifoldUKF(
            lambda x, u, w: x,
            lambda s: np.zeros((len(s), 1)),
            _euclid_phi,
            _euclid_phi_inv,
            Q=np.eye(2),
            R=1.0,
            state0=np.zeros(2),
            P0=np.eye(3)[:2],
        )
    with pytest.raises(ValueError, match="h"):
        ManifoldUKF(
            lambda x, u, w: x,
            None,
            _euclid_phi,
            _euclid_phi_inv,
            Q=np.eye(2),
            R=1.0,
            state0=np.zeros(2),
            P0=np.eye(2),
        )
    ukf = ManifoldUKF(
        lambda x, u, w: x + w,
        lambda s: np.stack(s),
        _euclid_phi,
        _euclid_phi_inv,
        Q=np.eye(2),
        R=1.0,
        state0=np.zeros(2),
        P0=np.eye(2),
    )
    with pytest.raises(ValueError, match="z"):
        ukf.update([np.nan, 0.0])
    with pytest.raises(ValueError, match="R"):
        ukf.update([0.0, 0.0], R=np.ones(3))


def _kalman(A, H, Q, R, x, P, zs):
    out = []
    for z in zs:
        x = A @ x
        P = A @ P @ A.T + Q
        S = H @ P @ H.T + R
        K = P @ H.T @ np.linalg.inv(S)
        x = x + K @ (z - H @ x)
        P = (np.eye(len(x)) - K @ H) @ P
        out.append((x.copy(), P.copy()))
    return out


@pytest.mark.parametrize("alpha,kappa", [(1.0, 0.0), (0.5, 1.0), (1e-2, 0.0)])
@pytest.mark.parametrize("woodbury", [False, True])
@pytest.mark.parametrize("n_iterations", [1, 3])
def test_linear_gaussian_matches_kalman_filter(alpha, kappa, woodbury, n_iterations):
    # Constant-velocity model in 2-D (state: position, velocity); noisy position and a linear mix.
    rng = np.random.default_rng(1)
    dt = 0.1
    A = np.block([[np.eye(2), dt * np.eye(2)], [np.zeros((2, 2)), np.eye(2)]])
    G = rng.normal(size=(4, 3))  # process noise enters through a non-square map: q = 3 != d = 4
    Qw = np.diag([0.01, 0.02, 0.03])
    # Many measurement rows when testing the Woodbury branch (m > 2d + 1).
    m = 12 if woodbury else 3
    H = rng.normal(size=(m, 4))
    r_diag = rng.uniform(0.05, 0.2, size=m)
    x0, P0 = np.array([0.0, 1.0, 0.5, -0.2]), np.diag([0.5, 0.5, 0.1, 0.1])
    xs_true, zs = x0.copy(), []
    for _ in range(20):
        xs_true = A @ xs_true + G @ rng.multivariate_normal(np.zeros(3), Qw)
        zs.append(H @ xs_true + rng.normal(size=m) * np.sqrt(r_diag))

    ukf = ManifoldUKF(
        f=lambda x, u, w: A @ x + G @ w,
        h=lambda states: np.stack([H @ s for s in states]),
        phi=_euclid_phi,
        phi_inv=_euclid_phi_inv,
        Q=Qw,
        R=r_diag if woodbury else np.diag(r_diag),
        state0=x0.copy(),
        P0=P0,
        alpha=alpha,
        kappa=kappa,
    )
    ref = _kalman(A, H, G @ Qw @ G.T, np.diag(r_diag), x0.copy(), P0.copy(), zs)
    for z, (x_ref, P_ref) in zip(zs, ref, strict=True):
        ukf.step(z, n_iterations=n_iterations)
        np.testing.assert_allclose(ukf.state, x_ref, atol=1e-6, rtol=1e-6)
        np.testing.assert_allclose(ukf.P, P_ref, atol=1e-6, rtol=1e-6)
