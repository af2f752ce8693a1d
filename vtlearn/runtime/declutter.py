"""The declutter graph: which object to singulate next and how (thesis ch. 5, 5.2.2, eq. 5.1-5.2, Fig. 5.3).

Before the target object can be reconstructed and registered, the objects cluttering it are removed one at a
time. The scene is encoded as a directed graph ``G = (V, E)`` whose root is the target ``O_T``; an edge
``e_ij`` from ``v_i`` to ``v_j`` carries the action that singulates ``v_j`` from ``v_i``.

Everything is computed on the table plane, seen from above: the world frame is z-up, the table top is the
plane z = 0, units are metres and radians. The input is one world-frame cloud per object (an instance-
segmented scene cloud; in simulation the pybullet segmentation mask stands in for the thesis's semantic
segmentation network, see :func:`segmented_cloud` and :func:`instance_clouds_from_rgbd`).

- **Masks.** Each object's (x, y) points are rasterised on one shared metric grid (:class:`TableGrid`,
  ``cell`` = 4 mm by default) and closed morphologically, so sparse points become a filled footprint.
- **Overlap metric (Definition 1).** ``IoU_ij`` of the minimum-area bounding rectangles of the two objects
  (rotating calipers over the convex hull of the object's xy points, :func:`min_area_rect`); the IoU of two
  rotated rectangles is exact, by Sutherland-Hodgman clipping and the shoelace area (:func:`rect_iou`).
- **Proximity metric (Definition 2).** ``d_ij``, the shortest xy distance between the two objects' points
  (their contours), in metres; 0 when the two masks share a cell (:func:`proximity`).
- **Edge weight, eq. 5.1.** ``e_ij = IoU_ij`` if ``IoU_ij > mu_o``; ``1 / d_ij`` if ``d_ij < mu_d`` and
  ``IoU_ij <= mu_o``; 0 otherwise (:func:`edge_weight`). The thesis sets ``mu_o = 0.05``, ``mu_d = 0.5``,
  ``mu_q = 0.1`` but measured ``d`` in image space without a unit. Here ``d`` is in metres and
  ``mu_d = 0.03`` m by default, about one fingertip width (the thesis gives ~3 cm): an object closer than
  that leaves no room for a finger. ``1 / d`` is in 1/m and ``d`` is floored at one grid cell, since two
  touching objects whose rectangles barely overlap have ``d = 0``. Proximity weights (>= 1 / mu_d = 33 /m)
  therefore always exceed overlap weights (<= 1), exactly as eq. 5.1 mixes them.
- **Action, eq. 5.2.** The edge into ``v_k`` carries a grasp ``a_grasp = (p_grasp, alpha_grasp, p_place)``
  if the grasp quality ``q_k >= mu_q`` and a push ``a_push = (p_push, d_push)`` otherwise. The thesis gets
  ``q_k`` from GG-CNN; without a network, :func:`grasp_quality` is a geometric stand-in (a parallel-jaw
  width score times the clearance of the two fingertip footprints). Qualities may also be given.
- **Push (text after Fig. 5.4, Fig. 5.3c).** ``v = sum_i w_i v_ik`` over the other objects around ``k``
  (those with a nonzero eq. 5.1 weight to it), ``d_push = -v / |v|``. Read literally, ``w_i v_ik`` with
  ``w_i`` proportional to ``1 / |v_ik|`` gives every neighbour the same pull; the thesis wants "higher weights
  for closer objects", so we weight the unit vectors ``v_ik / |v_ik|`` by ``w_i = (1 / |v_ik|) / sum``
  (:func:`push_direction`). The push point: the candidates are where the line through the centre along
  ``d_push`` leaves the back of the contour (the thesis's first choice) and samples along the convex hull
  whose outward normal opposes ``d_push`` (the pusher must be behind the object). A fingertip footprint is
  placed behind each, and the one covering least of the other objects' masks wins (ties: nearest the centre
  line). The thesis scores the mean IoU of the footprint with the other objects; we score the fraction of
  the footprint on them, since a footprint deep inside a large object has a small IoU yet cannot be reached.
- **Graph and traversal.** The graph is built breadth-first from the target, so each object hangs under the
  nearest-to-target object it has an edge to (the heaviest such edge when there are several). The next
  object to singulate is the leaf reached by depth-first descent from the root, taking the heaviest child
  at each step; decluttering is complete when the root has no children (:class:`DeclutterGraph`).

Shapes:
    clouds: mapping object id -> ``(N_k, 3)`` world points; masks: ``(nx, ny)`` bool, indexed ``[ix, iy]``;
    rectangles: :class:`MinAreaRect` (``corners`` ``(4, 2)``, counter-clockwise); polygons ``(P, 2)``;
    actions: ``p_grasp``, ``p_place``, ``p_push``, ``d_push`` ``(3,)`` in the world frame.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from scipy import ndimage
from scipy.spatial import ConvexHull, QhullError, cKDTree

from vtlearn.runtime.obb import check_object_cloud
from vtlearn.validation import as_int, as_points, as_real, to_numpy

__all__ = [
    "DeclutterAction",
    "DeclutterEdge",
    "DeclutterGraph",
    "DeclutterNode",
    "GraspAction",
    "MinAreaRect",
    "PushAction",
    "TableGrid",
    "action_kind",
    "clip_convex_polygon",
    "edge_weight",
    "grasp_quality",
    "instance_clouds_from_rgbd",
    "min_area_rect",
    "occupancy_masks",
    "polygon_area",
    "proximity",
    "push_direction",
    "rect_iou",
    "segmented_cloud",
]

# Thesis 5.2.2 thresholds; MU_D is ours in metres (the thesis's 0.5 has no stated unit, see the docstring).
MU_O = 0.05
MU_D = 0.03
MU_Q = 0.1
CELL = 0.004
FINGERTIP = (0.03, 0.02)  # (width across the push/closing direction, depth along it), metres
MAX_OPENING = 0.08
PUSH_DISTANCE = 0.10
# Largest grid we rasterise on: a 2 m x 2 m table at 1 mm cells.
_MAX_CELLS = 4_000_000


# ----------------------------------------------------------------------------------------------- checks
def _fingertip(fingertip: Any) -> tuple[float, float]:
    try:
        w, d = (float(v) for v in fingertip)
    except (TypeError, ValueError):
        raise ValueError(f"fingertip: need (width, depth) in metres, got {fingertip!r}") from None
    if not (math.isfinite(w) and math.isfinite(d) and w > 0 and d > 0):
        raise ValueError(f"fingertip: need two positive finite sizes, got {fingertip!r}")
    return w, d


def _xy(points: Any, name: str, min_points: int = 1) -> np.ndarray:
    """(N, 2) or (N, 3) -> (N, 2) float64 xy, validated."""
    shape = np.shape(points) if not hasattr(points, "shape") else tuple(points.shape)
    dim = 2 if len(shape) == 2 and shape[1] == 2 else 3
    return as_points(points, name, min_points=min_points, dim=dim)[:, :2]


def _vec(x: Any, name: str, dim: int) -> np.ndarray:
    """A single finite point of ``dim`` coordinates."""
    try:
        arr = np.asarray(to_numpy(x), dtype=np.float64)
    except (TypeError, ValueError):
        raise ValueError(f"{name}: need {dim} finite coordinates, got {x!r}") from None
    if arr.shape != (dim,):
        raise ValueError(f"{name}: need shape ({dim},), got {arr.shape}")
    return as_points(arr[None], name, dim=dim)[0]


def _polygon(poly: Any, name: str) -> np.ndarray:
    return as_points(poly, name, min_points=0, dim=2)


def _wrap_half_turn(angle: float) -> float:
    """An undirected axis angle in (-pi/2, pi/2]."""
    a = (angle + math.pi / 2) % math.pi - math.pi / 2
    return math.pi / 2 if a == -math.pi / 2 else a


# ---------------------------------------------------------------------------------------- rectangles
@dataclass(frozen=True)
class MinAreaRect:
    """A rotated rectangle on the table plane.

    Attributes:
        center: ``(2,)`` world xy of its centre, metres.
        size: ``(length, width)``, ``length >= width``, metres.
        angle: yaw of the long axis in rad, in (-pi/2, pi/2].

    Shapes:
        center ``(2,)``; axes ``(2, 2)`` rows (long axis u, short axis v = u rotated +90 deg);
        corners ``(4, 2)`` counter-clockwise.
    """

    center: np.ndarray
    size: tuple[float, float]
    angle: float

    @property
    def axes(self) -> np.ndarray:
        c, s = math.cos(self.angle), math.sin(self.angle)
        return np.array([[c, s], [-s, c]])

    @property
    def corners(self) -> np.ndarray:
        (u, v), (hl, hw) = self.axes, (self.size[0] / 2, self.size[1] / 2)
        signs = np.array([[-1.0, -1.0], [1.0, -1.0], [1.0, 1.0], [-1.0, 1.0]])
        return self.center + signs[:, :1] * hl * u + signs[:, 1:] * hw * v

    @property
    def area(self) -> float:
        return float(self.size[0] * self.size[1])

    def to_dict(self) -> dict:
        return {"center": self.center.tolist(), "size": list(self.size), "angle": self.angle}


def min_area_rect(points: Any) -> MinAreaRect:
    """Minimum-area bounding rectangle of the xy points (rotating calipers, Freeman and Shapira 1975).

    The minimum-area rectangle has a side collinear with an edge of the convex hull, so every hull edge
    direction is tried. Collinear or coincident points give a rectangle of zero width (and length).

    Args:
        points: ``(N, 2)`` xy or ``(N, 3)`` world points (z is ignored), N >= 1.

    Shapes:
        points ``(N, 2)`` or ``(N, 3)`` -> :class:`MinAreaRect`.
    """
    xy = _xy(points, "points")
    try:
        hull = xy[ConvexHull(xy).vertices]  # (H, 2), counter-clockwise
    except (QhullError, ValueError):
        return _degenerate_rect(xy)
    edges = np.roll(hull, -1, axis=0) - hull
    angles = np.arctan2(edges[:, 1], edges[:, 0])
    c, s = np.cos(angles), np.sin(angles)
    # hull points in each edge-aligned frame: (E, H)
    pu = c[:, None] * hull[None, :, 0] + s[:, None] * hull[None, :, 1]
    pv = -s[:, None] * hull[None, :, 0] + c[:, None] * hull[None, :, 1]
    lo_u, hi_u, lo_v, hi_v = pu.min(1), pu.max(1), pv.min(1), pv.max(1)
    k = int(np.argmin((hi_u - lo_u) * (hi_v - lo_v)))
    mu, mv = (lo_u[k] + hi_u[k]) / 2, (lo_v[k] + hi_v[k]) / 2
    center = np.array([c[k] * mu - s[k] * mv, s[k] * mu + c[k] * mv])
    du, dv, angle = float(hi_u[k] - lo_u[k]), float(hi_v[k] - lo_v[k]), float(angles[k])
    if dv > du:
        du, dv, angle = dv, du, angle + math.pi / 2
    return MinAreaRect(center, (du, dv), _wrap_half_turn(angle))


def _degenerate_rect(xy: np.ndarray) -> MinAreaRect:
    centred = xy - xy.mean(0)
    _, _, vt = np.linalg.svd(centred, full_matrices=False)
    u = vt[0] if np.abs(centred).max() > 0 else np.array([1.0, 0.0])
    t = centred @ u
    center = xy.mean(0) + u * (t.min() + t.max()) / 2
    return MinAreaRect(center, (float(t.max() - t.min()), 0.0), _wrap_half_turn(math.atan2(u[1], u[0])))


def polygon_area(poly: Any) -> float:
    """Unsigned area of a simple polygon by the shoelace formula; 0 for fewer than 3 vertices.

    Shapes:
        poly ``(P, 2)`` -> float.
    """
    P = _polygon(poly, "poly")
    if len(P) < 3:
        return 0.0
    x, y = P[:, 0], P[:, 1]
    return float(abs(np.dot(x, np.roll(y, -1)) - np.dot(y, np.roll(x, -1))) / 2)


def clip_convex_polygon(subject: Any, clip: Any) -> np.ndarray:
    """Intersection of two convex polygons by Sutherland-Hodgman clipping (Sutherland and Hodgman 1974).

    ``subject`` is clipped against each edge of ``clip`` in turn; both may wind either way.

    Shapes:
        subject ``(P, 2)``, clip ``(Q, 2)`` -> ``(R, 2)`` counter-clockwise (``(0, 2)`` when disjoint).
    """
    S, C = _polygon(subject, "subject"), _polygon(clip, "clip")
    if len(C) < 3 or len(S) < 3:
        return np.zeros((0, 2))
    if _signed_area(C) < 0:
        C = C[::-1]
    if _signed_area(S) < 0:
        S = S[::-1]
    out = list(S)
    for a, b in zip(C, np.roll(C, -1, axis=0), strict=True):
        if not out:
            break
        e = b - a
        inp, out = out, []
        side = [e[0] * (p[1] - a[1]) - e[1] * (p[0] - a[0]) for p in inp]  # >= 0: left of a->b, inside
        for i, (p, sp) in enumerate(zip(inp, side, strict=True)):
            q, sq = inp[i - 1], side[i - 1]
            if sp >= 0:
                if sq < 0:
                    out.append(q + (p - q) * (sq / (sq - sp)))
                out.append(p)
            elif sq >= 0:
                out.append(q + (p - q) * (sq / (sq - sp)))
    return np.array(out).reshape(-1, 2)


def _signed_area(P: np.ndarray) -> float:
    x, y = P[:, 0], P[:, 1]
    return float(np.dot(x, np.roll(y, -1)) - np.dot(y, np.roll(x, -1))) / 2


def rect_iou(a: MinAreaRect, b: MinAreaRect) -> float:
    """Exact IoU of two rotated rectangles: ``|a n b| / (|a| + |b| - |a n b|)`` (Definition 1).

    Shapes:
        two :class:`MinAreaRect` -> float in [0, 1]; 0 when the union has no area.
    """
    for r, name in ((a, "a"), (b, "b")):
        if not isinstance(r, MinAreaRect):
            raise ValueError(f"{name}: need a MinAreaRect, got {type(r).__name__}")
    inter = polygon_area(clip_convex_polygon(a.corners, b.corners)) if a.area > 0 and b.area > 0 else 0.0
    union = a.area + b.area - inter
    return float(min(max(inter / union, 0.0), 1.0)) if union > 0 else 0.0


# ----------------------------------------------------------------------------------------- the grid
@dataclass(frozen=True)
class TableGrid:
    """A metric grid on the table plane: cell ``(ix, iy)`` covers ``origin + cell * [ix, ix+1) x [iy, iy+1)``.

    Shapes:
        origin ``(2,)`` world xy of the lower-left corner; shape ``(nx, ny)``; masks ``(nx, ny)`` bool.
    """

    origin: np.ndarray
    cell: float
    shape: tuple[int, int]

    @classmethod
    def around(cls, xy: np.ndarray, cell: float, margin: float) -> TableGrid:
        """The grid covering the xy points plus ``margin`` metres on every side."""
        lo, hi = xy.min(0) - margin, xy.max(0) + margin
        shape = tuple(int(n) for n in np.ceil((hi - lo) / cell).astype(int) + 1)
        if shape[0] * shape[1] > _MAX_CELLS:
            raise ValueError(
                f"cell: a {cell} m grid over the {hi[0] - lo[0]:.2f} m x {hi[1] - lo[1]:.2f} m scene needs "
                f"{shape[0] * shape[1]} cells (more than {_MAX_CELLS}); use a larger cell"
            )
        return cls(lo, cell, shape)

    @property
    def extent(self) -> tuple[float, float, float, float]:
        """(xmin, xmax, ymin, ymax) for ``imshow(mask.T, origin="lower", extent=...)``."""
        x0, y0 = self.origin
        return (x0, x0 + self.shape[0] * self.cell, y0, y0 + self.shape[1] * self.cell)

    def index(self, xy: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Cell indices ``(ix, iy)`` of xy points and a bool saying which fall inside the grid."""
        ij = np.floor((xy - self.origin) / self.cell).astype(np.int64)
        inside = (ij[:, 0] >= 0) & (ij[:, 0] < self.shape[0]) & (ij[:, 1] >= 0) & (ij[:, 1] < self.shape[1])
        return ij[:, 0], ij[:, 1], inside

    def rasterise(self, xy: np.ndarray, closing: int = 1) -> np.ndarray:
        """Bool mask of the cells holding a point, closed ``closing`` times (3x3 square), holes filled."""
        ix, iy, inside = self.index(xy)
        mask = np.zeros(self.shape, dtype=bool)
        mask[ix[inside], iy[inside]] = True
        if closing > 0:
            mask = ndimage.binary_closing(mask, structure=np.ones((3, 3), bool), iterations=closing)
            mask = ndimage.binary_fill_holes(mask)
        return mask

    def box_overlap(self, occupied: np.ndarray, center: np.ndarray, along: np.ndarray, size) -> float:
        """Fraction of a rotated box that lies on ``occupied`` cells (cells off the grid are free).

        The box has ``size = (width, depth)``: ``depth`` along the unit ``along``, ``width`` across it. It is
        sampled at half-cell spacing.
        """
        w, d = size
        nw, nd = max(2, math.ceil(2 * w / self.cell)), max(2, math.ceil(2 * d / self.cell))
        sw = ((np.arange(nw) + 0.5) / nw - 0.5) * w
        sd = ((np.arange(nd) + 0.5) / nd - 0.5) * d
        across = np.array([-along[1], along[0]])
        pts = center + sd[:, None, None] * along + sw[None, :, None] * across  # (nd, nw, 2)
        ix, iy, inside = self.index(pts.reshape(-1, 2))
        hit = np.zeros(len(ix), dtype=bool)
        hit[inside] = occupied[ix[inside], iy[inside]]
        return float(hit.mean())


