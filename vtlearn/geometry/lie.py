"""SO(3) and SE(3) exponential and logarithm maps — thesis Appendix A.2 (Lie groups), used by ArtReg (ch.6).

Tangent conventions (documented once, used everywhere in vtlearn):

* so(3): ``phi`` (3,) is the rotation vector (axis * angle, radians); ``R = exp([phi]x)``.
* se(3): ``xi = (rho, phi)`` (6,), translation part first then rotation part, with
  ``T = exp(xi) = [[exp(phi), J(phi) rho], [0, 1]]`` and ``J`` the left Jacobian of SO(3).

Both maps are stable near zero (Taylor expansions) and near pi (``so3_log`` goes through the quaternion with
``atan2``; ``J^-1`` uses ``cot(theta/2)`` which stays finite at pi).

Shapes:
    phi: ``(..., 3)``; R: ``(..., 3, 3)``; xi: ``(..., 6)``; T: ``(..., 4, 4)``.
"""

from __future__ import annotations

import numpy as np
import torch

from vtlearn.geometry._compat import as_tensor, numpy_compatible
from vtlearn.geometry.quaternion import matrix_to_quat, skew

__all__ = [
    "so3_hat",
    "so3_exp",
    "so3_log",
    "so3_left_jacobian",
    "so3_left_jacobian_inv",
    "se3_exp",
    "se3_log",
    "se3_inverse",
    "make_transform",
]

_SMALL = 1e-4


