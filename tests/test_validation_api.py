"""Public functions given bad input raise a ValueError naming the argument (fuzzer findings)."""

import numpy as np
import pytest
import torch
import trimesh
from test_actor import TINY as TINY_ACTOR

from vtlearn.active.actions import marsaglia_sphere
from vtlearn.active.mc_dropout import select_power, select_top_k
from vtlearn.active.occupancy import OccupancyGrid
from vtlearn.active.sensors import ToFCamera
from vtlearn.geometry.metrics import scale_error
from vtlearn.geometry.sampling import knn, lengths_mask
from vtlearn.geometry.transforms import random_pose, transform_points
from vtlearn.io import read_geometry, write_cloud, write_mesh
from vtlearn.losses.mmd import multi_kernel_matrix
from vtlearn.models.actor import ACTOR, reconstruct

torch.set_num_threads(1)

CLOUD = np.random.default_rng(0).normal(size=(50, 3)) * 0.05


# ---------------------------------------------------------------- 1. ACTOR reconstruct
@pytest.fixture(scope="module")
def actor():
    return ACTOR(**TINY_ACTOR)


@pytest.mark.parametrize("model", [None, "actor.ckpt"])
def test_reconstruct_rejects_non_actor_model(model):
    with pytest.raises(ValueError, match="model: expected an ACTOR"):
        reconstruct(model, CLOUD)


def test_reconstruct_rejects_classifier_model():
    from vtlearn.models.xavtnet import XAVTNet

    net = XAVTNet(num_classes=3, global_dim=64, fc_dims=[32, 16])
    with pytest.raises(ValueError, match="model: expected an ACTOR"):
        reconstruct(net, CLOUD)


def test_reconstruct_batch_empty_clouds(actor):
    with pytest.raises(ValueError, match="points: .*empty"):
        reconstruct(actor, np.zeros((2, 0, 3)), lengths=[1, 1])


def test_reconstruct_batch_wrong_last_dim(actor):
    with pytest.raises(ValueError, match="points: expected a padded batch"):
        reconstruct(actor, np.zeros((2, 10, 2)), lengths=[10, 10])


def test_reconstruct_valid_still_works(actor):
    assert reconstruct(actor, CLOUD).shape == (64, 3)


# ---------------------------------------------------------------- 2. knn, lengths_mask
@pytest.mark.parametrize("k", [0, -1, 1.5])
def test_knn_bad_k(k):
    x = torch.rand(1, 20, 3)
    with pytest.raises(ValueError, match="k: need an integer >= 1"):
        knn(x, x, k=k)


def test_knn_k_above_points():
    x = torch.rand(1, 20, 3)
    with pytest.raises(ValueError, match="k: 21 neighbours"):
        knn(x, x, k=21)


def test_lengths_mask_bad_n_max():
    with pytest.raises(ValueError, match="n_max"):
        lengths_mask(torch.tensor([3, 2]), -1)


def test_lengths_mask_2d_lengths():
    with pytest.raises(ValueError, match="lengths: expected a 1-D tensor"):
        lengths_mask(torch.ones(2, 2, dtype=torch.long), 4)


def test_lengths_mask_valid():
    m = lengths_mask(torch.tensor([3, 0]), 4)
    assert m.tolist() == [[True, True, True, False], [False, False, False, False]]


# ---------------------------------------------------------------- 3. transform_points
def _last_row_bad():
    T = np.eye(4)
    T[3, 0] = 1.0
    return T


def _nan_T():
    T = np.eye(4)
    T[0, 3] = np.nan
    return T


@pytest.mark.parametrize(
    "T, msg",
    [
        (np.eye(3), "T_a_b: expected shape"),
        (_last_row_bad(), "T_a_b: last row"),
        (_nan_T(), "T_a_b: contains NaN"),
    ],
)
def test_transform_points_bad_transform(T, msg):
    with pytest.raises(ValueError, match=msg):
        transform_points(T, CLOUD)


def test_transform_points_bad_transform_in_batch():
    Tb = torch.eye(4, dtype=torch.float64).repeat(3, 1, 1)
    Tb[1, 3, 2] = 0.5
    with pytest.raises(ValueError, match="T_a_b: last row"):
        transform_points(Tb, torch.zeros(3, 5, 3, dtype=torch.float64))


def test_transform_points_valid_torch_batch_and_grad():
    T = torch.eye(4, dtype=torch.float32).repeat(2, 1, 1)
    T[:, :3, 3] = 1.0
    T.requires_grad_(True)
    p = torch.zeros(2, 5, 3)
    out = transform_points(T, p)
    assert torch.allclose(out, torch.ones(2, 5, 3))
    out.sum().backward()
    # tiny round-off in the last row (e.g. from an inverse) is tolerated
    T2 = np.eye(4)
    T2[3, 0] = 1e-12
    np.testing.assert_allclose(transform_points(T2, CLOUD), CLOUD)


# ---------------------------------------------------------------- 4. read_geometry
@pytest.mark.parametrize("n_points", [0, -1])
@pytest.mark.parametrize("kind", ["cloud", "mesh"])
def test_read_geometry_bad_n_points(tmp_path, kind, n_points):
    if kind == "cloud":
        path = write_cloud(tmp_path / "c.npy", CLOUD)
    else:
        path = write_mesh(tmp_path / "m.obj", trimesh.creation.box(extents=(0.1, 0.2, 0.3)))
    with pytest.raises(ValueError, match="n_points"):
        read_geometry(path, n_points=n_points)