def _check_clouds(clouds: Any) -> dict[int, np.ndarray]:
    if not isinstance(clouds, Mapping):
        raise ValueError(f"clouds: need a mapping object id -> (N, 3) points, got {type(clouds).__name__}")
    if len(clouds) == 0:
        raise ValueError("clouds: empty mapping; need at least the target object's cloud")
    out = {}
    for k, v in clouds.items():
        if isinstance(k, bool) or not isinstance(k, (int, np.integer)):
            raise ValueError(f"clouds: object ids must be integers, got key {k!r}")
        out[int(k)] = check_object_cloud(v, f"clouds[{k}]")
    return out


def occupancy_masks(
    clouds: Mapping[int, Any], *, cell: float = CELL, margin: float = 0.05, closing: int = 1
) -> tuple[TableGrid, dict[int, np.ndarray]]:
    """Top-down occupancy mask of every object on one shared grid.

    Args:
        clouds: object id -> world points (at least 3 each).
        cell: grid cell size, metres.
        margin: free border around the objects, metres.
        closing: iterations of the 3x3 morphological closing that fills the gaps between sparse points.

    Shapes:
        clouds ``{id: (N_k, 3)}`` -> (:class:`TableGrid`, ``{id: (nx, ny) bool}``).
    """
    pts = _check_clouds(clouds)
    cell = as_real(cell, "cell", low=0.0, open_low=True)
    margin = as_real(margin, "margin", low=0.0)
    closing = as_int(closing, "closing", minimum=0)
    # the closing must not reach the border, or it would erode footprints touching it
    grid = TableGrid.around(
        np.concatenate([p[:, :2] for p in pts.values()]), cell, margin + (closing + 1) * cell
    )
    return grid, {k: grid.rasterise(p[:, :2], int(closing)) for k, p in pts.items()}


