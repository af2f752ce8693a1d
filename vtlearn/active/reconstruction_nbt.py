"""Next-best touch or pinch for reconstruction by the expected fit of ACTOR's reconstruction to the
object's known bounding box (beyond the thesis; compare thesis 8.2.3, eq. 8.2-8.5, which scores actions
by the occupancy-grid gain).

The grid gain of eq. 8.4 saturates on a transparent object: every candidate whose rays start in unknown
cells scores the same, so it does not tell ACTOR's useful inputs from useless ones. This criterion scores
an action by what it is expected to do to the reconstruction itself:

1. ``R = ACTOR(P)``: the reconstruction from the points ``P`` measured so far (the network input of
   :func:`~vtlearn.active.closed_loop.network_input`).
2. The expected measurement ``ŷ(a)`` of candidate ``a`` is its guarded motion replayed on ``R``: every
   reconstructed point is a sphere of radius ``ρ = radius_factor × (mean nearest-neighbour spacing of R)``
   (points below the table are lifted onto it), each taxel ray reports the first sphere it enters, each
   pad stops ``τ_f / k`` past its first contact (:class:`~vtlearn.sim_data.tactile.TactileSimulator`),
   and the taxels within that depth plus ``contact_tolerance`` (the sphere surface is bumpy) report
   their hit point.
3. ``Q(a) = ACTOR(P ∪ ŷ(a))`` for every candidate, in one batched forward pass.
4. The box-fit error of a reconstruction ``X`` in the canonical frame (box centred, largest extent 1)
   is ``E(X) = Σ_axes |lo_q(X) − b_lo| + |hi_q(X) − b_hi|``, with ``lo_q`` and ``hi_q`` the
   ``percentile``-th and ``(100 − percentile)``-th percentiles of ``X`` along the axis and
   ``b = ± extents / (2 · max extent)`` the known box. The gain is ``G(a) = E(R) − E(Q(a))``, and the
   action with the largest gain is taken.

The box is the one the action samplers already assume known (from the RGB segmentation in the thesis);
ACTOR gets only the points, in a frame whose origin and scale come from that box, and its output extents
are otherwise unconstrained. The measurements (a greedy oracle's headroom over random actions, and this
criterion against random and uniform on held-out transparent objects) are in docs/active_perception.md.

Frames and units: world frame, metres, as in :mod:`vtlearn.active.closed_loop`; the box-fit error is in
canonical units (fractions of the largest box extent).

Shapes:
    points_world ``(M, 3)``; candidates ``A`` actions; gains ``(A,)``; rays ``(R, 3)`` with ``(R,)``
    ``max_range`` and ``pad_index``; clouds ``(B, N, 3)``.
"""

from __future__ import annotations

import numpy as np
import torch

from vtlearn.validation import as_int, as_real

__all__ = ["ExpectedBoxFitGain", "box_fit_error", "predict_tactile_contacts"]


def predict_tactile_contacts(
    points, origins, directions, max_range, pad_index, radius: float, stop_depth: float
) -> tuple[np.ndarray, np.ndarray]:
    """Guarded pad motions replayed on a cloud of spheres (step 2 of the module docstring).

    Args:
        points: ``(M, 3)`` sphere centres (world frame).
        origins, directions: ``(R, 3)`` taxel rays, unit directions.
        max_range: ``(R,)`` ray lengths.
        pad_index: ``(R,)`` int pad of each ray; a pad stops at its first contact.
        radius: sphere radius (m).
        stop_depth: a taxel is in contact when its range is within this of its pad's first contact (m).

    Returns:
        ranges ``(R,)`` (inf where the ray meets no sphere within ``max_range``) and the contact mask
        ``(R,)`` bool.
    """
    P = np.asarray(points, dtype=np.float64)
    o, d = np.asarray(origins, dtype=np.float64), np.asarray(directions, dtype=np.float64)
    mr, pad = np.asarray(max_range, dtype=np.float64), np.asarray(pad_index)
    if P.ndim != 2 or P.shape[1] != 3 or len(P) == 0 or not np.isfinite(P).all():
        raise ValueError(f"points: need finite (M >= 1, 3), got shape {P.shape}")
    if o.ndim != 2 or o.shape[1] != 3 or d.shape != o.shape:
        raise ValueError(f"origins, directions: need (R, 3) each, got {o.shape} and {d.shape}")
    if mr.shape != (len(o),) or pad.shape != (len(o),) or not np.issubdtype(pad.dtype, np.integer):
        raise ValueError(
            f"max_range, pad_index: need ({len(o)},) each (pad_index int), got {mr.shape}, {pad.shape}"
        )
    radius = as_real(radius, "radius", low=0.0, open_low=True, unit="m")
    stop_depth = as_real(stop_depth, "stop_depth", low=0.0, unit="m")
    if len(o) == 0:
        return np.zeros(0), np.zeros(0, dtype=bool)
    Pt, ot, dt = (torch.from_numpy(a) for a in (P, o, d))
    v = Pt[None] - ot[:, None]  # R x M x 3
    along = (v * dt[:, None]).sum(-1)  # R x M
    perp2 = (v * v).sum(-1) - along**2
    inside = (perp2 < radius**2) & (along > 0)
    entry = along - torch.sqrt((radius**2 - perp2).clamp(min=0.0))
    t = torch.where(inside, entry, torch.full_like(entry, float("inf"))).min(1).values.numpy()
    t[t > mr] = np.inf
    first = np.full(int(pad.max()) + 1, np.inf)
    np.minimum.at(first, pad, t)
    contact = np.isfinite(t) & (t <= first[pad] + stop_depth)
    return t, contact


