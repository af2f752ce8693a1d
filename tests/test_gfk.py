"""Geodesic Flow Kernel (Gong et al. 2012, eq. 6-7): the transfer step of the classical baseline of thesis
Table 7.4 (CLUE+GFK+1NN/SVM)."""

import numpy as np
import pytest
from scipy.linalg import null_space, subspace_angles
from sklearn.neighbors import KNeighborsClassifier

from vtlearn.classical.gfk import (
    SDM_LEVEL,
    GeodesicFlowKernel,
    gfk_embed,
    gfk_kernel,
    pca_basis,
    sdm_dimension,
    subspace_disagreement,
)


def _orth(rng, D, d):
    return np.linalg.qr(rng.normal(size=(D, d)))[0]


def _geodesic(P_s, P_t):
    """Φ(t) built independently of the module: explicit complement R_s and two SVDs."""
    U1, gamma, Vt = np.linalg.svd(P_s.T @ P_t)
    V = Vt.T
    theta = np.arccos(np.clip(gamma, -1.0, 1.0))
    R_s = null_space(P_s.T)
    W, S, Zt = np.linalg.svd(R_s.T @ P_t, full_matrices=False)
    # R_sᵀP_t = -U2 Σ Vᵀ: its right singular vectors are V's (distinct angles), with Σ ascending where Γ
    # descends; fix each one's order and sign against V.
    order = np.argsort(S)
    W, S, Z = W[:, order], S[order], Zt.T[:, order]
    sign = np.sign(np.sum(Z * V, axis=0))
    assert np.allclose(Z * sign, V, atol=1e-8)
    assert np.allclose(S, np.sin(theta), atol=1e-8)
    U2 = -W * sign

    def phi(t):
        return (P_s @ U1) * np.cos(t * theta) - (R_s @ U2) * np.sin(t * theta)

    return phi


def _quadrature(phi, nodes=60):
    x, w = np.polynomial.legendre.leggauss(nodes)
    t, w = (x + 1.0) / 2.0, w / 2.0  # [-1, 1] -> [0, 1]
    return sum(wi * phi(ti) @ phi(ti).T for ti, wi in zip(t, w, strict=True))


@pytest.mark.parametrize("D,d", [(12, 3), (40, 10)])
def test_closed_form_equals_integral(D, d):
    rng = np.random.default_rng(D)
    P_s, P_t = _orth(rng, D, d), _orth(rng, D, d)
    phi = _geodesic(P_s, P_t)
    G = gfk_kernel(P_s, P_t)
    np.testing.assert_allclose(G, _quadrature(phi), atol=1e-8)
    # the integral itself (eq. 6), not Gong et al.'s eq. 7 which is twice it
    assert np.trace(G) == pytest.approx(d, abs=1e-10)


def test_geodesic_endpoints():
    rng = np.random.default_rng(1)
    P_s, P_t = _orth(rng, 12, 3), _orth(rng, 12, 3)
    phi = _geodesic(P_s, P_t)
    np.testing.assert_allclose(phi(0.0) @ phi(0.0).T, P_s @ P_s.T, atol=1e-12)
    np.testing.assert_allclose(phi(1.0) @ phi(1.0).T, P_t @ P_t.T, atol=1e-10)
    np.testing.assert_allclose(phi(0.5).T @ phi(0.5), np.eye(3), atol=1e-10)  # stays on the Grassmannian


def test_identical_and_nearly_identical_subspaces():
    rng = np.random.default_rng(2)
    P_s = _orth(rng, 20, 4)
    Q = np.linalg.qr(rng.normal(size=(4, 4)))[0]
    np.testing.assert_allclose(gfk_kernel(P_s, P_s @ Q), P_s @ P_s.T, atol=1e-10)
    # tilt one direction by 1e-9 rad: G moves by O(θ), with no blow-up from the 1/θ terms
    e = null_space(P_s.T)[:, 0]
    P_t = P_s.copy()
    P_t[:, 0] = np.cos(1e-9) * P_s[:, 0] + np.sin(1e-9) * e
    assert np.abs(gfk_kernel(P_s, P_t) - P_s @ P_s.T).max() < 1e-8