# ------------------------------------------------------------------------------------ metrics, eq. 5.1
def _proximity(mask_a, mask_b, tree_a: cKDTree, xy_b: np.ndarray) -> float:
    if (mask_a & mask_b).any():
        return 0.0
    return float(tree_a.query(xy_b, k=1)[0].min())


def proximity(points_a: Any, points_b: Any, *, cell: float = CELL) -> float:
    """Shortest distance between two objects' contours (Definition 2), metres.

    The xy distance between the closest pair of points of the two clouds (scipy ``cKDTree``), and 0 when the
    two objects' top-down masks (:func:`occupancy_masks` at ``cell``) share a cell.

    Shapes:
        points_a ``(N, 3)``, points_b ``(M, 3)`` -> float.
    """
    a = as_points(points_a, "points_a", min_points=3)
    b = as_points(points_b, "points_b", min_points=3)
    _, masks = occupancy_masks({0: a, 1: b}, cell=cell, margin=0.0)
    if (masks[0] & masks[1]).any():
        return 0.0
    return float(cKDTree(a[:, :2]).query(b[:, :2], k=1)[0].min())


def edge_weight(
    iou: float, distance: float, *, mu_o: float = MU_O, mu_d: float = MU_D, d_floor: float = CELL
) -> tuple[float, str | None]:
    """Eq. 5.1: the weight of the edge between two objects and which metric made it.

    ``IoU`` if ``IoU > mu_o`` ("overlap"); ``1 / max(d, d_floor)`` (1/m) if ``d < mu_d`` and
    ``IoU <= mu_o`` ("proximity"); ``(0, None)`` otherwise (no edge).

    Args:
        iou: rectangle IoU (Definition 1), in [0, 1].
        distance: contour distance (Definition 2), metres, >= 0 (inf allowed: far apart).
        mu_o: overlap threshold (thesis 0.05).
        mu_d: proximity threshold, metres (default 0.03 m; see the module docstring).
        d_floor: smallest distance used in ``1 / d``, metres (one grid cell by default).

    Shapes:
        scalars -> (float, "overlap" | "proximity" | None).
    """
    iou = as_real(iou, "iou", low=0.0, high=1.0)
    try:
        distance = float(distance)
    except (TypeError, ValueError):
        raise ValueError(f"distance: need a number, got {distance!r}") from None
    if math.isnan(distance) or distance < 0:
        raise ValueError(f"distance: need a non-negative distance in metres, got {distance}")
    mu_o = as_real(mu_o, "mu_o")
    mu_d = as_real(mu_d, "mu_d", low=0.0, open_low=True)
    d_floor = as_real(d_floor, "d_floor", low=0.0, open_low=True)
    if iou > mu_o:
        return iou, "overlap"
    if distance < mu_d:
        return 1.0 / max(distance, d_floor), "proximity"
    return 0.0, None