def test_read_geometry_cloud_ignores_n_points(tmp_path):
    path = write_cloud(tmp_path / "c.npy", CLOUD)
    assert read_geometry(path, n_points=10).shape == CLOUD.shape


# ---------------------------------------------------------------- 5. AL selection
@pytest.mark.parametrize("select", [select_top_k, select_power])
def test_select_empty_scores(select):
    with pytest.raises(ValueError, match="scores: empty"):
        select(torch.zeros(0), 3)


@pytest.mark.parametrize("select", [select_top_k, select_power])
def test_select_nonfinite_scores(select):
    scores = torch.tensor([0.1, float("nan"), 0.3])
    with pytest.raises(ValueError, match="scores"):
        select(scores, 1)


def test_select_top_k_valid():
    assert select_top_k(torch.tensor([0.1, 0.5, 0.3]), 2).tolist() == [1, 2]


# ---------------------------------------------------------------- 6. pairs
def test_random_pose_short_trans_range():
    with pytest.raises(ValueError, match="trans_range"):
        random_pose(2, trans_range=(1.0,))


def test_tof_camera_short_fov():
    with pytest.raises(ValueError, match="fov_deg"):
        ToFCamera(fov_deg=(75.0,))


# ---------------------------------------------------------------- 7. MK-MMD kernel matrix
def test_multi_kernel_matrix_dim_mismatch():
    with pytest.raises(ValueError, match="y: feature dimension"):
        multi_kernel_matrix(torch.rand(8, 5), torch.rand(6, 4), torch.ones(3))


def test_multi_kernel_matrix_empty_bandwidths():
    with pytest.raises(ValueError, match="bandwidths"):
        multi_kernel_matrix(torch.rand(8, 5), torch.rand(6, 5), torch.ones(0))


def test_multi_kernel_matrix_not_2d():
    with pytest.raises(ValueError, match="x, y"):
        multi_kernel_matrix(torch.rand(8), torch.rand(6, 5), torch.ones(2))


# ---------------------------------------------------------------- 8. scales, sphere sampling
@pytest.mark.parametrize("arg", ["s_est", "s_gt"])
@pytest.mark.parametrize("bad", [np.zeros(3), -np.ones(3)])
def test_scale_error_nonpositive(arg, bad):
    kw = dict(s_est=np.ones(3), s_gt=np.ones(3))
    kw[arg] = bad
    with pytest.raises(ValueError, match=arg):
        scale_error(**kw)


@pytest.mark.parametrize("n", [0, -1])
def test_marsaglia_sphere_bad_n(n):
    with pytest.raises(ValueError, match="n: need an integer >= 1"):
        marsaglia_sphere(n, np.random.default_rng(0))


# ---------------------------------------------------------------- 9. occupancy rays
@pytest.mark.parametrize("ranges", [-1.0, float("nan"), float("inf")])
def test_insert_rays_bad_ranges(ranges):
    grid = OccupancyGrid.from_bounds([-0.2] * 3, [0.2] * 3, cells_per_axis=8)
    o = np.zeros((4, 3))
    d = np.tile([1.0, 0.0, 0.0], (4, 1))
    with pytest.raises(ValueError, match="ranges: must be finite"):
        grid.insert_rays(o, d, ranges, np.ones(4, dtype=bool))


def test_sensor_frame_takes_a_horizontal_direction_of_two_or_three_components():
    from vtlearn.runtime.pushing import sensor_frame

    T2, T3 = sensor_frame([0.1, 0.2, 0.3], [1.0, 0.0]), sensor_frame([0.1, 0.2, 0.3], [2.0, 0.0, 5.0])
    np.testing.assert_allclose(T2, T3)  # only the horizontal part of d counts
    np.testing.assert_allclose(T2[:3, 2], [1.0, 0.0, 0.0])
    np.testing.assert_allclose(T2[:3, :3] @ T2[:3, :3].T, np.eye(3), atol=1e-12)
    for bad in ([1.0], [1.0, 0.0, 0.0, 0.0], [[1.0, 0.0, 0.0]], [0.0, 0.0, 1.0], [np.nan, 1.0]):
        with pytest.raises(ValueError, match="d: need a finite direction"):
            sensor_frame([0.0, 0.0, 0.0], bad)


def test_as_bool_takes_only_true_and_false():
    from vtlearn.validation import as_bool

    assert as_bool(True, "flag") is True and as_bool(False, "flag") is False
    for bad in (1, 0, np.bool_(True), "true", None):
        with pytest.raises(ValueError, match="flag: expected True or False"):
            as_bool(bad, "flag")


def test_as_real_and_as_vector_state_the_bound_and_refuse_strings_bools_and_nan():
    from vtlearn.validation import as_real, as_vector

    assert as_real(2, "x", low=0.0) == 2.0 and as_real(np.float32(0.5), "p", low=0.0, high=1.0) == 0.5
    for bad, kw, msg in [(0.0, dict(low=0.0, open_low=True), "x: need a finite number > 0"),
                         (1.5, dict(low=0.0, high=1.0), r"x: need a finite number in \[0, 1\]"),
                         (np.nan, {}, "x: need a finite number, got nan"),
                         ("3", {}, "x: need a finite number"), (True, {}, "x: need a finite number")]:
        with pytest.raises(ValueError, match=msg):
            as_real(bad, "x", **kw)
    np.testing.assert_array_equal(as_vector([1, 2, 3], "v", 3), [1.0, 2.0, 3.0])
    for bad in ([1, 2], [1, 2, np.inf], "abc", [[1, 2, 3]]):
        with pytest.raises(ValueError, match="v: need 3 finite numbers"):
            as_vector(bad, "v", 3)
