"""ArtReg: visuo-tactile tracking of single, multiple and articulated objects (thesis ch.6, Algorithm 4).

Every object (or every part of an articulated object) is tracked by its own manifold unscented Kalman
filter on SE(3) (:class:`vtlearn.classical.ukf.ManifoldUKF`, eq. 6.1-6.10). No object or kinematic model
is needed: the model of part ``i`` is its segmented point cloud at t = 0 (or any cloud of it).

State and tangent space. The state of filter ``i`` is ``T_world_part``, the pose of the part's
*centroid frame* (the model frame shifted to the model cloud's centroid, same axes). Rotations then
turn the cloud about its own centre, which keeps the sigma points well conditioned. The retraction is
the right perturbation

    phi(T, xi) = T @ se3_exp(xi),       phi_inv(T_ref, T) = se3_log(T_ref^-1 @ T),

with the tangent order ``xi = (rho, phi)`` = (translation, rotation) of vtlearn.geometry.lie, expressed
in the centroid frame. Poses handed in and out are ``T_world_object`` in the caller's model frame.

Process model (thesis 6.2.3): a random walk, ``f(T, u, w) = T @ se3_exp(w)`` with ``w ~ N(0, Q)`` and
``Q = diag(sigma_t^2 I3, sigma_r^2 I3)`` per frame (``process_std``). The thesis sets the measurement
noise below the process noise so that the filter follows a moving object.

Measurement model (eq. 6.11): the measurement ``z`` stacks the scene points assigned to the part
(plus tactile contact points when present). For each sigma point ``sigma_M`` the predicted measurement
is, for every scene point ``s``, its closest model point moved by the sigma point,
``h_s(sigma_M) = sigma_M p*``, ``p* = argmin_{p in O} ||s - sigma_M p||``. The search is vectorised:
the scene points are mapped into the model frame by every sigma point's inverse and all
``(2M + 1) * m`` queries go to one KD-tree of the model in a single call (the model tree is built
once, at construction). The per-point measurement variance is ``visual_std^2`` for camera points and
``tactile_std^2`` for tactile points; points that lie further than ``robust_scale`` from the model at
the predicted pose get their variance inflated by ``(d / robust_scale)^2`` (a Cauchy-like
down-weighting that keeps partial-view outliers from dragging the estimate).

Data association. Scene points are assigned to the part whose model, at its predicted pose, is
closest (thesis 6.2.3); points further than ``max_correspondence_distance`` from every part are
ignored. At most ``max_points_per_part`` points per part enter the update (a fixed-seed random
subsample), which bounds the cost per frame; with the defaults (200 points, 3 iterations) two parts
with 1000 points each run above 30 Hz on one core (``vtlearn bench tracking`` prints the rate).

Frames with no usable point keep the last estimate: the filter only predicts, so the covariance grows.
"""

from __future__ import annotations

import warnings
from collections.abc import Sequence
from typing import Any

import numpy as np
from scipy.spatial import cKDTree

from vtlearn.classical.ukf import ManifoldUKF
from vtlearn.geometry.lie import se3_exp, se3_log
from vtlearn.validation import as_int, as_pair, as_points, as_real, as_transform, to_numpy

__all__ = ["ArtRegTracker", "se3_phi", "se3_phi_inv", "random_walk_se3"]


def _translation(t: np.ndarray) -> np.ndarray:
    T = np.eye(4)
    T[:3, 3] = t
    return T


def _frame_cloud(x: Any, name: str) -> np.ndarray:
    """A frame's (M, 3) cloud; an empty input of any shape is an empty frame, anything else is validated."""
    arr = to_numpy(x)
    if arr.size == 0:
        return np.zeros((0, 3))
    return as_points(arr, name)


def _inv(T: np.ndarray) -> np.ndarray:
    Ti = np.eye(4)
    Ti[:3, :3] = T[:3, :3].T
    Ti[:3, 3] = -T[:3, :3].T @ T[:3, 3]
    return Ti


