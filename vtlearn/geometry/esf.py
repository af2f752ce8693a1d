"""Ensemble of Shape Functions (ESF): a 640-bin global shape descriptor of a point cloud.

ESF is the descriptor of Wohlkinger and Vincze, "Ensemble of shape functions for 3D object classification",
IEEE ROBIO 2011. This module follows PCL's ``pcl::ESFEstimation``: the cloud is centred, scaled into a
``GRIDSIZE = 64`` voxel grid (farthest point at 32 voxels), voxelised with a 3x3x3 dilation, and 20000 random
point triplets give three shape functions (A3 angles, D2 distances, D3 sqrt-areas), each split by whether
the connecting lines run on the surface ("in"), off it ("out") or both ("mixed"). The ten weighted
64-bin histograms, concatenated in the order of ``ESF_BLOCKS`` and normalised to sum 1, are the descriptor.

In vtlearn it is the hand-crafted descriptor of the classical cross-modal baseline (descriptor + Geodesic
Flow Kernel + 1-NN/SVM, thesis Table 7.4). The thesis used the CLUE descriptor of Falco et al. (2019), which
is not public; ESF, the PCL global descriptor, takes its place.

Everything is vectorised over triplets: line tracing pads each line to a common length with a mask, so one
cloud of up to ~1000 points takes a few tens of milliseconds at the default 20000 samples.

Deviations from PCL (all deliberate):

* float64 instead of float32, so a value on a bin edge can rarely land one bin over.
* D2 is normalised by the true largest distance; PCL's max loop skips the last third of the distances and
  can then index past the histogram (undefined behaviour in C++).
* ``|cos|`` is clipped to 1 before ``arccos`` instead of rejecting the triplet when rounding pushes it over.
* voxel indices are clipped to the grid, which PCL leaves to luck when rounding puts a point at 32 + eps.
* triplets come from a seeded ``numpy.random.Generator`` instead of ``rand()`` seeded with the time.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence

import numpy as np

from vtlearn.validation import as_int, as_points

__all__ = ["ESF_BINS", "ESF_BLOCKS", "ESF_BLOCK_SLICES", "ESF_DIM", "esf_descriptor", "esf_descriptors"]

ESF_BINS = 64
ESF_BLOCKS = (
    "a3_in", "a3_out", "a3_mix",
    "d3_in", "d3_out", "d3_mix",
    "d2_in", "d2_out", "d2_mix", "d2_mix_ratio",
)
ESF_DIM = ESF_BINS * len(ESF_BLOCKS)
ESF_BLOCK_SLICES = {name: slice(i * ESF_BINS, (i + 1) * ESF_BINS) for i, name in enumerate(ESF_BLOCKS)}

_GRID = 64
_GRID_H = _GRID // 2
# PCL's block weights; d2_in and d2_mix_ratio carry an extra 0.5 in PCL's push_back loop.
_WEIGHTS = np.array([0.5, 0.5, 0.5, 0.5, 0.5, 1.0, 0.5 * 1.0, 2.0, 2.0, 0.5 * 2.0])
_HERON_MIN = 0.001
# Give up once this many triplets per requested sample were drawn: below a 1 % acceptance rate the cloud is
# degenerate for ESF (nearly all points coincide or lie on a line) and more drawing would not help.
_MAX_DRAW_FACTOR = 100
_LINE_BUCKET = 8


def _round_half_up(x: np.ndarray) -> np.ndarray:
    # PCL's pcl_round is roundf (half away from zero); np.round is half-to-even. All inputs here are >= 0.
    return np.floor(x + 0.5).astype(np.intp)


def _norm3(v: np.ndarray) -> np.ndarray:
    # Column-wise sum in a fixed order so that a 90-degree rotation (a permutation + sign flip of columns)
    # gives bit-identical lengths, hence the exact rotation test.
    return np.sqrt(v[..., 0] * v[..., 0] + v[..., 1] * v[..., 1] + v[..., 2] * v[..., 2])


def _scale_to_grid(points: np.ndarray) -> np.ndarray:
    """Centre on the centroid and scale so that the farthest point is at ``GRIDSIZE / 2 = 32``."""
    centred = points - points.mean(axis=0)
    return centred * (_GRID_H / _norm3(centred).max())


def _voxel_indices(scaled: np.ndarray) -> np.ndarray:
    """PCL's asymmetric voxel mapping: ``floor(c) + 32`` for ``c < 0``, else ``ceil(c) + 31``.

    Shapes:
        scaled (N, 3) -> (N, 3) int in [0, 63]
    """
    idx = np.where(scaled < 0.0, np.floor(scaled) + _GRID_H, np.ceil(scaled) + (_GRID_H - 1))
    return np.clip(idx, 0, _GRID - 1).astype(np.intp)


def _voxelise(scaled: np.ndarray) -> np.ndarray:
    """PCL's ``voxelize9``: each point's voxel and its 3x3x3 neighbourhood (clipped to the grid) occupied.

    Shapes:
        scaled (N, 3) -> (64, 64, 64) bool
    """
    grid = np.zeros((_GRID,) * 3, dtype=bool)
    v = _voxel_indices(scaled)
    grid[v[:, 0], v[:, 1], v[:, 2]] = True
    # A cube is separable: three 1-D dilations by one voxel equal the 3x3x3 one.
    for axis in range(3):
        g = np.moveaxis(grid, axis, 0)
        out = g.copy()
        out[1:] |= g[:-1]
        out[:-1] |= g[1:]
        grid = np.moveaxis(out, 0, axis)
    return np.ascontiguousarray(grid)


def _trace_lines(occupancy: np.ndarray, start: np.ndarray, end: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Occupied-voxel count and voxel count of PCL's 3-D Bresenham walk (``ESFEstimation::lci``).

    PCL visits the voxels at steps ``k = 0 .. max(L, 1) - 1`` from the start voxel along the driving axis,
    where ``L = max |delta|``, so the end voxel itself is never visited (unless ``L = 0``). On every axis
    PCL's integer error term puts the walk at offset ``sign(d) * ceil((2 |d| k - L) / (2 L))`` after ``k``
    steps (by induction on the error term; the driving axis gets ``k``), which is ``floor(k |d| / L + 1/2)``
    with ties rounded down. Evaluated as ``floor(k |d| / L + 0.499)`` in float32 it is exact: a non-tie
    ``k |d| / L`` is at least ``1 / (2 L) >= 1 / 126`` away from a half-integer, far more than 0.001 plus
    the rounding error.

    Shapes:
        occupancy (64, 64, 64), start (M, 3), end (M, 3) -> in_count (M,), count (M,)
    """
    occ = occupancy.reshape(-1)
    delta = end - start
    absd = np.abs(delta)
    length = absd.max(axis=1)
    count = np.maximum(length, 1)
    rate = (absd / np.maximum(length, 1)[:, None]).astype(np.float32)
    strides = np.array([_GRID * _GRID, _GRID, 1])
    signed_stride = np.where(delta < 0, -strides, strides).astype(np.int32)
    start_flat = (start @ strides).astype(np.int32)
    in_count = np.zeros(len(start), dtype=np.intp)
    # Lines padded per length bucket rather than all to 64 steps: mean length is ~half the maximum.
    bucket = (count - 1) // _LINE_BUCKET
    for b in np.unique(bucket):
        sel = np.flatnonzero(bucket == b)
        n_steps = int(count[sel].max())
        k = np.arange(n_steps, dtype=np.float32)
        flat = np.repeat(start_flat[sel, None], n_steps, axis=1)
        for axis in range(3):
            off = k * rate[sel, axis, None]
            off += 0.499
            step = off.astype(np.int32)
            step *= signed_stride[sel, axis, None]
            flat += step
        # Padding steps run past the end voxel, possibly off the grid; they are masked, so clip them anywhere.
        visited = occ.take(flat, mode="clip")
        visited &= np.arange(n_steps) < count[sel, None]
        in_count[sel] = np.count_nonzero(visited, axis=1)
    return in_count, count


