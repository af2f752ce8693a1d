"""Geometry core: quaternions, SO(3)/SE(3), transforms, sampling, kNN and metrics (see docs/CONTRACT.md)."""

from vtlearn.geometry.lie import (
    make_transform,
    se3_exp,
    se3_inverse,
    se3_log,
    so3_exp,
    so3_hat,
    so3_left_jacobian,
    so3_left_jacobian_inv,
    so3_log,
)
from vtlearn.geometry.metrics import (
    add,
    adi,
    chamfer_distance,
    earth_movers_distance,
    hausdorff_distance,
    rotation_error_deg,
    scale_error,
    translation_error,
)
from vtlearn.geometry.quaternion import (
    matrix_to_quat,
    quat_conj,
    quat_left_matrix,
    quat_mul,
    quat_normalize,
    quat_right_matrix,
    quat_rotate,
    quat_to_matrix,
    random_quaternion,
    skew,
)
from vtlearn.geometry.sampling import (
    farthest_point_sample,
    knn,
    lengths_mask,
    pad_clouds,
    random_subsample,
    sample_surface,
    voxel_downsample,
)
from vtlearn.geometry.transforms import random_pose, random_rotation, transform_points

__all__ = [
    "add", "adi", "chamfer_distance", "earth_movers_distance", "farthest_point_sample", "hausdorff_distance",
    "knn", "lengths_mask", "make_transform", "matrix_to_quat", "pad_clouds", "quat_conj", "quat_left_matrix",
    "quat_mul", "quat_normalize", "quat_right_matrix", "quat_rotate", "quat_to_matrix", "random_pose",
    "random_quaternion", "random_rotation", "random_subsample", "rotation_error_deg", "sample_surface",
    "scale_error", "se3_exp", "se3_inverse", "se3_log", "skew", "so3_exp", "so3_hat", "so3_left_jacobian",
    "so3_left_jacobian_inv", "so3_log", "transform_points", "translation_error", "voxel_downsample",
]
