"""One registration API for TIQF, S-TIQF and the peer baselines of thesis ch.5 (5.3.3, Fig. 5.15).

``register(model, scene, method=..., **options) -> RegistrationResult`` estimates ``T_scene_model`` (and a
per-axis scale for S-TIQF) from a model cloud and a scene cloud with unknown correspondences.

Methods:
    ``tiqf``, ``stiqf`` (this package); ``icp`` (point-to-point) and ``icp_plane`` (point-to-plane, model
    normals) from Open3D; ``sparse_icp`` (Bouaziz et al. 2013, :mod:`vtlearn.classical.sparse_icp`);
    ``ransac_fpfh`` and ``fgr`` (Open3D FPFH feature matching); ``filterreg`` and ``cpd`` through probreg when
    that optional extra is installed (``pip install -e .[probreg]``).

Every method goes through the same random-restart wrapper (``restarts=K`` or ``time_budget=seconds``): restart
``k > 0`` moves the model by a random rotation about its centroid and puts its centroid on the scene
centroid, runs the method from there, composes the result, and the restart with the lowest final
correspondence RMSE (scene to transformed model) wins. Restart 0 is the caller's ``T_init`` (identity by
default), so ``restarts=0`` is the plain method. Conventions: ``T_scene_model`` maps model points into the
scene, ``scene ~ R (scale . model) + t``; metres.
"""

from __future__ import annotations

import importlib.util
import time
from dataclasses import asdict, dataclass

import numpy as np
from scipy.spatial import cKDTree

from vtlearn.classical.sparse_icp import sparse_icp
from vtlearn.classical.stiqf import STIQF
from vtlearn.classical.tiqf import TIQF, _quat_to_matrix
from vtlearn.validation import as_int, as_points, as_real, as_transform, check_not_collinear

__all__ = ["RegistrationResult", "register", "METHODS", "available_methods"]


@dataclass
class RegistrationResult:
    """Result of :func:`register`.

    Attributes:
        R: ``(3, 3)`` rotation; t: ``(3,)`` translation; scale: ``(3,)`` per-axis model scale.
        T_scene_model: ``(4, 4)`` maps (scaled) model points into the scene.
        iterations: the method's iterations summed over restarts (0 where the library does not report them).
        time: wall-clock seconds of the whole call.
        cpu_time: CPU seconds of this process during the call (all threads; on a shared machine a steadier
            speed measure than the wall clock for single-threaded methods such as TIQF/S-TIQF).
        rmse: RMSE of the scene-to-model nearest-neighbour distances at the returned pose (m).
        method: the method name; restarts: restarts run beyond the first.
    """

    R: np.ndarray
    t: np.ndarray
    scale: np.ndarray
    T_scene_model: np.ndarray
    iterations: int
    time: float
    rmse: float
    method: str
    restarts: int = 0
    cpu_time: float = 0.0

    def to_dict(self) -> dict:
        d = asdict(self)
        for k in ("R", "t", "scale", "T_scene_model"):
            d[k] = np.asarray(d[k]).tolist()
        return d


# ------------------------------------------------------------------------------------------------------------
# Methods: each maps (model, scene, rng, options) -> (T_scene_model, scale, iterations)
def _o3d():
    import open3d as o3d

    # FPFH on a sparse scene often finds too few matches; that is a measured outcome, not worth a warning
    o3d.utility.set_verbosity_level(o3d.utility.VerbosityLevel.Error)
    return o3d


def _pcd(points, normals_radius=None):
    o3d = _o3d()
    pc = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(np.ascontiguousarray(points)))
    if normals_radius is not None:
        pc.estimate_normals(o3d.geometry.KDTreeSearchParamHybrid(radius=normals_radius, max_nn=30))
    return pc


def _diameter(points):
    return float(np.linalg.norm(points.max(0) - points.min(0)))


