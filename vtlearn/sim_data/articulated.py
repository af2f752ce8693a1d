"""Procedural articulated objects and tracking sequences in pybullet (thesis ch.6, 6.3.4-6.3.5 analogue).

The thesis benchmarks ArtReg on PartNet-Mobility objects (dishwasher, glasses, drawer, blade) seen by a
simulated depth camera at a 45 deg top-down view, and on tracking sequences of single, multiple (3-7)
and articulated objects (Table 6.2). PartNet-Mobility cannot be downloaded here, so the four categories
are generated procedurally as URDFs built from boxes, with random dimensions:

- ``dishwasher``: open-front cabinet + door on a revolute hinge at its bottom front edge (0..80 deg);
- ``glasses``: frame (bar, lenses, bridge) + two temples on revolute hinges about z (fold 0..90 deg);
- ``drawer``: open-front cabinet + drawer (box with front plate and handle) on a prismatic joint
  along -y (0..75 % of the depth);
- ``blade``: handle + blade on a prismatic joint along +x (0..85 % of the blade length).

Joint values are given normalised to [0, 1] of those ranges, as in the thesis. Link model clouds are
sampled area-uniformly from each link's box mesh (in the URDF link frame). Poses are kinematic
(``resetBasePositionAndOrientation`` / ``resetJointState``): the benchmark measures tracking, not
contact dynamics. The pushing probe is a small sphere placed against the pushed object on the side
opposite to its motion; its contact points (pybullet ``getClosestPoints``) are the tactile points, and
its pixels are removed from the camera cloud, as a robot's self-filter would.

Depth images come from :class:`vtlearn.sim_data.camera.RGBDCamera` (TinyRenderer, Kinect-like noise);
the table is removed by its segmentation id (an exact plane removal, so the benchmark isolates the
trackers; :mod:`vtlearn.classical.segmentation` does it by RANSAC on real data).

Shapes:
    ArticulatedObject.models: list of (K, 3) link clouds in the link frames.
    TrackingSequence.scenes[k]: (M_k, 3) world points; tactile[k]: (T_k, 3) or None;
    T_world_part[k]: (N, 4, 4) ground-truth part poses (T_world_link).
"""

from __future__ import annotations

import os
import tempfile
from dataclasses import dataclass, field

import numpy as np
import pybullet as p
import trimesh

from vtlearn.geometry.sampling import sample_surface
from vtlearn.sim_data.camera import DepthNoise, RGBDCamera
from vtlearn.sim_data.scene import Scene, pose_to_matrix
from vtlearn.validation import as_int, as_real, as_transform, as_vector

__all__ = [
    "CATEGORIES",
    "Box",
    "LinkSpec",
    "ArticulatedSpec",
    "make_articulated",
    "make_rigid",
    "to_urdf",
    "ArticulatedObject",
    "TrackingSequence",
    "look_at_45",
    "render_cloud",
    "articulation_sequence",
    "motion_sequence",
]

CATEGORIES = ("dishwasher", "glasses", "drawer", "blade")


@dataclass
class Box:
    """A box of a link: ``half`` extents (m), centre ``xyz`` and roll-pitch-yaw ``rpy`` in the link frame.

    ``half`` is 3 finite positive numbers, ``xyz`` and ``rpy`` 3 finite numbers each (``ValueError``).
    """

    half: tuple[float, float, float]
    xyz: tuple[float, float, float] = (0.0, 0.0, 0.0)
    rpy: tuple[float, float, float] = (0.0, 0.0, 0.0)

    def __post_init__(self):
        for name in ("half", "xyz", "rpy"):
            a = as_vector(getattr(self, name), name, 3)
            if name == "half" and not (a > 0).all():
                raise ValueError(f"half: need positive half extents, got {self.half!r}")

    def mesh(self) -> trimesh.Trimesh:
        m = trimesh.creation.box(extents=2 * np.asarray(self.half))
        T = trimesh.transformations.euler_matrix(*self.rpy, axes="sxyz")
        T[:3, 3] = self.xyz
        m.apply_transform(T)
        return m


