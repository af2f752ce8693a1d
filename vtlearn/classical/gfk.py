"""Geodesic Flow Kernel (Gong, Shi, Sha and Grauman, 2012, "Geodesic flow kernel for unsupervised domain
adaptation", CVPR, eq. 6-7), closed form, in numpy.

This is the transfer step of the classical cross-modal baseline of thesis Table 7.4 ("CLUE+GFK+1NN" and
"CLUE+GFK+SVM", Falco et al. 2019): hand-crafted descriptors of labelled visual clouds are the source,
those of unlabelled tactile clouds the target; both are embedded with the GFK and classified by 1-NN or a
linear SVM trained on the source.

Maths. ``P_s``, ``P_t`` are ``(D, d)`` orthonormal bases of the source and target subspaces (top-d PCA
directions), ``R_s`` an orthonormal basis of the complement of ``span(P_s)``. With the SVDs

    P_sᵀ P_t = U1 Γ Vᵀ,     R_sᵀ P_t = -U2 Σ Vᵀ,     Γ = diag cos θ_i,  Σ = diag sin θ_i,

(θ_i the principal angles, ascending, in [0, π/2]), the geodesic on the Grassmannian is

    Φ(t) = P_s U1 Γ(t) - R_s U2 Σ(t),     Γ(t) = diag cos(t θ_i),  Σ(t) = diag sin(t θ_i),  t ∈ [0, 1],

with ``span Φ(0) = span P_s`` and ``span Φ(1) = span P_t``. The kernel is the integral (eq. 6)

    G = ∫_0^1 Φ(t) Φ(t)ᵀ dt = [P_s U1, R_s U2] [[Λ1, Λ2], [Λ2, Λ3]] [P_s U1, R_s U2]ᵀ,

    λ1_i = ½ (1 + sin 2θ_i / 2θ_i),   λ2_i = -(1 - cos 2θ_i) / 4θ_i,   λ3_i = ½ (1 - sin 2θ_i / 2θ_i),

with the limits (1, 0, 0) at θ_i = 0. Gong et al.'s eq. 7 is twice this (their λ's lack the ½); here G is
the integral itself, so ``trace(G) = d`` and ``G = P_s P_sᵀ`` for identical subspaces. A global factor
does not change 1-NN predictions, and for a linear SVM it only rescales the regularisation C.

``R_s U2`` is never formed from a ``(D, D - d)`` complement basis: ``R_s U2 = -(I - P_s P_sᵀ) P_t V Σ⁻¹``
for θ_i > 0, and its column is set to zero when θ_i = 0 (it only meets zero weights there). The
construction needs ``2d <= D``.

Caveat: when some θ_i = π/2 exactly (e.g. orthogonal subspaces) the geodesic is not unique (the SVD of
``P_sᵀ P_t`` does not fix which directions are paired), and neither is G's cross term; generic data,
where the angles are below π/2, are unaffected.
"""

from __future__ import annotations

from typing import Literal

import numpy as np

__all__ = ["pca_basis", "gfk_kernel", "gfk_embed", "subspace_disagreement", "sdm_dimension",
           "GeodesicFlowKernel"]

_ORTHO_TOL = 1e-6
#: the SDM level read as Gong et al.'s "D(d) = 1": Fernando et al.'s getGFKDim.m (which the GFK code that
#: is passed around ships) takes the first d whose D rounds to 1.00, i.e. D >= 0.995
SDM_LEVEL = 0.995


def _as_matrix(name: str, X) -> np.ndarray:
    X = np.asarray(X, dtype=float)
    if X.ndim != 2:
        raise ValueError(f"{name}: need a 2-D array, got shape {X.shape}")
    if not np.all(np.isfinite(X)):
        raise ValueError(f"{name}: contains NaN or inf")
    return X


def pca_basis(X, d: int) -> np.ndarray:
    """Orthonormal basis of the top-``d`` principal directions of ``X``.

    Args:
        X: samples in rows; the columns are centred before the SVD.
        d: number of directions, ``1 <= d <= min(n, D)``.

    Returns:
        ``(D, d)`` matrix with orthonormal columns, by decreasing explained variance.

    Shapes:
        X (n, D), n >= 2 -> (D, d)
    """
    X = _as_matrix("X", X)
    n, D = X.shape
    if n < 2:
        raise ValueError(f"X: need at least 2 samples (rows), got {n}")
    if isinstance(d, bool) or not isinstance(d, (int, np.integer)) or not 1 <= d <= min(n, D):
        raise ValueError(f"d: need an integer in [1, min(n, D) = {min(n, D)}], got {d!r}")
    _, _, Vt = np.linalg.svd(X - X.mean(axis=0), full_matrices=False)
    return Vt[:d].T.copy()


