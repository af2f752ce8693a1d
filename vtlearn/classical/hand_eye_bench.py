"""``vtlearn bench hand-eye``: in-situ visuo-tactile hand-eye calibration in simulation (thesis 5.3.4,
Fig. 5.20e analogue).

Each trial draws a true hand-eye matrix ``T_E_C`` (camera 5-10 cm from the flange, any rotation), fixes a
object of about 15 cm on the table, and captures it from ``views`` end-effector poses ``T_W_E`` that look at
it from 0.35-0.5 m above and around. The visual cloud of a view is the object's surface samples facing the
camera (a one-sided cloud, as a depth camera sees it), expressed in the camera frame with Gaussian noise; the
tactile cloud is ``n_tactile`` surface points in the world frame with smaller noise (eq. 5.22; the tactile
arm's kinematics are taken as exact, as the thesis does). Every registration method of
:func:`vtlearn.classical.registration.register` then calibrates through :func:`in_situ_hand_eye`:

* global methods (S-TIQF, the thesis's; RANSAC-FPFH; FGR) start from nothing;
* local methods (TIQF, ICP) start from a nominal calibration off by ``init_trans`` metres and
  ``init_rot_deg`` degrees, the situation of a slightly wrong calibration that needs correcting;
* ``nominal`` reports that starting error itself.

Errors are the position and rotation error of ``T_E_C`` against the truth; the thesis reports < 1 cm and
< 5 degrees on real objects (5.3.4).
"""

from __future__ import annotations

import time

import numpy as np

from vtlearn.classical.hand_eye import LOCAL_METHODS, in_situ_hand_eye
from vtlearn.validation import as_int

__all__ = ["run_hand_eye_benchmark", "THESIS_BOUNDS"]

THESIS_BOUNDS = {"position_mm": 10.0, "rotation_deg": 5.0}
DEFAULT_METHODS = ("stiqf", "ransac_fpfh", "fgr", "tiqf", "icp")


def _look_at(eye: np.ndarray, target: np.ndarray, rng) -> np.ndarray:
    """``T_W_C`` of a camera at ``eye`` whose optical axis z points at ``target`` (random roll)."""
    z = target - eye
    z = z / np.linalg.norm(z)
    a = rng.normal(size=3)
    x = a - (a @ z) * z
    x = x / np.linalg.norm(x)
    T = np.eye(4)
    T[:3, :3] = np.stack([x, np.cross(z, x), z], axis=1)
    T[:3, 3] = eye
    return T


def _small_rotation(rng, deg: float) -> np.ndarray:
    """A rotation by ``deg`` degrees about a uniformly random axis."""
    from vtlearn.geometry import so3_exp

    axis = rng.normal(size=3)
    return np.asarray(so3_exp(np.radians(deg) * axis / np.linalg.norm(axis)), dtype=np.float64)


def _errors(T, X) -> tuple[float, float]:
    """(position error in mm, rotation error in degrees) of ``T`` against ``X``."""
    from vtlearn.geometry import rotation_error_deg, translation_error

    return 1e3 * translation_error(T[:3, 3], X[:3, 3]), rotation_error_deg(T[:3, :3], X[:3, :3])


def _trial(mesh, rng, views: int, n_visual: int, n_tactile: int, visual_noise: float, tactile_noise: float,
           one_sided: bool = True):
    import trimesh

    from vtlearn.geometry import random_pose

    m = mesh.copy()
    m.apply_scale(0.15 / float(m.extents.max()))
    T_W_O = random_pose(seed=rng)
    T_W_O[:3, 3] = [0.5, 0.0, 0.1]
    m.apply_transform(T_W_O)
    X = random_pose(seed=rng)
    X[:3, 3] = rng.uniform(-0.1, 0.1, 3)
    X[:3, 3] *= rng.uniform(0.05, 0.1) / np.linalg.norm(X[:3, 3])
    target = m.bounds.mean(0)
    pts, face = trimesh.sample.sample_surface(m, 6 * n_visual, seed=int(rng.integers(2**31)))
    normals = m.face_normals[face]
    visual, poses = [], []
    for _ in range(views):
        az, el = rng.uniform(0, 2 * np.pi), rng.uniform(np.radians(30), np.radians(70))
        dist = rng.uniform(0.35, 0.5)
        eye = target + dist * np.array([np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.sin(el)])
        T_W_C = _look_at(eye, target, rng)
        # one-sided: the surface facing the camera, as a depth camera sees it; else the whole surface
        seen = ((eye - pts) * normals).sum(1) > 0 if one_sided else np.ones(len(pts), dtype=bool)
        P = pts[seen][rng.permutation(int(seen.sum()))[:n_visual]]
        P_C = (P - T_W_C[:3, 3]) @ T_W_C[:3, :3] + rng.normal(0, visual_noise, P.shape)
        visual.append(P_C)
        poses.append(T_W_C @ np.linalg.inv(X))  # T_W_E = T_W_C T_E_C^-1
    tactile = np.asarray(trimesh.sample.sample_surface(m, n_tactile, seed=int(rng.integers(2**31)))[0])
    tactile = tactile + rng.normal(0, tactile_noise, tactile.shape)
    return X, visual, np.stack(poses), tactile