def test_orthogonal_subspaces():
    # θ_i = π/2: Φ(t) = P_s U1 cos(tπ/2) + P_t V sin(tπ/2), so
    # ∫ΦΦᵀ = ½(P_sP_sᵀ + P_tP_tᵀ) + (1/π)(P_s W P_tᵀ + its transpose) with W = U1 Vᵀ orthogonal:
    # the cross term (∫cos·sin = 1/π) does NOT vanish, so G != ½(P_sP_sᵀ + P_tP_tᵀ), and since P_sᵀP_t = 0
    # the pairing W is arbitrary (the geodesic is not unique). Assert that structure.
    rng = np.random.default_rng(3)
    Q = np.linalg.qr(rng.normal(size=(10, 10)))[0]
    P_s, P_t = Q[:, :3], Q[:, 3:6]
    G = gfk_kernel(P_s, P_t)
    half = 0.5 * (P_s @ P_s.T + P_t @ P_t.T)
    np.testing.assert_allclose(P_s.T @ G @ P_s, 0.5 * np.eye(3), atol=1e-10)
    np.testing.assert_allclose(P_t.T @ G @ P_t, 0.5 * np.eye(3), atol=1e-10)
    W = np.pi * P_s.T @ G @ P_t
    np.testing.assert_allclose(W @ W.T, np.eye(3), atol=1e-10)
    np.testing.assert_allclose(G, half + (P_s @ W @ P_t.T + P_t @ W.T @ P_s.T) / np.pi, atol=1e-10)
    assert np.abs(G - half).max() > 0.1
    # exactly orthogonal coordinate subspaces: the angles are exactly π/2 and the same identity holds
    E = np.eye(8)
    G = gfk_kernel(E[:, :2], E[:, 2:4])
    W = np.pi * G[:2, 2:4]
    np.testing.assert_allclose(W @ W.T, np.eye(2), atol=1e-12)
    np.testing.assert_allclose(np.diag(G)[:4], 0.5, atol=1e-12)
    assert np.abs(G[4:]).max() == 0.0


def test_symmetric_psd_and_basis_invariant():
    rng = np.random.default_rng(4)
    P_s, P_t = _orth(rng, 15, 5), _orth(rng, 15, 5)
    G = gfk_kernel(P_s, P_t)
    assert np.array_equal(G, G.T)
    assert np.linalg.eigvalsh(G).min() > -1e-12
    Q_s, Q_t = _orth(rng, 5, 5), _orth(rng, 5, 5)
    np.testing.assert_allclose(gfk_kernel(P_s @ Q_s, P_t @ Q_t), G, atol=1e-10)


def test_embed_reproduces_kernel():
    rng = np.random.default_rng(5)
    G = gfk_kernel(_orth(rng, 12, 4), _orth(rng, 12, 4))
    X, Z = rng.normal(size=(7, 12)), rng.normal(size=(5, 12))
    EX, EZ = gfk_embed(X, G), gfk_embed(Z, G)
    assert EX.shape == (7, 12)
    np.testing.assert_allclose(EX @ EZ.T, X @ G @ Z.T, atol=1e-10)


def test_pca_basis():
    rng = np.random.default_rng(6)
    X = rng.normal(size=(50, 8)) * np.array([5.0, 3.0, 1.0, 0.5, 0.2, 0.1, 0.1, 0.1]) + 7.0
    P = pca_basis(X, 2)
    assert P.shape == (8, 2)
    np.testing.assert_allclose(P.T @ P, np.eye(2), atol=1e-12)
    # the projector onto the top-2 eigenvectors of the sample covariance (so the offset 7 was centred away)
    top = np.linalg.eigh(np.cov(X.T))[1][:, -2:]
    np.testing.assert_allclose(P @ P.T, top @ top.T, atol=1e-10)


def test_fit_transform_angles_and_zscore():
    rng = np.random.default_rng(7)
    Xs = rng.normal(size=(30, 10)) * 3.0 + 1.0
    Xt = rng.normal(size=(25, 10)) @ rng.normal(size=(10, 10)) - 2.0
    gfk = GeodesicFlowKernel(dim=4).fit(Xs, Xt)
    assert gfk.G_.shape == (10, 10) and gfk.transform(Xt).shape == (25, 10)
    angles = gfk.principal_angles_
    expected = np.sort(subspace_angles(pca_basis(Xs, 4), pca_basis(Xt, 4)))
    np.testing.assert_allclose(angles, expected, atol=1e-10)
    assert np.all(np.diff(angles) >= 0)
    np.testing.assert_allclose(gfk.transform(Xs), gfk_embed(Xs, gfk.G_), atol=1e-12)

    gz = GeodesicFlowKernel(dim=4, zscore=True).fit(Xs, Xt)
    zs = (Xs - Xs.mean(0)) / Xs.std(0)
    zt = (Xt - Xt.mean(0)) / Xt.std(0)
    np.testing.assert_allclose(gz.G_, gfk_kernel(pca_basis(zs, 4), pca_basis(zt, 4)), atol=1e-10)
    np.testing.assert_allclose(gz.transform(Xs, domain="source"), gfk_embed(zs, gz.G_), atol=1e-10)
    np.testing.assert_allclose(gz.transform(Xt, domain="target"), gfk_embed(zt, gz.G_), atol=1e-10)
    with pytest.raises(ValueError, match="^domain"):
        gz.transform(Xs)
    with pytest.raises(ValueError, match="^domain"):
        gz.transform(Xs, domain="visual")