def _check_pair(X_source, X_target) -> tuple[np.ndarray, np.ndarray]:
    Xs = _as_matrix("X_source", X_source)
    Xt = _as_matrix("X_target", X_target)
    if Xs.shape[1] != Xt.shape[1]:
        raise ValueError(f"X_target: has {Xt.shape[1]} features, X_source has {Xs.shape[1]}")
    return Xs, Xt


def subspace_disagreement(X_source, X_target, max_dim: int | None = None) -> np.ndarray:
    """Gong et al.'s subspace disagreement measure (SDM), for every d up to
    ``max_dim``:

        D(d) = ½ (sin α_d + sin β_d),

    with α_d the d-th (largest) principal angle between the top-d PCA subspaces of the source and of the
    source and target pooled, and β_d the same for the target. D(d) is near 0 while the d-th directions of
    the two domains agree, and reaches 1 when the pooled subspace has a direction orthogonal to both
    domains' own (Gong et al. choose ``d* = min{d : D(d) = 1}``, :func:`sdm_dimension`). The data are
    used as given: standardise each domain first where the GFK does (``GeodesicFlowKernel(zscore=True)``
    fits the SDM on its standardised data).

    Args:
        X_source, X_target: samples in rows, same features.
        max_dim: the largest d (default and upper bound: ``min(D // 2, n_s - 1, n_t - 1)``, the
            GFK's ``2d <= D`` and the ranks of the centred PCAs).

    Returns:
        ``D(1) … D(max_dim)``, each in [0, 1].

    Shapes:
        X_source (n_s, D), X_target (n_t, D) -> (max_dim,)
    """
    Xs, Xt = _check_pair(X_source, X_target)
    limit = min(Xs.shape[1] // 2, Xs.shape[0] - 1, Xt.shape[0] - 1)
    if limit < 1:
        raise ValueError(f"X_source, X_target: need at least 2 features and 2 samples per domain, got "
                         f"{Xs.shape} and {Xt.shape}")
    if max_dim is None:
        max_dim = limit
    if isinstance(max_dim, bool) or not isinstance(max_dim, (int, np.integer)) or not 1 <= max_dim <= limit:
        raise ValueError(f"max_dim: need an integer in [1, min(D // 2, n_s - 1, n_t - 1) = {limit}], got "
                         f"{max_dim!r}")
    P_s, P_t = pca_basis(Xs, max_dim), pca_basis(Xt, max_dim)
    P_st = pca_basis(np.concatenate([Xs, Xt]), max_dim)
    out = np.empty(max_dim)
    for d in range(1, max_dim + 1):
        # the largest principal angle of two d-dim subspaces: cos = the smallest singular value of P1ᵀ P2
        sin_ab = [np.sqrt(max(0.0, 1.0 - min(1.0, np.linalg.svd(P[:, :d].T @ P_st[:, :d],
                                                                 compute_uv=False)[-1]) ** 2))
                  for P in (P_s, P_t)]
        out[d - 1] = 0.5 * (sin_ab[0] + sin_ab[1])
    return out


def sdm_dimension(X_source, X_target, max_dim: int | None = None, level: float = SDM_LEVEL) -> int:
    """Gong et al.'s subspace dimension ``d* = min{d : D(d) = 1}`` (:func:`subspace_disagreement`), with
    "= 1" read as ``D(d) >= level`` (:data:`SDM_LEVEL`, as in the public GFK code); ``max_dim`` (the
    largest d tried, see :func:`subspace_disagreement`) where no d reaches it.

    Shapes:
        X_source (n_s, D), X_target (n_t, D) -> int
    """
    if isinstance(level, bool) or not isinstance(level, (int, float)) or not 0.0 < level <= 1.0:
        raise ValueError(f"level: need a number in (0, 1], got {level!r}")
    return _sdm_choice(subspace_disagreement(X_source, X_target, max_dim), level)


def _sdm_choice(curve: np.ndarray, level: float) -> int:
    hits = np.flatnonzero(curve >= level)
    return int(hits[0]) + 1 if hits.size else len(curve)


def _check_basis(name: str, P) -> np.ndarray:
    P = _as_matrix(name, P)
    err = np.abs(P.T @ P - np.eye(P.shape[1])).max() if P.shape[1] else 0.0
    if err > _ORTHO_TOL:
        raise ValueError(f"{name}: columns are not orthonormal (max |PᵀP - I| = {err:.2e} > {_ORTHO_TOL})")
    return P


def _lambdas(theta: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    # np.sinc(x) = sin(πx)/(πx) is exact at 0, so these are stable down to θ = 0 with the right limits;
    # (1 - cos 2θ) / 4θ is rewritten as ½ sin θ · sin θ / θ to avoid the cancellation in 1 - cos 2θ.
    s2 = np.sinc(2.0 * theta / np.pi)  # sin 2θ / 2θ
    lam1 = 0.5 * (1.0 + s2)
    lam2 = -0.5 * np.sin(theta) * np.sinc(theta / np.pi)
    lam3 = 0.5 * (1.0 - s2)
    return lam1, lam2, lam3


def _gfk(P_s, P_t) -> tuple[np.ndarray, np.ndarray]:
    """Validated GFK and principal angles (ascending); see :func:`gfk_kernel`."""
    P_s = _check_basis("P_s", P_s)
    P_t = _check_basis("P_t", P_t)
    if P_s.shape != P_t.shape:
        raise ValueError(f"P_t: shape {P_t.shape} differs from P_s's {P_s.shape}")
    D, d = P_s.shape
    if d < 1 or 2 * d > D:
        raise ValueError(f"d: need 1 <= d and 2d <= D for the geodesic's complement part, got D={D}, d={d}")
    U1, gamma, Vt = np.linalg.svd(P_s.T @ P_t)
    V = Vt.T
    A = P_s @ U1
    # M = (I - P_s P_sᵀ) P_t V = -R_s U2 Σ has orthogonal columns of norm sin θ_i; reading sin θ off M
    # (instead of arccos of the singular values) keeps small angles accurate to round-off.
    PtV = P_t @ V
    M = PtV - P_s @ (P_s.T @ PtV)
    sigma = np.linalg.norm(M, axis=0)
    theta = np.arctan2(sigma, gamma)
    # a column with σ_i = 0 only meets λ2 = λ3 = 0; where σ_i is tiny the direction M_i/σ_i is noisy, but
    # its weights are O(θ_i), so the error in G stays at round-off level.
    B = -np.divide(M, sigma, out=np.zeros_like(M), where=sigma > 0)
    lam1, lam2, lam3 = _lambdas(theta)
    AB = (A * lam2) @ B.T
    G = (A * lam1) @ A.T + AB + AB.T + (B * lam3) @ B.T
    return 0.5 * (G + G.T), theta


def gfk_kernel(P_s, P_t) -> np.ndarray:
    """Geodesic Flow Kernel ``G = ∫_0^1 Φ(t) Φ(t)ᵀ dt`` between ``span(P_s)`` and ``span(P_t)``.

    This is Gong et al.'s eq. 6 exactly; their closed form (eq. 7) is ``2 G``.

    Args:
        P_s: orthonormal basis of the source subspace (e.g. :func:`pca_basis`).
        P_t: orthonormal basis of the target subspace, same shape; ``2d <= D``.

    Returns:
        ``G``, symmetric positive semi-definite, ``trace(G) = d``.

    Shapes:
        P_s (D, d), P_t (D, d) -> (D, D)
    """
    return _gfk(P_s, P_t)[0]


def _sqrt_psd(G: np.ndarray) -> np.ndarray:
    w, Q = np.linalg.eigh(G)
    # round-off can push G's zero eigenvalues slightly negative
    return (Q * np.sqrt(np.clip(w, 0.0, None))) @ Q.T


def gfk_embed(X, G) -> np.ndarray:
    """Embed rows of ``X`` as ``X G^{1/2}``, so that their dot products are the GFK ``x G zᵀ``.

    Euclidean distances between embedded rows are then GFK distances, which is what 1-NN and a linear
    SVM need.

    Args:
        X: samples in rows, in the feature space of ``G``.
        G: symmetric PSD kernel matrix (from :func:`gfk_kernel`); its square root is the symmetric one,
            from ``eigh``, with negative round-off eigenvalues clipped to 0.

    Shapes:
        X (n, D), G (D, D) -> (n, D)
    """
    X = _as_matrix("X", X)
    G = _as_matrix("G", G)
    if G.shape[0] != G.shape[1] or G.shape[0] != X.shape[1]:
        raise ValueError(f"G: need shape (D, D) with D = X.shape[1] = {X.shape[1]}, got {G.shape}")
    return X @ _sqrt_psd(0.5 * (G + G.T))


def _zscore_params(X: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    mean = X.mean(axis=0)
    std = X.std(axis=0)
    # a constant feature carries no information; leaving it unscaled avoids dividing by zero
    std[std == 0] = 1.0
    return mean, std


class GeodesicFlowKernel:
    """GFK domain adaptation, sklearn-like: ``fit(X_source, X_target)``, then ``transform``.

    ``fit`` takes the top-``dim`` PCA subspace of each domain (:func:`pca_basis`) and their kernel
    (:func:`gfk_kernel`, the integral of eq. 6, i.e. half Gong et al.'s eq. 7). ``transform`` embeds rows
    with :func:`gfk_embed`, so a 1-NN or linear SVM on the embedded source, applied to the embedded target,
    is the GFK+1NN / GFK+SVM baseline of thesis Table 7.4.

    With ``zscore=True`` (as Gong et al.'s code does) each domain is standardised with its own per-feature
    mean and (population) std before PCA, and ``transform`` must be told which domain the rows come from:
    ``transform(X, domain="source")`` or ``transform(X, domain="target")``; ``domain=None`` is then an
    error. With ``zscore=False`` (default) no preprocessing is done, neither in ``fit`` (beyond PCA's own
    centring) nor in ``transform``, and ``domain`` is accepted but has no effect.

    Args:
        dim: subspace dimension d; needs ``2 dim <= D`` and ``dim <= `` the number of samples of each
            domain. ``"sdm"``: Gong et al.'s choice by the subspace disagreement measure
            (:func:`sdm_dimension`, on the standardised data with ``zscore``).
        zscore: standardise each domain with its own statistics.

    Attributes (after ``fit``):
        dim_: the d used. sdm_: ``D(1) … D(d_max)`` of :func:`subspace_disagreement` (``dim="sdm"`` only).
        G_: ``(D, D)`` kernel. principal_angles_: ``(dim_,)`` radians, ascending. P_source_, P_target_:
        ``(D, dim_)`` PCA bases. source_mean_, source_std_, target_mean_, target_std_: ``(D,)`` z-score
        statistics (only with ``zscore=True``).

    Shapes:
        fit: X_source (n_s, D), X_target (n_t, D); transform: X (n, D) -> (n, D)
    """

    def __init__(self, dim: int | Literal["sdm"] = 20, zscore: bool = False):
        self.dim = dim
        self.zscore = zscore

    def fit(self, X_source, X_target) -> GeodesicFlowKernel:
        """Fit the two PCA subspaces and the kernel.

        Args:
            X_source: source samples in rows (e.g. descriptors of labelled visual clouds).
            X_target: target samples in rows, same features (e.g. descriptors of tactile clouds).

        Shapes:
            X_source (n_s, D), X_target (n_t, D) -> self
        """
        Xs, Xt = _check_pair(X_source, X_target)
        D = Xs.shape[1]
        d = self.dim
        sdm = isinstance(d, str) and d == "sdm"
        if not sdm:
            if isinstance(d, bool) or not isinstance(d, (int, np.integer)) or d < 1:
                raise ValueError(f"dim: need a positive integer or 'sdm', got {d!r}")
            if 2 * d > D:
                raise ValueError(f"dim: need 2 * dim <= D = {D} features, got dim = {d}")
            for name, X in (("X_source", Xs), ("X_target", Xt)):
                if X.shape[0] < max(d, 2):
                    raise ValueError(f"dim: {d} exceeds the {X.shape[0]} samples of {name} "
                                     f"(need >= max(dim, 2))")
        if self.zscore:
            self.source_mean_, self.source_std_ = _zscore_params(Xs)
            self.target_mean_, self.target_std_ = _zscore_params(Xt)
            Xs = (Xs - self.source_mean_) / self.source_std_
            Xt = (Xt - self.target_mean_) / self.target_std_
        if sdm:
            self.sdm_ = subspace_disagreement(Xs, Xt)
            d = _sdm_choice(self.sdm_, SDM_LEVEL)
        self.dim_ = int(d)
        self.P_source_ = pca_basis(Xs, d)
        self.P_target_ = pca_basis(Xt, d)
        self.G_, self.principal_angles_ = _gfk(self.P_source_, self.P_target_)
        self._sqrt_G = _sqrt_psd(self.G_)
        return self

    def transform(self, X, domain: Literal["source", "target"] | None = None) -> np.ndarray:
        """Embed rows with the fitted kernel (``X G^{1/2}``, after that domain's z-scoring if any).

        Args:
            X: samples in rows, with the features seen in ``fit``.
            domain: ``"source"`` or ``"target"``; required when ``zscore=True``, ignored otherwise.

        Shapes:
            X (n, D) -> (n, D)
        """
        if not hasattr(self, "G_"):
            raise RuntimeError("GeodesicFlowKernel: call fit() before transform()")
        if domain not in (None, "source", "target"):
            raise ValueError(f"domain: need 'source', 'target' or None, got {domain!r}")
        X = _as_matrix("X", X)
        D = self.G_.shape[0]
        if X.shape[1] != D:
            raise ValueError(f"X: has {X.shape[1]} features, the kernel was fitted on {D}")
        if self.zscore:
            if domain is None:
                raise ValueError("domain: with zscore=True say whether X is 'source' or 'target' data")
            mean, std = ((self.source_mean_, self.source_std_) if domain == "source"
                         else (self.target_mean_, self.target_std_))
            X = (X - mean) / std
        return X @ self._sqrt_G
