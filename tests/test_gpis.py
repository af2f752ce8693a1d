"""GPIS baseline (thesis Sec. 8.3.2): sphere recovery, normals, input validation."""

import numpy as np
import pytest

from vtlearn.models.gpis import estimate_normals, fit_gpis, gpis_reconstruct

CENTRE = np.array([0.3, -0.1, 0.2])


def _sphere(n: int, radius: float, seed: int = 0):
    v = np.random.default_rng(seed).normal(size=(n, 3))
    normals = v / np.linalg.norm(v, axis=1, keepdims=True)
    return CENTRE + radius * normals, normals


@pytest.mark.parametrize("given_normals", [True, False])
def test_sphere_radius_within_5_percent(given_normals):
    points, normals = _sphere(60, 0.05)
    result = gpis_reconstruct(points, normals if given_normals else None, num_points=500, resolution=24)
    assert result.points.shape == (500, 3)
    radii = np.linalg.norm(result.points - CENTRE, axis=1)
    assert abs(radii.mean() - 0.05) < 0.05 * 0.05
    assert radii.std() < 0.05 * 0.05
    # the implicit function is ~0 on the data, positive outside, negative inside
    gp, d = result.gp, result.offset
    f = gp.predict(np.stack([points[0], CENTRE, CENTRE + [0.2, 0, 0]])) + d
    assert abs(f[0]) < 0.1 * d and f[1] < 0 < f[2]


def test_estimate_normals_point_outward_on_sphere():
    points, normals = _sphere(200, 0.05, seed=1)
    est = estimate_normals(points, k=8)
    assert np.all(np.einsum("ij,ij->i", est, normals) > 0.95)


def test_invalid_input():
    points, normals = _sphere(20, 0.05)
    with pytest.raises(ValueError, match="points"):
        gpis_reconstruct(np.full((10, 3), np.nan))
    with pytest.raises(ValueError, match="points"):
        gpis_reconstruct(points[:3])
    with pytest.raises(ValueError, match="normals"):
        fit_gpis(points, normals[:5])
    with pytest.raises(ValueError, match="normals"):
        fit_gpis(points, np.zeros_like(points))
    with pytest.raises(ValueError, match="resolution"):
        gpis_reconstruct(points, normals, resolution=2)
    with pytest.raises(ValueError, match="points"):
        fit_gpis(np.zeros((10, 3)), normals[:10])


def test_ball_pivot_mesh_on_sphere():
    from vtlearn.models.meshing import ball_pivot_mesh

    points, normals = _sphere(800, 0.05, seed=2)
    mesh = ball_pivot_mesh(points)
    assert len(mesh.faces) > 800
    radii = np.linalg.norm(mesh.vertices - CENTRE, axis=1)
    np.testing.assert_allclose(radii, 0.05, rtol=1e-6)
    # most of the sphere's area is covered (4 pi r^2; a random sample leaves a few holes)
    assert mesh.area > 0.8 * 4 * np.pi * 0.05**2
    with pytest.raises(ValueError, match="normals"):
        ball_pivot_mesh(points, normals[:3])
    with pytest.raises(ValueError, match="radii"):
        ball_pivot_mesh(points, radii=[-1.0])


@pytest.mark.parametrize(
    "call, name",
    [
        (lambda p, n: estimate_normals(p, k=0), "k"),
        (lambda p, n: estimate_normals(p, k=2), "k"),  # two neighbours do not span a plane
        (lambda p, n: estimate_normals(p, k=2.5), "k"),
        (lambda p, n: fit_gpis(p, n, nu=0.0), "nu"),
        (lambda p, n: fit_gpis(p, n, nu="a"), "nu"),
        (lambda p, n: fit_gpis(p, n, length_scale=-0.01), "length_scale"),
        (lambda p, n: gpis_reconstruct(p, n, margin=-1.0), "margin"),
        (lambda p, n: gpis_reconstruct(p, n, margin=float("nan")), "margin"),
    ],
)
def test_invalid_parameters_are_named(call, name):
    points, normals = _sphere(20, 0.05)
    with pytest.raises(ValueError, match=f"^{name}: "):
        call(points, normals)


@pytest.mark.parametrize(
    "kwargs, name",
    [
        ({"knn": 0}, "knn"),  # reached Open3D before, which crashed the interpreter
        ({"knn": 2}, "knn"),
        ({"knn": 1.5}, "knn"),
        ({"radii": []}, "radii"),
        ({"radius_factors": ()}, "radius_factors"),
    ],
)
def test_ball_pivot_mesh_invalid_parameters_are_named(kwargs, name):
    from vtlearn.models.meshing import ball_pivot_mesh

    points, _ = _sphere(200, 0.05, seed=3)
    with pytest.raises(ValueError, match=f"^{name}: "):
        ball_pivot_mesh(points, **kwargs)
