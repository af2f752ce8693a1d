"""Candidate-action samplers for next-best-touch, pinch and next-best-view (thesis 5.2.3, eq. 5.3-5.5;
7.2.4; 8.2.3).

- Next-best-touch (5.2.3, 7.2.4): positions are sampled uniformly on each face of the object's oriented
  bounding box except the bottom face it rests on; the touch direction is the inward face normal, and
  the pad starts ``standoff`` metres outside the face.
- Pinch (8.2.3): the gripper comes straight down from a start point ``approach_height`` above the box
  and closes antipodally at a sampled height; the action is the grip pose.
- Next-best-view (5.2.3): camera positions on a hemisphere around the object centroid, sampled with
  Marsaglia's (1972) method, and oriented so that the optical axis passes through the centroid. The
  orientation follows eq. 5.3-5.5: ``h = (p_view - o) / |p_view - o|`` (5.3),
  ``theta = acos(h . Z)``, ``e = (h x Z) / |h x Z|`` (5.4), and ``R_v`` the Rodrigues matrix of
  ``(e, theta)`` (5.5). ``R_v`` rotates ``h`` onto the world ``Z``; the camera rotation
  ``R_world_camera = R_v^T diag(1, -1, -1)`` therefore puts the optical (+z) axis along ``-h``, towards
  the centroid (the thesis leaves that last step implicit).
- Kinematic feasibility: every sampler takes ``feasible``, a callable from ``(N, 4, 4)`` sensor poses
  ``T_world_sensor`` to an ``(N,)`` bool mask; the robot runtime plugs in its IK check there.
  Infeasible candidates are discarded and the sampler draws again, up to ``max_rounds`` times.

Frames: ``T_world_box`` maps box-frame points into the world; the box frame has its origin at the box
centre and z up, so its bottom face is ``z = -extent_z / 2``. Sensor frames are those of
:mod:`vtlearn.active.sensors`. Units are metres.

Shapes:
    ActionSet.T_world_sensor: ``(N, 4, 4)``; ActionSet.start: ``(N, 3)`` where the motion starts;
    ActionSet.face: ``(N,)`` int (touch: 0..4 for +x, -x, +y, -y, +z; -1 otherwise).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from vtlearn.validation import as_int, as_pair, as_points, as_real, as_transform, as_vector

__all__ = [
    "ActionSet",
    "OrientedBox",
    "ReachFeasibility",
    "marsaglia_sphere",
    "sample_pinch_actions",
    "sample_touch_actions",
    "sample_view_actions",
    "view_rotation",
]

Feasibility = Callable[[np.ndarray], np.ndarray]

# Box faces used for touching: outward normal in the box frame and two in-face axes. The bottom face
# (-z) is excluded because the object rests on it.
FACE_NAMES = ("+x", "-x", "+y", "-y", "+z")
_FACE_NORMALS = np.array([[1, 0, 0], [-1, 0, 0], [0, 1, 0], [0, -1, 0], [0, 0, 1]], dtype=float)
_FACE_U = np.array([[0, 1, 0], [0, 1, 0], [1, 0, 0], [1, 0, 0], [1, 0, 0]], dtype=float)
_FACE_V = np.array([[0, 0, 1], [0, 0, 1], [0, 0, 1], [0, 0, 1], [0, 1, 0]], dtype=float)


@dataclass
class OrientedBox:
    """An object's oriented bounding box: ``T_world_box`` (centre, z up) and full ``extents`` (3,)."""

    T_world_box: np.ndarray
    extents: np.ndarray

    def __post_init__(self):
        self.T_world_box = as_transform(self.T_world_box, "T_world_box")
        self.extents = np.asarray(self.extents, dtype=np.float64)
        if self.extents.shape != (3,) or not np.isfinite(self.extents).all() or (self.extents <= 0).any():
            raise ValueError(f"extents: expected three positive finite sizes, got {self.extents.tolist()}")

    @classmethod
    def from_aabb(cls, lower, upper) -> OrientedBox:
        """An axis-aligned box ``[lower, upper]`` in the world frame (metres).

        Shapes:
            lower, upper: ``(3,)`` each, ``upper > lower`` on every axis.
        """
        lower = as_vector(lower, "lower", 3, "a finite (3,) corner")
        upper = as_vector(upper, "upper", 3, "a finite (3,) corner")
        if (upper <= lower).any():
            raise ValueError(
                f"upper: must exceed lower on every axis, got {lower.tolist()} and {upper.tolist()}"
            )
        T = np.eye(4)
        T[:3, 3] = (lower + upper) / 2
        return cls(T, upper - lower)

    @classmethod
    def from_points(cls, points, margin: float = 0.0) -> OrientedBox:
        """The world-axis-aligned box around ``points``, grown by ``margin`` (metres, >= 0) on every side.

        Shapes:
            points: ``(N, 3)``, N >= 2.
        """
        pts = as_points(points, "points", min_points=2)
        margin = as_real(margin, "margin", low=0.0, unit="m")
        if margin == 0.0 and (pts.max(axis=0) == pts.min(axis=0)).all():
            raise ValueError(f"points: all {len(pts)} points coincide, so they bound no box; "
                             "pass points that span the object or a margin > 0")
        lower, upper = pts.min(axis=0) - margin, pts.max(axis=0) + margin
        return cls.from_aabb(lower, np.maximum(upper, lower + 1e-6))

    @property
    def center(self) -> np.ndarray:
        return self.T_world_box[:3, 3].copy()

    def corners(self) -> np.ndarray:
        """``(8, 3)`` world-frame corners."""
        signs = np.array(np.meshgrid([-1, 1], [-1, 1], [-1, 1], indexing="ij")).reshape(3, -1).T
        local = signs * self.extents / 2
        return local @ self.T_world_box[:3, :3].T + self.T_world_box[:3, 3]


