import numpy as np
import pytest
import torch
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.spatial.transform import Rotation

from vtlearn.geometry import (
    farthest_point_sample,
    knn,
    make_transform,
    matrix_to_quat,
    pad_clouds,
    quat_conj,
    quat_left_matrix,
    quat_mul,
    quat_normalize,
    quat_right_matrix,
    quat_rotate,
    quat_to_matrix,
    random_pose,
    random_quaternion,
    random_subsample,
    sample_surface,
    se3_exp,
    se3_inverse,
    se3_log,
    so3_exp,
    so3_log,
    transform_points,
    voxel_downsample,
)

finite = st.floats(-3.0, 3.0, allow_nan=False)
vec6 = st.lists(finite, min_size=6, max_size=6)
seeds = st.integers(0, 2**31 - 1)


def test_quat_mul_hand_computed():
    i = np.array([0.0, 1, 0, 0])
    j = np.array([0.0, 0, 1, 0])
    k = np.array([0.0, 0, 0, 1])
    np.testing.assert_allclose(quat_mul(i, j), k)  # Hamilton: ij = k
    np.testing.assert_allclose(quat_mul(j, i), -k)
    np.testing.assert_allclose(quat_mul(i, i), [-1.0, 0, 0, 0])


def test_left_right_product_matrices_eq_a8_a9():
    q = random_quaternion(16, seed=0, numpy=True)
    p = random_quaternion(16, seed=1, numpy=True)
    np.testing.assert_allclose(quat_mul(q, p), np.einsum("nij,nj->ni", quat_left_matrix(q), p), atol=1e-12)
    np.testing.assert_allclose(quat_mul(p, q), np.einsum("nij,nj->ni", quat_right_matrix(q), p), atol=1e-12)


def test_quat_matrix_matches_scipy_and_rotate():
    q = random_quaternion(32, seed=2, numpy=True)
    R = quat_to_matrix(q)
    np.testing.assert_allclose(R, Rotation.from_quat(q[:, [1, 2, 3, 0]]).as_matrix(), atol=1e-12)
    v = np.random.default_rng(0).normal(size=(32, 3))
    np.testing.assert_allclose(quat_rotate(q, v), np.einsum("nij,nj->ni", R, v), atol=1e-12)
    np.testing.assert_allclose(quat_mul(q, quat_conj(q)), np.tile([1.0, 0, 0, 0], (32, 1)), atol=1e-12)


@settings(max_examples=60, deadline=None)
@given(seeds)
def test_quat_matrix_round_trip(seed):
    q = random_quaternion(4, seed=seed, numpy=True)
    q2 = matrix_to_quat(quat_to_matrix(q))
    # q and -q are the same rotation; matrix_to_quat returns w >= 0 as random_quaternion does
    np.testing.assert_allclose(q2, q, atol=1e-9)


def test_matrix_to_quat_near_pi_and_identity():
    for angle in (0.0, 1e-9, np.pi - 1e-9, np.pi):
        for axis in np.eye(3):
            R = Rotation.from_rotvec(axis * angle).as_matrix()
            np.testing.assert_allclose(quat_to_matrix(matrix_to_quat(R)), R, atol=1e-9)


def test_random_quaternion_uniform_statistics():
    q = random_quaternion(20000, seed=3, numpy=True)
    np.testing.assert_allclose(np.linalg.norm(q, axis=1), 1.0, atol=1e-12)
    # uniform on SO(3): rotated z-axis is uniform on the sphere -> mean ~ 0, E[z^2] = 1/3
    z = quat_rotate(q, np.tile([0.0, 0, 1], (len(q), 1)))
    assert np.abs(z.mean(0)).max() < 0.03
    assert abs((z[:, 2] ** 2).mean() - 1 / 3) < 0.02


def test_quat_normalize_rejects_zero():
    with pytest.raises(ValueError, match="zero norm"):
        quat_normalize(np.zeros(4))
    with pytest.raises(ValueError, match=r"q1: expected shape \(\.\.\., 4\)"):
        quat_mul(np.zeros(3), np.zeros(4))


@settings(max_examples=80, deadline=None)
@given(vec6)
def test_se3_exp_log_round_trip(xi):
    xi = np.array(xi)
    T = se3_exp(xi)
    np.testing.assert_allclose(se3_exp(se3_log(T)), T, atol=1e-9)
    if np.linalg.norm(xi[3:]) < np.pi - 1e-6:  # log is the inverse of exp inside the injectivity radius
        np.testing.assert_allclose(se3_log(T), xi, atol=1e-8)


@settings(max_examples=60, deadline=None)
@given(seeds)
def test_transform_inverse_is_identity(seed):
    T_a_b = random_pose(seed=seed)
    T_b_a = se3_inverse(T_a_b)
    np.testing.assert_allclose(T_a_b @ T_b_a, np.eye(4), atol=1e-9)
    np.testing.assert_allclose(T_b_a @ T_a_b, np.eye(4), atol=1e-9)