def action_kind(quality: float, mu_q: float = MU_Q) -> str:
    """Eq. 5.2: ``"grasp"`` when the grasp quality ``q >= mu_q``, else ``"push"``."""
    return "grasp" if as_real(quality, "quality") >= as_real(mu_q, "mu_q") else "push"


# --------------------------------------------------------------------------------------------- actions
@dataclass(frozen=True)
class GraspAction:
    """``a_grasp = (p_grasp, alpha_grasp, p_place)`` for object ``object_id`` (thesis 5.2.2, Fig. 5.4a).

    ``p_grasp`` is the rectangle centre at half the object's height; ``alpha_grasp`` the yaw of the jaws'
    closing direction (the rectangle's short axis), rad in (-pi/2, pi/2]; ``width`` the object width
    across the jaws, metres.

    Shapes:
        p_grasp, p_place ``(3,)`` world.
    """

    object_id: int
    p_grasp: np.ndarray
    alpha_grasp: float
    p_place: np.ndarray
    quality: float
    width: float
    kind: str = field(default="grasp", init=False)

    def to_dict(self) -> dict:
        return {
            "kind": self.kind,
            "object_id": self.object_id,
            "p_grasp": self.p_grasp.tolist(),
            "alpha_grasp": self.alpha_grasp,
            "p_place": self.p_place.tolist(),
            "quality": self.quality,
            "width": self.width,
        }


@dataclass(frozen=True)
class PushAction:
    """``a_push = (p_push, d_push)``: a straight push of ``distance`` metres (thesis 5.2.2, Fig. 5.3c, 5.4b).

    ``p_push`` is the contact point on the object's contour at half its height, ``d_push`` the unit push
    direction (z = 0), ``fingertip`` the centre of the fingertip footprint behind the contact where the push
    starts, ``overlap`` the fraction of that footprint on other objects (0 = free), ``quality`` the grasp
    quality that ruled out a grasp (eq. 5.2).

    Shapes:
        p_push, d_push, fingertip, p_end ``(3,)`` world.
    """

    object_id: int
    p_push: np.ndarray
    d_push: np.ndarray
    distance: float
    fingertip: np.ndarray
    overlap: float
    quality: float
    kind: str = field(default="push", init=False)

    @property
    def p_end(self) -> np.ndarray:
        return self.p_push + self.distance * self.d_push

    def to_dict(self) -> dict:
        return {
            "kind": self.kind,
            "object_id": self.object_id,
            "p_push": self.p_push.tolist(),
            "d_push": self.d_push.tolist(),
            "distance": self.distance,
            "fingertip": self.fingertip.tolist(),
            "overlap": self.overlap,
            "quality": self.quality,
        }


DeclutterAction = GraspAction | PushAction


def _grasp_quality(rect: MinAreaRect, grid: TableGrid, others: np.ndarray, max_opening, fingertip) -> float:
    width_score = min(max(1.0 - rect.size[1] / max_opening, 0.0), 1.0)
    if width_score == 0.0:
        return 0.0
    v = rect.axes[1]
    off = rect.size[1] / 2 + fingertip[1] / 2
    busy = [grid.box_overlap(others, rect.center + s * off * v, v, fingertip) for s in (-1.0, 1.0)]
    return width_score * (1.0 - float(np.mean(busy)))


def grasp_quality(
    points: Any,
    others: Sequence[Any] = (),
    *,
    cell: float = CELL,
    max_opening: float = MAX_OPENING,
    fingertip: tuple[float, float] = FINGERTIP,
) -> float:
    """A geometric stand-in for the GG-CNN grasp quality ``q_k`` of eq. 5.2, in [0, 1].

    A top-down parallel-jaw grasp closes across the short side of the object's minimum-area rectangle, of
    width ``w``. The width score ``clip(1 - w / max_opening, 0, 1)`` is 0 for objects wider than the opening
    and falls as the object fills the jaws. It is multiplied by the clearance: the free fraction of the two
    fingertip footprints (``fingertip = (width, depth)``, width along the rectangle's long axis) placed just
    outside the object on both sides of its short axis, where "occupied" means on another object's mask.

    Args:
        points: the object's world points.
        others: the other objects' world points (each at least 3 points).
        cell: grid cell of the masks, metres.
        max_opening: the gripper's largest opening, metres.
        fingertip: fingertip footprint (width, depth), metres.

    Shapes:
        points ``(N, 3)``, others sequence of ``(M_i, 3)`` -> float.
    """
    if isinstance(others, Mapping) or isinstance(others, np.ndarray) and others.ndim == 2:
        raise ValueError("others: need a sequence of (M, 3) clouds, one per other object")
    clouds = {0: points, **{i + 1: o for i, o in enumerate(others)}}
    max_opening = as_real(max_opening, "max_opening", low=0.0, open_low=True)
    fingertip = _fingertip(fingertip)
    try:
        grid, masks = occupancy_masks(clouds, cell=cell, margin=0.0)
    except ValueError as exc:  # name the caller's argument
        msg = str(exc).replace("clouds[0]", "points").replace("clouds[", "others[")
        raise ValueError(msg) from None
    others_mask = np.zeros(grid.shape, bool)
    for k, m in masks.items():
        if k:
            others_mask |= m
    return _grasp_quality(min_area_rect(points), grid, others_mask, max_opening, fingertip)