@dataclass
class ActionSet:
    """Candidate actions of one kind (``"touch"``, ``"pinch"`` or ``"view"``)."""

    kind: str
    T_world_sensor: np.ndarray
    start: np.ndarray
    face: np.ndarray

    def __len__(self) -> int:
        return self.T_world_sensor.shape[0]

    def subset(self, idx) -> ActionSet:
        idx = np.asarray(idx)
        return ActionSet(self.kind, self.T_world_sensor[idx], self.start[idx], self.face[idx])


class ReachFeasibility:
    """A simple stand-in feasibility hook: the sensor origin lies within ``[min_reach, max_reach]`` of a
    robot base at ``base`` (world frame). The robot runtime replaces it with an IK query."""

    def __init__(self, base, max_reach: float, min_reach: float = 0.0):
        self.base = np.asarray(base, dtype=np.float64)
        if self.base.shape != (3,) or not np.isfinite(self.base).all():
            raise ValueError(f"base: expected a finite (3,) position, got {self.base.tolist()}")
        min_reach = as_real(min_reach, "min_reach", low=0.0, unit="m")
        if max_reach != np.inf:  # inf: no outer limit
            max_reach = as_real(max_reach, "max_reach", unit="m")
        if not min_reach < max_reach:
            raise ValueError(f"max_reach: need 0 <= min_reach < max_reach, got {min_reach}, {max_reach}")
        self.max_reach, self.min_reach = max_reach, min_reach

    def __call__(self, T_world_sensor: np.ndarray) -> np.ndarray:
        dist = np.linalg.norm(T_world_sensor[:, :3, 3] - self.base, axis=1)
        return (dist >= self.min_reach) & (dist <= self.max_reach)


def _frames_from_z(z: np.ndarray, x_hint: np.ndarray) -> np.ndarray:
    """``(N, 3, 3)`` rotations whose z column is ``z`` and x column is ``x_hint`` made orthogonal to it."""
    z = z / np.linalg.norm(z, axis=1, keepdims=True)
    x = x_hint - (x_hint * z).sum(axis=1, keepdims=True) * z
    x = x / np.linalg.norm(x, axis=1, keepdims=True)
    y = np.cross(z, x)
    return np.stack([x, y, z], axis=2)


