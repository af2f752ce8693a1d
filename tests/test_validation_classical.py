"""Bad input to the classical registration and segmentation functions raises a ValueError naming the argument.

Cases found by fuzzing: before the checks, ``knn=0`` crashed the process inside Open3D, and the others gave
Open3D/numpy/scipy errors that did not name the argument, or silently returned NaN or empty results.
"""

import subprocess
import sys

import numpy as np
import pytest

from vtlearn.classical.segmentation import (
    estimate_normals_and_curvature,
    region_growing,
    remove_plane,
    remove_statistical_outliers,
    segment_parts,
)
from vtlearn.classical.sparse_icp import kabsch, shrink_lp, sparse_icp
from vtlearn.classical.stiqf import best_buddy_pairs
from vtlearn.classical.tiqf import TIQF, tiqf_translation, tiqf_update

RNG = np.random.default_rng(0)
CLOUD = RNG.normal(size=(60, 3)) * 0.05


def _with(cloud: np.ndarray, value: float) -> np.ndarray:
    c = cloud.copy()
    c[3, 1] = value
    return c


BAD_CLOUDS = [
    pytest.param(CLOUD[:, :2], id="(N,2)"),
    pytest.param(CLOUD[:, 0], id="1-D"),
    pytest.param(_with(CLOUD, np.nan), id="NaN"),
    pytest.param(_with(CLOUD, np.inf), id="inf"),
]


# ---------------------------------------------------------------------------------------------- segmentation
@pytest.mark.parametrize("knn", [0, -1, 2, 2.5])
def test_estimate_normals_bad_knn(knn):
    with pytest.raises(ValueError, match="knn"):
        estimate_normals_and_curvature(CLOUD, knn=knn)


@pytest.mark.parametrize("knn", [0, -1])
def test_region_growing_bad_knn(knn):
    with pytest.raises(ValueError, match="knn"):
        region_growing(CLOUD, knn=knn)


def test_segment_parts_bad_knn():
    with pytest.raises(ValueError, match="knn"):
        segment_parts(CLOUD, knn=0)


def test_knn_zero_does_not_crash_the_process():
    code = (
        "import numpy as np\n"
        "from vtlearn.classical.segmentation import estimate_normals_and_curvature, region_growing\n"
        "p = np.random.default_rng(0).normal(size=(50, 3))\n"
        "for f in (estimate_normals_and_curvature, region_growing):\n"
        "    try:\n"
        "        f(p, knn=0)\n"
        "    except ValueError as e:\n"
        "        assert 'knn' in str(e)\n"
        "    else:\n"
        "        raise SystemExit(2)\n"
    )
    res = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert res.returncode == 0, res.stderr


@pytest.mark.parametrize("points", [*BAD_CLOUDS, pytest.param(np.zeros((0, 3)), id="empty")])
def test_estimate_normals_bad_points(points):
    with pytest.raises(ValueError, match="points"):
        estimate_normals_and_curvature(points)


def test_estimate_normals_valid_call():
    n, c = estimate_normals_and_curvature(CLOUD, knn=3)
    assert n.shape == (60, 3) and c.shape == (60,) and np.isfinite(n).all() and np.isfinite(c).all()


@pytest.mark.parametrize("std_ratio", [0.0, -1.0, np.nan, np.inf])
def test_remove_statistical_outliers_bad_std_ratio(std_ratio):
    with pytest.raises(ValueError, match="std_ratio"):
        remove_statistical_outliers(CLOUD, std_ratio=std_ratio)


@pytest.mark.parametrize("nb_neighbors", [0, -1, 2.5])
def test_remove_statistical_outliers_bad_nb_neighbors(nb_neighbors):
    with pytest.raises(ValueError, match="nb_neighbors"):
        remove_statistical_outliers(CLOUD, nb_neighbors=nb_neighbors)


@pytest.mark.parametrize("size", [0, -1])
def test_region_growing_bad_min_region_size(size):
    with pytest.raises(ValueError, match="min_region_size"):
        region_growing(CLOUD, min_region_size=size)


@pytest.mark.parametrize("angle", [np.nan, 0.0, -1.0, 4.0])
def test_region_growing_bad_angle_threshold(angle):
    with pytest.raises(ValueError, match="angle_threshold"):
        region_growing(CLOUD, angle_threshold=angle)


@pytest.mark.parametrize("name", ["colour_threshold", "curvature_threshold", "merge_colour_threshold"])
def test_region_growing_bad_thresholds(name):
    with pytest.raises(ValueError, match=name):
        region_growing(CLOUD, **{name: np.nan})


@pytest.mark.parametrize("fraction", [np.nan, -1.0, 2.0])
def test_segment_parts_bad_min_region_fraction(fraction):
    with pytest.raises(ValueError, match="min_region_fraction"):
        segment_parts(CLOUD, min_region_fraction=fraction)


@pytest.mark.parametrize("n", [0, -1])
def test_remove_plane_bad_num_iterations(n):
    with pytest.raises(ValueError, match="num_iterations"):
        remove_plane(CLOUD, num_iterations=n)


def test_remove_plane_bad_distance_threshold():
    with pytest.raises(ValueError, match="distance_threshold"):
        remove_plane(CLOUD, distance_threshold=np.inf)


# ------------------------------------------------------------------------------------------------ sparse ICP
@pytest.mark.parametrize("x", [*BAD_CLOUDS, pytest.param(np.zeros((0, 3)), id="empty")])
def test_kabsch_bad_x(x):
    with pytest.raises(ValueError, match="^x:"):
        kabsch(x, CLOUD)