def _sample_triplets(scaled: np.ndarray, n_samples: int, rng: np.random.Generator, name: str) -> np.ndarray:
    """``n_samples`` triplets of distinct indices whose triangle passes PCL's Heron test, drawn in batches.

    Shapes:
        scaled (N, 3) -> (n_samples, 3) int
    """
    n = len(scaled)
    kept: list[np.ndarray] = []
    n_kept = drawn = 0
    while n_kept < n_samples:
        if drawn >= _MAX_DRAW_FACTOR * n_samples:
            raise ValueError(
                f"{name}: only {n_kept} of {n_samples} random triplets had a non-degenerate triangle after "
                f"{drawn} draws; the cloud is (nearly) collinear or has too few distinct points for ESF"
            )
        rate = max(n_kept, 1) / drawn if drawn else 0.8
        # Capped so that a near-degenerate cloud costs a few bounded rounds, not one huge allocation.
        batch = int(min((n_samples - n_kept) / rate * 1.1, 10 * n_samples) + 64)
        idx = rng.integers(0, n, size=(batch, 3))
        drawn += batch
        idx = idx[(idx[:, 0] != idx[:, 1]) & (idx[:, 0] != idx[:, 2]) & (idx[:, 1] != idx[:, 2])]
        p1, p2, p3 = scaled[idx[:, 0]], scaled[idx[:, 1]], scaled[idx[:, 2]]
        a, b, c = _norm3(p2 - p1), _norm3(p3 - p1), _norm3(p2 - p3)
        s = (a + b + c) * 0.5
        idx = idx[s * (s - a) * (s - b) * (s - c) > _HERON_MIN]
        kept.append(idx[: n_samples - n_kept])
        n_kept += len(kept[-1])
    return np.concatenate(kept)