@dataclass
class LinkSpec:
    """One link: its boxes and colour; for a child link also the joint from the base link."""

    name: str
    boxes: list[Box]
    rgba: tuple[float, float, float, float]
    joint_type: str = "fixed"  # "revolute" | "prismatic" for child links
    joint_xyz: tuple[float, float, float] = (0.0, 0.0, 0.0)  # joint origin in the base link frame
    axis: tuple[float, float, float] = (1.0, 0.0, 0.0)
    lower: float = 0.0
    upper: float = 0.0

    def mesh(self) -> trimesh.Trimesh:
        return trimesh.util.concatenate([b.mesh() for b in self.boxes])


@dataclass
class ArticulatedSpec:
    """A base link and child links (each jointed to the base)."""

    category: str
    links: list[LinkSpec]

    @property
    def n_joints(self) -> int:
        return len(self.links) - 1


def _u(rng: np.random.Generator, lo: float, hi: float) -> float:
    return float(rng.uniform(lo, hi))


def _colour(rng: np.random.Generator) -> tuple[float, float, float, float]:
    return (*(float(c) for c in rng.uniform(0.15, 0.95, size=3)), 1.0)


def _cabinet(W: float, D: float, H: float, t: float) -> list[Box]:
    """Open-front cabinet (front is -y), base-link origin at the bottom centre."""
    return [
        Box((W / 2, D / 2, t / 2), (0, 0, t / 2)),  # bottom
        Box((W / 2, D / 2, t / 2), (0, 0, H - t / 2)),  # top
        Box((t / 2, D / 2, H / 2), (-W / 2 + t / 2, 0, H / 2)),  # left
        Box((t / 2, D / 2, H / 2), (W / 2 - t / 2, 0, H / 2)),  # right
        Box((W / 2, t / 2, H / 2), (0, D / 2 - t / 2, H / 2)),  # back
    ]


def make_articulated(category: str, rng: np.random.Generator | int | None = None) -> ArticulatedSpec:
    """A random instance of one of :data:`CATEGORIES` (dimensions in metres)."""
    if category not in CATEGORIES:
        raise ValueError(f"category: expected one of {CATEGORIES}, got {category!r}")
    rng = np.random.default_rng(rng)
    c_base, c_part = _colour(rng), _colour(rng)
    while np.linalg.norm(np.subtract(c_base[:3], c_part[:3])) < 0.3:  # parts distinguishable by colour
        c_part = _colour(rng)
    if category == "dishwasher":
        W, D, H, t = _u(rng, 0.25, 0.4), _u(rng, 0.25, 0.35), _u(rng, 0.25, 0.4), 0.012
        base = LinkSpec("body", _cabinet(W, D, H, t), c_base)
        door = LinkSpec(
            "door",
            [
                Box((W / 2, t / 2, H / 2 - t / 2), (0, -t / 2, H / 2 - t / 2)),
                Box((W / 4, 0.01, 0.008), (0, -t - 0.01, H - 0.04)),
            ],
            c_part,
            "revolute",
            (0, -D / 2, t),
            (1, 0, 0),
            0.0,
            np.deg2rad(80),
        )
        return ArticulatedSpec(category, [base, door])
    if category == "glasses":
        w, h, t = _u(rng, 0.12, 0.15), _u(rng, 0.035, 0.05), 0.004
        L = _u(rng, 0.11, 0.14)
        lens = w / 2 - 0.012
        frame = LinkSpec(
            "frame",
            [
                Box((w / 2, t, 0.005), (0, 0, h)),  # top bar
                Box((lens / 2, t / 2, h / 2 - 0.004), (-w / 4 - 0.003, 0, h / 2)),
                Box((lens / 2, t / 2, h / 2 - 0.004), (w / 4 + 0.003, 0, h / 2)),
                Box((0.008, t, 0.004), (0, 0, h * 0.6)),  # bridge
            ],
            c_base,
        )
        temples = [
            LinkSpec(
                name,
                [Box((0.004, L / 2, 0.004), (0, L / 2, 0))],
                c_part,
                "revolute",
                (sx * (w / 2 - 0.004), 0, h),
                (0, 0, sx),
                0.0,
                np.deg2rad(90),
            )
            for name, sx in (("temple_left", -1.0), ("temple_right", 1.0))
        ]
        # a positive angle about +-z folds each temple towards the centre, behind the lenses
        return ArticulatedSpec(category, [frame, *temples])
    if category == "drawer":
        W, D, H, t = _u(rng, 0.25, 0.4), _u(rng, 0.25, 0.35), _u(rng, 0.12, 0.22), 0.012
        base = LinkSpec("cabinet", _cabinet(W, D, H, t), c_base)
        w, d, h = W - 2 * t - 0.004, D - t - 0.01, H - 2 * t - 0.01
        drawer = LinkSpec(
            "drawer",
            [
                Box((W / 2, t / 2, H / 2), (0, -t / 2, H / 2 - t)),  # front plate
                Box((w / 2, d / 2, t / 2), (0, d / 2, t / 2)),  # bottom
                Box((t / 2, d / 2, h / 2), (-w / 2 + t / 2, d / 2, h / 2)),
                Box((t / 2, d / 2, h / 2), (w / 2 - t / 2, d / 2, h / 2)),
                Box((w / 2, t / 2, h / 2), (0, d - t / 2, h / 2)),
                Box((W / 6, 0.012, 0.01), (0, -t - 0.012, H / 2 - t)),  # handle
            ],
            c_part,
            "prismatic",
            (0, -D / 2, t),
            (0, -1, 0),
            0.0,
            0.75 * D,
        )
        return ArticulatedSpec(category, [base, drawer])
    # blade
    Lh, Wh, Hh = _u(rng, 0.09, 0.13), _u(rng, 0.022, 0.03), _u(rng, 0.014, 0.02)
    Lb, Wb = _u(rng, 0.07, 0.1), Wh * 0.7
    handle = LinkSpec("handle", [Box((Lh / 2, Wh / 2, Hh / 2), (0, 0, Hh / 2))], c_base)
    blade = LinkSpec(
        "blade",
        [Box((Lb / 2, Wb / 2, 0.0015), (-Lb / 2, 0, 0))],
        c_part,
        "prismatic",
        (Lh / 2, 0, Hh + 0.0015),
        (1, 0, 0),
        0.0,
        0.85 * Lb,
    )
    return ArticulatedSpec("blade", [handle, blade])


