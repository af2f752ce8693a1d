"""Oriented bounding box of a part cloud from its covariance (thesis ch.6, 6.2.2 "Action Execution").

The thesis parameterises every action (push, hold, pull; and the goal-driven push of 6.2.4) by the
oriented bounding box (OBB) of the part's point cloud: the eigenvectors of the covariance matrix are
the major axis ``V_x`` (along the length of the object), the middle axis ``V_y`` and the minor axis
``V_z`` (normal to the surface); ``O`` is the geometric centre of the box, not the centroid.

Two variants:

* ``planar=False``: 3-D PCA of the points (the hold action needs ``V_z`` of a part);
* ``planar=True``: PCA of the xy coordinates only, the table-plane box that a pusher moving parallel
  to the table sees; ``V_z`` is then the world z axis and the z extent is the points' height range.

Eigenvector signs are made deterministic: the component of largest magnitude of ``V_x`` and ``V_y`` is
positive, and ``V_z = V_x x V_y`` makes the frame right-handed.

Shapes:
    points: (N, 3) world points -> OBB.centre (3,), OBB.axes (3, 3) with columns V_x, V_y, V_z,
    OBB.half_extents (3,).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from vtlearn.validation import as_points

__all__ = ["MAX_OBJECT_EXTENT_M", "OBB", "check_object_cloud", "oriented_bounding_box"]

# The longest cloud of one object (or part) on a table top that the runtime accepts, metres. A cloud in
# millimetres spans a thousand times its size in metres, so the unit mistake cannot pass for an object.
MAX_OBJECT_EXTENT_M = 2.0


def check_object_cloud(points, name: str, min_points: int = 3) -> np.ndarray:
    """``points`` validated as one table-top object's world cloud in metres: a ``ValueError`` naming ``name``
    for a wrong shape, too few points, NaN/inf, or an extent above :data:`MAX_OBJECT_EXTENT_M`.

    Shapes:
        points: (N, 3) -> (N, 3) float64.
    """
    from vtlearn.bench_utils import check_metres

    pts = as_points(points, name, min_points=min_points)
    check_metres(pts, name, MAX_OBJECT_EXTENT_M, "a table-top object")
    return pts


@dataclass(frozen=True)
class OBB:
    """An oriented box: ``T_world_box`` has rotation ``axes`` (columns V_x, V_y, V_z) and origin ``centre``.

    Attributes:
        centre: (3,) geometric centre O of the box (world frame, metres).
        axes: (3, 3) rotation whose columns are V_x (major), V_y (middle), V_z (minor).
        half_extents: (3,) half lengths of the box along V_x, V_y, V_z (metres).
    """

    centre: np.ndarray
    axes: np.ndarray
    half_extents: np.ndarray

    @property
    def V_x(self) -> np.ndarray:
        return self.axes[:, 0]

    @property
    def V_y(self) -> np.ndarray:
        return self.axes[:, 1]

    @property
    def V_z(self) -> np.ndarray:
        return self.axes[:, 2]

    @property
    def T_world_box(self) -> np.ndarray:
        """(4, 4) pose of the box frame (axes V_x, V_y, V_z at O) in the world."""
        T = np.eye(4)
        T[:3, :3], T[:3, 3] = self.axes, self.centre
        return T


def _canonical(v: np.ndarray) -> np.ndarray:
    return v if v[np.argmax(np.abs(v))] >= 0 else -v


def oriented_bounding_box(points, planar: bool = False) -> OBB:
    """The OBB of ``points`` from the eigenvectors of their covariance (thesis 6.2.2).

    Args:
        points: the part cloud, world frame, metres.
        planar: PCA of the xy coordinates only (a table-plane box, V_z = world z); see the module docstring.

    Shapes:
        points: (N, 3), N >= 3 -> :class:`OBB`.

    Raises:
        ValueError: fewer than 3 points, NaN/inf, or all points (their xy when ``planar``) coincident.
    """
    pts = as_points(points, "points", min_points=3)
    if planar:
        xy = pts[:, :2]
        cov = np.cov((xy - xy.mean(0)).T)
        w, V = np.linalg.eigh(cov)  # ascending eigenvalues
        if w[-1] <= 1e-18:
            raise ValueError("points: all xy coordinates coincide; the table-plane box is undefined")
        vx = _canonical(V[:, 1])
        axes = np.array([[vx[0], -vx[1], 0.0], [vx[1], vx[0], 0.0], [0.0, 0.0, 1.0]])
    else:
        cov = np.cov((pts - pts.mean(0)).T)
        w, V = np.linalg.eigh(cov)
        if w[-1] <= 1e-18:
            raise ValueError("points: all points coincide; the box is undefined")
        vx, vy = _canonical(V[:, 2]), _canonical(V[:, 1])
        axes = np.stack([vx, vy, np.cross(vx, vy)], axis=1)
    local = pts @ axes  # (N, 3) coordinates along V_x, V_y, V_z
    lo, hi = local.min(0), local.max(0)
    return OBB(centre=axes @ ((lo + hi) / 2), axes=axes, half_extents=(hi - lo) / 2)