def push_direction(center: Any, neighbours: Any, *, away_from: Any = None) -> np.ndarray:
    """``d_push = -v / |v|`` with ``v = sum_i w_i v_ik / |v_ik|``, ``w_i`` proportional to ``1 / |v_ik|``.

    ``v_ik`` runs from the pushed object's centre to neighbour ``i``'s (see the module docstring for why the
    vectors are normalised). When ``v`` vanishes (no neighbours, or they cancel), the push goes away from
    ``away_from`` (the target's centre); failing that, along +x.

    Shapes:
        center ``(2,)``, neighbours ``(M, 2)`` (M may be 0), away_from ``(2,)`` or None -> ``(3,)``
        unit vector with z = 0.
    """
    c = _vec(center, "center", 2)
    nb = as_points(neighbours, "neighbours", min_points=0, dim=2)
    v = np.zeros(2)
    if len(nb):
        vec = nb - c
        dist = np.linalg.norm(vec, axis=1)
        keep = dist > 1e-12
        if keep.any():
            w = 1.0 / dist[keep]
            v = ((w / w.sum())[:, None] * vec[keep] / dist[keep, None]).sum(0)
    if np.linalg.norm(v) <= 1e-9:
        v = np.array([-1.0, 0.0])
        if away_from is not None:
            a = _vec(away_from, "away_from", 2)
            if np.linalg.norm(c - a) > 1e-12:
                v = a - c
    d = -v / np.linalg.norm(v)
    return np.array([d[0], d[1], 0.0])


def _hull(xy: np.ndarray) -> np.ndarray:
    """Convex hull vertices, counter-clockwise; a thin rectangle for collinear or coincident points."""
    try:
        return xy[ConvexHull(xy).vertices]
    except (QhullError, ValueError):  # a micrometre of thickness keeps the edge normals defined
        r = _degenerate_rect(xy)
        return MinAreaRect(r.center, (max(r.size[0], 1e-6), max(r.size[1], 1e-6)), r.angle).corners


def _contour_samples(hull: np.ndarray, n: int) -> tuple[np.ndarray, np.ndarray]:
    """``n`` points equally spaced by arc length along a convex polygon and their outward unit normals."""
    edges = np.roll(hull, -1, axis=0) - hull
    lengths = np.linalg.norm(edges, axis=1)
    cum = np.concatenate([[0.0], np.cumsum(lengths)])
    s = np.arange(n) * cum[-1] / n
    e = np.clip(np.searchsorted(cum, s, side="right") - 1, 0, len(edges) - 1)
    t = (s - cum[e]) / np.maximum(lengths[e], 1e-300)
    pts = hull[e] + t[:, None] * edges[e]
    normals = np.stack([edges[e, 1], -edges[e, 0]], axis=1) / np.maximum(lengths[e, None], 1e-300)
    return pts, normals


def _ray_exit(hull: np.ndarray, origin: np.ndarray, direction: np.ndarray):
    """Where the ray from ``origin`` (inside) along ``direction`` leaves a convex polygon, and that edge's
    outward unit normal; None for a degenerate polygon."""
    best = None
    for a, b in zip(hull, np.roll(hull, -1, axis=0), strict=True):
        e = b - a
        den = direction[0] * e[1] - direction[1] * e[0]
        if abs(den) < 1e-15:
            continue
        w = a - origin
        t = (w[0] * e[1] - w[1] * e[0]) / den
        u = (w[0] * direction[1] - w[1] * direction[0]) / den
        if t >= 0 and -1e-12 <= u <= 1 + 1e-12 and (best is None or t > best[0]):
            best = (t, origin + t * direction, np.array([e[1], -e[0]]) / np.linalg.norm(e))
    return None if best is None else best[1:]


def _push_point(
    xy, centre, d_push, grid, others, fingertip, n_samples
) -> tuple[np.ndarray, np.ndarray, float]:
    """The contour point behind the object whose fingertip footprint overlaps the other objects least.

    The candidates are where the line through the centre along ``d_push`` meets the back of the contour (the
    thesis's first choice: a push through the centre) and ``n_samples`` points along the convex hull whose
    outward normal opposes ``d_push``. Ties (equal overlap, e.g. all free) go to the candidate nearest that
    centre line. The footprint's front face touches the contour point; where the contour is oblique to
    ``d_push`` it may clip the object's own footprint, which is not counted.
    """
    hull = _hull(xy)
    d = d_push[:2]
    pts, normals = _contour_samples(hull, n_samples)
    exit_ = _ray_exit(hull, centre, -d)
    if exit_ is not None:
        pts, normals = np.vstack([exit_[0], pts]), np.vstack([exit_[1], normals])
    behind = normals @ d < -1e-9
    if not behind.any():
        behind[:] = True
    best = None
    for p in pts[behind]:
        box = p - (fingertip[1] / 2) * d
        overlap = grid.box_overlap(others, box, d, fingertip)
        offset = abs(float(d[0] * (p - centre)[1] - d[1] * (p - centre)[0]))
        key = (overlap, offset)
        if best is None or key < best[0]:
            best = (key, p, box)
    (overlap, _), p, box = best
    return p, box, overlap


# ------------------------------------------------------------------------------------------ the graph
@dataclass(frozen=True)
class DeclutterNode:
    """An object in the declutter graph: its parent (None for the root), breadth-first depth, rectangle,
    height (its highest point above the table, metres) and grasp quality (None for the root)."""

    object_id: int
    parent: int | None
    depth: int
    rect: MinAreaRect
    height: float
    quality: float | None

    def to_dict(self) -> dict:
        return {
            "object_id": self.object_id,
            "parent": self.parent,
            "depth": self.depth,
            "rect": self.rect.to_dict(),
            "height": self.height,
            "quality": self.quality,
        }


@dataclass(frozen=True)
class DeclutterEdge:
    """``e_ij`` from ``parent`` (v_i) to ``child`` (v_j): eq. 5.1 weight, the metric that made it (``kind``
    "overlap" or "proximity"), both metrics, and the eq. 5.2 action that singulates the child."""

    parent: int
    child: int
    weight: float
    kind: str
    iou: float
    distance: float
    action: DeclutterAction

    def to_dict(self) -> dict:
        return {
            "parent": self.parent,
            "child": self.child,
            "weight": self.weight,
            "kind": self.kind,
            "iou": self.iou,
            "distance": self.distance,
            "action": self.action.to_dict(),
        }


QualitySource = Mapping[int, float] | Callable[[int, np.ndarray], float] | None


