"""Active touch by expected information gain for TIQF (thesis 4.2.4, Algorithm 1, eq. 4.24-4.25, Table 4.1).

Each step:

1. **Actions** (thesis 4.2.4): rays ``a = (n, d)`` whose start points are uniform on the faces of the model's
   bounding box (inflated by a margin) at the current estimate ``T_scene_model``, pointing inwards along the
   face normal (the coordinate-axis directions of the robot experiments, 4.3.3). ``faces`` picks which of
   the six faces (default all; the robot experiments drop the bottom, ``-z``).
2. **Hypothetical measurements** ``z^``: ray-mesh intersection with the mesh at the estimated pose (Open3D
   ``RaycastingScene``; the rays are moved into the model frame, so the scene is built once per mesh).
3. **One-step look-ahead**, batched over all candidates: the TIQF update (eq. 4.18-4.22) of the current
   belief with the pairs that the new point forms with every measured point. A new point ``w = (z^, o^)``
   paired with points ``v_i = (s_i, o_i)`` has the pair moment ``sum_i (w - v_i)(w - v_i)^T =
   n (w - v_mean)(w - v_mean)^T + n Cov(v)``, so all candidates cost one batched 4x4 update
   (:func:`~vtlearn.classical.tiqf.tiqf_update_moment`).
4. **Information gain**: the closed-form Gaussian KL of posterior against prior (Appendix B, eq. 4.25) and
   ``argmax`` (eq. 4.24). With fewer than 3 measured points the action is random (Algorithm 1).

:func:`simulate_touches` runs Algorithm 1 in simulation against a ground-truth pose (active or random
selection) and :func:`run_active_touch_benchmark` gives the Table 4.1 timing and the Fig. 4.5 curves.
Conventions: ``T_scene_model`` maps model points into the scene (world) frame; quaternions (w, x, y, z);
metres.
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np
import trimesh
from tqdm import tqdm

from vtlearn.bench_utils import ratio, save_figure
from vtlearn.classical.tiqf import SequentialTIQF, _quat_to_matrix, gaussian_kl, tiqf_update_moment
from vtlearn.validation import (
    as_int,
    as_points,
    as_real,
    as_surface_mesh,
    as_transform,
    as_vector,
    load_named,
)

__all__ = [
    "ActionSampler",
    "MeshRaycaster",
    "lookahead_information_gain",
    "select_action",
    "simulate_touches",
    "run_active_touch_benchmark",
    "TouchTrace",
]

_FACE_AXES = {"+x": (0, 1), "-x": (0, -1), "+y": (1, 1), "-y": (1, -1), "+z": (2, 1), "-z": (2, -1)}


class MeshRaycaster:
    """Ray-mesh intersection in the model frame (Open3D ``RaycastingScene``, built once per mesh).

    Args:
        mesh: the object mesh in its model frame (faces, finite vertices, area > 0).
    """

    def __init__(self, mesh: trimesh.Trimesh):
        import open3d as o3d

        mesh = as_surface_mesh(mesh, "mesh")
        self._o3d = o3d
        self.scene = o3d.t.geometry.RaycastingScene()
        self.scene.add_triangles(
            o3d.core.Tensor(np.asarray(mesh.vertices, dtype=np.float32)),
            o3d.core.Tensor(np.asarray(mesh.faces, dtype=np.uint32)),
        )
        self.n_faces = int(len(mesh.faces))

    def cast(self, origins: np.ndarray, directions: np.ndarray, T_scene_model: np.ndarray):
        """First hits of rays given in the scene frame against the mesh placed at ``T_scene_model``.

        Shapes:
            origins, directions: ``(C, 3)`` (unit directions) -> hits ``(C, 3)`` in the scene frame and a hit
            mask ``(C,)``.
        """
        R, t = T_scene_model[:3, :3], T_scene_model[:3, 3]
        o_m = (origins - t) @ R  # R^T (o - t)
        d_m = directions @ R
        rays = np.concatenate([o_m, d_m], 1).astype(np.float32)
        ans = self.scene.cast_rays(self._o3d.core.Tensor(rays))
        t_hit = ans["t_hit"].numpy().astype(np.float64)
        hit = np.isfinite(t_hit)
        p_m = o_m + np.where(hit, t_hit, 0.0)[:, None] * d_m
        return p_m @ R.T + t, hit


@dataclass
class ActionSampler:
    """Candidate touch rays on the faces of the model's bounding box at the estimated pose.

    Args:
        lo, hi: model-frame bounding box ``(3,)`` each.
        margin: the box is inflated by this fraction of its longest side, so rays start off the object.
        faces: which faces carry actions (``"+x" ... "-z"``).
    """

    lo: np.ndarray
    hi: np.ndarray
    margin: float = 0.1
    faces: tuple = ("+x", "-x", "+y", "-y", "+z", "-z")

    def __post_init__(self):
        self.lo = as_vector(self.lo, "lo", 3, "a finite (3,) box corner")
        self.hi = as_vector(self.hi, "hi", 3, "a finite (3,) box corner")
        if (self.hi <= self.lo).any():
            raise ValueError(
                f"hi: must exceed lo on every axis, got lo={self.lo.tolist()} hi={self.hi.tolist()}"
            )
        self.margin = as_real(self.margin, "margin", low=0.0)
        faces = tuple(self.faces) if not isinstance(self.faces, str) else (self.faces,)
        if not faces or any(f not in _FACE_AXES for f in faces):
            raise ValueError(f"faces: expected a non-empty tuple of {tuple(_FACE_AXES)}, got {self.faces!r}")
        self.faces = faces

    def sample(self, n: int, T_scene_model: np.ndarray, rng) -> tuple[np.ndarray, np.ndarray]:
        """``n`` rays (origins, unit directions) in the scene frame, uniform over the chosen faces' area.

        Shapes:
            T_scene_model: ``(4, 4)`` the estimated pose -> origins ``(n, 3)``, directions ``(n, 3)``.
        """
        n = as_int(n, "n")
        rng = np.random.default_rng(rng)
        pad = self.margin * float((self.hi - self.lo).max())
        lo, hi = self.lo - pad, self.hi + pad
        ext = hi - lo
        areas = np.array([np.prod(np.delete(ext, _FACE_AXES[f][0])) for f in self.faces])
        face = rng.choice(len(self.faces), size=n, p=areas / areas.sum())
        u = rng.uniform(size=(n, 3))
        origins = lo + u * ext
        dirs = np.zeros((n, 3))
        for k, f in enumerate(self.faces):
            axis, sign = _FACE_AXES[f]
            sel = face == k
            origins[sel, axis] = hi[axis] if sign > 0 else lo[axis]
            dirs[sel, axis] = -sign  # pointing inwards
        R, t = T_scene_model[:3, :3], T_scene_model[:3, 3]
        return origins @ R.T + t, dirs @ R.T


def lookahead_information_gain(
    x, P, scene_points, model_corr, z_hat, o_hat, rho: float, criterion: str = "kl"
) -> np.ndarray:
    """Expected information gain (eq. 4.24-4.25) of each hypothetical measurement, batched.

    Args:
        x, P: current belief, quaternion (w, x, y, z) and covariance.
        scene_points: measured points ``s_i``; model_corr: their model correspondences ``o_i``.
        z_hat: hypothetical measured points, one per candidate; o_hat: their model correspondences.
        rho: TIQF correspondence uncertainty (eq. 4.18).

    Shapes:
        x: ``(4,)``; P: ``(4, 4)``; scene_points, model_corr: ``(n, 3)``, n >= 1; z_hat, o_hat: ``(C, 3)``
        -> ``(C,)`` KL(posterior || prior).
    """
    if criterion not in ("kl", "entropy"):
        raise ValueError(f"criterion: expected 'kl' or 'entropy', got {criterion!r}")
    scene_points = as_points(scene_points, "scene_points")
    model_corr = as_points(model_corr, "model_corr")
    if model_corr.shape != scene_points.shape:
        raise ValueError(f"model_corr: expected shape {scene_points.shape} to match scene_points, "
                         f"got {model_corr.shape}")
    z_hat = as_points(z_hat, "z_hat")
    o_hat = as_points(o_hat, "o_hat")
    if o_hat.shape != z_hat.shape:
        raise ValueError(f"o_hat: expected shape {z_hat.shape} to match z_hat, got {o_hat.shape}")
    v = np.concatenate([scene_points, model_corr], 1)  # nx6
    n = len(v)
    vm = v.mean(0)
    cov = (v - vm).T @ (v - vm)  # sum_i (v_i - v_mean)(v_i - v_mean)^T
    w = np.concatenate([z_hat, o_hat], 1) - vm  # Cx6
    M = n * np.einsum("ca,cb->cab", w, w) + cov  # sum_i (w - v_i)(w - v_i)^T
    C = len(w)
    x_post, P_post = tiqf_update_moment(np.broadcast_to(x, (C, 4)), np.broadcast_to(P, (C, 4, 4)), M, rho)
    if criterion == "kl":
        return gaussian_kl(x_post, P_post, x, P)
    # entropy reduction 1/2 log(det P / det P+): the expected KL over measurements (mutual information)
    # of a linear-Gaussian update; it leaves out the mean-shift term that eq. 4.25 evaluates at z^
    return 0.5 * (np.linalg.slogdet(P)[1] - np.linalg.slogdet(P_post)[1])


def select_action(
    filt: SequentialTIQF,
    raycaster: MeshRaycaster,
    sampler: ActionSampler,
    n_candidates: int,
    rng,
    active: bool = True,
    criterion: str = "kl",
):
    """Algorithm 1's action choice: returns ``(origins, directions, order)``, candidates best first.

    With ``active`` and at least 3 measured points the order is by decreasing expected information gain of
    the candidates that hit the mesh at the estimated pose (the others follow in random order); otherwise
    the order is random.
    """
    rng = np.random.default_rng(rng)
    T_est = filt.T_scene_model
    origins, dirs = sampler.sample(n_candidates, T_est, rng)
    if not active or len(filt.scene) <= 2:
        return origins, dirs, rng.permutation(n_candidates)
    z_hat, hit = raycaster.cast(origins, dirs, T_est)
    gain = np.full(n_candidates, -np.inf)
    if hit.any():
        o_hat = filt.correspondences(z_hat[hit])
        gain[hit] = lookahead_information_gain(
            filt.x, filt.P, filt.scene, filt.paired_model_points(), z_hat[hit], o_hat, filt.rho, criterion
        )
    # ties and misses in random order
    order = np.lexsort((rng.random(n_candidates), -gain))
    return origins, dirs, order


@dataclass
class TouchTrace:
    """Errors after each contact of one simulated run: translation (m) and rotation (degrees)."""

    trans_err: np.ndarray
    rot_err_deg: np.ndarray
    contacts: int
    attempts: int


def _rot_err_deg(R_a, R_b) -> float:
    return float(np.degrees(np.arccos(np.clip((np.trace(R_a.T @ R_b) - 1) / 2, -1.0, 1.0))))


def simulate_touches(
    mesh: trimesh.Trimesh,
    T_gt,
    T_init,
    *,
    n_touches: int = 20,
    active: bool = True,
    n_candidates: int = 100,
    noise: float = 1e-3,
    n_model: int = 2000,
    rho: float = 1e-2,
    refine: bool = False,
    mode: str = "reassociate",
    n_escapes: int = 3,
    raycaster: MeshRaycaster | None = None,
    criterion: str = "kl",
    max_rounds: int = 100,
    seed=None,
) -> TouchTrace:
    """Algorithm 1 in simulation: touch the object at ``T_gt`` starting from the belief ``T_init``.

    A chosen ray that misses the real object gives no point (negative information is not used, as in the
    thesis); the next candidate in the order is executed instead, so every step yields one contact. When
    ``max_rounds`` fresh batches of ``n_candidates`` in a row all miss (the candidates are sampled on the box
    at the estimate, so an estimate far from ``T_gt`` can leave none on the object), a ``ValueError``
    naming ``T_init`` is raised instead of searching forever.

    Args:
        mesh: the object in its model frame (metres); n_touches: contacts to collect, >= 1;
        n_candidates: candidate rays per step, >= 1; noise: contact-position noise std (m, >= 0);
        n_model: model points sampled from the mesh; rho: TIQF correspondence uncertainty (eq. 4.18, > 0);
        criterion: ``"kl"`` (eq. 4.24-4.25) or ``"entropy"``.

    Shapes:
        T_gt, T_init: ``(4, 4)`` ``T_scene_model`` -> TouchTrace arrays ``(n_touches,)``.
    """
    mesh = as_surface_mesh(mesh, "mesh")
    T_gt = as_transform(T_gt, "T_gt")
    T_init = as_transform(T_init, "T_init")
    n_touches = as_int(n_touches, "n_touches")
    n_candidates = as_int(n_candidates, "n_candidates")
    n_model = as_int(n_model, "n_model", minimum=3)
    max_rounds = as_int(max_rounds, "max_rounds")
    noise = as_real(noise, "noise", low=0.0, unit="m")
    rho = as_real(rho, "rho", low=0.0, open_low=True)
    if criterion not in ("kl", "entropy"):
        raise ValueError(f"criterion: expected 'kl' or 'entropy', got {criterion!r}")
    rng = np.random.default_rng(seed)
    model = trimesh.sample.sample_surface(mesh, n_model, seed=int(rng.integers(1 << 31)))[0].view(np.ndarray)
    caster = MeshRaycaster(mesh) if raycaster is None else raycaster
    lo, hi = mesh.bounds
    sampler = ActionSampler(np.asarray(lo, float), np.asarray(hi, float))
    filt = SequentialTIQF(
        model,
        T_init=T_init,
        rho=rho,
        refine=refine,
        n_escapes=n_escapes,
        tangent=True,
        mode=mode,
        seed=int(rng.integers(1 << 31)),
    )
    t_err, r_err = [], []
    attempts = 0
    misses = 0  # batches in a row without a contact
    while len(t_err) < n_touches:
        origins, dirs, order = select_action(filt, caster, sampler, n_candidates, rng, active, criterion)
        real, hit = caster.cast(origins[order], dirs[order], T_gt)
        attempts += int(np.argmax(hit)) + 1 if hit.any() else n_candidates
        if not hit.any():
            misses += 1
            if misses >= max_rounds:
                raise ValueError(
                    f"T_init: no candidate ray reached the object at T_gt in {max_rounds} rounds of "
                    f"{n_candidates} after {len(t_err)} contacts; the estimate is too far from the true pose "
                    f"for rays sampled on the box at the estimate"
                )
            continue
        misses = 0
        z = real[np.argmax(hit)] + rng.normal(scale=noise, size=3)
        T = filt.add(z[None])
        t_err.append(float(np.linalg.norm(T[:3, 3] - T_gt[:3, 3])))
        r_err.append(_rot_err_deg(T[:3, :3], T_gt[:3, :3]))
    return TouchTrace(np.array(t_err), np.array(r_err), len(t_err), attempts)


def _mesh_with_faces(base: trimesh.Trimesh, n_faces: int) -> trimesh.Trimesh:
    """``base`` subdivided then decimated (Open3D quadric decimation) to about ``n_faces`` faces."""
    import open3d as o3d

    m = base
    while len(m.faces) < n_faces:
        m = m.subdivide()
    om = o3d.geometry.TriangleMesh(
        o3d.utility.Vector3dVector(m.vertices), o3d.utility.Vector3iVector(m.faces)
    )
    om = om.simplify_quadric_decimation(target_number_of_triangles=int(n_faces))
    return trimesh.Trimesh(np.asarray(om.vertices), np.asarray(om.triangles), process=False)


def _perturbed(T_gt, rng, trans: float, rot_deg: float) -> np.ndarray:
    axis = rng.normal(size=3)
    axis /= np.linalg.norm(axis)
    a = np.radians(rng.uniform(-rot_deg, rot_deg))
    q = np.concatenate([[np.cos(a / 2)], np.sin(a / 2) * axis])
    T = T_gt.copy()
    T[:3, :3] = T_gt[:3, :3] @ _quat_to_matrix(q)
    T[:3, 3] = T_gt[:3, 3] + rng.uniform(-trans, trans, 3)
    return T


#: thesis Table 4.1 look-ahead times (s): {faces: {candidates: seconds}}
THESIS_TABLE_4_1 = {5000: {10: 0.33, 100: 5.06, 1000: 42.56}, 1000: {10: 0.17, 100: 1.75, 1000: 13.70}}


def time_lookahead(
    mesh: trimesh.Trimesh, n_candidates: int, repeats: int = 5, n_points: int = 10, seed: int = 0
) -> list[float]:
    """Seconds for one action selection (sampling, ray casting, batched look-ahead, KL, argmax)."""
    rng = np.random.default_rng(seed)
    caster = MeshRaycaster(mesh)
    model = trimesh.sample.sample_surface(mesh, 2000, seed=seed)[0].view(np.ndarray)
    lo, hi = mesh.bounds
    sampler = ActionSampler(np.asarray(lo, float), np.asarray(hi, float))
    filt = SequentialTIQF(model, T_init=np.eye(4))
    filt.add(model[rng.choice(len(model), n_points, replace=False)])
    times = []
    for r in range(repeats + 1):
        t0 = time.perf_counter()
        select_action(filt, caster, sampler, n_candidates, rng, active=True)
        if r > 0:  # the first call warms up Open3D
            times.append(time.perf_counter() - t0)
    return times


def run_active_touch_benchmark(
    candidates=(10, 100, 1000),
    faces=(1000, 5000),
    repeats: int = 5,
    trials: int = 10,
    touches: int = 25,
    seed: int = 0,
    mesh_spec: str = "bunny",
    object_size: float = 0.2,
    init_trans: float = 0.02,
    init_rot_deg: float = 30.0,
    plot_path=None,
) -> dict:
    """Table 4.1 timing and Fig. 4.5 active-vs-random curves (see module doc).

    Args:
        candidates, faces: candidate counts and mesh face counts of the timing table (integers >= 1 / >= 4).
        repeats, trials, touches: timing repeats, active-vs-random trials and contacts per trial (>= 1).
        mesh_spec: ``bunny``, ``shape:CATEGORY[:SEED]`` or a mesh file; object_size: its longest side (m).
        init_trans: initial translation error bound per axis (m, >= 0); init_rot_deg: initial rotation
            error bound (degrees, in [0, 180]; the thesis uses 30).
        plot_path: where the active-vs-random curves are drawn (PNG), or None.

    Returns:
        ``lookahead_rows`` (seconds, the thesis's Table 4.1 seconds, ``speedup_vs_thesis`` = thesis / ours),
        ``curve_rows`` (RMSE after k contacts, mm and degrees, and each active strategy's RMSE divided by
        random's: ``active_over_random_trans`` < 1 means active is better), ``curves_rmse`` and ``setup``.
    """
    from vtlearn.classical.registration_bench import load_benchmark_mesh

    if not len(candidates) or not len(faces):
        raise ValueError(f"{'candidates' if not len(candidates) else 'faces'}: need at least one count")
    candidates = [as_int(c, "candidates") for c in candidates]
    faces = [as_int(f, "faces", minimum=4) for f in faces]  # 4: a tetrahedron
    repeats = as_int(repeats, "repeats")
    trials = as_int(trials, "trials")
    touches = as_int(touches, "touches")
    object_size = as_real(object_size, "object_size", low=0.0, open_low=True, unit="m")
    init_trans = as_real(init_trans, "init_trans", low=0.0, unit="m")
    init_rot_deg = as_real(init_rot_deg, "init_rot_deg", low=0.0, high=180.0, unit="deg")
    _, base = load_named(load_benchmark_mesh, mesh_spec, "mesh_spec")
    base = base.copy()
    base.vertices = base.vertices * (object_size / 2.0)  # [-1, 1]^3 -> longest side object_size (m)
    rows = []
    for f in faces:
        mesh_f = _mesh_with_faces(base, f)
        for c in candidates:
            ts = time_lookahead(mesh_f, c, repeats=repeats, seed=seed)
            rows.append(
                {
                    "faces": len(mesh_f.faces),
                    "target_faces": f,
                    "candidates": c,
                    "lookahead_s": float(np.mean(ts)),
                    "lookahead_median_s": float(np.median(ts)),
                    "thesis_s": THESIS_TABLE_4_1.get(f, {}).get(c),
                }
            )
            thesis_s, ours = rows[-1]["thesis_s"], rows[-1]["lookahead_s"]
            rows[-1]["speedup_vs_thesis"] = thesis_s / ours if thesis_s is not None and ours > 0 else None
    rng = np.random.default_rng(seed)
    caster = MeshRaycaster(base)
    # "active" is eq. 4.24/4.25 (KL at the hypothetical measurement); "active_entropy" ranks by the entropy
    # reduction (the KL's expectation over measurements); "random" picks a random candidate
    strategies = {"active": ("kl", True), "active_entropy": ("entropy", True), "random": ("kl", False)}
    curves = {name: {"t": [], "r": []} for name in strategies}
    for trial in tqdm(range(trials), desc="active vs random touch"):
        T_gt = np.eye(4)
        q = rng.normal(size=4)
        T_gt[:3, :3] = _quat_to_matrix(q / np.linalg.norm(q))
        T_gt[:3, 3] = rng.uniform(-0.5, 0.5, 3)
        T_init = _perturbed(T_gt, rng, init_trans, init_rot_deg)
        s = int(rng.integers(1 << 31))
        for name, (criterion, active) in strategies.items():
            try:
                tr = simulate_touches(
                    base,
                    T_gt,
                    T_init,
                    n_touches=touches,
                    active=active,
                    criterion=criterion,
                    raycaster=caster,
                    seed=s,
                )
            except ValueError as exc:
                if not str(exc).startswith("T_init:"):
                    raise
                raise ValueError(
                    f"init_trans, init_rot_deg: trial {trial} ({name}) lost the object: "
                    f"{str(exc).removeprefix('T_init: ')}; use a smaller initial error than "
                    f"{init_trans} m / {init_rot_deg} deg"
                ) from exc
            curves[name]["t"].append(tr.trans_err)
            curves[name]["r"].append(tr.rot_err_deg)
    curve_rows = []
    rmse = {
        k: {"t": np.sqrt(np.mean(np.square(v["t"]), 0)), "r": np.sqrt(np.mean(np.square(v["r"]), 0))}
        for k, v in curves.items()
    }
    for k in range(touches):
        if k + 1 in (1, 3, 5, 10, 15, 20, 25, 30, 40, 50) or k == touches - 1:
            curve_rows.append(
                {"touches": k + 1}
                | {f"{name}_trans_rmse_mm": 1e3 * rmse[name]["t"][k] for name in strategies}
                | {f"{name}_rot_rmse_deg": rmse[name]["r"][k] for name in strategies}
                # < 1: the active strategy's error is below random's after k + 1 contacts
                | {f"{name}_over_random_trans": ratio(rmse[name]["t"][k], rmse["random"]["t"][k])
                   for name in ("active", "active_entropy")}
                | {f"{name}_over_random_rot": ratio(rmse[name]["r"][k], rmse["random"]["r"][k])
                   for name in ("active", "active_entropy")}
            )
    result = {
        "lookahead_rows": rows,
        "curve_rows": curve_rows,
        "curves_rmse": {k: {"trans_m": v["t"], "rot_deg": v["r"]} for k, v in rmse.items()},
        "setup": {
            "mesh": mesh_spec,
            "object_size_m": object_size,
            "init_trans_m": init_trans,
            "init_rot_deg": init_rot_deg,
            "trials": trials,
            "touches": touches,
            "candidates_per_step": 100,
            "noise_m": 1e-3,
        },
        "thesis_table_4_1": THESIS_TABLE_4_1,
    }
    if plot_path is not None:
        result["plot"] = str(_plot_curves(rmse, plot_path, trials))
    return result


def _plot_curves(rmse: dict, path, trials: int):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 2, figsize=(9, 3.5))
    for name, style in (("active", "-"), ("active_entropy", "-."), ("random", "--")):
        n = np.arange(1, len(rmse[name]["t"]) + 1)
        axes[0].plot(n, 1e3 * rmse[name]["t"], style, label=name)
        axes[1].plot(n, rmse[name]["r"], style, label=name)
    axes[0].set_ylabel("translation RMSE (mm)")
    axes[1].set_ylabel("rotation RMSE (deg)")
    for ax in axes:
        # Algorithm 1 touches at random until 3 points are measured: every strategy shares those
        ax.axvline(3, color="0.6", lw=0.8, ls=":")
        ax.set_xlabel("number of contacts (first 3 random for all)")
        ax.legend()
    fig.suptitle(f"Active vs random touch, RMSE over {trials} trials (Fig. 4.5 analogue)")
    fig.tight_layout()
    return save_figure(fig, path, dpi=120)
