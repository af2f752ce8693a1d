"""A headless pybullet scene holding meshes on a table (shared by the tactile and camera simulators).

pybullet runs in DIRECT mode (no GUI, no GPU), one physics client per :class:`Scene`, so scenes in
worker processes are independent. The world frame is z-up with the table top at z = 0.

Shapes:
    add_mesh: canonical mesh vertices (V, 3) times ``scale`` metres, placed by T_world_object (4, 4)
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pybullet as p
import trimesh

from vtlearn.geometry import matrix_to_quat
from vtlearn.validation import as_int, as_points, as_real, as_surface_mesh, as_transform, as_vector

# Bullet pads every collider by a margin (1 mm for meshes by default) and reports contact points on
# the padded surface; 0.1 mm keeps physical-mode tactile points within 0.1 mm of the mesh.
COLLISION_MARGIN = 1e-4


@dataclass
class SceneObject:
    body_id: int
    mesh_m: trimesh.Trimesh  # in the object frame, metres
    T_world_object: np.ndarray
    fixed: bool
    transparent: bool


def matrix_to_xyzw(R: np.ndarray) -> list[float]:
    """The pybullet (x, y, z, w) quaternion of a rotation matrix; vtlearn itself stores Hamilton (w, x, y, z)
    (STYLE.md), so this is only for calls into pybullet.

    Shapes:
        R (3, 3) -> list of 4 floats.
    """
    w, x, y, z = np.asarray(matrix_to_quat(np.asarray(R, dtype=np.float64)), dtype=np.float64)
    return [float(x), float(y), float(z), float(w)]


def pose_to_matrix(pos, quat_xyzw) -> np.ndarray:
    """T_world_link (4, 4) from a pybullet position and (x, y, z, w) quaternion."""
    T = np.eye(4)
    T[:3, :3] = np.asarray(p.getMatrixFromQuaternion(quat_xyzw), dtype=np.float64).reshape(3, 3)
    T[:3, 3] = pos
    return T


class Scene:
    """A pybullet DIRECT client with an optional table plane and the meshes added to it.

    Args:
        table: add a static 1.2 m x 1.2 m x 2 cm table whose top face is the plane z = 0. It collides
            like any body, but TinyRenderer does not draw it; :class:`~vtlearn.sim_data.camera.RGBDCamera`
            adds its top face analytically (depth, segmentation id ``table_id``, flat colour ``table_rgba``).
        gravity: z gravity in m/s^2 (used only when free objects are stepped), finite.

    Each scene owns one pybullet connection until :meth:`close` (or the end of a ``with`` block, or garbage
    collection) disconnects it.
    """

    def __init__(self, table: bool = True, gravity: float = -9.81):
        gravity = as_real(gravity, "gravity", unit="m/s^2")  # before connecting, so a bad value leaks nothing
        self.client = p.connect(p.DIRECT)
        p.setGravity(0, 0, gravity, physicsClientId=self.client)
        self.objects: dict[int, SceneObject] = {}
        self.table_id: int | None = None
        self.table_half_extents = np.array([0.6, 0.6, 0.01])
        self.table_rgba = np.array([0.55, 0.45, 0.35, 1.0])
        if table:
            col = p.createCollisionShape(
                p.GEOM_BOX, halfExtents=self.table_half_extents.tolist(), physicsClientId=self.client
            )
            # Alpha 0 makes TinyRenderer skip the table: shading its ~60k pixels cost ~35 ms a frame at
            # 320x240, and RGBDCamera draws the flat top exactly by ray-plane intersection instead.
            vis = p.createVisualShape(
                p.GEOM_BOX,
                halfExtents=self.table_half_extents.tolist(),
                rgbaColor=[*self.table_rgba[:3], 0.0],
                physicsClientId=self.client,
            )
            self.table_id = p.createMultiBody(
                0, col, vis, basePosition=[0, 0, -0.01], physicsClientId=self.client
            )

    # ------------------------------------------------------------------ objects
    def add_mesh(
        self,
        mesh: trimesh.Trimesh,
        scale: float = 1.0,
        T_world_object: np.ndarray | None = None,
        fixed: bool = True,
        transparent: bool = False,
        rgba=(0.8, 0.3, 0.2, 1.0),
        mass: float = 0.2,
    ) -> int:
        """Add ``mesh`` (vertices times ``scale`` = metres) at ``T_world_object``; returns the body id.

        A fixed object gets an exact concave triangle-mesh collider (what the taxel rays hit). A free
        object gets its convex hull as collider, because Bullet only simulates convex dynamic meshes.

        Raises ``ValueError`` naming the argument for a mesh without faces, with NaN/inf vertices or zero
        total area (e.g. all vertices collinear); a non-positive or non-finite ``scale``; a
        ``T_world_object`` that is not a finite rigid (4, 4) transform; ``rgba`` other than 4 finite
        numbers; or, for a free object, a ``mass`` that is not positive and finite.

        Shapes:
            mesh.vertices (V, 3), canonical units; T_world_object (4, 4); rgba (4,) -> body id (int)
        """
        as_surface_mesh(mesh, "mesh")
        scale = as_real(scale, "scale", low=0.0, open_low=True)
        T = np.eye(4) if T_world_object is None else np.asarray(T_world_object, dtype=np.float64)
        if T.shape != (4, 4):
            raise ValueError(f"T_world_object: need shape (4, 4), got {T.shape}")
        T = as_transform(T, "T_world_object")
        rgba_arr = as_vector(rgba, "rgba", 4, "4 finite numbers (r, g, b, a)")
        if not fixed:
            mass = as_real(mass, "mass", low=0.0, open_low=True, unit="kg")
        mesh_m = trimesh.Trimesh(mesh.vertices * scale, mesh.faces, process=False)
        v = mesh_m.vertices.astype(np.float64).tolist()
        idx = mesh_m.faces.astype(np.int32).ravel().tolist()
        kw = {"physicsClientId": self.client}
        if fixed:
            col = p.createCollisionShape(
                p.GEOM_MESH, vertices=v, indices=idx, flags=p.GEOM_FORCE_CONCAVE_TRIMESH, **kw
            )
        else:
            hull = mesh_m.convex_hull
            col = p.createCollisionShape(p.GEOM_MESH, vertices=hull.vertices.tolist(), **kw)
        # Unit normals per vertex make TinyRenderer shading sane for revolved meshes.
        vis = p.createVisualShape(
            p.GEOM_MESH,
            vertices=v,
            indices=idx,
            rgbaColor=rgba_arr.tolist(),
            normals=mesh_m.vertex_normals.tolist(),
            **kw,
        )
        body = p.createMultiBody(
            0.0 if fixed else mass,
            col,
            vis,
            basePosition=T[:3, 3].tolist(),
            baseOrientation=matrix_to_xyzw(T[:3, :3]),
            **kw,
        )
        p.changeDynamics(body, -1, collisionMargin=COLLISION_MARGIN, **kw)
        self.objects[body] = SceneObject(body, mesh_m, T, fixed, transparent)
        return body

    def remove(self, body_id: int) -> None:
        """Remove the object ``body_id`` (a ``ValueError`` naming it unless it is in :attr:`objects`)."""
        if body_id not in self.objects:
            raise ValueError(f"body_id: {body_id!r} is not an object of the scene ({sorted(self.objects)})")
        p.removeBody(body_id, physicsClientId=self.client)
        del self.objects[body_id]

    def clear(self) -> None:
        for b in list(self.objects):
            self.remove(b)

    def T_world_object(self, body_id: int) -> np.ndarray:
        """Current pose T_world_object (4, 4) of a body of the scene (free objects may have moved).

        A ``ValueError`` names ``body_id`` when pybullet has no such body.
        """
        try:
            pos, q = p.getBasePositionAndOrientation(body_id, physicsClientId=self.client)
        except p.error:
            raise ValueError(f"body_id: no body {body_id!r} in the scene") from None
        return pose_to_matrix(pos, q)

    def step(self, n: int = 1) -> None:
        """Advance the physics ``n`` steps of pybullet's default 1/240 s (only free objects move)."""
        n = as_int(n, "n", minimum=0)
        for _ in range(n):
            p.stepSimulation(physicsClientId=self.client)

    def ray_test(
        self, starts: np.ndarray, ends: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """Batched ray casts. Returns (body ids (R,), hit fractions (R,), hit points (R, 3), normals (R, 3)).

        Missed rays have body id -1 and fraction 1. ``starts`` and ``ends`` must be finite (R, 3) arrays of
        the same length (``ValueError`` naming the argument otherwise).

        Shapes:
            starts (R, 3), ends (R, 3), world frame -> ids (R,), fractions (R,), points (R, 3), normals (R, 3)
        """
        starts = as_points(starts, "starts", min_points=0)
        ends = as_points(ends, "ends", min_points=0)
        if len(starts) != len(ends):
            raise ValueError(f"starts/ends: need the same number of rays, got {len(starts)} and {len(ends)}")
        out = []
        # pybullet caps one batch at MAX_RAY_INTERSECTION_BATCH_SIZE (16k) rays.
        for i in range(0, len(starts), 16000):
            out += p.rayTestBatch(
                starts[i : i + 16000].tolist(), ends[i : i + 16000].tolist(), physicsClientId=self.client
            )
        ids = np.array([o[0] for o in out], dtype=np.int64)
        frac = np.array([o[2] for o in out], dtype=np.float64)
        pts = np.array([o[3] for o in out], dtype=np.float64).reshape(-1, 3)
        nrm = np.array([o[4] for o in out], dtype=np.float64).reshape(-1, 3)
        return ids, frac, pts, nrm

    def close(self) -> None:
        if self.client is not None and p.isConnected(self.client):
            p.disconnect(self.client)
        self.client = None

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()

    def __del__(self):
        try:
            self.close()
        except Exception:  # interpreter shutdown: pybullet may already be gone
            pass
