"""Probabilistic occupancy grid, batched 3-D DDA ray traversal and expected information gain.

Thesis 5.2.3 (eq. 5.6-5.9), 7.2.4 (eq. 7.9-7.12) and 8.2.3 (eq. 8.2-8.5) all use the same machinery:

- The space around the object is a dense voxel grid. Each cell is an independent Bernoulli variable
  stored as log-odds ``L(g) = log p(g) / (1 - p(g))``; every cell starts at ``p = 0.5`` (``L = 0``).
- A measurement ray updates the cell where it ends as a hit and the cells before it as misses,
  ``L(g|z) = L(g) + l(z)`` with ``l(hit) = logit(p_hit)`` and ``l(miss) = logit(p_miss)``,
  ``p_hit = 0.7`` and ``p_miss = 0.4`` (eq. 5.7 / 7.10 / 8.3, OctoMap sensor model, Hornung et al. 2013).
  As in OctoMap the log-odds are clamped to ``[logit(clamp_min), logit(clamp_max)]`` so that the map
  stays updatable; one scan updates each cell at most once, and a hit wins over a miss.
- The uncertainty of the grid is the Shannon entropy (eq. 5.6 = eq. 7.9, in nats)
  ``H(G) = -sum_g p log p + (1 - p) log(1 - p)``. Eq. 8.2 of the thesis prints the same sum without the
  leading minus and with ``(1 - log p)``; that is a typesetting slip, and eq. 5.6 is what is computed.
- The expected information gain of an action (eq. 5.8 / 7.11 / 8.4) is ``H(G) - H(G | a, z_hat)``:
  the prior entropy minus the entropy after a *hypothetical* update with the measurement the action is
  expected to produce. The expected measurement ``z_hat`` is a ray-cast against the current belief: a ray
  stops at the first cell whose occupancy probability exceeds ``occupied_threshold`` (a predicted hit),
  and runs to its maximum range through every other cell, unknown ones included (predicted misses).
  Because cells are independent, the gain is a sum over the distinct cells an action would update, so
  the gains of many candidate actions are computed at once without touching the grid.

Rays are traversed with the voxel walk of Amanatides and Woo (1987), vectorised over a batch of rays:
each iteration advances every live ray by one cell along the axis whose next boundary is nearest.

The grid is axis-aligned in the frame its rays are given in (call it the grid frame; for an object
with an oriented bounding box, express rays in the box frame). Units are metres.

Shapes:
    log_odds: ``(nx, ny, nz)`` float64; flat cell index ``i = (ix * ny + iy) * nz + iz``.
    origins, directions: ``(R, 3)``; max_range / ranges: ``(R,)`` or a scalar; hit: ``(R,)`` bool.
    action_index: ``(R,)`` int, the candidate action each ray belongs to (a PyG-style ``batch``
    vector); expected_information_gain -> ``(A,)``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from vtlearn.validation import as_int, as_points, as_real, as_vector

__all__ = [
    "OccupancyGrid",
    "RayTraversal",
    "binary_entropy",
    "logit",
]

# OctoMap's default clamping thresholds (Hornung et al. 2013): log-odds stay within [-2, 3.5].
DEFAULT_CLAMP_MIN = 0.1192
DEFAULT_CLAMP_MAX = 0.971


def _as_probability(p, name: str, *, closed: bool) -> np.ndarray:
    """``p`` as a float64 array of probabilities in ``[0, 1]`` (``closed``) or ``(0, 1)``; a ``ValueError``
    naming ``name`` for NaN, inf, anything outside that range, or something that is not numbers."""
    try:
        a = np.asarray(p, dtype=np.float64)
    except (TypeError, ValueError):
        raise ValueError(f"{name}: expected probabilities (numbers), got {p!r}") from None
    ok = np.isfinite(a) & ((a >= 0.0) & (a <= 1.0) if closed else (a > 0.0) & (a < 1.0))
    if not ok.all():
        bad = a[~ok].ravel()[0]
        raise ValueError(f"{name}: probabilities must lie in {'[0, 1]' if closed else '(0, 1)'}, "
                         f"got {bad!r} ({int((~ok).sum())} of {a.size} out of range)")
    return a


def logit(p):
    """Log-odds ``L = log p / (1 - p)`` of a probability in (0, 1); eq. 5.7 / 7.10 use
    ``l(hit) = logit(p_hit)``.

    Shapes:
        p: any shape, values in (0, 1) -> log-odds of the same shape.
    """
    p = _as_probability(p, "p", closed=False)
    return np.log(p) - np.log1p(-p)


def binary_entropy(p):
    """Per-cell Shannon entropy in nats, ``-p log p - (1 - p) log(1 - p)`` (the summand of eq. 5.6 / 7.9);
    0 at ``p = 0`` and ``p = 1``.

    Shapes:
        p: any shape, values in [0, 1] -> entropies of the same shape.
    """
    p = _as_probability(p, "p", closed=True)
    with np.errstate(divide="ignore", invalid="ignore"):
        h = -(p * np.log(p) + (1.0 - p) * np.log1p(-p))
    return np.where((p <= 0.0) | (p >= 1.0), 0.0, h)


def _entropy_from_log_odds(L: np.ndarray) -> np.ndarray:
    # With a = |L| and e = exp(-a): p = 1 / (1 + e) for the likelier outcome, and
    # -p log p - (1 - p) log(1 - p) = log(1 + e) + a e / (1 + e); exact far from p = 0.5 too.
    a = np.abs(L)
    e = np.exp(-a)
    return np.log1p(e) + a * e / (1.0 + e)


@dataclass
class RayTraversal:
    """The cells a batch of rays passes through, in walk order within each ray.

    Attributes:
        ray_index: ``(E,)`` int64, the ray of each visited cell.
        cell_index: ``(E,)`` int64, flat cell index of each visited cell.
        is_stop: ``(E,)`` bool, True for the cell where a ray was stopped by ``stop_mask``.
        stop_cell: ``(R,)`` int64, the stopping cell of each ray, or -1 where none stopped it.
        stop_range: ``(R,)`` float64, for stopped rays the distance along the ray to the middle of the
            segment inside the stopping cell (a point strictly inside it); ``inf`` for the others.
    """

    ray_index: np.ndarray
    cell_index: np.ndarray
    is_stop: np.ndarray
    stop_cell: np.ndarray
    stop_range: np.ndarray


class OccupancyGrid:
    """Dense voxel occupancy grid in log-odds (thesis eq. 5.6-5.9, 7.9-7.12, 8.2-8.5).

    Args:
        origin: ``(3,)`` grid-frame position of the grid's minimum corner, metres.
        resolution: edge length of a cubic cell, metres (``G_res`` / ``g_res`` / ``og_res`` in the thesis).
        shape: number of cells ``(nx, ny, nz)``.
        p_hit, p_miss: sensor model of eq. 5.7 (0.7 and 0.4 in the thesis).
        clamp_min, clamp_max: probability bounds the log-odds are clamped to after each update.
        occupied_threshold: a cell with ``p > occupied_threshold`` stops a predicted ray.

    Shapes:
        log_odds: ``(nx, ny, nz)``.
    """

    def __init__(
        self,
        origin,
        resolution: float,
        shape,
        *,
        p_hit: float = 0.7,
        p_miss: float = 0.4,
        clamp_min: float = DEFAULT_CLAMP_MIN,
        clamp_max: float = DEFAULT_CLAMP_MAX,
        occupied_threshold: float = 0.5,
    ):
        origin = as_vector(origin, "origin", 3, "a finite (3,) position")
        resolution = as_real(resolution, "resolution", low=0.0, open_low=True, unit="m")
        shape_arr = np.asarray(shape)
        if shape_arr.shape != (3,) or not np.issubdtype(shape_arr.dtype, np.integer) or (shape_arr < 1).any():
            raise ValueError(f"shape: expected three positive integers (nx, ny, nz), got {shape}")
        p_hit = as_real(p_hit, "p_hit", low=0.5, high=1.0, open_low=True, open_high=True)
        p_miss = as_real(p_miss, "p_miss", low=0.0, high=0.5, open_low=True, open_high=True)
        clamp_min = as_real(clamp_min, "clamp_min", low=0.0, high=0.5, open_low=True, open_high=True)
        clamp_max = as_real(clamp_max, "clamp_max", low=0.5, high=1.0, open_low=True, open_high=True)
        occupied_threshold = as_real(occupied_threshold, "occupied_threshold")
        if not clamp_min <= occupied_threshold < clamp_max:
            raise ValueError(
                f"occupied_threshold: must lie in [clamp_min, clamp_max), got {occupied_threshold}"
            )
        self.origin = origin
        self.resolution = float(resolution)
        self.shape = tuple(int(s) for s in shape_arr)
        self.p_hit, self.p_miss = float(p_hit), float(p_miss)
        self.l_hit, self.l_miss = float(logit(p_hit)), float(logit(p_miss))
        self.l_min, self.l_max = float(logit(clamp_min)), float(logit(clamp_max))
        self.l_occupied = float(logit(occupied_threshold))
        self.log_odds = np.zeros(self.shape, dtype=np.float64)
        self._stamp: np.ndarray | None = None
        # Size of the scratch buffer of expected_information_gain, in (action, cell) slots.
        self.max_buffer_cells = 1 << 24

    @classmethod
    def from_bounds(cls, lower, upper, cells_per_axis: int = 64, **kwargs) -> OccupancyGrid:
        """A cubic-cell grid covering ``[lower, upper]``; the longest side gets ``cells_per_axis`` cells."""
        lower = np.asarray(lower, dtype=np.float64)
        upper = np.asarray(upper, dtype=np.float64)
        if (
            lower.shape != (3,)
            or upper.shape != (3,)
            or not (np.isfinite(lower).all() and np.isfinite(upper).all())
        ):
            raise ValueError(
                f"lower, upper: expected finite (3,) corners, got {lower.tolist()}, {upper.tolist()}"
            )
        if (upper <= lower).any():
            raise ValueError(
                f"upper: must exceed lower on every axis, got lower={lower.tolist()} upper={upper.tolist()}"
            )
        cells_per_axis = as_int(cells_per_axis, "cells_per_axis")
        res = float((upper - lower).max()) / cells_per_axis
        shape = np.maximum(np.ceil((upper - lower) / res - 1e-9).astype(np.int64), 1)
        return cls(lower, res, shape, **kwargs)

    # ------------------------------------------------------------------ basic queries
    @property
    def n_cells(self) -> int:
        return int(np.prod(self.shape))

    @property
    def upper(self) -> np.ndarray:
        """``(3,)`` maximum corner of the grid."""
        return self.origin + self.resolution * np.asarray(self.shape, dtype=np.float64)

    def copy(self) -> OccupancyGrid:
        other = OccupancyGrid.__new__(OccupancyGrid)
        other.__dict__.update(self.__dict__)
        other.log_odds = self.log_odds.copy()
        other._stamp = None
        return other

    def probabilities(self) -> np.ndarray:
        """``(nx, ny, nz)`` occupancy probabilities ``p(g)``."""
        return 0.5 * (1.0 + np.tanh(0.5 * self.log_odds))

    def cell_entropy(self) -> np.ndarray:
        """``(nx, ny, nz)`` per-cell entropy in nats (summands of eq. 5.6 / 7.9)."""
        return _entropy_from_log_odds(self.log_odds)

    def entropy(self) -> float:
        """Shannon entropy of the whole grid in nats, eq. 5.6 / 7.9. An all-unknown grid has ``n ln 2``."""
        return float(self.cell_entropy().sum())

    def occupied_mask(self) -> np.ndarray:
        """``(nx, ny, nz)`` bool, cells believed occupied (``p > occupied_threshold``)."""
        return self.log_odds > self.l_occupied

    def known_fraction(self, margin: float = 0.1) -> float:
        """Fraction of cells whose probability is at least ``margin`` (in [0, 0.5]) away from 0.5."""
        margin = as_real(margin, "margin", low=0.0, high=0.5)
        return float((np.abs(self.probabilities() - 0.5) >= margin).mean())

    def point_to_cell(self, points) -> np.ndarray:
        """``(N, 3)`` integer cell coordinates of grid-frame points (may lie outside ``[0, shape)``)."""
        pts = as_points(points, "points")
        return np.floor((pts - self.origin) / self.resolution).astype(np.int64)

    def _as_cells(self, cells, inside: bool) -> np.ndarray:
        """``cells`` as ``(N, 3)`` int64 cell coordinates; a ``ValueError`` naming ``cells`` for another
        shape, non-integer values, or (with ``inside``) a cell outside ``[0, shape)``."""
        a = np.asarray(cells)
        if a.ndim != 2 or a.shape[1] != 3 or not (
            np.issubdtype(a.dtype, np.integer) or (np.issubdtype(a.dtype, np.floating)
                                                   and np.isfinite(a).all() and (a == np.round(a)).all())
        ):
            raise ValueError(f"cells: expected (N, 3) integer cell coordinates, got {a.dtype} {a.shape}")
        a = a.astype(np.int64)
        if inside and ((a < 0) | (a >= np.asarray(self.shape))).any(axis=1).any():
            bad = a[((a < 0) | (a >= np.asarray(self.shape))).any(axis=1)][0]
            raise ValueError(f"cells: {bad.tolist()} lies outside the grid of shape {self.shape}")
        return a

    def cell_centers(self, cells=None) -> np.ndarray:
        """Grid-frame centres of integer cells (metres), or of all cells in flat order when None.

        Shapes:
            cells: ``(N, 3)`` int (may lie outside the grid) -> ``(N, 3)``; None -> ``(n_cells, 3)``.
        """
        if cells is None:
            cells = np.stack(np.unravel_index(np.arange(self.n_cells), self.shape), axis=1)
        cells = self._as_cells(cells, inside=False)
        return self.origin + (cells + 0.5) * self.resolution

    def flat_index(self, cells) -> np.ndarray:
        """Flat index ``(ix * ny + iy) * nz + iz`` of cells inside the grid.

        Shapes:
            cells: ``(N, 3)`` int in ``[0, shape)`` -> ``(N,)`` int64.
        """
        cells = self._as_cells(cells, inside=True)
        return np.ravel_multi_index(cells.T, self.shape)

    # ------------------------------------------------------------------ ray traversal
    def _check_rays(self, origins, directions, max_range, range_name: str = "max_range"):
        o = as_points(origins, "origins")
        d = as_points(directions, "directions")
        if d.shape[0] != o.shape[0]:
            raise ValueError(f"directions: expected {o.shape[0]} rays to match origins, got {d.shape[0]}")
        norm = np.linalg.norm(d, axis=1)
        if (norm < 1e-12).any():
            raise ValueError(f"directions: {int((norm < 1e-12).sum())} direction vectors have zero length")
        d = d / norm[:, None]
        r = np.asarray(max_range, dtype=np.float64)
        if r.ndim == 0:
            r = np.full(o.shape[0], float(r))
        if r.shape != (o.shape[0],):
            raise ValueError(
                f"{range_name}: expected a scalar or shape ({o.shape[0]},), got {tuple(r.shape)}"
            )
        if not np.isfinite(r).all() or (r < 0).any():
            raise ValueError(f"{range_name}: must be finite and non-negative")
        return o, d, r

    def traverse(self, origins, directions, max_range, stop_mask=None) -> RayTraversal:
        """Walk rays through the grid with the vectorised Amanatides-Woo DDA.

        A ray visits every cell it enters at a distance ``t < max_range`` from its origin, in order. With
        ``stop_mask`` (an ``(nx, ny, nz)`` bool array) a ray also ends at the first cell where the mask is
        True, and that cell is flagged in ``is_stop``. The output is ray-major: all cells of ray 0 in walk
        order, then those of ray 1, and so on (rays that miss the grid contribute nothing).

        Shapes:
            origins, directions: ``(R, 3)`` (directions need not be unit); max_range: scalar or ``(R,)``.
        """
        o, d, t_max = self._check_rays(origins, directions, max_range)
        stop_flat = None
        if stop_mask is not None:
            stop_mask = np.asarray(stop_mask, dtype=bool)
            if stop_mask.shape != self.shape:
                raise ValueError(f"stop_mask: expected shape {self.shape}, got {tuple(stop_mask.shape)}")
            stop_flat = stop_mask.ravel()
        return self._dda(o, d, t_max, stop_flat)

    def _dda(
        self, o: np.ndarray, d: np.ndarray, t_max: np.ndarray, stop_flat: np.ndarray | None
    ) -> RayTraversal:
        n_rays = o.shape[0]
        lo, hi, res = self.origin, self.upper, self.resolution
        shape = np.asarray(self.shape, dtype=np.int64)
        with np.errstate(divide="ignore", invalid="ignore"):
            inv_d = 1.0 / d
            # Slab test; an axis-parallel ray is inside a slab for all t or for none.
            t1 = (lo - o) * inv_d
            t2 = (hi - o) * inv_d
        inside = (o >= lo) & (o <= hi)
        parallel = d == 0.0
        t_near = np.where(parallel, np.where(inside, -np.inf, np.inf), np.minimum(t1, t2))
        t_far = np.where(parallel, np.where(inside, np.inf, -np.inf), np.maximum(t1, t2))
        t_enter = np.maximum(t_near.max(axis=1), 0.0)
        t_exit = np.minimum(t_far.min(axis=1), t_max)
        live = t_enter < t_exit

        stop_cell = np.full(n_rays, -1, dtype=np.int64)
        stop_range = np.full(n_rays, np.inf)
        ray = np.nonzero(live)[0]
        if ray.size == 0:
            empty = np.zeros(0, dtype=np.int64)
            return RayTraversal(empty, empty.copy(), np.zeros(0, dtype=bool), stop_cell, stop_range)

        o, d, inv_d = o[ray], d[ray], inv_d[ray]
        t_in, t_end = t_enter[ray], t_exit[ray]
        cell0 = np.floor((o + d * t_in[:, None] - lo) / res).astype(np.int64)
        np.clip(cell0, 0, shape - 1, out=cell0)
        step = np.sign(d).astype(np.int64)
        moving = step != 0
        with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
            # Time of the first boundary crossing along each axis, and the time between crossings.
            t_first = np.where(moving, (lo + (cell0 + (step > 0)) * res - o) * inv_d, np.inf)
            t_delta = np.where(moving, res * np.abs(inv_d), np.inf)
            # Crossings k = 0, 1, ... happen at t_first + k * t_delta; count those before t_end, but no
            # more than the cells left in the grid along that axis.
            room = np.where(step > 0, shape - 1 - cell0, np.where(step < 0, cell0, 0))
            est = np.where(moving, np.ceil((t_end[:, None] - t_first) / t_delta), 0.0)
        n_cross = np.clip(np.nan_to_num(est, nan=0.0, posinf=0.0, neginf=0.0), 0, room).astype(np.int64)
        n_cross = self._fix_count(n_cross, t_first, t_delta, t_end[:, None], room, inclusive=False)

        # Amanatides-Woo visits cells in the order of the crossing times; merged over the three axes
        # that order is closed-form: the rank of a crossing is 1 + the crossings before it on all axes
        # (ties go to the lower axis first, as argmin would pick it). No sort and no per-step loop.
        m = 1 + n_cross.sum(axis=1)
        offset = np.cumsum(m) - m
        total = int(m.sum())
        strides = np.array([shape[1] * shape[2], shape[2], 1], dtype=np.int64)
        flat0 = cell0 @ strides
        cell_index = np.empty(total, dtype=np.int64)
        cell_index[offset] = flat0
        for a in range(3):
            cnt_a = n_cross[:, a]
            n_ev = int(cnt_a.sum())
            if n_ev == 0:
                continue
            # Per-ray values are expanded with np.repeat (sequential) rather than gathered.
            ev_k = np.arange(n_ev) - np.repeat(np.cumsum(cnt_a) - cnt_a, cnt_a)
            t_ev = np.repeat(t_first[:, a], cnt_a) + ev_k * np.repeat(t_delta[:, a], cnt_a)
            rank = 1 + ev_k
            flat = np.repeat(flat0, cnt_a) + (ev_k + 1) * np.repeat(step[:, a] * strides[a], cnt_a)
            for b in range(3):
                if b == a or not n_cross[cnt_a > 0, b].any():
                    continue
                nb = np.repeat(n_cross[:, b], cnt_a)
                tf, td = np.repeat(t_first[:, b], cnt_a), np.repeat(t_delta[:, b], cnt_a)
                with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
                    est = np.ceil((t_ev - tf) / td)
                cnt = np.clip(np.nan_to_num(est, nan=0.0, posinf=0.0, neginf=0.0), 0, nb).astype(np.int64)
                cnt = self._fix_count(cnt, tf, td, t_ev, nb, inclusive=b < a)
                rank += cnt
                flat += cnt * np.repeat(step[:, b] * strides[b], cnt_a)
            cell_index[np.repeat(offset, cnt_a) + rank] = flat
        ray_out = np.repeat(ray, m)

        no_stop = np.zeros(total, dtype=bool)
        if stop_flat is None:
            return RayTraversal(ray_out, cell_index, no_stop, stop_cell, stop_range)
        occ_pos = np.flatnonzero(stop_flat[cell_index])
        if occ_pos.size == 0:
            return RayTraversal(ray_out, cell_index, no_stop, stop_cell, stop_range)
        # Entries are ray-major, so the first stopping entry of each ray is its first occurrence.
        occ_ray = np.searchsorted(offset, occ_pos, side="right") - 1  # local ray of each entry
        first = np.r_[True, occ_ray[1:] != occ_ray[:-1]]
        pos, r_loc = occ_pos[first], occ_ray[first]
        # Drop everything after the stopping cell of each stopped ray.
        n_drop = offset[r_loc] + m[r_loc] - 1 - pos
        drop = np.repeat(pos + 1 - np.cumsum(n_drop) + n_drop, n_drop) + np.arange(int(n_drop.sum()))
        keep = np.ones(total, dtype=bool)
        keep[drop] = False
        is_stop = no_stop
        is_stop[pos] = True
        # Distance to the middle of the ray's segment inside the stopping cell (slab test on that cell).
        cell_lo = lo + np.stack(np.unravel_index(cell_index[pos], self.shape), axis=1) * res
        with np.errstate(invalid="ignore", over="ignore"):
            ta = (cell_lo - o[r_loc]) * inv_d[r_loc]
            tb = (cell_lo + res - o[r_loc]) * inv_d[r_loc]
        par = d[r_loc] == 0.0
        t_lo = np.where(par, -np.inf, np.minimum(ta, tb)).max(axis=1)
        t_hi = np.where(par, np.inf, np.maximum(ta, tb)).min(axis=1)
        t_lo = np.maximum(t_lo, t_in[r_loc])
        t_hi = np.minimum(t_hi, t_end[r_loc])
        stop_cell[ray[r_loc]] = cell_index[pos]
        stop_range[ray[r_loc]] = 0.5 * (t_lo + np.maximum(t_hi, t_lo))
        return RayTraversal(ray_out[keep], cell_index[keep], is_stop[keep], stop_cell, stop_range)

    @staticmethod
    def _fix_count(cnt, t_first, t_delta, t_limit, cap, inclusive: bool):
        """Correct a ceil-division count of crossings ``t_first + k t_delta < t_limit`` (``<=`` when
        ``inclusive``) by at most one in each direction, comparing the same floats the walk uses."""

        def before(k):
            with np.errstate(invalid="ignore", over="ignore"):
                t = t_first + k * t_delta
            return (t <= t_limit) if inclusive else (t < t_limit)

        down = (cnt > 0) & ~before(np.maximum(cnt - 1, 0))
        cnt = cnt - down
        up = (cnt < cap) & before(cnt)
        return cnt + up

    # ------------------------------------------------------------------ measurement updates
    def insert_rays(self, origins, directions, ranges, hit) -> None:
        """Integrate one scan of measured rays (eq. 5.7): the end cell of a hit ray is updated as a hit,
        every cell before it as a miss; a ray without a return (``hit`` False) misses every cell up to
        ``ranges``. Each cell is updated at most once per call, and hit wins over miss.

        Args:
            ranges: measured ranges, finite and ``>= 0``.

        Shapes:
            origins, directions: ``(R, 3)``; ranges: scalar or ``(R,)``; hit: ``(R,)`` bool.
        """
        o, d, r = self._check_rays(origins, directions, ranges, "ranges")
        hit = np.asarray(hit, dtype=bool)
        if hit.shape != (o.shape[0],):
            raise ValueError(f"hit: expected a ({o.shape[0]},) bool array, got shape {tuple(hit.shape)}")
        trav = self._dda(o, d, r, None)
        end_cells = np.floor((o + d * r[:, None] - self.origin) / self.resolution).astype(np.int64)
        in_grid = hit & ((end_cells >= 0) & (end_cells < np.asarray(self.shape))).all(axis=1)
        end_flat = np.full(o.shape[0], -1, dtype=np.int64)
        if in_grid.any():
            end_flat[in_grid] = np.ravel_multi_index(end_cells[in_grid].T, self.shape)
        free = trav.cell_index[trav.cell_index != end_flat[trav.ray_index]]
        self._apply(np.unique(free), np.unique(end_flat[in_grid]))

    def insert_points(self, origins, endpoints) -> None:
        """Integrate hit rays from ``origins`` to measured surface points ``endpoints`` (both ``(R, 3)``)."""
        o = as_points(origins, "origins")
        e = as_points(endpoints, "endpoints")
        if e.shape != o.shape:
            raise ValueError(f"endpoints: expected shape {o.shape} to match origins, got {e.shape}")
        delta = e - o
        r = np.linalg.norm(delta, axis=1)
        if (r < 1e-12).any():
            raise ValueError("endpoints: some endpoints coincide with their origins")
        self.insert_rays(o, delta / r[:, None], r, np.ones(o.shape[0], dtype=bool))

    def _apply(self, miss_cells: np.ndarray, hit_cells: np.ndarray) -> None:
        L = self.log_odds.reshape(-1)
        miss_cells = np.setdiff1d(miss_cells, hit_cells, assume_unique=True)
        L[miss_cells] = np.clip(L[miss_cells] + self.l_miss, self.l_min, self.l_max)
        L[hit_cells] = np.clip(L[hit_cells] + self.l_hit, self.l_min, self.l_max)

    # ------------------------------------------------------------------ prediction and information gain
    def expected_measurement(self, origins, directions, max_range) -> tuple[np.ndarray, np.ndarray]:
        """Ray-cast against the current belief: the measurement each ray is expected to return.

        Returns:
            ranges: ``(R,)`` distance to a point inside the first cell believed occupied, else ``max_range``.
            hit: ``(R,)`` bool, whether a believed-occupied cell was met before ``max_range``.
        """
        o, d, r = self._check_rays(origins, directions, max_range)
        trav = self._dda(o, d, r, self.occupied_mask().ravel())
        hit = trav.stop_cell >= 0
        return np.where(hit, trav.stop_range, r), hit

    def _delta_entropy_tables(self) -> tuple[np.ndarray, np.ndarray]:
        """Per-cell entropy drop of one miss and of one hit update, ``(n_cells,)`` each."""
        L = self.log_odds.reshape(-1)

        def drop(Lc):
            h0 = _entropy_from_log_odds(Lc)
            return (
                h0 - _entropy_from_log_odds(np.clip(Lc + self.l_miss, self.l_min, self.l_max)),
                h0 - _entropy_from_log_odds(np.clip(Lc + self.l_hit, self.l_min, self.l_max)),
            )

        # Unknown cells (L = 0) share one value; evaluating the entropy only at known cells keeps this
        # cheap early in an exploration, when most of the grid is unknown.
        known = np.flatnonzero(L)
        miss0, hit0 = drop(np.zeros(1))
        dh_miss = np.full(L.size, miss0[0])
        dh_hit = np.full(L.size, hit0[0])
        if known.size:
            dh_miss[known], dh_hit[known] = drop(L[known])
        return dh_miss, dh_hit

    def expected_information_gain(
        self,
        origins,
        directions,
        max_range,
        action_index=None,
        n_actions: int | None = None,
        mode: str = "raycast",
    ) -> np.ndarray:
        """Expected information gain ``H(G) - H(G | a, z_hat)`` of many candidate actions at once (eq. 5.8).

        Each action is the set of rays that share its ``action_index``. With ``mode="raycast"`` (the
        thesis' criterion) its expected measurement is the ray-cast of :meth:`expected_measurement`; the
        hypothetical update follows :meth:`insert_rays` (each cell once per action, hit over miss), and
        the grid itself is left unchanged.

        ``mode="probabilistic"`` is an extension beyond the thesis: each ray may stop in any cell it
        crosses, with probability ``p_i prod_{j<i} (1 - p_j)`` under the current belief, and the gain is
        the expectation over those outcomes (stop at ``i``: misses before ``i``, a hit at ``i``; no
        stop: misses everywhere). Unknown cells then count as likely surface instead of free space, so
        the criterion stops favouring long sweeps through unexplored volume. The rays of one action are
        treated as independent here (their gains add), so overlapping rays are counted more than once.

        Args:
            origins, directions, max_range: the rays of all candidate actions, grid frame.
            action_index: ``(R,)`` int in ``[0, n_actions)``; None means one ray per action.
            n_actions: number of actions ``A``; defaults to ``action_index.max() + 1``.
            mode: ``"raycast"`` or ``"probabilistic"``.

        Shapes:
            origins, directions: ``(R, 3)``; max_range: scalar or ``(R,)``; -> ``(A,)`` nats.
        """
        o, d, r = self._check_rays(origins, directions, max_range)
        if action_index is None:
            action_index = np.arange(o.shape[0])
        action_index = np.asarray(action_index)
        if action_index.shape != (o.shape[0],) or not np.issubdtype(action_index.dtype, np.integer):
            raise ValueError(
                f"action_index: expected a ({o.shape[0]},) integer array, "
                f"got {action_index.dtype} {action_index.shape}"
            )
        if (action_index < 0).any():
            raise ValueError("action_index: must be non-negative")
        n_act = int(action_index.max()) + 1 if n_actions is None else as_int(n_actions, "n_actions")
        if n_act < int(action_index.max()) + 1:
            raise ValueError(
                f"n_actions: {n_act} is smaller than action_index.max() + 1 = {int(action_index.max()) + 1}"
            )

        if mode == "probabilistic":
            return self._probabilistic_gain(o, d, r, action_index, n_act)
        if mode != "raycast":
            raise ValueError(f"mode: expected 'raycast' or 'probabilistic', got {mode!r}")
        trav = self._dda(o, d, r, self.occupied_mask().ravel())
        dh_miss, dh_hit = self._delta_entropy_tables()
        act = action_index[trav.ray_index].astype(np.int64)
        cells, is_hit = trav.cell_index, trav.is_stop
        rep = self._first_per_action_cell(act, cells, is_hit, n_act)
        if rep.size < act.size:  # some rays of an action share cells
            act, cells, is_hit = act[rep], cells[rep], is_hit[rep]
        gain = np.where(is_hit, dh_hit[cells], dh_miss[cells])
        return np.bincount(act, weights=gain, minlength=n_act)

    def _probabilistic_gain(self, o, d, r, action_index, n_act) -> np.ndarray:
        trav = self._dda(o, d, r, None)
        if trav.cell_index.size == 0:
            return np.zeros(n_act)
        dh_miss, dh_hit = self._delta_entropy_tables()
        L = self.log_odds.reshape(-1)[trav.cell_index]
        p = 0.5 * (1.0 + np.tanh(0.5 * L))
        log_free = -np.logaddexp(0.0, L)  # log(1 - p)
        ray = trav.ray_index
        start = np.r_[True, ray[1:] != ray[:-1]]
        seg = np.cumsum(start) - 1  # segment (ray) id of every entry, entries are ray-major
        first = np.flatnonzero(start)

        def exclusive_segment_cumsum(x):
            c = np.cumsum(x) - x
            return c - c[first][seg]

        reach = np.exp(exclusive_segment_cumsum(log_free))  # P(ray reaches cell i)
        m_before = exclusive_segment_cumsum(dh_miss[trav.cell_index])
        m_all = m_before + dh_miss[trav.cell_index]
        last = np.r_[first[1:] - 1, ray.size - 1]
        gain_stop = reach * p * (m_before + dh_hit[trav.cell_index])
        ray_gain = np.bincount(seg, weights=gain_stop)
        ray_gain += reach[last] * (1.0 - p[last]) * m_all[last]  # passes every cell
        return np.bincount(action_index[ray[first]], weights=ray_gain, minlength=n_act)

    def _first_per_action_cell(self, act, cells, is_hit, n_act) -> np.ndarray:
        """Indices of one entry per distinct (action, cell) pair, a hit entry wherever the pair has one.

        A scratch buffer indexed by ``(action, cell)`` is written with entry ids, misses first and hits
        second; afterwards exactly one entry per pair reads back its own id. Only written slots are read,
        so the buffer never needs clearing; actions are processed in chunks to bound its size.
        """
        n_cells = self.n_cells
        chunk = max(1, min(n_act, self.max_buffer_cells // n_cells))
        if self._stamp is None or self._stamp.size < chunk * n_cells:
            self._stamp = np.empty(chunk * n_cells, dtype=np.int64)
        buf = self._stamp
        entry = np.arange(act.size, dtype=np.int64)
        keep = np.zeros(act.size, dtype=bool)
        # Entries come ray-major, so they are grouped by action whenever the rays are.
        grouped = act.size < 2 or bool((act[1:] >= act[:-1]).all())
        for a0 in range(0, n_act, chunk):
            if chunk >= n_act:
                sel = entry
            elif grouped:
                i0, i1 = np.searchsorted(act, [a0, a0 + chunk])
                sel = entry[i0:i1]
            else:
                sel = entry[(act >= a0) & (act < a0 + chunk)]
            key = (act[sel] - a0) * n_cells + cells[sel]
            h = is_hit[sel]
            if h.any():
                buf[key[~h]] = sel[~h]
                buf[key[h]] = sel[h]
            else:
                buf[key] = sel
            keep[sel[buf[key] == sel]] = True
        return np.nonzero(keep)[0]