def run_hand_eye_benchmark(meshes, trials: int = 5, views: int = 3, n_visual: int = 1024,
                           n_tactile: int = 60, visual_noise: float = 1e-3, tactile_noise: float = 5e-4,
                           init_trans: float = 0.02, init_rot_deg: float = 5.0, methods=DEFAULT_METHODS,
                           one_sided: bool = True, seed: int = 0, progress: bool = True) -> dict:
    """Calibration errors of every method over ``trials`` trials per mesh (module docstring).

    Args:
        meshes: ``(name, trimesh)`` pairs.
        trials, views: trials per mesh, captures per trial.
        n_visual, n_tactile: points per visual cloud and in the tactile cloud.
        visual_noise, tactile_noise: Gaussian noise std (m).
        init_trans, init_rot_deg: error of the nominal calibration the local methods start from.
        methods: registration methods.
        one_sided: each visual cloud holds only the surface facing the camera (a depth view); False gives
            every view the whole surface (an idealised complete object cloud, e.g. from a fixed rig).

    Returns:
        ``{"runs": [...], "summary": {method: {...}}, "settings": {...}}``.
    """
    from tqdm.auto import tqdm

    from vtlearn.classical.registration import METHODS

    methods = list(methods)
    unknown = [m for m in methods if m not in METHODS]
    if unknown:
        raise ValueError(f"methods: unknown {unknown}; choose from {sorted(METHODS)}")
    for name, value, low in (("trials", trials, 1), ("views", views, 1), ("n_tactile", n_tactile, 3),
                             ("n_visual", n_visual, 3)):
        as_int(value, name, minimum=low)
    rng = np.random.default_rng(seed)
    runs = []
    bar = tqdm(total=len(meshes) * trials, desc="bench hand-eye", disable=not progress)
    for mesh_name, mesh in meshes:
        for trial in range(trials):
            X, visual, poses, tactile = _trial(mesh, rng, views, n_visual, n_tactile, visual_noise,
                                               tactile_noise, one_sided)
            nominal = X.copy()
            nominal[:3, :3] = X[:3, :3] @ _small_rotation(rng, init_rot_deg)
            d = rng.normal(size=3)
            nominal[:3, 3] += init_trans * d / np.linalg.norm(d)
            runs.append({"mesh": mesh_name, "trial": trial, "method": "nominal",
                         **dict(zip(("position_mm", "rotation_deg"), _errors(nominal, X), strict=True)),
                         "seconds": 0.0})
            for method in methods:
                t0 = time.perf_counter()
                res = in_situ_hand_eye(visual, tactile, poses, method=method,
                                       T_E_C_init=nominal if method in LOCAL_METHODS else None, seed=trial)
                pos, rot = _errors(res.T_E_C, X)
                runs.append({"mesh": mesh_name, "trial": trial, "method": method, "position_mm": pos,
                             "rotation_deg": rot, "seconds": time.perf_counter() - t0,
                             "spread_mm": 1e3 * res.spread_m})
            bar.update()
    bar.close()
    summary = {}
    for method in ["nominal", *methods]:
        r = [x for x in runs if x["method"] == method]
        pos = np.array([x["position_mm"] for x in r])
        rot = np.array([x["rotation_deg"] for x in r])
        summary[method] = {
            "position_mm_median": float(np.median(pos)), "position_mm_mean": float(pos.mean()),
            "rotation_deg_median": float(np.median(rot)), "rotation_deg_mean": float(rot.mean()),
            "within_thesis_bounds": float(np.mean((pos < THESIS_BOUNDS["position_mm"])
                                                  & (rot < THESIS_BOUNDS["rotation_deg"]))),
            "seconds_mean": float(np.mean([x["seconds"] for x in r])),
            "start": "nominal" if method in LOCAL_METHODS else ("-" if method == "nominal" else "none"),
            "position_mm_median_per_mesh": {
                name: float(np.median([x["position_mm"] for x in r if x["mesh"] == name]))
                for name, _ in meshes
            },
        }
    settings = {"meshes": [n for n, _ in meshes], "trials": trials, "views": views, "n_visual": n_visual,
                "n_tactile": n_tactile, "visual_noise": visual_noise, "tactile_noise": tactile_noise,
                "init_trans": init_trans, "init_rot_deg": init_rot_deg, "one_sided": one_sided, "seed": seed}
    return {"runs": runs, "summary": summary, "settings": settings, "thesis": THESIS_BOUNDS}