@dataclass
class DeclutterGraph:
    """The declutter graph ``G = (V, E)`` rooted at the target (thesis 5.2.2); build it with :meth:`build`.

    Attributes:
        target: the root object id.
        nodes: object id -> :class:`DeclutterNode` for every object in the graph (the root included).
        edges: the :class:`DeclutterEdge` list, parent before child.
        params: the thresholds and sizes it was built with.
        grid, masks, rects: the shared :class:`TableGrid`, every object's mask and rectangle (objects outside
            the graph included), kept for plotting.
    """

    target: int
    nodes: dict[int, DeclutterNode]
    edges: list[DeclutterEdge]
    params: dict
    grid: TableGrid
    masks: dict[int, np.ndarray]
    rects: dict[int, MinAreaRect]

    @classmethod
    def build(
        cls,
        clouds: Mapping[int, Any],
        target: int,
        *,
        grasp_quality: QualitySource = None,
        mu_o: float = MU_O,
        mu_d: float = MU_D,
        mu_q: float = MU_Q,
        cell: float = CELL,
        place_position: Any = None,
        push_distance: float = PUSH_DISTANCE,
        fingertip: tuple[float, float] = FINGERTIP,
        max_opening: float = MAX_OPENING,
        n_push_samples: int = 32,
    ) -> DeclutterGraph:
        """Build the declutter graph: eq. 5.1 edges, eq. 5.2 actions, breadth-first from ``target``.

        Args:
            clouds: object id -> world points of that object (>= 3 points, metres, z-up, table top
                z = 0). A cloud longer than :data:`~vtlearn.runtime.obb.MAX_OBJECT_EXTENT_M` (2 m) is
                refused: in practice it is in millimetres.
            target: id of the target object O_T, the root.
            grasp_quality: None for :func:`grasp_quality`; or a mapping id -> q with an entry for every
                object that joins the graph but the target; or a callable ``(object_id, points (N, 3)) -> q``.
                The grasp pose comes from the object's rectangle either way.
            mu_o: overlap threshold of eq. 5.1 (IoU, thesis 0.05).
            mu_d: proximity threshold of eq. 5.1, metres (0.03 m; the thesis's 0.5 was in image space).
            mu_q: grasp-quality threshold of eq. 5.2 (thesis 0.1).
            cell: mask grid cell, metres; also the floor of ``d`` in ``1 / d``.
            place_position: ``(3,)`` world point where grasped objects are put; None: 0.15 m beyond the
                largest x of the scene, at the scene's mean y, on the table (z = 0).
            push_distance: length of a straight push, metres.
            fingertip: fingertip footprint (width, depth), metres.
            max_opening: the gripper's largest opening, metres.
            n_push_samples: contour samples tried as push points.

        Shapes:
            clouds ``{id: (N_k, 3)}``; place_position ``(3,)``.
        """
        pts = _check_clouds(clouds)
        if isinstance(target, bool) or not isinstance(target, (int, np.integer)) or int(target) not in pts:
            raise ValueError(f"target: {target!r} is not an object id of clouds ({sorted(pts)})")
        target = int(target)
        mu_o = as_real(mu_o, "mu_o", low=0.0, high=1.0, open_high=True)
        mu_d = as_real(mu_d, "mu_d", low=0.0, open_low=True)
        mu_q = as_real(mu_q, "mu_q")
        cell = as_real(cell, "cell", low=0.0, open_low=True)
        push_distance = as_real(push_distance, "push_distance", low=0.0, open_low=True)
        fingertip = _fingertip(fingertip)
        max_opening = as_real(max_opening, "max_opening", low=0.0, open_low=True)
        n_push_samples = as_int(n_push_samples, "n_push_samples", minimum=4)
        if (
            grasp_quality is not None
            and not isinstance(grasp_quality, Mapping)
            and not callable(grasp_quality)
        ):
            raise ValueError(
                "grasp_quality: need None, a mapping id -> q or a callable, "
                f"got {type(grasp_quality).__name__}"
            )
        all_xy = np.concatenate([p[:, :2] for p in pts.values()])
        if place_position is None:
            place = np.array([all_xy[:, 0].max() + 0.15, all_xy[:, 1].mean(), 0.0])
        else:
            place = _vec(place_position, "place_position", 3)

        grid, masks = occupancy_masks(pts, cell=cell, margin=max(fingertip) + cell)
        ids = sorted(pts)
        xy = {k: pts[k][:, :2] for k in ids}
        rects = {k: min_area_rect(xy[k]) for k in ids}
        trees = {k: cKDTree(xy[k]) for k in ids}
        weight: dict[tuple[int, int], tuple[float, str | None, float, float]] = {}
        for a_i, a in enumerate(ids):
            for b in ids[a_i + 1 :]:
                iou = rect_iou(rects[a], rects[b])
                d = _proximity(masks[a], masks[b], trees[a], xy[b])
                w, kind = edge_weight(iou, d, mu_o=mu_o, mu_d=mu_d, d_floor=cell)
                weight[a, b] = weight[b, a] = (w, kind, iou, d)

        # breadth-first, level by level: each object joins under its heaviest edge to the previous level
        depth, parent = {target: 0}, {target: None}
        frontier = [target]
        while frontier:
            found: dict[int, tuple[float, int]] = {}
            for u in frontier:
                for v in ids:
                    if v in depth or weight[u, v][0] <= 0:
                        continue
                    if v not in found or weight[u, v][0] > found[v][0]:
                        found[v] = (weight[u, v][0], u)
            for v, (_, u) in found.items():
                depth[v], parent[v] = depth[u] + 1, u
            frontier = sorted(found)

        occupancy = np.zeros(grid.shape, np.int32)
        for m in masks.values():
            occupancy += m
        heights = {k: max(float(pts[k][:, 2].max()), 0.0) for k in ids}
        nodes, edges = {}, []
        for v in sorted(depth, key=lambda k: (depth[k], k)):
            q = None
            if v != target:
                others = (occupancy - masks[v]) > 0
                q = _quality(grasp_quality, v, pts[v], rects[v], grid, others, max_opening, fingertip)
            nodes[v] = DeclutterNode(v, parent[v], depth[v], rects[v], heights[v], q)
            if v == target:
                continue
            u = parent[v]
            w, kind, iou, d = weight[u, v]
            z = heights[v] / 2
            if action_kind(q, mu_q) == "grasp":
                r = rects[v]
                alpha = _wrap_half_turn(r.angle + math.pi / 2)
                action = GraspAction(v, np.array([*r.center, z]), alpha, place.copy(), q, r.size[1])
            else:
                around = [k for k in ids if k != v and weight[v, k][0] > 0]
                d_push = push_direction(
                    rects[v].center,
                    np.array([rects[k].center for k in around]).reshape(-1, 2),
                    away_from=rects[target].center,
                )
                p, box, overlap = _push_point(
                    xy[v], rects[v].center, d_push, grid, others, fingertip, int(n_push_samples)
                )
                action = PushAction(
                    v, np.array([*p, z]), d_push, push_distance, np.array([*box, z]), overlap, q
                )
            edges.append(DeclutterEdge(u, v, w, kind, iou, d, action))
        params = {
            "mu_o": mu_o,
            "mu_d": mu_d,
            "mu_q": mu_q,
            "cell": cell,
            "place_position": place.tolist(),
            "push_distance": push_distance,
            "fingertip": list(fingertip),
            "max_opening": max_opening,
            "n_push_samples": int(n_push_samples),
        }
        return cls(target, nodes, edges, params, grid, masks, rects)

    # ------------------------------------------------------------------ traversal
    def children(self, v: int) -> list[DeclutterEdge]:
        """Edges out of ``v``, heaviest first (ties by child id)."""
        if v not in self.nodes:
            raise ValueError(f"v: {v!r} is not a node of the graph ({sorted(self.nodes)})")
        return sorted((e for e in self.edges if e.parent == v), key=lambda e: (-e.weight, e.child))

    def next_edge(self) -> DeclutterEdge | None:
        """The edge into the leaf reached by depth-first descent from the root along the heaviest children."""
        edge, v = None, self.target
        while kids := self.children(v):
            edge = kids[0]
            v = edge.child
        return edge

    def next_action(self) -> DeclutterAction | None:
        """The action that singulates the next object, or None when decluttering is complete."""
        edge = self.next_edge()
        return None if edge is None else edge.action

    @property
    def is_done(self) -> bool:
        """True when the root has no children: nothing clutters the target."""
        return not any(e.parent == self.target for e in self.edges)

    def to_dict(self) -> dict:
        """A JSON-serialisable description: nodes, edges, the next action and the parameters."""
        nxt = self.next_action()
        return {
            "target": self.target,
            "nodes": [n.to_dict() for n in self.nodes.values()],
            "edges": [e.to_dict() for e in self.edges],
            "outside_graph": sorted(k for k in self.rects if k not in self.nodes),
            "is_done": self.is_done,
            "next_action": None if nxt is None else nxt.to_dict(),
            "params": dict(self.params),
        }

    # ------------------------------------------------------------------ figures
    def _colours(self) -> dict[int, tuple]:
        import matplotlib

        cmap = matplotlib.colormaps["tab10"]
        return {
            k: cmap(i % 10) if k in self.nodes else (0.6, 0.6, 0.6, 1.0) for i, k in enumerate(self.rects)
        }

    def plot(self, ax=None, *, edge_labels: bool = True):
        """Top-down scene: footprints coloured by id (grey: outside the graph), their rectangles, the graph's
        edges as arrows (labelled with weight and action when ``edge_labels``) and the next action: the push
        arrow from the fingertip footprint, or the two fingertips of the grasp and the place position.
        Returns ``ax``."""
        from matplotlib.patches import FancyArrowPatch, Polygon

        ax = ax if ax is not None else _new_axes()
        colour = self._colours()
        image = np.ones((*self.grid.shape[::-1], 4))
        for k, rgba in colour.items():
            m = self.masks[k].T
            image[m] = 0.5 * np.array(rgba) + 0.5 * image[m]
        ax.imshow(image, origin="lower", extent=self.grid.extent, interpolation="nearest")
        for k, r in self.rects.items():
            root = k == self.target
            ax.add_patch(
                Polygon(
                    r.corners,
                    closed=True,
                    fill=False,
                    lw=2.5 if root else 1.0,
                    ls="-" if root else "--",
                    ec=colour[k],
                )
            )
            label = f"{k}\ntarget" if root else (str(k) if k in self.nodes else f"{k}\n(free)")
            ax.text(*r.center, label, ha="center", va="center", fontsize=8, weight="bold", color="0.1")
        nxt = self.next_edge()
        path = set(self._path_to(nxt.child)) if nxt is not None else set()
        for e in self.edges:
            a, b = self.rects[e.parent].center, self.rects[e.child].center
            hot = e.child in path
            ax.add_patch(
                FancyArrowPatch(
                    a,
                    b,
                    arrowstyle="-|>",
                    mutation_scale=12,
                    shrinkA=6,
                    shrinkB=6,
                    lw=2.0 if hot else 1.0,
                    color="navy" if hot else "0.2",
                )
            )
            if edge_labels:
                ax.text(
                    *(0.35 * a + 0.65 * b),
                    _edge_label(e),
                    fontsize=6.5,
                    ha="center",
                    va="center",
                    bbox={"boxstyle": "round,pad=0.15", "fc": "white", "ec": "0.7", "alpha": 0.8},
                )
        action = None if nxt is None else nxt.action
        fw, fd = self.params["fingertip"]
        x0, x1, y0, y1 = self.grid.extent
        if isinstance(action, PushAction):
            d = action.d_push[:2]
            ax.add_patch(
                Polygon(
                    _box_corners(action.fingertip[:2], d, fw, fd),
                    closed=True,
                    fc="crimson",
                    ec="darkred",
                    alpha=0.7,
                )
            )
            ax.add_patch(
                FancyArrowPatch(
                    action.p_push[:2],
                    action.p_end[:2],
                    arrowstyle="-|>",
                    mutation_scale=18,
                    lw=2.5,
                    color="crimson",
                )
            )
            x0, x1 = min(x0, action.p_end[0]), max(x1, action.p_end[0])
            y0, y1 = min(y0, action.p_end[1]), max(y1, action.p_end[1])
        elif isinstance(action, GraspAction):
            v = np.array([math.cos(action.alpha_grasp), math.sin(action.alpha_grasp)])
            for s in (-1.0, 1.0):
                c = action.p_grasp[:2] + s * (action.width / 2 + fd / 2) * v
                ax.add_patch(
                    Polygon(
                        _box_corners(c, v, fw, fd), closed=True, fc="seagreen", ec="darkgreen", alpha=0.75
                    )
                )
            ax.plot(*action.p_grasp[:2], "x", color="darkgreen", ms=9, mew=2.5)
            ax.plot(*action.p_place[:2], "*", color="seagreen", ms=15, mec="darkgreen")
            ax.annotate(
                "place",
                action.p_place[:2],
                xytext=(6, 6),
                textcoords="offset points",
                fontsize=8,
                color="darkgreen",
            )
            ax.add_patch(
                FancyArrowPatch(
                    action.p_grasp[:2],
                    action.p_place[:2],
                    arrowstyle="->",
                    mutation_scale=12,
                    ls=":",
                    lw=1.2,
                    color="seagreen",
                    shrinkB=8,
                )
            )
            pad = 3 * self.grid.cell
            x0, x1 = min(x0, action.p_place[0] - pad), max(x1, action.p_place[0] + pad)
            y0, y1 = min(y0, action.p_place[1] - pad), max(y1, action.p_place[1] + pad)
        ax.set_xlim(x0, x1)
        ax.set_ylim(y0, y1)
        ax.set_aspect("equal")
        ax.set_xlabel("x (m)")
        ax.set_ylabel("y (m)")
        if action is None:
            ax.set_title(f"target {self.target}: decluttering complete")
        else:
            ax.set_title(f"target {self.target}: next {action.kind} object {action.object_id}")
        return ax

    def plot_tree(self, ax=None):
        """The graph as a tree: root on top, children left to right heaviest first, edges labelled with the
        eq. 5.1 weight and the eq. 5.2 action, the depth-first path to the next object in red.

        Returns ``ax``.
        """
        from matplotlib.patches import FancyArrowPatch

        ax = ax if ax is not None else _new_axes()
        colour = self._colours()
        pos: dict[int, tuple[float, float]] = {}
        leaves = [0]

        def place(v: int) -> float:  # tidy layout: leaves in depth-first order, parents over their children
            kids = [e.child for e in self.children(v)]
            x = float(np.mean([place(c) for c in kids])) if kids else float(leaves[0])
            leaves[0] += not kids
            pos[v] = (x, -float(self.nodes[v].depth))
            return x

        place(self.target)
        nxt = self.next_edge()
        path = set(self._path_to(nxt.child)) if nxt is not None else set()
        for e in self.edges:
            hot = e.child in path
            ax.add_patch(
                FancyArrowPatch(
                    pos[e.parent],
                    pos[e.child],
                    arrowstyle="-|>",
                    mutation_scale=14,
                    shrinkA=13,
                    shrinkB=13,
                    lw=2.2 if hot else 1.1,
                    color="crimson" if hot else "0.3",
                )
            )
            mid = np.mean([pos[e.parent], pos[e.child]], axis=0)
            ax.text(
                *mid,
                _edge_label(e),
                fontsize=7,
                ha="center",
                va="center",
                color="crimson" if hot else "0.1",
                bbox={"boxstyle": "round,pad=0.2", "fc": "white", "ec": "0.8"},
            )
        for v, (x, y) in pos.items():
            root = v == self.target
            ax.scatter(
                [x],
                [y],
                s=520,
                color=colour[v],
                edgecolors="black",
                linewidths=2.0 if root else 0.8,
                marker="s" if root else "o",
                zorder=3,
            )
            ax.text(x, y, str(v), ha="center", va="center", fontsize=9, weight="bold", zorder=4)
        free = sorted(k for k in self.rects if k not in self.nodes)
        note = f"not in graph: {', '.join(map(str, free))}" if free else "every object is in the graph"
        ax.text(0.02, 0.02, note, transform=ax.transAxes, fontsize=8, color="0.4")
        xs = [p[0] for p in pos.values()]
        ys = [p[1] for p in pos.values()]
        ax.set_xlim(min(xs) - 0.8, max(xs) + 0.8)
        ax.set_ylim(min(ys) - 0.6, 0.6)
        ax.set_axis_off()
        p = self.params
        ax.set_title(f"declutter graph (mu_o {p['mu_o']:g}, mu_d {p['mu_d']:g} m, mu_q {p['mu_q']:g})")
        return ax

    def _path_to(self, v: int) -> list[int]:
        out = []
        while v is not None and v != self.target:
            out.append(v)
            v = self.nodes[v].parent
        return out

    def figure(self, path):
        """Save the scene (:meth:`plot`) beside the tree (:meth:`plot_tree`) as ``path``; returns the path."""
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt

        from vtlearn.bench_utils import save_figure

        fig, (ax_scene, ax_tree) = plt.subplots(1, 2, figsize=(12, 5.5), width_ratios=(1.2, 1))
        self.plot(ax_scene, edge_labels=False)
        self.plot_tree(ax_tree)
        fig.tight_layout()
        return save_figure(fig, path)


