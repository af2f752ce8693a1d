"""The two-arm visuo-tactile robot runtime (thesis ch.5, 5.2.1-5.2.3, Fig. 5.1-5.2).

The thesis' framework is a robot team on one table: a Franka Panda with an eye-in-hand RGB-D camera and a
UR5 whose gripper carries tactile arrays (Fig. 5.1). Together they

1. declutter the scene around an unknown target object, driven by the declutter graph (5.2.2,
   eq. 5.1-5.2, :mod:`vtlearn.runtime.declutter`);
2. explore the target with next-best views and touches on a shared occupancy grid (5.2.3,
   eq. 5.6-5.10, :func:`vtlearn.active.closed_loop.run_episode`), touch preferred when the target is
   transparent;
3. reconstruct it (ACTOR, ch.8), recognise it (xAVTNet, ch.7) and estimate its pose with S-TIQF
   (5.2.4), using models loaded from Lightning checkpoints (``weights_only=True``).

Here both robots are pybullet Pandas (``pybullet_data/franka_panda``; there is no UR5 in
pybullet_data): the *vision arm* faces +x from ``(-0.6, 0, 0)`` and carries the camera at
:func:`camera_mount`; the *tactile arm* faces -x from ``(0.6, 0, 0)`` and carries the taxel pad of
:class:`~vtlearn.sim_data.arm.PandaArm`. Every sensing action is checked by inverse kinematics before it
is scored (:class:`IKFeasibility` fills the feasibility hook of :mod:`vtlearn.active.actions`), and a
touch is executed from the pad pose that forward kinematics (pytorch-kinematics) gives for the IK
solution, so the contact points are where the arm really put the pad.

What is simulated and what is not:

- The RGB-D camera is :class:`~vtlearn.sim_data.camera.RGBDCamera` (TinyRenderer): depth noise, and
  missing or wrongly deep pixels on transparent bodies. Its segmentation image stands in for the
  thesis' semantic segmentation network (Chen et al. 2017); objects are told apart by body id.
- Transparency is *detected*, not read from the scene: the IoU of the RGB mask box with the depth
  cloud's box (thesis 5.2.3, :func:`vtlearn.active.selection.detect_transparent`). A transparent object's
  footprint comes from its RGB mask projected on the table plane, because its depth is unusable.
- Both robots declutter (thesis 5.2.2): an action goes to the tactile arm, or to the vision arm when
  only that one reaches it (IK). Grasps of the declutter graph are kinematic: when an arm reaches the
  top-down pre-grasp pose, the object is placed at the next place position. There are no finger
  dynamics, so the thesis' tactile monitoring of a dropped object is not modelled.
- Pushes are physical: when an arm reaches the push pose (IK), a pad-sized pusher slides along
  the push direction through the Bullet contact dynamics (:meth:`vtlearn.runtime.pushing.GoalPusher.push`)
  and stops when its contact with the pushed object is lost; whatever it meets moves.
- Touches are the guarded motions of :class:`~vtlearn.sim_data.tactile.TactileSimulator`; the target
  stays fixed while it is touched (thesis: the target is not moved during exploration). Pinches need
  a two-finger tactile gripper, which the runtime does not model, so exploration uses touches (and
  views).

Frames and units: metres; world z-up with the table top at z = 0. ``T_world_camera`` is the optical
frame (z forward, x right, y down); ``T_world_pad`` the pad frame (z = pressing direction).

Shapes:
    IKFeasibility(T_world_sensor (N, 4, 4)) -> (N,) bool
    TwoArmRuntime.observe() -> Observation with instance clouds {body id: (M, 3)} (world frame)
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pybullet as p

from vtlearn.active.closed_loop import Episode, SimObject, TouchWorld, run_episode
from vtlearn.runtime.pushing import GoalPusher, sensor_frame
from vtlearn.sim_data.arm import PandaArm
from vtlearn.sim_data.camera import RGBDCamera, RGBDFrame, backproject
from vtlearn.sim_data.scene import Scene
from vtlearn.validation import as_int, as_real, as_transform, as_vector, load_named

log = logging.getLogger(__name__)

DECLUTTER_POLICIES = ("graph", "nearest", "random")
# The arms stand at x = -0.6 and +0.6 m: an object farther than this from the table centre is out of both
# reaches, and in practice a pose given in millimetres.
_TABLE_REACH_M = 1.5

__all__ = [
    "DECLUTTER_POLICIES",
    "ArmTouchWorld",
    "IKFeasibility",
    "Observation",
    "RuntimeReport",
    "TwoArmRuntime",
    "camera_mount",
    "check_class_names",
    "clutter_scene",
    "symmetric_rolls",
]


def check_class_names(class_names: Sequence[str], xavtnet, name: str) -> list[str]:
    """``class_names`` as strings, one per class of the loaded ``xavtnet``; a ``ValueError`` naming ``name``
    (an argument or a command-line flag) when their count differs from the checkpoint's ``num_classes``,
    which would silently mislabel every prediction."""
    names = [str(c) for c in class_names]
    n_classes = dict(getattr(xavtnet, "hparams", {})).get("num_classes")
    if n_classes is not None and len(names) != int(n_classes):
        raise ValueError(
            f"{name}: {len(names)} class names but the xAVTNet checkpoint has {n_classes} classes"
        )
    return names


def _yaw_base(x: float, yaw: float) -> np.ndarray:
    T = np.eye(4)
    c, s = np.cos(yaw), np.sin(yaw)
    T[:3, :3] = [[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]]
    T[0, 3] = x
    return T


def camera_mount() -> np.ndarray:
    """``T_hand_camera`` of the eye-in-hand camera: 12 cm along the hand's approach axis, just beyond the
    fingertips so they do not occlude the image, optical axis along it (the camera looks where the
    gripper points), image x along the hand's x."""
    T = np.eye(4)
    T[2, 3] = 0.12
    return T