def test_so3_stable_near_zero_and_pi():
    for angle in (0.0, 1e-12, 1e-6, np.pi - 1e-7, np.pi):
        phi = np.array([0.3, -0.5, 0.81]) / np.linalg.norm([0.3, -0.5, 0.81]) * angle
        R = so3_exp(phi)
        np.testing.assert_allclose(R, Rotation.from_rotvec(phi).as_matrix(), atol=1e-9)
        back = so3_log(R)
        assert np.isfinite(back).all()
        np.testing.assert_allclose(so3_exp(back), R, atol=1e-9)
    # gradients are finite at exactly zero
    p = torch.zeros(3, dtype=torch.float64, requires_grad=True)
    so3_log(so3_exp(p)).sum().backward()
    assert torch.isfinite(p.grad).all()


def test_se3_tangent_order_is_translation_first():
    T = se3_exp(np.array([1.0, 2.0, 3.0, 0.0, 0.0, 0.0]))
    np.testing.assert_allclose(T[:3, 3], [1.0, 2.0, 3.0])
    np.testing.assert_allclose(T[:3, :3], np.eye(3))


def test_transform_points_single_and_batched():
    rng = np.random.default_rng(0)
    T = random_pose(3, seed=1)
    pts = rng.normal(size=(3, 10, 3))
    out = transform_points(T, pts)
    for b in range(3):
        ref = np.stack([T[b, :3, :3] @ p + T[b, :3, 3] for p in pts[b]])  # naive loop
        np.testing.assert_allclose(out[b], ref, atol=1e-12)
        np.testing.assert_allclose(transform_points(T[b], pts[b]), ref, atol=1e-12)
    np.testing.assert_allclose(
        transform_points(T[0], pts), np.stack([transform_points(T[0], p) for p in pts])
    )
    with pytest.raises(ValueError, match="points_b"):
        transform_points(T, pts[:2])
    with pytest.raises(ValueError, match="T_a_b"):
        transform_points(np.eye(3), pts[0])


def test_random_pose_ranges():
    T = random_pose(500, seed=0)
    assert T.shape == (500, 4, 4)
    assert T[:, :3, 3].min() >= -5 and T[:, :3, 3].max() <= 5
    np.testing.assert_allclose(
        np.einsum("nji,njk->nik", T[:, :3, :3], T[:, :3, :3]), np.tile(np.eye(3), (500, 1, 1)), atol=1e-9
    )
    with pytest.raises(ValueError, match="trans_range"):
        random_pose(trans_range=(1, 0))
    np.testing.assert_array_equal(random_pose(seed=7), random_pose(seed=7))


def test_make_transform_matches_blocks():
    R = so3_exp(np.array([0.1, 0.2, 0.3]))
    T = make_transform(R, np.array([1.0, 2.0, 3.0]))
    np.testing.assert_allclose(T[:3, :3], R)
    np.testing.assert_allclose(T[3], [0, 0, 0, 1])


def test_sample_surface_on_box_is_uniform_and_on_surface():
    import trimesh

    box = trimesh.creation.box(extents=(2.0, 1.0, 1.0))
    pts, normals = sample_surface(box, 20000, seed=0)
    # every point on a face: one coordinate at its half-extent
    on_face = np.isclose(np.abs(pts), [1.0, 0.5, 0.5], atol=1e-9).any(axis=1)
    assert on_face.all()
    # area-uniform: faces |x|=1 have area 1 each of the total 10 -> 20 % of points
    frac = np.isclose(np.abs(pts[:, 0]), 1.0).mean()
    assert abs(frac - 0.2) < 0.02
    np.testing.assert_allclose(np.linalg.norm(normals, axis=1), 1.0)
    np.testing.assert_array_equal(sample_surface(box, 5, seed=3)[0], sample_surface(box, 5, seed=3)[0])


def test_sample_surface_rejects_degenerate_mesh():
    import trimesh

    flat = trimesh.Trimesh(vertices=[[0, 0, 0], [1, 0, 0], [2, 0, 0]], faces=[[0, 1, 2]], process=False)
    with pytest.raises(ValueError, match="degenerate"):
        sample_surface(flat, 10)
    with pytest.raises(ValueError, match="no faces"):
        sample_surface(trimesh.Trimesh(), 10)


def test_subsampling():
    rng = np.random.default_rng(0)
    pts = rng.random((1000, 3))
    v = voxel_downsample(pts, 0.25)
    assert len(v) <= 64 and len(v) > 40
    # centroid of all points is preserved by count-weighted voxel centroids
    s = random_subsample(pts, 100, seed=1)
    assert s.shape == (100, 3) and len(np.unique(s, axis=0)) == 100
    f = farthest_point_sample(pts, 50)
    assert f.shape == (50, 3)
    # FPS spreads points: min pairwise distance larger than random subsampling's
    d = lambda a: np.min(np.linalg.norm(a[:, None] - a[None], axis=-1) + np.eye(len(a)) * 9)  # noqa: E731
    assert d(f) > d(random_subsample(pts, 50, seed=2))
    with pytest.raises(ValueError, match="voxel_size"):
        voxel_downsample(pts, 0)
    with pytest.raises(ValueError, match="points: point cloud is empty"):
        random_subsample(np.empty((0, 3)), 5)
    with pytest.raises(ValueError, match="NaN"):
        farthest_point_sample(np.full((5, 3), np.nan), 2)


