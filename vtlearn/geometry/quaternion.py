"""Hamilton quaternions stored as (w, x, y, z) — thesis Appendix A.1, eq. A.5-A.9.

All functions work on batches: the quaternion is the last dimension. They accept torch tensors (and keep
autograd) or numpy arrays (and return numpy arrays).

Shapes:
    quaternion: ``(..., 4)`` (w, x, y, z); rotation matrix: ``(..., 3, 3)``; vector: ``(..., 3)``.
"""

from __future__ import annotations

import numpy as np
import torch

from vtlearn.geometry._compat import as_tensor, numpy_compatible
from vtlearn.validation import as_int

__all__ = [
    "quat_mul",
    "quat_conj",
    "quat_normalize",
    "quat_to_matrix",
    "matrix_to_quat",
    "quat_left_matrix",
    "quat_right_matrix",
    "quat_rotate",
    "random_quaternion",
    "skew",
]


def skew(v: torch.Tensor) -> torch.Tensor:
    """Skew-symmetric matrix ``[v]x`` with ``[v]x @ u = v x u``.

    Shapes:
        v: ``(..., 3)`` -> ``(..., 3, 3)``.
    """
    x, y, z = v.unbind(-1)
    o = torch.zeros_like(x)
    return torch.stack(
        [torch.stack([o, -z, y], -1), torch.stack([z, o, -x], -1), torch.stack([-y, x, o], -1)], -2
    )


@numpy_compatible
def quat_mul(q1, q2):
    """Hamilton product ``q1 ⊙ q2`` (eq. A.7), quaternions (w, x, y, z).

    Shapes:
        q1, q2: ``(..., 4)`` (broadcastable) -> ``(..., 4)``.
    """
    q1 = as_tensor(q1, "q1", last_dims=(4,))
    q2 = as_tensor(q2, "q2", last_dims=(4,))
    w1, x1, y1, z1 = q1.unbind(-1)
    w2, x2, y2, z2 = q2.unbind(-1)
    return torch.stack(
        [
            w1 * w2 - x1 * x2 - y1 * y2 - z1 * z2,
            w1 * x2 + x1 * w2 + y1 * z2 - z1 * y2,
            w1 * y2 + y1 * w2 + z1 * x2 - x1 * z2,
            w1 * z2 + z1 * w2 + x1 * y2 - y1 * x2,
        ],
        -1,
    )


@numpy_compatible
def quat_conj(q):
    """Conjugate (w, -x, -y, -z); the inverse of a unit quaternion.

    Shapes:
        q: ``(..., 4)`` -> ``(..., 4)``.
    """
    q = as_tensor(q, "q", last_dims=(4,))
    return q * q.new_tensor([1.0, -1.0, -1.0, -1.0])


@numpy_compatible
def quat_normalize(q, eps: float = 1e-12):
    """Scale to unit norm (used as the renormalisation step, thesis eq. 4.22).

    Shapes:
        q: ``(..., 4)`` -> ``(..., 4)``.

    Raises:
        ValueError: if any quaternion has (near) zero norm.
    """
    q = as_tensor(q, "q", last_dims=(4,))
    n = q.norm(dim=-1, keepdim=True)
    if bool((n < eps).any()):
        raise ValueError("q: cannot normalise a quaternion with zero norm")
    return q / n


@numpy_compatible
def quat_left_matrix(q):
    """Left-product matrix ``L(q)`` with ``q ⊙ p = L(q) p`` (eq. A.8).

    ``L(q) = [[w, -v^T], [v, w I + [v]x]]`` for ``q = (w, v)``.

    Shapes:
        q: ``(..., 4)`` -> ``(..., 4, 4)``.
    """
    q = as_tensor(q, "q", last_dims=(4,))
    w, v = q[..., :1], q[..., 1:]
    eye = torch.eye(3, dtype=q.dtype, device=q.device)
    top = torch.cat([w, -v], -1).unsqueeze(-2)
    bottom = torch.cat([v.unsqueeze(-1), w.unsqueeze(-1) * eye + skew(v)], -1)
    return torch.cat([top, bottom], -2)


@numpy_compatible
def quat_right_matrix(q):
    """Right-product matrix ``R(q)`` with ``p ⊙ q = R(q) p`` (eq. A.9).

    ``R(q) = [[w, -v^T], [v, w I - [v]x]]`` for ``q = (w, v)``.

    Shapes:
        q: ``(..., 4)`` -> ``(..., 4, 4)``.
    """
    q = as_tensor(q, "q", last_dims=(4,))
    w, v = q[..., :1], q[..., 1:]
    eye = torch.eye(3, dtype=q.dtype, device=q.device)
    top = torch.cat([w, -v], -1).unsqueeze(-2)
    bottom = torch.cat([v.unsqueeze(-1), w.unsqueeze(-1) * eye - skew(v)], -1)
    return torch.cat([top, bottom], -2)