def _check_box(box) -> OrientedBox:
    if not isinstance(box, OrientedBox):
        raise ValueError(f"box: expected an OrientedBox (e.g. OrientedBox.from_points(mesh.vertices)), "
                         f"got {type(box).__name__}")
    return box


def _check_count(n, name="n"):
    if not isinstance(n, (int, np.integer)) or n < 1:
        raise ValueError(f"{name}: need a positive integer count, got {n!r}")
    return int(n)


def _sample_feasible(
    draw: Callable[[int], ActionSet], n: int, feasible: Feasibility | None, max_rounds: int
) -> ActionSet:
    max_rounds = as_int(max_rounds, "max_rounds")
    if feasible is None:
        return draw(n)
    kept: list[ActionSet] = []
    have = 0
    for _ in range(max_rounds):
        cand = draw(max(n - have, 1) * 2)
        mask = np.asarray(feasible(cand.T_world_sensor), dtype=bool)
        if mask.shape != (len(cand),):
            raise ValueError(f"feasible: must return a ({len(cand)},) bool mask, got shape {mask.shape}")
        kept.append(cand.subset(np.nonzero(mask)[0]))
        have += int(mask.sum())
        if have >= n:
            break
    out = ActionSet(
        kept[0].kind,
        np.concatenate([k.T_world_sensor for k in kept])[:n],
        np.concatenate([k.start for k in kept])[:n],
        np.concatenate([k.face for k in kept])[:n],
    )
    return out


def sample_touch_actions(
    box: OrientedBox,
    n: int,
    *,
    standoff: float = 0.02,
    area_weighted: bool = True,
    seed: int | np.random.Generator | None = None,
    feasible: Feasibility | None = None,
    max_rounds: int = 10,
) -> ActionSet:
    """Next-best-touch candidates on the box faces except the bottom (thesis 5.2.3, 7.2.4).

    Each candidate is a pad pose ``T_world_pad`` whose pressing axis (+z) is the inward face normal and
    whose origin lies ``standoff`` metres outside a uniformly sampled face point. Faces are chosen with
    probability proportional to their area (``area_weighted``) or uniformly.

    Returns:
        ActionSet of kind ``"touch"`` with ``face`` in 0..4 (see ``FACE_NAMES``); may hold fewer than
        ``n`` actions if ``feasible`` rejects too many.

    Shapes:
        -> ``T_world_sensor`` ``(n, 4, 4)`` pad poses ``T_world_pad``, ``start`` ``(n, 3)``,
        ``face`` ``(n,)``.
    """
    box = _check_box(box)
    n = _check_count(n)
    standoff = as_real(standoff, "standoff", low=0.0, unit="m")
    rng = np.random.default_rng(seed)
    half = box.extents / 2
    area = np.array(
        [box.extents[1] * box.extents[2]] * 2
        + [box.extents[0] * box.extents[2]] * 2
        + [box.extents[0] * box.extents[1]]
    )
    prob = area / area.sum() if area_weighted else np.full(5, 0.2)
    R_wb, t_wb = box.T_world_box[:3, :3], box.T_world_box[:3, 3]

    def draw(m: int) -> ActionSet:
        face = rng.choice(5, size=m, p=prob)
        normal, u, v = _FACE_NORMALS[face], _FACE_U[face], _FACE_V[face]
        su = rng.uniform(-1, 1, (m, 1))
        sv = rng.uniform(-1, 1, (m, 1))
        point_b = normal * half + su * u * half + sv * v * half  # on the face, box frame
        origin_b = point_b + standoff * normal
        R_b_pad = _frames_from_z(-normal, u)
        T = np.tile(np.eye(4), (m, 1, 1))
        T[:, :3, :3] = R_wb @ R_b_pad
        T[:, :3, 3] = origin_b @ R_wb.T + t_wb
        return ActionSet("touch", T, T[:, :3, 3].copy(), face.astype(np.int64))

    return _sample_feasible(draw, n, feasible, max_rounds)


