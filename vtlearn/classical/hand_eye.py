"""In-situ visuo-tactile hand-eye calibration with any object in the workspace (thesis ch.5, 5.2.5,
eq. 5.19-5.22).

The camera is on the end-effector E of one arm (eye-in-hand); a tactile sensor on the other arm probes a
fixed object with guarded motions, so its contacts are known in the world frame W through that arm's
kinematics (eq. 5.22, ``P_W = T_W_B T_B_T P_T``). Calibration is cast as point-cloud registration: the
camera-frame visual cloud ``P_C`` of the object is registered to the sparse tactile cloud ``P_W``
(eq. 5.21; S-TIQF by default, the thesis's choice, or any method of
:func:`vtlearn.classical.registration.register`, so the peers of 5.3.3 too), giving ``T_W_C``. The arm's
kinematics give ``T_W_E`` for the capture (eq. 5.19, ``T_W_C = T_W_B T_B_E T_E_C``), and the hand-eye
matrix is (eq. 5.20)

    T_E_C = T_W_E⁻¹ · T_W_C.

No calibration target is needed. Several captures (views) are each registered on their own and their
``T_E_C`` estimates combined: rotations by the quaternion average of Markley et al. (2007, the
eigenvector of ``Σ q qᵀ``) and translations by their mean. A nominal calibration ``T_E_C_init``, when
given, starts every registration at ``T_W_E · T_E_C_init``; local methods (TIQF, eq. 4.1-4.23, ICP, ...)
need one, global ones (S-TIQF, RANSAC-FPFH, FGR) do not.

Frames: ``T_a_b`` maps points in frame b into frame a; W world, E end-effector of the camera arm, C camera.
Quaternions are Hamilton (w, x, y, z); metres.

Shapes:
    visual_points_C: ``(M, 3)`` or a list of them (one per view); tactile_points_W ``(N, 3)``, N >= 3;
    T_W_E: ``(4, 4)`` or ``(V, 4, 4)``; result ``T_E_C`` ``(4, 4)``.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from vtlearn.geometry import rotation_error_deg
from vtlearn.validation import as_points, as_transform

__all__ = ["HandEyeResult", "average_transforms", "hand_eye_from_registration", "in_situ_hand_eye",
           "LOCAL_METHODS"]

# registration methods that only refine a starting pose: they need T_E_C_init
LOCAL_METHODS = ("tiqf", "icp", "icp_plane", "sparse_icp", "filterreg", "cpd")


@dataclass
class HandEyeResult:
    """Output of :func:`in_situ_hand_eye`.

    Attributes:
        T_E_C: the hand-eye calibration (camera in the end-effector frame), eq. 5.20.
        T_W_C: the camera pose of each view from the registration (eq. 5.21), ``(V, 4, 4)``.
        T_E_C_views: the calibration from each view alone, ``(V, 4, 4)``.
        rmse: registration RMSE of each view (m), ``(V,)``.
        spread_m, spread_deg: largest translation / rotation deviation of a view's estimate from
            ``T_E_C`` (0 for one view): a consistency check that needs no ground truth.
    """

    T_E_C: np.ndarray
    T_W_C: np.ndarray
    T_E_C_views: np.ndarray
    rmse: np.ndarray
    spread_m: float = 0.0
    spread_deg: float = 0.0
    extra: dict = field(default_factory=dict)


def hand_eye_from_registration(T_W_C, T_W_E) -> np.ndarray:
    """Eq. 5.20: ``T_E_C = T_W_E⁻¹ T_W_C``.

    Shapes:
        T_W_C (4, 4), T_W_E (4, 4) -> (4, 4)
    """
    T_W_C = as_transform(T_W_C, "T_W_C")
    T_W_E = as_transform(T_W_E, "T_W_E")
    return np.linalg.inv(T_W_E) @ T_W_C


def average_transforms(T) -> np.ndarray:
    """Mean of rigid transforms: Markley's quaternion average for the rotation (sign-invariant: the
    principal eigenvector of ``Σ q qᵀ``), the arithmetic mean for the translation.

    Shapes:
        T (V, 4, 4), V >= 1 -> (4, 4)
    """
    from vtlearn.geometry import matrix_to_quat, quat_to_matrix

    T = np.asarray(T, dtype=np.float64)
    if T.ndim != 3 or T.shape[1:] != (4, 4) or len(T) == 0:
        raise ValueError(f"T: need shape (V >= 1, 4, 4), got {T.shape}")
    for i, Ti in enumerate(T):
        as_transform(Ti, f"T[{i}]")
    q = np.asarray(matrix_to_quat(T[:, :3, :3]), dtype=np.float64).reshape(-1, 4)
    _, vecs = np.linalg.eigh(q.T @ q)
    q_mean = vecs[:, -1] * np.sign(vecs[0, -1] if vecs[0, -1] != 0 else 1.0)
    out = np.eye(4)
    out[:3, :3] = np.asarray(quat_to_matrix(q_mean), dtype=np.float64)
    out[:3, 3] = T[:, :3, 3].mean(0)
    return out


def in_situ_hand_eye(
    visual_points_C,
    tactile_points_W,
    T_W_E,
    *,
    method: str = "stiqf",
    T_E_C_init=None,
    seed: int = 0,
    **options,
) -> HandEyeResult:
    """In-situ visuo-tactile hand-eye calibration (thesis 5.2.5, eq. 5.19-5.22).

    Args:
        visual_points_C: the object's visual cloud in the camera frame, or one per view.
        tactile_points_W: tactile contacts on the same (fixed) object in the world frame (eq. 5.22).
        T_W_E: camera-arm end-effector pose of each view from its kinematics (eq. 5.19).
        method: a method of :func:`vtlearn.classical.registration.register`; ``"stiqf"`` (global, the
            thesis's) by default.
        T_E_C_init: nominal calibration, the start of every registration; required by
            :data:`LOCAL_METHODS`.
        seed: seeds the registration.
        **options: passed to :func:`~vtlearn.classical.registration.register` (e.g. ``restarts``).

    Returns:
        :class:`HandEyeResult`.

    Shapes:
        visual_points_C (M, 3) or V x (M_v, 3); tactile_points_W (N, 3); T_W_E (4, 4) or (V, 4, 4).
    """
    from vtlearn.classical.registration import METHODS, register

    if method not in METHODS:
        raise ValueError(f"method: unknown {method!r}; choose from {sorted(METHODS)}")
    single = hasattr(visual_points_C, "shape") and len(visual_points_C.shape) == 2  # one (M, 3) array/tensor
    views = [visual_points_C] if single else list(visual_points_C)
    if not views:
        raise ValueError("visual_points_C: no view given")
    clouds = [as_points(v, f"visual_points_C[{i}]", min_points=3) for i, v in enumerate(views)]
    tactile = as_points(tactile_points_W, "tactile_points_W", min_points=3)
    T_W_E = np.asarray(T_W_E, dtype=np.float64)
    T_W_E = T_W_E[None] if T_W_E.ndim == 2 else T_W_E
    if T_W_E.ndim != 3 or len(T_W_E) != len(clouds):
        raise ValueError(f"T_W_E: need one (4, 4) pose per view ({len(clouds)}), got shape {T_W_E.shape}")
    T_W_E = np.stack([as_transform(T, f"T_W_E[{i}]") for i, T in enumerate(T_W_E)])
    if T_E_C_init is not None:
        T_E_C_init = as_transform(T_E_C_init, "T_E_C_init")
    elif method in LOCAL_METHODS:
        raise ValueError(f"T_E_C_init: method {method!r} refines a nominal calibration, none given")
    T_W_C, rmse = [], []
    for cloud, T in zip(clouds, T_W_E, strict=True):
        # eq. 5.21: register the visual cloud (model, frame C) to the tactile cloud (scene, frame W)
        T_init = None if T_E_C_init is None else T @ T_E_C_init
        res = register(cloud, tactile, method, T_init=T_init, seed=seed, **options)
        T_W_C.append(np.asarray(res.T_scene_model, dtype=np.float64))
        rmse.append(float(res.rmse))
    T_W_C = np.stack(T_W_C)
    per_view = np.stack([np.linalg.inv(T) @ Tc for T, Tc in zip(T_W_E, T_W_C, strict=True)])  # eq. 5.20
    T_E_C = average_transforms(per_view)
    dev_m = np.linalg.norm(per_view[:, :3, 3] - T_E_C[:3, 3], axis=1)
    dev_deg = [rotation_error_deg(T_E_C[:3, :3], X[:3, :3]) for X in per_view]
    return HandEyeResult(T_E_C, T_W_C, per_view, np.asarray(rmse), float(dev_m.max()), float(max(dev_deg)),
                         {"method": method})