def make_rigid(rng: np.random.Generator | int | None = None, kind: str | None = None) -> ArticulatedSpec:
    """A single rigid box-built object (box, L-shape or T-shape; 5-14 cm) for the tracking sequences."""
    rng = np.random.default_rng(rng)
    kind = kind or str(rng.choice(["box", "L", "T"]))
    a, b, c = _u(rng, 0.05, 0.12), _u(rng, 0.04, 0.09), _u(rng, 0.04, 0.1)
    if kind == "box":
        boxes = [Box((a / 2, b / 2, c / 2), (0, 0, c / 2))]
    elif kind == "L":
        boxes = [
            Box((a / 2, b / 4, c / 2), (0, -b / 4, c / 2)),
            Box((a / 4, b / 4, c / 2), (-a / 4, b / 4, c / 2)),
        ]
    elif kind == "T":
        boxes = [
            Box((a / 2, b / 4, c / 2), (0, -b / 4, c / 2)),
            Box((a / 6, b / 4, c / 2), (0, b / 4, c / 2)),
        ]
    else:
        raise ValueError(f"kind: expected 'box', 'L' or 'T', got {kind!r}")
    return ArticulatedSpec("rigid", [LinkSpec(kind, boxes, _colour(rng))])


def _fmt(v) -> str:
    return " ".join(f"{float(x):.6g}" for x in v)


