"""TIQF: the Translation-Invariant Quaternion Filter (thesis ch.4, eq. 4.1-4.23; Appendix B for the KL).

Point cloud registration ``s_i = R o_i + t`` (eq. 4.1) is split into rotation and translation. Differences of
two correspondences cancel the translation, ``s_ji = R o_ji`` (eq. 4.3), which in quaternion algebra is the
linear pseudo-measurement ``H(s_ji, o_ji) x = 0`` (eq. 4.12-4.14) in the rotation quaternion ``x``. A Kalman
filter with the state-dependent measurement noise of eq. 4.18 estimates ``x`` (eq. 4.19-4.21), the state is
renormalised (eq. 4.22) and the translation follows in closed form (eq. 4.23). An outer loop re-estimates the
correspondences by the closest-point rule until the pose changes by less than 0.1 mm and 0.1 degrees or 100
iterations pass (thesis 4.2.3).

Conventions: quaternions are Hamilton (w, x, y, z); ``T_scene_model`` maps model points into the scene frame;
units are metres.

Implementation notes (where the thesis text is ambiguous or has a typo):

* Eq. 4.12/4.13 prints the lower-right block as ``[s_j + s_i + o_j + o_i]x``. Expanding eq. 4.11,
  ``L(s~_ji) - R(o~_ji)`` gives ``[s_ji + o_ji]x``; that is the matrix for which ``H x = 0`` holds for the
  true rotation, so it is what :func:`pseudo_measurement_matrix` builds.
* A batch of ``M`` pairs is ``M`` stacked 4-row measurements with block-diagonal noise
  ``blockdiag(P_v, ..., P_v)``. Eq. 4.19-4.21 are evaluated in the algebraically identical information form
  (matrix inversion lemma): ``P+ = (P^-1 + sum_m H_m^T P_v^-1 H_m)^-1`` and ``K H x = P+ sum_m H_m^T P_v^-1
  H_m x``. Only 4x4 matrices are inverted, whatever ``M`` is; ``tests/test_tiqf.py`` checks it against the
  literal 4M x 4M form.
* Choice of pairs (i, j) for a batch of N correspondences: all pairs i < j when N <= ``max_all_pairs``
  (the estimate then does not depend on any ordering; as ``H`` is linear in ``(s_ji, o_ji)`` and the sum over
  all pairs of their outer products is N times the centred second moment, this costs O(N), see
  :func:`tiqf_update_moment`), otherwise ``n_shifts`` random cyclic shifts of a random permutation
  (``n_shifts * N`` pairs, every point used ``2 * n_shifts`` times, long baselines on average).
* Batch mode: every outer iteration changes the correspondences, so the pseudo-measurements of the previous
  iteration are superseded rather than repeated. The update therefore starts each outer iteration from the
  current mean with the initial covariance ``Sigma_0`` (``reset_covariance=True``); otherwise the information
  of stale correspondences would accumulate and freeze the filter. In sequential mode
  (:class:`SequentialTIQF`, ``mode="carry"``) the covariance carries over between touches and each touch only
  adds the pairs that contain a new point, so after all touches the filter has seen every pair exactly once;
  ``mode="reassociate"`` re-derives the posterior from the initial belief with all pairs at the current
  correspondences.
* Local-minimum escape (thesis 4.3.2): after convergence, the rotation is perturbed by angles drawn from
  U[-2, 2] degrees about each axis and the filter is rerun; a perturbed solution is kept when it lowers the
  correspondence RMSE.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy.spatial import cKDTree

from vtlearn.classical.correspondences import TangentPlanes
from vtlearn.validation import as_int, as_points, as_real, as_transform

__all__ = [
    "pseudo_measurement_matrix",
    "measurement_noise_covariance",
    "tiqf_update",
    "tiqf_update_moment",
    "all_pairs_moment",
    "tiqf_translation",
    "make_pairs",
    "gaussian_kl",
    "TIQF",
    "TIQFResult",
    "SequentialTIQF",
]


# ----------------------------------------------------------------------------------------------------------
# numpy quaternion helpers for the inner loops (the torch-based vtlearn.geometry versions cost a tensor round
# trip per call, which dominates at 4x4 sizes; tests/test_tiqf.py checks these against vtlearn.geometry).
def _quat_to_matrix(q: np.ndarray) -> np.ndarray:
    """Unit quaternion(s) (w, x, y, z) ``(..., 4)`` -> rotation matrices ``(..., 3, 3)``."""
    w, x, y, z = np.moveaxis(q, -1, 0)
    return np.stack(
        [
            np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)], -1),
            np.stack([2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)], -1),
            np.stack([2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)], -1),
        ],
        -2,
    )


def _matrix_to_quat(R: np.ndarray) -> np.ndarray:
    """Rotation matrix ``(3, 3)`` -> unit quaternion (w, x, y, z) with w >= 0 (Shepperd's method)."""
    m = R
    tr = m[0, 0] + m[1, 1] + m[2, 2]
    if tr > 0:
        s = np.sqrt(tr + 1.0) * 2
        q = [0.25 * s, (m[2, 1] - m[1, 2]) / s, (m[0, 2] - m[2, 0]) / s, (m[1, 0] - m[0, 1]) / s]
    elif m[0, 0] > m[1, 1] and m[0, 0] > m[2, 2]:
        s = np.sqrt(1.0 + m[0, 0] - m[1, 1] - m[2, 2]) * 2
        q = [(m[2, 1] - m[1, 2]) / s, 0.25 * s, (m[0, 1] + m[1, 0]) / s, (m[0, 2] + m[2, 0]) / s]
    elif m[1, 1] > m[2, 2]:
        s = np.sqrt(1.0 + m[1, 1] - m[0, 0] - m[2, 2]) * 2
        q = [(m[0, 2] - m[2, 0]) / s, (m[0, 1] + m[1, 0]) / s, 0.25 * s, (m[1, 2] + m[2, 1]) / s]
    else:
        s = np.sqrt(1.0 + m[2, 2] - m[0, 0] - m[1, 1]) * 2
        q = [(m[1, 0] - m[0, 1]) / s, (m[0, 2] + m[2, 0]) / s, (m[1, 2] + m[2, 1]) / s, 0.25 * s]
    q = np.asarray(q, dtype=np.float64)
    q /= np.linalg.norm(q)
    return q if q[0] >= 0 else -q


def _skew(v: np.ndarray) -> np.ndarray:
    """``[v]x`` for ``(..., 3)`` -> ``(..., 3, 3)``."""
    x, y, z = np.moveaxis(v, -1, 0)
    o = np.zeros_like(x)
    return np.stack([np.stack([o, -z, y], -1), np.stack([z, o, -x], -1), np.stack([-y, x, o], -1)], -2)


def _rotation_from_euler_small(angles: np.ndarray) -> np.ndarray:
    """Rotation ``Rz Ry Rx`` from three angles (radians); used for the small escape perturbations."""
    ax, ay, az = angles
    cx, sx, cy, sy, cz, sz = np.cos(ax), np.sin(ax), np.cos(ay), np.sin(ay), np.cos(az), np.sin(az)
    Rx = np.array([[1, 0, 0], [0, cx, -sx], [0, sx, cx]])
    Ry = np.array([[cy, 0, sy], [0, 1, 0], [-sy, 0, cy]])
    Rz = np.array([[cz, -sz, 0], [sz, cz, 0], [0, 0, 1]])
    return Rz @ Ry @ Rx


def _check_quaternion(q, name: str, *, batched: bool = False) -> np.ndarray:
    """``q`` as a float array if it is a finite quaternion (w, x, y, z) of norm > 1e-9.

    ``batched`` allows leading dimensions ``(..., 4)``; otherwise the shape must be ``(4,)``.
    """
    try:
        q = np.asarray(q, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise ValueError(f"{name}: cannot be converted to a float array ({exc})") from None
    ok = q.shape[-1:] == (4,) if batched else q.shape == (4,)
    if not ok:
        want = "(..., 4)" if batched else "(4,)"
        raise ValueError(f"{name}: expected a quaternion (w, x, y, z) of shape {want}, got {q.shape}")
    if not np.isfinite(q).all():
        raise ValueError(f"{name}: contains NaN or inf")
    if not (np.linalg.norm(q, axis=-1) > 1e-9).all():
        raise ValueError(f"{name}: quaternion has (near) zero norm; it must be non-zero")
    return q


def _rotation_angle_deg(R_a: np.ndarray, R_b: np.ndarray) -> float:
    c = (np.trace(R_a.T @ R_b) - 1.0) / 2.0
    return float(np.degrees(np.arccos(np.clip(c, -1.0, 1.0))))


# ----------------------------------------------------------------------------------------------------------
# The filter equations
def pseudo_measurement_matrix(s_ji, o_ji) -> np.ndarray:
    """Pseudo-measurement matrix ``H`` of thesis eq. 4.13 (with the corrected skew block, see module doc).

    ``H = [[0, -(s_ji - o_ji)^T], [s_ji - o_ji, [s_ji + o_ji]x]]`` so that ``H x = 0`` for the true rotation
    quaternion ``x`` (w, x, y, z) when ``s_ji = R(x) o_ji`` (eq. 4.12).

    Args:
        s_ji: scene difference vectors ``s_j - s_i``.
        o_ji: model difference vectors ``o_j - o_i``.

    Shapes:
        s_ji, o_ji: ``(..., 3)`` -> ``(..., 4, 4)``.
    """
    s_ji = np.asarray(s_ji, dtype=np.float64)
    o_ji = np.asarray(o_ji, dtype=np.float64)
    if s_ji.shape != o_ji.shape or s_ji.shape[-1:] != (3,):
        raise ValueError(f"s_ji, o_ji: expected equal shapes (..., 3), got {s_ji.shape} and {o_ji.shape}")
    d = s_ji - o_ji
    H = np.zeros(s_ji.shape[:-1] + (4, 4))
    H[..., 0, 1:] = -d
    H[..., 1:, 0] = d
    H[..., 1:, 1:] = _skew(s_ji + o_ji)
    return H


def measurement_noise_covariance(x, P, rho: float) -> np.ndarray:
    """State-dependent pseudo-measurement noise ``P_v`` of thesis eq. 4.18.

    ``P_v = rho / 4 * (tr(x x^T + P) I_4 - (x x^T + P))``.

    Args:
        x: quaternion mean (w, x, y, z).
        P: its covariance.
        rho: correspondence uncertainty (> 0).

    Shapes:
        x: ``(..., 4)``; P: ``(..., 4, 4)`` -> ``(..., 4, 4)``.
    """
    rho = as_real(rho, "rho", low=0.0, open_low=True)
    x = np.asarray(x, dtype=np.float64)
    A = x[..., :, None] * x[..., None, :] + np.asarray(P, dtype=np.float64)
    tr = np.trace(A, axis1=-2, axis2=-1)[..., None, None]
    return 0.25 * rho * (tr * np.eye(4) - A)


def tiqf_update(x, P, s_ji, o_ji, rho: float, weights=None) -> tuple[np.ndarray, np.ndarray]:
    """One Kalman update of the rotation quaternion from a batch of pairs (eq. 4.18-4.22).

    The stacked measurement of ``M`` pairs with noise ``blockdiag(P_v)`` is processed in information form,
    identical to eq. 4.19-4.21 by the matrix inversion lemma (see module doc). Leading batch dimensions
    (for instance one per candidate touch in the active look-ahead) are processed in one go.

    Args:
        x: prior quaternion mean (w, x, y, z), unit norm; finite and non-zero.
        P: prior covariance, finite.
        s_ji, o_ji: scene and model difference vectors of the pairs, finite.
        rho: correspondence uncertainty of eq. 4.18.
        weights: optional per-pair weights in [0, 1] (0 masks a padded pair).

    Shapes:
        x: ``(..., 4)``; P: ``(..., 4, 4)``; s_ji, o_ji: ``(..., M, 3)``; weights: ``(..., M)``.
        Returns the posterior ``x`` ``(..., 4)`` (renormalised, eq. 4.22) and ``P`` ``(..., 4, 4)``.
    """
    x = _check_quaternion(x, "x", batched=True)
    P = np.asarray(P, dtype=np.float64)
    if P.shape[-2:] != (4, 4):
        raise ValueError(f"P: expected a covariance of shape (..., 4, 4), got {P.shape}")
    if not np.isfinite(P).all():
        raise ValueError("P: contains NaN or inf")
    s_ji = np.asarray(s_ji, dtype=np.float64)
    o_ji = np.asarray(o_ji, dtype=np.float64)
    for arr, name in ((s_ji, "s_ji"), (o_ji, "o_ji")):
        if not np.isfinite(arr).all():
            raise ValueError(f"{name}: contains NaN or inf")
    if weights is not None:
        weights = np.asarray(weights, dtype=np.float64)
        if not (np.isfinite(weights).all() and (weights >= 0).all() and (weights <= 1).all()):
            raise ValueError("weights: must be finite and in [0, 1]")
    return _tiqf_update(x, P, s_ji, o_ji, rho, weights)


def _tiqf_update(x, P, s_ji, o_ji, rho: float, weights=None) -> tuple[np.ndarray, np.ndarray]:
    """:func:`tiqf_update` without the argument checks (the filter loops)."""
    x = np.asarray(x, dtype=np.float64)
    P = np.asarray(P, dtype=np.float64)
    H = pseudo_measurement_matrix(s_ji, o_ji)  # ...xMx4x4
    Pv = measurement_noise_covariance(x, P, rho)  # ...x4x4
    W = np.linalg.inv(Pv)
    WH = np.einsum("...ab,...mbc->...mac", W, H)  # ...xMx4x4
    if weights is not None:
        WH = WH * np.asarray(weights, dtype=np.float64)[..., None, None]
    Lam = np.einsum("...mba,...mbc->...ac", H, WH)  # sum_m H_m^T P_v^-1 H_m, ...x4x4
    return _posterior(x, P, Lam)


_H_BASIS = None


def _h_basis() -> np.ndarray:
    """``B_k`` with ``H(s_ji, o_ji) = sum_k u_k B_k`` for ``u = (s_ji, o_ji)`` (H is linear in u)."""
    global _H_BASIS
    if _H_BASIS is None:
        e = np.eye(6)
        _H_BASIS = pseudo_measurement_matrix(e[:, :3], e[:, 3:])  # 6x4x4
    return _H_BASIS


def all_pairs_moment(scene_points, model_points) -> np.ndarray:
    """``sum_{i<j} u_ji u_ji^T`` over all pairs, with ``u_ji = (s_ji, o_ji)``, in O(N).

    Uses ``sum_{i<j} (p_j - p_i)(p_j - p_i)^T = N sum_i (p_i - p_mean)(p_i - p_mean)^T``.

    Shapes:
        scene_points, model_points: ``(..., N, 3)`` -> ``(..., 6, 6)``.
    """
    u = np.concatenate([scene_points, model_points], -1)
    u = u - u.mean(-2, keepdims=True)
    return u.shape[-2] * np.einsum("...na,...nb->...ab", u, u)


def tiqf_update_moment(x, P, M, rho: float) -> tuple[np.ndarray, np.ndarray]:
    """:func:`tiqf_update` for pairs summarised by their second moment ``M = sum_m u_m u_m^T``.

    Because ``H`` is linear in ``u = (s_ji, o_ji)`` and every pair shares ``P_v``,
    ``sum_m H_m^T P_v^-1 H_m = sum_kl M_kl B_k^T P_v^-1 B_l`` exactly (``B`` from :func:`_h_basis`).
    With :func:`all_pairs_moment` this is the all-pairs update in O(N) instead of O(N^2).

    Shapes:
        x: ``(..., 4)``; P: ``(..., 4, 4)``; M: ``(..., 6, 6)``.
    """
    x = np.asarray(x, dtype=np.float64)
    P = np.asarray(P, dtype=np.float64)
    B = _h_basis()
    W = np.linalg.inv(measurement_noise_covariance(x, P, rho))
    WB = np.einsum("...ab,lbc->...lac", W, B)  # ...x6x4x4
    Lam = np.einsum("...kl,kba,...lbc->...ac", M, B, WB)
    return _posterior(x, P, Lam)


def _posterior(x, P, Lam):
    """Information-form eq. 4.19-4.21 followed by the renormalisation eq. 4.22."""
    P_post = np.linalg.inv(np.linalg.inv(P) + Lam)
    P_post = 0.5 * (P_post + np.swapaxes(P_post, -1, -2))
    x_post = x - np.einsum("...ab,...bc,...c->...a", P_post, Lam, x)  # eq. 4.19 with K H x = P+ Lam x
    n = np.linalg.norm(x_post, axis=-1)
    return x_post / n[..., None], P_post / (n**2)[..., None, None]


def tiqf_translation(R, scene_points, model_points) -> np.ndarray:
    """Closed-form translation of eq. 4.23: ``t = mean_i(s_i - R o_i)``.

    Args:
        R: finite rotation ``R_scene_model``.
        scene_points, model_points: finite, at least 1, the same number of rows.

    Shapes:
        R: ``(3, 3)``; scene_points, model_points: ``(N, 3)`` corresponding rows -> ``(3,)``.
    """
    R = np.asarray(R, dtype=np.float64)
    if R.shape != (3, 3) or not np.isfinite(R).all():
        raise ValueError(f"R: expected a finite (3, 3) rotation, got shape {R.shape}")
    s = as_points(scene_points, "scene_points", min_points=1)
    o = as_points(model_points, "model_points", min_points=1)
    if len(s) != len(o):
        raise ValueError(f"scene_points: expected {len(o)} rows to match model_points, got {len(s)}")
    return _translation(R, s, o)


def _translation(R: np.ndarray, scene_points: np.ndarray, model_points: np.ndarray) -> np.ndarray:
    """:func:`tiqf_translation` without the argument checks (the filter loops)."""
    return np.mean(scene_points - model_points @ R.T, axis=0)


def make_pairs(
    n: int, *, max_all_pairs: int = 4096, n_shifts: int = 8, rng=None
) -> tuple[np.ndarray, np.ndarray]:
    """Index pairs ``(i, j)`` for a batch of ``n`` correspondences (see module doc for the rule).

    Returns:
        ``(i, j)`` integer arrays of equal length ``M``.
    """
    n = as_int(n, "n", minimum=2)
    if n <= max_all_pairs:
        i, j = np.triu_indices(n, k=1)
        return i, j
    rng = np.random.default_rng(rng)
    perm = rng.permutation(n)
    shifts = rng.choice(np.arange(1, n), size=min(n_shifts, n - 1), replace=False)
    i = np.tile(perm, len(shifts))
    j = np.concatenate([np.roll(perm, -int(s)) for s in shifts])
    return i, j


def gaussian_kl(mu_p, Sigma_p, mu_q, Sigma_q) -> np.ndarray:
    """Closed-form ``KL(p || q)`` between Gaussians ``p = N(mu_p, Sigma_p)`` and ``q = N(mu_q, Sigma_q)``.

    Appendix B: ``KL = 1/2 [log(det Sigma_q / det Sigma_p) + tr(Sigma_q^-1 Sigma_p) - d
    + (mu_q - mu_p)^T Sigma_q^-1 (mu_q - mu_p)]``. For the information gain of eq. 4.24/4.25, ``p`` is the
    (hypothetical) posterior and ``q`` the prior. Eq. 4.25 prints the posterior covariance inside the
    Mahalanobis term; Appendix B's derivation gives the prior (``q``), which is what is used here.

    Shapes:
        mu_p, mu_q: ``(..., d)``; Sigma_p, Sigma_q: ``(..., d, d)`` (broadcastable) -> ``(...)``.
    """
    mu_p = np.asarray(mu_p, dtype=np.float64)
    mu_q = np.asarray(mu_q, dtype=np.float64)
    Sigma_p = np.asarray(Sigma_p, dtype=np.float64)
    Sigma_q = np.asarray(Sigma_q, dtype=np.float64)
    d = mu_p.shape[-1]
    _, logdet_p = np.linalg.slogdet(Sigma_p)
    _, logdet_q = np.linalg.slogdet(Sigma_q)
    Sq_inv = np.linalg.inv(Sigma_q)
    trace = np.einsum("...ab,...ba->...", Sq_inv, Sigma_p)
    diff = mu_q - mu_p
    maha = np.einsum("...a,...ab,...b->...", diff, Sq_inv, diff)
    return 0.5 * (logdet_q - logdet_p + trace - d + maha)


# ----------------------------------------------------------------------------------------------------------
@dataclass
class TIQFResult:
    """Output of :meth:`TIQF.register`.

    Attributes:
        T_scene_model: ``(4, 4)`` maps model points into the scene frame.
        q: rotation quaternion (w, x, y, z) ``(4,)``; P: its covariance ``(4, 4)``.
        iterations: outer (correspondence) iterations run in total, escapes included.
        rmse: RMSE of the final scene-to-model correspondence distances (m).
    """

    T_scene_model: np.ndarray
    q: np.ndarray
    P: np.ndarray
    iterations: int
    rmse: float
    history: list = field(default_factory=list)


def _closest_point_correspondences(tree: cKDTree, scene_in_model: np.ndarray):
    d, idx = tree.query(scene_in_model, k=1)
    return d, idx


class TIQF:
    """Batch-mode TIQF registration with closest-point correspondences (thesis 4.2.3, eq. 4.1-4.23).

    Args:
        rho: correspondence uncertainty of eq. 4.18 (m^2 scale; smaller trusts the pairs more).
        sigma0: initial quaternion covariance ``Sigma_0 = sigma0 * I_4`` (the thesis uses ``I_4``).
        max_iter: outer iterations (thesis: 100).
        tol_trans: convergence threshold on the translation change (m; thesis: 0.1 mm).
        tol_rot_deg: convergence threshold on the rotation change (degrees; thesis: 0.1).
        reset_covariance: restart each outer iteration from ``Sigma_0`` (see module doc).
        max_all_pairs, n_shifts: pair selection, see :func:`make_pairs`.
        n_escapes: number of local-minimum escape attempts (thesis 4.3.2); 0 disables them.
        escape_deg: half-width of the uniform perturbation per axis (thesis: 2 degrees).
        seed: seeds pair selection and the escape perturbations.
    """

    def __init__(
        self,
        rho: float = 1e-2,
        sigma0: float = 1.0,
        max_iter: int = 100,
        tol_trans: float = 1e-4,
        tol_rot_deg: float = 0.1,
        reset_covariance: bool = True,
        max_all_pairs: int = 4096,
        n_shifts: int = 8,
        n_escapes: int = 0,
        escape_deg: float = 2.0,
        seed: int | None = 0,
    ):
        as_real(rho, "rho", low=0.0, open_low=True)
        as_real(sigma0, "sigma0", low=0.0, open_low=True)
        max_iter = as_int(max_iter, "max_iter")
        self.rho = rho
        self.sigma0 = sigma0
        self.max_iter = max_iter
        self.tol_trans = tol_trans
        self.tol_rot_deg = tol_rot_deg
        self.reset_covariance = reset_covariance
        self.max_all_pairs = max_all_pairs
        self.n_shifts = n_shifts
        self.n_escapes = n_escapes
        self.escape_deg = escape_deg
        self.seed = seed

    def __repr__(self) -> str:
        return (
            f"TIQF(rho={self.rho}, sigma0={self.sigma0}, max_iter={self.max_iter}, "
            f"n_escapes={self.n_escapes})"
        )

    # -- one filter step with given correspondences ------------------------------------------------------
    def update(self, x, P, scene_points, model_points, rng=None):
        """Kalman update from index-aligned correspondences ``scene_points[k] <-> model_points[k]``.

        Shapes:
            x: ``(4,)``; P: ``(4, 4)``; scene_points, model_points: ``(N, 3)``, N >= 2.
        """
        if len(scene_points) <= self.max_all_pairs:
            return tiqf_update_moment(x, P, all_pairs_moment(scene_points, model_points), self.rho)
        i, j = make_pairs(len(scene_points), max_all_pairs=0, n_shifts=self.n_shifts, rng=rng)
        s_ji = scene_points[j] - scene_points[i]
        o_ji = model_points[j] - model_points[i]
        return _tiqf_update(x, P, s_ji, o_ji, self.rho)

    def solve_known_correspondences(self, model_points, scene_points, q_init=None, n_iter: int | None = None):
        """Register index-aligned correspondences (``scene[k] = R model[k] + t``), no correspondence search.

        Repeats the update until the rotation change is below ``tol_rot_deg`` (or ``n_iter`` updates).

        Args:
            model_points, scene_points: index-aligned correspondences, finite, at least 3, equal lengths.
            q_init: initial rotation quaternion (w, x, y, z), shape ``(4,)``, finite, norm > 1e-9
                (normalised here); default identity.
            n_iter: maximum number of updates (default ``max_iter``).

        Shapes:
            model_points, scene_points: ``(N, 3)`` -> ``T_scene_model`` ``(4, 4)``, q ``(4,)``, P ``(4, 4)``.
        """
        o = as_points(model_points, "model_points", min_points=3)
        s = as_points(scene_points, "scene_points", min_points=3)
        if len(o) != len(s):
            raise ValueError(f"scene_points: expected {len(o)} rows to match model_points, got {len(s)}")
        rng = np.random.default_rng(self.seed)
        if q_init is None:
            x = np.array([1.0, 0, 0, 0])
        else:
            x = _check_quaternion(q_init, "q_init")
            x = x / np.linalg.norm(x)
        P = self.sigma0 * np.eye(4)
        n_iter = self.max_iter if n_iter is None else n_iter
        for _ in range(n_iter):
            R_old = _quat_to_matrix(x)
            P_prior = self.sigma0 * np.eye(4) if self.reset_covariance else P
            x, P = self.update(x, P_prior, s, o, rng)
            if _rotation_angle_deg(R_old, _quat_to_matrix(x)) < self.tol_rot_deg:
                break
        R = _quat_to_matrix(x)
        T = np.eye(4)
        T[:3, :3] = R
        T[:3, 3] = _translation(R, s, o)
        return T, x, P

    # -- ICP-style outer loop ----------------------------------------------------------------------------
    def _run(self, tree, model, scene, x, t, rng, correspondences=None):
        """Outer loop from quaternion ``x`` and translation ``t``; returns (x, P, t, iters, rmse)."""
        P = self.sigma0 * np.eye(4)
        it = 0
        R = _quat_to_matrix(x)
        for it in range(1, self.max_iter + 1):  # noqa: B007 - the last value is the count returned
            scene_in_model = (scene - t) @ R  # R^T (s - t)
            if correspondences is None:
                _, idx = tree.query(scene_in_model, k=1)
                s_sel, o_sel = scene, model[idx]
            else:
                s_sel, o_sel = correspondences(scene_in_model, R, t)
            if len(s_sel) < 3:
                break
            P_prior = self.sigma0 * np.eye(4) if self.reset_covariance else P
            x, P = self.update(x, P_prior, s_sel, o_sel, rng)
            R_new = _quat_to_matrix(x)
            t_new = _translation(R_new, s_sel, o_sel)
            dt = np.linalg.norm(t_new - t)
            dr = _rotation_angle_deg(R, R_new)
            R, t = R_new, t_new
            if dt < self.tol_trans and dr < self.tol_rot_deg:
                break
        d, _ = tree.query((scene - t) @ R, k=1)
        rmse = float(np.sqrt(np.mean(d**2)))
        return x, P, t, it, rmse

    def register(self, model, scene, T_init=None, model_tree: cKDTree | None = None, correspondences=None):
        """Estimate ``T_scene_model`` from unordered clouds (batch mode, closest-point correspondences).

        Args:
            model: model cloud O.
            scene: scene cloud S (dense visual or sparse tactile).
            T_init: initial ``T_scene_model`` (default identity).
            model_tree: optional prebuilt ``cKDTree(model)``.
            correspondences: optional callable ``(scene_in_model, R, t) -> (s_sel, o_sel)`` that replaces the
                closest-point rule (S-TIQF passes best-buddy pairs).

        Shapes:
            model: ``(M, 3)``; scene: ``(N, 3)``, N >= 3; T_init: ``(4, 4)``.
        """
        model = as_points(model, "model", min_points=3)
        scene = as_points(scene, "scene", min_points=3)
        T0 = np.eye(4) if T_init is None else as_transform(T_init, "T_init")
        tree = cKDTree(model) if model_tree is None else model_tree
        rng = np.random.default_rng(self.seed)
        x = _matrix_to_quat(T0[:3, :3])
        t = T0[:3, 3].copy()
        x, P, t, iters, rmse = self._run(tree, model, scene, x, t, rng, correspondences)
        history = [rmse]
        total = iters
        for _ in range(self.n_escapes):
            angles = np.radians(rng.uniform(-self.escape_deg, self.escape_deg, size=3))
            R_pert = _quat_to_matrix(x) @ _rotation_from_euler_small(angles)
            # keep the model centroid fixed in the scene while perturbing its rotation
            c = model.mean(0)
            t_pert = t + _quat_to_matrix(x) @ c - R_pert @ c
            x2, P2, t2, it2, rmse2 = self._run(
                tree, model, scene, _matrix_to_quat(R_pert), t_pert, rng, correspondences
            )
            total += it2
            history.append(rmse2)
            if rmse2 < rmse:
                x, P, t, rmse = x2, P2, t2, rmse2
        T = np.eye(4)
        T[:3, :3] = _quat_to_matrix(x)
        T[:3, 3] = t
        return TIQFResult(T_scene_model=T, q=x, P=P, iterations=total, rmse=rmse, history=history)


class SequentialTIQF:
    """Sequential TIQF: points arrive one touch at a time and the filter state carries over (thesis 4.2.2).

    Each :meth:`add` appends the touch's points and performs one Kalman update from the carried prior with
    the pairs that contain at least one new point (old-old pairs were already used by earlier touches).
    The correspondences of all points are re-estimated by the closest-point rule at the current pose
    ``inner_iter`` times, each time redoing the update of this touch from the same prior; the translation
    follows eq. 4.23 over all points.

    Args:
        model: model cloud O ``(M, 3)``.
        T_init: initial ``T_scene_model`` (e.g. from vision), ``(4, 4)``.
        P_init: initial quaternion covariance ``(4, 4)`` (thesis: ``I_4``).
        rho: correspondence uncertainty of eq. 4.18.
        inner_iter: correspondence re-estimations per touch.
        refine: after the sequential update, re-estimate the mean with the batch outer loop (:class:`TIQF`,
            closest points for all measured points, ``n_escapes`` perturbation escapes) from the current
            estimate. The covariance stays the sequential one. Without it, pairs whose correspondences were
            wrong at the time of their touch keep pulling the mean (their information is frozen in ``P``),
            which stalls the filter from a poor initial pose; Algorithm 1 likewise re-estimates the
            correspondences of all points at every touch.
        n_escapes: escape attempts of the refinement (thesis 4.3.2).
        tangent: pair each point with the foot on the model's local tangent plane
            (:class:`~vtlearn.classical.correspondences.TangentPlanes`) instead of the nearest sample.
        mode: ``"carry"`` is the filter as written in 4.2.2: the prior of each touch is the previous
            posterior and only the pairs with a new point are added. ``"reassociate"`` re-derives the
            posterior at every touch from the initial belief ``(T_init, P_init)`` with all pairs at the
            current correspondences (the same information, once each pair, but a pair's correspondence is no
            longer frozen at the value it had when it was first measured); this is Algorithm 1's
            "estimate correspondences(O, S); update TIQF(x, Sigma, C)" over all points, without counting a
            pair twice.
    """

    def __init__(
        self,
        model,
        T_init=None,
        P_init=None,
        rho: float = 1e-2,
        inner_iter: int = 10,
        tol_rot_deg: float = 0.1,
        tol_trans: float = 1e-4,
        refine: bool = False,
        n_escapes: int = 0,
        tangent: bool = False,
        mode: str = "carry",
        seed: int | None = 0,
    ):
        as_real(rho, "rho", low=0.0, open_low=True)
        self.model = as_points(model, "model", min_points=3)
        self.tree = cKDTree(self.model)
        T0 = np.eye(4) if T_init is None else as_transform(T_init, "T_init")
        self.x = _matrix_to_quat(T0[:3, :3])
        self.t = T0[:3, 3].copy()
        self.P = np.eye(4) if P_init is None else np.asarray(P_init, dtype=np.float64).copy()
        if self.P.shape != (4, 4) or not np.isfinite(self.P).all():
            raise ValueError(f"P_init: expected a finite (4, 4) covariance, got shape {self.P.shape}")
        self.rho = rho
        self.inner_iter = inner_iter
        self.tol_rot_deg = tol_rot_deg
        self.tol_trans = tol_trans
        self.scene = np.zeros((0, 3))
        self.refine = refine
        if mode not in ("carry", "reassociate"):
            raise ValueError(f"mode: expected 'carry' or 'reassociate', got {mode!r}")
        self.mode = mode
        self.x0, self.P0 = self.x.copy(), self.P.copy()
        self._tangent = TangentPlanes(self.model, self.tree) if tangent else None
        self._batch = TIQF(
            rho=rho, tol_rot_deg=tol_rot_deg, tol_trans=tol_trans, n_escapes=n_escapes, seed=seed
        )

    @property
    def R(self) -> np.ndarray:
        return _quat_to_matrix(self.x)

    @property
    def T_scene_model(self) -> np.ndarray:
        T = np.eye(4)
        T[:3, :3] = self.R
        T[:3, 3] = self.t
        return T

    def _corr_points(self, R, t):
        """Model points paired with all measured points at pose (R, t) (tangent feet when enabled)."""
        q = (self.scene - t) @ R
        _, idx = self.tree.query(q, k=1)
        return self._tangent.project(q, idx) if self._tangent is not None else self.model[idx]

    def paired_model_points(self) -> np.ndarray:
        """The model points the filter pairs with the measured points at the current pose ``(n, 3)``."""
        return self._corr_points(self.R, self.t)

    def correspondences(self, scene=None, R=None, t=None):
        """Closest model point for every scene point at pose (R, t). Returns model points ``(N, 3)``."""
        scene = self.scene if scene is None else scene
        R = self.R if R is None else R
        t = self.t if t is None else t
        _, idx = self.tree.query((scene - t) @ R, k=1)
        return self.model[idx]

    @staticmethod
    def new_pairs(n_old: int, n_new: int) -> tuple[np.ndarray, np.ndarray]:
        """Pairs (i, j), i < j, among ``n_old + n_new`` points that contain at least one of the new points."""
        n = n_old + n_new
        i, j = np.triu_indices(n, k=1)
        keep = j >= n_old
        return i[keep], j[keep]

    def add(self, points):
        """Incorporate one touch: points ``(K, 3)`` in the scene frame. Returns ``T_scene_model``."""
        pts = as_points(points, "points", min_points=1)
        n_old = len(self.scene)
        self.scene = np.concatenate([self.scene, pts], 0)
        if len(self.scene) < 2:
            self.t = self.scene.mean(0) - self.R @ self.correspondences().mean(0)
            return self.T_scene_model
        R, t = self.R, self.t
        if self.mode == "reassociate":
            x_prior, P_prior = self.x0, self.P0
        else:
            x_prior, P_prior = self.x, self.P
            i, j = self.new_pairs(n_old, len(pts))
        x, P = x_prior, P_prior
        for _ in range(self.inner_iter):
            o = self._corr_points(R, t)
            if self.mode == "reassociate":
                x, P = tiqf_update_moment(x_prior, P_prior, all_pairs_moment(self.scene, o), self.rho)
            else:
                x, P = _tiqf_update(x_prior, P_prior, self.scene[j] - self.scene[i], o[j] - o[i], self.rho)
            R_new = _quat_to_matrix(x)
            t_new = _translation(R_new, self.scene, o)
            done = (
                np.linalg.norm(t_new - t) < self.tol_trans
                and _rotation_angle_deg(R, R_new) < self.tol_rot_deg
            )
            R, t = R_new, t_new
            if done:
                break
        self.x, self.P, self.t = x, P, t
        if self.refine and len(self.scene) >= 3:
            corr = None
            if self._tangent is not None:
                scene = self.scene

                def corr(scene_in_model, R, t):
                    _, idx = self.tree.query(scene_in_model, k=1)
                    return scene, self._tangent.project(scene_in_model, idx)

            res = self._batch.register(
                self.model, self.scene, T_init=self.T_scene_model, model_tree=self.tree, correspondences=corr
            )
            self.x = res.q if res.q @ self.x >= 0 else -res.q
            self.t = res.T_scene_model[:3, 3].copy()
        return self.T_scene_model
