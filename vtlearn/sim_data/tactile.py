"""Simulated taxel-array touch and pinch actions (thesis 4.2.4, 5.2.3, 7.2.4, 8.2.3).

Touch action (thesis 4.2.4 / 8.2.3): a ray ``(start, direction)``. The sensor pad, its z-axis along
``direction``, moves from ``start`` in a guarded straight line and stops when the force on any taxel
passes the threshold tau_f (thesis 4.3.1: "contact ... when the norm of the 3-axis force of any taxel
exceeds a threshold"). The positions of the contacted taxels are the tactile points.

Contact model (free-floating sensor, fixed object). Each taxel i casts a ray along ``direction``
from its rest position; ``t_i`` is the travel at which it first meets the surface. The elastomer is a
linear spring of stiffness ``k`` per taxel, so after a pad travel ``t`` taxel i presses with
``f_i = k * max(0, t - t_i)``. The pad stops at ``t* = min_i t_i + tau_f / k``: the first taxel then
reaches the force threshold. A rigid housing grid between the taxels stops the pad too (it carries
no taxels). Taxels with ``f_i >= f_min`` are in contact; their point is where the (compressed)
membrane meets the surface, ``start_i + t_i * direction``, with the surface normal from the ray hit
and the force ``f_i``. One batched ray cast (pybullet ``rayTestBatch``) replaces the stepped physics,
so a touch costs a few hundred microseconds.

Physical mode (free objects, issue 3: "objects are fixed, or free when an action is allowed to move
them"). The ray model cannot push anything, so when a touched object is free (a dynamic body, see
:meth:`Scene.add_mesh` with ``fixed=False``) the touch runs as real physics. The pad becomes a
dynamic compound body, one ``pitch x pitch x 3 mm`` box per taxel tiling the pad, so that Bullet
keeps one contact manifold per taxel. Its contacts are soft, with Bullet's contact stiffness set to
the elastomer's ``k`` (critically damped), so force grows with compression as in the ray model and a
flat face engages every taxel. A fixed constraint drags it along ``direction`` in steps of
``physics_step`` metres, one ``stepSimulation`` each. Each step reads ``getContactPoints``; every
contact point goes to the taxel under it (nearest taxel centre in the pad plane). Per taxel, the
force is the sum of pybullet's normal forces, the point is the force-weighted mean contact point on
the object, and the normal is the mean contact normal. The motion stops once any taxel force passes
tau_f or any penetration passes ``tau_f / k`` (the ray model's compression). It also stops
``max_push`` metres past the first contact, so a pad that keeps pushing a sliding object gives up.
The pad is then removed and the world is stepped ``settle_steps`` more times, and the new object
poses are returned in :attr:`TouchResult.T_world_objects`. A ray cast skips the free-space part of
the approach. Forces come from Bullet's contact solver, so they are coarser than the ray model's
(0.8-1.3 N instead of exactly tau_f on a flat face), and a physical touch costs tens of
milliseconds to a second (a long push) instead of a few hundred microseconds.

Pinch action (thesis 8.2.3): two parallel sensorised fingers open to a width wider than the object,
descend vertically from above to a grasp height (the descent is checked against collisions) and
close antipodally along an axis in the xy-plane. With a fixed object each finger closes until its own
first taxel reaches tau_f, the same guarded motion as a touch. In physical mode both fingers close
at the same time, each stopping on its own threshold, so a free object is squeezed, not pushed away.

Sensor realism knobs (:class:`TactileConfig`): Gaussian position noise, independent taxel dropout,
the force threshold, and a minimum contact count below which a touch reports no contact.

Shapes:
    TouchResult.points (K, 3), normals (K, 3), forces (K,), taxel_ids (K,) in the world frame;
    TouchResult.T_world_objects {body id: (4, 4)} object poses after a physical action
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import pybullet as p

from vtlearn.sim_data.scene import COLLISION_MARGIN, Scene, matrix_to_xyzw
from vtlearn.sim_data.sensors import TaxelSensor, get_sensor
from vtlearn.validation import as_int, as_real, as_transform, as_vector


@dataclass
class TactileConfig:
    """Sensor realism knobs. Defaults: noise off, no dropout, thesis tau_f = 1.1 (normalised force).

    ``physics_step``, ``max_push``, ``settle_steps``, ``pad_mass`` and ``pad_max_force`` only matter
    in physical mode (see the module docstring).
    """

    stiffness: float = 500.0  # N/m per taxel: 1.1 N threshold -> 2.2 mm elastomer compression
    force_threshold: float = 1.1  # tau_f, thesis 5.3.1
    min_force: float = 0.05  # a taxel reports contact from this force on (N)
    position_noise: float = 0.0  # std of Gaussian noise on each contact point (m)
    dropout: float = 0.0  # probability that a contacted taxel is not reported
    min_contacts: int = 1  # fewer surviving contacts -> the touch reports nothing
    max_travel: float = 0.5  # guarded motion gives up after this distance (m)
    # physical mode (free objects) only:
    physics_step: float = 2e-4  # pad advance per stepSimulation (m); 2e-4 m at 240 Hz is 4.8 cm/s
    max_push: float = 0.05  # give up this far past the first contact (m)
    settle_steps: int = 120  # world steps after the pad is removed, so pushed objects come to rest
    pad_mass: float = 0.1  # kg
    pad_max_force: float = 50.0  # N, strength of the constraint that drags the pad

    def __post_init__(self):
        as_int(self.settle_steps, "settle_steps", minimum=0)
        for name in (
            "stiffness",
            "force_threshold",
            "max_travel",
            "physics_step",
            "max_push",
            "pad_mass",
            "pad_max_force",
        ):
            as_real(getattr(self, name), name, low=0.0, open_low=True)
        if not as_real(self.min_force, "min_force", low=0.0) < self.force_threshold:
            raise ValueError(f"min_force: need 0 <= min_force < force_threshold, got {self.min_force}")
        as_real(self.position_noise, "position_noise", low=0.0, unit="m")
        as_real(self.dropout, "dropout", low=0.0, high=1.0, open_high=True)
        as_int(self.min_contacts, "min_contacts")


@dataclass
class TouchResult:
    """Contacted taxels of one action, world frame. Empty arrays mean no (valid) contact."""

    points: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))
    normals: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))
    forces: np.ndarray = field(default_factory=lambda: np.zeros(0))
    taxel_ids: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=np.int64))
    body_ids: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=np.int64))
    T_world_pad: np.ndarray | None = None  # pad pose where the guarded motion stopped
    # physical mode: T_world_object of every free object after the action (it may have been pushed)
    T_world_objects: dict[int, np.ndarray] = field(default_factory=dict)

    @property
    def num_contacts(self) -> int:
        return len(self.points)

    @staticmethod
    def merge(results: list[TouchResult]) -> TouchResult:
        if not results:
            return TouchResult()
        return TouchResult(
            np.concatenate([r.points for r in results]),
            np.concatenate([r.normals for r in results]),
            np.concatenate([r.forces for r in results]),
            np.concatenate([r.taxel_ids for r in results]),
            np.concatenate([r.body_ids for r in results]),
            results[-1].T_world_pad,
            {k: v for r in results for k, v in r.T_world_objects.items()},
        )


def pad_frame(start, direction, roll: float = 0.0) -> np.ndarray:
    """T_world_pad with origin ``start`` and z-axis ``direction``; ``roll`` (rad) turns the grid about z.

    ``start`` is a finite (3,) point, ``direction`` a finite non-zero (3,) vector and ``roll`` finite.

    Shapes:
        start (3,) world frame, metres; direction (3,) world frame, any length -> T_world_pad (4, 4)
    """
    start = np.asarray(start, dtype=np.float64)
    d = np.asarray(direction, dtype=np.float64)
    if start.shape != (3,) or not np.all(np.isfinite(start)):
        raise ValueError(f"start: need a finite (3,) point, got {start}")
    n = np.linalg.norm(d)
    if d.shape != (3,) or not np.isfinite(n) or n < 1e-12:
        raise ValueError(f"direction: need a finite non-zero (3,) vector, got {direction}")
    roll = as_real(roll, "roll")
    z = d / n
    ref = np.array([1.0, 0.0, 0.0]) if abs(z[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    x = np.cross(ref, z)
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    c, s = np.cos(roll), np.sin(roll)
    x, y = c * x + s * y, -s * x + c * y
    T = np.eye(4)
    T[:3, 0], T[:3, 1], T[:3, 2], T[:3, 3] = x, y, z, start
    return T


class TactileSimulator:
    """Free-floating taxel sensor acting on the objects of a :class:`Scene`.

    Args:
        scene: the pybullet scene to touch.
        sensor: a :class:`TaxelSensor` or a preset name such as ``"xela_4x4"``.
        config: realism knobs, see :class:`TactileConfig`.
        objects: body ids that count as touched objects (default: every object in the scene);
            contact with anything else (the table) stops the pad but yields no tactile point.
        mode: ``"auto"`` (default) runs the ray model when every touched object is fixed and the
            physical mode when any is free; ``"ray"`` or ``"physics"`` force one (the ray model never
            moves an object).
    """

    MODES = ("auto", "ray", "physics")

    def __init__(
        self,
        scene: Scene,
        sensor: TaxelSensor | str = "xela_4x4",
        config: TactileConfig | None = None,
        objects: list[int] | None = None,
        mode: str = "auto",
    ):
        if mode not in self.MODES:
            raise ValueError(f"mode: expected one of {self.MODES}, got {mode!r}")
        if objects is not None:
            unknown = [b for b in objects if b not in scene.objects]
            if unknown:
                raise ValueError(f"objects: body ids {unknown} are not objects of the scene")
        self.scene = scene
        self.sensor = get_sensor(sensor)
        self.config = config or TactileConfig()
        self.objects = objects
        self.mode = mode
        self._taxels = self.sensor.taxel_positions()
        self._housing = self.sensor.housing_positions()
        self._pad_shape: int | None = None

    def _object_ids(self) -> list[int]:
        return list(self.scene.objects) if self.objects is None else list(self.objects)

    def _is_object(self, ids: np.ndarray) -> np.ndarray:
        return np.isin(ids, self._object_ids())

    @property
    def physical(self) -> bool:
        """Whether actions run as stepped physics (see ``mode``)."""
        if self.mode != "auto":
            return self.mode == "physics"
        return any(not self.scene.objects[b].fixed for b in self._object_ids() if b in self.scene.objects)

    def touch(
        self, start, direction, roll: float = 0.0, rng: np.random.Generator | None = None
    ) -> TouchResult:
        """Guarded touch along ``direction`` from ``start`` (world frame, metres), thesis 4.2.4 / 8.2.3.

        The pad's grid is turned by ``roll`` (rad) about ``direction`` (see :func:`pad_frame`); ``rng`` draws
        the noise and dropout of :class:`TactileConfig` (pass one for reproducible output).

        Shapes:
            start (3,), direction (3,), world frame -> TouchResult with points (K, 3) in the world frame,
            on the touched surface (noise off), K <= sensor.num_taxels
        """
        return self.touch_from(pad_frame(start, direction, roll), rng)

    def touch_from(self, T_world_pad: np.ndarray, rng: np.random.Generator | None = None) -> TouchResult:
        """Guarded motion of the pad along its own z-axis from the pose ``T_world_pad``.

        Shapes:
            T_world_pad (4, 4), a rigid transform (``ValueError`` otherwise) -> TouchResult (world frame)
        """
        T_world_pad = as_transform(T_world_pad, "T_world_pad")
        if self.physical:
            return self._physical_touches([T_world_pad], rng)[0]
        cfg = self.config
        R, o = T_world_pad[:3, :3], T_world_pad[:3, 3]
        d = R[:, 2]
        starts = np.concatenate([self._taxels, self._housing]) @ R.T + o
        ids, frac, pts, nrm = self.scene.ray_test(starts, starts + cfg.max_travel * d)
        hit = ids >= 0
        if not hit.any():
            return TouchResult(T_world_pad=T_world_pad)
        t = np.where(hit, frac * cfg.max_travel, np.inf)
        depth = cfg.force_threshold / cfg.stiffness
        t_stop = min(t.min() + depth, cfg.max_travel)
        nt = len(self._taxels)
        force = cfg.stiffness * np.clip(t_stop - t[:nt], 0.0, None)
        contact = hit[:nt] & (force >= cfg.min_force) & self._is_object(ids[:nt])
        T_stop = T_world_pad.copy()
        T_stop[:3, 3] = o + t_stop * d
        return self._report(np.flatnonzero(contact), pts[:nt], nrm[:nt], force, ids[:nt], T_stop, rng)

    # ------------------------------------------------------------------ physical mode
    def _pad_collision_shape(self) -> int:
        """One box per taxel, tiling the pad, front faces on the pad plane z = 0 (the pad looks along +z)."""
        if self._pad_shape is None:
            half = [self.sensor.pitch / 2, self.sensor.pitch / 2, 0.0015]
            pos = self._taxels - np.array([0.0, 0.0, half[2]])
            self._pad_shape = p.createCollisionShapeArray(
                shapeTypes=[p.GEOM_BOX] * len(pos),
                halfExtents=[half] * len(pos),
                collisionFramePositions=pos.tolist(),
                physicsClientId=self.scene.client,
            )
        return self._pad_shape

    def _physical_touches(self, T_pads: list[np.ndarray], rng) -> list[TouchResult]:
        """Guarded motions of pads at the poses ``T_pads``, run together in stepped physics."""
        cfg, kw = self.config, {"physicsClientId": self.scene.client}
        depth = cfg.force_threshold / cfg.stiffness
        objects = set(self._object_ids())
        pads = []
        for T in T_pads:
            # Skip the free-space approach: start 5 mm before the first surface the pad's rays meet.
            R, o = T[:3, :3], T[:3, 3]
            starts = np.concatenate([self._taxels, self._housing]) @ R.T + o
            ids, frac, _, _ = self.scene.ray_test(starts, starts + cfg.max_travel * R[:, 2])
            if not (ids >= 0).any():
                pads.append(None)
                continue
            t_first = float(frac[ids >= 0].min() * cfg.max_travel)
            s0 = max(0.0, t_first - 0.005)
            pos = o + s0 * R[:, 2]
            body = p.createMultiBody(
                cfg.pad_mass, self._pad_collision_shape(), -1, pos.tolist(), matrix_to_xyzw(R), **kw
            )
            p.changeDynamics(
                body,
                -1,
                collisionMargin=COLLISION_MARGIN,
                contactStiffness=cfg.stiffness,
                contactDamping=2 * np.sqrt(cfg.stiffness * cfg.pad_mass),
                **kw,
            )
            cid = p.createConstraint(
                body,
                -1,
                -1,
                -1,
                p.JOINT_FIXED,
                [0, 0, 0],
                parentFramePosition=[0, 0, 0],
                childFramePosition=pos.tolist(),
                childFrameOrientation=matrix_to_xyzw(R),
                **kw,
            )
            p.changeConstraint(cid, maxForce=cfg.pad_max_force, **kw)
            limit = min(cfg.max_travel, t_first + cfg.max_push)
            pads.append(
                {"T": T, "body": body, "cid": cid, "s": s0, "limit": limit, "done": False, "last": None}
            )
        active = [q for q in pads if q is not None]
        while any(not q["done"] for q in active):
            for q in active:
                if not q["done"]:
                    q["s"] = min(q["s"] + cfg.physics_step, q["limit"])
                    target = q["T"][:3, 3] + q["s"] * q["T"][:3, 2]
                    p.changeConstraint(
                        q["cid"], target.tolist(), matrix_to_xyzw(q["T"][:3, :3]), cfg.pad_max_force, **kw
                    )
            p.stepSimulation(**kw)
            for q in active:
                if q["done"]:
                    continue
                q["last"] = self._read_taxels(q["body"], objects)
                force, pen = q["last"][2], q["last"][5]
                if force.max() >= cfg.force_threshold or pen >= depth or q["s"] >= q["limit"]:
                    q["done"] = True
                    q["T_stop"] = self.scene.T_world_object(q["body"])
                    p.removeConstraint(q["cid"], **kw)
                    p.removeBody(q["body"], **kw)
        for _ in range(cfg.settle_steps if active else 0):
            p.stepSimulation(**kw)
        poses = {b: self.scene.T_world_object(b) for b in objects if not self.scene.objects[b].fixed}
        out = []
        for T, q in zip(T_pads, pads, strict=True):
            if q is None:
                out.append(TouchResult(T_world_pad=T, T_world_objects=dict(poses)))
                continue
            pts, nrm, force, ids, is_obj, _ = q["last"]
            idx = np.flatnonzero(is_obj & (force >= cfg.min_force))
            res = self._report(idx, pts, nrm, force, ids, q["T_stop"], rng)
            res.T_world_objects = dict(poses)
            out.append(res)
        return out

    def _read_taxels(self, pad: int, objects: set[int]):
        """Per-taxel contact state of ``pad`` from ``getContactPoints``.

        Returns (points (T, 3), normals (T, 3), forces (T,), body ids (T,), on-object mask (T,),
        max penetration): each contact point goes to the taxel nearest to it in the pad plane.
        """
        nt = len(self._taxels)
        pts, nrm = np.zeros((nt, 3)), np.zeros((nt, 3))
        force, ids = np.zeros(nt), np.full(nt, -1, dtype=np.int64)
        cps = p.getContactPoints(bodyA=pad, physicsClientId=self.scene.client)
        if not cps:
            return pts, nrm, force, ids, np.zeros(nt, bool), 0.0
        body_b = np.array([c[2] for c in cps], dtype=np.int64)
        on_a = np.array([c[5] for c in cps], dtype=np.float64)
        on_b = np.array([c[6] for c in cps], dtype=np.float64)
        n_b = np.array([c[7] for c in cps], dtype=np.float64)  # from B (the object) towards the pad
        dist = np.array([c[8] for c in cps], dtype=np.float64)
        f = np.array([c[9] for c in cps], dtype=np.float64)
        T_pad = self.scene.T_world_object(pad)
        local = (on_a - T_pad[:3, 3]) @ T_pad[:3, :3]  # (C, 3) in the pad frame
        s = self.sensor
        col = np.clip(np.round(local[:, 0] / s.pitch + (s.cols - 1) / 2), 0, s.cols - 1).astype(np.int64)
        row = np.clip(np.round(local[:, 1] / s.pitch + (s.rows - 1) / 2), 0, s.rows - 1).astype(np.int64)
        taxel = row * s.cols + col  # row-major, as TaxelSensor.taxel_positions
        # Zero-force points (touching, not yet pushing) still locate the contact, with a tiny weight.
        w = f + 1e-9
        np.add.at(force, taxel, f)
        wsum = np.bincount(taxel, weights=w, minlength=nt)
        for k in range(3):
            pts[:, k] = np.bincount(taxel, weights=w * on_b[:, k], minlength=nt)
            nrm[:, k] = np.bincount(taxel, weights=w * n_b[:, k], minlength=nt)
        hit = wsum > 0
        pts[hit] /= wsum[hit, None]
        nrm[hit] /= np.maximum(np.linalg.norm(nrm[hit], axis=1, keepdims=True), 1e-12)
        # A taxel is on an object when its strongest contact is with one of ``objects``.
        order = np.lexsort((f, taxel))
        last = np.r_[taxel[order][1:] != taxel[order][:-1], True]
        ids[taxel[order][last]] = body_b[order][last]
        is_obj = hit & np.isin(ids, list(objects))
        return pts, nrm, force, ids, is_obj, float(max(0.0, -dist.min()))

    def _report(self, idx, pts, nrm, force, ids, T_stop, rng) -> TouchResult:
        cfg = self.config
        if len(idx) and cfg.dropout > 0:
            rng = rng if rng is not None else np.random.default_rng()
            idx = idx[rng.uniform(size=len(idx)) >= cfg.dropout]
        if len(idx) < cfg.min_contacts:
            return TouchResult(T_world_pad=T_stop)
        points = pts[idx].copy()
        if cfg.position_noise > 0:
            rng = rng if rng is not None else np.random.default_rng()
            points += rng.normal(scale=cfg.position_noise, size=points.shape)
        return TouchResult(
            points,
            nrm[idx].copy(),
            force[idx].copy(),
            idx.astype(np.int64),
            ids[idx].astype(np.int64),
            T_stop,
        )

    def pinch(
        self,
        center,
        axis_angle: float,
        width: float,
        approach_height: float = 0.1,
        rng: np.random.Generator | None = None,
    ) -> TouchResult:
        """Pinch from above: descend two facing pads to ``center`` and close them along an xy axis.

        Args:
            center: (3,) grasp centre in the world frame; the fingers end at its height.
            axis_angle: closing axis direction in the xy-plane (rad from world x).
            width: initial finger opening (m), wider than the object at that height.
            approach_height: height above ``center`` from which the fingers descend.

        Shapes:
            center (3,) world frame, metres -> TouchResult with the points (K, 3) of both fingers, world
            frame, K <= 2 * sensor.num_taxels; empty when the descent is blocked or too few taxels touch.
        """
        c = np.asarray(center, dtype=np.float64)
        if c.shape != (3,) or not np.all(np.isfinite(c)):
            raise ValueError(f"center: need a finite (3,) point, got {center}")
        width = as_real(width, "width", low=0.0, open_low=True, unit="m")
        approach_height = as_real(approach_height, "approach_height", low=0.0, open_low=True, unit="m")
        axis_angle = as_real(axis_angle, "axis_angle")
        u = np.array([np.cos(axis_angle), np.sin(axis_angle), 0.0])
        fingers = []
        for sign in (1.0, -1.0):
            # Pad faces inward (-sign * u); its grid's x-axis stays horizontal, y vertical.
            T = pad_frame(c + sign * u * width / 2, -sign * u)
            T_top = T.copy()
            T_top[:3, 3] += [0, 0, approach_height]
            if self._descent_blocked(T_top, approach_height):
                return TouchResult(T_world_pad=T)
            fingers.append(T)
        if self.physical:  # both fingers close together, so a free object is squeezed, not pushed away
            results = self._physical_touches(fingers, rng)
        else:
            results = [self.touch_from(T, rng) for T in fingers]
        cfg = self.config
        merged = TouchResult.merge(results)
        if merged.num_contacts >= cfg.min_contacts:
            return merged
        return TouchResult(T_world_pad=merged.T_world_pad, T_world_objects=merged.T_world_objects)

    def _descent_blocked(self, T_top: np.ndarray, drop: float) -> bool:
        starts = self._housing @ T_top[:3, :3].T + T_top[:3, 3]
        ids, _, _, _ = self.scene.ray_test(starts, starts - np.array([0, 0, drop]))
        return bool(self._is_object(ids).any())


# --------------------------------------------------------------------------- action samplers
def bbox_faces(lo, hi):
    """The five faces of an axis-aligned box except the bottom: (centre, outward normal, u, v half-axes).

    The face of outward normal ``n = ±e_axis`` is centred at ``c + h[axis] * n`` (``c``, ``h`` the box centre
    and half extents), so the -x and -y faces lie on the ``lo`` side of the box.

    Shapes:
        lo (3,), hi (3,) -> 5 tuples of (3,) arrays, in the frame of ``lo``/``hi``.
    """
    lo, hi = np.asarray(lo, float), np.asarray(hi, float)
    c, h = (lo + hi) / 2, (hi - lo) / 2
    faces = []
    for axis in range(3):
        for sign in (1.0, -1.0):
            if axis == 2 and sign < 0:
                continue  # the bottom face rests on the table (thesis 5.2.3, 7.2.4)
            n = np.zeros(3)
            n[axis] = sign
            others = [a for a in range(3) if a != axis]
            u, v = np.zeros(3), np.zeros(3)
            u[others[0]], v[others[1]] = h[others[0]], h[others[1]]
            faces.append((c + h[axis] * n, n, u, v))
    return faces


def _check_box(lo, hi) -> tuple[np.ndarray, np.ndarray]:
    """``lo``, ``hi`` as finite (3,) float arrays with ``lo <= hi``; ValueError naming the argument."""
    out = [as_vector(x, name, 3, "a finite (3,) box corner") for name, x in (("lo", lo), ("hi", hi))]
    if (out[0] > out[1]).any():
        raise ValueError(f"lo/hi: need lo <= hi on every axis, got {out[0].tolist()} and {out[1].tolist()}")
    return out[0], out[1]


def sample_touches(
    lo,
    hi,
    n: int,
    rng: np.random.Generator,
    standoff: float = 0.03,
    mode: str = "random",
    margin: float = 0.9,
) -> list[tuple[np.ndarray, np.ndarray, float]]:
    """Touch actions (start, direction, roll) on the bounding-box faces except the bottom.

    ``mode="random"`` picks faces with probability proportional to area and points uniformly on them
    (Monte-Carlo sampling, thesis 7.2.4); ``mode="grid"`` spreads ``n`` touches as regular grids over
    the five faces. Starts lie ``standoff`` metres outside the face; directions point inward.

    ``lo``/``hi`` are finite (3,) box corners with ``lo <= hi`` and a positive surface area, ``standoff`` is
    finite and >= 0, ``margin`` (the fraction of each face used) lies in [0, 1].

    Shapes:
        lo (3,), hi (3,), world frame, metres -> n tuples (start (3,), direction (3,) unit, roll float)
    """
    n = as_int(n, "n")
    if mode not in ("random", "grid"):
        raise ValueError(f"mode: expected 'random' or 'grid', got {mode!r}")
    lo, hi = _check_box(lo, hi)
    standoff = as_real(standoff, "standoff", low=0.0)
    margin = as_real(margin, "margin", low=0.0, high=1.0)
    faces = bbox_faces(lo, hi)
    out = []
    if mode == "random":
        area = np.array([np.linalg.norm(u) * np.linalg.norm(v) for _, _, u, v in faces])
        if not area.sum() > 0:
            raise ValueError(f"lo/hi: the box {lo.tolist()} - {hi.tolist()} has no face area to touch")
        choice = rng.choice(len(faces), size=n, p=area / area.sum())
        ab = rng.uniform(-margin, margin, size=(n, 2))
        for f, (a, b) in zip(choice, ab, strict=True):
            c, nrm, u, v = faces[f]
            out.append((c + a * u + b * v + standoff * nrm, -nrm, float(rng.uniform(0, np.pi))))
        return out
    per_face = max(1, int(np.ceil(n / len(faces))))
    k = int(np.ceil(np.sqrt(per_face)))
    g = np.linspace(-margin, margin, k) if k > 1 else np.zeros(1)
    for c, nrm, u, v in faces:
        for a in g:
            for b in g:
                out.append((c + a * u + b * v + standoff * nrm, -nrm, 0.0))
    return out[:n] if len(out) > n else out


def sample_pinches(lo, hi, n: int, rng: np.random.Generator, clearance: float = 0.03):
    """Pinch actions from above: (centre, axis angle, width) with the centre inside the footprint.

    ``lo``/``hi`` are finite (3,) box corners with ``lo <= hi``; ``clearance`` is finite and >= 0, and the
    resulting finger opening must be positive.

    Shapes:
        lo (3,), hi (3,), world frame, metres -> n tuples (centre (3,), axis angle float, width float)
    """
    n = as_int(n, "n")
    lo, hi = _check_box(lo, hi)
    clearance = as_real(clearance, "clearance", low=0.0)
    c, h = (lo + hi) / 2, (hi - lo) / 2
    width = 2 * np.linalg.norm(h[:2]) + 2 * clearance
    if not width > 0:
        raise ValueError("lo/hi/clearance: zero footprint and zero clearance give a zero pinch width")
    out = []
    for _ in range(n):
        xy = c[:2] + rng.uniform(-0.3, 0.3, size=2) * h[:2]
        z = lo[2] + rng.uniform(0.15, 0.95) * (hi[2] - lo[2])
        out.append((np.array([xy[0], xy[1], z]), float(rng.uniform(0, np.pi)), float(width)))
    return out
