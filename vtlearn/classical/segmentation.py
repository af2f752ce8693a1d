"""Part segmentation of a table-top RGB-D cloud for ArtReg (thesis ch.6, section 6.2.2).

The pipeline of the thesis, step by step:

1. :func:`remove_plane` -- RANSAC plane fit (Open3D ``segment_plane``) and removal of the support
   plane's inliers.
2. :func:`remove_statistical_outliers` -- Open3D statistical outlier removal: a point goes when its mean
   distance to its k neighbours is more than ``std_ratio`` standard deviations above the cloud's mean.
3. :func:`region_growing` -- region growing on normals and colour. Open3D has none, so it is written
   here on an Open3D ``KDTreeFlann``: seeds are taken in order of increasing curvature; a neighbour
   joins the region when its normal is within ``angle_threshold`` of the current point's normal and its
   colour within ``colour_threshold`` (Euclidean distance of RGB in [0, 1]); it becomes a new seed when
   its curvature is below ``curvature_threshold`` (as in PCL's RegionGrowingRGB).
4. Colour merging -- adjacent regions whose mean colours differ by less than ``merge_colour_threshold``
   are merged (union-find), which joins the faces of one box that normal smoothness alone separates.
   Regions smaller than ``min_region_size`` are dropped (label -1).

:func:`segment_parts` runs all four and returns the number of parts and the per-part clouds.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import open3d as o3d

from vtlearn.validation import as_int, as_points, as_real

__all__ = [
    "SegmentationResult",
    "remove_plane",
    "remove_statistical_outliers",
    "estimate_normals_and_curvature",
    "region_growing",
    "segment_parts",
]


# Open3D's PCA normal and covariance estimation falls back to a default normal and an identity covariance
# when a point has fewer than 3 neighbours, and a KNN search of 0 neighbours crashes the process.
_MIN_KNN = 3


def _colors(colors: Any, n: int, name: str = "colors") -> np.ndarray | None:
    if colors is None:
        return None
    c = np.asarray(colors, dtype=np.float64)
    if c.shape != (n, 3):
        raise ValueError(f"{name} must have shape ({n}, 3) like the points, got {c.shape}")
    if not np.all(np.isfinite(c)):
        raise ValueError(f"{name} contains NaN or inf")
    if c.max(initial=0.0) > 1.0 + 1e-9 or c.min(initial=0.0) < 0.0:
        raise ValueError(f"{name} must be RGB in [0, 1]")
    return c


def _pcd(points: np.ndarray, colors: np.ndarray | None = None) -> o3d.geometry.PointCloud:
    pcd = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(points))
    if colors is not None:
        pcd.colors = o3d.utility.Vector3dVector(colors)
    return pcd


def remove_plane(
    points: Any,
    colors: Any = None,
    *,
    distance_threshold: float = 0.005,
    num_iterations: int = 500,
    seed: int | None = 0,
) -> tuple[np.ndarray, np.ndarray | None, np.ndarray]:
    """Remove the dominant plane (the table) by RANSAC (thesis 6.2.2).

    Args:
        points: (N, 3) cloud, N >= 3.
        colors: optional (N, 3) RGB in [0, 1], filtered alongside.
        distance_threshold: inlier distance to the plane (m), finite and > 0.
        num_iterations: RANSAC iterations, an integer >= 1.
        seed: seed of Open3D's random generator (None leaves it alone).

    Returns:
        (points without the plane (M, 3), their colours (M, 3) or None, plane (4,) a, b, c, d with
        a x + b y + c z + d = 0 and unit normal).
    """
    pts = as_points(points, "points", min_points=3)
    col = _colors(colors, len(pts))
    distance_threshold = as_real(distance_threshold, "distance_threshold", low=0.0, open_low=True)
    num_iterations = as_int(num_iterations, "num_iterations", 1)
    if seed is not None:
        o3d.utility.random.seed(int(seed))
    plane, inliers = _pcd(pts).segment_plane(distance_threshold, 3, num_iterations)
    keep = np.ones(len(pts), dtype=bool)
    keep[np.asarray(inliers, dtype=np.int64)] = False
    return pts[keep], (col[keep] if col is not None else None), np.asarray(plane, dtype=np.float64)


def remove_statistical_outliers(
    points: Any, colors: Any = None, *, nb_neighbors: int = 20, std_ratio: float = 2.0
) -> tuple[np.ndarray, np.ndarray | None]:
    """Open3D statistical outlier removal. Returns the kept points and colours. (N, 3) -> (M, 3).

    Args:
        points: (N, 3) cloud, N >= 1.
        colors: optional (N, 3) RGB in [0, 1], filtered alongside.
        nb_neighbors: neighbours of the mean distance, an integer >= 1.
        std_ratio: a point goes when its mean distance exceeds the cloud's mean by more than this many
            standard deviations; finite and > 0.
    """
    pts = as_points(points, "points", min_points=1)
    col = _colors(colors, len(pts))
    nb_neighbors = as_int(nb_neighbors, "nb_neighbors", 1)
    std_ratio = as_real(std_ratio, "std_ratio", low=0.0, open_low=True)
    if len(pts) <= nb_neighbors:
        return pts, col
    _, idx = _pcd(pts).remove_statistical_outlier(nb_neighbors, std_ratio)
    idx = np.asarray(idx, dtype=np.int64)
    return pts[idx], (col[idx] if col is not None else None)


def estimate_normals_and_curvature(points: Any, knn: int = 15) -> tuple[np.ndarray, np.ndarray]:
    """Normals (Open3D, PCA of k neighbours) and surface variation curvature l0 / (l0 + l1 + l2).

    Args:
        points: (N, 3) finite cloud, N >= 1.
        knn: neighbours of each PCA, an integer >= 3 (Open3D gives a default normal below 3).

    Shapes:
        points: (N, 3) -> normals (N, 3), curvature (N,).
    """
    pts = as_points(points, "points", min_points=1)
    knn = as_int(knn, "knn", _MIN_KNN)
    return _normals_and_curvature(pts, knn)


def _normals_and_curvature(points: np.ndarray, knn: int) -> tuple[np.ndarray, np.ndarray]:
    """:func:`estimate_normals_and_curvature` without the argument checks."""
    pcd = _pcd(points)
    pcd.estimate_normals(o3d.geometry.KDTreeSearchParamKNN(knn))
    pcd.estimate_covariances(o3d.geometry.KDTreeSearchParamKNN(knn))
    cov = np.asarray(pcd.covariances)
    ev = np.linalg.eigvalsh(cov)  # ascending
    curvature = ev[:, 0] / np.maximum(ev.sum(1), 1e-18)
    return np.asarray(pcd.normals), curvature


def region_growing(
    points: Any,
    colors: Any = None,
    normals: Any = None,
    *,
    knn: int = 15,
    angle_threshold: float = np.deg2rad(12.0),
    colour_threshold: float = 0.15,
    curvature_threshold: float = 0.05,
    merge_colour_threshold: float = 0.1,
    min_region_size: int = 30,
    colour_space: str = "chromaticity",
) -> np.ndarray:
    """Region growing on normals and colour with similar-colour merging (thesis 6.2.2).

    Args:
        points: (N, 3) cloud.
        colors: optional (N, 3) RGB in [0, 1]; without colours only normals drive the growth and
            no merging is done.
        normals: optional (N, 3); estimated from ``knn`` neighbours when omitted.
        knn: neighbourhood size for normals, growth and adjacency, an integer >= 3.
        angle_threshold: max angle (rad) between neighbouring normals (sign-agnostic), finite, in (0, pi].
        colour_threshold: max RGB distance between neighbouring points, finite and >= 0.
        curvature_threshold: points flatter than this continue the growth as seeds, finite and >= 0.
        merge_colour_threshold: adjacent regions with mean colours closer than this are merged, finite and
            >= 0.
        min_region_size: regions with fewer points get label -1; an integer >= 1.
        colour_space: ``"chromaticity"`` compares ``rgb / (r + g + b)`` (times 3, so grey is
            (1, 1, 1)), which ignores the brightness changes that shading puts on the faces of one
            part; ``"rgb"`` compares raw colours.

    Shapes:
        return: (N,) int64 labels 0..L-1, -1 for points in no region; labels ordered by region size.
    """
    pts = as_points(points, "points", min_points=3)
    col = _colors(colors, len(pts))
    if colour_space not in ("chromaticity", "rgb"):
        raise ValueError(f"colour_space must be 'chromaticity' or 'rgb', got {colour_space!r}")
    knn = as_int(knn, "knn", _MIN_KNN)
    min_region_size = as_int(min_region_size, "min_region_size", 1)
    angle_threshold = as_real(angle_threshold, "angle_threshold", low=0.0, high=math.pi, open_low=True)
    colour_threshold = as_real(colour_threshold, "colour_threshold", low=0.0)
    curvature_threshold = as_real(curvature_threshold, "curvature_threshold", low=0.0)
    merge_colour_threshold = as_real(merge_colour_threshold, "merge_colour_threshold", low=0.0)
    if col is not None and colour_space == "chromaticity":
        col = 3.0 * col / np.maximum(col.sum(1, keepdims=True), 1e-3)
    n = len(pts)
    if normals is None:
        nrm, curv = _normals_and_curvature(pts, knn)
    else:
        nrm = as_points(normals, "normals")
        if nrm.shape != pts.shape:
            raise ValueError(f"normals must have shape {pts.shape}, got {nrm.shape}")
        nrm = nrm / np.maximum(np.linalg.norm(nrm, axis=1, keepdims=True), 1e-12)
        _, curv = _normals_and_curvature(pts, knn)
    k = min(knn, n)
    tree = o3d.geometry.KDTreeFlann(_pcd(pts))
    nbrs = np.empty((n, k), dtype=np.int64)
    for i in range(n):
        _, idx, _ = tree.search_knn_vector_3d(pts[i], k)
        nbrs[i] = np.asarray(idx)

    cos_thr = np.cos(angle_threshold)
    # neighbour acceptance, vectorised once: normal angle and colour distance per (point, neighbour)
    ok = np.abs(np.einsum("nd,nkd->nk", nrm, nrm[nbrs])) >= cos_thr
    if col is not None:
        ok &= np.linalg.norm(col[:, None, :] - col[nbrs], axis=2) <= colour_threshold
    labels = np.full(n, -1, dtype=np.int64)
    n_regions = 0
    for seed in np.argsort(curv, kind="stable"):
        if labels[seed] >= 0:
            continue
        labels[seed] = n_regions
        stack = [seed]
        while stack:
            p = stack.pop()
            for j, accept in zip(nbrs[p], ok[p], strict=True):
                if accept and labels[j] < 0:
                    labels[j] = n_regions
                    if curv[j] < curvature_threshold:
                        stack.append(j)
        n_regions += 1

    if col is not None and n_regions > 1:
        labels = _merge_similar_colour(labels, n_regions, nbrs, col, merge_colour_threshold)

    # drop small regions, relabel by decreasing size
    uniq, counts = np.unique(labels[labels >= 0], return_counts=True)
    order = uniq[np.argsort(-counts, kind="stable")]
    big = [u for u in order if np.sum(labels == u) >= min_region_size]
    remap = np.full(labels.max() + 2, -1, dtype=np.int64)
    for new, old in enumerate(big):
        remap[old] = new
    return remap[labels]  # labels of -1 index the last entry, which stays -1


def _merge_similar_colour(
    labels: np.ndarray, n_regions: int, nbrs: np.ndarray, col: np.ndarray, thr: float
) -> np.ndarray:
    """Union-find over adjacent regions whose mean colours differ by less than ``thr``."""
    mean = np.zeros((n_regions, 3))
    np.add.at(mean, labels, col)
    mean /= np.bincount(labels, minlength=n_regions)[:, None]
    a = np.repeat(labels, nbrs.shape[1])
    b = labels[nbrs.reshape(-1)]
    pairs = np.unique(np.stack([np.minimum(a, b), np.maximum(a, b)], 1)[a != b], axis=0)
    parent = np.arange(n_regions)

    def find(x: int) -> int:
        while parent[x] != x:
            parent[x] = parent[parent[x]]
            x = parent[x]
        return x

    for r1, r2 in pairs:
        if np.linalg.norm(mean[r1] - mean[r2]) < thr:
            x, y = find(r1), find(r2)
            if x != y:
                parent[max(x, y)] = min(x, y)
    roots = np.array([find(r) for r in range(n_regions)])
    return roots[labels]


@dataclass
class SegmentationResult:
    """Output of :func:`segment_parts`.

    Attributes:
        n_parts: number of parts found.
        parts: per-part clouds, largest first, each (N_i, 3).
        part_colors: per-part colours (N_i, 3) or None when no colours were given.
        points: the cloud after plane and outlier removal, (M, 3).
        labels: (M,) part label of each point of ``points`` (-1: in no part).
        plane: (4,) the removed plane (a, b, c, d), or None when plane removal was off.
    """

    n_parts: int
    parts: list[np.ndarray]
    part_colors: list[np.ndarray] | None
    points: np.ndarray
    labels: np.ndarray
    plane: np.ndarray | None = field(default=None)


def segment_parts(
    points: Any,
    colors: Any = None,
    *,
    remove_support_plane: bool = True,
    plane_distance_threshold: float = 0.005,
    nb_neighbors: int = 20,
    std_ratio: float = 2.0,
    seed: int | None = 0,
    min_region_fraction: float = 0.01,
    **region_growing_kwargs: Any,
) -> SegmentationResult:
    """Plane removal, outlier removal, region growing and colour merging (thesis 6.2.2).

    Regions smaller than ``min_region_fraction`` of the remaining points (at least 30) are dropped,
    unless ``min_region_size`` is passed through ``region_growing_kwargs``. ``min_region_fraction`` must lie
    in [0, 1]; ``nb_neighbors`` and ``std_ratio`` are checked as in :func:`remove_statistical_outliers`,
    ``region_growing_kwargs`` as in :func:`region_growing`.

    Shapes:
        points: (N, 3); colors: (N, 3) RGB in [0, 1] or None. See :class:`SegmentationResult`.
    """
    pts = as_points(points, "points", min_points=3)
    col = _colors(colors, len(pts))
    min_region_fraction = as_real(min_region_fraction, "min_region_fraction", low=0.0, high=1.0)
    as_int(nb_neighbors, "nb_neighbors", 1)
    as_real(std_ratio, "std_ratio", low=0.0, open_low=True)
    if "knn" in region_growing_kwargs:  # checked here too: a bad knn must not depend on the cloud
        as_int(region_growing_kwargs["knn"], "knn", _MIN_KNN)
    if "min_region_size" in region_growing_kwargs:
        as_int(region_growing_kwargs["min_region_size"], "min_region_size", 1)
    plane = None
    if remove_support_plane:
        pts, col, plane = remove_plane(pts, col, distance_threshold=plane_distance_threshold, seed=seed)
    if len(pts) < 3:
        return SegmentationResult(0, [], [] if col is not None else None, pts, np.full(len(pts), -1), plane)
    pts, col = remove_statistical_outliers(pts, col, nb_neighbors=nb_neighbors, std_ratio=std_ratio)
    region_growing_kwargs.setdefault("min_region_size", max(30, int(min_region_fraction * len(pts))))
    labels = region_growing(pts, col, **region_growing_kwargs)
    n_parts = int(labels.max() + 1) if len(labels) else 0
    parts = [pts[labels == i] for i in range(n_parts)]
    part_colors = [col[labels == i] for i in range(n_parts)] if col is not None else None
    return SegmentationResult(n_parts, parts, part_colors, pts, labels, plane)
