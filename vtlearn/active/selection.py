"""Joint visuo-tactile sensor and next-best-action selection (thesis 5.2.3, eq. 5.9-5.10, Algorithm 2).

The next action is chosen among views, touches and pinches together:

    a* = argmax_a  E[I(p(g | a, z_hat))] / D(a)                       (eq. 5.10)

where the expected information gain comes from the shared occupancy grid (eq. 5.8,
:mod:`vtlearn.active.occupancy`) and ``D(a)`` is an energy cost encoding the robot time an action takes.
Views are cheaper than touches (``D(view) < D(touch)``) unless the target object is transparent, in
which case the depth camera returns unreliable data and touch becomes the cheaper choice
(``D(touch) < D(view)``). With all costs equal, eq. 5.10 reduces to eq. 5.9.

Transparency is detected as in thesis 5.2.3 (Fig. 5.6): from a perpendicular top-down view, the 2-D
bounding box ``C_rgb`` of the object in the RGB image is compared with the 2-D bounding box ``C_pc`` of
its point cloud once the support plane is removed; the object is transparent if
``IoU(C_pc, C_rgb) < omega``. Both boxes are expressed in metres in the table plane, the RGB box by
back-projecting its pixel corners onto the plane. The thesis gives no value for ``omega``; 0.5 is used.

Shapes:
    gains, costs: ``(A,)``; boxes: ``(4,)`` as ``(x_min, y_min, x_max, y_max)``; mask: ``(H, W)`` bool;
    points: ``(N, 3)`` world frame, z up.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from vtlearn.validation import as_real, as_transform, to_numpy

__all__ = [
    "EnergyCosts",
    "box_iou_2d",
    "cloud_top_down_box",
    "detect_transparent",
    "energy_costs",
    "mask_box",
    "pixel_box_to_plane",
    "pixels_to_plane",
    "next_best_action",
    "select_next_best_action",
]


@dataclass(frozen=True)
class EnergyCosts:
    """Energy costs ``D(a)`` per action kind (relative robot time), eq. 5.10.

    ``opaque`` and ``transparent`` map an action kind to its cost. The defaults encode the thesis'
    ordering: for opaque objects a view is cheaper than a touch or pinch; for transparent ones a touch is
    cheaper than a view. The thesis gives no numbers. A view casts far more rays than a tactile pad
    (1440 beams at the default ToF stride against 16 taxels), so its raw gain is about two orders of
    magnitude larger; the transparent view cost is set high enough (1000) that touch is preferred as the
    thesis requires, while a view is still taken once touches stop gaining anything.
    """

    opaque: tuple[tuple[str, float], ...] = (("view", 1.0), ("touch", 4.0), ("pinch", 5.0))
    transparent: tuple[tuple[str, float], ...] = (("view", 1000.0), ("touch", 1.0), ("pinch", 1.25))

    def __post_init__(self):
        for name in ("opaque", "transparent"):
            for kind, cost in getattr(self, name):
                as_real(cost, f"{name}: cost of {kind!r}", low=0.0, open_low=True)

    def cost(self, kind: str, transparent: bool) -> float:
        table = dict(self.transparent if transparent else self.opaque)
        if kind not in table:
            raise ValueError(f"kind: no energy cost for action kind {kind!r}; known: {sorted(table)}")
        return float(table[kind])


def energy_costs(kinds, transparent: bool, costs: EnergyCosts | None = None) -> np.ndarray:
    """``(A,)`` energy cost ``D(a)`` of each action from its kind (``"view"``, ``"touch"``, ``"pinch"``)."""
    costs = costs or EnergyCosts()
    kinds = list(kinds)
    if not kinds:
        raise ValueError("kinds: need at least one action kind")
    return np.array([costs.cost(k, bool(transparent)) for k in kinds], dtype=np.float64)


def select_next_best_action(gains, costs=None) -> int:
    """Index of ``argmax_a gains[a] / costs[a]`` (eq. 5.10; eq. 5.9 when ``costs`` is None)."""
    g = to_numpy(gains).reshape(-1) if np.ndim(gains) else np.array([gains], dtype=np.float64)
    if g.size == 0:
        raise ValueError("gains: no candidate actions")
    if not np.isfinite(g).all():
        raise ValueError("gains: contains NaN or inf")
    if costs is None:
        return int(np.argmax(g))
    c = to_numpy(costs).reshape(-1)
    if c.shape != g.shape:
        raise ValueError(f"costs: expected shape {g.shape} to match gains, got {c.shape}")
    if not np.isfinite(c).all() or (c <= 0).any():
        raise ValueError("costs: energy costs must be positive and finite")
    return int(np.argmax(g / c))


def _check_box(box, name: str) -> np.ndarray:
    b = to_numpy(box).reshape(-1)
    if b.shape != (4,) or not np.isfinite(b).all():
        raise ValueError(f"{name}: expected finite (x_min, y_min, x_max, y_max), got {b.tolist()}")
    if b[2] < b[0] or b[3] < b[1]:
        raise ValueError(f"{name}: max corner below min corner in {b.tolist()}")
    return b


def box_iou_2d(box_a, box_b) -> float:
    """Intersection over union of two axis-aligned 2-D boxes ``(x_min, y_min, x_max, y_max)``."""
    a, b = _check_box(box_a, "box_a"), _check_box(box_b, "box_b")
    iw = max(0.0, min(a[2], b[2]) - max(a[0], b[0]))
    ih = max(0.0, min(a[3], b[3]) - max(a[1], b[1]))
    inter = iw * ih
    union = (a[2] - a[0]) * (a[3] - a[1]) + (b[2] - b[0]) * (b[3] - b[1]) - inter
    return float(inter / union) if union > 0 else 0.0


def mask_box(mask) -> np.ndarray:
    """Pixel box ``(u_min, v_min, u_max, v_max)`` of the largest connected region of a segmentation mask.

    The thesis extracts ``C_rgb`` by contour segmentation; the largest 8-connected component stands in
    for the object contour here. Pixel edges are used, so a single pixel ``(u, v)`` gives
    ``(u, v, u + 1, v + 1)``.
    """
    from scipy import ndimage

    m = np.asarray(mask, dtype=bool)
    if m.ndim != 2:
        raise ValueError(f"mask: expected an (H, W) image, got shape {m.shape}")
    if not m.any():
        raise ValueError("mask: is empty (no object pixels)")
    labels, count = ndimage.label(m, structure=np.ones((3, 3)))
    sizes = np.bincount(labels.ravel())[1:]
    vs, us = np.nonzero(labels == 1 + int(np.argmax(sizes)))
    return np.array([us.min(), vs.min(), us.max() + 1, vs.max() + 1], dtype=np.float64)


def pixels_to_plane(uv: np.ndarray, K: np.ndarray, T_world_camera: np.ndarray,
                    plane_z: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
    """Intersect the camera rays through pixel coordinates ``uv`` with the plane ``z = plane_z``.

    A pinhole ray ``d_camera = K⁻¹ (u, v, 1)`` is turned into the world, ``d_world = R d_camera``, and meets
    the plane at ``t_world + s d_world`` with ``s = (plane_z − t_z) / d_z``. Rays parallel to the plane or
    that meet it behind the camera (``s ≤ 0``) are not valid.

    Shapes:
        uv (M, 2) pixels, K (3, 3), T_world_camera (4, 4) optical frame -> points (M, 3) world metres
        (NaN where not valid), valid (M,) bool
    """
    uv = np.asarray(uv, dtype=np.float64)
    if uv.ndim != 2 or uv.shape[1] != 2 or not np.isfinite(uv).all():
        raise ValueError(f"uv: expected finite (M, 2) pixel coordinates, got shape {uv.shape}")
    K = to_numpy(K)
    if K.shape != (3, 3) or not np.isfinite(K).all():
        raise ValueError(f"K: expected a finite (3, 3) intrinsics matrix, got shape {K.shape}")
    T_world_camera = as_transform(T_world_camera, "T_world_camera")
    d_world = np.linalg.solve(K, np.column_stack([uv, np.ones(len(uv))]).T).T @ T_world_camera[:3, :3].T
    points = np.full((len(uv), 3), np.nan)
    valid = np.abs(d_world[:, 2]) >= 1e-12
    s = (plane_z - T_world_camera[2, 3]) / np.where(valid, d_world[:, 2], 1.0)
    valid &= s > 0
    points[valid] = T_world_camera[:3, 3] + s[valid, None] * d_world[valid]
    return points, valid


def pixel_box_to_plane(box_px, K, T_world_camera, plane_z: float = 0.0) -> np.ndarray:
    """Back-project a pixel box onto the horizontal plane ``z = plane_z`` and return its world xy box.

    Args:
        box_px: ``(u_min, v_min, u_max, v_max)`` in pixels.
        K: ``(3, 3)`` camera intrinsics.
        T_world_camera: ``(4, 4)`` optical frame (z forward, x right, y down) in the world.
    """
    b = _check_box(box_px, "box_px")
    corners = [[b[0], b[1]], [b[2], b[1]], [b[2], b[3]], [b[0], b[3]]]
    corners, valid = pixels_to_plane(corners, K, T_world_camera, plane_z)
    if not valid.all():
        raise ValueError("T_world_camera: the plane is parallel to or behind the camera for some box corners")
    xy = corners[:, :2]
    return np.array([xy[:, 0].min(), xy[:, 1].min(), xy[:, 0].max(), xy[:, 1].max()])


def cloud_top_down_box(
    points, plane_distance: float = 0.005, min_points: int = 10, seed: int = 0
) -> np.ndarray | None:
    """World xy box ``C_pc`` of an object's cloud after removing the support plane (thesis 5.2.3).

    The dominant plane is found by RANSAC (Open3D ``segment_plane``); if it holds points, they are
    removed. Returns None when fewer than ``min_points`` object points remain, which is what a
    transparent object's depth image tends to give.
    """
    import open3d as o3d

    pts = to_numpy(points)
    if pts.ndim != 2 or pts.shape[1] != 3:
        raise ValueError(f"points: expected shape (N, 3), got {tuple(pts.shape)}")
    if pts.shape[0] and not np.isfinite(pts).all():
        raise ValueError("points: contains NaN or inf")
    plane_distance = as_real(plane_distance, "plane_distance", low=0.0, open_low=True, unit="m")
    if pts.shape[0] >= 3:
        pcd = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(pts))
        o3d.utility.random.seed(seed)
        _, inliers = pcd.segment_plane(plane_distance, 3, 200)
        keep = np.ones(pts.shape[0], dtype=bool)
        # Only drop the plane if it is the support plane (close to horizontal) and not the object itself.
        if len(inliers) >= 3:
            normal = np.linalg.svd(pts[inliers] - pts[inliers].mean(axis=0))[2][-1]
            if abs(normal[2]) > 0.9:
                keep[np.asarray(inliers)] = False
        pts = pts[keep]
    if pts.shape[0] < min_points:
        return None
    return np.array([pts[:, 0].min(), pts[:, 1].min(), pts[:, 0].max(), pts[:, 1].max()])


def detect_transparent(
    rgb_box_xy, points, omega: float = 0.5, plane_distance: float = 0.005
) -> tuple[bool, float]:
    """Transparency test of thesis 5.2.3: ``IoU(C_pc, C_rgb) < omega``.

    Args:
        rgb_box_xy: ``C_rgb`` in world metres, e.g. from :func:`mask_box` and :func:`pixel_box_to_plane`.
        points: ``(N, 3)`` top-down depth cloud of the object region, support plane included or not.
        omega: IoU threshold.

    Returns:
        (is_transparent, iou); an object whose cloud vanishes with the plane has IoU 0.
    """
    omega = as_real(omega, "omega", low=0.0, high=1.0, open_low=True)
    c_rgb = _check_box(rgb_box_xy, "rgb_box_xy")
    c_pc = cloud_top_down_box(points, plane_distance=plane_distance)
    iou = 0.0 if c_pc is None else box_iou_2d(c_pc, c_rgb)
    return bool(iou < omega), iou


@dataclass
class Selection:
    """Result of :func:`next_best_action`: the chosen action and the scores of every candidate."""

    kind: str
    index: int
    T_world_sensor: np.ndarray
    gains: np.ndarray
    costs: np.ndarray
    kinds: list[str]


def next_best_action(
    grid, candidates, transparent: bool = False, costs: EnergyCosts | None = None
) -> Selection:
    """Algorithm 2 of the thesis: score views, touches and pinches on one grid and pick by eq. 5.10.

    Args:
        grid: a :class:`vtlearn.active.occupancy.OccupancyGrid` holding the shared belief.
        candidates: list of ``(ActionSet, sensor)`` pairs; ``sensor.rays(T_world_sensor)`` gives the
            virtual measurement rays of the set (:mod:`vtlearn.active.sensors`).
        transparent: result of :func:`detect_transparent`; switches the energy costs.

    Returns:
        Selection with the chosen ``kind``, its ``index`` within that ActionSet, and per-candidate
        ``gains`` (eq. 5.8, nats) and ``costs`` (all candidates concatenated in the order given).

    Shapes:
        candidates: ``A_k`` actions in set ``k`` -> ``gains``, ``costs``: ``(A,)`` with ``A = sum_k A_k``;
        ``T_world_sensor``: ``(4, 4)``.
    """
    from vtlearn.active.actions import ActionSet
    from vtlearn.active.occupancy import OccupancyGrid
    from vtlearn.active.sensors import Rays

    if not isinstance(grid, OccupancyGrid):
        raise ValueError(f"grid: expected an OccupancyGrid, got {type(grid).__name__}")
    if not candidates:
        raise ValueError("candidates: need at least one (ActionSet, sensor) pair")
    for i, pair in enumerate(candidates):
        if not (isinstance(pair, (tuple, list)) and len(pair) == 2 and isinstance(pair[0], ActionSet)
                and callable(getattr(pair[1], "rays", None))):
            raise ValueError(f"candidates[{i}]: expected an (ActionSet, sensor) pair such as "
                             f"(sample_touch_actions(...), TactileArray()), got {type(pair).__name__}")
    parts, kinds, local = [], [], []
    for actions, sensor in candidates:
        if len(actions) == 0:
            continue
        parts.append(sensor.rays(actions.T_world_sensor))
        kinds += [actions.kind] * len(actions)
        local += list(range(len(actions)))
    if not parts:
        raise ValueError("candidates: every ActionSet is empty")
    rays = Rays.concatenate(parts)
    gains = grid.expected_information_gain(
        rays.origins, rays.directions, rays.max_range, rays.action_index, rays.n_actions
    )
    d = energy_costs(kinds, transparent, costs)
    best = select_next_best_action(gains, d)
    owner = [actions for actions, _ in candidates if len(actions)]
    set_of = np.repeat(np.arange(len(owner)), [len(a) for a in owner])
    chosen = owner[int(set_of[best])]
    return Selection(kinds[best], local[best], chosen.T_world_sensor[local[best]].copy(), gains, d, kinds)
