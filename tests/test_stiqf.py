"""Tests for vtlearn.classical.stiqf (thesis ch.5, eq. 5.11-5.18, Algorithm 3)."""

import os

import numpy as np
import pytest
import trimesh
from scipy.spatial import cKDTree

from vtlearn.classical.stiqf import (
    STIQF,
    DistanceField,
    TangentPlanes,
    aabb_scale,
    annealing_field,
    best_buddy_pairs,
    simulated_annealing,
)
from vtlearn.classical.tiqf import _quat_to_matrix


def _bunny():
    import pybullet_data

    mesh = trimesh.load(os.path.join(pybullet_data.getDataPath(), "bunny.obj"), force="mesh")
    v = mesh.vertices
    mesh.vertices = (v - (v.max(0) + v.min(0)) / 2) / ((v.max(0) - v.min(0)).max() / 2)  # into [-1, 1]^3
    return mesh


def _pose(rng, trans=5.0):
    q = rng.normal(size=4)
    q /= np.linalg.norm(q)
    T = np.eye(4)
    T[:3, :3] = _quat_to_matrix(q)
    T[:3, 3] = rng.uniform(-trans, trans, 3)
    return T


def _adi(model, T_est, T_gt):
    a = model @ T_gt[:3, :3].T + T_gt[:3, 3]
    b = model @ T_est[:3, :3].T + T_est[:3, 3]
    return cKDTree(b).query(a)[0].mean()


def test_aabb_scale_eq_5_12():
    rng = np.random.default_rng(0)
    model = rng.uniform(0, 1, size=(200, 3))
    model[:2] = [[0, 0, 0], [1, 1, 1]]
    scale = np.array([0.5, 2.0, 1.5])
    np.testing.assert_allclose(aabb_scale(model * scale + 3.0, model), scale)
    # the scene box in the model axes undoes a known rotation
    R = _quat_to_matrix(np.array([np.cos(0.4), 0.0, np.sin(0.4), 0.0]))
    scene = (model * scale) @ R.T
    np.testing.assert_allclose(aabb_scale(scene, model, R), scale, atol=1e-12)
    with pytest.raises(ValueError, match="model"):
        aabb_scale(scene, np.zeros((5, 3)))


def test_best_buddy_pairs_are_mutual():
    model = np.array([[0.0, 0, 0], [1, 0, 0], [2, 0, 0], [5, 0, 0]])
    # scene points 0 and 1 both have model point 0 as nearest; only scene 0 is its best buddy
    scene = np.array([[0.1, 0, 0], [0.3, 0, 0], [2.05, 0, 0]])
    si, mi = best_buddy_pairs(scene, model)
    assert si.tolist() == [0, 2] and mi.tolist() == [0, 2]
    # normal check removes a pair whose normals disagree
    n_model = np.tile([0.0, 0, 1], (4, 1))
    n_scene = np.array([[0.0, 0, 1], [0, 0, 1], [0, 0, -1]])
    si, mi = best_buddy_pairs(scene, model, None, n_scene, n_model, normal_angle_deg=30.0)
    assert si.tolist() == [0]


def test_distance_field_exact_at_nodes_and_close_between():
    rng = np.random.default_rng(1)
    pts = rng.uniform(-1, 1, size=(300, 3))
    field = DistanceField(pts, grid=24)
    tree = cKDTree(pts)
    nodes = field.lo + field.h * np.array([[3, 5, 7], [10, 2, 0], [20, 20, 20]])
    np.testing.assert_allclose(field(nodes), tree.query(nodes)[0], atol=1e-12)
    q = rng.uniform(-1, 1, size=(500, 3))
    assert np.abs(field(q) - tree.query(q)[0]).max() < field.h  # distance is 1-Lipschitz
    far = np.array([[10.0, 0, 0]])
    assert field(far)[0] == pytest.approx(tree.query(far)[0][0], abs=2 * field.h)
    xs, ys, zs = q.T
    np.testing.assert_allclose(field.lookup(xs, ys, zs), field(q))


def test_tangent_planes_project_onto_plane():
    g = np.stack(np.meshgrid(np.arange(5.0), np.arange(5.0), indexing="ij"), -1).reshape(-1, 2)
    model = np.concatenate([g, np.zeros((25, 1))], 1)
    tp = TangentPlanes(model, cKDTree(model), k=6)
    q = np.array([[2.3, 1.8, 0.7]])
    foot = tp.project(q, np.array([2 * 5 + 2]))
    np.testing.assert_allclose(foot, [[2.3, 1.8, 0.0]], atol=1e-9)
    assert tp.distance(q, cKDTree(model))[0] == pytest.approx(0.7, abs=1e-9)