def symmetric_rolls(taxels: np.ndarray, tol: float = 1e-6) -> tuple[float, ...]:
    """The quarter turns about the pad z-axis that map the taxel layout ``(K, 3)`` (pad frame) onto
    itself: ``(0, pi/2, pi, -pi/2)`` for a square grid centred on the pad origin, ``(0, pi)`` for a
    centred rectangle. A touch rolled by one of them measures along the same rays."""
    t = np.asarray(taxels, dtype=np.float64)
    if t.ndim != 2 or t.shape[1] != 3 or not len(t):
        raise ValueError(f"taxels: need a non-empty (K, 3) layout, got shape {t.shape}")
    out = []
    for roll in (0.0, np.pi / 2, np.pi, -np.pi / 2):
        c, s = np.cos(roll), np.sin(roll)
        r = t @ np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]]).T
        if np.abs(r[:, None] - t[None]).sum(-1).min(1).max() <= tol:
            out.append(roll)
    return tuple(out)


class IKFeasibility:
    """Kinematic feasibility of sensor poses by inverse kinematics (:mod:`vtlearn.active.actions` hook).

    A pose ``T_world_sensor`` is feasible when the arm's IK solution puts the sensor, mounted at
    ``T_hand_sensor`` on ``panda_hand``, within ``position_tol`` metres and ``angle_tol_deg`` degrees
    of it, with the joints inside their limits (pybullet damped least squares, refined from the
    current joint state; the error is measured with pytorch-kinematics forward kinematics). Queries
    leave the arm where it was.

    Args:
        arm: the :class:`~vtlearn.sim_data.arm.PandaArm` that would carry the sensor.
        T_hand_sensor: the sensor mount (default: the arm's pad mount ``arm.T_hand_pad``).
        position_tol, angle_tol_deg: the accepted pose error.
        iterations: at most this many IK refinements per roll (in rounds of 5, stopping once the pose is
            reached; poses facing the robot's own base need about 20).
        rolls: rotations about the sensor z-axis (radians) that leave the sensor's measurement the
            same, tried in turn: ``(0, pi/2, pi, -pi/2)`` for a square taxel grid pressed along z. IK
            from one rest posture misses many wrist rolls that another roll of the same touch reaches.
        rest_q: the posture (7,) every query starts from, so that answers do not depend on the arm's
            current state (default: the arm's joints at construction).

    Shapes:
        __call__: T_world_sensor ``(N, 4, 4)`` -> ``(N,)`` bool
    """

    def __init__(
        self,
        arm: PandaArm,
        T_hand_sensor: np.ndarray | None = None,
        position_tol: float = 0.005,
        angle_tol_deg: float = 3.0,
        iterations: int = 25,
        rolls: Sequence[float] = (0.0,),
        rest_q=None,
    ):
        if not isinstance(arm, PandaArm):
            raise ValueError(f"arm: need a PandaArm, got {type(arm).__name__}")
        position_tol = as_real(position_tol, "position_tol", low=0.0, open_low=True, unit="m")
        angle_tol_deg = as_real(angle_tol_deg, "angle_tol_deg", low=0.0, open_low=True, unit="deg")
        iterations = as_int(iterations, "iterations")
        self.rolls = tuple(float(r) for r in rolls)
        if not self.rolls or not np.isfinite(self.rolls).all():
            raise ValueError(f"rolls: need at least one finite angle, got {rolls}")
        self.arm = arm
        self.T_hand_sensor = (
            arm.T_hand_pad.copy() if T_hand_sensor is None else as_transform(T_hand_sensor, "T_hand_sensor")
        )
        # IK is solved for the arm's own mount; a pose of this sensor maps to a pose of that mount.
        self._T_sensor_pad = np.linalg.inv(self.T_hand_sensor) @ arm.T_hand_pad
        self.position_tol, self.angle_tol_deg, self.iterations = (
            float(position_tol),
            float(angle_tol_deg),
            int(iterations),
        )
        # A roll still this far off after a round of refinement does not converge (measured: the poses
        # that need ~20 refinements start 5-8 cm off, the unreachable ones 20 cm or more).
        self.give_up_m = 0.15
        self.rest_q = arm.q.copy() if rest_q is None else np.asarray(rest_q, dtype=np.float64)
        if self.rest_q.shape != (7,) or not np.isfinite(self.rest_q).all():
            raise ValueError(f"rest_q: need 7 finite joint angles, got {rest_q}")
        self.queries = 0

    def T_world_sensor(self, q) -> np.ndarray:
        """Forward kinematics of the sensor for joint angles ``q`` (7,)."""
        return self.arm.fk_hand(q) @ self.T_hand_sensor

    def _solve_one(self, T: np.ndarray) -> tuple[np.ndarray, bool, float, float]:
        q0 = self.arm.q.copy()
        T_pad = T @ self._T_sensor_pad
        # Damped IK depends on where it starts; always starting from the rest posture makes a query's
        # answer independent of where earlier actions left the arm (the filter and the execution agree).
        self.arm.set_joints(self.rest_q)
        try:
            done = 0
            while done < self.iterations:  # refine in rounds of 5; stop as soon as the pose is reached
                step = min(5, self.iterations - done)
                q = self.arm.ik(T_pad, iterations=step)
                done += step
                sol = self._check(q, T)
                if sol[1] or sol[2] > self.give_up_m:
                    break
        finally:
            self.arm.set_joints(q0)
        return sol

    def _check(self, q: np.ndarray, T: np.ndarray) -> tuple[np.ndarray, bool, float, float]:
        T_fk = self.T_world_sensor(q)
        pos = float(np.linalg.norm(T_fk[:3, 3] - T[:3, 3]))
        cos = (np.trace(T_fk[:3, :3].T @ T[:3, :3]) - 1.0) / 2.0
        ang = float(np.degrees(np.arccos(np.clip(cos, -1.0, 1.0))))
        inside = bool(np.all(q >= self.arm.lower - 1e-9) and np.all(q <= self.arm.upper + 1e-9))
        return q, inside and pos <= self.position_tol and ang <= self.angle_tol_deg, pos, ang

    def solve(self, T_world_sensor: np.ndarray) -> tuple[np.ndarray, bool, float, float]:
        """IK for one pose, trying each of ``rolls`` about the sensor z-axis in turn; returns
        ``(q, feasible, position error m, angle error deg)`` of the first feasible roll (else of the
        smallest error). The errors are against the rolled pose. The arm is left where it was."""
        T = as_transform(T_world_sensor, "T_world_sensor")
        self.queries += 1
        best = None
        for roll in self.rolls:
            R = np.eye(4)
            c, s = np.cos(roll), np.sin(roll)
            R[:2, :2] = [[c, -s], [s, c]]
            sol = self._solve_one(T @ R)
            if sol[1]:
                return sol
            if best is None or sol[2] + sol[3] / 1000 < best[2] + best[3] / 1000:
                best = sol
        return best

    def __call__(self, T_world_sensor: np.ndarray) -> np.ndarray:
        T = np.asarray(T_world_sensor, dtype=np.float64)
        if T.ndim != 3 or T.shape[1:] != (4, 4):
            raise ValueError(f"T_world_sensor: need shape (N, 4, 4), got {T.shape}")
        return np.array([self.solve(t)[1] for t in T], dtype=bool)


