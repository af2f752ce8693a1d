"""Surface meshing of ACTOR's dense reconstruction by ball pivoting (thesis ch.8, Sec. 8.2.2).

"For surface reconstruction from the dense reconstructed point cloud, the ball-pivoting algorithm
(Bernardini et al., 1999) was used." Open3D's implementation is used. Normals are estimated from the
cloud (k nearest neighbours) and oriented away from the centroid unless given; the ball radii are
multiples of the mean nearest-neighbour spacing.

Shapes:
    points (N, 3), normals (N, 3) or None -> trimesh.Trimesh
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
import open3d as o3d
import trimesh
from scipy.spatial import cKDTree

from vtlearn.validation import as_int, as_points, as_real

__all__ = ["ball_pivot_mesh"]


def ball_pivot_mesh(
    points, normals=None, radii: Sequence[float] | None = None, radius_factors=(1.0, 2.0, 4.0), knn: int = 12
) -> trimesh.Trimesh:
    """Triangle mesh through the points by ball pivoting.

    Args:
        points: dense cloud (ACTOR output).
        normals: outward normals; estimated (k nearest neighbours, oriented outward) when None.
        radii: explicit ball radii in input units; default ``radius_factors`` times the mean spacing.
        radius_factors: multiples of the mean nearest-neighbour distance used when ``radii`` is None.
        knn: neighbours for normal estimation (>= 3, the fewest that span a plane).

    Raises:
        ValueError: bad input, or when no triangle could be built.

    Shapes:
        points (N, 3) with N >= 4 -> mesh with vertices (N', 3), faces (F, 3).
    """
    pts = as_points(points, "points", min_points=4)
    knn = as_int(knn, "knn", minimum=3)  # Open3D's normal estimation crashes the interpreter on knn = 0
    pcd = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(pts))
    if normals is None:
        pcd.estimate_normals(o3d.geometry.KDTreeSearchParamKNN(knn))
        nrm = np.asarray(pcd.normals)
        flip = np.einsum("ij,ij->i", nrm, pts - pts.mean(axis=0)) < 0
        nrm[flip] *= -1
        pcd.normals = o3d.utility.Vector3dVector(nrm)
    else:
        nrm = as_points(normals, "normals")
        if nrm.shape != pts.shape:
            raise ValueError(f"normals: expected shape {pts.shape}, got {nrm.shape}")
        pcd.normals = o3d.utility.Vector3dVector(nrm)
    if radii is None:
        if len(radius_factors) == 0:
            raise ValueError("radius_factors: empty; give at least one multiple of the point spacing")
        d, _ = cKDTree(pts).query(pts, k=2)
        spacing = float(np.mean(d[:, 1]))
        if spacing <= 0:
            raise ValueError("points: duplicate points only, cannot choose ball radii")
        radii = [f * spacing for f in radius_factors]
    elif len(radii) == 0:
        raise ValueError("radii: empty; give at least one ball radius (or None for the default)")
    radii = [as_real(r, "radii", low=0.0, open_low=True) for r in radii]
    mesh = o3d.geometry.TriangleMesh.create_from_point_cloud_ball_pivoting(
        pcd, o3d.utility.DoubleVector(list(radii))
    )
    faces = np.asarray(mesh.triangles)
    if len(faces) == 0:
        raise ValueError("points: ball pivoting built no triangles (try larger radii)")
    return trimesh.Trimesh(np.asarray(mesh.vertices), faces, process=True)