def to_urdf(spec: ArticulatedSpec) -> str:
    """URDF text of ``spec``: box visuals and colliders, each child jointed to the base link."""
    out = [f'<?xml version="1.0"?>\n<robot name="{spec.category}">']
    for i, link in enumerate(spec.links):
        out.append(f'  <link name="{link.name}">')
        # identity inertial origin: pybullet's base frame then equals the URDF base-link frame
        out.append(
            '    <inertial><origin xyz="0 0 0"/><mass value="0.5"/>'
            '<inertia ixx="1e-3" iyy="1e-3" izz="1e-3" ixy="0" ixz="0" iyz="0"/></inertial>'
        )
        for b in link.boxes:
            size = _fmt(2 * np.asarray(b.half))
            geo = (
                f'<origin xyz="{_fmt(b.xyz)}" rpy="{_fmt(b.rpy)}"/><geometry><box size="{size}"/></geometry>'
            )
            out.append(
                f'    <visual>{geo}<material name="m{i}">'
                f'<color rgba="{_fmt(link.rgba)}"/></material></visual>'
            )
            out.append(f"    <collision>{geo}</collision>")
        out.append("  </link>")
    base = spec.links[0].name
    for link in spec.links[1:]:
        out.append(
            f'  <joint name="{link.name}_joint" type="{link.joint_type}"><parent link="{base}"/>'
            f'<child link="{link.name}"/><origin xyz="{_fmt(link.joint_xyz)}"/>'
            f'<axis xyz="{_fmt(link.axis)}"/>'
            f'<limit lower="{link.lower}" upper="{link.upper}" effort="10" velocity="1"/></joint>'
        )
    out.append("</robot>\n")
    return "\n".join(out)


def _n_points(mesh: trimesh.Trimesh, n_model_points: int | float) -> int:
    """An int is a fixed count (>= 1); a float is a spacing in metres (finite, > 0): area / spacing^2 points,
    in [500, 20000]. ``ValueError`` naming ``n_model_points`` otherwise (a bool or a string included)."""
    if isinstance(n_model_points, (int, np.integer)) and not isinstance(n_model_points, bool):
        return as_int(n_model_points, "n_model_points")
    spacing = as_real(n_model_points, "n_model_points", low=0.0, open_low=True, unit="m")
    return int(np.clip(mesh.area / spacing**2, 500, 20000))


class ArticulatedObject:
    """An :class:`ArticulatedSpec` loaded into a :class:`Scene` (fixed base, kinematic joints).

    Args:
        scene: the pybullet scene.
        spec: the object.
        n_model_points: points sampled on each link mesh for the link model clouds: an int is a
            count per link, a float a target spacing in metres (area / spacing^2 points, 500..20000).
        seed: seed of the model sampling.
    """

    def __init__(
        self, scene: Scene, spec: ArticulatedSpec, n_model_points: int | float = 0.005, seed: int = 0
    ):
        self.scene, self.spec = scene, spec
        counts = [_n_points(link.mesh(), n_model_points) for link in spec.links]  # checked before loading
        fd, path = tempfile.mkstemp(suffix=".urdf")
        try:
            with os.fdopen(fd, "w") as fh:
                fh.write(to_urdf(spec))
            self.body = p.loadURDF(path, useFixedBase=True, physicsClientId=scene.client)
        finally:
            os.unlink(path)
        self.models = [
            sample_surface(link.mesh(), n, seed=seed + i)[0]
            for i, (link, n) in enumerate(zip(spec.links, counts, strict=True))
        ]

    @property
    def n_parts(self) -> int:
        return len(self.spec.links)

    def set_state(self, T_world_base: np.ndarray, q: np.ndarray | None = None) -> None:
        """Place the base at ``T_world_base`` and set the joints from normalised values ``q`` in [0, 1].

        ``T_world_base`` must be a finite rigid transform and ``q`` (when given) ``n_joints`` finite values
        in [0, 1]; both are checked before anything moves (``ValueError`` naming the argument).

        Shapes:
            T_world_base (4, 4); q (n_joints,)
        """
        from vtlearn.sim_data.scene import matrix_to_xyzw

        T_world_base = as_transform(T_world_base, "T_world_base")
        if q is not None:
            q = np.asarray(q, dtype=np.float64)
            if q.shape != (self.spec.n_joints,) or not np.all((q >= 0) & (q <= 1)):
                raise ValueError(f"q: need {self.spec.n_joints} values in [0, 1], got {q}")
        c = self.scene.client
        p.resetBasePositionAndOrientation(
            self.body, T_world_base[:3, 3].tolist(), matrix_to_xyzw(T_world_base[:3, :3]), physicsClientId=c
        )
        if q is None:
            return
        for j, (link, qj) in enumerate(zip(self.spec.links[1:], q, strict=True)):
            p.resetJointState(self.body, j, link.lower + qj * (link.upper - link.lower), physicsClientId=c)

    def part_poses(self) -> np.ndarray:
        """(N, 4, 4) T_world_link of every link (URDF link frames)."""
        c = self.scene.client
        out = [pose_to_matrix(*p.getBasePositionAndOrientation(self.body, physicsClientId=c))]
        for j in range(self.spec.n_joints):
            st = p.getLinkState(self.body, j, computeForwardKinematics=True, physicsClientId=c)
            out.append(pose_to_matrix(st[4], st[5]))
        return np.stack(out)