class ArmTouchWorld(TouchWorld):
    """The target of a :class:`TwoArmRuntime` as a :class:`~vtlearn.active.closed_loop.TouchWorld`: the
    pad is carried by the tactile arm, and views are taken by the vision arm's camera.

    A touch first moves the arm by IK to the commanded pad pose; the guarded motion then starts from the
    forward-kinematics pad pose, so the contacts are those of the pose the arm reached (within the
    feasibility tolerance of the commanded one, whose rays the occupancy grid integrates). A touch whose
    pose the arm cannot reach is still executed from where the arm got to, and counted in
    ``unreached``; with the feasibility hook on the candidates this does not happen.
    """

    def __init__(self, runtime: TwoArmRuntime, obj: SimObject, body: int):
        from vtlearn.sim_data.tactile import TactileSimulator

        # Not TouchWorld.__init__: the runtime owns the scene; only the target counts as touched.
        self.obj, self.scene, self.body = obj, runtime.scene, body
        self.sim = TactileSimulator(runtime.scene, runtime.sensor, objects=[body])
        self.feasibility = runtime.touch_feasibility
        self.arm = runtime.tactile_arm
        self._mesh_world = None
        self.unreached = 0

    def close(self) -> None:
        """Nothing to release: the runtime's scene outlives the exploration."""

    def press(self, T_world_pad: np.ndarray, ray_length: float):
        T = np.asarray(T_world_pad, dtype=np.float64).reshape(-1, 4, 4)
        if len(T) != 1:
            raise ValueError(
                f"T_world_pad: the runtime's tactile arm carries one pad, got {len(T)} pad poses (a pinch); "
                "explore with pinch=False"
            )
        q, ok, _, _ = self.feasibility.solve(T[0])
        self.arm.set_joints(q)
        self.unreached += int(not ok)
        T_fk = self.arm.T_world_pad(q)
        ranges, hit, points = super().press(T_fk[None], ray_length)
        # The arm may have reached a symmetric roll of the commanded pad; give the evidence in the
        # commanded taxel order, which is the order of the rays the occupancy grid integrates.
        taxels = self.sim.sensor.taxel_positions()
        o_cmd = taxels @ T[0, :3, :3].T + T[0, :3, 3]
        o_fk = taxels @ T_fk[:3, :3].T + T_fk[:3, 3]
        order = np.argmin(np.linalg.norm(o_cmd[:, None] - o_fk[None], axis=-1), axis=1)
        return ranges[order], hit[order], points


@dataclass
class Observation:
    """One top-down RGB-D observation: the frame, and per object (body id) its world-frame cloud, its
    RGB-mask box on the table plane ``(x_min, y_min, x_max, y_max)``, the box IoU of the thesis'
    transparency test and its verdict, and the fraction of its mask pixels with plausible depth (above
    the table). The cloud is the depth cloud when that fraction is at least 0.5, else the mask on the
    table plane."""

    frame: RGBDFrame
    clouds: dict[int, np.ndarray]
    rgb_boxes: dict[int, np.ndarray]
    transparency_iou: dict[int, float]
    transparent: dict[int, bool]
    depth_valid: dict[int, float]


@dataclass
class RuntimeReport:
    """What :meth:`TwoArmRuntime.run` did and found (JSON-ready through :meth:`to_dict`)."""

    declutter_actions: list[dict] = field(default_factory=list)
    declutter_done: bool = False
    transparent_detected: bool | None = None
    episode: Episode | None = None
    unreached_touches: int = 0
    ik_queries: int = 0
    perception: dict = field(default_factory=dict)
    perception_error: str | None = None
    seconds: dict = field(default_factory=dict)
    arrays: dict = field(default_factory=dict, repr=False)  # perception arrays for figures; not in JSON

    def to_dict(self) -> dict:
        return {
            "declutter_actions": self.declutter_actions,
            "declutter_done": self.declutter_done,
            "transparent_detected": self.transparent_detected,
            "episode": None if self.episode is None else self.episode.to_dict(),
            "unreached_touches": self.unreached_touches,
            "ik_queries": self.ik_queries,
            "perception": self.perception,
            "perception_error": self.perception_error,
            "seconds": self.seconds,
        }