def box_fit_error(clouds, extents, percentile: float = 2.0) -> np.ndarray:
    """Box-fit error ``E`` of step 4: L1 distance of each cloud's percentile box to ``± extents / 2``.

    Shapes:
        clouds (B, N, 3) canonical frame, extents (3,) -> (B,)
    """
    X = np.asarray(clouds, dtype=np.float64)
    e = np.asarray(extents, dtype=np.float64)
    if X.ndim != 3 or X.shape[2] != 3 or X.shape[1] == 0 or not np.isfinite(X).all():
        raise ValueError(f"clouds: need finite (B, N >= 1, 3), got shape {X.shape}")
    if e.shape != (3,) or not np.isfinite(e).all() or (e <= 0).any():
        raise ValueError(f"extents: need 3 positive finite extents, got {e.tolist()}")
    percentile = as_real(percentile, "percentile", low=0.0, high=50.0, open_high=True)
    lo = np.percentile(X, percentile, axis=1)
    hi = np.percentile(X, 100.0 - percentile, axis=1)
    return np.abs(lo + e / 2).sum(1) + np.abs(hi - e / 2).sum(1)


class ExpectedBoxFitGain:
    """The gain ``G(a) = E(R) − E(Q(a))`` of the module docstring for an ACTOR ``model``.

    Args:
        model: an :class:`~vtlearn.models.actor.ACTOR` (or any module with its ``(x, lengths)`` call).
        max_points: network input points (random voxel subsampling, as the bench scores episodes).
        radius_factor: sphere radius over the mean nearest-neighbour spacing of the reconstruction.
        contact_tolerance: added to the elastomer compression ``τ_f / k`` when deciding which taxels of
            a pad are in contact (m).
        percentile: the robust extent of a cloud along an axis (see :func:`box_fit_error`).
    """

    def __init__(
        self,
        model,
        max_points: int = 120,
        radius_factor: float = 0.75,
        contact_tolerance: float = 0.002,
        percentile: float = 2.0,
    ):
        max_points = as_int(max_points, "max_points", minimum=3)
        radius_factor = as_real(radius_factor, "radius_factor", low=0.0, open_low=True)
        contact_tolerance = as_real(contact_tolerance, "contact_tolerance", low=0.0, unit="m")
        percentile = as_real(percentile, "percentile", low=0.0, high=50.0, open_high=True)
        self.model = model
        self.max_points = int(max_points)
        self.radius_factor = float(radius_factor)
        self.contact_tolerance = float(contact_tolerance)
        self.percentile = float(percentile)

    def _reconstruct(self, obj, clouds_world, seed: int) -> np.ndarray:
        from vtlearn.active.closed_loop import _pad, network_input
        from vtlearn.models.actor import reconstruct

        x, lengths = _pad([network_input(obj, c, self.max_points, seed=seed) for c in clouds_world])
        return reconstruct(self.model, x, lengths)  # B x N x 3 canonical

    def gains(self, obj, points_world: np.ndarray, candidates, touch_config, seed: int = 0) -> np.ndarray:
        """``G(a)`` for every candidate of ``candidates``, a list of ``(ActionSet, sensor)`` (tactile kinds).

        Args:
            obj: the :class:`~vtlearn.active.closed_loop.SimObject` (its bounding box and frames).
            points_world: the points measured so far (world frame); with fewer than 3 no reconstruction
                exists and every gain is 0.
            touch_config: the simulator's contact model (``force_threshold``, ``stiffness``).
            seed: voxel-subsampling seed of the network input.

        Shapes:
            points_world (M, 3) -> (A,), A the total number of candidates in order.
        """
        from vtlearn.active.sensors import Rays

        P = np.asarray(points_world, dtype=np.float64).reshape(-1, 3)
        if not np.isfinite(P).all():
            raise ValueError("points_world: contains NaN or inf")
        if not candidates or all(len(a) == 0 for a, _ in candidates):
            raise ValueError("candidates: need at least one non-empty (ActionSet, sensor) pair")
        if any(a.kind == "view" for a, _ in candidates):
            raise ValueError("candidates: the box-fit gain scores touches and pinches, not views")
        n_actions = sum(len(a) for a, _ in candidates)
        if len(P) < 3:
            return np.zeros(n_actions)
        # Rays are action-major and, within a pinch, pad-major: a pad is num_taxels consecutive rays.
        parts, pads, n_pads = [], [], 0
        for actions, sensor in candidates:
            if len(actions):
                r = sensor.rays(actions.T_world_sensor)
                parts.append(r)
                pads.append(n_pads + np.arange(len(r)) // sensor.layout.num_taxels)
                n_pads += len(r) // sensor.layout.num_taxels
        rays = Rays.concatenate(parts)
        pad, action = np.concatenate(pads), rays.action_index

        lo, hi = obj.bounds
        scale = float((hi - lo).max())
        R = self._reconstruct(obj, [P], seed)[0]
        surface = obj.from_canonical(R)
        surface[:, 2] = np.maximum(surface[:, 2], 0.0)  # nothing lies below the table
        nn = torch.cdist(torch.from_numpy(surface), torch.from_numpy(surface))
        nn.fill_diagonal_(float("inf"))
        radius = self.radius_factor * float(nn.min(1).values.mean())
        depth = float(touch_config.force_threshold) / float(touch_config.stiffness) + self.contact_tolerance
        t, contact = predict_tactile_contacts(
            surface, rays.origins, rays.directions, rays.max_range, pad, radius, depth
        )
        hit_points = rays.origins + np.where(contact, t, 0.0)[:, None] * rays.directions
        clouds = [np.concatenate([P, hit_points[contact & (action == a)]]) for a in range(n_actions)]
        Q = self._reconstruct(obj, clouds, seed)
        extents = (hi - lo) / scale
        e0 = box_fit_error(R[None], extents, self.percentile)[0]
        return e0 - box_fit_error(Q, extents, self.percentile)