def _histogram(index: np.ndarray, weights: np.ndarray | None = None) -> np.ndarray:
    return np.bincount(index, weights=weights, minlength=ESF_BINS).astype(np.float64)


def _esf_from_triplets(scaled: np.ndarray, occupancy: np.ndarray, triplets: np.ndarray) -> np.ndarray:
    """The ESF histogram of given triplets (PCL's ``computeESF`` after sampling).

    Args:
        scaled: the cloud after :func:`_scale_to_grid`.
        occupancy: :func:`_voxelise` of ``scaled``.
        triplets: point indices; every triangle must pass the Heron test.

    Shapes:
        scaled (N, 3), occupancy (64, 64, 64), triplets (S, 3) -> (640,)
    """
    i1, i2, i3 = triplets[:, 0], triplets[:, 1], triplets[:, 2]
    p1, p2, p3 = scaled[i1], scaled[i2], scaled[i3]
    v21, v31, v23 = p2 - p1, p3 - p1, p2 - p3
    a, b, c = _norm3(v21), _norm3(v31), _norm3(v23)
    s = (a + b + c) * 0.5
    d3 = np.sqrt(np.sqrt(s * (s - a) * (s - b) * (s - c)))
    u21, u31, u23 = v21 / a[:, None], v31 / b[:, None], v23 / c[:, None]

    def angle_bin(u: np.ndarray, v: np.ndarray) -> np.ndarray:
        cos = np.abs(u[:, 0] * v[:, 0] + u[:, 1] * v[:, 1] + u[:, 2] * v[:, 2])
        return _round_half_up(np.arccos(np.minimum(cos, 1.0)) / (np.pi / 2) * (ESF_BINS - 1))

    th1, th2, th3 = angle_bin(u21, u31), angle_bin(u23, u31), angle_bin(u23, u21)

    # Lines in PCL's order and direction: p1->p2, p1->p3, p2->p3 (the start voxel matters to the walk).
    vox = _voxel_indices(scaled)
    n = len(scaled)
    starts = np.concatenate([i1, i1, i2])
    ends = np.concatenate([i2, i3, i3])
    if n * n < len(starts):
        # Small clouds: tracing every ordered pair once is cheaper than tracing 3 * S mostly repeated lines.
        grid_i, grid_j = np.divmod(np.arange(n * n), n)
        all_in, all_count = _trace_lines(occupancy, vox[grid_i], vox[grid_j])
        pair = starts * n + ends
        in_count, count = all_in[pair], all_count[pair]
    else:
        in_count, count = _trace_lines(occupancy, vox[starts], vox[ends])

    line_cls = np.where(in_count >= count - 1, 0, np.where(in_count <= 7, 1, 2))
    d2 = np.concatenate([a, b, c])
    d2_bin = _round_half_up(d2 / d2.max() * (ESF_BINS - 1))
    mixed = line_cls == 2
    ratio_bin = _round_half_up(in_count[mixed] / count[mixed] * (ESF_BINS - 1))

    n_tri = len(triplets)
    in3, cnt3 = in_count.reshape(3, n_tri), count.reshape(3, n_tri)
    vsum, psum = in3.sum(axis=0), cnt3.sum(axis=0)
    tri_cls = np.where(vsum <= 21, 1, np.where(psum - vsum < 4, 0, 2))  # 0 in, 1 out, 2 mixed
    weight = np.where(tri_cls == 1, 0.0, np.where(tri_cls == 0, 1.0, vsum / psum))
    d3_cls = np.where(weight >= 0.999, 0, np.where(weight <= 0.001, 1, 2))
    d3_bin = _round_half_up(d3 / d3.max() * (ESF_BINS - 1))

    # th1 (at p1) weighs with the opposite line p2p3, th2 (at p3) with p1p2, th3 (at p2) with p1p3.
    a3_bins = np.concatenate([th1, th2, th3])
    a3_weights = np.concatenate([cnt3[2], cnt3[0], cnt3[1]]) / 32.0
    a3_cls = np.tile(tri_cls, 3)

    blocks = [_histogram(a3_bins[a3_cls == k], a3_weights[a3_cls == k]) for k in (0, 1, 2)]
    blocks += [_histogram(d3_bin[d3_cls == k]) for k in (0, 1, 2)]
    blocks += [_histogram(d2_bin[line_cls == k]) for k in (0, 1, 2)]
    blocks.append(_histogram(ratio_bin))
    hist = np.concatenate(blocks) * np.repeat(_WEIGHTS, ESF_BINS)
    return hist / hist.sum()


