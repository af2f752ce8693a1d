"""Baseline trackers that ArtReg is compared against (thesis 6.3.5), with ArtReg's interface.

Each class is built as ``Tracker(models, T_world_object0, ...)`` and tracks with
``.step(scene_cloud, tactile_cloud=None) -> list of (4, 4) T_world_object``, like
:class:`vtlearn.classical.artreg.ArtRegTracker`, so the benchmark feeds all of them identical frames.

- :class:`ParticleFilterTracker` -- a particle filter per part on SE(3) (the thesis re-implemented one
  with Open3D; Cabido et al. 2009, Cifuentes et al. 2016). ``n_particles`` particles (default 300)
  diffuse by a random walk; the likelihood of a particle is
  ``exp(-sum_j min(d_j, tau)^2 / (2 sigma^2))`` over the closest-point distances ``d_j`` between the
  part's scene points and its model at the particle pose (one KD-tree query for all particles);
  the estimate is the weighted tangent-space mean around the best particle; systematic resampling.
- :class:`FrameToFrameICPTracker` -- Open3D point-to-point ICP of each part's points in the previous
  frame onto its points in the current frame (at most ``max_points_per_part`` = 2000, random
  subsample), composed over time (drifts, by construction).
- :class:`FilterRegTracker` -- FilterReg (Gao and Tedrake, 2019) through ``probreg``, model-to-frame,
  only when the optional extra ``vtlearn[probreg]`` is installed (:data:`HAS_PROBREG`).

Scene points are split between parts by proximity to each part at its current estimate, the same rule
ArtReg uses, so the comparison isolates the estimator.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np
import open3d as o3d
from scipy.spatial import cKDTree

from vtlearn.classical.artreg import _frame_cloud, _inv, _translation
from vtlearn.geometry import se3_exp, se3_log
from vtlearn.validation import as_int, as_points, as_real, as_transform

try:  # optional extra
    from probreg import filterreg as _filterreg

    HAS_PROBREG = True
except Exception:  # noqa: BLE001 - any import failure means the baseline is unavailable
    _filterreg = None
    HAS_PROBREG = False

__all__ = ["ParticleFilterTracker", "FrameToFrameICPTracker", "FilterRegTracker", "HAS_PROBREG"]


class _TrackerBase:
    """Validation, centroid frames and proximity assignment shared by the baselines."""

    def __init__(
        self, models: Sequence[Any], T_world_object0: Sequence[Any], max_correspondence_distance: float
    ):
        if len(models) == 0:
            raise ValueError("models is empty: give at least one model cloud")
        if len(models) != len(T_world_object0):
            raise ValueError(
                f"T_world_object0 must have one pose per model: {len(T_world_object0)} poses, "
                f"{len(models)} models"
            )
        self.max_correspondence_distance = as_real(
            max_correspondence_distance, "max_correspondence_distance", low=0.0, open_low=True
        )
        self.models_c: list[np.ndarray] = []
        self.trees: list[cKDTree] = []
        self._T_object_centroid: list[np.ndarray] = []
        self._T: list[np.ndarray] = []  # T_world_centroid per part
        for i, (m, T0) in enumerate(zip(models, T_world_object0, strict=True)):
            pts = as_points(m, f"models[{i}]", min_points=3)
            T0 = as_transform(T0, f"T_world_object0[{i}]")
            c = pts.mean(0)
            self.models_c.append(pts - c)
            self.trees.append(cKDTree(pts - c))
            self._T_object_centroid.append(_translation(c))
            self._T.append(T0 @ _translation(c))

    @property
    def n_parts(self) -> int:
        return len(self._T)

    @property
    def poses(self) -> list[np.ndarray]:
        return [T @ _inv(T_oc) for T, T_oc in zip(self._T, self._T_object_centroid, strict=True)]

    def _split(self, scene_cloud: Any, tactile_cloud: Any) -> list[np.ndarray]:
        """Per-part measurement points: nearest part at its current estimate, within the gate."""
        pts = _frame_cloud(scene_cloud, "scene_cloud")
        if tactile_cloud is not None:
            pts = np.concatenate([pts, _frame_cloud(tactile_cloud, "tactile_cloud")])
        if len(pts) == 0:
            return [np.zeros((0, 3))] * self.n_parts
        d = np.empty((self.n_parts, len(pts)))
        for i, (T, tree) in enumerate(zip(self._T, self.trees, strict=True)):
            d[i], _ = tree.query((pts - T[:3, 3]) @ T[:3, :3], k=1, workers=1)
        owner = np.argmin(d, 0)
        ok = d[owner, np.arange(len(pts))] <= self.max_correspondence_distance
        return [pts[ok & (owner == i)] for i in range(self.n_parts)]


class ParticleFilterTracker(_TrackerBase):
    """Particle-filter tracker on SE(3), one filter per part (baseline of thesis 6.3.5).

    Args:
        models, T_world_object0: as :class:`~vtlearn.classical.artreg.ArtRegTracker`.
        n_particles: particles per part.
        process_std: (m, rad) random-walk standard deviation per frame.
        likelihood_std: sigma (m) of the closest-point distance likelihood.
        truncation: tau (m), distances are clipped here so that outliers cost a bounded amount.
        max_points_per_part: scene points per part used in the likelihood (random subsample).
        max_correspondence_distance: gate (m) for assigning scene points to parts.
        seed: random seed.

    Shapes:
        models[i]: (K_i, 3); step() -> list of N (4, 4) T_world_object.
    """

    def __init__(
        self,
        models: Sequence[Any],
        T_world_object0: Sequence[Any],
        *,
        n_particles: int = 300,
        process_std: tuple[float, float] = (0.006, 0.03),
        likelihood_std: float = 0.004,
        truncation: float = 0.02,
        max_points_per_part: int = 150,
        max_correspondence_distance: float = 0.05,
        seed: int = 0,
    ) -> None:
        super().__init__(models, T_world_object0, max_correspondence_distance)
        self.n_particles = as_int(n_particles, "n_particles", minimum=2)
        self.process_std = process_std
        self.likelihood_std, self.truncation = float(likelihood_std), float(truncation)
        self.max_points_per_part = int(max_points_per_part)
        self.rng = np.random.default_rng(seed)
        self.particles = [np.repeat(T[None], self.n_particles, 0) for T in self._T]

    def _diffuse(self, P: np.ndarray) -> np.ndarray:
        w = self.rng.normal(size=(len(P), 6)) * np.repeat(self.process_std, 3)
        return P @ np.asarray(se3_exp(w))  # batched over particles

    def step(self, scene_cloud: Any, tactile_cloud: Any = None) -> list[np.ndarray]:
        """Track one frame; empty frames keep the last estimate. Returns N (4, 4) T_world_object."""
        parts = self._split(scene_cloud, tactile_cloud)
        for i, s in enumerate(parts):
            if len(s) < 3:
                continue
            if len(s) > self.max_points_per_part:
                s = s[self.rng.choice(len(s), self.max_points_per_part, replace=False)]
            P = self._diffuse(self.particles[i])
            R, t = P[:, :3, :3], P[:, :3, 3]
            local = np.einsum("pji,pmj->pmi", R, s[None] - t[:, None])
            d, _ = self.trees[i].query(local.reshape(-1, 3), k=1, workers=1)
            cost = np.minimum(d.reshape(len(P), -1), self.truncation) ** 2
            logw = -cost.sum(1) / (2 * self.likelihood_std**2)
            w = np.exp(logw - logw.max())
            w /= w.sum()
            best = P[int(np.argmax(w))]
            xis = np.asarray(se3_log(_inv(best)[None] @ P))  # batched over particles
            self._T[i] = best @ np.asarray(se3_exp(w @ xis))
            # systematic resampling
            pos = (self.rng.uniform() + np.arange(len(P))) / len(P)
            self.particles[i] = P[np.minimum(np.searchsorted(np.cumsum(w), pos), len(P) - 1)]
        return self.poses


class FrameToFrameICPTracker(_TrackerBase):
    """Frame-to-frame ICP (Open3D point-to-point): each part's previous points onto its current points.

    The first frame's source is the model at its initial pose. The pose increments are composed, so
    errors accumulate (the weakness the thesis points out for registration-only trackers).

    Shapes:
        models[i]: (K_i, 3); step() -> list of N (4, 4) T_world_object.
    """

    def __init__(
        self,
        models: Sequence[Any],
        T_world_object0: Sequence[Any],
        *,
        max_correspondence_distance: float = 0.05,
        icp_distance: float = 0.02,
        max_iterations: int = 30,
        max_points_per_part: int = 2000,
        seed: int = 0,
    ) -> None:
        super().__init__(models, T_world_object0, max_correspondence_distance)
        self.icp_distance, self.max_iterations = float(icp_distance), int(max_iterations)
        self.max_points_per_part = int(max_points_per_part)
        self.rng = np.random.default_rng(seed)
        self.prev = [m @ T[:3, :3].T + T[:3, 3] for m, T in zip(self.models_c, self._T, strict=True)]

    def step(self, scene_cloud: Any, tactile_cloud: Any = None) -> list[np.ndarray]:
        """Track one frame; empty frames keep the last estimate. Returns N (4, 4) T_world_object."""
        parts = self._split(scene_cloud, tactile_cloud)
        for i, s in enumerate(parts):
            if len(s) < 3:
                continue
            if len(s) > self.max_points_per_part:
                s = s[self.rng.choice(len(s), self.max_points_per_part, replace=False)]
            src = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(self.prev[i]))
            dst = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(s))
            res = o3d.pipelines.registration.registration_icp(
                src,
                dst,
                self.icp_distance,
                np.eye(4),
                o3d.pipelines.registration.TransformationEstimationPointToPoint(),
                o3d.pipelines.registration.ICPConvergenceCriteria(max_iteration=self.max_iterations),
            )
            self._T[i] = np.asarray(res.transformation) @ self._T[i]
            self.prev[i] = s
        return self.poses


class FilterRegTracker(_TrackerBase):
    """FilterReg (Gao and Tedrake, 2019) via probreg: register each part's model, at its last pose,
    onto its current points. Needs the optional extra ``vtlearn[probreg]``.

    Shapes:
        models[i]: (K_i, 3); step() -> list of N (4, 4) T_world_object.
    """

    def __init__(
        self,
        models: Sequence[Any],
        T_world_object0: Sequence[Any],
        *,
        max_correspondence_distance: float = 0.05,
        sigma2: float | None = None,
        max_points_per_part: int = 300,
        seed: int = 0,
    ) -> None:
        if not HAS_PROBREG:
            raise ImportError("FilterRegTracker needs probreg: pip install 'vtlearn[probreg]'")
        super().__init__(models, T_world_object0, max_correspondence_distance)
        self.sigma2, self.max_points_per_part = sigma2, int(max_points_per_part)
        self.rng = np.random.default_rng(seed)

    def step(self, scene_cloud: Any, tactile_cloud: Any = None) -> list[np.ndarray]:
        """Track one frame; empty frames keep the last estimate. Returns N (4, 4) T_world_object."""
        parts = self._split(scene_cloud, tactile_cloud)
        for i, s in enumerate(parts):
            if len(s) < 3:
                continue
            if len(s) > self.max_points_per_part:
                s = s[self.rng.choice(len(s), self.max_points_per_part, replace=False)]
            T = self._T[i]
            src = self.models_c[i] @ T[:3, :3].T + T[:3, 3]
            res = _filterreg.registration_filterreg(src, s, sigma2=self.sigma2)
            tf = res.transformation
            dT = np.eye(4)
            dT[:3, :3], dT[:3, 3] = np.asarray(tf.rot), np.asarray(tf.t)
            self._T[i] = dT @ T
        return self.poses
