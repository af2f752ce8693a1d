"""Tests for vtlearn.active.sensors: taxel rays, antipodal pinch pads, ToF beams, mesh ray-casting."""

import numpy as np
import pytest
import trimesh

from vtlearn.active.sensors import PinchSensor, Rays, TactileArray, ToFCamera, cast_rays_on_mesh


def test_tactile_array_one_ray_per_taxel_along_pad_z():
    T = np.eye(4)
    T[:3, 3] = [0.1, 0.2, 0.3]
    T[:3, :3] = [[1, 0, 0], [0, 0, -1], [0, 1, 0]]  # pad z = world -y
    rays = TactileArray("xela_4x4", ray_length=0.05).rays(T)
    assert len(rays) == 16 and rays.n_actions == 1 and (rays.action_index == 0).all()
    assert np.allclose(rays.directions, [0, -1, 0])
    assert np.allclose(rays.max_range, 0.05)
    # 4 x 4 taxels at 4.7 mm pitch, centred on the pad origin, in the pad's x-y plane (world x-z)
    offs = rays.origins - [0.1, 0.2, 0.3]
    assert np.allclose(offs[:, 1], 0)
    assert np.allclose(np.unique(np.round(offs[:, 0], 6)), np.array([-1.5, -0.5, 0.5, 1.5]) * 0.0047)
    assert len(TactileArray("contactile_3x3").rays(np.stack([T, T])).origins) == 18
    assert TactileArray("xela_6x1").rays_per_action == 6 and TactileArray("xela_6x4").rays_per_action == 24


def test_pinch_pads_face_each_other_across_the_opening():
    sensor = PinchSensor("xela_4x4", opening=0.1)
    rays = sensor.rays(np.eye(4))
    assert len(rays) == 32 and rays.n_actions == 1
    a, b = rays.origins[:16], rays.origins[16:]
    assert np.allclose(a[:, 0], 0.05) and np.allclose(b[:, 0], -0.05)
    assert np.allclose(rays.directions[:16], [-1, 0, 0]) and np.allclose(rays.directions[16:], [1, 0, 0])
    assert np.allclose(np.sort(a[:, 1]), np.sort(b[:, 1])) and np.allclose(np.sort(a[:, 2]), np.sort(b[:, 2]))
    pads = sensor.pad_transforms(np.eye(4))
    assert np.allclose(np.linalg.det(pads[0, :, :3, :3]), 1)


def test_tof_camera_beams_span_fov_with_stride():
    cam = ToFCamera(width=64, height=48, fov_deg=(90.0, 60.0), stride=4, max_range=1.5)
    d = cam.pixel_directions()
    assert d.shape == (16 * 12, 3) == (cam.rays_per_action, 3)
    assert np.allclose(np.linalg.norm(d, axis=1), 1) and (d[:, 2] > 0).all()
    half_h = np.degrees(np.arctan2(np.abs(d[:, 0]), d[:, 2])).max()
    assert 40 < half_h <= 45  # close to, and inside, the 45 deg half-FOV
    coarse = ToFCamera(width=64, height=48, stride=16)
    assert coarse.rays_per_action == 4 * 3
    T = np.eye(4)
    T[:3, 3] = [0, 0, 1]
    T[:3, :3] = np.diag([1.0, -1.0, -1.0])  # looking down
    rays = cam.rays(T)
    assert (rays.directions[:, 2] < 0).all() and np.allclose(rays.origins, [0, 0, 1])


def test_concatenate_renumbers_actions():
    t = TactileArray().rays(np.stack([np.eye(4)] * 2))
    p = PinchSensor().rays(np.eye(4))
    both = Rays.concatenate([t, p])
    assert both.n_actions == 3 and len(both) == 64
    assert np.array_equal(np.bincount(both.action_index), [16, 16, 32])


def test_cast_rays_on_mesh_hits_box_surface():
    mesh = trimesh.creation.box(extents=[0.1, 0.1, 0.1])
    rays = Rays(
        np.array([[-0.2, 0, 0], [-0.2, 0.2, 0]]),
        np.array([[1.0, 0, 0], [1.0, 0, 0]]),
        np.array([0.5, 0.5]),
        np.array([0, 1]),
        2,
    )
    ranges, hit = cast_rays_on_mesh(mesh, rays)
    assert hit.tolist() == [True, False]
    assert ranges[0] == pytest.approx(0.15, abs=1e-6) and ranges[1] == 0.5


def test_bad_input_raises_value_error():
    with pytest.raises(ValueError, match="ray_length"):
        TactileArray(ray_length=0)
    with pytest.raises(ValueError, match="spec"):
        TactileArray("nonsense")
    with pytest.raises(ValueError, match="opening"):
        PinchSensor(opening=-1)
    with pytest.raises(ValueError, match="fov_deg"):
        ToFCamera(fov_deg=(190, 60))
    with pytest.raises(ValueError, match="stride"):
        ToFCamera(stride=0)
    with pytest.raises(ValueError, match="T_world_pad"):
        TactileArray().rays(np.ones((4, 4)))
    with pytest.raises(ValueError, match="T_world_camera"):
        ToFCamera().rays(np.zeros((0, 4, 4)))


def test_bad_sensor_and_mesh_input_is_named():
    with pytest.raises(ValueError, match="stride"):
        ToFCamera(width=8, height=8, stride=100)  # would give zero beams
    rays = TactileArray().rays(np.eye(4))
    flat = trimesh.Trimesh([[0, 0, 0], [1, 0, 0], [2, 0, 0]], [[0, 1, 2]], process=False)
    with pytest.raises(ValueError, match="mesh: degenerate"):
        cast_rays_on_mesh(flat, rays)
    nan_mesh = trimesh.Trimesh([[0, 0, np.nan], [1, 0, 0], [0, 1, 0]], [[0, 1, 2]], process=False)
    with pytest.raises(ValueError, match="mesh: vertices contain NaN"):
        cast_rays_on_mesh(nan_mesh, rays)
    with pytest.raises(ValueError, match="mesh: need a trimesh"):
        cast_rays_on_mesh("bunny.obj", rays)
    with pytest.raises(ValueError, match="rays: expected a Rays"):
        cast_rays_on_mesh(trimesh.creation.box(), np.zeros((3, 6)))


def test_open3d_mesh_casts_like_trimesh():
    import open3d as o3d

    box = trimesh.creation.box(extents=[0.1, 0.1, 0.1])
    o3d_box = o3d.geometry.TriangleMesh(o3d.utility.Vector3dVector(box.vertices),
                                        o3d.utility.Vector3iVector(box.faces))
    T = np.eye(4)
    T[2, 3] = 0.2
    T[:3, :3] = np.diag([1.0, -1.0, -1.0])  # pad pressing down onto the top face
    rays = TactileArray(ray_length=0.5).rays(T)
    r_tri, h_tri = cast_rays_on_mesh(box, rays)
    r_o3d, h_o3d = cast_rays_on_mesh(o3d_box, rays)
    assert h_tri.all() and (h_o3d == h_tri).all()
    np.testing.assert_allclose(r_o3d, r_tri)
    np.testing.assert_allclose(r_tri, 0.15, atol=1e-6)