def _check_cloud(points, name: str) -> np.ndarray:
    pts = as_points(points, name, min_points=3)
    centred = pts - pts.mean(axis=0)
    if not np.any(centred):
        raise ValueError(f"{name}: all {len(pts)} points are identical; ESF needs a 2-D spread")
    sv = np.linalg.svd(centred, compute_uv=False)
    # Relative test: ESF is scale-invariant, so a tiny but well-shaped cloud is fine.
    if sv[1] <= 1e-9 * sv[0]:
        raise ValueError(f"{name}: all points are collinear; ESF needs non-degenerate triangles")
    return pts


def _make_rng(rng, seed) -> np.random.Generator:
    if rng is not None and seed is not None:
        raise ValueError("rng, seed: pass at most one of them")
    if rng is not None:
        if not isinstance(rng, np.random.Generator):
            raise ValueError(f"rng: need a numpy.random.Generator, got {type(rng).__name__}")
        return rng
    try:
        return np.random.default_rng(seed)
    except (TypeError, ValueError) as exc:
        raise ValueError(f"seed: need an int, a sequence of ints or None, got {seed!r} ({exc})") from None


def _descriptor(pts: np.ndarray, n_samples: int, rng: np.random.Generator, name: str) -> np.ndarray:
    scaled = _scale_to_grid(pts)
    occupancy = _voxelise(scaled)
    triplets = _sample_triplets(scaled, n_samples, rng, name)
    return _esf_from_triplets(scaled, occupancy, triplets)