def se3_phi(T: np.ndarray, xi: np.ndarray) -> np.ndarray:
    """Retraction on SE(3): ``T @ exp(xi)``, xi = (rho, phi) in the body frame. (4, 4), (6,) -> (4, 4)."""
    return T @ se3_exp(np.asarray(xi, dtype=np.float64))


def se3_phi_inv(T_ref: np.ndarray, T: np.ndarray) -> np.ndarray:
    """Inverse retraction: ``log(T_ref^-1 @ T)`` as (rho, phi). (4, 4), (4, 4) -> (6,)."""
    return se3_log(_inv(T_ref) @ T)


def random_walk_se3(T: np.ndarray, u: Any, w: np.ndarray) -> np.ndarray:
    """Random-walk process model of ArtReg: the pose is constant up to the noise ``w`` (thesis 6.2.3)."""
    return T @ se3_exp(np.asarray(w, dtype=np.float64))


class _PartMeasurement:
    """Closest-point measurement model of eq. 6.11 for one part, vectorised over sigma points."""

    def __init__(self, model_c: np.ndarray) -> None:
        self.model_c = model_c  # model in its centroid frame, (K, 3)
        self.tree = cKDTree(model_c)
        self.scene: np.ndarray = np.zeros((0, 3))

    def __call__(self, states: Sequence[np.ndarray]) -> np.ndarray:
        T = np.stack(states)  # Sx4x4, T_world_part of each sigma point
        R, t = T[:, :3, :3], T[:, :3, 3]
        # scene points in each sigma point's part frame: R^T (s - t), SxMx3
        local = (self.scene[None, :, :] - t[:, None, :]) @ R
        _, idx = self.tree.query(local.reshape(-1, 3), k=1, workers=1)  # one query for all sigma points
        p = self.model_c[idx].reshape(local.shape)  # SxMx3 closest model points
        h = p @ R.transpose(0, 2, 1) + t[:, None, :]  # moved by each sigma point
        return h.reshape(len(states), -1)