class TwoArmRuntime:
    """Two Pandas, a table, a camera and a taxel pad in pybullet, with the models that perceive.

    Args:
        actor, xavtnet: loaded :class:`~vtlearn.models.actor.ACTOR` and
            :class:`~vtlearn.models.xavtnet.XAVTNet` (or None to explore only); see
            :meth:`from_checkpoints`.
        class_names: xAVTNet's class names, in label order; default: the names its checkpoint records.
        sensor: taxel preset of the tactile arm's pad.
        image_size: ``(width, height)`` of the RGB-D camera.
        camera_height: height of the overview viewpoint above the target, metres.
        seed: seeds the camera noise and the exploration.

    Use as a context manager (it owns a pybullet connection).
    """

    def __init__(
        self,
        actor=None,
        xavtnet=None,
        class_names: Sequence[str] | None = None,
        *,
        sensor: str = "xela_4x4",
        image_size: tuple[int, int] = (320, 240),
        camera_height: float = 0.6,
        seed: int = 0,
    ):
        if xavtnet is not None and class_names is None:
            class_names = dict(getattr(xavtnet, "hparams", {})).get("class_names")  # newer checkpoints
            if not class_names:
                raise ValueError(
                    "class_names: needed with an xavtnet model whose checkpoint records no class names "
                    "(the label order of its classes; pass the crossmodal manifest.json)"
                )
        if xavtnet is not None:
            class_names = check_class_names(class_names, xavtnet, "class_names")
        camera_height = as_real(camera_height, "camera_height", low=0.2, high=0.9, unit="m")
        self.actor, self.xavtnet = actor, xavtnet
        self.class_names = None if class_names is None else [str(c) for c in class_names]
        self.sensor = sensor
        self.seed = int(seed)
        self.camera_height = float(camera_height)
        self.rng = np.random.default_rng([self.seed, 77])
        self.scene = Scene()
        self.vision_arm = PandaArm(
            self.scene, sensor, T_world_base=_yaw_base(-0.6, 0.0), T_hand_pad=camera_mount()
        )
        self.tactile_arm = PandaArm(self.scene, sensor, T_world_base=_yaw_base(0.6, np.pi))
        self.camera = RGBDCamera(*image_size)
        self.view_feasibility = IKFeasibility(self.vision_arm, camera_mount())
        square = symmetric_rolls(self.tactile_arm.sim.sensor.taxel_positions())
        self.touch_feasibility = IKFeasibility(self.tactile_arm, rolls=square)
        # Decluttering uses both robots (thesis 5.2.2): the vision arm pushes and grasps with its gripper,
        # a contact face at the same 12 cm along the hand as the pad.
        self.manipulation_feasibility = {
            "tactile": self.touch_feasibility,
            "vision": IKFeasibility(self.vision_arm, T_hand_sensor=self.tactile_arm.T_hand_pad, rolls=square),
        }
        self._home = {
            "vision": self.vision_arm.q.copy(),
            "tactile": self.tactile_arm.q.copy(),
        }
        self.sim_objects: dict[int, SimObject] = {}
        self._placed: list[int] = []

    @classmethod
    def from_checkpoints(
        cls, actor_ckpt: str | Path | None, xavtnet_ckpt: str | Path | None, class_names=None, **kwargs
    ) -> TwoArmRuntime:
        """Load the models with ``weights_only=True`` (:func:`~vtlearn.models.actor.load_actor`,
        :func:`~vtlearn.models.xavtnet.load_xavtnet`); ``class_names`` may be a list, or the path of
        a crossmodal dataset's ``manifest.json`` (its ``class_names``)."""
        from vtlearn.datamodules.shards import read_class_names
        from vtlearn.models.actor import load_actor
        from vtlearn.models.xavtnet import load_xavtnet

        if isinstance(class_names, (str, Path)):
            class_names = read_class_names(class_names, "class_names")
        actor = None if actor_ckpt is None else load_named(load_actor, actor_ckpt, "actor_ckpt")
        xav = None if xavtnet_ckpt is None else load_named(load_xavtnet, xavtnet_ckpt, "xavtnet_ckpt")
        return cls(actor, xav, class_names, **kwargs)

    # ------------------------------------------------------------------ lifecycle
    def close(self) -> None:
        self.scene.close()

    def __enter__(self) -> TwoArmRuntime:
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    # ------------------------------------------------------------------ scene
    def add_object(self, obj: SimObject, *, fixed: bool = False, rgba=None) -> int:
        """Put ``obj`` on the table at ``obj.T_world_object``; returns its body id. The target is added
        ``fixed`` (it is touched, not moved); clutter is free, so pushes move it."""
        if not isinstance(obj, SimObject):
            raise ValueError(f"obj: need a SimObject (vtlearn.active.closed_loop), got {type(obj).__name__}")
        colour = rgba if rgba is not None else ((0.7, 0.85, 0.95, 1.0) if obj.transparent else None)
        kw = {} if colour is None else {"rgba": colour}
        body = self.scene.add_mesh(
            obj.mesh, obj.scale_m, obj.T_world_object, fixed=fixed, transparent=obj.transparent, **kw
        )
        self.sim_objects[body] = obj
        return body

    def home(self) -> None:
        """Both arms back to their start poses, out of the camera's way."""
        self.vision_arm.set_joints(self._home["vision"])
        self.tactile_arm.set_joints(self._home["tactile"])

    # ------------------------------------------------------------------ perception
    def overview_pose(self, center_xy=(0.0, 0.0)) -> np.ndarray:
        """``T_world_camera`` of the top-down overview: ``camera_height`` above ``center_xy``, optical axis
        straight down (thesis 5.2.3).

        Raises ``ValueError`` naming ``center_xy`` unless it is two finite numbers (world x, y in metres).

        Shapes:
            center_xy (2,) -> (4, 4)
        """
        T = np.eye(4)
        T[:3, :3] = np.diag([1.0, -1.0, -1.0])
        T[:2, 3] = as_vector(center_xy, "center_xy", 2, "an (x, y) pair of finite numbers in metres")
        T[2, 3] = self.camera_height
        return T

    def observe(self, center_xy=(0.0, 0.0), omega: float = 0.5) -> Observation:
        """Move the vision arm to the overview pose (IK), render RGB-D from the camera pose that forward
        kinematics gives, and split the scene into per-object clouds by the segmentation image.

        Each object's transparency is tested as in thesis 5.2.3: the IoU of its RGB-mask box with the box
        of its pixels whose depth lies above the table, below ``omega``. Both boxes are taken in the
        image, which keeps the perspective of tall objects off the image centre out of the test, and the
        known table plane is cut by height rather than by RANSAC (which removes a can's flat top seen
        from straight above). A body is also called transparent when less than half of its mask has
        plausible depth: a thin glass keeps a few depth points that still span its box. A transparent
        object's cloud is its RGB mask back-projected onto the table plane."""
        from vtlearn.active.selection import box_iou_2d, mask_box, pixel_box_to_plane

        omega = as_real(omega, "omega", low=0.0, high=1.0, open_low=True)
        T_world_view = self.overview_pose(center_xy)
        self.tactile_arm.set_joints(self._home["tactile"])
        q, ok, pos, ang = self.view_feasibility.solve(T_world_view)
        if not ok:
            raise ValueError(
                f"camera_height: the vision arm cannot reach the overview pose "
                f"({pos * 1000:.0f} mm, {ang:.1f} deg off)"
            )
        self.vision_arm.set_joints(q)
        T_world_camera = self.view_feasibility.T_world_sensor(q)
        frame = self.camera.render(self.scene, T_world_camera, self.rng)
        clouds, boxes, ious, clear, valid = {}, {}, {}, {}, {}
        # Pixels whose depth puts them above the (known) table plane: a transparent body's pixels are
        # missing or wrongly deep, below it.
        xyz = np.full((*frame.depth.shape, 3), -np.inf)  # world point of every pixel with depth
        xyz[frame.depth > 0] = backproject(frame.depth, frame.K, T_world_camera)
        above = xyz[..., 2] > 0.002
        for body in self.scene.objects:
            mask = frame.seg == body
            if mask.sum() < 10:
                continue
            box_px = mask_box(mask)
            boxes[body] = pixel_box_to_plane(box_px, frame.K, T_world_camera)
            plausible = mask & above
            pts = xyz[plausible]
            valid[body] = float(plausible.sum()) / float(mask.sum())
            ious[body] = box_iou_2d(mask_box(plausible), box_px) if plausible.sum() >= 10 else 0.0
            clear[body] = bool(ious[body] < omega or valid[body] < 0.5)
            # The footprint comes from depth where most of the mask has plausible depth, else from the
            # RGB mask on the table plane (what a transparent body leaves usable).
            clouds[body] = pts if valid[body] >= 0.5 else _mask_on_plane(mask, frame.K, T_world_camera)
        return Observation(frame, clouds, boxes, ious, clear, valid)

    # ------------------------------------------------------------------ decluttering
    def place_position(self, k: int) -> np.ndarray:
        """The ``k``-th place position of grasped objects: beside the table centre on +-y, outside the
        overview camera's field of view and within the tactile arm's reach."""
        side = 1.0 if k % 2 == 0 else -1.0
        return np.array([0.25 - 0.12 * (k // 2), side * 0.45, 0.0])

    def declutter(
        self,
        target: int,
        max_actions: int = 8,
        *,
        policy: str = "graph",
        figure: str | Path | None = None,
        progress: Callable[[int, int], None] | None = None,
        **graph_kwargs,
    ) -> tuple[list[dict], bool]:
        """Singulate ``target`` (thesis 5.2.2): observe, build the declutter graph, execute its next
        action (grasp-and-place, or push), and repeat until the root has no children or
        ``max_actions`` actions were executed.

        Args:
            policy: which object to act on. ``"graph"`` is the thesis: the leaf reached by depth-first
                descent (:meth:`~vtlearn.runtime.declutter.DeclutterGraph.next_action`). The baselines
                of ``vtlearn bench declutter`` use the same graph, actions and stopping rule but pick
                differently: ``"nearest"`` acts on the heaviest child of the target (the nearest
                clutter, whatever clutters it in turn), ``"random"`` on a random object of the graph.
                An object whose action neither arm reached is passed over (the descent takes the next
                heaviest branch) until an action succeeds; when nothing is left, decluttering stops.
            figure: save the first graph there (:meth:`~vtlearn.runtime.declutter.DeclutterGraph.figure`).
            progress: ``progress(done, max_actions)`` after every executed action.
            graph_kwargs: passed to :meth:`~vtlearn.runtime.declutter.DeclutterGraph.build`.

        Returns:
            the executed actions (JSON records) and whether decluttering finished.
        """
        from vtlearn.runtime.declutter import DeclutterGraph

        if target not in self.scene.objects:
            raise ValueError(f"target: {target} is not an object of the scene")
        max_actions = as_int(max_actions, "max_actions", minimum=0)
        if policy not in DECLUTTER_POLICIES:
            raise ValueError(f"policy: expected one of {DECLUTTER_POLICIES}, got {policy!r}")
        rng = np.random.default_rng([self.seed, 31])
        if "place_position" in graph_kwargs:
            raise ValueError("graph_kwargs: the runtime chooses place positions (see place_position)")
        done_actions: list[dict] = []
        blocked: set[int] = set()
        center = self.scene.T_world_object(target)[:2, 3]
        for i in range(int(max_actions) + 1):
            obs = self.observe(center)
            if target not in obs.clouds:
                raise ValueError(f"target: body {target} is not visible to the overview camera")
            graph = DeclutterGraph.build(
                obs.clouds, target, place_position=self.place_position(len(self._placed)), **graph_kwargs
            )
            if i == 0 and figure is not None:
                graph.figure(figure)
            if graph.is_done:
                return done_actions, True
            edge = _choose_edge(graph, target, policy, blocked, rng)
            if edge is None or len(done_actions) == int(max_actions):
                break  # every candidate is out of both arms' reach, or the budget is spent
            done_actions.append(self._execute(edge.action))
            if progress is not None:
                progress(len(done_actions), int(max_actions))
            # An object that no arm reached is passed over until something in the scene has moved.
            if done_actions[-1]["reachable"]:
                blocked.clear()
            else:
                blocked.add(edge.child)
        return done_actions, False

    def _reach(self, T_world_sensor: np.ndarray) -> tuple[str | None, np.ndarray | None]:
        """The first arm (tactile, then vision) whose IK reaches ``T_world_sensor``, and its joints."""
        for name, feasibility in self.manipulation_feasibility.items():
            q, ok, _, _ = feasibility.solve(T_world_sensor)
            if ok:
                feasibility.arm.set_joints(q)
                return name, q
        return None, None

    def _execute(self, action) -> dict:
        """Carry out one declutter action with whichever arm reaches it; returns its JSON record with
        ``arm`` (None when neither reaches), ``reachable`` and ``moved_m``."""
        record = dict(action.to_dict())
        body = int(action.object_id)
        before = self.scene.T_world_object(body)
        if action.kind == "grasp":
            T_pre = np.eye(4)  # the hand straight down over the grasp point, 5 cm above it
            T_pre[:3, :3] = np.diag([1.0, -1.0, -1.0])
            T_pre[:3, 3] = np.asarray(action.p_grasp, dtype=np.float64) + [0.0, 0.0, 0.05]
            arm, _ = self._reach(T_pre)
            if arm is not None:
                xyz = np.asarray(action.p_place, dtype=np.float64).copy()
                xyz[2] = before[2, 3] + 0.002  # the object keeps its height above the table
                orn = p.getBasePositionAndOrientation(body, physicsClientId=self.scene.client)[1]
                p.resetBasePositionAndOrientation(body, xyz.tolist(), orn, physicsClientId=self.scene.client)
                self._placed.append(body)
                self.scene.step(60)
        else:
            # The pad (3 cm) at mid height of the body, but its lower edge clear of the table.
            lo, hi = np.asarray(p.getAABB(body, physicsClientId=self.scene.client))[:, 2]
            point = np.asarray(action.p_push, dtype=np.float64).copy()
            point[2] = max((lo + hi) / 2, 0.017)
            T_W_S = sensor_frame(point, action.d_push)
            arm, _ = self._reach(T_W_S)
            if arm is not None:
                pusher = GoalPusher(self.scene, body)
                try:
                    contact, lost, pushed = pusher.push(T_W_S, float(action.distance))
                finally:
                    pusher.close()
                record.update(contact=bool(contact), contact_lost=bool(lost), pushed_m=float(pushed))
        record.update(arm=arm, reachable=arm is not None)
        self.home()
        after = self.scene.T_world_object(body)
        record["moved_m"] = float(np.linalg.norm(after[:2, 3] - before[:2, 3]))
        return record

    # ------------------------------------------------------------------ articulation (thesis ch.6)
    def detect_articulation(
        self,
        spec,
        T_world_base: np.ndarray,
        q=None,
        *,
        tracker: str = "artreg",
        max_actions: int = 12,
        seed: int = 0,
    ) -> dict:
        """Interactive articulation detection by the two robots (thesis 6.2.2, Fig. 6.3).

        The articulated object ``spec`` (:mod:`vtlearn.sim_data.articulated`) is put on the table at
        ``T_world_base`` with normalised joint values ``q``. Every action of
        :func:`~vtlearn.runtime.articulation.detect_articulation` must be reachable before it is done:
        a push by either arm, and a hold-pull as in the thesis, the hold by the vision arm (the Panda
        with the camera) and the pull by the tactile arm. The motion itself is the object's true
        kinematics (:class:`~vtlearn.runtime.articulation.KinematicArticulationSim`); with
        ``tracker="artreg"`` the part poses are tracked by ArtReg from a depth camera
        (:class:`~vtlearn.runtime.articulation.TrackedArticulationSim`), with ``"truth"`` they are exact.

        Args:
            spec: the object, :func:`~vtlearn.sim_data.articulated.make_articulated`.
            T_world_base: pose of its base link in the world (metres, table top at z = 0); within
                1.5 m of the table centre, where the arms stand.
            q: normalised joint values in [0, 1] (default all 0).
            tracker: ``"artreg"`` or ``"truth"``.
            max_actions: stop after this many actions.
            seed: seeds the object's model clouds and the tracker's camera.

        Shapes:
            T_world_base ``(4, 4)``; q ``(J,)`` for the object's J joints.

        The object leaves the scene again on return, and also when an argument is refused.

        Returns:
            ``{"joint_type", "explored", "n_actions", "actions": [{"kind", "arms"}], "unreachable":
            the action no arm could do (None when every action was reachable), "result":
            ArticulationResult or None}``. Detection stops at an unreachable action.
        """
        from vtlearn.runtime.articulation import (
            HoldPullAction,
            KinematicArticulationSim,
            TrackedArticulationSim,
        )
        from vtlearn.runtime.articulation import detect_articulation as detect
        from vtlearn.sim_data.articulated import ArticulatedObject, ArticulatedSpec
        from vtlearn.sim_data.tactile import pad_frame

        if not isinstance(spec, ArticulatedSpec):
            raise ValueError(
                f"spec: need an ArticulatedSpec (vtlearn.sim_data.articulated.make_articulated), "
                f"got {type(spec).__name__}"
            )
        if tracker not in ("artreg", "truth"):
            raise ValueError(f"tracker: expected 'artreg' or 'truth', got {tracker!r}")
        max_actions = as_int(max_actions, "max_actions")
        T_world_base = as_transform(T_world_base, "T_world_base")
        off = float(np.linalg.norm(T_world_base[:3, 3]))
        if off > _TABLE_REACH_M:
            raise ValueError(
                f"T_world_base: puts the object {off:.4g} m from the table centre, beyond the "
                f"{_TABLE_REACH_M} m that the two arms span; vtlearn reads metres (a translation in "
                "millimetres?)"
            )
        obj = ArticulatedObject(self.scene, spec, n_model_points=0.01, seed=seed)
        done: list[dict] = []

        def execute(action) -> None:
            if isinstance(action, HoldPullAction):
                hold = self.manipulation_feasibility["vision"].solve(
                    pad_frame(action.hold.point, action.hold.direction)
                )[1]
                pull = self.manipulation_feasibility["tactile"].solve(
                    pad_frame(action.pull.point, action.pull.direction)
                )[1]
                arms = ["vision" if hold else None, "tactile" if pull else None]
            else:
                arms = [self._reach(pad_frame(action.point, action.direction))[0]]
            self.home()
            done.append({"kind": action.kind, "arms": arms})
            if None in arms:
                raise _Unreachable(action.kind)
            world.execute(action)

        try:  # from here on, whatever is raised (a bad q among them), the object leaves the scene again
            sim = KinematicArticulationSim(obj, T_world_base, q)
            world = TrackedArticulationSim(sim, seed=seed) if tracker == "artreg" else sim
            res = detect(world.observe, execute, max_actions=max_actions)
        except _Unreachable:
            res = None
        finally:
            p.removeBody(obj.body, physicsClientId=self.scene.client)  # the object is not a Scene mesh
        return {
            "joint_type": None if res is None else res.joint_type,
            "explored": False if res is None else bool(res.explored),
            "n_actions": len(done),
            "actions": done,
            "unreachable": None if res is not None else done[-1]["kind"],
            "result": res,
        }

    # ------------------------------------------------------------------ exploration
    def explore(
        self,
        target: int,
        n_touches: int = 20,
        *,
        n_views: int = 0,
        strategy: str = "active",
        n_candidates: int = 60,
        cells: int = 32,
        gain_mode: str = "auto",
        progress: Callable[[int, int], None] | None = None,
    ) -> tuple[Episode, ArmTouchWorld]:
        """Next-best touches (and views) on the target by the tactile (and vision) arm, each candidate
        checked by IK (:func:`~vtlearn.active.closed_loop.run_episode` with ``feasible``).

        ``gain_mode="auto"`` (:func:`~vtlearn.active.closed_loop.run_episode`) scores touch-only episodes
        (a transparent target: no views) by the box-fit criterion of
        :mod:`vtlearn.active.reconstruction_nbt` when an ACTOR is loaded, and everything else by the
        probabilistic grid gain. Any :data:`~vtlearn.active.closed_loop.GAIN_MODES` value is passed on."""
        if target not in self.sim_objects or not self.scene.objects[target].fixed:
            raise ValueError(f"target: {target} must be an object added with fixed=True")
        strategy, n_touches = _check_exploration(strategy, n_touches)
        if gain_mode == "box_fit" and self.actor is None:
            raise ValueError("gain_mode: 'box_fit' needs the runtime's ACTOR (load models first)")
        reconstructor = None
        if gain_mode in ("auto", "box_fit") and self.actor is not None:
            from vtlearn.active.reconstruction_nbt import ExpectedBoxFitGain

            reconstructor = ExpectedBoxFitGain(self.actor)  # "auto": used by touch-only episodes only
        world = ArmTouchWorld(self, self.sim_objects[target], target)
        feasible: Mapping[str, Callable] = {"touch": self.touch_feasibility, "view": self.view_feasibility}
        ep = run_episode(
            world,
            strategy,
            n_touches,
            n_views=n_views,
            pinch=False,
            n_candidates=n_candidates,
            cells=cells,
            gain_mode=gain_mode,
            seed=self.seed,
            progress=progress,
            feasible=feasible,
            reconstructor=reconstructor,
        )
        self.home()
        return ep, world

    def run(
        self,
        target: int,
        *,
        strategy: str = "active",
        n_touches: int = 20,
        max_declutter_actions: int = 8,
        n_candidates: int = 60,
        cells: int = 32,
        stiqf_restarts: int = 4,
        declutter_figure: str | Path | None = None,
        progress: Callable[[int, int], None] | None = None,
        declutter_progress: Callable[[int, int], None] | None = None,
    ) -> RuntimeReport:
        """Declutter, then explore, then perceive (thesis Fig. 5.2, a-c). Perception needs both models;
        without them the report stops after exploration.

        Args:
            target: body id of the target, added with ``fixed=True`` (:meth:`add_object`).
            strategy: touch selection, one of :data:`~vtlearn.active.closed_loop.TOUCH_STRATEGIES`
                (``"active"``: expected information gain, eq. 5.6-5.10; the tactile arm has no pinch).
            n_touches: touch budget (>= 1); an opaque target also gets 3 views.
            max_declutter_actions: declutter action limit (:meth:`declutter`).
            n_candidates, cells: candidates per active step and occupancy-grid cells per side.
            stiqf_restarts: S-TIQF restarts of the pose estimate (5.2.4).
            declutter_figure: save the first declutter graph there.
            progress: ``progress(done, total)`` after every exploration action.
            declutter_progress: ``declutter_progress(done, max_declutter_actions)`` after every declutter
                action.

        Every argument is checked before the arms move: a bad ``strategy`` or ``n_touches`` raises a
        ``ValueError`` naming it, not after decluttering.
        """
        if target not in self.sim_objects or not self.scene.objects[target].fixed:
            raise ValueError(f"target: {target} must be an object added with fixed=True")
        _check_exploration(strategy, n_touches)
        report = RuntimeReport()
        t0 = time.perf_counter()
        report.declutter_actions, report.declutter_done = self.declutter(
            target, max_declutter_actions, figure=declutter_figure, progress=declutter_progress
        )
        obs = self.observe(self.scene.T_world_object(target)[:2, 3])
        report.transparent_detected = bool(obs.transparent.get(target, False))
        report.seconds["declutter"] = round(time.perf_counter() - t0, 2)
        return self.explore_and_perceive(
            target,
            report,
            strategy=strategy,
            n_touches=n_touches,
            n_candidates=n_candidates,
            cells=cells,
            stiqf_restarts=stiqf_restarts,
            progress=progress,
        )

    def explore_and_perceive(
        self,
        target: int,
        report: RuntimeReport,
        *,
        strategy: str = "active",
        n_touches: int = 20,
        n_candidates: int = 60,
        cells: int = 32,
        stiqf_restarts: int = 4,
        progress: Callable[[int, int], None] | None = None,
    ) -> RuntimeReport:
        """Explore the (decluttered) target with ``strategy`` and perceive it; returns a new report with the
        declutter fields of ``report`` (so several strategies can follow one decluttering). An opaque
        target (as detected) is seen from 3 views as well as touched (thesis Fig. 5.13); a transparent
        one only touched, because its views return no depth."""
        from vtlearn.pipeline import perceive_object

        out = RuntimeReport(
            declutter_actions=list(report.declutter_actions),
            declutter_done=report.declutter_done,
            transparent_detected=report.transparent_detected,
            seconds={k: v for k, v in report.seconds.items() if k == "declutter"},
        )
        t0 = time.perf_counter()
        queries0 = self.touch_feasibility.queries + self.view_feasibility.queries
        n_views = 0 if out.transparent_detected else 3
        out.episode, world = self.explore(
            target,
            n_touches,
            n_views=n_views,
            strategy=strategy,
            n_candidates=n_candidates,
            cells=cells,
            progress=progress,
        )
        out.unreached_touches = world.unreached
        out.ik_queries = self.touch_feasibility.queries + self.view_feasibility.queries - queries0
        out.seconds["explore"] = round(time.perf_counter() - t0, 2)
        if self.actor is not None and self.xavtnet is not None:
            t0 = time.perf_counter()
            try:
                out.perception, out.arrays = perceive_object(
                    self.actor,
                    self.xavtnet,
                    self.class_names,
                    self.sim_objects[target],
                    out.episode,
                    seed=self.seed,
                    stiqf_restarts=stiqf_restarts,
                )
            except ValueError as exc:  # too few contacts to reconstruct: a failed trial, not a crash
                out.perception_error = str(exc)
            out.perception.pop("actions", None)  # the episode's kinds are in out.episode
            out.seconds["perceive"] = round(time.perf_counter() - t0, 2)
        return out


def _check_exploration(strategy: str, n_touches: int) -> tuple[str, int]:
    """``strategy`` and ``n_touches`` of an arm-carried exploration, checked (ValueError naming them)."""
    from vtlearn.active.closed_loop import TOUCH_STRATEGIES

    if strategy not in TOUCH_STRATEGIES:
        raise ValueError(
            f"strategy: expected one of {TOUCH_STRATEGIES} (the tactile arm carries one pad, no pinch), "
            f"got {strategy!r}"
        )
    return strategy, as_int(n_touches, "n_touches")


class _Unreachable(Exception):
    """An articulation action that neither arm reaches; ends :meth:`TwoArmRuntime.detect_articulation`."""


def _choose_edge(graph, target: int, policy: str, blocked: set[int], rng: np.random.Generator):
    """The edge whose action ``policy`` takes next, passing over the ``blocked`` objects: for ``"graph"``
    the depth-first descent along the heaviest children (thesis 5.2.2); None when nothing is left."""
    if policy == "graph":
        edge, v = None, target
        while kids := [e for e in graph.children(v) if e.child not in blocked]:
            edge, v = kids[0], kids[0].child
        return edge
    if policy == "nearest":
        kids = [e for e in graph.children(target) if e.child not in blocked]
        return kids[0] if kids else None
    edges = [e for e in graph.edges if e.child not in blocked]
    return edges[int(rng.integers(len(edges)))] if edges else None


def clutter_scene(
    target_category: str = "wineglass",
    clutter_categories: Sequence[str] = ("can", "box", "bowl"),
    *,
    transparent: bool | None = True,
    gap: float = 0.008,
    chain: bool = True,
    seed: int = 0,
    sections: int = 24,
) -> tuple[SimObject, list[SimObject]]:
    """An unseen target among clutter (thesis 5.3, Fig. 5.1): held-out instances, the target at the
    table centre and one clutter object per category of ``clutter_categories`` around it, ``gap``
    metres from the target's footprint at evenly spaced bearings (random offset). With ``chain`` the
    last clutter object stands behind the first one instead, so that it clutters the clutter (a
    two-level declutter graph).

    Returns the target (its ``T_world_object`` at the origin) and the clutter objects, placed.
    """
    from vtlearn.active.closed_loop import HELD_OUT_SEED, held_out_objects
    from vtlearn.sim_data.shapes import CATEGORIES

    cats = [str(c) for c in clutter_categories]
    if target_category not in CATEGORIES:
        raise ValueError(f"target_category: unknown {target_category!r}, expected one of {CATEGORIES}")
    unknown = [c for c in cats if c not in CATEGORIES]
    if unknown:
        raise ValueError(f"clutter_categories: unknown {unknown}, expected some of {CATEGORIES}")
    if target_category in cats:
        raise ValueError(
            f"clutter_categories: hold the target category {target_category!r}; the clutter must differ "
            "from the target (thesis 5.2.2)"
        )
    gap = as_real(gap, "gap", low=0.0, unit="m")
    target = held_out_objects([target_category], 1, transparent=transparent, sections=sections)[0]
    rng = np.random.default_rng([int(seed), 4242])
    clutter = [
        held_out_objects(
            [c], 1, transparent=False, base_seed=HELD_OUT_SEED + 17 * int(seed) + i, sections=sections
        )[0]
        for i, c in enumerate(cats)
    ]

    def reach(o: SimObject, u: np.ndarray) -> float:
        """How far the footprint of ``o`` extends from its box centre along ``u`` (support function)."""
        return float(((o.surface_world[:, :2] - o.bounds.mean(0)[:2]) @ u).max())

    def centre_at(o: SimObject, xy: np.ndarray) -> None:
        shift = np.r_[xy - o.bounds.mean(0)[:2], 0.0]
        o.T_world_object = o.T_world_object.copy()
        o.T_world_object[:3, 3] += shift
        o.surface_world = o.surface_world + shift

    def beside(o: SimObject, anchor: SimObject, u: np.ndarray) -> None:
        """Put ``o`` on the ``u`` side of ``anchor``, their footprints ``gap`` apart along ``u``."""
        centre_at(o, anchor.bounds.mean(0)[:2] + (reach(anchor, u) + reach(o, -u) + gap) * u)

    centre_at(target, np.zeros(2))
    n_ring = len(clutter) - 1 if chain and len(clutter) > 1 else len(clutter)
    phase = rng.uniform(0, 2 * np.pi)
    bearings = []
    for i, o in enumerate(clutter[:n_ring]):
        a = phase + 2 * np.pi * i / max(n_ring, 1)
        bearings.append(np.array([np.cos(a), np.sin(a)]))
        beside(o, target, bearings[-1])
    if n_ring < len(clutter):
        beside(clutter[-1], clutter[0], bearings[0])
    return target, clutter


def _mask_on_plane(mask: np.ndarray, K: np.ndarray, T_world_camera: np.ndarray, plane_z: float = 0.0):
    """The pixel centres of ``mask`` back-projected along their rays onto the plane ``z = plane_z``.

    Shapes:
        mask (H, W) bool -> (M, 3) world metres, M ≤ mask.sum() (rays that miss the plane dropped)
    """
    from vtlearn.active.selection import pixels_to_plane

    v, u = np.nonzero(mask)
    points, valid = pixels_to_plane(np.column_stack([u, v]) + 0.5, K, T_world_camera, plane_z)
    return points[valid]


def save_report(report: RuntimeReport, out: str | Path) -> Path:
    """Write ``runtime.json`` into ``out`` atomically (:func:`vtlearn.bench_utils.write_json`)."""
    from vtlearn.bench_utils import write_json

    return write_json(Path(out) / "runtime.json", report.to_dict())