def esf_descriptor(
    points,
    n_samples: int = 20000,
    rng: np.random.Generator | None = None,
    seed: int | Sequence[int] | None = None,
) -> np.ndarray:
    """The ESF descriptor of one point cloud (as PCL's ``ESFEstimation``, see the module docstring).

    Invariant to translation and uniform scale; rotations change it only through the axis-aligned voxel
    grid (a 90-degree rotation about a grid axis leaves it unchanged for the same triplets).

    Args:
        points: the cloud (array-like or torch tensor), at least 3 points, not all on a line.
        n_samples: number of non-degenerate random point triplets (PCL: 20000).
        rng: a ``numpy.random.Generator`` for the triplets; or
        seed: a seed for ``numpy.random.default_rng`` (an int or a sequence of ints). With neither, the
            triplets are drawn from fresh OS entropy, so the result differs from call to call.

    Returns:
        float64 histogram; ``ESF_BLOCK_SLICES[name]`` selects one of the ten 64-bin blocks of ``ESF_BLOCKS``.

    Shapes:
        points (N, 3) -> (640,), non-negative, summing to 1

    Raises:
        ValueError: naming the argument, for a bad shape, NaN/inf, fewer than 3 points, coincident or
            collinear points, a non-positive ``n_samples``, or both ``rng`` and ``seed``.
    """
    pts = _check_cloud(points, "points")
    n_samples = as_int(n_samples, "n_samples")
    return _descriptor(pts, n_samples, _make_rng(rng, seed), "points")


def esf_descriptors(clouds, n_samples: int = 20000, seed: int = 0, progress: bool = False,
                    on_cloud: Callable[[], object] | None = None) -> np.ndarray:
    """ESF descriptors of many clouds; cloud ``i`` draws from ``np.random.default_rng([seed, i])``.

    Each cloud has its own generator, so a row does not depend on the other clouds and equals
    ``esf_descriptor(clouds[i], n_samples, seed=[seed, i])``. All clouds are validated before any is computed.

    Args:
        clouds: a sequence of clouds of varying size (or an ``(n, N, 3)`` array).
        n_samples: random triplets per cloud.
        seed: non-negative int base seed.
        progress: show a tqdm progress bar.
        on_cloud: called with no argument after each cloud's descriptor (a caller's own progress count).

    Shapes:
        clouds [n x (N_i, 3)] -> (n, 640)

    Raises:
        ValueError: for an empty ``clouds``, a bad ``n_samples`` or ``seed``, or a bad cloud (naming
            ``clouds[i]``).
    """
    if isinstance(clouds, np.ndarray) and clouds.ndim == 3:
        clouds = list(clouds)
    if not isinstance(clouds, Sequence) or isinstance(clouds, (str, bytes)):
        raise ValueError(f"clouds: need a sequence of (N, 3) point clouds, got {type(clouds).__name__}")
    if len(clouds) == 0:
        raise ValueError("clouds: is empty; need at least one point cloud")
    n_samples = as_int(n_samples, "n_samples")
    seed = as_int(seed, "seed", minimum=0)
    checked = [_check_cloud(cloud, f"clouds[{i}]") for i, cloud in enumerate(clouds)]
    items = enumerate(checked)
    if progress:
        from tqdm.auto import tqdm

        items = tqdm(items, total=len(checked), desc="ESF")
    out = np.empty((len(checked), ESF_DIM))
    for i, pts in items:
        out[i] = _descriptor(pts, n_samples, np.random.default_rng([seed, i]), f"clouds[{i}]")
        if on_cloud is not None:
            on_cloud()
    return out