def _new_axes():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt.subplots(figsize=(6.5, 6))[1]


def _edge_label(e: DeclutterEdge) -> str:
    w = f"IoU {e.weight:.2f}" if e.kind == "overlap" else f"1/d {e.weight:.0f} /m"
    return f"{w}\n{e.action.kind} (q {e.action.quality:.2f})"


def _box_corners(center: np.ndarray, along: np.ndarray, width: float, depth: float) -> np.ndarray:
    across = np.array([-along[1], along[0]])
    signs = np.array([[-1, -1], [1, -1], [1, 1], [-1, 1]], dtype=float)
    return center + signs[:, :1] * depth / 2 * along + signs[:, 1:] * width / 2 * across


def _quality(source: QualitySource, k: int, pts, rect, grid, others, max_opening, fingertip) -> float:
    if source is None:
        return _grasp_quality(rect, grid, others, max_opening, fingertip)
    if isinstance(source, Mapping):
        if k not in source:
            raise ValueError(
                f"grasp_quality: no quality for object {k}; give one for every non-target object"
            )
        q = source[k]
    else:
        q = source(k, pts)
    return as_real(q, f"grasp_quality[{k}]")


# --------------------------------------------------------------------------------- segmented clouds
def segmented_cloud(camera, frame, rng: np.random.Generator | None = None) -> tuple[np.ndarray, np.ndarray]:
    """World points of every valid pixel of a simulated RGB-D frame and the body id that rendered it.

    Composes :meth:`vtlearn.sim_data.camera.RGBDCamera.point_cloud` (which back-projects the valid pixels
    in row-major order) with the frame's segmentation at the same pixels.

    Shapes:
        frame: an ``RGBDFrame`` (depth ``(H, W)``, seg ``(H, W)``) -> points ``(N, 3)``, seg_ids ``(N,)`` int.
    """
    for attr in ("depth", "seg", "K", "T_world_camera"):
        if not hasattr(frame, attr):
            raise ValueError(f"frame: need an RGBDFrame with .{attr}, got {type(frame).__name__}")
    if not hasattr(camera, "point_cloud"):
        raise ValueError(f"camera: need an RGBDCamera, got {type(camera).__name__}")
    valid = np.asarray(frame.depth) > 0
    return camera.point_cloud(frame, rng=rng), np.asarray(frame.seg)[valid].astype(np.int64)


