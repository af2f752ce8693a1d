"""Simulated RGB-D camera with a Kinect-like noise model and a transparent-object failure model
(thesis ch.5 5.2.1-5.2.2: visual point clouds from the Azure Kinect; NBV viewpoints eq. 5.3-5.5).

The camera frame is the OpenCV one: x right, y down, z forward along the optical axis. Images are
rendered with pybullet's TinyRenderer (CPU). Depth is metric z along the optical axis; 0 marks an
invalid pixel.

Depth noise (Kinect-like, Nguyen et al. 2012): axial std ``sigma_z(z) = a + b (z - z0)^2`` with
a = 1.2 mm, b = 1.9 mm/m^2, z0 = 0.4 m, a lateral std of ``lateral_px`` pixels applied during
back-projection, and no return outside ``[min_range, max_range]``.

Transparent objects (the failure that motivates the thesis, ch.1 and 5): a time-of-flight camera
sees through glass or gets multipath returns. For every pixel of a body flagged transparent, with
probability ``p_missing`` the depth is lost (0) and otherwise it is pushed ``U(deep_min, deep_max)``
metres too deep. Opaque objects are unaffected.

Viewpoints (eq. 5.3-5.5): camera positions are drawn uniformly on a hemisphere around the object
centroid (Marsaglia 1972), and the orientation comes from the angle-axis of eq. 5.4 through
Rodrigues' formula eq. 5.5 so that the optical axis passes through the centroid.

Shapes:
    RGBDFrame.rgb (H, W, 3) uint8, depth (H, W) float32 metres, seg (H, W) int32 body id (-1 none),
    K (3, 3), T_world_camera (4, 4); backproject -> (N, 3) world points
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pybullet as p

from vtlearn.sim_data.scene import Scene
from vtlearn.validation import as_int, as_real, as_transform, as_vector


@dataclass
class DepthNoise:
    """Kinect-like depth noise; see the module docstring. ``DepthNoise.off()`` disables it.

    All values are finite; ``axial_a``, ``axial_b``, ``lateral_px`` >= 0 and ``0 <= min_range < max_range``.
    """

    axial_a: float = 0.0012
    axial_b: float = 0.0019
    axial_z0: float = 0.4
    lateral_px: float = 0.5
    min_range: float = 0.2
    max_range: float = 3.0
    enabled: bool = True

    @classmethod
    def off(cls) -> DepthNoise:
        return cls(enabled=False)

    def __post_init__(self):
        for name in ("axial_a", "axial_b", "axial_z0", "lateral_px", "min_range", "max_range"):
            non_negative = name in ("axial_a", "axial_b", "lateral_px")
            as_real(getattr(self, name), name, low=0.0 if non_negative else -np.inf)
        if not 0 <= self.min_range < self.max_range:
            raise ValueError(
                "min_range/max_range: need 0 <= min_range < max_range, "
                f"got {self.min_range}, {self.max_range}"
            )


@dataclass
class TransparencyModel:
    """Failure of depth sensing on transparent bodies (missing and wrongly deep pixels)."""

    p_missing: float = 0.7
    deep_min: float = 0.02
    deep_max: float = 0.3

    def __post_init__(self):
        as_real(self.p_missing, "p_missing", low=0.0, high=1.0)
        as_real(self.deep_min, "deep_min", low=0.0)
        as_real(self.deep_max, "deep_max", low=0.0)
        if not self.deep_min <= self.deep_max:
            raise ValueError(
                f"deep_min/deep_max: need 0 <= deep_min <= deep_max, got {self.deep_min}, {self.deep_max}"
            )


@dataclass
class RGBDFrame:
    rgb: np.ndarray
    depth: np.ndarray
    seg: np.ndarray
    K: np.ndarray
    T_world_camera: np.ndarray


def intrinsics_from_fov(width: int, height: int, fov_y_deg: float) -> np.ndarray:
    """Pinhole K (3, 3) with square pixels for a vertical field of view in degrees.

    Shapes:
        -> K (3, 3), pixels
    """
    width, height = as_int(width, "width"), as_int(height, "height")
    fov_y_deg = as_real(fov_y_deg, "fov_y_deg", low=0.0, high=180.0, open_low=True, open_high=True,
                        unit="deg")
    f = height / (2.0 * np.tan(np.deg2rad(fov_y_deg) / 2))
    return np.array([[f, 0, width / 2], [0, f, height / 2], [0, 0, 1.0]])


class RGBDCamera:
    """A pinhole RGB-D camera rendered by TinyRenderer.

    Args:
        width, height: image size in pixels (integers >= 1).
        fov_y_deg: vertical field of view (the Azure Kinect NFOV depth mode is about 65 deg).
        near, far: clipping planes in metres.
        noise: :class:`DepthNoise` (``DepthNoise.off()`` for exact depth).
        transparency: :class:`TransparencyModel` applied to bodies flagged transparent in the scene.
    """

    def __init__(
        self,
        width: int = 320,
        height: int = 240,
        fov_y_deg: float = 60.0,
        near: float = 0.05,
        far: float = 4.0,
        noise: DepthNoise | None = None,
        transparency: TransparencyModel | None = None,
    ):
        self.width, self.height = as_int(width, "width", 1), as_int(height, "height", 1)
        near, far = as_real(near, "near"), as_real(far, "far")
        self.K = intrinsics_from_fov(self.width, self.height, fov_y_deg)
        # TinyRenderer rasterises pixel (u, v) at image coordinates (u, v + 1) rather than at the
        # centre (u + 0.5, v + 0.5), measured against the mesh (median error 0.2 mm vs 1 mm). Shift
        # the principal point so that backproject's pixel-centre convention is exact for it.
        self.K[0, 2] += 0.5
        self.K[1, 2] -= 0.5
        if not 0 < near < far:
            raise ValueError(f"near/far: need 0 < near < far, got {near}, {far}")
        self.fov_y_deg, self.near, self.far = float(fov_y_deg), float(near), float(far)
        self.noise = noise if noise is not None else DepthNoise()
        self.transparency = transparency if transparency is not None else TransparencyModel()
        self._proj = p.computeProjectionMatrixFOV(
            self.fov_y_deg, self.width / self.height, self.near, self.far
        )
        v, u = np.mgrid[0 : self.height, 0 : self.width]
        uv1 = np.stack([u + 0.5, v + 0.5, np.ones_like(u, dtype=np.float64)], axis=-1)
        self._rays = (uv1 @ np.linalg.inv(self.K).T).astype(np.float32)  # (H, W, 3), camera depth 1

    def render(
        self, scene: Scene, T_world_camera: np.ndarray, rng: np.random.Generator | None = None
    ) -> RGBDFrame:
        """Render RGB, metric depth (noise and transparency applied) and the body-id segmentation.

        TinyRenderer draws the objects; the scene's table top is added by ray-plane intersection
        (see :meth:`_draw_table`), which is exact for the flat top and saves TinyRenderer's shading of
        most of the image. Arrays stay float32 as TinyRenderer returns them. ``rng`` draws the depth
        noise and the transparency failures (pass one for reproducible output).

        Shapes:
            T_world_camera (4, 4), OpenCV camera axes -> RGBDFrame: rgb (H, W, 3) uint8, depth (H, W)
            float32 metres (0 = no return), seg (H, W) int32 body id (-1 none)
        """
        T = as_transform(T_world_camera, "T_world_camera")
        rng = rng if rng is not None else np.random.default_rng()
        # OpenGL looks down -z with y up: T_world_gl = T_world_camera @ diag(1, -1, -1, 1).
        view = np.linalg.inv(T @ np.diag([1.0, -1.0, -1.0, 1.0]))
        _, _, rgba, zbuf, seg = p.getCameraImage(
            self.width,
            self.height,
            viewMatrix=view.T.ravel().tolist(),
            projectionMatrix=self._proj,
            renderer=p.ER_TINY_RENDERER,
            physicsClientId=scene.client,
        )
        rgba = np.ascontiguousarray(rgba, dtype=np.uint8).reshape(self.height, self.width, 4)
        zbuf = np.asarray(zbuf, dtype=np.float32).reshape(self.height, self.width)
        seg = np.asarray(seg, dtype=np.int32).reshape(self.height, self.width)
        # pybullet packs the link index above bit 24 of the body id; base links (all ours) have 0.
        seg = np.where(seg >= 0, seg & ((1 << 24) - 1), -1).astype(np.int32)
        f, n = np.float32(self.far), np.float32(self.near)
        background = zbuf >= 1.0
        depth = f * n / (f - (f - n) * zbuf)
        depth[background] = np.inf
        self._draw_table(scene, T, depth, seg, rgba)
        depth[np.isinf(depth)] = 0.0
        rgb = rgba[..., :3]  # a view: pybullet returns a fresh array per call
        depth = self._apply_transparency(depth, seg, scene, rng)
        depth = self._apply_noise(depth, rng)
        return RGBDFrame(rgb, depth, seg, self.K.copy(), T.copy())

    def _draw_table(self, scene: Scene, T_world_camera, depth, seg, rgba) -> None:
        """Composite the table face the camera sees into ``depth`` (inf = empty), ``seg`` and ``rgba``.

        Pixel (u, v) looks along ``r = K^-1 [u + 0.5, v + 0.5, 1]`` (camera depth 1), the convention of
        :func:`backproject`, so table pixels back-project exactly onto the plane. Along ``T r`` the
        world height is ``o_z + t (R r)_z``; the face at height ``z_f`` is met at camera depth
        ``t = (z_f - o_z) / (R r)_z``, and kept where it lies within the table, within the clipping
        planes and in front of what TinyRenderer drew. The 2 cm table sides are not drawn.
        """
        if scene.table_id is None:
            return
        hx, hy, hz = scene.table_half_extents
        o, R = T_world_camera[:3, 3], T_world_camera[:3, :3]
        if o[2] > 0:
            z_face = 0.0  # the top, seen from above
        elif o[2] < -2 * hz:
            z_face = -2 * hz  # the underside
        else:
            return  # the camera is level with the slab and sees only its edge
        rays = self._rays  # (H, W, 3) float32
        with np.errstate(divide="ignore", invalid="ignore"):
            t = np.float32(z_face - o[2]) / (rays @ R[2].astype(np.float32))
            x = np.float32(o[0]) + t * (rays @ R[0].astype(np.float32))
            y = np.float32(o[1]) + t * (rays @ R[1].astype(np.float32))
            hit = (t > self.near) & (t < self.far) & (np.abs(x) <= hx) & (np.abs(y) <= hy) & (t < depth)
        depth[hit] = t[hit]
        seg[hit] = scene.table_id
        # one uint32 store per pixel: a masked store of 3 bytes per pixel costs ~5 ms per frame
        colour = np.round(255 * scene.table_rgba).astype(np.uint8).view(np.uint32)[0]
        rgba.view(np.uint32)[..., 0][hit] = colour

    def _apply_transparency(self, depth, seg, scene, rng):
        clear = [b for b, o in scene.objects.items() if o.transparent]
        if not clear:
            return depth
        mask = np.isin(seg, clear) & (depth > 0)
        n = int(mask.sum())
        tm = self.transparency
        missing = rng.uniform(size=n) < tm.p_missing
        vals = depth[mask] + rng.uniform(tm.deep_min, tm.deep_max, size=n).astype(np.float32)
        vals[missing] = 0.0
        depth[mask] = vals
        return depth

    def _apply_noise(self, depth, rng):
        nz = self.noise
        if not nz.enabled:
            return depth
        valid = depth > 0
        z = depth[valid]
        sigma = np.float32(nz.axial_a) + np.float32(nz.axial_b) * np.square(z - np.float32(nz.axial_z0))
        depth[valid] = z + rng.standard_normal(z.shape, dtype=np.float32) * sigma
        depth[(depth < nz.min_range) | (depth > nz.max_range)] = 0.0
        return depth

    def point_cloud(
        self, frame: RGBDFrame, body_id: int | None = None, rng: np.random.Generator | None = None
    ):
        """World-frame cloud of the valid pixels (of ``body_id`` only when given), via :func:`backproject`.

        Shapes:
            frame.depth (H, W) -> (N, 3) world frame, metres
        """
        mask = frame.depth > 0
        if body_id is not None:
            mask &= frame.seg == body_id
        lateral = self.noise.lateral_px if self.noise.enabled else 0.0
        return backproject(frame.depth, frame.K, frame.T_world_camera, mask, lateral_px=lateral, rng=rng)


def backproject(
    depth: np.ndarray,
    K: np.ndarray,
    T_world_camera: np.ndarray,
    mask: np.ndarray | None = None,
    lateral_px: float = 0.0,
    rng: np.random.Generator | None = None,
) -> np.ndarray:
    """Back-project a metric depth image to world-frame points ``p_world = T_world_camera @ p_camera``.

    Pixel (u, v) looks through its centre (u + 0.5, v + 0.5); ``p_camera = z K^-1 [u, v, 1]``.
    ``K`` must be finite and invertible, ``T_world_camera`` a finite rigid transform, ``mask`` (if given)
    the shape of ``depth`` and ``lateral_px`` finite and >= 0 (``ValueError`` naming the argument).

    Shapes:
        depth (H, W) metres, K (3, 3), T_world_camera (4, 4), mask (H, W) bool -> (N, 3) world frame, metres
    """
    depth = np.asarray(depth, dtype=np.float64)
    if depth.ndim != 2:
        raise ValueError(f"depth: need an (H, W) image, got shape {depth.shape}")
    K = np.asarray(K, dtype=np.float64)
    if K.shape != (3, 3):
        raise ValueError(f"K: need shape (3, 3), got {K.shape}")
    if not np.isfinite(K).all():
        raise ValueError("K: contains NaN or inf")
    if K[0, 0] == 0 or K[1, 1] == 0 or abs(np.linalg.det(K)) < 1e-12:
        raise ValueError(f"K: singular intrinsics (fx={K[0, 0]}, fy={K[1, 1]}, det={np.linalg.det(K)})")
    T = as_transform(T_world_camera, "T_world_camera")
    if mask is not None and np.shape(mask) != depth.shape:
        raise ValueError(f"mask: need the shape of depth {depth.shape}, got {np.shape(mask)}")
    lateral_px = as_real(lateral_px, "lateral_px", low=0.0)
    valid = depth > 0 if mask is None else (np.asarray(mask, bool) & (depth > 0))
    v, u = np.nonzero(valid)
    z = depth[v, u]
    uu, vv = u + 0.5, v + 0.5
    if lateral_px > 0:
        rng = rng if rng is not None else np.random.default_rng()
        uu = uu + rng.normal(scale=lateral_px, size=uu.shape)
        vv = vv + rng.normal(scale=lateral_px, size=vv.shape)
    x = (uu - K[0, 2]) / K[0, 0] * z
    y = (vv - K[1, 2]) / K[1, 1] * z
    pts_c = np.stack([x, y, z], axis=1)
    return pts_c @ T[:3, :3].T + T[:3, 3]


def viewpoint_rotation(p_view: np.ndarray, o_centroid: np.ndarray) -> np.ndarray:
    """R_world_camera whose optical axis (+z) passes from ``p_view`` through ``o_centroid``.

    Eq. 5.3: h = (p_view - o_centroid) / |.|;  eq. 5.4: theta = acos(h . Z), e = (h x Z) / |h x Z|;
    eq. 5.5: R_v = Rodrigues(e, theta), which rotates h onto Z. Hence R_v^T Z = h, and the camera,
    which must look along -h, is R_world_camera = R_v^T Rx(pi). Straight above (h = Z), e is
    undefined and R_v = I. ``p_view`` and ``o_centroid`` are distinct finite (3,) points.

    Shapes:
        p_view (3,), o_centroid (3,), world frame -> R_world_camera (3, 3)
    """
    h = as_vector(p_view, "p_view", 3, "a finite (3,) point") - as_vector(
        o_centroid, "o_centroid", 3, "a finite (3,) point")
    nh = np.linalg.norm(h)
    if nh < 1e-12:
        raise ValueError("p_view: coincides with o_centroid")
    h /= nh
    Z = np.array([0.0, 0.0, 1.0])
    axis = np.cross(h, Z)
    s = np.linalg.norm(axis)
    if s < 1e-9:
        Rv = np.eye(3) if h[2] > 0 else np.diag([1.0, -1.0, -1.0])
    else:
        e = axis / s
        theta = np.arccos(np.clip(h @ Z, -1, 1))
        ex, ey, ez = e
        c, sn, C = np.cos(theta), np.sin(theta), 1 - np.cos(theta)
        Rv = np.array(
            [
                [c + ex * ex * C, ex * ey * C - ez * sn, ey * sn + ex * ez * C],
                [ez * sn + ex * ey * C, c + ey * ey * C, -ex * sn + ey * ez * C],
                [-ey * sn + ex * ez * C, ex * sn + ey * ez * C, c + ez * ez * C],
            ]
        )
    return Rv.T @ np.diag([1.0, -1.0, -1.0])


def sample_hemisphere_views(
    o_centroid, radius: float, n: int, rng: np.random.Generator, min_elevation_deg: float = 10.0
) -> np.ndarray:
    """(n, 4, 4) T_world_camera on the upper hemisphere of ``radius`` around ``o_centroid`` (eq. 5.3-5.5).

    Positions are uniform on the sphere by Marsaglia's method, reflected to z >= 0 and rejected
    below ``min_elevation_deg`` (views grazing the table see little of the object). ``o_centroid`` is a
    finite (3,) point, ``radius`` finite and > 0, ``n >= 1`` and ``min_elevation_deg`` finite and < 90.

    Shapes:
        o_centroid (3,) world frame, metres -> (n, 4, 4) T_world_camera
    """
    n = as_int(n, "n")
    radius = as_real(radius, "radius", low=0.0, open_low=True)
    min_elevation_deg = as_real(min_elevation_deg, "min_elevation_deg", high=90.0, open_high=True, unit="deg")
    o = as_vector(o_centroid, "o_centroid", 3, "a finite (3,) point")
    out = []
    min_z = np.sin(np.deg2rad(min_elevation_deg))
    while len(out) < n:
        x1, x2 = rng.uniform(-1, 1, size=2)
        s = x1 * x1 + x2 * x2
        if s >= 1:
            continue
        d = np.array([2 * x1 * np.sqrt(1 - s), 2 * x2 * np.sqrt(1 - s), abs(1 - 2 * s)])
        if d[2] < min_z:
            continue
        T = np.eye(4)
        T[:3, 3] = o + radius * d
        T[:3, :3] = viewpoint_rotation(T[:3, 3], o)
        out.append(T)
    return np.stack(out)
