"""RGB-D camera: intrinsics, back-projection accuracy, noise bound, transparency failure, eq. 5.3-5.5
views."""

import numpy as np
import pytest
import trimesh

from vtlearn.sim_data.camera import (
    DepthNoise,
    RGBDCamera,
    backproject,
    intrinsics_from_fov,
    sample_hemisphere_views,
    viewpoint_rotation,
)
from vtlearn.sim_data.scene import Scene
from vtlearn.sim_data.shapes import generate_shape


def _scene(transparent=False, category="bottle"):
    mesh, rec = generate_shape(category, 1, sections=32)
    scene = Scene()
    T = np.eye(4)
    T[2, 3] = -mesh.bounds[0, 2] * rec.scale_m
    body = scene.add_mesh(mesh, rec.scale_m, T, transparent=transparent)
    mesh_w = scene.objects[body].mesh_m.copy()
    mesh_w.apply_transform(T)
    return scene, body, mesh_w


def _dist(mesh_w, pts):
    from scipy.spatial import cKDTree

    ref, _ = trimesh.sample.sample_surface(mesh_w, 300_000, seed=0)
    return cKDTree(ref).query(pts)[0]


def test_backproject_hand_case():
    K = intrinsics_from_fov(4, 2, 90.0)  # f = 1, centre (2, 1)
    assert np.allclose(K, [[1, 0, 2], [0, 1, 1], [0, 0, 1]])
    depth = np.zeros((2, 4))
    depth[0, 3] = 2.0  # pixel centre (3.5, 0.5) -> ray (1.5, -0.5, 1)
    T = np.eye(4)
    T[:3, 3] = [1, 2, 3]
    np.testing.assert_allclose(backproject(depth, K, T), [[1 + 3.0, 2 - 1.0, 3 + 2.0]])
    with pytest.raises(ValueError, match="depth"):
        backproject(np.zeros(3), K, T)


def test_viewpoint_rotation_eq_5_3_to_5_5():
    rng = np.random.default_rng(0)
    o = np.array([0.1, -0.2, 0.05])
    views = sample_hemisphere_views(o, 0.7, 20, rng)
    for T in views:
        R = T[:3, :3]
        assert np.allclose(R.T @ R, np.eye(3), atol=1e-9) and np.isclose(np.linalg.det(R), 1)
        assert np.isclose(np.linalg.norm(T[:3, 3] - o), 0.7) and T[2, 3] >= o[2]
        axis = (o - T[:3, 3]) / 0.7
        np.testing.assert_allclose(R[:, 2], axis, atol=1e-9)  # optical axis through the centroid
    np.testing.assert_allclose(viewpoint_rotation([0, 0, 1], [0, 0, 0])[:, 2], [0, 0, -1])


def test_clean_depth_backprojects_onto_surface():
    scene, body, mesh_w = _scene()
    cam = RGBDCamera(160, 120, noise=DepthNoise.off())
    T = sample_hemisphere_views(mesh_w.centroid, 0.5, 1, np.random.default_rng(3))[0]
    frame = cam.render(scene, T)
    assert (
        frame.rgb.shape == (120, 160, 3) and frame.depth.shape == (120, 160) and frame.seg.dtype == np.int32
    )
    assert (frame.seg == body).sum() > 200 and (frame.seg == scene.table_id).any()
    pts = cam.point_cloud(frame, body)
    assert np.median(_dist(mesh_w, pts)) < 1e-3


def test_kinect_noise_is_bounded():
    scene, body, mesh_w = _scene()
    cam = RGBDCamera(160, 120)
    T = sample_hemisphere_views(mesh_w.centroid, 0.6, 1, np.random.default_rng(3))[0]
    pts = cam.point_cloud(cam.render(scene, T, np.random.default_rng(0)), body, np.random.default_rng(1))
    d = _dist(mesh_w, pts)
    assert 0.3e-3 < np.median(d) < 5e-3


def test_transparent_object_loses_at_least_half_its_points():
    """Acceptance: a transparent object yields >= 50 % fewer valid camera points than opaque."""
    views = None
    counts = {}
    for transparent in (False, True):
        scene, body, mesh_w = _scene(transparent)
        views = sample_hemisphere_views(mesh_w.centroid, 0.6, 3, np.random.default_rng(5))
        cam = RGBDCamera(160, 120)
        rng = np.random.default_rng(0)
        counts[transparent] = sum(len(cam.point_cloud(cam.render(scene, V, rng), body)) for V in views)
        if transparent:  # the surviving points are wrongly deep, not on the glass
            pts = cam.point_cloud(cam.render(scene, views[0], rng), body)
            assert np.median(_dist(mesh_w, pts)) > 0.01
    assert counts[True] <= 0.5 * counts[False]
    assert counts[False] > 500