def instance_clouds_from_rgbd(
    points_world: Any, seg_ids: Any, exclude: Sequence[int] = (), min_points: int = 20
) -> dict[int, np.ndarray]:
    """Split an instance-segmented cloud into one cloud per object.

    Points with a negative id (background) or an id in ``exclude`` (the table, the robot) are dropped, and
    so are objects with fewer than ``min_points`` points (slivers at the image border, noise).

    Args:
        points_world: world points.
        seg_ids: the instance id of each point (e.g. the pybullet body id, see :func:`segmented_cloud`).
        exclude: ids that are not objects.
        min_points: smallest cloud kept, >= 3.

    Shapes:
        points_world ``(N, 3)``, seg_ids ``(N,)`` -> ``{id: (M_id, 3)}``.
    """
    pts = as_points(points_world, "points_world", min_points=0)
    ids = np.asarray(seg_ids)
    if ids.shape != (len(pts),):
        raise ValueError(f"seg_ids: need shape ({len(pts)},) to match points_world, got {ids.shape}")
    if ids.size and not np.issubdtype(ids.dtype, np.integer):
        raise ValueError(f"seg_ids: need integer ids, got dtype {ids.dtype}")
    min_points = as_int(min_points, "min_points", minimum=3)
    try:
        drop = np.asarray(list(exclude), dtype=np.int64)
    except (TypeError, ValueError):
        raise ValueError(f"exclude: need a sequence of integer ids, got {exclude!r}") from None
    keep = (ids >= 0) & ~np.isin(ids, drop)
    out = {}
    for k in np.unique(ids[keep]):
        sel = pts[ids == k]
        if len(sel) >= min_points:
            out[int(k)] = sel
    return out