def _theta(phi: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """Angle, its square, and a mask of small angles; the angle is made safe (non-zero) for gradients."""
    theta2 = (phi * phi).sum(-1)
    small = theta2 < _SMALL**2
    theta = torch.sqrt(torch.where(small, torch.ones_like(theta2), theta2))
    return theta, theta2, small


@numpy_compatible
def so3_hat(phi):
    """``[phi]x``, the skew-symmetric matrix of a rotation vector.

    Shapes:
        phi: ``(..., 3)`` -> ``(..., 3, 3)``.
    """
    return skew(as_tensor(phi, "phi", last_dims=(3,)))


@numpy_compatible
def so3_exp(phi):
    """Rodrigues' formula ``R = I + a [phi]x + b [phi]x^2``, ``a = sin t / t``, ``b = (1 - cos t) / t^2``.

    Shapes:
        phi: ``(..., 3)`` -> ``(..., 3, 3)``.
    """
    phi = as_tensor(phi, "phi", last_dims=(3,))
    theta, theta2, small = _theta(phi)
    a = torch.where(small, 1 - theta2 / 6, torch.sin(theta) / theta)
    b = torch.where(small, 0.5 - theta2 / 24, (1 - torch.cos(theta)) / (theta * theta))
    K = skew(phi)
    eye = torch.eye(3, dtype=phi.dtype, device=phi.device).expand_as(K)
    return eye + a[..., None, None] * K + b[..., None, None] * (K @ K)


@numpy_compatible
def so3_log(R):
    """Rotation vector of a rotation matrix, angle in ``[0, pi]``; stable at 0 and pi.

    Computed from the quaternion ``(w, v)`` with ``w >= 0`` as ``phi = 2 atan2(|v|, w) v / |v|``.

    Shapes:
        R: ``(..., 3, 3)`` -> ``(..., 3)``.
    """
    R = as_tensor(R, "R", last_dims=(3, 3))
    q = matrix_to_quat(R)
    w, v = q[..., 0], q[..., 1:]
    n2 = (v * v).sum(-1)
    small = n2 < _SMALL**2
    n = torch.sqrt(torch.where(small, torch.ones_like(n2), n2))
    # series of 2 atan(n / w) / n for small n (w ~ 1 there)
    factor = torch.where(small, 2 / w * (1 - n2 / (3 * w * w)), 2 * torch.atan2(n, w) / n)
    return factor[..., None] * v


@numpy_compatible
def so3_left_jacobian(phi):
    """Left Jacobian ``J = I + (1 - cos t)/t^2 [phi]x + (t - sin t)/t^3 [phi]x^2``.

    Shapes:
        phi: ``(..., 3)`` -> ``(..., 3, 3)``.
    """
    phi = as_tensor(phi, "phi", last_dims=(3,))
    theta, theta2, small = _theta(phi)
    b = torch.where(small, 0.5 - theta2 / 24, (1 - torch.cos(theta)) / (theta * theta))
    c = torch.where(small, 1.0 / 6 - theta2 / 120, (theta - torch.sin(theta)) / (theta2 * theta))
    K = skew(phi)
    eye = torch.eye(3, dtype=phi.dtype, device=phi.device).expand_as(K)
    return eye + b[..., None, None] * K + c[..., None, None] * (K @ K)


@numpy_compatible
def so3_left_jacobian_inv(phi):
    """Inverse left Jacobian ``J^-1 = I - [phi]x / 2 + (1/t^2 - cot(t/2) / (2 t)) [phi]x^2``.

    Shapes:
        phi: ``(..., 3)`` -> ``(..., 3, 3)``.
    """
    phi = as_tensor(phi, "phi", last_dims=(3,))
    theta, theta2, small = _theta(phi)
    half = theta / 2
    d = torch.where(
        small,
        1.0 / 12 + theta2 / 720,
        1 / (theta * theta) - torch.cos(half) / (2 * theta * torch.sin(half)),
    )
    K = skew(phi)
    eye = torch.eye(3, dtype=phi.dtype, device=phi.device).expand_as(K)
    return eye - 0.5 * K + d[..., None, None] * (K @ K)


@numpy_compatible
def make_transform(R, t):
    """Homogeneous ``T_a_b`` from a rotation ``R`` (..., 3, 3) and translation ``t`` (..., 3).

    Shapes:
        R: ``(..., 3, 3)``, t: ``(..., 3)`` -> ``(..., 4, 4)``.
    """
    R = as_tensor(R, "R", last_dims=(3, 3))
    t = as_tensor(t, "t", last_dims=(3,)).to(R.dtype)
    batch = torch.broadcast_shapes(R.shape[:-2], t.shape[:-1])
    T = torch.zeros(*batch, 4, 4, dtype=R.dtype, device=R.device)
    T[..., :3, :3] = R
    T[..., :3, 3] = t
    T[..., 3, 3] = 1
    return T


def se3_exp(xi):
    """SE(3) exponential of ``xi = (rho, phi)`` (translation first).

    A single numpy ``(6,)`` vector takes a plain-numpy path (tens of microseconds instead of a millisecond of
    torch dispatch), which filters calling it per sigma point rely on; everything else goes through torch.

    Shapes:
        xi: ``(..., 6)`` -> ``(..., 4, 4)``.
    """
    if isinstance(xi, np.ndarray) and xi.shape == (6,):
        return _se3_exp_single(xi.astype(np.float64, copy=False))
    return _se3_exp(xi)


@numpy_compatible
def _se3_exp(xi):
    xi = as_tensor(xi, "xi", last_dims=(6,))
    rho, phi = xi[..., :3], xi[..., 3:]
    R = so3_exp(phi)
    t = (so3_left_jacobian(phi) @ rho[..., None])[..., 0]
    return make_transform(R, t)


def se3_log(T):
    """SE(3) logarithm, returning ``xi = (rho, phi)`` (translation first).

    A single numpy ``(4, 4)`` matrix takes a plain-numpy path, as in :func:`se3_exp`.

    Shapes:
        T: ``(..., 4, 4)`` -> ``(..., 6)``.
    """
    if isinstance(T, np.ndarray) and T.shape == (4, 4):
        return _se3_log_single(T.astype(np.float64, copy=False))
    return _se3_log(T)


@numpy_compatible
def _se3_log(T):
    T = as_tensor(T, "T", last_dims=(4, 4))
    phi = so3_log(T[..., :3, :3])
    rho = (so3_left_jacobian_inv(phi) @ T[..., :3, 3:])[..., 0]
    return torch.cat([rho, phi], -1)


@numpy_compatible
def se3_inverse(T_a_b):
    """``T_b_a = T_a_b^-1 = [[R^T, -R^T t], [0, 1]]``.

    Shapes:
        T_a_b: ``(..., 4, 4)`` -> ``(..., 4, 4)``.
    """
    T = as_tensor(T_a_b, "T_a_b", last_dims=(4, 4))
    Rt = T[..., :3, :3].transpose(-1, -2)
    return make_transform(Rt, -(Rt @ T[..., :3, 3:])[..., 0])


def _hat_np(v: np.ndarray) -> np.ndarray:
    return np.array([[0.0, -v[2], v[1]], [v[2], 0.0, -v[0]], [-v[1], v[0], 0.0]])


def _se3_exp_single(xi: np.ndarray) -> np.ndarray:
    """Plain-numpy :func:`se3_exp` of one ``(6,)`` vector; same Taylor switch as the torch version."""
    rho, phi = xi[:3], xi[3:]
    th2 = float(phi @ phi)
    th = np.sqrt(th2)
    Phi = _hat_np(phi)
    Phi2 = Phi @ Phi
    if th < _SMALL:
        a, b, c = 1.0 - th2 / 6.0, 0.5 - th2 / 24.0, 1.0 / 6.0 - th2 / 120.0
    else:
        s, co = np.sin(th), np.cos(th)
        a, b, c = s / th, (1.0 - co) / th2, (th - s) / (th2 * th)
    T = np.eye(4)
    T[:3, :3] = np.eye(3) + a * Phi + b * Phi2
    T[:3, 3] = rho + b * (Phi @ rho) + c * (Phi2 @ rho)  # J(phi) rho
    return T


def _se3_log_single(T: np.ndarray) -> np.ndarray:
    """Plain-numpy :func:`se3_log` of one ``(4, 4)``; the angle comes from the quaternion (Shepperd)."""
    R = T[:3, :3]
    tr = R[0, 0] + R[1, 1] + R[2, 2]
    if tr > 0:
        S = np.sqrt(tr + 1.0) * 2
        q = np.array([0.25 * S, (R[2, 1] - R[1, 2]) / S, (R[0, 2] - R[2, 0]) / S, (R[1, 0] - R[0, 1]) / S])
    else:
        i = int(np.argmax([R[0, 0], R[1, 1], R[2, 2]]))
        j, k = (i + 1) % 3, (i + 2) % 3
        S = np.sqrt(1.0 + R[i, i] - R[j, j] - R[k, k]) * 2
        q = np.empty(4)
        q[0] = (R[k, j] - R[j, k]) / S
        q[1 + i] = 0.25 * S
        q[1 + j] = (R[j, i] + R[i, j]) / S
        q[1 + k] = (R[k, i] + R[i, k]) / S
    if q[0] < 0:
        q = -q
    vn = np.sqrt(q[1:] @ q[1:])
    th = 2.0 * np.arctan2(vn, q[0])
    phi = q[1:] * (th / vn) if vn > 1e-12 else 2.0 * q[1:] / q[0]
    Phi = _hat_np(phi)
    if th < _SMALL:
        c = 1.0 / 12.0 + th * th / 720.0
    else:
        c = 1.0 / (th * th) - 1.0 / (2.0 * th * np.tan(0.5 * th))  # 1/th^2 - cot(th/2) / (2 th)
    t = T[:3, 3]
    return np.concatenate([t - 0.5 * (Phi @ t) + c * (Phi @ (Phi @ t)), phi])  # J(phi)^-1 t