_TIQF_OPTIONS = ("rho", "sigma0", "max_iter", "tol_trans", "tol_rot_deg", "n_escapes", "escape_deg")
_STIQF_OPTIONS = (
    "estimate_scale",
    "t0",
    "t_min",
    "zeta",
    "restarts_sa",
    "sa_cost",
    "grid",
    "n_refine",
    "best_buddies",
    "normal_angle_deg",
    "rho",
    "max_iter",
    "tol_trans",
    "tol_rot_deg",
    "n_escapes",
    "scale_iters",
    "tangent",
    "tangent_cap",
    "tangent_patches",
    "tangent_k",
    "sa_field",
    "chains_per_restart",
    "sa_max_points",
)
_STIQF_REGISTER_OPTIONS = ("model_normals", "scene_normals")  # arguments of STIQF.register, not of STIQF


def _run_tiqf(model, scene, rng, opts):
    res = TIQF(seed=int(rng.integers(1 << 31)), **{k: opts[k] for k in _TIQF_OPTIONS if k in opts}).register(
        model, scene
    )
    return res.T_scene_model, np.ones(3), res.iterations


def _run_stiqf(model, scene, rng, opts):
    kw = {k: opts[k] for k in _STIQF_OPTIONS if k in opts}
    if "restarts_sa" in kw:
        kw["restarts"] = kw.pop("restarts_sa")
    res = STIQF(seed=int(rng.integers(1 << 31)), **kw).register(
        model, scene, model_normals=opts.get("model_normals"), scene_normals=opts.get("scene_normals")
    )
    return res.T_scene_model, res.scale, res.iterations


def _run_icp(model, scene, rng, opts, plane=False):
    o3d = _o3d()
    reg = o3d.pipelines.registration
    diam = _diameter(model)
    # source = scene (sparse), target = model (dense, carries the normals for point-to-plane)
    target = _pcd(model, normals_radius=0.05 * diam if plane else None)
    source = _pcd(scene)
    est = reg.TransformationEstimationPointToPlane() if plane else reg.TransformationEstimationPointToPoint()
    crit = reg.ICPConvergenceCriteria(
        relative_fitness=1e-7, relative_rmse=1e-7, max_iteration=int(opts.get("max_iter", 100))
    )
    thr = float(opts.get("max_correspondence_distance", 10.0 * diam))
    r = reg.registration_icp(source, target, thr, np.eye(4), est, crit)
    return np.linalg.inv(np.asarray(r.transformation)), np.ones(3), 0


def _run_sparse_icp(model, scene, rng, opts):
    T_model_scene, it = sparse_icp(
        scene,
        model,
        p=float(opts.get("p", 0.4)),
        mu=float(opts.get("mu", 10.0)),
        max_icp=int(opts.get("max_iter", 100)),
    )
    return np.linalg.inv(T_model_scene), np.ones(3), it


def _fpfh(pc, voxel):
    o3d = _o3d()
    pc.estimate_normals(o3d.geometry.KDTreeSearchParamHybrid(radius=2 * voxel, max_nn=30))
    return o3d.pipelines.registration.compute_fpfh_feature(
        pc, o3d.geometry.KDTreeSearchParamHybrid(radius=5 * voxel, max_nn=100)
    )


def _run_feature(model, scene, rng, opts, fgr=False):
    o3d = _o3d()
    reg = o3d.pipelines.registration
    voxel = float(opts.get("voxel_size", 0.05 * _diameter(model)))
    source, target = _pcd(scene), _pcd(model)
    fs, ft = _fpfh(source, voxel), _fpfh(target, voxel)
    dist = 1.5 * voxel
    if fgr:
        r = reg.registration_fgr_based_on_feature_matching(
            source, target, fs, ft, reg.FastGlobalRegistrationOption(maximum_correspondence_distance=dist)
        )
    else:
        o3d.utility.random.seed(int(rng.integers(1 << 31)))
        r = reg.registration_ransac_based_on_feature_matching(
            source,
            target,
            fs,
            ft,
            True,
            dist,
            reg.TransformationEstimationPointToPoint(False),
            3,
            [reg.CorrespondenceCheckerBasedOnEdgeLength(0.9), reg.CorrespondenceCheckerBasedOnDistance(dist)],
            reg.RANSACConvergenceCriteria(int(opts.get("max_iter", 100000)), 0.999),
        )
    return np.linalg.inv(np.asarray(r.transformation)), np.ones(3), 0


