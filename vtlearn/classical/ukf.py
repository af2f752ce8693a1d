"""Unscented Kalman filter on a manifold (thesis ch.6, eq. 6.1-6.10; Appendix A.3.2, eq. A.21-A.27).

The filter follows the design of ukfm (Brossard et al., 2020, "A code for unscented Kalman filtering
on manifolds"): the whole filter is one class, and the manifold enters only through the retraction
``phi(x, xi)`` and its inverse ``phi_inv(x_ref, x)``. The state ``x`` can be any object (a 4x4 SE(3)
matrix for ArtReg, a plain vector for a Euclidean filter); its uncertainty lives in the tangent space
at the current estimate as a ``(d, d)`` covariance ``P``.

Sigma points and weights (eq. A.22), for a dimension ``n`` and scaling parameters alpha, beta, kappa:

    lambda      = alpha^2 (n + kappa) - n
    sigma^0     = 0                                  (the mean itself)
    sigma^i     = +(sqrt((n + lambda) P))_i          i = 1..n      (columns of a Cholesky factor)
    sigma^{i+n} = -(sqrt((n + lambda) P))_i
    W0^(m)      = lambda / (n + lambda)
    W0^(c)      = lambda / (n + lambda) + (1 - alpha^2 + beta)
    Wi^(m) = Wi^(c) = 1 / (2 (n + lambda))           i = 1..2n

Prediction (eq. 6.2-6.5): the mean goes through the noise-free process model directly,
``x_pred = f(x, u, 0)``. The state and the process noise each get their own sigma points: the state
sigma points ``phi(x, sigma^i)`` and the noise sigma points ``sigma'^i = +-(sqrt((q + lambda') Q))_i``
are propagated through ``f`` and mapped back to the tangent space at ``x_pred`` with ``phi_inv``:

    P_pred = sum_i W_i phi_inv(x_pred, f(phi(x, sigma^i), u, 0)) (.)^T          (6.3)
           + sum_i W'_i phi_inv(x_pred, f(x, u, sigma'^i)) (.)^T                 (6.4, 6.5)

Update (eq. 6.6-6.10): sigma points are drawn from ``P_pred`` on the manifold, all of them go through
the measurement model ``h`` in one call (so that ``h`` can be vectorised, as ArtReg's closest-point
model is), and

    z_hat = sum_i W^(m)_i h(sigma_M^i)                                            (6.6)
    Pzz   = sum_i W^(c)_i (h(sigma_M^i) - z_hat)(.)^T + R                         (6.7)
    Pxz   = sum_i W^(c)_i sigma^i (h(sigma_M^i) - z_hat)^T                        (6.7)
    K     = Pxz Pzz^-1                                                            (6.8)
    x     = phi(x_pred, K (z - z_hat))                                            (6.9)
    P     = P_pred - K Pzz K^T                                                    (6.10)

For long measurement vectors (ArtReg stacks thousands of 3-D points) with a diagonal ``R`` the gain is
computed with the Woodbury identity, so the cost grows linearly in the measurement dimension instead
of cubically; the result is the same ``K`` as eq. 6.8 up to round-off.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from vtlearn.validation import as_int, as_real

__all__ = ["ManifoldUKF", "SigmaWeights", "sigma_weights", "sigma_offsets"]


@dataclass(frozen=True)
class SigmaWeights:
    """Weights of eq. A.22 for one dimension ``n``.

    Attributes:
        n: dimension of the distribution the sigma points describe.
        lam: lambda = alpha^2 (n + kappa) - n.
        scale: sqrt(n + lambda), the factor on the Cholesky columns.
        wm0: W0^(m), the mean weight of the central point.
        wc0: W0^(c), the covariance weight of the central point.
        wi: Wi^(m) = Wi^(c) = 1 / (2 (n + lambda)) for the 2n outer points.
    """

    n: int
    lam: float
    scale: float
    wm0: float
    wc0: float
    wi: float

    @property
    def wm(self) -> np.ndarray:
        """Mean weights of all 2n + 1 points, central point first. Shape (2n + 1,)."""
        return np.concatenate([[self.wm0], np.full(2 * self.n, self.wi)])

    @property
    def wc(self) -> np.ndarray:
        """Covariance weights of all 2n + 1 points, central point first. Shape (2n + 1,)."""
        return np.concatenate([[self.wc0], np.full(2 * self.n, self.wi)])


def sigma_weights(n: int, alpha: float = 1.0, beta: float = 2.0, kappa: float = 0.0) -> SigmaWeights:
    """Sigma-point weights of eq. A.22 (thesis Appendix A.3.2).

    Args:
        n: dimension (M in the thesis; 6 for a pose on SE(3)).
        alpha: spread of the sigma points, > 0.
        beta: prior knowledge of the distribution (2 is optimal for a Gaussian).
        kappa: secondary scaling; ``n + lambda`` must stay positive.

    Raises:
        ValueError: naming the argument when n < 1, alpha <= 0 or n + lambda <= 0.
    """
    n = as_int(n, "n")
    alpha = as_real(alpha, "alpha", low=0.0, open_low=True)
    beta, kappa = as_real(beta, "beta"), as_real(kappa, "kappa")
    lam = alpha**2 * (n + kappa) - n
    if n + lam <= 0:
        raise ValueError(f"kappa gives n + lambda = {n + lam} <= 0; choose kappa > -n (kappa={kappa!r})")
    wm0 = lam / (n + lam)
    return SigmaWeights(
        n=n,
        lam=lam,
        scale=float(np.sqrt(n + lam)),
        wm0=wm0,
        wc0=wm0 + (1.0 - alpha**2 + beta),
        wi=1.0 / (2.0 * (n + lam)),
    )


def _sqrt_psd(P: np.ndarray) -> np.ndarray:
    """A matrix square root L with L L^T = P for a symmetric positive semi-definite P."""
    P = 0.5 * (P + P.T)
    try:
        return np.linalg.cholesky(P)
    except np.linalg.LinAlgError:
        # Semi-definite (e.g. a zero noise block): fall back on the eigen-decomposition.
        vals, vecs = np.linalg.eigh(P)
        return vecs * np.sqrt(np.clip(vals, 0.0, None))


def sigma_offsets(P: np.ndarray, weights: SigmaWeights) -> np.ndarray:
    """Tangent-space sigma points of eq. A.22 for a zero-mean covariance P.

    Shapes:
        P: (n, n) symmetric positive semi-definite.
        return: (2n, n); rows 0..n-1 are +(sqrt((n+lambda)P))_i, rows n..2n-1 are their negatives.
        The central point (zero) is not included.
    """
    L = weights.scale * _sqrt_psd(P)  # n x n, columns are the offsets
    return np.concatenate([L.T, -L.T], axis=0)


def _as_cov(M: Any, name: str, dim: int | None = None) -> np.ndarray:
    M = np.asarray(M, dtype=np.float64)
    if M.ndim == 0 or M.ndim == 1:
        raise ValueError(f"{name} must be a square (d, d) matrix, got shape {M.shape}")
    if M.ndim != 2 or M.shape[0] != M.shape[1]:
        raise ValueError(f"{name} must be a square (d, d) matrix, got shape {M.shape}")
    if dim is not None and M.shape[0] != dim:
        raise ValueError(f"{name} must be ({dim}, {dim}), got shape {M.shape}")
    if not np.all(np.isfinite(M)):
        raise ValueError(f"{name} contains NaN or inf")
    if not np.allclose(M, M.T, atol=1e-9 * max(1.0, float(np.abs(M).max()))):
        raise ValueError(f"{name} must be symmetric")
    if np.linalg.eigvalsh(0.5 * (M + M.T)).min() < -1e-9 * max(1.0, float(np.abs(M).max())):
        raise ValueError(f"{name} must be positive semi-definite")
    return 0.5 * (M + M.T)


def _as_meas_cov(R: Any, m: int, name: str = "R") -> np.ndarray:
    """R as a scalar variance, an (m,) diagonal or an (m, m) matrix -> (m,) or (m, m) array."""
    R = np.asarray(R, dtype=np.float64)
    if not np.all(np.isfinite(R)):
        raise ValueError(f"{name} contains NaN or inf")
    if R.ndim == 0:
        if R <= 0:
            raise ValueError(f"{name} as a scalar variance must be > 0, got {float(R)}")
        return np.full(m, float(R))
    if R.ndim == 1:
        if R.shape[0] != m:
            raise ValueError(f"{name} diagonal must have length {m} (the measurement size), got {R.shape[0]}")
        if np.any(R <= 0):
            raise ValueError(f"{name} diagonal entries must be > 0")
        return R
    return _as_cov(R, name, m)


class ManifoldUKF:
    """Unscented Kalman filter whose state lives on a manifold (thesis eq. 6.1-6.10, Algorithm 4).

    Args:
        f: process model ``f(x, u, w) -> x_next``; ``w`` is a process-noise vector of length ``q``
            (``np.zeros(q)`` for the noise-free propagation of eq. 6.2).
        h: measurement model evaluated on all sigma points at once:
            ``h(states: list) -> (S, m)`` array, one row per state (eq. 6.6).
        phi: retraction ``phi(x, xi) -> x`` mapping a tangent vector ``xi`` of length ``d`` at ``x``
            onto the manifold (the exponential map on SE(3)).
        phi_inv: its inverse ``phi_inv(x_ref, x) -> xi`` (the logarithmic map).
        Q: (q, q) process-noise covariance.
        R: measurement-noise covariance: a scalar variance (``R * I``), an (m,) diagonal, or an
            (m, m) matrix. ``update(z, R=...)`` may override it per step (ArtReg's measurement size
            changes from frame to frame).
        state0: initial state estimate.
        P0: (d, d) initial covariance in the tangent space at ``state0``.
        alpha, beta, kappa: sigma-point parameters of eq. A.22, shared by the state, noise and
            update sigma points (each set uses its own dimension n).

    Shapes:
        P: (d, d); Q: (q, q); z: (m,); h(states): (S, m) with S = 2d + 1.
    """

    def __init__(
        self,
        f: Callable[[Any, Any, np.ndarray], Any],
        h: Callable[[Sequence[Any]], np.ndarray],
        phi: Callable[[Any, np.ndarray], Any],
        phi_inv: Callable[[Any, Any], np.ndarray],
        Q: Any,
        R: Any,
        state0: Any,
        P0: Any,
        alpha: float = 1.0,
        beta: float = 2.0,
        kappa: float = 0.0,
    ) -> None:
        for name, fn in (("f", f), ("h", h), ("phi", phi), ("phi_inv", phi_inv)):
            if not callable(fn):
                raise ValueError(f"{name} must be callable, got {type(fn).__name__}")
        self.f, self.h, self.phi, self.phi_inv = f, h, phi, phi_inv
        self.P = _as_cov(P0, "P0")
        self.d = self.P.shape[0]
        self.Q = _as_cov(Q, "Q")
        self.q = self.Q.shape[0]
        self.R = R
        self.state = state0
        self.alpha, self.beta, self.kappa = float(alpha), float(beta), float(kappa)
        self.w_state = sigma_weights(self.d, alpha, beta, kappa)
        self.w_noise = sigma_weights(self.q, alpha, beta, kappa)
        # Statistics of the last update, handy for diagnostics (NIS, gating).
        self.last_innovation: np.ndarray | None = None
        self.last_gain: np.ndarray | None = None

    # ------------------------------------------------------------------ prediction (eq. 6.2-6.5)
    def predict(self, u: Any = None) -> Any:
        """Propagate the state and covariance one step (eq. 6.2-6.5). Returns the predicted state."""
        x = self.state
        w0 = np.zeros(self.q)
        x_pred = self.f(x, u, w0)  # eq. 6.2: mean straight through the noise-free model

        # eq. 6.3: state sigma points through f, back to the tangent space at x_pred.
        xis = sigma_offsets(self.P, self.w_state)
        dev_s = np.stack([self.phi_inv(x_pred, self.f(self.phi(x, xi), u, w0)) for xi in xis])
        P_s = self.w_state.wi * dev_s.T @ dev_s

        # eq. 6.4: process-noise sigma points through f.
        ws = sigma_offsets(self.Q, self.w_noise)
        dev_n = np.stack([self.phi_inv(x_pred, self.f(x, u, w)) for w in ws])
        P_n = self.w_noise.wi * dev_n.T @ dev_n

        self.state = x_pred
        self.P = 0.5 * ((P_s + P_n) + (P_s + P_n).T)  # eq. 6.5
        return x_pred

    # ------------------------------------------------------------------ update (eq. 6.6-6.10)
    def update(self, z: Any, R: Any = None, n_iterations: int = 1) -> Any:
        """Fuse a measurement ``z`` (eq. 6.6-6.10). Returns the updated state.

        Args:
            z: (m,) measurement vector.
            R: optional measurement covariance for this step (scalar, (m,) or (m, m)); defaults to
                the ``R`` given at construction.
            n_iterations: 1 is the update of eq. 6.6-6.10. With more, the measurement is
                re-linearised about the latest estimate (an iterated, Gauss-Newton update as in the
                iterated UKF / iterated posterior linearisation): sigma points with the *prior*
                covariance are drawn around the iterate ``x_j``, the statistical linearisation
                ``H_j = Pxz_j^T P^-1`` gives ``x_{j+1} = phi(x_pred, K_j (z - z_hat_j + H_j delta_j))``
                with ``delta_j = phi_inv(x_pred, x_j)``, and eq. 6.10 uses the last ``K_j``. The
                measurement is used once; only the linearisation point moves. Closest-point
                measurements (ArtReg) need this when an object moves far between frames.
        """
        z = np.asarray(z, dtype=np.float64).reshape(-1)
        if z.size == 0:
            raise ValueError("z is empty")
        if not np.all(np.isfinite(z)):
            raise ValueError("z contains NaN or inf")
        n_iterations = as_int(n_iterations, "n_iterations")
        m = z.shape[0]
        R_m = _as_meas_cov(self.R if R is None else R, m)

        x_pred, P = self.state, self.P
        w = self.w_state
        xis = sigma_offsets(P, w)  # (2d, d), the same tangent offsets at every iterate
        wm, wc = w.wm, w.wc
        x_j, delta = x_pred, np.zeros(self.d)
        for j in range(int(n_iterations)):
            sigmas = [x_j] + [self.phi(x_j, xi) for xi in xis]
            Z = np.asarray(self.h(sigmas), dtype=np.float64)
            if Z.shape != (2 * self.d + 1, m):
                raise ValueError(f"h must return shape ({2 * self.d + 1}, {m}), got {Z.shape}")
            z_hat = wm @ Z  # eq. 6.6
            D = Z - z_hat  # (S, m)
            Pxz = w.wi * xis.T @ D[1:]  # eq. 6.7, (d, m); the central point has sigma^0 = 0
            if R_m.ndim == 1 and m > D.shape[0]:
                K = self._gain_woodbury(D, wc, R_m, Pxz)
            else:
                Pzz = D.T @ (wc[:, None] * D) + (np.diag(R_m) if R_m.ndim == 1 else R_m)  # eq. 6.7
                K = np.linalg.solve(Pzz, Pxz.T).T  # eq. 6.8
            innovation = z - z_hat
            if j > 0:
                innovation = innovation + Pxz.T @ np.linalg.solve(P, delta)  # + H_j delta_j
            delta = K @ innovation
            x_j = self.phi(x_pred, delta)  # eq. 6.9
            if j + 1 < n_iterations:
                delta = self.phi_inv(x_pred, x_j)
        self.state = x_j
        # eq. 6.10: K Pzz K^T = K Pxz^T because K Pzz = Pxz.
        P_new = P - K @ Pxz.T
        self.P = 0.5 * (P_new + P_new.T)
        self.last_innovation, self.last_gain = innovation, K
        return self.state

    @staticmethod
    def _gain_woodbury(D: np.ndarray, wc: np.ndarray, r: np.ndarray, Pxz: np.ndarray) -> np.ndarray:
        """K = Pxz (D^T C D + diag(r))^-1 through the Woodbury identity, C = diag(wc).

        (diag(r) + D^T C D)^-1 = R^-1 - R^-1 D^T (C^-1 + D R^-1 D^T)^-1 D R^-1; sigma points with a
        zero covariance weight contribute nothing to Pzz and are dropped first.
        """
        keep = wc != 0.0
        D, wc = D[keep], wc[keep]
        B = D / r  # (S, m) = D R^-1
        A = Pxz / r  # (d, m) = Pxz R^-1
        inner = np.diag(1.0 / wc) + B @ D.T  # (S, S)
        return A - (A @ D.T) @ np.linalg.solve(inner, B)

    def step(self, z: Any, u: Any = None, R: Any = None, n_iterations: int = 1) -> Any:
        """One full filter cycle: :meth:`predict` then :meth:`update`. Returns the updated state."""
        self.predict(u)
        return self.update(z, R, n_iterations)
