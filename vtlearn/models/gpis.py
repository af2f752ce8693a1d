"""Gaussian-process implicit surface (GPIS) from tactile points: the ACTOR baseline (thesis ch.8, Sec. 8.3.2).

Murali, "Visuo-tactile perception and learning for robots", Sec. 8.3.2: "Gaussian Process Implicit
Surfaces (GPIS) was used as baseline ... the Matérn kernel was used for the GP. The identical input
tactile point clouds were provided to the GPIS method as to ACTOR". The thesis used the GPML toolbox;
here the GP is scikit-learn's ``GaussianProcessRegressor`` (Dragiev et al., 2011 formulation):

* an implicit function f(x) with f = 0 on the touched points, f = +d at ``p + d n`` (outside) and
  f = -d at ``p - d n`` (inside), where n is the contact normal (the thesis takes it from the force
  direction; :func:`estimate_normals` gives a PCA estimate when none is measured);
* a constant prior mean of +d, so that space far from every touch is "outside" instead of producing
  spurious zero crossings;
* kernel ``C * Matern(nu) + White``, hyper-parameters fitted by maximum marginal likelihood;
* the zero level set of the posterior mean on a regular grid is extracted by marching cubes
  (scikit-image) and resampled area-uniformly to 2048 points, so it is scored like ACTOR.

Shapes:
    points (N, 3), normals (N, 3) -> GPISResult(points (num_points, 3), mesh trimesh.Trimesh)
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass

import numpy as np
import trimesh
from scipy.optimize import minimize
from scipy.spatial import cKDTree
from skimage.measure import marching_cubes
from sklearn.exceptions import ConvergenceWarning
from sklearn.gaussian_process import GaussianProcessRegressor
from sklearn.gaussian_process.kernels import ConstantKernel, Matern, WhiteKernel

from vtlearn.geometry.sampling import sample_surface
from vtlearn.validation import as_int, as_points, as_real

__all__ = ["GPISResult", "estimate_normals", "fit_gpis", "gpis_reconstruct"]


@dataclass
class GPISResult:
    """Dense GPIS reconstruction: resampled ``points`` (num_points, 3), the marching-cubes ``mesh``,
    the fitted ``gp`` and the ``offset`` d used for the off-surface targets."""

    points: np.ndarray
    mesh: trimesh.Trimesh
    gp: GaussianProcessRegressor
    offset: float


def estimate_normals(points, k: int = 10) -> np.ndarray:
    """Unit normals by PCA of the k nearest neighbours, oriented away from the centroid.

    Args:
        points: the cloud, at least 4 points.
        k: neighbours per point, each point included (>= 3, the fewest that span a plane; at most N are used).

    Shapes:
        points (N, 3) -> (N, 3)
    """
    pts = as_points(points, "points", min_points=4)
    k = min(as_int(k, "k", minimum=3), len(pts))
    _, idx = cKDTree(pts).query(pts, k=k)
    nbrs = pts[idx]  # N x k x 3
    centred = nbrs - nbrs.mean(axis=1, keepdims=True)
    _, _, vt = np.linalg.svd(centred, full_matrices=False)
    normals = vt[:, -1, :]
    outward = pts - pts.mean(axis=0)
    normals[np.einsum("ij,ij->i", normals, outward) < 0] *= -1
    return normals / np.linalg.norm(normals, axis=1, keepdims=True)


def _bounded_lbfgs(obj_func, initial_theta, bounds):
    """sklearn's L-BFGS-B marginal-likelihood optimiser, capped at 40 iterations (bounded bench runtime)."""
    res = minimize(
        obj_func, initial_theta, method="L-BFGS-B", jac=True, bounds=bounds, options={"maxiter": 40}
    )
    return res.x, res.fun