def test_knn_matches_naive_and_respects_lengths():
    rng = np.random.default_rng(0)
    clouds_x = [rng.random((n, 3)) for n in (7, 12)]
    clouds_y = [rng.random((n, 3)) for n in (9, 4)]
    x, xl = pad_clouds(clouds_x, dtype=torch.float64)
    y, yl = pad_clouds(clouds_y, dtype=torch.float64)
    d, idx = knn(x, y, 3, xl, yl)
    for b in range(2):
        for i, p in enumerate(clouds_x[b]):
            ref = np.sort(np.linalg.norm(clouds_y[b] - p, axis=1))[:3]
            np.testing.assert_allclose(d[b, i].numpy(), ref, atol=1e-12)
            assert (idx[b, i] < yl[b]).all()
    with pytest.raises(ValueError, match="k: 5"):
        knn(x, y, 5, xl, yl)


def test_pad_clouds():
    pts, lengths = pad_clouds([np.ones((2, 3)), np.ones((5, 3))])
    assert pts.shape == (2, 5, 3) and lengths.tolist() == [2, 5]
    assert pts[0, 2:].abs().sum() == 0
    with pytest.raises(ValueError, match="clouds"):
        pad_clouds([])
    with pytest.raises(ValueError, match=r"clouds\[1\]"):
        pad_clouds([np.ones((2, 3)), np.ones((2, 2))])


@pytest.mark.parametrize("theta", [0.0, 1e-7, 1e-3, 1.0, 3.0, np.pi - 1e-6, np.pi])
def test_se3_single_numpy_path_matches_batched_torch_path(theta):
    rng = np.random.default_rng(3)
    axis = rng.normal(size=3)
    axis /= np.linalg.norm(axis)
    xi = np.concatenate([rng.normal(size=3), theta * axis])
    T = se3_exp(xi)  # (6,) numpy: the plain-numpy fast path
    T_batched = se3_exp(xi[None])[0]  # (1, 6): the torch path
    np.testing.assert_allclose(T, T_batched, atol=1e-12)
    np.testing.assert_allclose(se3_log(T), se3_log(T[None])[0], atol=1e-9)
    np.testing.assert_allclose(se3_exp(se3_log(T)), T, atol=1e-9)
    if theta < np.pi - 1e-3:
        np.testing.assert_allclose(se3_log(T), xi, atol=1e-8)


def test_canonical_box_is_the_box_centre_and_the_largest_extent():
    from vtlearn.geometry.transforms import canonical_box

    pts = np.array([[0.0, 0.0, 0.0], [0.2, 0.1, 0.0], [0.1, 0.0, 0.4]]) + [1.0, 2.0, 3.0]
    centre, scale = canonical_box(pts)
    np.testing.assert_allclose(centre, [1.1, 2.05, 3.2])
    assert scale == pytest.approx(0.4)
    assert canonical_box(pts, extent_m=0.5)[1] == 0.5
    with pytest.raises(ValueError, match="extent_m"):
        canonical_box(pts, extent_m="big")
    with pytest.raises(ValueError, match="coincide"):
        canonical_box(np.ones((4, 3)))
    with pytest.raises(ValueError, match="cloud: point cloud has only 2 points"):
        canonical_box(pts[:2], name="cloud")



def test_canonical_box_refuses_a_cloud_longer_than_twice_its_extent():
    from vtlearn.geometry.transforms import canonical_box

    pts = np.random.default_rng(0).uniform(0, 0.1, (50, 3))  # a 10 cm patch
    centre, scale = canonical_box(pts, 0.15)
    assert scale == 0.15 and np.allclose(centre, (pts.min(0) + pts.max(0)) / 2)
    with pytest.raises(ValueError, match=r"extent_m: points spans .* millimetres"):
        canonical_box(pts * 1000.0, 0.15)


def test_lists_in_give_numpy_out_and_torch_in_gives_torch_out():
    """The interop rule of vtlearn.geometry: torch in, torch out; numpy or plain lists in, numpy out."""
    from vtlearn.geometry import chamfer_distance, random_pose, transform_points

    P = np.random.default_rng(0).random((20, 3))
    T = random_pose(seed=0)
    moved = transform_points(T.tolist(), P.tolist())
    assert isinstance(moved, np.ndarray) and np.allclose(moved, P @ T[:3, :3].T + T[:3, 3])
    assert isinstance(chamfer_distance(P.tolist(), moved.tolist()), float)
    assert isinstance(transform_points(torch.as_tensor(T), P), torch.Tensor)
    from vtlearn.geometry import make_transform, quat_to_matrix

    # lists of whole numbers are float64 vectors, not float32 through an integer tensor
    assert quat_to_matrix((1, 0, 0, 0)).dtype == np.float64
    assert make_transform([[1, 0, 0], [0, 1, 0], [0, 0, 1]], [0.1, 0.2, 123456.789])[2, 3] == 123456.789
    assert isinstance(chamfer_distance(torch.as_tensor(P), P), torch.Tensor)
