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


@numpy_compatible
def se3_exp(xi):
    """SE(3) exponential of ``xi = (rho, phi)`` (translation first).

    Shapes:
        xi: ``(..., 6)`` -> ``(..., 4, 4)``.
    """
    xi = as_tensor(xi, "xi", last_dims=(6,))
    rho, phi = xi[..., :3], xi[..., 3:]
    R = so3_exp(phi)
    t = (so3_left_jacobian(phi) @ rho[..., None])[..., 0]
    return make_transform(R, t)


@numpy_compatible
def se3_log(T):
    """SE(3) logarithm, returning ``xi = (rho, phi)`` (translation first).

    Shapes:
        T: ``(..., 4, 4)`` -> ``(..., 6)``.
    """
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