def sample_pinch_actions(
    box: OrientedBox,
    n: int,
    *,
    approach_height: float = 0.1,
    height_range: tuple[float, float] = (0.2, 0.9),
    seed: int | np.random.Generator | None = None,
    feasible: Feasibility | None = None,
    max_rounds: int = 10,
) -> ActionSet:
    """Pinch candidates from above (thesis 8.2.3).

    The grip centre is sampled uniformly over the box footprint, at a height that is a uniform fraction
    in ``height_range`` of the box height, with a uniform yaw of the closing axis in [0, pi). The grip
    frame's approach axis (+z) points straight down. ``start`` is the point ``approach_height`` metres
    above the box top from which the gripper descends.

    Shapes:
        -> ``T_world_sensor`` ``(n, 4, 4)`` grip poses ``T_world_grip``, ``start`` ``(n, 3)``, ``face``
        ``(n,)`` all -1.
    """
    box = _check_box(box)
    n = _check_count(n)
    lo_f, hi_f = as_pair(height_range, "height_range")
    if not 0.0 <= lo_f <= hi_f <= 1.0:
        raise ValueError(f"height_range: need 0 <= low <= high <= 1, got {height_range}")
    approach_height = as_real(approach_height, "approach_height", low=0.0, unit="m")
    rng = np.random.default_rng(seed)
    half = box.extents / 2
    R_wb, t_wb = box.T_world_box[:3, :3], box.T_world_box[:3, 3]

    def draw(m: int) -> ActionSet:
        xy = rng.uniform(-1, 1, (m, 2)) * half[:2]
        z = -half[2] + rng.uniform(lo_f, hi_f, m) * box.extents[2]
        yaw = rng.uniform(0, np.pi, m)
        closing = np.stack([np.cos(yaw), np.sin(yaw), np.zeros(m)], axis=1)
        R_b_grip = _frames_from_z(np.tile([0.0, 0.0, -1.0], (m, 1)), closing)
        centre_b = np.concatenate([xy, z[:, None]], axis=1)
        start_b = np.concatenate([xy, np.full((m, 1), half[2] + approach_height)], axis=1)
        T = np.tile(np.eye(4), (m, 1, 1))
        T[:, :3, :3] = R_wb @ R_b_grip
        T[:, :3, 3] = centre_b @ R_wb.T + t_wb
        return ActionSet("pinch", T, start_b @ R_wb.T + t_wb, np.full(m, -1, dtype=np.int64))

    return _sample_feasible(draw, n, feasible, max_rounds)


def marsaglia_sphere(n: int, rng: np.random.Generator | int | None = None) -> np.ndarray:
    """``(n, 3)`` points uniform on the unit sphere by Marsaglia (1972): draw ``(x1, x2)`` uniform in the
    unit disc, then ``(2 x1 sqrt(1 - s), 2 x2 sqrt(1 - s), 1 - 2 s)`` with ``s = x1^2 + x2^2``.

    Args:
        n: number of points, an integer ``>= 1``.
        rng: a ``numpy.random.Generator``, a seed or None.

    Shapes:
        -> ``(n, 3)`` unit vectors.
    """
    n = as_int(n, "n")
    rng = np.random.default_rng(rng)
    out = np.empty((0, 2))
    while out.shape[0] < n:
        x = rng.uniform(-1, 1, (2 * (n - out.shape[0]) + 8, 2))
        out = np.concatenate([out, x[(x**2).sum(axis=1) < 1]])
    x1, x2 = out[:n, 0], out[:n, 1]
    s = x1**2 + x2**2
    root = np.sqrt(1 - s)
    return np.stack([2 * x1 * root, 2 * x2 * root, 1 - 2 * s], axis=1)