def look_at_45(target: np.ndarray, distance: float, azimuth: float = -np.pi / 2) -> np.ndarray:
    """T_world_camera (OpenCV axes) of a camera 45 deg above the table looking at ``target``.

    ``azimuth`` is the direction, in the table plane, from the target to the camera (default -y, the
    objects' front). ``target`` is a finite (3,) point, ``distance`` finite and > 0, ``azimuth`` finite.
    """
    target = as_vector(target, "target", 3, "a finite (3,) point")
    distance = as_real(distance, "distance", low=0.0, open_low=True, unit="m")
    azimuth = as_real(azimuth, "azimuth", unit="rad")
    d = np.array(
        [np.cos(azimuth) * np.cos(np.pi / 4), np.sin(azimuth) * np.cos(np.pi / 4), np.sin(np.pi / 4)]
    )
    eye = target + distance * d
    z = (target - eye) / np.linalg.norm(target - eye)
    x = np.cross(z, [0.0, 0.0, 1.0])
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    T = np.eye(4)
    T[:3, :3] = np.stack([x, y, z], 1)
    T[:3, 3] = eye
    return T


@dataclass
class TrackingSequence:
    """Rendered frames with ground truth for a tracking run.

    Attributes:
        category: benchmark category (a :data:`CATEGORIES` name, ``single``, ``multiple``, ``articulated``).
        models: (K, 3) model cloud per tracked part, in the part (link) frame.
        T_world_part: (F, N, 4, 4) ground truth per frame and part.
        scenes: F world-frame camera clouds (table and probe removed).
        tactile: F tactile clouds (None when the probe touches nothing).
        joint_values: (F, J) normalised joint values (J = 0 for rigid objects).
    """

    category: str
    models: list[np.ndarray]
    T_world_part: np.ndarray
    scenes: list[np.ndarray]
    tactile: list[np.ndarray | None]
    joint_values: np.ndarray = field(default_factory=lambda: np.zeros((0, 0)))


def _planar_pose(x: float, y: float, yaw: float, z: float = 0.0) -> np.ndarray:
    c, s = np.cos(yaw), np.sin(yaw)
    T = np.eye(4)
    T[:3, :3] = [[c, -s, 0], [s, c, 0], [0, 0, 1]]
    T[:3, 3] = [x, y, z]
    return T


def _smooth_path(rng: np.random.Generator, n_frames: int, n_waypoints: int, scale: np.ndarray) -> np.ndarray:
    """A random path through ``n_waypoints`` random offsets: straight segments in space, each
    travelled with smoothstep timing (zero speed at the waypoints, so the motion is C1 in time)."""
    wp = np.concatenate(
        [np.zeros((1, len(scale))), rng.uniform(-1, 1, size=(n_waypoints, len(scale))) * scale]
    )
    s = np.linspace(0, n_waypoints, n_frames)
    i = np.minimum(s.astype(int), n_waypoints - 1)
    u = (s - i)[:, None]
    h = 3 * u**2 - 2 * u**3  # smoothstep per segment: zero velocity at the waypoints
    return wp[i] * (1 - h) + wp[i + 1] * h


def render_cloud(
    scene: Scene, camera: RGBDCamera, T_world_camera: np.ndarray, drop: set[int], rng: np.random.Generator
) -> np.ndarray:
    """World-frame cloud of one rendered frame without the bodies in ``drop`` (e.g. the table): what a
    tracker gets after plane and background removal (thesis 6.2.2)."""
    frame = camera.render(scene, T_world_camera, rng)
    mask = (frame.depth > 0) & (frame.seg >= 0) & ~np.isin(frame.seg, list(drop))
    return camera.point_cloud(frame, rng=rng)[mask[frame.depth > 0]]