def _run_probreg(model, scene, rng, opts, kind):
    from probreg import cpd, filterreg

    if kind == "cpd":
        tf, _, _ = cpd.registration_cpd(scene, model, maxiter=int(opts.get("max_iter", 100)))
    else:
        tf, _, _ = filterreg.registration_filterreg(scene, model, maxiter=int(opts.get("max_iter", 100)))
    T = np.eye(4)
    T[:3, :3] = np.asarray(tf.rot)
    T[:3, 3] = np.asarray(tf.t)
    return np.linalg.inv(T), np.ones(3), 0


METHODS = {
    "tiqf": _run_tiqf,
    "stiqf": _run_stiqf,
    "icp": lambda m, s, r, o: _run_icp(m, s, r, o, plane=False),
    "icp_plane": lambda m, s, r, o: _run_icp(m, s, r, o, plane=True),
    "sparse_icp": _run_sparse_icp,
    "ransac_fpfh": lambda m, s, r, o: _run_feature(m, s, r, o, fgr=False),
    "fgr": lambda m, s, r, o: _run_feature(m, s, r, o, fgr=True),
    "filterreg": lambda m, s, r, o: _run_probreg(m, s, r, o, "filterreg"),
    "cpd": lambda m, s, r, o: _run_probreg(m, s, r, o, "cpd"),
}
_NEEDS_PROBREG = {"filterreg", "cpd"}
# the **options each method reads; register() refuses any other, so a misspelt or inapplicable option is an
# error rather than a silent default
METHOD_OPTIONS: dict[str, tuple[str, ...]] = {
    "tiqf": _TIQF_OPTIONS,
    "stiqf": _STIQF_OPTIONS + _STIQF_REGISTER_OPTIONS,
    "icp": ("max_iter", "max_correspondence_distance"),
    "icp_plane": ("max_iter", "max_correspondence_distance"),
    "sparse_icp": ("p", "mu", "max_iter"),
    "ransac_fpfh": ("voxel_size", "max_iter"),
    "fgr": ("voxel_size",),
    "filterreg": ("max_iter",),
    "cpd": ("max_iter",),
}


def available_methods() -> list[str]:
    """Methods usable in this environment (probreg ones only when probreg is importable)."""
    have_probreg = importlib.util.find_spec("probreg") is not None
    return [m for m in METHODS if have_probreg or m not in _NEEDS_PROBREG]


# ------------------------------------------------------------------------------------------------------------
def _random_rotation(rng) -> np.ndarray:
    q = rng.normal(size=4)
    return _quat_to_matrix(q / np.linalg.norm(q))


def _restart_pose(model, scene, rng) -> np.ndarray:
    """``T`` that rotates the model randomly about its centroid and puts the centroid on the scene's."""
    R = _random_rotation(rng)
    T = np.eye(4)
    T[:3, :3] = R
    T[:3, 3] = scene.mean(0) - R @ model.mean(0)
    return T


def _nn_rmse(tree, scene, T) -> float:
    R, t = T[:3, :3], T[:3, 3]
    d, _ = tree.query((scene - t) @ R, k=1)
    return float(np.sqrt(np.mean(d**2)))