def test_analytic_table_matches_tinyrenderer():
    """The table top drawn by ray-plane intersection equals TinyRenderer's own drawing of the table."""
    import pybullet as p

    scene, body, mesh_w = _scene()
    cam = RGBDCamera(160, 120, noise=DepthNoise.off())
    for T in sample_hemisphere_views(mesh_w.centroid, 0.6, 3, np.random.default_rng(7)):
        fast = cam.render(scene, T)
        p.changeVisualShape(scene.table_id, -1, rgbaColor=[0.5, 0.5, 0.5, 1], physicsClientId=scene.client)
        _, _, _, zbuf, seg = p.getCameraImage(
            160,
            120,
            viewMatrix=np.linalg.inv(T @ np.diag([1.0, -1.0, -1.0, 1.0])).T.ravel().tolist(),
            projectionMatrix=cam._proj,
            renderer=p.ER_TINY_RENDERER,
            physicsClientId=scene.client,
        )
        p.changeVisualShape(scene.table_id, -1, rgbaColor=[0.5, 0.5, 0.5, 0], physicsClientId=scene.client)
        seg = np.asarray(seg).reshape(120, 160)
        depth = cam.far * cam.near / (cam.far - (cam.far - cam.near) * np.asarray(zbuf).reshape(120, 160))
        table = seg == scene.table_id
        assert table.sum() > 1000 and (fast.seg == scene.table_id).sum() > 1000
        assert np.mean((fast.seg == scene.table_id) == table) > 0.995
        both = table & (fast.seg == scene.table_id)
        np.testing.assert_allclose(fast.depth[both], depth[both], atol=1e-4)
        assert np.abs(cam.point_cloud(fast, scene.table_id)[:, 2]).max() < 1e-4  # on the plane z = 0


def test_camera_cloud_of_a_rotated_box_lies_on_it_in_the_world_frame():
    """point_cloud returns world-frame metres: with noise off, every pixel of a rotated, shifted box lies on
    the box's surface to 1e-5 m (exact box distance), and every table pixel on the plane z = 0."""
    half = np.array([0.05, 0.04, 0.03])
    T_world_box = trimesh.transformations.rotation_matrix(0.4, [0, 0, 1])
    T_world_box[:3, 3] = [0.02, -0.01, half[2]]
    cam = RGBDCamera(96, 72, noise=DepthNoise.off())
    with Scene() as scene:
        body = scene.add_mesh(trimesh.creation.box(extents=2 * half), T_world_object=T_world_box)
        views = sample_hemisphere_views(T_world_box[:3, 3], 0.5, 3, np.random.default_rng(1))
        for T_world_camera in views:
            frame = cam.render(scene, T_world_camera)
            pts_world = cam.point_cloud(frame, body)
            assert len(pts_world) > 100
            pts_box = (pts_world - T_world_box[:3, 3]) @ T_world_box[:3, :3]  # p_box = T_box_world p_world
            q = np.abs(pts_box) - half
            dist = np.linalg.norm(np.maximum(q, 0), axis=1) + np.minimum(q.max(axis=1), 0)
            assert np.abs(dist).max() < 1e-5
            table = cam.point_cloud(frame, scene.table_id)
            assert len(table) > 100 and np.abs(table[:, 2]).max() < 1e-5


def test_same_seed_same_noisy_frame_and_cloud():
    scene, body, mesh_w = _scene(transparent=True)
    cam = RGBDCamera(64, 48)
    T = sample_hemisphere_views(mesh_w.centroid, 0.5, 1, np.random.default_rng(3))[0]
    runs = []
    for _ in range(2):
        rng = np.random.default_rng(7)
        frame = cam.render(scene, T, rng)
        runs.append((frame.depth, cam.point_cloud(frame, rng=rng)))
    np.testing.assert_array_equal(runs[0][0], runs[1][0])
    np.testing.assert_array_equal(runs[0][1], runs[1][1])
    scene.close()
