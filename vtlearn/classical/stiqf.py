"""S-TIQF: Stochastic TIQF with scale estimation (thesis ch.5, eq. 5.11-5.18, Algorithm 3).

Three steps on top of :mod:`vtlearn.classical.tiqf`:

1. **Scale** (eq. 5.12, optional): the ratio of the axis-aligned bounding boxes of scene and model,
   ``s = AABB(S) / AABB(O)`` per axis, and ``o' = s . o`` (eq. 5.11). The thesis takes both boxes in their own
   axes, which assumes an unrotated scene. Here the scene box is taken in the model's axes through the
   current rotation estimate and the whole registration is redone with the refined scale (``scale_iters``
   times). Because eq. 5.12 needs a rotation, the very first scale fed
   to the annealing is the rotation-invariant isotropic ratio of RMS radii about the centroids.
2. **Simulated-annealing initial alignment** (eq. 5.13-5.14): cost eq. 5.14 is the mean nearest-neighbour
   distance from the scene points to the transformed model (scene -> model; with a sparse scene this is the
   direction that is defined for every scene point). Geometric cooling ``t <- zeta t`` with ``zeta = 0.98``
   from ``t0 = 1`` to ``t_min = 1e-4`` (456 steps), Metropolis acceptance eq. 5.13, 10 restarts. Proposals
   are neighbourhood moves whose size shrinks with the temperature: a rotation by ``N(0, (pi sqrt(t))^2)``
   radians about each axis and a shift of the model centroid by ``N(0, (r sqrt(t))^2)``, ``r`` the model's RMS
   radius (the cost is divided by ``r`` too, so the temperatures of the thesis, set for [-1, 1]^3 objects,
   apply to any size). The restarts are independent chains run side by side, vectorised: every temperature
   step scores all chains' proposals in one lookup. Each of the 10 restarts runs ``chains_per_restart``
   (default 3) chains: since the per-step cost is mostly fixed call overhead, 30 chains cost less than twice
   10, and on the bunny at 20 scene points they cut the searches that end in a worse basin than the true one
   from 6 to 2 in 30 trials (mean ADI 4.0 -> 3.0 cm). The nearest-neighbour distance is read from a
   distance field of the model cloud (exact on a ``grid``^3 lattice, trilinear in between, exact distance
   to the box outside); ``sa_cost="kdtree"`` uses the exact KD-tree query instead (slower).
3. **Best-buddy pairs** (eq. 5.15): a scene point and its nearest model point are kept only when the scene
   point is also the nearest scene point of that model point; with normals for both clouds, also only when
   the normals agree within ``normal_angle_deg``. Fewer than 3 buddies falls back to all closest points.
4. **TIQF refinement** (eq. 5.16-5.18): the best ``n_refine`` (5) chain results are refined with TIQF on
   best-buddy pairs and the one with the lowest exact eq. 5.14 cost is returned. By default
   (``tangent=True``) the model point of each pair is slid along the model's local tangent plane to the foot
   of the scene point (:class:`TangentPlanes`), and the cost uses that distance: with 1024 model samples the
   sample spacing, not the pose, otherwise limits the accuracy on sparse scenes (measured on the bunny at 20
   scene points: mean ADI 4.0 cm with it, 4.8 cm without). The patches reach two sample spacings and a point
   takes the closest patch of its 8 nearest samples (thin walls, see :class:`TangentPlanes`); the annealing
   field of step 2 holds the distance to the same patches (:func:`annealing_field`).

Conventions: Hamilton quaternions (w, x, y, z); ``T_scene_model`` maps (scaled) model points into the scene:
``s = R (scale . o) + t``; metres.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy.ndimage import map_coordinates
from scipy.spatial import cKDTree

from vtlearn.classical.correspondences import TangentPlanes
from vtlearn.classical.tiqf import TIQF, _matrix_to_quat, _quat_to_matrix
from vtlearn.validation import as_int, as_points, as_real, check_not_collinear

__all__ = [
    "STIQF",
    "STIQFResult",
    "aabb_scale",
    "best_buddy_pairs",
    "DistanceField",
    "annealing_field",
    "simulated_annealing",
    "TangentPlanes",
]


def aabb_scale(scene, model, R=None) -> np.ndarray:
    """Per-axis scale of eq. 5.12: ``|max - min|_S / |max - min|_O`` for x, y, z.

    Args:
        scene: scene cloud S.
        model: model cloud O.
        R: optional rotation estimate ``R_scene_model``; the scene box is then taken in the model axes.

    Shapes:
        scene: ``(N, 3)``; model: ``(M, 3)``; R: ``(3, 3)`` -> ``(3,)``.
    """
    scene = as_points(scene, "scene", min_points=2)
    model = as_points(model, "model", min_points=2)
    if R is not None:
        scene = scene @ np.asarray(R, dtype=np.float64)  # rows R^T s
    ext_s = scene.max(0) - scene.min(0)
    ext_o = model.max(0) - model.min(0)
    if (ext_o <= 0).any():
        raise ValueError(f"model: bounding box is flat (extent {ext_o.tolist()}); scale is undefined")
    scale = ext_s / ext_o
    # a flat scene box along one axis carries no information there: use the mean of the other axes
    flat = scale <= 1e-9
    if flat.all():
        raise ValueError("scene: bounding box has zero extent; scale is undefined")
    scale[flat] = scale[~flat].mean()
    return scale


def _normals_like(normals, cloud: np.ndarray, name: str) -> np.ndarray:
    n = as_points(normals, name)
    if n.shape != cloud.shape:
        raise ValueError(f"{name}: expected shape {cloud.shape} like its cloud, got {n.shape}")
    return n


def best_buddy_pairs(
    scene_in_model,
    model,
    model_tree=None,
    scene_normals_in_model=None,
    model_normals=None,
    normal_angle_deg: float | None = None,
):
    """Mutual nearest neighbours between a scene (already in the model frame) and a model (eq. 5.15).

    Args:
        scene_in_model: finite scene points in the model frame, at least 1.
        model: finite model points, at least 1.
        model_tree: optional prebuilt ``cKDTree(model)`` (must hold as many points as ``model``).
        scene_normals_in_model, model_normals: optional finite normals, one per point of their cloud.
        normal_angle_deg: normal-agreement threshold (degrees, finite); used when both normals are given.

    Returns:
        ``(scene_idx, model_idx)`` index arrays of the best-buddy pairs.

    Shapes:
        scene_in_model: ``(N, 3)``; model: ``(M, 3)``; normals: same shapes as their clouds.
    """
    scene_in_model = as_points(scene_in_model, "scene_in_model", min_points=1)
    model = as_points(model, "model", min_points=1)
    if model_tree is not None and model_tree.n != len(model):
        raise ValueError(f"model_tree: holds {model_tree.n} points, model has {len(model)}")
    if scene_normals_in_model is not None:
        scene_normals_in_model = _normals_like(
            scene_normals_in_model, scene_in_model, "scene_normals_in_model"
        )
    if model_normals is not None:
        model_normals = _normals_like(model_normals, model, "model_normals")
    if normal_angle_deg is not None:
        normal_angle_deg = as_real(normal_angle_deg, "normal_angle_deg", unit="deg")
    return _best_buddy_pairs(
        scene_in_model, model, model_tree, scene_normals_in_model, model_normals, normal_angle_deg
    )


def _best_buddy_pairs(
    scene_in_model, model, model_tree, scene_normals_in_model, model_normals, normal_angle_deg
):
    """:func:`best_buddy_pairs` without the argument checks (called in the TIQF outer loop)."""
    tree = cKDTree(model) if model_tree is None else model_tree
    _, nn_model = tree.query(scene_in_model, k=1)
    _, nn_back = cKDTree(scene_in_model).query(model[nn_model], k=1)
    scene_idx = np.arange(len(scene_in_model))
    keep = nn_back == scene_idx
    if normal_angle_deg is not None and scene_normals_in_model is not None and model_normals is not None:
        cos = np.einsum("nd,nd->n", scene_normals_in_model, model_normals[nn_model])
        keep &= cos >= np.cos(np.radians(normal_angle_deg))
    return scene_idx[keep], nn_model[keep]


class DistanceField:
    """Unsigned distance to a point cloud on a regular lattice, trilinear lookup (S-TIQF's SA cost).

    Args:
        points: the cloud ``(M, 3)``.
        grid: lattice nodes along the longest box side.
        pad: padding of the lattice beyond the cloud's box, as a fraction of its longest side.
        distance_fn: optional ``(K, 3) -> (K,)`` distance to the surface the cloud samples (e.g.
            :meth:`TangentPlanes.distance`) used at the lattice nodes instead of the distance to the points.
    """

    def __init__(
        self,
        points,
        grid: int = 32,
        pad: float = 0.25,
        tree: cKDTree | None = None,
        distance_fn=None,
    ):
        points = as_points(points, "points", min_points=1)
        if isinstance(grid, bool) or not isinstance(grid, int | np.integer) or grid < 2:
            raise ValueError(f"grid: need an integer >= 2 lattice nodes per side, got {grid!r}")
        pad = as_real(pad, "pad", low=0.0)
        lo, hi = points.min(0), points.max(0)
        side = float((hi - lo).max())
        side = side if side > 0 else 1.0
        self.lo = lo - pad * side
        hi = hi + pad * side
        self.h = (side * (1 + 2 * pad)) / (grid - 1)
        self.shape = np.maximum(np.ceil((hi - self.lo) / self.h).astype(int) + 1, 2)
        self.hi = self.lo + (self.shape - 1) * self.h
        axes = [self.lo[k] + self.h * np.arange(self.shape[k]) for k in range(3)]
        nodes = np.stack(np.meshgrid(*axes, indexing="ij"), -1).reshape(-1, 3)
        tree = cKDTree(points) if tree is None else tree
        values = tree.query(nodes, k=1)[0] if distance_fn is None else distance_fn(nodes)
        self.values = np.asarray(values, dtype=np.float64).reshape(tuple(self.shape))

    def __call__(self, q: np.ndarray) -> np.ndarray:
        """Distances for query points ``(..., 3)`` -> ``(...)``."""
        q = np.asarray(q, dtype=np.float64)
        return self.lookup(q[..., 0], q[..., 1], q[..., 2])

    def lookup(self, x: np.ndarray, y: np.ndarray, z: np.ndarray) -> np.ndarray:
        """Distances for coordinates given as three arrays of equal shape ``(...)`` -> ``(...)``.

        Trilinear interpolation is one ``scipy.ndimage.map_coordinates`` call (clamped at the lattice
        border); outside the lattice the exact distance to the lattice box is added.
        """
        q = np.stack([np.ravel(x), np.ravel(y), np.ravel(z)])  # 3xK
        g = (q - self.lo[:, None]) * (1.0 / self.h)
        inside = map_coordinates(self.values, g, order=1, mode="nearest")
        d = np.maximum(np.maximum(self.lo[:, None] - q, q - self.hi[:, None]), 0.0)
        return (inside + np.sqrt((d * d).sum(0))).reshape(np.shape(x))


def annealing_field(
    model, tree: cKDTree, tangent: TangentPlanes | None = None, grid: int = 32
) -> DistanceField:
    """The distance field of S-TIQF's annealing cost (eq. 5.14) for a model cloud.

    With ``tangent`` the lattice holds the distance to the model's tangent patches
    (:meth:`TangentPlanes.distance`), so the annealing scores a pose with the same surface approximation as
    the refinement; without it, the distance to the points. (Keeping the point distance at nodes farther
    than two patch radii saves little CPU but puts a step of up to one patch radius into the field; on the
    three-mesh benchmark at 120 points it raised the mean ADI from 2.12 to 2.50 cm.)

    Shapes:
        model: ``(M, 3)``.
    """
    dist = None
    if tangent is not None:

        def dist(nodes):
            return tangent.distance(nodes, tree)

    return DistanceField(model, grid=grid, tree=tree, distance_fn=dist)


def _rotvec_to_matrix(w: np.ndarray) -> np.ndarray:
    """Rodrigues: rotation vectors ``(..., 3)`` -> ``(..., 3, 3)``."""
    theta = np.linalg.norm(w, axis=-1)[..., None, None]
    k = w / np.maximum(np.linalg.norm(w, axis=-1, keepdims=True), 1e-12)
    x, y, z = np.moveaxis(k, -1, 0)
    o = np.zeros_like(x)
    K = np.stack([np.stack([o, -z, y], -1), np.stack([z, o, -x], -1), np.stack([-y, x, o], -1)], -2)
    return np.eye(3) + np.sin(theta) * K + (1 - np.cos(theta)) * (K @ K)


def _random_rotations(n: int, rng: np.random.Generator) -> np.ndarray:
    q = rng.normal(size=(n, 4))
    q /= np.linalg.norm(q, axis=1, keepdims=True)
    return _quat_to_matrix(q)


def simulated_annealing(
    model,
    scene,
    *,
    cost_fn,
    t0: float = 1.0,
    t_min: float = 1e-4,
    zeta: float = 0.98,
    restarts: int = 10,
    rng=None,
    scale_ref: float | None = None,
):
    """Simulated-annealing initial alignment (eq. 5.13-5.14, Algorithm 3), ``restarts`` parallel chains.

    Args:
        model: model cloud ``(M, 3)`` (already scaled).
        scene: scene cloud ``(N, 3)``.
        cost_fn: maps the x, y, z coordinates ``(C, N)`` each of the scene points expressed in the model frame
            to their nearest-neighbour distances to the model ``(C, N)`` (e.g. :meth:`DistanceField.lookup`).
        t0, t_min, zeta: temperature schedule (thesis: 1, 1e-4, 0.98).
        restarts: number of chains (thesis: 10 restarts).
        rng: seed or ``np.random.Generator``.
        scale_ref: length unit of the cost and of the proposals (default: model RMS radius).

    Returns:
        ``(T_scene_model (C, 4, 4), best_cost (C,))`` per chain, best first.
    """
    zeta = as_real(zeta, "zeta", low=0.0, high=1.0, open_low=True, open_high=True)
    t0 = as_real(t0, "t0")
    t_min = as_real(t_min, "t_min", low=0.0, open_low=True)
    if not t0 > t_min:
        raise ValueError(f"t_min: must satisfy 0 < t_min < t0, got t0={t0}, t_min={t_min}")
    rng = np.random.default_rng(rng)
    model = np.asarray(model, dtype=np.float64)
    scene = np.asarray(scene, dtype=np.float64)
    m_c = model.mean(0)
    r = scale_ref if scale_ref is not None else float(np.sqrt(((model - m_c) ** 2).sum(1).mean()))
    C = restarts
    s_c = scene.mean(0)

    scene_t = np.ascontiguousarray(scene.T)  # 3xN

    def cost(R, c):
        # T = [R, c - R m_c]; the scene in the model frame is R^T (s - c) + m_c
        q = np.swapaxes(R, 1, 2) @ (scene_t[None] - c[:, :, None]) + m_c[None, :, None]  # Cx3xN
        return cost_fn(q[:, 0], q[:, 1], q[:, 2]).mean(-1) / r

    n_steps = int(math.ceil(math.log(t_min / t0) / math.log(zeta)))
    temps = t0 * zeta ** np.arange(1, n_steps + 1)
    # proposal noise does not depend on the state, so it is drawn for all steps at once
    sig = np.sqrt(temps)[:, None, None]
    dR = _rotvec_to_matrix(rng.normal(size=(n_steps, C, 3)) * (math.pi * sig))  # SxCx3x3
    dc_noise = rng.normal(size=(n_steps, C, 3)) * (r * sig)
    u = rng.random((n_steps, C))
    R = _random_rotations(C, rng)
    c = np.repeat(s_c[None], C, 0)
    cur = cost(R, c)
    best_R, best_c, best = R.copy(), c.copy(), cur.copy()
    for k in range(n_steps):
        R_new = dR[k] @ R
        c_new = c + dc_noise[k]
        new = cost(R_new, c_new)
        dc = new - cur
        # eq. 5.13: accept with probability 1 if dc <= 0, else exp(-dc / t)
        accept = (dc <= 0) | (np.exp(-np.maximum(dc, 0) / temps[k]) > u[k])
        R = np.where(accept[:, None, None], R_new, R)
        c = np.where(accept[:, None], c_new, c)
        cur = np.where(accept, new, cur)
        better = cur < best
        if better.any():
            best_R[better], best_c[better], best[better] = R[better], c[better], cur[better]
    order = np.argsort(best)
    T = np.tile(np.eye(4), (C, 1, 1))
    T[:, :3, :3] = best_R
    T[:, :3, 3] = best_c - np.einsum("cij,j->ci", best_R, m_c)
    return T[order], best[order] * r


@dataclass
class STIQFResult:
    """Output of :meth:`STIQF.register`.

    Attributes:
        T_scene_model: ``(4, 4)`` maps *scaled* model points ``scale * o`` into the scene.
        scale: per-axis scale ``(3,)`` (ones when not estimated).
        iterations: TIQF outer iterations of the returned solution.
        rmse: RMSE of the final best-buddy (or closest-point) correspondence distances (m).
        cost: eq. 5.14 cost (mean scene-to-model NN distance, m) of the returned pose.
        sa_cost: best annealing cost (m).
    """

    T_scene_model: np.ndarray
    scale: np.ndarray
    iterations: int
    rmse: float
    cost: float
    sa_cost: float


class STIQF:
    """S-TIQF registration (Algorithm 3).

    Args:
        estimate_scale: estimate a per-axis scale (eq. 5.12).
        t0, t_min, zeta, restarts: annealing schedule (thesis 5.2.4: 1, 1e-4, 0.98, 10).
        chains_per_restart: independent chains per restart, run in parallel with the others.
        sa_max_points: if set, the annealing cost (eq. 5.14) uses a random subset of at most this many scene
            points (the TIQF refinement always uses all of them); ``None`` uses all, as the thesis does.
            64 cut the CPU time at 120 scene points from about 0.43 to 0.26 s on the bunny at the same
            accuracy (30 trials), but on the three-mesh benchmark the mean ADI at 80/120 points rose from
            2.62/2.24 to 3.19/2.62 cm, so the default keeps all points.
        sa_cost: ``"field"`` (distance-field lookup) or ``"kdtree"`` (exact).
        grid: distance-field resolution.
        n_refine: how many chain results TIQF refines.
        best_buddies: use best-buddy pairs (eq. 5.15) instead of plain closest points.
        normal_angle_deg: normal-agreement threshold for best buddies (needs normals for both clouds).
        rho, max_iter, tol_trans, tol_rot_deg, n_escapes: passed to :class:`~vtlearn.classical.tiqf.TIQF`.
        scale_iters: scale re-estimations in the model axes after registration.
        tangent: sub-sample correspondences on local tangent planes (:class:`TangentPlanes`).
        tangent_cap: tangent patch radius in median sample spacings (``TangentPlanes(cap_factor=...)``).
        tangent_patches: a point is matched to the closest patch of its this many nearest samples.
        tangent_k: neighbours of the PCA normal of each patch (``TangentPlanes(k=...)``). The patch normal,
            not its curvature, dominates the surface error at the true pose: on the mug the mean
            distance of true surface points to the patches is 1.06 cm with k = 10, 0.66 cm with k = 24 and
            0.34 cm with the exact mesh normals (a quadric patch did not help). With 12 trials per mesh,
            k = 24 instead of 10 moved the mean ADI of bunny / mug / spray bottle at 20 / 40 / 80 / 120
            points from 4.11 / 3.51 / 2.32 / 2.18 to 4.17 / 2.97 / 1.83 / 1.85 cm.
        sa_field: ``"tangent"``: the annealing distance field holds the distance to the tangent patches (the
            refinement's surface); ``"points"``: the distance to the sample points. On the three-mesh
            benchmark (18 trials per size) 2 spacings, 8 patches and the tangent field lowered the mean ADI
            from 4.50 / 3.71 / 2.62 / 2.24 to 4.18 / 3.52 / 2.10 / 2.12 cm at 20 / 40 / 80 / 120 points, for
            about 0.07 s more CPU at 120 points.
        seed: makes the whole run reproducible.
    """

    def __init__(
        self,
        estimate_scale: bool = False,
        t0: float = 1.0,
        t_min: float = 1e-4,
        zeta: float = 0.98,
        restarts: int = 10,
        sa_cost: str = "field",
        grid: int = 32,
        n_refine: int = 5,
        chains_per_restart: int = 3,
        sa_max_points: int | None = None,
        best_buddies: bool = True,
        normal_angle_deg: float | None = None,
        rho: float = 1e-2,
        max_iter: int = 100,
        tol_trans: float = 1e-4,
        tol_rot_deg: float = 0.1,
        n_escapes: int = 0,
        scale_iters: int = 2,
        tangent: bool = True,
        tangent_cap: float = 2.0,
        tangent_patches: int = 8,
        tangent_k: int = 24,
        sa_field: str = "tangent",
        seed: int | None = 0,
    ):
        if sa_field not in ("points", "tangent"):
            raise ValueError(f"sa_field: expected 'points' or 'tangent', got {sa_field!r}")
        as_real(tangent_cap, "tangent_cap", low=0.0)
        tangent_patches = as_int(tangent_patches, "tangent_patches")
        tangent_k = as_int(tangent_k, "tangent_k", minimum=3)
        self.tangent_k = tangent_k
        self.tangent_cap, self.tangent_patches, self.sa_field = tangent_cap, tangent_patches, sa_field
        if sa_cost not in ("field", "kdtree"):
            raise ValueError(f"sa_cost: expected 'field' or 'kdtree', got {sa_cost!r}")
        restarts = as_int(restarts, "restarts")
        self.chains_per_restart = as_int(chains_per_restart, "chains_per_restart")
        if sa_max_points is not None:
            sa_max_points = as_int(sa_max_points, "sa_max_points", minimum=3)
        self.sa_max_points = sa_max_points
        n_refine = as_int(n_refine, "n_refine")
        if isinstance(grid, bool) or not isinstance(grid, int | np.integer) or grid < 2:
            raise ValueError(f"grid: need an integer >= 2 distance-field nodes per side, got {grid!r}")
        # the annealing temperature t <- zeta t must fall to t_min
        as_real(zeta, "zeta", low=0.0, high=1.0, open_low=True, open_high=True)
        if not as_real(t_min, "t_min", low=0.0, open_low=True) < as_real(t0, "t0"):
            raise ValueError(f"t0, t_min: need 0 < t_min < t0, got t0={t0}, t_min={t_min}")
        self.estimate_scale = estimate_scale
        self.t0, self.t_min, self.zeta, self.restarts = t0, t_min, zeta, restarts
        self.sa_cost, self.grid, self.n_refine = sa_cost, grid, n_refine
        self.best_buddies = best_buddies
        self.normal_angle_deg = normal_angle_deg
        self.scale_iters = scale_iters
        self.tangent = tangent
        self.seed = seed
        self.tiqf = TIQF(
            rho=rho,
            max_iter=max_iter,
            tol_trans=tol_trans,
            tol_rot_deg=tol_rot_deg,
            n_escapes=n_escapes,
            seed=seed,
        )

    def __repr__(self) -> str:
        return (
            f"STIQF(estimate_scale={self.estimate_scale}, zeta={self.zeta}, t0={self.t0}, "
            f"t_min={self.t_min}, restarts={self.restarts}, sa_cost={self.sa_cost!r})"
        )

    def tangent_planes(self, model, tree: cKDTree) -> TangentPlanes:
        """The model's tangent patches with this instance's settings (refinement and annealing field).

        Shapes:
            model: ``(M, 3)``.
        """
        return TangentPlanes(
            model, tree, k=self.tangent_k, cap_factor=self.tangent_cap, n_patches=self.tangent_patches
        )

    def _correspondence_fn(self, model, tree, model_normals, scene, scene_normals, tangent):
        def corr(scene_in_model, R, t):
            if self.best_buddies:
                sn = None if scene_normals is None else scene_normals @ R  # rows R^T n
                si, mi = _best_buddy_pairs(
                    scene_in_model, model, tree, sn, model_normals, self.normal_angle_deg
                )
            else:
                si = np.arange(0)
            if len(si) < 3:
                _, mi = tree.query(scene_in_model, k=1)
                si = np.arange(len(scene_in_model))
            o = model[mi]
            if tangent is not None:
                o = tangent.closest(scene_in_model[si], tree)[1]
            return scene[si], o

        return corr

    def _register_scaled(self, model, scene, rng, model_normals, scene_normals):
        tree = cKDTree(model)
        tangent = None
        if self.tangent:
            tangent = self.tangent_planes(model, tree)
        if self.sa_cost == "field":
            surface = tangent if self.sa_field == "tangent" else None
            field = annealing_field(model, tree, surface, grid=self.grid)
            cost_fn = field.lookup
        else:

            def cost_fn(x, y, z):
                return tree.query(np.stack([x, y, z], -1).reshape(-1, 3), k=1)[0].reshape(x.shape)

        sa_scene = scene
        if self.sa_max_points is not None and len(scene) > self.sa_max_points:
            sa_scene = scene[rng.choice(len(scene), self.sa_max_points, replace=False)]
        T_sa, c_sa = simulated_annealing(
            model,
            sa_scene,
            cost_fn=cost_fn,
            t0=self.t0,
            t_min=self.t_min,
            zeta=self.zeta,
            restarts=self.restarts * self.chains_per_restart,
            rng=rng,
        )
        corr = self._correspondence_fn(model, tree, model_normals, scene, scene_normals, tangent)
        best = None
        for k in range(min(self.n_refine, len(T_sa))):
            res = self.tiqf.register(model, scene, T_init=T_sa[k], model_tree=tree, correspondences=corr)
            R, t = res.T_scene_model[:3, :3], res.T_scene_model[:3, 3]
            q = (scene - t) @ R
            cost = float((tangent.distance(q, tree) if tangent is not None else tree.query(q, k=1)[0]).mean())
            if best is None or cost < best[1]:
                best = (res, cost)
        return best[0], best[1], float(c_sa[0])

    def register(self, model, scene, model_normals=None, scene_normals=None) -> STIQFResult:
        """Estimate scale, rotation and translation with ``scene ~ R (scale . model) + t``.

        Shapes:
            model: ``(M, 3)``; scene: ``(N, 3)``, N >= 3, not collinear; normals: like their clouds.
        """
        model = as_points(model, "model", min_points=3)
        scene = as_points(scene, "scene", min_points=3)
        check_not_collinear(scene, "scene")
        if model_normals is not None:
            model_normals = as_points(model_normals, "model_normals", min_points=len(model))
        if scene_normals is not None:
            scene_normals = as_points(scene_normals, "scene_normals", min_points=len(scene))
        rng = np.random.default_rng(self.seed)
        scale = np.ones(3)
        if self.estimate_scale:
            r_s = np.sqrt(((scene - scene.mean(0)) ** 2).sum(1).mean())
            r_o = np.sqrt(((model - model.mean(0)) ** 2).sum(1).mean())
            if r_o <= 0:
                raise ValueError("model: all points coincide; scale is undefined")
            scale = np.full(3, r_s / r_o)
        res, cost, sa_cost = self._register_scaled(model * scale, scene, rng, model_normals, scene_normals)
        if self.estimate_scale:
            # eq. 5.12 in the model axes of the current rotation, then the whole S-TIQF again with that scale
            for _ in range(self.scale_iters):
                scale = aabb_scale(scene, model, res.T_scene_model[:3, :3])
                res, cost, sa_cost = self._register_scaled(
                    model * scale, scene, rng, model_normals, scene_normals
                )
        return STIQFResult(
            T_scene_model=res.T_scene_model,
            scale=scale,
            iterations=res.iterations,
            rmse=res.rmse,
            cost=cost,
            sa_cost=sa_cost,
        )


def quat_of(T: np.ndarray) -> np.ndarray:
    """Rotation quaternion (w, x, y, z) of a ``(4, 4)`` transform (convenience for reports)."""
    return _matrix_to_quat(np.asarray(T)[:3, :3])