@numpy_compatible
def quat_to_matrix(q):
    """Rotation matrix of a quaternion (w, x, y, z); the input is normalised first.

    Shapes:
        q: ``(..., 4)`` -> ``(..., 3, 3)``.
    """
    q = quat_normalize(as_tensor(q, "q", last_dims=(4,)))
    w, x, y, z = q.unbind(-1)
    return torch.stack(
        [
            torch.stack([1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)], -1),
            torch.stack([2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)], -1),
            torch.stack([2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)], -1),
        ],
        -2,
    )


@numpy_compatible
def matrix_to_quat(R):
    """Quaternion (w, x, y, z) of a rotation matrix, ``w >= 0`` (Shepperd's method, stable at all angles).

    Shapes:
        R: ``(..., 3, 3)`` -> ``(..., 4)``.
    """
    R = as_tensor(R, "R", last_dims=(3, 3))
    m00, m11, m22 = R[..., 0, 0], R[..., 1, 1], R[..., 2, 2]
    tr = m00 + m11 + m22
    # four candidate solutions; pick, per matrix, the one with the largest (best-conditioned) denominator
    cands = torch.stack(
        [
            torch.stack(
                [
                    1 + tr,
                    R[..., 2, 1] - R[..., 1, 2],
                    R[..., 0, 2] - R[..., 2, 0],
                    R[..., 1, 0] - R[..., 0, 1],
                ],
                -1,
            ),
            torch.stack(
                [
                    R[..., 2, 1] - R[..., 1, 2],
                    1 + m00 - m11 - m22,
                    R[..., 0, 1] + R[..., 1, 0],
                    R[..., 0, 2] + R[..., 2, 0],
                ],
                -1,
            ),
            torch.stack(
                [
                    R[..., 0, 2] - R[..., 2, 0],
                    R[..., 0, 1] + R[..., 1, 0],
                    1 - m00 + m11 - m22,
                    R[..., 1, 2] + R[..., 2, 1],
                ],
                -1,
            ),
            torch.stack(
                [
                    R[..., 1, 0] - R[..., 0, 1],
                    R[..., 0, 2] + R[..., 2, 0],
                    R[..., 1, 2] + R[..., 2, 1],
                    1 - m00 - m11 + m22,
                ],
                -1,
            ),
        ],
        -2,
    )  # (..., 4 candidates, 4)
    diag = torch.stack([1 + tr, 1 + m00 - m11 - m22, 1 - m00 + m11 - m22, 1 - m00 - m11 + m22], -1)
    best = diag.argmax(-1)
    q = torch.gather(cands, -2, best[..., None, None].expand(*best.shape, 1, 4)).squeeze(-2)
    q = q / q.norm(dim=-1, keepdim=True)
    return torch.where(q[..., :1] < 0, -q, q)


@numpy_compatible
def quat_rotate(q, v):
    """Rotate vectors by unit quaternions: ``q ⊙ (0, v) ⊙ q*``.

    Shapes:
        q: ``(..., 4)``, v: ``(..., 3)`` -> ``(..., 3)``.
    """
    q = as_tensor(q, "q", last_dims=(4,))
    v = as_tensor(v, "v", last_dims=(3,))
    w, u = q[..., :1], q[..., 1:]
    uv = torch.cross(u.expand_as(v), v, dim=-1)
    return v + 2 * (w * uv + torch.cross(u.expand_as(v), uv, dim=-1))


def random_quaternion(
    n: int | None = None, seed: int | np.random.Generator | None = None, *, numpy: bool = False
):
    """Uniformly distributed unit quaternions (Shoemake's method), (w, x, y, z) with ``w >= 0``.

    Args:
        n: how many; ``None`` returns a single ``(4,)`` quaternion.
        seed: an int seed or a ``numpy.random.Generator``.
        numpy: return a numpy array instead of a float64 tensor.

    Shapes:
        output: ``(4,)`` or ``(n, 4)``.
    """
    if n is not None:
        n = as_int(n, "n")
    rng = seed if isinstance(seed, np.random.Generator) else np.random.default_rng(seed)
    m = 1 if n is None else n
    u1, u2, u3 = rng.random((3, m))
    a, b = np.sqrt(1 - u1), np.sqrt(u1)
    q = np.stack(
        [
            b * np.cos(2 * np.pi * u3),
            a * np.sin(2 * np.pi * u2),
            a * np.cos(2 * np.pi * u2),
            b * np.sin(2 * np.pi * u3),
        ],
        -1,
    )
    q = np.where(q[:, :1] < 0, -q, q)
    q = q[0] if n is None else q
    return q if numpy else torch.from_numpy(q)