def test_one_nn_gains_on_geodesic_shift():
    # Five Gaussian classes in a 5-D subspace S of R^30; the target is the same classes turned by
    # 1.2-1.3 rad out of S (each axis e_i towards its own orthogonal f_i, i.e. along a Grassmann geodesic),
    # plus a global shift and isotropic noise. This is the shift GFK models, so the gain is real: both
    # sides z-score each domain, 1-NN goes 0.82 -> 1.00 here (over seeds 6-29 it was 0.78 -> 0.99 on
    # average, gain >= 0.09 on every seed). A generic rotation that also mixes directions inside S would
    # not be undone: GFK pairs directions by principal angles, not by class.
    rng = np.random.default_rng(2)
    D, d, n = 30, 5, 40
    Q = np.linalg.qr(rng.normal(size=(D, D)))[0]
    E, F = Q[:, :d], Q[:, d:2 * d]
    y = np.repeat(np.arange(d), n)
    means = 4.0 * np.eye(d)
    theta = rng.uniform(1.2, 1.3, size=d)
    Cs = means[y] + rng.normal(scale=0.6, size=(d * n, d))
    Ct = means[y] + rng.normal(scale=0.6, size=(d * n, d))
    Xs = Cs @ E.T + 0.3 * rng.normal(size=(d * n, D))
    Xt = (Ct * np.cos(theta)) @ E.T + (Ct * np.sin(theta)) @ F.T + 0.3 * rng.normal(size=(d * n, D))
    Xt += rng.normal(scale=3.0, size=D)

    def z(X):
        return (X - X.mean(0)) / X.std(0)

    base = KNeighborsClassifier(1).fit(z(Xs), y).score(z(Xt), y)
    gfk = GeodesicFlowKernel(dim=d, zscore=True).fit(Xs, Xt)
    acc = KNeighborsClassifier(1).fit(gfk.transform(Xs, "source"), y).score(gfk.transform(Xt, "target"), y)
    assert base < 0.9
    assert acc >= 0.97 and acc >= base + 0.1


def _axis_data(rng, n, D, variances):
    """n samples whose covariance is exactly diag(variances) on the axes named by the dict's keys (0 on
    every other axis): centred orthonormal columns, scaled."""
    A = rng.normal(size=(n, len(variances)))
    Q = np.linalg.qr(A - A.mean(0))[0]  # combinations of centred columns stay centred
    X = np.zeros((n, D))
    for j, (axis, var) in enumerate(variances.items()):
        X[:, axis] = Q[:, j] * np.sqrt(var * n)
    return X


def test_subspace_disagreement_on_known_axes():
    # Both domains vary along e0-e2 alike; the source's 4th and 5th directions are e3, e5, the target's
    # e4, e6. The pooled data rank e0-e2, e3, e4, ... (equal n, so pooled variances are the means). So
    # D(1..3) = 0, D(4) = ½ (the target's 4th direction e4 is orthogonal to the pooled e0-e3, the source's
    # e3 is in it) and D(5) = 1 (e5 and e6 are both orthogonal to the pooled e0-e4): Gong et al.'s d* = 5.
    rng = np.random.default_rng(3)
    D, n = 16, 200
    Xs = _axis_data(rng, n, D, {0: 9.0, 1: 5.0, 2: 3.0, 3: 2.0, 5: 0.2})
    Xt = _axis_data(rng, n, D, {0: 9.0, 1: 5.0, 2: 3.0, 4: 1.0, 6: 0.1})
    curve = subspace_disagreement(Xs, Xt, max_dim=6)
    np.testing.assert_allclose(curve[:5], [0.0, 0.0, 0.0, 0.5, 1.0], atol=1e-6)
    assert sdm_dimension(Xs, Xt) == 5
    # the data are read as given: an unequal scaling of the domains moves the pooled ranking, not D(1..3)
    assert np.all(subspace_disagreement(Xs, 3.0 * Xt)[:3] < 1e-6)
    # where no d up to max_dim reaches the level, the largest d tried; by default min(D // 2, n - 1)
    assert sdm_dimension(Xs, Xt, max_dim=4) == 4
    assert len(subspace_disagreement(Xs, Xt)) == D // 2
    assert len(subspace_disagreement(Xs[:6], Xt)) == 5