def fit_gpis(
    points,
    normals,
    offset: float | None = None,
    nu: float = 1.5,
    length_scale: float | None = None,
    optimize: bool = True,
) -> tuple[GaussianProcessRegressor, float]:
    """Fit the implicit-surface GP. Returns the regressor (on f - d) and the offset d.

    Args:
        points, normals: contact points and outward unit normals.
        offset: d, distance of the off-surface training points; default 5 % of the cloud's extent.
        nu: Matérn smoothness (1.5 or 2.5 are the usual choices).
        length_scale: initial Matérn length scale; default 30 % of the extent.
        optimize: fit the kernel hyper-parameters by maximum marginal likelihood.

    Shapes:
        points (N, 3), normals (N, 3).
    """
    pts = as_points(points, "points", min_points=4)
    nrm = as_points(normals, "normals")
    if nrm.shape != pts.shape:
        raise ValueError(f"normals: expected shape {pts.shape}, got {nrm.shape}")
    norm = np.linalg.norm(nrm, axis=1, keepdims=True)
    if np.any(norm < 1e-12):
        raise ValueError("normals: contains zero vectors")
    nrm = nrm / norm
    extent = float(np.max(pts.max(0) - pts.min(0)))
    if extent <= 0:
        raise ValueError("points: all points coincide")
    nu = as_real(nu, "nu", low=0.0, open_low=True)
    d = 0.05 * extent if offset is None else as_real(offset, "offset", low=0.0, open_low=True)
    ls = (0.3 * extent if length_scale is None
          else as_real(length_scale, "length_scale", low=0.0, open_low=True))
    X = np.concatenate([pts, pts + d * nrm, pts - d * nrm])
    y = np.concatenate([np.zeros(len(pts)), np.full(len(pts), d), np.full(len(pts), -d)])
    kernel = ConstantKernel(d**2, (1e-4 * d**2, 1e4 * d**2)) * Matern(
        length_scale=ls, length_scale_bounds=(0.02 * extent, 5 * extent), nu=nu
    ) + WhiteKernel(1e-4 * d**2, (1e-8 * d**2, 1e-1 * d**2))
    gp = GaussianProcessRegressor(
        kernel=kernel, alpha=1e-10, optimizer=_bounded_lbfgs if optimize else None, normalize_y=False
    )
    with warnings.catch_warnings():
        # hyper-parameters at their bounds (e.g. a very smooth sphere) are expected, not an error
        warnings.simplefilter("ignore", ConvergenceWarning)
        gp.fit(X, y - d)  # constant prior mean +d: far from the touches is outside
    return gp, d


def gpis_reconstruct(
    points,
    normals=None,
    num_points: int = 2048,
    resolution: int = 32,
    margin: float = 0.25,
    nu: float = 1.5,
    offset: float | None = None,
    seed: int | None = 0,
) -> GPISResult:
    """GPIS reconstruction resampled to ``num_points`` surface points (thesis Sec. 8.3.2 baseline).

    Args:
        points: tactile contact points.
        normals: outward contact normals; estimated with :func:`estimate_normals` when None.
        num_points: points resampled from the zero level set (2048 to compare with ACTOR).
        resolution: grid cells along the largest side of the evaluation box.
        margin: the box is the points' bounding box grown by this fraction of the extent per side.
        nu, offset: see :func:`fit_gpis`.
        seed: resampling seed.

    Raises:
        ValueError: bad input, or no zero level set inside the box.

    Shapes:
        points (N, 3), normals (N, 3) or None -> GPISResult.points (num_points, 3).
    """
    pts = as_points(points, "points", min_points=4)
    resolution = as_int(resolution, "resolution", minimum=4)
    num_points = as_int(num_points, "num_points")
    margin = as_real(margin, "margin", low=0.0)
    nrm = estimate_normals(pts) if normals is None else normals
    gp, d = fit_gpis(pts, nrm, offset=offset, nu=nu)
    lo, hi = pts.min(0), pts.max(0)
    extent = float(np.max(hi - lo))
    lo, hi = lo - margin * extent, hi + margin * extent
    step = float(np.max(hi - lo)) / resolution
    axes = [np.arange(lo[i], hi[i] + step, step) for i in range(3)]
    grid = np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, 3)
    values = (
        np.concatenate([gp.predict(chunk) for chunk in np.array_split(grid, max(1, len(grid) // 20000))]) + d
    )
    values = values.reshape(len(axes[0]), len(axes[1]), len(axes[2]))
    if not (values.min() < 0 < values.max()):
        raise ValueError("points: the GP implicit surface has no zero level set inside the evaluation box")
    verts, faces, _, _ = marching_cubes(values, level=0.0, spacing=(step, step, step))
    mesh = trimesh.Trimesh(verts + lo, faces, process=True)
    dense, _ = sample_surface(mesh, num_points, seed=seed)
    return GPISResult(points=dense, mesh=mesh, gp=gp, offset=d)
