"""Point sampling: uniform surface sampling, voxel/random/farthest-point subsampling, batched kNN, padding.

The one batching format for variable-size clouds in vtlearn is padded ``(B, N_max, 3)`` plus ``lengths``
``(B,)`` (as in pytorch3d); ``pad_clouds`` builds it and ``knn`` honours it.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
import torch

from vtlearn.validation import as_int, as_points, as_real

__all__ = [
    "sample_surface",
    "voxel_downsample",
    "random_subsample",
    "farthest_point_sample",
    "knn",
    "pad_clouds",
    "lengths_mask",
]


def sample_surface(
    mesh, n: int, seed: int | np.random.Generator | None = None
) -> tuple[np.ndarray, np.ndarray]:
    """Area-uniform random points on a triangle mesh, with the face normal of each point.

    Args:
        mesh: a ``trimesh.Trimesh`` with at least one non-degenerate face.
        n: number of points.
        seed: int seed or ``numpy.random.Generator``.

    Shapes:
        output: points ``(n, 3)``, normals ``(n, 3)`` (float64, unit length).
    """
    n = as_int(n, "n")
    faces = getattr(mesh, "faces", None)
    if faces is None or len(faces) == 0:
        raise ValueError("mesh: has no faces")
    rng = seed if isinstance(seed, np.random.Generator) else np.random.default_rng(seed)
    tri = np.asarray(mesh.vertices, dtype=np.float64)[np.asarray(faces)]  # F x 3 x 3
    cross = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    area2 = np.linalg.norm(cross, axis=1)
    total = area2.sum()
    if not np.isfinite(total) or total <= 0:
        raise ValueError("mesh: is degenerate (zero total surface area)")
    face = rng.choice(len(tri), size=n, p=area2 / total)
    u, v = rng.random((2, n))
    flip = u + v > 1
    u[flip], v[flip] = 1 - u[flip], 1 - v[flip]
    t = tri[face]
    pts = t[:, 0] + u[:, None] * (t[:, 1] - t[:, 0]) + v[:, None] * (t[:, 2] - t[:, 0])
    normals = cross[face] / np.maximum(area2[face], 1e-300)[:, None]
    return pts, normals


def voxel_downsample(points, voxel_size: float) -> np.ndarray:
    """Voxel-grid subsampling: the centroid of the points in each occupied voxel (deterministic).

    Shapes:
        points: ``(N, 3)`` -> ``(M, 3)``, ``M <= N``.
    """
    pts = as_points(points, "points")
    voxel_size = as_real(voxel_size, "voxel_size", low=0.0, open_low=True)
    keys = np.floor((pts - pts.min(0)) / voxel_size).astype(np.int64)
    _, inverse, counts = np.unique(keys, axis=0, return_inverse=True, return_counts=True)
    inverse = inverse.reshape(-1)
    sums = np.zeros((len(counts), 3))
    np.add.at(sums, inverse, pts)
    return sums / counts[:, None]


def random_subsample(points, n: int, seed: int | np.random.Generator | None = None) -> np.ndarray:
    """``n`` points drawn without replacement (with replacement only if the cloud has fewer than ``n``).

    Shapes:
        points: ``(N, 3)`` -> ``(n, 3)``.
    """
    pts = as_points(points, "points")
    n = as_int(n, "n")
    rng = seed if isinstance(seed, np.random.Generator) else np.random.default_rng(seed)
    idx = rng.choice(len(pts), size=n, replace=len(pts) < n)
    return pts[idx]


def farthest_point_sample(points, n: int) -> np.ndarray:
    """Farthest-point sampling through Open3D (``PointCloud.farthest_point_down_sample``).

    Shapes:
        points: ``(N, 3)`` -> ``(min(n, N), 3)``.
    """
    import open3d as o3d

    pts = as_points(points, "points")
    n = as_int(n, "n")
    if n >= len(pts):
        return pts.copy()
    pcd = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(pts))
    return np.asarray(pcd.farthest_point_down_sample(int(n)).points)


def lengths_mask(lengths: torch.Tensor, n_max: int) -> torch.Tensor:
    """Boolean validity mask from ``lengths``. Shapes: ``(B,)`` -> ``(B, n_max)``.

    Args:
        lengths: 1-D tensor of per-cloud lengths.
        n_max: the padded cloud size, ``>= 0``.
    """
    if not isinstance(lengths, torch.Tensor) or lengths.dim() != 1:
        got = tuple(lengths.shape) if isinstance(lengths, torch.Tensor) else type(lengths).__name__
        raise ValueError(f"lengths: expected a 1-D tensor of shape (B,), got {got}")
    n_max = as_int(n_max, "n_max", minimum=0)
    return torch.arange(n_max, device=lengths.device)[None, :] < lengths[:, None]


def pad_clouds(clouds: Sequence, dtype: torch.dtype = torch.float32) -> tuple[torch.Tensor, torch.Tensor]:
    """Pad a list of clouds of different sizes with zeros.

    Shapes:
        clouds: list of ``(N_i, 3)`` -> points ``(B, max N_i, 3)``, lengths ``(B,)`` int64.
    """
    if len(clouds) == 0:
        raise ValueError("clouds: empty list")
    tensors = []
    for i, c in enumerate(clouds):
        arr = as_points(c, f"clouds[{i}]")
        tensors.append(torch.as_tensor(arr, dtype=dtype))
    lengths = torch.tensor([len(t) for t in tensors], dtype=torch.int64)
    out = torch.zeros(len(tensors), int(lengths.max()), 3, dtype=dtype)
    for i, t in enumerate(tensors):
        out[i, : len(t)] = t
    return out, lengths


def knn(
    x: torch.Tensor,
    y: torch.Tensor,
    k: int = 1,
    x_lengths: torch.Tensor | None = None,
    y_lengths: torch.Tensor | None = None,
) -> tuple[torch.Tensor, torch.Tensor]:
    """Batched k nearest neighbours of every ``x`` point among the ``y`` points (``torch.cdist`` + ``topk``).

    Padded ``y`` points (index >= ``y_lengths``) are never returned as neighbours. Rows of padded ``x`` points
    are computed but meaningless; mask them with ``x_lengths``. Distances are Euclidean (not squared) and
    differentiable.

    Args:
        k: number of neighbours, ``1 <= k <=`` the smallest ``y`` cloud length.

    Shapes:
        x: ``(B, N, 3)``, y: ``(B, M, 3)``, lengths ``(B,)`` -> dists ``(B, N, k)``, idx ``(B, N, k)`` int64.
    """
    if x.dim() != 3 or y.dim() != 3 or x.shape[-1] != y.shape[-1] or x.shape[0] != y.shape[0]:
        raise ValueError(f"x, y: expected (B, N, D) and (B, M, D), got {tuple(x.shape)} and {tuple(y.shape)}")
    k = as_int(k, "k")
    m = y.shape[1]
    if y_lengths is None:
        y_lengths = torch.full((y.shape[0],), m, dtype=torch.int64, device=y.device)
    if int(y_lengths.min()) < k:
        raise ValueError(
            f"k: {k} neighbours requested but a cloud in y has only {int(y_lengths.min())} points"
        )
    d = torch.cdist(x, y)  # B x N x M
    invalid = ~lengths_mask(y_lengths, m)  # B x M
    d = d.masked_fill(invalid[:, None, :], float("inf"))
    dists, idx = d.topk(k, dim=-1, largest=False)
    if x_lengths is not None:
        xmask = lengths_mask(x_lengths, x.shape[1])[..., None]
        dists = dists.masked_fill(~xmask, 0.0)
    return dists, idx