def register(
    model,
    scene,
    method: str = "stiqf",
    *,
    T_init=None,
    restarts: int = 0,
    time_budget: float | None = None,
    seed: int | None = 0,
    **options,
) -> RegistrationResult:
    """Register ``model`` to ``scene`` with any method; see the module doc.

    Args:
        model: model cloud O (e.g. 1024 points sampled from a CAD mesh or a reconstruction).
        scene: scene cloud S (dense visual or sparse tactile, at least 3 non-collinear points).
        method: one of :data:`METHODS`.
        T_init: initial ``T_scene_model`` for restart 0 (default identity).
        restarts: extra random restarts (the common wrapper).
        time_budget: if given, seconds >= 0: keep restarting until they have passed (``restarts`` is then
            ignored; the first run always happens); used for time-matched comparisons.
        seed: seeds every random choice.
        **options: method options, e.g. ``estimate_scale=True`` for S-TIQF, ``max_iter``, ``rho``,
            ``p``/``mu`` for sparse ICP, ``voxel_size`` for FPFH, ``model_normals``/``scene_normals`` for
            S-TIQF; :data:`METHOD_OPTIONS` lists each method's, and any other is refused.

    Shapes:
        model: ``(M, 3)``; scene: ``(N, 3)``, N >= 3; T_init: ``(4, 4)``.

    Raises:
        ValueError: unknown or unavailable method, an option the method does not take, fewer than 3 points,
            NaN/inf, a collinear scene, or a non-rigid ``T_init``.
    """
    if method not in METHODS:
        raise ValueError(f"method: unknown {method!r}; choose from {sorted(METHODS)}")
    if method in _NEEDS_PROBREG and importlib.util.find_spec("probreg") is None:
        raise ValueError(f"method: {method!r} needs the optional probreg extra (pip install -e .[probreg])")
    model = as_points(model, "model", min_points=3)
    scene = as_points(scene, "scene", min_points=3)
    check_not_collinear(scene, "scene")
    check_not_collinear(model, "model")
    unknown = sorted(set(options) - set(METHOD_OPTIONS[method]))
    if unknown:
        raise ValueError(f"options: method {method!r} takes no {', '.join(map(repr, unknown))}; its options "
                         f"are {', '.join(METHOD_OPTIONS[method])}")
    restarts = as_int(restarts, "restarts", minimum=0)
    if time_budget is not None:
        time_budget = as_real(time_budget, "time_budget", low=0.0, unit="s")
    T0 = np.eye(4) if T_init is None else as_transform(T_init, "T_init")
    if options.get("estimate_scale") and (restarts or time_budget is not None or T_init is not None):
        # a scale in the model axes does not compose with a pre-move of the model
        raise ValueError("estimate_scale: cannot be combined with restarts, time_budget or T_init")
    rng = np.random.default_rng(seed)
    run = METHODS[method]
    start = time.perf_counter()
    cpu_start = time.process_time()
    best = None
    iterations = 0
    k = 0
    while True:
        T_pre = T0 if k == 0 else _restart_pose(model, scene, rng)
        moved = model @ T_pre[:3, :3].T + T_pre[:3, 3]
        T_found, scale, it = run(moved, scene, rng, options)
        iterations += int(it)
        T = T_found @ T_pre  # T_found maps (scale . moved) into the scene; T_pre is identity when scaling
        model_s = model * scale
        rmse = _nn_rmse(cKDTree(model_s), scene, T)
        if best is None or rmse < best[0]:
            best = (rmse, T, scale)
        k += 1
        elapsed = time.perf_counter() - start
        if time_budget is not None:
            if elapsed >= time_budget:
                break
        elif k > restarts:
            break
    rmse, T, scale = best
    return RegistrationResult(
        R=T[:3, :3].copy(),
        t=T[:3, 3].copy(),
        scale=np.asarray(scale, dtype=np.float64),
        T_scene_model=T,
        iterations=iterations,
        time=time.perf_counter() - start,
        rmse=rmse,
        method=method,
        restarts=k - 1,
        cpu_time=time.process_time() - cpu_start,
    )