def test_tangent_planes_closest_matches_naive_loop():
    rng = np.random.default_rng(5)
    model = rng.normal(size=(200, 3))
    tree = cKDTree(model)
    tp = TangentPlanes(model, tree, cap_factor=2.0, n_patches=5)
    q = rng.normal(size=(30, 3))
    idx, foot = tp.closest(q, tree)
    for i in range(len(q)):
        _, nbr = tree.query(q[i], k=5)
        feet = [tp.project(q[i][None], np.array([j]))[0] for j in nbr]
        d = [np.linalg.norm(q[i] - f) for f in feet]
        assert idx[i] == nbr[int(np.argmin(d))]
        np.testing.assert_allclose(foot[i], feet[int(np.argmin(d))], atol=1e-12)
    np.testing.assert_allclose(tp.distance(q, tree), np.linalg.norm(q - foot, axis=1))
    # one patch: the nearest sample's patch, as before
    tp1 = TangentPlanes(model, tree, n_patches=1)
    _, nn = tree.query(q, k=1)
    np.testing.assert_allclose(tp1.closest(q, tree)[1], tp1.project(q, nn))


def test_tangent_patches_see_the_near_side_of_a_thin_wall():
    # two parallel sheets 0.3 apart, sample spacing 1: the nearest sample of a point on the lower sheet is
    # often on the upper one; with several patches the distance to the lower sheet is found
    g = np.stack(np.meshgrid(np.arange(8.0), np.arange(8.0), indexing="ij"), -1).reshape(-1, 2)
    lower = np.concatenate([g, np.zeros((64, 1))], 1)
    upper = np.concatenate([g + 0.5, np.full((64, 1), 0.3)], 1)
    model = np.concatenate([lower, upper])
    tree = cKDTree(model)
    q = np.array([[3.45, 3.45, 0.0], [3.5, 3.5, 0.0]])
    assert (tree.query(q)[1] >= 64).all()  # nearest samples on the upper sheet
    one = TangentPlanes(model, tree, k=9, n_patches=1).distance(q, tree)
    many = TangentPlanes(model, tree, k=9, n_patches=8).distance(q, tree)
    np.testing.assert_allclose(one, 0.3, atol=1e-9)
    np.testing.assert_allclose(many, 0.0, atol=1e-9)


def test_tangent_planes_reject_bad_parameters():
    model = np.random.default_rng(0).normal(size=(20, 3))
    with pytest.raises(ValueError, match="cap_factor"):
        TangentPlanes(model, cKDTree(model), cap_factor=-1.0)
    with pytest.raises(ValueError, match="n_patches"):
        TangentPlanes(model, cKDTree(model), n_patches=0)


def test_annealing_field_uses_patch_distance_near_the_cloud():
    g = np.stack(np.meshgrid(np.linspace(-1, 1, 9), np.linspace(-1, 1, 9), indexing="ij"), -1).reshape(-1, 2)
    model = np.concatenate([g, np.zeros((81, 1))], 1)
    tree = cKDTree(model)
    tp = TangentPlanes(model, tree, k=6, cap_factor=1.0, n_patches=4)
    field = annealing_field(model, tree, tp, grid=24)
    plain = annealing_field(model, tree, None, grid=24)
    q = np.array([[0.13, -0.37, 0.0], [0.6, 0.12, 0.05]])  # between samples, on or near the plane
    np.testing.assert_allclose(field(q), np.abs(q[:, 2]), atol=field.h)
    assert (plain(q) > field(q) + 0.02).all()  # the point distance sees the gaps between samples
    axes = [field.lo[k] + field.h * np.arange(field.shape[k]) for k in range(3)]
    nodes = np.stack(np.meshgrid(*axes, indexing="ij"), -1).reshape(-1, 3)
    np.testing.assert_allclose(field.values.ravel(), tp.distance(nodes, tree))
    assert (field.values <= plain.values + 1e-12).all()  # a patch contains its sample