@pytest.mark.parametrize("y", BAD_CLOUDS)
def test_kabsch_bad_y(y):
    with pytest.raises(ValueError, match="^y:"):
        kabsch(CLOUD, y)


def test_kabsch_length_mismatch():
    with pytest.raises(ValueError, match="^y:"):
        kabsch(CLOUD, CLOUD[:10])


@pytest.mark.parametrize("mu", [0.0, -1.0, np.nan, np.inf])
def test_shrink_lp_bad_mu(mu):
    with pytest.raises(ValueError, match="mu"):
        shrink_lp(CLOUD, mu, 0.5)


def test_shrink_lp_bad_h_and_p():
    with pytest.raises(ValueError, match="^h:"):
        shrink_lp(_with(CLOUD, np.nan), 1.0, 0.5)
    with pytest.raises(ValueError, match="^p:"):
        shrink_lp(CLOUD, 1.0, 0.0)
    with pytest.raises(ValueError, match="n_fixed_point"):
        shrink_lp(CLOUD, 1.0, 0.5, n_fixed_point=0)


@pytest.mark.parametrize("name", ["max_icp", "max_admm"])
@pytest.mark.parametrize("value", [0, -1])
def test_sparse_icp_bad_iteration_counts(name, value):
    with pytest.raises(ValueError, match=name):
        sparse_icp(CLOUD, CLOUD, **{name: value})


def test_sparse_icp_bad_mu():
    with pytest.raises(ValueError, match="mu"):
        sparse_icp(CLOUD, CLOUD, mu=np.inf)


# ------------------------------------------------------------------------------------------- best buddies
@pytest.mark.parametrize("model", [*BAD_CLOUDS, pytest.param(np.zeros((0, 3)), id="empty")])
def test_best_buddy_pairs_bad_model(model):
    with pytest.raises(ValueError, match="model"):
        best_buddy_pairs(CLOUD, model)


@pytest.mark.parametrize("scene", [*BAD_CLOUDS, pytest.param(np.zeros((0, 3)), id="empty")])
def test_best_buddy_pairs_bad_scene(scene):
    with pytest.raises(ValueError, match="scene_in_model"):
        best_buddy_pairs(scene, CLOUD)


def test_best_buddy_pairs_bad_normals():
    with pytest.raises(ValueError, match="model_normals"):
        best_buddy_pairs(CLOUD, CLOUD, None, CLOUD, CLOUD[:5], normal_angle_deg=30.0)


# ---------------------------------------------------------------------------------------------------- TIQF
BAD_QUATS = [
    pytest.param(np.array([1.0, 0, 0]), id="len-3"),
    pytest.param(np.array([1.0, 0, 0, 0, 0]), id="len-5"),
    pytest.param(np.zeros(4), id="zero-norm"),
    pytest.param(np.array([np.nan, 0, 0, 1.0]), id="NaN"),
]


@pytest.mark.parametrize("q", BAD_QUATS)
def test_solve_known_correspondences_bad_q_init(q):
    with pytest.raises(ValueError, match="q_init"):
        TIQF().solve_known_correspondences(CLOUD, CLOUD, q_init=q)


def test_solve_known_correspondences_normalises_q_init():
    _, q, _ = TIQF(max_iter=5).solve_known_correspondences(CLOUD, CLOUD, q_init=[2.0, 0, 0, 0])
    assert np.isfinite(q).all() and np.isclose(np.linalg.norm(q), 1.0)


def _pairs():
    s = CLOUD[:10]
    return s[1:] - s[:-1], s[1:] - s[:-1]


@pytest.mark.parametrize("x", BAD_QUATS)
def test_tiqf_update_bad_x(x):
    s_ji, o_ji = _pairs()
    with pytest.raises(ValueError, match="^x:"):
        tiqf_update(x, np.eye(4), s_ji, o_ji, 0.1)


def test_tiqf_update_bad_P_and_pairs():
    s_ji, o_ji = _pairs()
    x = np.array([1.0, 0, 0, 0])
    with pytest.raises(ValueError, match="^P:"):
        tiqf_update(x, np.full((4, 4), np.nan), s_ji, o_ji, 0.1)
    with pytest.raises(ValueError, match="s_ji"):
        tiqf_update(x, np.eye(4), _with(s_ji, np.nan), o_ji, 0.1)


@pytest.mark.parametrize("scene", [*BAD_CLOUDS, pytest.param(np.zeros((0, 3)), id="empty")])
def test_tiqf_translation_bad_scene_points(scene):
    with pytest.raises(ValueError, match="scene_points"):
        tiqf_translation(np.eye(3), scene, CLOUD)


def test_tiqf_translation_bad_R():
    with pytest.raises(ValueError, match="^R:"):
        tiqf_translation(np.eye(4), CLOUD, CLOUD)


@pytest.mark.parametrize("kwargs, name", [(dict(grid=1), "grid"), (dict(grid=0), "grid"),
                                          (dict(zeta=1.0), "zeta"), (dict(zeta=0.0), "zeta"),
                                          (dict(t_min=2.0), "t_min")])
def test_stiqf_settings_that_could_not_anneal_or_build_a_field_are_refused(kwargs, name):
    """zeta >= 1 never cools (the annealing loop would not end), and a grid of one node has no spacing."""
    from vtlearn.classical.stiqf import STIQF

    with pytest.raises(ValueError, match=name):
        STIQF(**kwargs)


@pytest.mark.parametrize("grid", [0, 1, 2.5])
def test_distance_field_bad_grid(grid):
    from vtlearn.classical.stiqf import DistanceField

    with pytest.raises(ValueError, match="grid"):
        DistanceField(CLOUD, grid=grid)