def articulation_sequence(
    category: str,
    seed: int,
    n_frames: int = 20,
    *,
    width: int = 320,
    height: int = 240,
    n_model_points: int | float = 0.005,
    noise: bool = True,
) -> TrackingSequence:
    """Thesis 6.3.5 analogue: a random instance, random base pose, joints moved from 0 to random q in [0, 1].

    The camera is at 45 deg top-down in front of the object, at a distance that frames it.
    """
    n_frames = as_int(n_frames, "n_frames")
    rng = np.random.default_rng(seed)
    spec = make_articulated(category, rng)
    with Scene(table=True) as scene:
        obj = ArticulatedObject(scene, spec, n_model_points=n_model_points, seed=seed)
        T_base = _planar_pose(_u(rng, -0.05, 0.05), _u(rng, -0.05, 0.05), _u(rng, -0.5, 0.5))
        q_end = rng.uniform(0, 1, size=spec.n_joints)
        size = float(np.max(spec.links[0].mesh().extents))
        camera = RGBDCamera(width, height, fov_y_deg=50.0, noise=DepthNoise() if noise else DepthNoise.off())
        T_wc = look_at_45(T_base[:3, 3] + [0, 0, 0.3 * size], distance=max(0.35, 2.4 * size))
        gts, scenes, qs = [], [], []
        for k in range(n_frames):
            s = k / max(n_frames - 1, 1)
            q = q_end * (3 * s**2 - 2 * s**3)
            obj.set_state(T_base, q)
            gts.append(obj.part_poses())
            scenes.append(render_cloud(scene, camera, T_wc, {scene.table_id}, rng))
            qs.append(q)
    return TrackingSequence(category, obj.models, np.stack(gts), scenes, [None] * n_frames, np.stack(qs))