def _rodrigues(axis: np.ndarray, theta: np.ndarray) -> np.ndarray:
    """Eq. 5.5: ``(N, 3, 3)`` rotation by ``theta`` about unit ``axis``."""
    ex, ey, ez = axis[:, 0], axis[:, 1], axis[:, 2]
    c, s = np.cos(theta), np.sin(theta)
    C = 1 - c
    return np.stack(
        [
            np.stack([c + ex**2 * C, ex * ey * C - ez * s, ey * s + ex * ez * C], axis=-1),
            np.stack([ez * s + ex * ey * C, c + ey**2 * C, -ex * s + ey * ez * C], axis=-1),
            np.stack([-ey * s + ex * ez * C, ex * s + ey * ez * C, c + ez**2 * C], axis=-1),
        ],
        axis=1,
    )


def view_rotation(p_view, o_centroid) -> np.ndarray:
    """Camera rotations ``R_world_camera`` ``(N, 3, 3)`` looking from ``p_view`` ``(N, 3)`` at ``o_centroid``
    ``(3,)`` by eq. 5.3-5.5 (see the module docstring for the final flip)."""
    p = as_points(p_view, "p_view")
    o = np.asarray(o_centroid, dtype=np.float64).reshape(3)
    diff = p - o
    dist = np.linalg.norm(diff, axis=1)
    if (dist < 1e-12).any():
        raise ValueError("p_view: a viewpoint coincides with the centroid")
    h = diff / dist[:, None]  # eq. 5.3
    Z = np.array([0.0, 0.0, 1.0])
    theta = np.arccos(np.clip(h @ Z, -1.0, 1.0))  # eq. 5.4
    cross = np.cross(h, Z)
    norm = np.linalg.norm(cross, axis=1)
    # h parallel to Z leaves e undefined; any axis perpendicular to Z then works (theta is 0 or pi).
    e = np.where(norm[:, None] > 1e-12, cross / np.maximum(norm, 1e-300)[:, None], [1.0, 0.0, 0.0])
    R_v = _rodrigues(e, theta)  # eq. 5.5, maps h onto Z
    return R_v.transpose(0, 2, 1) @ np.diag([1.0, -1.0, -1.0])


def sample_view_actions(
    o_centroid,
    radius: float,
    n: int,
    *,
    min_elevation_deg: float = 10.0,
    seed: int | np.random.Generator | None = None,
    feasible: Feasibility | None = None,
    max_rounds: int = 10,
) -> ActionSet:
    """Next-best-view candidates on the upper hemisphere of ``radius`` around ``o_centroid`` (thesis 5.2.3).

    Points come from Marsaglia sampling of the sphere folded onto the upper half; those lower than
    ``min_elevation_deg`` above the centroid's horizontal plane are discarded (the table blocks them).
    Returns an ActionSet of kind ``"view"`` whose ``T_world_sensor`` are optical frames
    ``T_world_camera``, oriented by eq. 5.3-5.5.

    Shapes:
        o_centroid: ``(3,)`` -> ``T_world_sensor`` ``(n, 4, 4)``, ``start`` ``(n, 3)`` the viewpoints.
    """
    n = _check_count(n)
    o = as_vector(o_centroid, "o_centroid", 3, "a finite (3,) position")
    radius = as_real(radius, "radius", low=0.0, open_low=True)
    min_elevation_deg = as_real(min_elevation_deg, "min_elevation_deg", low=0.0, high=90.0, open_high=True,
                                unit="deg")
    rng = np.random.default_rng(seed)
    z_min = np.sin(np.radians(min_elevation_deg))

    def draw(m: int) -> ActionSet:
        pts = np.empty((0, 3))
        while pts.shape[0] < m:
            s = marsaglia_sphere(2 * m, rng)
            s[:, 2] = np.abs(s[:, 2])
            pts = np.concatenate([pts, s[s[:, 2] >= z_min]])
        p_view = o + radius * pts[:m]
        T = np.tile(np.eye(4), (m, 1, 1))
        T[:, :3, :3] = view_rotation(p_view, o)
        T[:, :3, 3] = p_view
        return ActionSet("view", T, p_view.copy(), np.full(m, -1, dtype=np.int64))

    return _sample_feasible(draw, n, feasible, max_rounds)
