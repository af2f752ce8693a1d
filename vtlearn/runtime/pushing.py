r"""Goal-driven visuo-tactile pushing (thesis ch.6, 6.2.4, eq. 6.12-6.17).

A free object on the table is pushed to a goal position ``T`` in a discrete loop. Each iteration
re-estimates the object's oriented bounding box (OBB, :mod:`vtlearn.runtime.obb`) from its point
cloud, with geometric centre ``O``; computes the push pose through ``O`` along the OBB's middle
eigenvector ``V_y`` (thesis 6.2.2); measures the bearing ``theta`` between the push line and the goal
(eq. 6.12-6.14); slides the tactile sensor along the pushed face by the output ``c`` of a PID on
``e = theta - theta_d``, ``theta_d = 0`` (eq. 6.15, 6.16); and pushes 3 cm. The loop stops when the
distance to goal ``d`` (eq. 6.17) is below the tolerance. The tactile pad detects the loss of contact
(here pybullet ``getContactPoints`` between pad and object); the next iteration recomputes the pose.

Frames: ``W`` world (z up, table top z = 0), ``S`` tactile sensor (pad) frame with ``z_S`` the push
direction (horizontal), ``x_S = z_S x z_W`` the horizontal tangent of the pushed face pointing to the
right of the push direction, and ``y_S = -z_W``. ``T_W_S`` maps sensor points to the world.

Why eq. 6.16 shifts along ``x_S``: ``x_S`` is the only in-plane pad axis parallel to the table, so a
shift along it slides the pad along the object's perimeter at constant height; ``y_S`` is vertical
and would lift the pad off the face or press it into the table. With ``x_S`` to the right of the
push, a positive ``c`` (goal to the left, ``theta > 0``) moves the contact to the right of ``O``:
the line from the new push point through ``O`` tilts towards the goal, and the off-centre push turns
the object (counter-clockwise) towards it.

Bearing, eq. 6.12-6.14. The thesis uses the slope ``m`` of the line ``l_PO`` (eq. 6.12), the foot
``I`` of the perpendicular from ``T`` on it (eq. 6.13) and ``theta = atan(|TI| / |OI|)`` (eq. 6.14).
Here ``I`` is the vector projection ``I = O + ((T - O) . u) u`` with ``u = (O - P) / |O - P|``, which
is the same point: with ``u ~ (1, m)`` the projection expands to
``I_x = (T_x + m^2 O_x - m (O_y - T_y)) / (1 + m^2)`` and ``I_y = O_y + m (I_x - O_x)``, the solution
of ``y - O_y = m (x - O_x)`` and ``y - T_y = -(x - T_x) / m``, but it needs no slope, so a vertical
line (``P_x = O_x``, ``m = inf``) is no special case. (The printed eq. 6.13 reads ``-m^2 O_x`` and
``I_y = -I_x / m + T_y``; solving the two line equations gives ``+m^2 O_x`` and
``I_y = T_y - (I_x - T_x) / m``, which the projection matches.)

Sign and range of ``theta``. Eq. 6.14 is unsigned and, with ``|OI|``, cannot tell a goal ahead of
``O`` from one behind it. Here ``theta = atan2(|T - I|, s)`` with ``s = (T - O) . u`` the signed
distance from ``O`` to ``I`` along the push direction: it equals eq. 6.14 for goals ahead
(``s >= 0``), and grows to ``pi`` for goals behind ``O``. The signed bearing
``atan2(cross(O - P, T - O), (O - P) . (T - O))`` in ``(-pi, pi]`` has the same magnitude and is
positive when the goal lies to the left (counter-clockwise) of the push direction; the controller
uses it to know which way to slide.

Shapes:
    O, P, T: (2,) xy or (3,) points (only x and y are used); points_world: (N, 3);
    T_W_S: (4, 4); push point: (3,).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pybullet as p

from vtlearn.geometry.sampling import sample_surface
from vtlearn.runtime.obb import MAX_OBJECT_EXTENT_M, OBB, check_object_cloud, oriented_bounding_box
from vtlearn.sim_data.scene import COLLISION_MARGIN, Scene, matrix_to_xyzw
from vtlearn.validation import as_int, as_real, as_transform

__all__ = [
    "bearing_angle",
    "PushPID",
    "shift_sensor",
    "distance_to_goal",
    "push_pose",
    "PushRecord",
    "PushResult",
    "GoalPusher",
]

# Thesis 6.2.4: PID gains found by trial and error, saturation at +-3 cm, 3 cm per push.
KP, KI, KD, C_LIMIT, PUSH_STEP = 0.05, 0.0, 0.03, 0.03, 0.03


def _xy(v, name: str) -> np.ndarray:
    try:
        a = np.asarray(v, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise ValueError(f"{name}: cannot be converted to a float array ({exc})") from None
    if a.shape not in ((2,), (3,)):
        raise ValueError(f"{name}: expected a (2,) or (3,) point, got shape {a.shape}")
    if not np.isfinite(a).all():
        raise ValueError(f"{name}: contains NaN or inf")
    return a[:2]


def _cross2(a: np.ndarray, b: np.ndarray) -> float:
    return float(a[0] * b[1] - a[1] * b[0])


def bearing_angle(O, P, T, signed: bool = False) -> float:
    """Bearing ``theta`` of the goal ``T`` from the push line ``P -> O`` (eq. 6.12-6.14), radians.

    ``I = O + ((T - O) . u) u``, ``u = (O - P) / |O - P|``, is the foot of the perpendicular from ``T``
    on the line (eq. 6.13 without its slope singularity, see the module docstring) and
    ``theta = atan2(|T - I|, (T - O) . u)``: eq. 6.14 for a goal ahead of ``O``, up to ``pi`` behind it.

    Args:
        O: geometric centre of the object's OBB.
        P: push point (the pusher moves from ``P`` through ``O``).
        T: target (goal) position.
        signed: return the signed bearing in ``(-pi, pi]``, positive when ``T`` lies to the left
            (counter-clockwise, seen from above) of the push direction; the sign of
            ``cross(O - P, T - O)``. Otherwise ``theta`` in ``[0, pi]``.

    Shapes:
        O, P, T: (2,) or (3,) each; only x and y are used (the table plane) -> float.

    Raises:
        ValueError: a point of the wrong shape or not finite, or ``P`` on ``O`` (no push line).
    """
    o, pp, t = _xy(O, "O"), _xy(P, "P"), _xy(T, "T")
    u = o - pp
    n = float(np.linalg.norm(u))
    if n < 1e-12:
        raise ValueError("P: coincides with O; the push line P -> O is undefined")
    u /= n
    s = float(np.dot(t - o, u))  # signed distance O -> I along the push direction
    I = o + s * u
    theta = float(np.arctan2(np.linalg.norm(t - I), s))
    if signed and _cross2(u, t - o) < 0:
        theta = -theta
    return theta


class PushPID:
    """Discrete PID of eq. 6.15 on ``e = theta - theta_d`` with the output clipped to ``+-limit``.

    ``c_k = kp e_k + ki sum_j e_j dt_j + kd (e_k - e_{k-1}) / dt_k``; the derivative is 0 on the first
    call after construction or :meth:`reset` (no previous error). Defaults are the thesis's gains
    (0.05, 0.0, 0.03; metres per radian) and saturation (3 cm). In :class:`GoalPusher` one push is one
    time step (``dt = 1``), so the gains act per push.

    Args:
        kp, ki, kd: gains (>= 0).
        limit: saturation of the output ``c`` in metres (> 0).

    Shapes:
        error, dt: floats -> c: float.
    """

    def __init__(self, kp: float = KP, ki: float = KI, kd: float = KD, limit: float = C_LIMIT):
        self.kp, self.ki, self.kd = (as_real(kp, "kp", low=0.0), as_real(ki, "ki", low=0.0),
                                     as_real(kd, "kd", low=0.0))
        self.limit = as_real(limit, "limit", low=0.0, open_low=True, unit="m")
        self.reset()

    def reset(self) -> None:
        """Clear the integral and the previous error."""
        self.integral = 0.0
        self.prev_error: float | None = None

    def __call__(self, error: float, dt: float = 1.0) -> float:
        error = as_real(error, "error")
        dt = as_real(dt, "dt", low=0.0, open_low=True)
        self.integral += error * dt
        deriv = 0.0 if self.prev_error is None else (error - self.prev_error) / dt
        self.prev_error = error
        c = self.kp * error + self.ki * self.integral + self.kd * deriv
        return float(np.clip(c, -self.limit, self.limit))

    def __repr__(self) -> str:
        return f"PushPID(kp={self.kp}, ki={self.ki}, kd={self.kd}, limit={self.limit})"


def shift_sensor(T_W_S, c: float) -> np.ndarray:
    """Eq. 6.16: ``T_W_S' = T_W_S @ T_S_S'`` with ``T_S_S'`` a translation of ``c`` along the sensor x axis.

    ``x_S`` is the pad's horizontal in-plane axis (module docstring), so the shift slides the pad
    along the object's perimeter at constant height and keeps its orientation (push direction).

    Args:
        T_W_S: sensor pose in the world.
        c: shift in metres (the PID output).

    Shapes:
        T_W_S: (4, 4) -> T_W_S': (4, 4).
    """
    T = as_transform(T_W_S, "T_W_S")
    c = as_real(c, "c")
    T_S_Sp = np.eye(4)
    T_S_Sp[0, 3] = c
    return T @ T_S_Sp


def distance_to_goal(O, T) -> float:
    """Eq. 6.17: ``d = sqrt((T_x - O_x)^2 + (T_y - O_y)^2)``, metres.

    Shapes:
        O, T: (2,) or (3,) each; only x and y are used -> float.
    """
    o, t = _xy(O, "O"), _xy(T, "T")
    return float(np.hypot(t[0] - o[0], t[1] - o[1]))


def sensor_frame(point, d) -> np.ndarray:
    """T_W_S at ``point`` (3,) with z_S along the horizontal part of ``d``, x_S = z_S x z_W, y_S = -z_W.

    Shapes:
        point (3,), d (2,) or (3,) (only its horizontal part is used) -> (4, 4)
    """
    point = np.asarray(point, dtype=np.float64)
    d = np.asarray(d, dtype=np.float64)
    if point.shape != (3,) or not np.isfinite(point).all():
        raise ValueError(f"point: need a finite (3,) position, got {point.tolist()}")
    if d.shape not in ((2,), (3,)) or not np.isfinite(d).all() or np.hypot(d[0], d[1]) < 1e-12:
        raise ValueError(f"d: need a finite direction with a horizontal part, got {d.tolist()}")
    d = d / np.hypot(d[0], d[1])
    z = np.array([d[0], d[1], 0.0])
    x = np.cross(z, [0.0, 0.0, 1.0])
    T = np.eye(4)
    T[:3, :3] = np.stack([x, np.cross(z, x), z], axis=1)
    T[:3, 3] = point
    return T


def _face(obb: OBB, target_xy: np.ndarray, face: str) -> tuple[np.ndarray, float, float]:
    """Push direction (2,), half extent along it and half extent across it."""
    o = obb.centre[:2]
    to_goal = target_xy - o
    cands = [(obb.V_y[:2], obb.half_extents[1], obb.half_extents[0])]
    if face == "best":
        cands.append((obb.V_x[:2], obb.half_extents[0], obb.half_extents[1]))
    best = None
    for v, along, across in cands:
        for sgn in (1.0, -1.0):
            score = float(np.dot(sgn * v, to_goal))
            if best is None or score > best[0] + 1e-12:
                best = (score, sgn * v, along, across)
    return best[1] / np.linalg.norm(best[1]), float(best[2]), float(best[3])


def push_pose(
    points_world, target_xy, offset: float = 0.0, face: str = "y", margin: float = 0.015
) -> tuple[np.ndarray, np.ndarray]:
    """Push pose on the object's table-plane OBB (thesis 6.2.2 and 6.2.4).

    The push direction is the middle eigenvector ``V_y`` (sign towards the goal), through the OBB centre
    ``O``; the push point is where that line enters the box, at mid height. ``offset`` then slides the
    sensor along the face by eq. 6.16 (:func:`shift_sensor`), clipped to ``+-(half width - margin)``
    so that a pad of half width ``margin`` stays on the face.

    Args:
        points_world: the object's cloud.
        target_xy: the goal; decides the sign of the push direction.
        offset: shift ``c`` along the sensor x axis (metres).
        face: ``"y"`` pushes along +-V_y as in the thesis; ``"best"`` picks among +-V_x, +-V_y the face
            normal closest to the goal direction (a free object whose V_y is across the goal direction
            would otherwise be turned by ~90 deg before it heads for the goal).
        margin: half width of the pad (metres).

    Shapes:
        points_world: (N, 3); target_xy: (2,) or (3,) -> (T_W_S (4, 4), push point (3,)).
    """
    pts = check_object_cloud(points_world, "points_world")
    t = _xy(target_xy, "target_xy")
    if face not in ("y", "best"):
        raise ValueError(f"face: must be 'y' or 'best', got {face!r}")
    offset = as_real(offset, "offset")
    margin = as_real(margin, "margin", low=0.0)
    obb = oriented_bounding_box(pts, planar=True)
    d, along, across = _face(obb, t, face)
    point = np.append(obb.centre[:2] - along * d, obb.centre[2])
    T_W_S = sensor_frame(point, d)
    room = max(across - margin, 0.0)
    T_W_S = shift_sensor(T_W_S, float(np.clip(offset, -room, room)))
    return T_W_S, T_W_S[:3, 3].copy()


@dataclass
class PushRecord:
    """One iteration of the loop, measured before its push.

    Attributes:
        O: (2,) OBB centre; theta: signed bearing (rad); c: PID output (m, before the face clip);
        d: distance to goal (m); push_point: (3,) pad contact point after the shift;
        direction: (3,) push direction; contact: the pad touched the object;
        contact_lost: contact was made and then lost during the push; pushed: metres pushed in contact.
    """

    O: np.ndarray
    theta: float
    c: float
    d: float
    push_point: np.ndarray
    direction: np.ndarray
    contact: bool
    contact_lost: bool
    pushed: float


@dataclass
class PushResult:
    """The trajectory of a :class:`GoalPusher` run.

    Attributes:
        target: (2,) goal; records: one per push; final_O: (2,) OBB centre at the end;
        final_distance: eq. 6.17 at the end (m); success: ``final_distance < tolerance``.
    """

    target: np.ndarray
    records: list[PushRecord]
    final_O: np.ndarray
    final_distance: float
    success: bool
    tolerance: float
    final_obb: OBB | None = field(default=None, repr=False)

    @property
    def n_pushes(self) -> int:
        return len(self.records)

    @property
    def path(self) -> np.ndarray:
        """(K + 1, 2) OBB centres: before every push, then the final one."""
        return np.stack([r.O for r in self.records] + [self.final_O])

    def figure(self, path: str | Path) -> Path:
        """Top-down plot: centre path, goal with tolerance circle, push points and directions (PNG)."""
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt

        path = Path(path)
        path.parent.mkdir(parents=True, exist_ok=True)
        fig, ax = plt.subplots(figsize=(5, 5))
        c = self.path
        ax.plot(c[:, 0], c[:, 1], "o-", ms=3, color="tab:blue", label="object centre O")
        ax.plot(*self.target, "*", ms=14, color="tab:green", label="goal T")
        ax.add_patch(plt.Circle(self.target, self.tolerance, fill=False, ls="--", color="tab:green"))
        if self.records:
            pp = np.stack([r.push_point[:2] for r in self.records])
            dd = np.stack([r.direction[:2] for r in self.records])
            lost = np.array([r.contact_lost or not r.contact for r in self.records])
            ax.quiver(pp[:, 0], pp[:, 1], dd[:, 0], dd[:, 1], color="tab:red", scale=25, width=0.004)
            ax.plot(pp[:, 0], pp[:, 1], ".", color="tab:red", label="push point, direction")
            if lost.any():
                ax.plot(pp[lost, 0], pp[lost, 1], "x", color="k", label="contact lost")
        if self.final_obb is not None:
            ob = self.final_obb
            corners = np.array([[1, 1], [-1, 1], [-1, -1], [1, -1], [1, 1]], dtype=float)
            xy = ob.centre[:2] + (corners * ob.half_extents[:2]) @ ob.axes[:2, :2].T
            ax.plot(xy[:, 0], xy[:, 1], "-", color="tab:blue", lw=1)
        ax.set_aspect("equal")
        ax.set_xlabel("x (m)")
        ax.set_ylabel("y (m)")
        ax.set_title(f"{self.n_pushes} pushes, d = {100 * self.final_distance:.1f} cm")
        ax.legend(loc="best", fontsize=7)
        fig.tight_layout()
        fig.savefig(path, dpi=110)
        plt.close(fig)
        return path


class GoalPusher:
    """Closed-loop goal-driven pushing of a free object in a pybullet :class:`Scene` (thesis 6.2.4).

    The pusher is a pad-sized box (``pad_size``: width along x_S, height along y_S, thickness along
    z_S) dragged by a fixed constraint in steps of ``speed`` metres per physics step (as the physical
    tactile mode of :mod:`vtlearn.sim_data.tactile` drags its pad). A push approaches from
    ``standoff`` before the face until the pad touches the object, then pushes ``push_step`` further
    (the last push shortened to the remaining distance), and stops early when the contact has been
    lost for ``lost_steps`` consecutive steps. The object pose is re-estimated every iteration from
    ``model_points`` (surface samples in the object frame) moved by the simulated pose, i.e. a
    noiseless, deterministic stand-in for the segmented camera cloud. The pad body is created on the
    first :meth:`run` and stays in the scene, parked at z = 1 m, between pushes and runs.

    Args:
        scene: the scene holding ``body`` (a free object, ``Scene.add_mesh(..., fixed=False)``).
        body: body id of the object.
        model_points: (M, 3) object-frame cloud; by default 2000 area-uniform samples of its mesh.
        pid: the controller (default the thesis's gains).
        tolerance: success when the distance to goal drops below it (m).
        max_pushes: give up after this many pushes.
        face: push-face rule of :func:`push_pose`.

    Shapes:
        target_xy: (2,) or (3,) -> :class:`PushResult`.
    """

    def __init__(
        self,
        scene: Scene,
        body: int,
        model_points=None,
        pid: PushPID | None = None,
        tolerance: float = 0.02,
        max_pushes: int = 30,
        push_step: float = PUSH_STEP,
        face: str = "best",
        pad_size: tuple[float, float, float] = (0.03, 0.03, 0.01),
        speed: float = 5e-4,
        standoff: float = 0.01,
        lost_steps: int = 10,
        settle_steps: int = 60,
        pad_max_force: float = 50.0,
    ):
        if body not in scene.objects:
            raise ValueError(f"body: {body} is not an object of the scene")
        if scene.objects[body].fixed:
            raise ValueError(f"body: {body} is fixed; pushing needs a free object (add_mesh(fixed=False))")
        for name, v in (
            ("tolerance", tolerance),
            ("push_step", push_step),
            ("speed", speed),
            ("standoff", standoff),
            ("pad_max_force", pad_max_force),
        ):
            as_real(v, name, low=0.0, open_low=True)
        as_int(max_pushes, "max_pushes")
        as_int(lost_steps, "lost_steps")
        as_int(settle_steps, "settle_steps", minimum=0)
        pad = np.asarray(pad_size, dtype=np.float64)
        if pad.shape != (3,) or not (np.isfinite(pad).all() and (pad > 0).all()):
            raise ValueError(f"pad_size: need 3 positive sizes (m), got {pad_size}")
        if face not in ("y", "best"):
            raise ValueError(f"face: must be 'y' or 'best', got {face!r}")
        self.scene, self.body = scene, body
        if model_points is None:
            model_points = sample_surface(scene.objects[body].mesh_m, 2000, seed=0)[0]
        self.model_points = check_object_cloud(model_points, "model_points")
        self.pid = pid if pid is not None else PushPID()
        self.tolerance, self.max_pushes, self.push_step = float(tolerance), int(max_pushes), float(push_step)
        self.face, self.pad_half = face, pad / 2
        self.speed, self.standoff, self.lost_steps = float(speed), float(standoff), int(lost_steps)
        self.settle_steps, self.pad_max_force = int(settle_steps), float(pad_max_force)
        self._pad: int | None = None
        self._cid: int | None = None

    # ------------------------------------------------------------------ sensing
    def object_cloud(self) -> np.ndarray:
        """(M, 3) object cloud in the world at the simulated pose."""
        T = self.scene.T_world_object(self.body)
        return self.model_points @ T[:3, :3].T + T[:3, 3]

    def _in_contact(self) -> bool:
        kw = {"physicsClientId": self.scene.client}
        return len(p.getContactPoints(self._pad, self.body, **kw)) > 0

    # ------------------------------------------------------------------ pad
    def _make_pad(self) -> None:
        kw = {"physicsClientId": self.scene.client}
        park = [0.0, 0.0, 1.0]
        col = p.createCollisionShape(p.GEOM_BOX, halfExtents=self.pad_half.tolist(), **kw)
        self._pad = p.createMultiBody(0.1, col, -1, park, **kw)
        p.changeDynamics(self._pad, -1, collisionMargin=COLLISION_MARGIN, **kw)
        self._cid = p.createConstraint(self._pad, -1, -1, -1, p.JOINT_FIXED, [0, 0, 0], [0, 0, 0], park, **kw)
        p.changeConstraint(self._cid, maxForce=self.pad_max_force, **kw)

    def _place_pad(self, centre: np.ndarray, R: np.ndarray, teleport: bool = False) -> None:
        kw = {"physicsClientId": self.scene.client}
        q = matrix_to_xyzw(R)
        if teleport:
            p.resetBasePositionAndOrientation(self._pad, centre.tolist(), q, **kw)
            p.resetBaseVelocity(self._pad, [0, 0, 0], [0, 0, 0], **kw)
        p.changeConstraint(self._cid, centre.tolist(), q, self.pad_max_force, **kw)

    def close(self) -> None:
        """Remove the pad body and its constraint from the scene (a later push makes a new one)."""
        if self._pad is not None:
            kw = {"physicsClientId": self.scene.client}
            p.removeConstraint(self._cid, **kw)
            p.removeBody(self._pad, **kw)
            self._pad = self._cid = None

    def _park(self) -> None:
        self._place_pad(np.array([0.0, 0.0, 1.0]), np.eye(3), teleport=True)

    def push(self, T_W_S: np.ndarray, length: float) -> tuple[bool, bool, float]:
        """One push: approach along z_S until the pad touches ``body``, then push ``length`` metres in
        contact, stopping early when the contact is lost (the tactile monitoring of the thesis, 6.2.4).
        Returns (contact made, contact lost, distance pushed in contact in metres).

        Shapes:
            T_W_S: (4, 4), the pad pose (module docstring: z_S the push direction) at the push point.
        """
        T_W_S = as_transform(T_W_S, "T_W_S")
        length = as_real(length, "length", low=0.0, open_low=True, unit="m")
        if self._pad is None:
            self._make_pad()
        R, z = T_W_S[:3, :3], T_W_S[:3, 2]
        # the pad's front face (its +z_S side) starts ``standoff`` before the push point
        start = T_W_S[:3, 3] - (self.standoff + self.pad_half[2]) * z
        self._place_pad(start, R, teleport=True)
        self.scene.step(1)
        s, touched_at, last_contact, contact, lost = 0.0, None, 0, False, False
        max_approach = self.standoff + 0.02
        n_max = int(np.ceil((max_approach + length) / self.speed)) + 1
        for k in range(n_max):
            s += self.speed
            self._place_pad(start + s * z, R)
            self.scene.step(1)
            if self._in_contact():
                if touched_at is None:
                    touched_at = s
                contact, last_contact = True, k
            if touched_at is None:
                if s >= max_approach:
                    break
                continue
            if s - touched_at >= length:
                break
            if k - last_contact >= self.lost_steps:
                lost = True
                break
        pushed = 0.0 if touched_at is None else s - touched_at
        # back off 1 cm before parking, so that the teleport does not drag the object
        self._place_pad(start + (s - 0.01) * z, R)
        self.scene.step(10)
        self._park()
        self.scene.step(self.settle_steps)
        return contact, lost, pushed

    # ------------------------------------------------------------------ loop
    def run(self, target_xy) -> PushResult:
        """Push until the distance to goal (eq. 6.17) is below ``tolerance`` or ``max_pushes`` is reached.

        Args:
            target_xy: the goal ``T`` in the world, metres; a goal farther than
                :data:`~vtlearn.runtime.obb.MAX_OBJECT_EXTENT_M` (2 m) from the object is refused (in
                practice, one given in millimetres).

        Shapes:
            target_xy: (2,) or (3,) (only x and y are used) -> :class:`PushResult`.
        """
        t = _xy(target_xy, "target_xy")
        d0 = distance_to_goal(oriented_bounding_box(self.object_cloud(), planar=True).centre, t)
        if d0 > MAX_OBJECT_EXTENT_M:
            raise ValueError(
                f"target_xy: the goal is {d0:.4g} m from the object, more than the "
                f"{MAX_OBJECT_EXTENT_M:g} m of a table top; vtlearn reads metres (a goal in millimetres?)"
            )
        self.pid.reset()
        if self._pad is None:
            self._make_pad()
        records: list[PushRecord] = []
        for _ in range(self.max_pushes + 1):
            cloud = self.object_cloud()
            obb = oriented_bounding_box(cloud, planar=True)
            O = obb.centre[:2].copy()
            d = distance_to_goal(O, t)
            if d < self.tolerance or len(records) == self.max_pushes:
                break
            T_W_S0, P0 = push_pose(cloud, t, 0.0, self.face, margin=float(self.pad_half[0]))
            # pad below mid height would scrape the table: keep its lower edge 2 mm above it
            h = max(P0[2], self.pad_half[1] + 0.002)
            T_W_S0[2, 3], P0[2] = h, h
            theta = bearing_angle(O, P0, t, signed=True)
            c = self.pid(theta, 1.0)
            T_W_S, _ = push_pose(cloud, t, c, self.face, margin=float(self.pad_half[0]))
            T_W_S[2, 3] = h
            contact, lost, pushed = self.push(T_W_S, min(self.push_step, d))
            records.append(
                PushRecord(O, theta, c, d, T_W_S[:3, 3].copy(), T_W_S[:3, 2].copy(), contact, lost, pushed)
            )
        return PushResult(t.copy(), records, O, d, bool(d < self.tolerance), self.tolerance, obb)
