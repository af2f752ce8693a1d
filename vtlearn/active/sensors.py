"""Virtual sensor models that turn candidate actions into rays (thesis 5.2.3, 7.2.4, 8.2.3).

The next-best-action criteria of the thesis predict what an action would measure by casting the rays
of a *virtual sensor* into the occupancy grid:

- tactile array (eq. 7.10 context, 5.2.3): one ray per taxel, ``R_t = {r_1 .. r_taxel}``, cast for a
  distance ``d_ray`` along the pressing (+z) axis of the pad frame. The taxel layouts (Xela 4x4, 6x4,
  6x1 at 4.7 mm, Contactile 3x3 at 7 mm, thesis ch.3) come from :mod:`vtlearn.sim_data.sensors`;
- pinch (8.2.3): the two antipodal pads of a parallel gripper, each a tactile array pressing towards the
  other across the opening;
- time-of-flight camera (5.2.3): beams ``R_v = {r_1 .. r_nv}`` spanning the field of view, subsampled
  by a configurable pixel stride.

Frames: ``T_world_pad`` maps pad-frame points into the world (grid) frame; the pad frame is the one of
:class:`vtlearn.sim_data.sensors.TaxelSensor` (origin at the taxel-grid centre, x along columns, y along
rows, z the pressing direction). ``T_world_grip`` has its origin midway between the open pads, x the
closing axis and z the approach direction. ``T_world_camera`` is an optical frame: z forward along the
optical axis, x right, y down. Units are metres and radians.

Shapes:
    Rays.origins, Rays.directions: ``(R, 3)`` unit directions; Rays.max_range: ``(R,)``;
    Rays.action_index: ``(R,)`` int64 in ``[0, n_actions)`` (a PyG-style batch vector).
    All ``rays(T)`` methods take ``T``: ``(N, 4, 4)`` or ``(4, 4)`` and give ``N * rays_per_action`` rays,
    action-major.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from vtlearn.sim_data.sensors import SENSORS, TaxelSensor, get_sensor
from vtlearn.validation import as_int, as_pair, as_real, as_surface_mesh, to_numpy

__all__ = ["PinchSensor", "Rays", "TactileArray", "ToFCamera", "as_transforms", "cast_rays_on_mesh"]


def as_transforms(T, name: str) -> np.ndarray:
    """Validate a ``(4, 4)`` or ``(N, 4, 4)`` stack of rigid transforms; returns ``(N, 4, 4)`` float64."""
    arr = to_numpy(T)
    if arr.ndim == 2:
        arr = arr[None]
    if arr.ndim != 3 or arr.shape[1:] != (4, 4) or arr.shape[0] == 0:
        raise ValueError(
            f"{name}: expected shape (4, 4) or (N, 4, 4) with N >= 1, got {tuple(to_numpy(T).shape)}"
        )
    if not np.isfinite(arr).all():
        raise ValueError(f"{name}: contains NaN or inf")
    R = arr[:, :3, :3]
    if not np.allclose(R.transpose(0, 2, 1) @ R, np.eye(3), atol=1e-5) or (np.linalg.det(R) < 0).any():
        raise ValueError(f"{name}: rotation blocks must be orthonormal with determinant +1")
    if not np.allclose(arr[:, 3], [0.0, 0.0, 0.0, 1.0], atol=1e-6):
        raise ValueError(f"{name}: last row must be (0, 0, 0, 1)")
    return arr


@dataclass
class Rays:
    """A batch of rays grouped into actions."""

    origins: np.ndarray
    directions: np.ndarray
    max_range: np.ndarray
    action_index: np.ndarray
    n_actions: int

    def __len__(self) -> int:
        return self.origins.shape[0]

    @staticmethod
    def concatenate(parts: list[Rays]) -> Rays:
        """Join ray batches; the actions of later parts are numbered after those of earlier ones."""
        if not parts:
            raise ValueError("parts: need at least one Rays batch")
        shift = np.cumsum([0] + [p.n_actions for p in parts[:-1]])
        return Rays(
            np.concatenate([p.origins for p in parts]),
            np.concatenate([p.directions for p in parts]),
            np.concatenate([p.max_range for p in parts]),
            np.concatenate([p.action_index + s for p, s in zip(parts, shift, strict=False)]),
            int(sum(p.n_actions for p in parts)),
        )


def _pad_rays(T_world_pad: np.ndarray, local: np.ndarray, ray_length: float) -> Rays:
    # local: K x 3 taxel centres in the pad frame; each casts along the pad's +z axis.
    n, k = T_world_pad.shape[0], local.shape[0]
    R, t = T_world_pad[:, :3, :3], T_world_pad[:, :3, 3]
    origins = np.einsum("nij,kj->nki", R, local) + t[:, None, :]  # N x K x 3
    directions = np.broadcast_to(R[:, None, :, 2], (n, k, 3))
    return Rays(
        origins.reshape(-1, 3),
        np.ascontiguousarray(directions).reshape(-1, 3),
        np.full(n * k, float(ray_length)),
        np.repeat(np.arange(n, dtype=np.int64), k),
        n,
    )


class TactileArray:
    """Virtual tactile sensor: one ray per taxel along the pad's pressing axis (thesis 7.2.4, ``d_ray``).

    Args:
        layout: a :class:`TaxelSensor` or a preset name (``xela_4x4``, ``xela_6x4``, ``xela_6x1``,
            ``contactile_3x3``) or ``"RxC@Pmm"``.
        ray_length: ``d_ray``, how far each taxel ray is cast, metres.
    """

    def __init__(self, layout: TaxelSensor | str = "xela_4x4", ray_length: float = 0.1):
        self.layout = get_sensor(layout)
        self.ray_length = as_real(ray_length, "ray_length", low=0.0, open_low=True, unit="m")

    @property
    def rays_per_action(self) -> int:
        return self.layout.num_taxels

    def rays(self, T_world_pad) -> Rays:
        """Rays of the taxels of pads at ``T_world_pad`` ``(N, 4, 4)``."""
        T = as_transforms(T_world_pad, "T_world_pad")
        return _pad_rays(T, self.layout.taxel_positions(), self.ray_length)

    def __repr__(self) -> str:
        return f"TactileArray({self.layout.name}, ray_length={self.ray_length})"


class PinchSensor:
    """Virtual pinch sensor (thesis 8.2.3): two antipodal tactile pads that close across ``opening``.

    In the grip frame the pads sit at ``x = +opening / 2`` and ``x = -opening / 2`` facing each other; the
    taxel columns run along the grip y axis and the rows along the approach (z) axis. Each pad casts its
    taxel rays across the whole opening, so a pinch predicts the first surface met from either side.

    Args:
        layout: taxel layout of each pad (see :class:`TactileArray`).
        opening: distance between the open pads, metres (the Robotiq 2F-140 opens 0.14 m).
    """

    def __init__(self, layout: TaxelSensor | str = "xela_4x4", opening: float = 0.14):
        self.layout = get_sensor(layout)
        self.opening = as_real(opening, "opening", low=0.0, open_low=True, unit="m")

    @property
    def rays_per_action(self) -> int:
        return 2 * self.layout.num_taxels

    def pad_transforms(self, T_world_grip) -> np.ndarray:
        """``(N, 2, 4, 4)`` ``T_world_pad`` of the +x pad and the -x pad."""
        T = as_transforms(T_world_grip, "T_world_grip")
        h = self.opening / 2
        # Pad at +x presses along -x; its columns (x_pad) follow grip y, so y_pad = z_pad x x_pad.
        T_grip_pad = np.zeros((2, 4, 4))
        T_grip_pad[0, :3, :3] = np.array([[0, 0, -1], [1, 0, 0], [0, -1, 0]], dtype=float)
        T_grip_pad[1, :3, :3] = np.array([[0, 0, 1], [1, 0, 0], [0, 1, 0]], dtype=float)
        T_grip_pad[0, :3, 3] = [h, 0, 0]
        T_grip_pad[1, :3, 3] = [-h, 0, 0]
        T_grip_pad[:, 3, 3] = 1.0
        return np.einsum("nij,pjk->npik", T, T_grip_pad)

    def rays(self, T_world_grip) -> Rays:
        """Rays of both pads of grippers at ``T_world_grip`` ``(N, 4, 4)``; both pads belong to one action."""
        pads = self.pad_transforms(T_world_grip)  # N x 2 x 4 x 4
        n = pads.shape[0]
        r = _pad_rays(pads.reshape(-1, 4, 4), self.layout.taxel_positions(), self.opening)
        r.action_index = np.repeat(np.arange(n, dtype=np.int64), self.rays_per_action)
        r.n_actions = n
        return r

    def __repr__(self) -> str:
        return f"PinchSensor({self.layout.name}, opening={self.opening})"


class ToFCamera:
    """Virtual time-of-flight camera (thesis 5.2.3): pinhole beams spanning the field of view.

    Defaults follow the Azure Kinect narrow-FOV depth mode (640 x 576 px, 75 x 65 degrees).

    Args:
        width, height: image size in pixels.
        fov_deg: horizontal and vertical field of view in degrees, a pair each in (0, 180).
        stride: keep every ``stride``-th pixel in both directions (the subsampling of ``n_v`` beams).
        max_range: beam length, metres.
    """

    def __init__(
        self,
        width: int = 640,
        height: int = 576,
        fov_deg: tuple[float, float] = (75.0, 65.0),
        stride: int = 16,
        max_range: float = 2.0,
    ):
        width, height = as_int(width, "width"), as_int(height, "height")
        fx_deg, fy_deg = as_pair(fov_deg, "fov_deg", "a (horizontal, vertical) pair of angles in degrees")
        if not (0 < fx_deg < 180 and 0 < fy_deg < 180):
            raise ValueError(f"fov_deg: each angle must lie in (0, 180) degrees, got {fov_deg}")
        stride = as_int(stride, "stride")
        if stride // 2 >= min(width, height):
            # the first kept pixel is stride // 2 in both directions: no beam would be left
            raise ValueError(f"stride: {stride} keeps no pixel of a {width} x {height} image; "
                             f"need stride // 2 < {min(width, height)}")
        max_range = as_real(max_range, "max_range", low=0.0, open_low=True, unit="m")
        self.width, self.height, self.stride = int(width), int(height), int(stride)
        self.fov_deg = (fx_deg, fy_deg)
        self.max_range = float(max_range)
        self.fx = (self.width / 2) / np.tan(np.radians(fx_deg) / 2)
        self.fy = (self.height / 2) / np.tan(np.radians(fy_deg) / 2)
        self.cx, self.cy = (self.width - 1) / 2, (self.height - 1) / 2

    @property
    def intrinsics(self) -> np.ndarray:
        """``(3, 3)`` pinhole matrix K."""
        return np.array([[self.fx, 0, self.cx], [0, self.fy, self.cy], [0, 0, 1.0]])

    def pixel_directions(self) -> np.ndarray:
        """``(n_v, 3)`` unit beam directions in the optical frame, one per kept pixel (row-major)."""
        u = np.arange(self.stride // 2, self.width, self.stride, dtype=np.float64)
        v = np.arange(self.stride // 2, self.height, self.stride, dtype=np.float64)
        vv, uu = np.meshgrid(v, u, indexing="ij")
        d = np.stack([(uu - self.cx) / self.fx, (vv - self.cy) / self.fy, np.ones_like(uu)], axis=-1).reshape(
            -1, 3
        )
        return d / np.linalg.norm(d, axis=1, keepdims=True)

    @property
    def rays_per_action(self) -> int:
        return len(range(self.stride // 2, self.width, self.stride)) * len(
            range(self.stride // 2, self.height, self.stride)
        )

    def rays(self, T_world_camera) -> Rays:
        """Beams of cameras at ``T_world_camera`` ``(N, 4, 4)`` (optical frames)."""
        T = as_transforms(T_world_camera, "T_world_camera")
        local = self.pixel_directions()
        n, k = T.shape[0], local.shape[0]
        directions = np.einsum("nij,kj->nki", T[:, :3, :3], local).reshape(-1, 3)
        origins = np.repeat(T[:, :3, 3], k, axis=0)
        return Rays(
            origins, directions, np.full(n * k, self.max_range), np.repeat(np.arange(n, dtype=np.int64), k), n
        )

    def __repr__(self) -> str:
        return (
            f"ToFCamera({self.width}x{self.height}, fov={self.fov_deg}, stride={self.stride}, "
            f"max_range={self.max_range})"
        )


def cast_rays_on_mesh(mesh, rays: Rays) -> tuple[np.ndarray, np.ndarray]:
    """Simulate the measurement of ``rays`` on a triangle mesh with Open3D's RaycastingScene.

    Args:
        mesh: a ``trimesh.Trimesh`` or an ``open3d.geometry.TriangleMesh`` in the grid frame, with
            triangles, finite vertices and a positive area.
        rays: a :class:`Rays` batch, e.g. from a sensor's ``rays(T)``.

    Returns:
        ranges: ``(R,)`` distance to the first surface, or ``max_range`` where none is met within it.
        hit: ``(R,)`` bool.

    Shapes:
        rays: ``R`` rays -> ranges ``(R,)``, hit ``(R,)``.
    """
    import open3d as o3d
    import trimesh

    if not isinstance(rays, Rays):
        raise ValueError(f"rays: expected a Rays batch (from a sensor's rays()), got {type(rays).__name__}")
    if isinstance(mesh, o3d.geometry.TriangleMesh):
        if len(mesh.triangles) == 0:
            raise ValueError("mesh: has no triangles")
        mesh = trimesh.Trimesh(np.asarray(mesh.vertices), np.asarray(mesh.triangles), process=False)
    mesh = as_surface_mesh(mesh, "mesh")
    vertices, faces = np.asarray(mesh.vertices), np.asarray(mesh.faces)
    scene = o3d.t.geometry.RaycastingScene()
    scene.add_triangles(
        o3d.core.Tensor(vertices.astype(np.float32)), o3d.core.Tensor(faces.astype(np.uint32))
    )
    q = np.concatenate([rays.origins, rays.directions], axis=1).astype(np.float32)
    t_hit = scene.cast_rays(o3d.core.Tensor(q))["t_hit"].numpy().astype(np.float64)
    hit = np.isfinite(t_hit) & (t_hit <= rays.max_range)
    return np.where(hit, t_hit, rays.max_range), hit


# Re-exported so that callers of the active-perception sensors see the same presets as sim_data.
TAXEL_LAYOUTS = SENSORS