class ArtRegTracker:
    """Track N rigid objects or parts with N manifold UKFs on SE(3) (thesis ch.6, Algorithm 4).

    Args:
        models: one model cloud per object/part (the segmented cloud at t = 0 or points sampled from
            its mesh), each in its own model frame. At least 3 points each.
        T_world_object0: initial poses ``T_world_object`` (4x4, maps model-frame points into the
            world frame), one per model. For segmented t = 0 clouds already in the world frame this
            is the identity.
        process_std: (translation m, rotation rad) standard deviation of the random walk per frame;
            ``Q = diag(t^2, t^2, t^2, r^2, r^2, r^2)``.
        visual_std: standard deviation (m) of one camera point, per axis; ``R`` for visual points.
        tactile_std: standard deviation (m) of one tactile contact point (more precise than vision).
        init_std: (translation m, rotation rad) standard deviation of the initial pose.
        max_correspondence_distance: scene points further than this (m) from every part at its
            predicted pose are not assigned to any part.
        robust_scale: distance (m) beyond which a point's variance is inflated by (d / scale)^2.
        max_points_per_part: cap on the measurement points per part and frame (random subsample with
            a fixed seed); ``None`` uses every point. Scenes with more than ``8 * cap * N`` points are
            randomly subsampled to that many before the assignment, which bounds its cost too.
        n_iterations: measurement re-linearisations per frame (see :meth:`ManifoldUKF.update`);
            1 is the plain update of eq. 6.6-6.10. Closest-point correspondences are only right near
            the true pose, so a few iterations let the filter follow faster motions.
        alpha, beta, kappa: sigma-point parameters of eq. A.22.
        seed: seed of the subsampling generator.

    Shapes:
        models[i]: (K_i, 3); T_world_object0[i]: (4, 4); scene_cloud: (M, 3); tactile_cloud: (T, 3);
        step() -> list of N (4, 4) ``T_world_object``; covariances: list of N (6, 6) in the tangent
        space (rho, phi) of the part's centroid frame.
    """

    def __init__(
        self,
        models: Sequence[Any],
        T_world_object0: Sequence[Any],
        *,
        process_std: tuple[float, float] = (0.005, 0.015),
        visual_std: float = 0.003,
        tactile_std: float = 0.001,
        init_std: tuple[float, float] = (0.005, 0.02),
        max_correspondence_distance: float = 0.05,
        robust_scale: float = 0.01,
        max_points_per_part: int | None = 200,
        n_iterations: int = 3,
        alpha: float = 1.0,
        beta: float = 2.0,
        kappa: float = 0.0,
        seed: int = 0,
    ) -> None:
        if hasattr(models, "shape") and len(models.shape) == 2:  # one numpy array or torch tensor
            raise ValueError(f"models: need a list of (K_i, 3) model clouds, one per object, got one array "
                             f"of shape {tuple(models.shape)}; for one object pass [model]")
        if hasattr(T_world_object0, "shape") and len(T_world_object0.shape) == 2:
            raise ValueError("T_world_object0: need a list of (4, 4) poses, one per model, got one (4, 4) "
                             "array; for one object pass [T]")
        if len(models) == 0:
            raise ValueError("models is empty: give at least one model cloud")
        if len(models) != len(T_world_object0):
            raise ValueError(
                f"T_world_object0 must have one pose per model: {len(T_world_object0)} poses, "
                f"{len(models)} models"
            )
        for name, pair in (("process_std", process_std), ("init_std", init_std)):
            what = "two positive numbers (m, rad)"
            if not all(np.isfinite(v) and v > 0 for v in as_pair(pair, name, what)):
                raise ValueError(f"{name}: expected {what}, got {pair!r}")
        self.visual_std = as_real(visual_std, "visual_std", low=0.0, open_low=True, unit="m")
        self.tactile_std = as_real(tactile_std, "tactile_std", low=0.0, open_low=True, unit="m")
        self.max_correspondence_distance = as_real(
            max_correspondence_distance, "max_correspondence_distance", low=0.0, open_low=True, unit="m"
        )
        self.robust_scale = as_real(robust_scale, "robust_scale", low=0.0, open_low=True, unit="m")
        if max_points_per_part is not None:
            max_points_per_part = as_int(max_points_per_part, "max_points_per_part", minimum=3)
        self.max_points_per_part = max_points_per_part
        self.n_iterations = as_int(n_iterations, "n_iterations")
        self.rng = np.random.default_rng(seed)
        self.Q = np.diag([process_std[0] ** 2] * 3 + [process_std[1] ** 2] * 3)
        P0 = np.diag([init_std[0] ** 2] * 3 + [init_std[1] ** 2] * 3)

        self._T_object_centroid: list[np.ndarray] = []
        self._meas: list[_PartMeasurement] = []
        self.filters: list[ManifoldUKF] = []
        for i, (model, T0) in enumerate(zip(models, T_world_object0, strict=True)):
            pts = as_points(model, f"models[{i}]", min_points=3)
            T0 = as_transform(T0, f"T_world_object0[{i}]")
            c = pts.mean(0)
            meas = _PartMeasurement(pts - c)
            T_oc = _translation(c)
            self._T_object_centroid.append(T_oc)
            self._meas.append(meas)
            self.filters.append(
                ManifoldUKF(
                    f=random_walk_se3,
                    h=meas,
                    phi=se3_phi,
                    phi_inv=se3_phi_inv,
                    Q=self.Q,
                    R=self.visual_std**2,
                    state0=T0 @ T_oc,
                    P0=P0,
                    alpha=alpha,
                    beta=beta,
                    kappa=kappa,
                )
            )
        self.n_frames = 0
        #: number of measurement points each part used in the last frame
        self.last_counts: list[int] = [0] * len(self.filters)
        self._warned_unassigned = False

    @property
    def n_parts(self) -> int:
        return len(self.filters)

    @property
    def poses(self) -> list[np.ndarray]:
        """Current ``T_world_object`` estimates, one (4, 4) per part."""
        return [f.state @ _inv(T_oc) for f, T_oc in zip(self.filters, self._T_object_centroid, strict=True)]

    @property
    def covariances(self) -> list[np.ndarray]:
        """Current (6, 6) covariances, tangent order (rho, phi) in each part's centroid frame."""
        return [f.P.copy() for f in self.filters]

    def _assign(self, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Nearest part (by distance to its model at the predicted pose) and that distance per point."""
        dists = np.empty((self.n_parts, len(points)))
        for i, (f, meas) in enumerate(zip(self.filters, self._meas, strict=True)):
            T = f.state
            local = (points - T[:3, 3]) @ T[:3, :3]
            dists[i], _ = meas.tree.query(local, k=1, workers=1)
        owner = np.argmin(dists, axis=0)
        return owner, dists[owner, np.arange(len(points))]

    def step(
        self, scene_cloud: Any, tactile_cloud: Any = None, *, allow_empty: bool = True
    ) -> list[np.ndarray]:
        """Track one frame (Algorithm 4 for every part). Returns the N ``T_world_object`` (4, 4).

        Args:
            scene_cloud: (M, 3) camera points in the world frame (plane and background removed, as in
                thesis 6.2.2). An empty cloud (M = 0) is an empty frame: every part keeps its last
                estimate (prediction only).
            tactile_cloud: optional (T, 3) tactile contact points in the world frame, appended to the
                measurement with the smaller ``tactile_std``.
            allow_empty: when False, an empty ``scene_cloud`` is an error instead of an empty frame.

        Raises:
            ValueError: naming ``scene_cloud`` / ``tactile_cloud`` for a wrong shape or NaN/inf values,
                or an empty ``scene_cloud`` when ``allow_empty`` is False.
        """
        scene = _frame_cloud(scene_cloud, "scene_cloud")
        if len(scene) == 0 and not allow_empty:
            raise ValueError("scene_cloud is empty (pass allow_empty=True to keep the last estimate)")
        tactile = (
            _frame_cloud(tactile_cloud, "tactile_cloud") if tactile_cloud is not None else np.zeros((0, 3))
        )
        if self.max_points_per_part is not None and len(scene) > 8 * self.max_points_per_part * self.n_parts:
            scene = scene[
                self.rng.choice(len(scene), 8 * self.max_points_per_part * self.n_parts, replace=False)
            ]
        points = np.concatenate([scene, tactile], axis=0)
        var = np.concatenate(
            [np.full(len(scene), self.visual_std**2), np.full(len(tactile), self.tactile_std**2)]
        )

        for f in self.filters:
            f.predict()  # random walk: the mean stays, the covariance grows by Q (eq. 6.2-6.5)
        self.n_frames += 1
        self.last_counts = [0] * self.n_parts
        if len(points) == 0:
            return self.poses

        owner, dist = self._assign(points)
        ok = dist <= self.max_correspondence_distance
        if len(points) >= 3 and not ok.any() and not self._warned_unassigned:
            self._warned_unassigned = True
            warnings.warn(
                f"ArtRegTracker: frame {self.n_frames}: none of its {len(points)} points lies within "
                f"max_correspondence_distance = {self.max_correspondence_distance:g} m of any part (the "
                f"nearest is {dist.min():.3g} away), so every part keeps its prediction. Clouds are in "
                "metres (is this one in millimetres?), and a part moves less than that distance between "
                "frames. last_counts gives each part's points per frame; this warning is shown once.",
                stacklevel=2,
            )
        for i, (f, meas) in enumerate(zip(self.filters, self._meas, strict=True)):
            sel = np.flatnonzero(ok & (owner == i))
            if len(sel) < 3:
                continue  # too little evidence: keep the prediction
            n_tactile_sel = sel[sel >= len(scene)]
            if self.max_points_per_part is not None and len(sel) > self.max_points_per_part:
                # keep every tactile point, subsample the camera points
                vis = sel[sel < len(scene)]
                n_vis = max(self.max_points_per_part - len(n_tactile_sel), 0)
                vis = self.rng.choice(vis, size=min(n_vis, len(vis)), replace=False)
                sel = np.concatenate([vis, n_tactile_sel])
            s = points[sel]
            d = dist[sel]
            r = var[sel] * np.maximum(1.0, (d / self.robust_scale) ** 2)
            meas.scene = s
            f.update(s.reshape(-1), R=np.repeat(r, 3), n_iterations=self.n_iterations)
            self.last_counts[i] = len(sel)
        return self.poses
