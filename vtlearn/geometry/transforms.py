"""Applying rigid transforms to points and sampling random poses (thesis 5.3.3 benchmark ranges).

A transform ``T_a_b`` maps points expressed in frame b into frame a: ``points_a = transform_points(T_a_b,
points_b)``.
"""

from __future__ import annotations

import numpy as np
import torch

from vtlearn.geometry._compat import as_tensor, numpy_compatible
from vtlearn.geometry.lie import make_transform
from vtlearn.geometry.quaternion import quat_to_matrix, random_quaternion
from vtlearn.validation import as_pair, as_points, as_real

__all__ = ["transform_points", "random_pose", "random_rotation", "canonical_box"]


_LAST_ROW = np.array([0.0, 0.0, 0.0, 1.0])


def _check_homogeneous(a: np.ndarray, tol: float = 1e-5) -> None:
    """Cheap (O(1) per transform, no rotation check) test that ``a`` (..., 4, 4) is finite with last row
    0 0 0 1; ``ValueError`` naming ``T_a_b`` if not. Runs in inner loops, hence the exact fast path."""
    total = float(a.sum())
    if total - total != 0.0 and not np.isfinite(a).all():  # NaN/inf (the sum alone may just overflow)
        raise ValueError("T_a_b: contains NaN or inf")
    if a.ndim == 2 and a[3].tolist() == [0.0, 0.0, 0.0, 1.0]:
        return
    dev = np.abs(a[..., 3, :] - _LAST_ROW)
    if dev.max() <= tol:
        return
    bad = a.reshape(-1, 4, 4)[int(np.argmax(dev.reshape(-1, 4).max(axis=1)))][3]
    raise ValueError(f"T_a_b: last row must be (0, 0, 0, 1), got {bad.tolist()}")


@numpy_compatible
def transform_points(T_a_b, points_b):
    """``points_a = R_a_b points_b + t_a_b``.

    Args:
        T_a_b: one transform ``(4, 4)`` or a batch ``(B, 4, 4)``; must be finite with last row
            ``(0, 0, 0, 1)`` (checked for CPU inputs only, to avoid a device sync; the rotation block is not
            checked for orthonormality, as this runs in inner loops: use
            :func:`vtlearn.validation.as_transform` for that).
        points_b: ``(N, 3)`` with a single transform, or ``(B, N, 3)`` with one transform per cloud.

    Shapes:
        (4, 4), (N, 3) -> (N, 3);  (4, 4), (B, N, 3) -> (B, N, 3);  (B, 4, 4), (B, N, 3) -> (B, N, 3).
    """
    T = as_tensor(T_a_b, "T_a_b", last_dims=(4, 4))
    if T.is_cpu and T.numel() and T.dtype != torch.bfloat16:
        _check_homogeneous(T.detach().numpy() if T.requires_grad else T.numpy())
    p = as_tensor(points_b, "points_b", last_dims=(3,)).to(T.dtype)
    if T.dim() == 3 and (p.dim() != 3 or p.shape[0] != T.shape[0]):
        raise ValueError(
            f"points_b: with a batch of {T.shape[0]} transforms expected shape ({T.shape[0]}, N, 3), "
            f"got {tuple(p.shape)}"
        )
    if T.dim() > 3 or p.dim() > 3:
        raise ValueError(f"T_a_b/points_b: unsupported shapes {tuple(T.shape)} and {tuple(p.shape)}")
    R, t = T[..., :3, :3], T[..., :3, 3]
    return p @ R.transpose(-1, -2) + t.unsqueeze(-2)


def random_rotation(n: int | None = None, seed: int | np.random.Generator | None = None) -> np.ndarray:
    """Uniformly random rotation matrices (numpy). Shapes: ``(3, 3)`` or ``(n, 3, 3)``."""
    return quat_to_matrix(random_quaternion(n, seed, numpy=True))


def random_pose(
    n: int | None = None,
    *,
    trans_range: tuple[float, float] = (-5.0, 5.0),
    seed: int | np.random.Generator | None = None,
) -> np.ndarray:
    """Random rigid transforms: rotation uniform over SO(3), translation uniform in ``trans_range`` per axis.

    The default ``[-5, 5]`` m matches the initial-pose range of the thesis registration benchmark (5.3.3).

    Args:
        trans_range: a ``(low, high)`` pair with ``high >= low``.

    Shapes:
        output: ``(4, 4)`` or ``(n, 4, 4)`` numpy float64.
    """
    lo, hi = as_pair(trans_range, "trans_range")
    if not hi >= lo:
        raise ValueError(f"trans_range: expected (low, high) with high >= low, got {trans_range}")
    rng = seed if isinstance(seed, np.random.Generator) else np.random.default_rng(seed)
    m = 1 if n is None else n
    R = quat_to_matrix(random_quaternion(m, rng, numpy=True))
    t = rng.uniform(lo, hi, size=(m, 3))
    T = make_transform(R, t)
    return T[0] if n is None else T


def canonical_box(points, extent_m: float | None = None, name: str = "points") -> tuple[np.ndarray, float]:
    """Centre and scale of the canonical object frame of the models' training data: the centre of the
    cloud's axis-aligned bounding box, and the object's largest bounding-box extent (``extent_m``, or the
    cloud's own when it is None). ``canonical = (points - centre) / scale`` and back.

    The simulated datasets store clouds in this frame
    (:meth:`vtlearn.active.closed_loop.SimObject.to_canonical`), so ACTOR and xAVTNet trained on them
    expect it. The cloud must be gravity-aligned (z up) and, with ``extent_m``, in metres: a cloud more
    than twice as long as ``extent_m`` is refused (the usual cause is a cloud in millimetres).

    Shapes:
        points ``(N, 3)`` (N >= 3) -> centre ``(3,)``, scale (float, metres per canonical unit).
    """
    pts = as_points(points, name, min_points=3)
    lo, hi = pts.min(0), pts.max(0)
    if extent_m is None:
        scale = float((hi - lo).max())
        if scale <= 1e-9:
            raise ValueError(f"{name}: all {len(pts)} points coincide; the cloud has no extent to scale by")
    else:
        scale = as_real(extent_m, "extent_m", low=0.0, open_low=True, unit="m")
        own = float((hi - lo).max())
        if own > 2.0 * scale:  # a cloud of the object cannot be twice the object's size
            raise ValueError(f"extent_m: {name} spans {own:.4g} along its longest axis, more than twice the "
                             f"object's extent_m = {scale:.4g} m; are the points in millimetres, or is "
                             "extent_m another object's?")
    return (lo + hi) / 2, scale