def motion_sequence(
    kind: str,
    seed: int,
    n_frames: int = 60,
    *,
    n_objects: int | None = None,
    width: int = 320,
    height: int = 240,
    n_model_points: int | float = 0.005,
    noise: bool = True,
    probe_radius: float = 0.01,
) -> TrackingSequence:
    """Thesis Table 6.2 analogue: objects moved along random smooth planar trajectories.

    Args:
        kind: ``single`` (one rigid object), ``multiple`` (3-7 rigid objects, ``n_objects`` to fix it)
            or ``articulated`` (a dishwasher or drawer, base and joint moving: 2 parts).
        seed: random seed.
        n_frames: frames (at 30 Hz, about 2 s for 60 frames; up to ~15 cm and ~35 deg per object).

    The first object is pushed by the probe, which yields the tactile points.
    """
    if kind not in ("single", "multiple", "articulated"):
        raise ValueError(f"kind: expected 'single', 'multiple' or 'articulated', got {kind!r}")
    n_frames = as_int(n_frames, "n_frames")
    probe_radius = as_real(probe_radius, "probe_radius", low=0.0, open_low=True, unit="m")
    rng = np.random.default_rng(seed)
    if kind == "single":
        specs = [make_rigid(rng)]
    elif kind == "multiple":
        n = as_int(n_objects, "n_objects") if n_objects is not None else int(rng.integers(3, 8))
        if n > 9:
            raise ValueError(f"n_objects: need an integer in 1..9, got {n}")
        specs = [make_rigid(rng) for _ in range(n)]
    else:
        specs = [make_articulated(str(rng.choice(["dishwasher", "drawer"])), rng)]
    # lay the objects out on a grid of 0.25 m cells so that their paths never cross
    cols = int(np.ceil(np.sqrt(len(specs))))
    cell = 0.25 if kind != "articulated" else 0.6
    starts = [
        ((i % cols - (cols - 1) / 2) * cell, (i // cols - (len(specs) - 1) // cols / 2) * cell)
        for i in range(len(specs))
    ]
    reach = np.array([0.06, 0.06, 0.6]) if kind != "articulated" else np.array([0.08, 0.08, 0.3])
    paths = [_smooth_path(rng, n_frames, 3, reach) for _ in specs]
    yaw0 = rng.uniform(-np.pi, np.pi, size=len(specs)) if kind != "articulated" else rng.uniform(-0.4, 0.4, 1)
    with Scene(table=True) as scene:
        objs = [
            ArticulatedObject(scene, s, n_model_points=n_model_points, seed=seed + 10 * i)
            for i, s in enumerate(specs)
        ]
        kw = {"physicsClientId": scene.client}
        probe = p.createMultiBody(
            0,
            p.createCollisionShape(p.GEOM_SPHERE, radius=probe_radius, **kw),
            p.createVisualShape(p.GEOM_SPHERE, radius=probe_radius, rgbaColor=[0.2, 0.2, 0.2, 1], **kw),
            basePosition=[0, 0, 2.0],
            **kw,
        )
        extent = cell * cols
        camera = RGBDCamera(width, height, fov_y_deg=50.0, noise=DepthNoise() if noise else DepthNoise.off())
        T_wc = look_at_45(np.array([0.0, 0.0, 0.05]), distance=max(0.7, 1.5 * extent))
        q_end = rng.uniform(0.3, 1.0, size=max(specs[0].n_joints, 0))
        gts, scenes, tactile, qs = [], [], [], []
        for k in range(n_frames):
            s = k / max(n_frames - 1, 1)
            for obj, st, path, y0 in zip(objs, starts, paths, yaw0, strict=True):
                q = q_end * (3 * s**2 - 2 * s**3) if obj.spec.n_joints else None
                obj.set_state(_planar_pose(st[0] + path[k, 0], st[1] + path[k, 1], y0 + path[k, 2]), q)
            gts.append(np.concatenate([o.part_poses() for o in objs]))
            # the probe trails the first object along its direction of motion, touching it
            vel = paths[0][min(k + 1, n_frames - 1), :2] - paths[0][max(k - 1, 0), :2]
            tactile.append(_place_probe(scene, objs[0], probe, vel, probe_radius))
            scenes.append(render_cloud(scene, camera, T_wc, {scene.table_id, probe}, rng))
            if objs[0].spec.n_joints:
                qs.append(q_end * (3 * s**2 - 2 * s**3))
    models = [m for o in objs for m in o.models]
    joint_values = np.stack(qs) if qs else np.zeros((n_frames, 0))
    return TrackingSequence(kind, models, np.stack(gts), scenes, tactile, joint_values)


def _place_probe(
    scene: Scene, obj: ArticulatedObject, probe: int, vel: np.ndarray, r: float
) -> np.ndarray | None:
    """Put the probe against ``obj``'s base on the side opposite to ``vel``; return the contact points."""
    kw = {"physicsClientId": scene.client}
    if np.linalg.norm(vel) < 1e-6:
        p.resetBasePositionAndOrientation(probe, [0, 0, 2.0], [0, 0, 0, 1], **kw)
        return None
    d = np.append(vel / np.linalg.norm(vel), 0.0)
    T = obj.part_poses()[0]
    mesh = obj.spec.links[0].mesh()
    verts = mesh.vertices @ T[:3, :3].T + T[:3, 3]
    c = verts.mean(0)
    c[2] = 0.5 * verts[:, 2].max()
    # back off along -d until the sphere just touches the base link
    support = float(np.max((c - verts) @ d))
    pos = c - (support + r) * d
    for _ in range(8):
        p.resetBasePositionAndOrientation(probe, pos.tolist(), [0, 0, 0, 1], **kw)
        cps = p.getClosestPoints(probe, obj.body, 0.05, linkIndexB=-1, **kw)
        if not cps:
            break
        gap = min(cp[8] for cp in cps)
        if abs(gap) < 5e-4:
            break
        pos = pos + gap * d  # move along d by the signed gap
    cps = p.getClosestPoints(probe, obj.body, 0.002, linkIndexB=-1, **kw)
    if not cps:
        return None
    return np.array([cp[6] for cp in cps], dtype=np.float64)  # positionOnB: on the object surface