def test_subspace_disagreement_of_one_domain_is_zero():
    # identical domains agree along every direction: D(d) = 0 and no d reaches the level
    rng = np.random.default_rng(4)
    X = rng.normal(size=(50, 12)) * np.linspace(3.0, 0.5, 12)
    curve = subspace_disagreement(X, X.copy())
    assert curve.shape == (6,) and np.all(curve < 1e-6)
    assert sdm_dimension(X, X.copy()) == 6


def test_gfk_dim_sdm():
    rng = np.random.default_rng(5)
    Xs = _axis_data(rng, 200, 16, {0: 9.0, 1: 5.0, 2: 3.0, 3: 2.0, 5: 0.2})
    Xt = _axis_data(rng, 200, 16, {0: 9.0, 1: 5.0, 2: 3.0, 4: 1.0, 6: 0.1})
    Xt += rng.normal(size=(200, 16)) * 1e-9  # a trace of every axis, so each has a z-score
    Xs += rng.normal(size=(200, 16)) * 1e-9
    plain = GeodesicFlowKernel(dim="sdm").fit(Xs, Xt)
    assert plain.dim_ == 5 and plain.G_.shape == (16, 16) and plain.principal_angles_.shape == (5,)
    np.testing.assert_allclose(plain.sdm_, subspace_disagreement(Xs, Xt))
    np.testing.assert_allclose(plain.G_, GeodesicFlowKernel(dim=5).fit(Xs, Xt).G_, atol=1e-10)
    # with zscore the SDM is read on each domain's standardised data
    z = GeodesicFlowKernel(dim="sdm", zscore=True).fit(Xs, Xt)

    def std(X):
        return (X - X.mean(0)) / X.std(0)

    np.testing.assert_allclose(z.sdm_, subspace_disagreement(std(Xs), std(Xt)), atol=1e-10)
    assert z.dim_ == sdm_dimension(std(Xs), std(Xt))
    assert GeodesicFlowKernel(dim=3).fit(Xs, Xt).dim_ == 3
    assert 0.99 < SDM_LEVEL < 1.0


def test_bad_input():
    rng = np.random.default_rng(8)
    P = _orth(rng, 10, 3)
    with pytest.raises(ValueError, match="^P_s.*orthonormal"):
        gfk_kernel(2.0 * P, P)
    with pytest.raises(ValueError, match="^P_t.*shape"):
        gfk_kernel(P, _orth(rng, 10, 4))
    bad = P.copy()
    bad[0, 0] = np.nan
    with pytest.raises(ValueError, match="^P_t.*NaN"):
        gfk_kernel(P, bad)
    with pytest.raises(ValueError, match="^d:.*2d <= D"):
        gfk_kernel(_orth(rng, 6, 4), _orth(rng, 6, 4))
    with pytest.raises(ValueError, match="^d:"):
        pca_basis(rng.normal(size=(3, 10)), 4)
    with pytest.raises(ValueError, match="^X:"):
        pca_basis(rng.normal(size=(1, 10)), 1)
    with pytest.raises(ValueError, match="^dim:.*samples"):
        GeodesicFlowKernel(dim=6).fit(rng.normal(size=(5, 20)), rng.normal(size=(30, 20)))
    with pytest.raises(ValueError, match="^dim:.*2 \\* dim"):
        GeodesicFlowKernel(dim=6).fit(rng.normal(size=(30, 10)), rng.normal(size=(30, 10)))
    with pytest.raises(ValueError, match="^X_target:.*features"):
        GeodesicFlowKernel(dim=2).fit(rng.normal(size=(30, 10)), rng.normal(size=(30, 9)))
    with pytest.raises(ValueError, match="^G:"):
        gfk_embed(rng.normal(size=(4, 10)), np.eye(9))
    with pytest.raises(ValueError, match="^dim:.*'sdm'"):
        GeodesicFlowKernel(dim="pca").fit(rng.normal(size=(30, 10)), rng.normal(size=(30, 10)))
    with pytest.raises(ValueError, match="^max_dim:.*= 5\\]"):
        subspace_disagreement(rng.normal(size=(30, 10)), rng.normal(size=(30, 10)), max_dim=6)
    with pytest.raises(ValueError, match="^max_dim:"):
        subspace_disagreement(rng.normal(size=(30, 10)), rng.normal(size=(30, 10)), max_dim=0)
    with pytest.raises(ValueError, match="^X_source, X_target:.*2 samples"):
        subspace_disagreement(rng.normal(size=(1, 10)), rng.normal(size=(30, 10)))
    with pytest.raises(ValueError, match="^X_target:.*features"):
        subspace_disagreement(rng.normal(size=(30, 10)), rng.normal(size=(30, 9)))
    with pytest.raises(ValueError, match="^level:"):
        sdm_dimension(rng.normal(size=(30, 10)), rng.normal(size=(30, 10)), level=1.5)