def test_simulated_annealing_is_seedable_and_lowers_cost():
    rng = np.random.default_rng(2)
    model = rng.uniform(-1, 1, size=(256, 3)) * [1.0, 0.6, 0.3]
    T = _pose(rng)
    scene = model[:60] @ T[:3, :3].T + T[:3, 3]
    field = DistanceField(model)
    T1, c1 = simulated_annealing(model, scene, cost_fn=field.lookup, rng=5, restarts=4)
    T2, c2 = simulated_annealing(model, scene, cost_fn=field.lookup, rng=5, restarts=4)
    np.testing.assert_array_equal(T1, T2)
    assert T1.shape == (4, 4, 4) and np.all(np.diff(c1) >= 0)
    start = field((scene - scene.mean(0)) + model.mean(0)).mean()
    assert c1[0] < 0.5 * start
    with pytest.raises(ValueError, match="zeta"):
        simulated_annealing(model, scene, cost_fn=field.lookup, zeta=1.5)


def test_stiqf_noiseless_subset_exact():
    rng = np.random.default_rng(3)
    mesh = _bunny()
    model = trimesh.sample.sample_surface(mesh, 512, seed=1)[0]
    T = _pose(rng)
    scene = model[rng.choice(512, 80, replace=False)] @ T[:3, :3].T + T[:3, 3]
    res = STIQF(seed=0, tangent=False, tol_rot_deg=1e-8, tol_trans=1e-10, max_iter=200).register(model, scene)
    np.testing.assert_allclose(res.T_scene_model, T, atol=1e-6)
    np.testing.assert_allclose(res.scale, 1.0)


def test_stiqf_noisy_surface_samples_bound():
    rng = np.random.default_rng(4)
    mesh = _bunny()
    model = trimesh.sample.sample_surface(mesh, 1024, seed=2)[0]
    T = _pose(rng)
    pts = trimesh.sample.sample_surface(mesh, 80, seed=3)[0] + rng.normal(scale=0.005, size=(80, 3))
    scene = pts @ T[:3, :3].T + T[:3, 3]
    res = STIQF(seed=0).register(model, scene)
    assert _adi(model, res.T_scene_model, T) < 0.06  # 6 cm on a 2 m object (thesis Table 5.1: 3.05 cm)


def test_stiqf_recovers_scaled_rotated_model():
    rng = np.random.default_rng(5)
    mesh = _bunny()
    model = trimesh.sample.sample_surface(mesh, 512, seed=4)[0]
    scale_gt = np.array([1.3, 0.8, 1.1])
    T = _pose(rng, trans=1.0)
    dense = trimesh.sample.sample_surface(mesh, 100, seed=5)[0] * scale_gt
    scene = dense @ T[:3, :3].T + T[:3, 3]
    res = STIQF(seed=0, estimate_scale=True, chains_per_restart=2).register(model, scene)
    assert np.linalg.norm(res.scale - scale_gt) < 0.15  # eq. 5.25
    pred = (model * res.scale) @ res.T_scene_model[:3, :3].T + res.T_scene_model[:3, 3]
    true = (model * scale_gt) @ T[:3, :3].T + T[:3, 3]
    assert cKDTree(pred).query(true)[0].mean() < 0.1


def test_stiqf_same_seed_same_result():
    rng = np.random.default_rng(6)
    model = rng.uniform(-1, 1, size=(300, 3)) * [1.0, 0.5, 0.25]
    scene = model[:30] @ _pose(rng)[:3, :3].T
    a = STIQF(seed=3).register(model, scene)
    b = STIQF(seed=3).register(model, scene)
    np.testing.assert_array_equal(a.T_scene_model, b.T_scene_model)


@pytest.mark.parametrize(
    "scene, match",
    [
        (np.zeros((2, 3)), "scene"),
        (np.array([[0.0, 0, 0], [1, 1, 1], [np.nan, 0, 0]]), "scene"),
        (np.array([[0.0, 0, 0], [1, 1, 1], [2, 2, 2], [3, 3, 3]]), "scene"),  # collinear
    ],
)
def test_stiqf_rejects_bad_input(scene, match):
    with pytest.raises(ValueError, match=match):
        STIQF().register(np.random.rand(50, 3), scene)


def test_stiqf_rejects_bad_parameters():
    with pytest.raises(ValueError, match="sa_cost"):
        STIQF(sa_cost="nope")
    with pytest.raises(ValueError, match="restarts"):
        STIQF(restarts=0)
    with pytest.raises(ValueError, match="sa_field"):
        STIQF(sa_field="nope")
    with pytest.raises(ValueError, match="tangent_cap"):
        STIQF(tangent_cap=-1.0)
    with pytest.raises(ValueError, match="tangent_patches"):
        STIQF(tangent_patches=0)
    with pytest.raises(ValueError, match="tangent_k"):
        STIQF(tangent_k=2)
    assert "zeta=0.98" in repr(STIQF())
