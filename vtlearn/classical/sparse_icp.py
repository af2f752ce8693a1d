"""Sparse ICP (Bouaziz, Tagliasacchi, Pauly, SGP 2013), point-to-point, a baseline of thesis ch.5 (S-ICP).

ICP where the residuals ``z_i = R x_i + t - y_i`` are penalised by ``sum_i ||z_i||_2^p`` with ``p < 1``, which
ignores outlier pairs instead of averaging them in. Each ICP iteration solves
``min_{R,t,z} sum ||z_i||^p  s.t.  z_i = R x_i + t - y_i`` by ADMM with multipliers ``lambda_i``:

* z-step: the ``l_p`` shrinkage of ``h_i = R x_i + t - y_i + lambda_i / mu`` (Bouaziz et al., eq. 8-10),
* (R, t)-step: a rigid least-squares fit of ``x`` to ``y + z - lambda / mu`` (Kabsch/Umeyama),
* multiplier step: ``lambda_i += mu (R x_i + t - y_i - z_i)``.

All steps are vectorised over the points. Conventions: ``T_target_source`` maps source points into the target
frame; metres.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree

from vtlearn.validation import as_int, as_points, as_real, as_transform

__all__ = ["kabsch", "shrink_lp", "sparse_icp"]


def kabsch(x, y) -> np.ndarray:
    """Least-squares rigid ``T_y_x`` with ``y_i ~ R x_i + t`` (Umeyama 1991, no scale).

    Args:
        x: source points, finite, at least 3 (the rotation is unique only for 3 or more non-collinear
            points; collinear ones give one of the minimisers).
        y: target points, finite, the same number of rows as ``x``.

    Shapes:
        x, y: ``(N, 3)`` corresponding rows -> ``(4, 4)``.
    """
    x = as_points(x, "x", min_points=3)
    y = as_points(y, "y", min_points=3)
    if len(x) != len(y):
        raise ValueError(f"y: expected {len(x)} rows to match x, got {len(y)}")
    return _kabsch(x, y)


def _kabsch(x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """:func:`kabsch` without the argument checks (the ADMM inner loop)."""
    mx, my = x.mean(0), y.mean(0)
    U, _, Vt = np.linalg.svd((x - mx).T @ (y - my))
    D = np.diag([1.0, 1.0, np.sign(np.linalg.det(Vt.T @ U.T))])
    R = Vt.T @ D @ U.T
    T = np.eye(4)
    T[:3, :3] = R
    T[:3, 3] = my - R @ mx
    return T


def shrink_lp(h: np.ndarray, mu: float, p: float, n_fixed_point: int = 3) -> np.ndarray:
    """Solve ``argmin_z ||z||^p + mu/2 ||z - h||^2`` row-wise (Bouaziz et al. 2013, sec. 4).

    Below the threshold ``h_a = a + (p/mu) a^(p-1)``, ``a = (2 (1-p) / mu)^(1/(2-p))`` the minimiser is 0;
    above, ``z = beta h`` with ``beta = 1 - (p/mu) |h|^(p-2) beta^(p-1)`` found by fixed-point iteration.

    Args:
        h: finite points.
        mu: ADMM penalty, finite and > 0.
        p: norm exponent in (0, 1].
        n_fixed_point: fixed-point iterations, an integer >= 1.

    Shapes:
        h: ``(N, 3)`` -> ``(N, 3)``.
    """
    h = as_points(h, "h", min_points=0)
    mu = as_real(mu, "mu", low=0.0, open_low=True)
    p = as_real(p, "p", low=0.0, high=1.0, open_low=True)
    return _shrink_lp(h, mu, p, as_int(n_fixed_point, "n_fixed_point"))


def _shrink_lp(h: np.ndarray, mu: float, p: float, n_fixed_point: int = 3) -> np.ndarray:
    """:func:`shrink_lp` without the argument checks (the ADMM inner loop)."""
    a = (2.0 / mu * (1.0 - p)) ** (1.0 / (2.0 - p))
    ha = a + (p / mu) * a ** (p - 1.0)
    hn = np.linalg.norm(h, axis=1)
    beta = np.ones_like(hn)
    big = hn > ha
    hb = hn[big]
    b = beta[big]
    for _ in range(n_fixed_point):
        b = 1.0 - (p / mu) * hb ** (p - 2.0) * b ** (p - 1.0)
    beta[big] = b
    beta[~big] = 0.0
    return beta[:, None] * h


def sparse_icp(
    source,
    target,
    T_init=None,
    *,
    p: float = 0.4,
    mu: float = 10.0,
    max_icp: int = 100,
    max_admm: int = 20,
    tol: float = 1e-5,
    target_tree: cKDTree | None = None,
):
    """Register ``source`` to ``target`` with point-to-point sparse ICP.

    Args:
        source: points to move, e.g. the sparse scene.
        target: fixed points, e.g. the dense model.
        T_init: initial ``T_target_source``.
        p: norm exponent in (0, 1].
        mu: ADMM penalty (in 1/length^(2-p) units; 10 suits objects of about 1 m, as in Bouaziz et al.),
            finite and > 0.
        max_icp: correspondence iterations; max_admm: ADMM iterations per correspondence set; both
            integers >= 1.
        tol: stop when the largest source-point displacement of an ICP iteration is below ``tol`` (m).

    Shapes:
        source: ``(N, 3)``; target: ``(M, 3)``; T_init: ``(4, 4)``.

    Returns:
        ``(T_target_source (4, 4), icp_iterations)``.
    """
    X = as_points(source, "source", min_points=3)
    Y = as_points(target, "target", min_points=3)
    p = as_real(p, "p", low=0.0, high=1.0, open_low=True)
    mu = as_real(mu, "mu", low=0.0, open_low=True)
    max_icp = as_int(max_icp, "max_icp")
    max_admm = as_int(max_admm, "max_admm")
    T = np.eye(4) if T_init is None else as_transform(T_init, "T_init")
    tree = cKDTree(Y) if target_tree is None else target_tree
    Xt = X @ T[:3, :3].T + T[:3, 3]
    lam = np.zeros_like(X)
    Z = np.zeros_like(X)
    it = 0
    for it in range(1, max_icp + 1):  # noqa: B007 - the last value is the iteration count returned
        _, idx = tree.query(Xt, k=1)
        Q = Y[idx]
        X_prev = Xt
        for _ in range(max_admm):
            Z = _shrink_lp(Xt - Q + lam / mu, mu, p)
            T_step = _kabsch(Xt, Q + Z - lam / mu)
            Xt = Xt @ T_step[:3, :3].T + T_step[:3, 3]
            T = T_step @ T
            delta = Xt - Q - Z
            lam = lam + mu * delta
            if np.abs(delta).max() < tol:
                break
        if np.abs(Xt - X_prev).max() < tol:
            break
    return T, it
