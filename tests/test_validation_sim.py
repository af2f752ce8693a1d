"""Bad inputs to the simulation / dataset-generation API raise a ValueError naming the argument (fuzzer
findings), while valid calls keep working."""

import numpy as np
import pytest
import trimesh

from vtlearn.sim_data.articulated import Box, look_at_45
from vtlearn.sim_data.camera import (
    DepthNoise,
    RGBDCamera,
    backproject,
    sample_hemisphere_views,
    viewpoint_rotation,
)
from vtlearn.sim_data.cloud_touch import touch_cloud
from vtlearn.sim_data.loaders import check_mesh, scan_mesh_folder
from vtlearn.sim_data.scene import Scene
from vtlearn.sim_data.shapes import generate_shape, instance_seed, normalize_mesh, write_shapes
from vtlearn.sim_data.tactile import pad_frame, sample_pinches, sample_touches
from vtlearn.sim_data.writer import GenConfig, crop_to_box, generate_dataset

BOX = trimesh.creation.box(extents=[0.05, 0.05, 0.05])
LO, HI = np.array([-0.05, -0.05, 0.0]), np.array([0.05, 0.05, 0.1])


@pytest.fixture
def scene():
    s = Scene()
    yield s
    s.close()


def _nan_box():
    v = BOX.vertices.copy()
    v[0, 0] = np.nan
    return trimesh.Trimesh(v, BOX.faces, process=False)


def _collinear():
    v = np.array([[0, 0, 0], [1, 0, 0], [2, 0, 0], [3, 0, 0.0]]) * 0.05
    return trimesh.Trimesh(v, [[0, 1, 2], [1, 2, 3]], process=False)


# ------------------------------------------------------------------ Scene
@pytest.mark.parametrize("mesh", [_nan_box(), _collinear()], ids=["nan", "collinear"])
def test_add_mesh_rejects_degenerate_mesh(scene, mesh):
    with pytest.raises(ValueError, match="mesh"):
        scene.add_mesh(mesh)
    assert not scene.objects


def test_add_mesh_rejects_bad_pose_and_mass(scene):
    T = np.eye(4)
    T[0, 3] = np.nan
    with pytest.raises(ValueError, match="T_world_object"):
        scene.add_mesh(BOX, T_world_object=T)
    with pytest.raises(ValueError, match="T_world_object"):
        scene.add_mesh(BOX, T_world_object=np.diag([2.0, 2.0, 2.0, 1.0]))
    for m in (-1.0, 0.0, np.nan):
        with pytest.raises(ValueError, match="mass"):
            scene.add_mesh(BOX, fixed=False, mass=m)
    with pytest.raises(ValueError, match="rgba"):
        scene.add_mesh(BOX, rgba=(1, 0))
    assert not scene.objects
    assert scene.add_mesh(BOX, fixed=False, mass=0.1) in scene.objects


def test_ray_test_checks_shapes(scene):
    scene.add_mesh(BOX)
    starts = np.array([[0, 0, 0.5], [0.01, 0, 0.5]])
    ends = starts - [0, 0, 1.0]
    with pytest.raises(ValueError, match="starts/ends"):
        scene.ray_test(starts, ends[:1])
    with pytest.raises(ValueError, match="starts"):
        scene.ray_test(starts[:, :2], ends[:, :2])
    with pytest.raises(ValueError, match="ends"):
        scene.ray_test(starts, np.full((2, 3), np.nan))
    ids, frac, _, _ = scene.ray_test(starts, ends)
    assert (ids >= 0).all() and len(frac) == 2


# ------------------------------------------------------------------ loaders
def test_check_mesh_rejects_flat_and_nan_but_keeps_open(tmp_path):
    d = tmp_path / "cat"
    d.mkdir()
    flat = trimesh.Trimesh(
        [[0, 0, 0], [1, 0, 0], [0, 1, 0], [1, 1, 0.0]], [[0, 1, 2], [1, 3, 2]], process=False
    )
    flat.export(d / "flat.obj")
    _nan_box().export(d / "nan.obj")
    (d / "nan2.obj").write_text("v nan 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n")
    trimesh.Trimesh(BOX.vertices, BOX.faces[:6], process=False).export(d / "open.obj")
    assert check_mesh(d / "flat.obj")[1].startswith("flat")
    assert check_mesh(d / "nan.obj")[1] == "non-finite vertices"
    assert check_mesh(d / "nan2.obj")[0] is None
    mesh, reason = check_mesh(d / "open.obj")  # not watertight, still usable (ShapeNet meshes often are)
    assert reason is None and not mesh.is_watertight
    assert [i["file"].split("/")[-1] for i in scan_mesh_folder(tmp_path)] == ["open.obj"]
    with pytest.raises(FileNotFoundError, match="path"):
        check_mesh(d / "missing.obj")


# ------------------------------------------------------------------ shapes
def test_normalize_mesh_rejects_non_meshes():
    with pytest.raises(ValueError, match="mesh_m"):
        normalize_mesh(trimesh.Trimesh(np.zeros((3, 3)), np.zeros((0, 3), dtype=int), process=False))
    with pytest.raises(ValueError, match="mesh_m"):
        normalize_mesh(np.zeros((3, 3)))
    with pytest.raises(ValueError, match="mesh_m"):
        normalize_mesh(_collinear())
    mesh, scale = normalize_mesh(BOX)
    assert np.isclose(scale, 0.05) and np.allclose(mesh.extents, 1.0)


def test_generate_shape_and_instance_seed_name_arguments():
    with pytest.raises(ValueError, match="seed"):
        generate_shape("mug", -1, 8)
    with pytest.raises(ValueError, match="sections"):
        generate_shape("mug", 0, "abc")
    with pytest.raises(ValueError, match="category"):
        instance_seed(0, "bogus", 0)
    with pytest.raises(ValueError, match="seed"):
        instance_seed(-1, "mug", 0)
    with pytest.raises(ValueError, match="index"):
        instance_seed(0, "mug", -1)
    assert generate_shape("mug", instance_seed(0, "mug", 0), 8)[1].category == "mug"


def test_write_shapes_and_generate_dataset_reject_file_out_dir(tmp_path):
    f = tmp_path / "afile"
    f.write_text("x")
    with pytest.raises(ValueError, match="out_dir"):
        write_shapes(f, ["mug"], 1, progress=False)
    with pytest.raises(ValueError, match="out_dir"):
        generate_dataset(GenConfig(categories=["mug"], per_category=1), f, progress=False)
    with pytest.raises(ValueError, match="categories"):
        write_shapes(tmp_path / "s", [], 1, progress=False)


# ------------------------------------------------------------------ NaN -> NaN arrays
def test_nan_inputs_rejected():
    with pytest.raises(ValueError, match="roll"):
        pad_frame([0, 0, 0], [0, 0, -1], np.nan)
    with pytest.raises(ValueError, match="distance"):
        look_at_45(np.zeros(3), 0.0)
    with pytest.raises(ValueError, match="target"):
        look_at_45([np.nan, 0, 0], 1.0)
    with pytest.raises(ValueError, match="p_view"):
        viewpoint_rotation([np.nan, 0, 1], np.zeros(3))
    with pytest.raises(ValueError, match="p_view"):
        viewpoint_rotation([0, 1], np.zeros(3))
    with pytest.raises(ValueError, match="o_centroid"):
        sample_hemisphere_views([np.nan, 0, 0], 1.0, 2, np.random.default_rng(0))
    with pytest.raises(ValueError, match="radius"):
        sample_hemisphere_views(np.zeros(3), np.inf, 2, np.random.default_rng(0))
    assert np.isfinite(look_at_45(np.zeros(3), 1.0)).all()
    assert np.isfinite(sample_hemisphere_views(np.zeros(3), 1.0, 3, np.random.default_rng(0))).all()


def test_backproject_checks_K_and_T():
    depth = np.full((4, 4), 1.0)
    K = np.array([[100.0, 0, 2], [0, 100.0, 2], [0, 0, 1]])
    with pytest.raises(ValueError, match="K"):
        backproject(depth, np.zeros((3, 3)), np.eye(4))
    with pytest.raises(ValueError, match="K"):
        backproject(depth, np.full((3, 3), np.nan), np.eye(4))
    T = np.eye(4)
    T[1, 3] = np.nan
    with pytest.raises(ValueError, match="T_world_camera"):
        backproject(depth, K, T)
    assert np.isfinite(backproject(depth, K, np.eye(4))).all()


def test_sample_touches_and_pinches_check_box():
    rng = np.random.default_rng(0)
    for fn in (sample_touches, sample_pinches):
        with pytest.raises(ValueError, match="lo"):
            fn([0, 0], HI, 3, rng)
        with pytest.raises(ValueError, match="lo"):
            fn([np.nan, 0, 0], HI, 3, rng)
        with pytest.raises(ValueError, match="lo/hi"):
            fn(HI, LO, 3, rng)
    with pytest.raises(ValueError, match="lo/hi"):
        sample_touches(np.zeros(3), np.zeros(3), 3, rng)
    with pytest.raises(ValueError, match="margin"):
        sample_touches(LO, HI, 3, rng, margin=-1)
    with pytest.raises(ValueError, match="standoff"):
        sample_touches(LO, HI, 3, rng, standoff=np.nan)
    with pytest.raises(ValueError, match="clearance"):
        sample_pinches(LO, HI, 3, rng, clearance=-1)
    assert len(sample_touches(LO, HI, 3, rng)) == 3 and len(sample_pinches(LO, HI, 3, rng)) == 3


def test_crop_to_box_checks():
    pts = np.zeros((5, 3))
    with pytest.raises(ValueError, match="lo/hi"):
        crop_to_box(pts, HI, LO, 0.1)
    with pytest.raises(ValueError, match="lo"):
        crop_to_box(pts, [np.nan, 0, 0], HI, 0.1)
    with pytest.raises(ValueError, match="margin"):
        crop_to_box(pts, LO, HI, -1.0)
    with pytest.raises(ValueError, match="points"):
        crop_to_box(np.zeros((5, 2)), LO, HI, 0.1)
    assert len(crop_to_box(pts, LO, HI, 0.1)) == 5


# ------------------------------------------------------------------ GenConfig
@pytest.mark.parametrize(
    "field, value",
    [
        ("tactile_clouds", 0),
        ("dense_points", 0),
        ("visual_points", -1),
        ("touches", 0),
        ("pinches", -1),
        ("views", 0),
        ("image_width", 0),
        ("image_height", 2.5),
        ("seed", -1),
        ("keep_split", 1),
    ],
)
def test_genconfig_names_field(field, value):
    with pytest.raises(ValueError, match=field):
        GenConfig(**{field: value})


def test_genconfig_allows_zero_pinches_and_checks_sources(tmp_path):
    GenConfig(pinches=0).validate()
    with pytest.raises(FileNotFoundError, match="mesh_source"):
        GenConfig(mesh_source=str(tmp_path / "nope")).validate()
    with pytest.raises(ValueError, match="sensor"):
        GenConfig(sensor="bogus").validate()
    (tmp_path / "empty").mkdir()
    with pytest.raises(ValueError, match="mesh_source"):
        generate_dataset(GenConfig(mesh_source=str(tmp_path / "empty")), tmp_path / "out", progress=False)


def test_generate_dataset_checks_workers_and_max_shards(tmp_path):
    cfg = GenConfig(categories=["mug"], per_category=1)
    with pytest.raises(ValueError, match="workers"):
        generate_dataset(cfg, tmp_path / "a", workers=0, progress=False)
    with pytest.raises(ValueError, match="max_shards"):
        generate_dataset(cfg, tmp_path / "b", max_shards=-1, progress=False)
    assert not (tmp_path / "a").exists() and not (tmp_path / "b").exists()


# ------------------------------------------------------------------ small configs
def test_camera_noise_and_box_configs():
    with pytest.raises(ValueError, match="axial_a"):
        DepthNoise(axial_a=-1.0)
    with pytest.raises(ValueError, match="min_range"):
        DepthNoise(min_range=2.0, max_range=1.0)
    with pytest.raises(ValueError, match="width"):
        RGBDCamera(width=2.5)
    with pytest.raises(ValueError, match="half"):
        Box((-0.1, 0.1, 0.1))
    assert RGBDCamera(width=32, height=24).width == 32


def test_touch_cloud_checks_margin_and_budget():
    pts = np.random.default_rng(0).uniform(-0.05, 0.05, size=(200, 3))
    rng = np.random.default_rng(1)
    with pytest.raises(ValueError, match="max_touches"):
        touch_cloud(pts, 10, rng, 0.01, max_touches=0)
    with pytest.raises(ValueError, match="margin"):
        touch_cloud(pts, 10, rng, 0.01, margin=np.nan)
    with pytest.raises(ValueError, match="margin"):
        touch_cloud(pts, 10, rng, 0.01, margin=-1.0)


def test_pinch_names_a_non_finite_axis_angle():
    from vtlearn.sim_data.scene import Scene
    from vtlearn.sim_data.tactile import TactileSimulator

    with Scene() as scene:
        sim = TactileSimulator(scene)
        with pytest.raises(ValueError, match="axis_angle"):
            sim.pinch([0.0, 0.0, 0.05], float("nan"), 0.1)


def test_sensor_tactile_and_scene_numbers_are_checked(scene):
    from vtlearn.sim_data.sensors import TaxelSensor
    from vtlearn.sim_data.tactile import TactileConfig, TactileSimulator

    with pytest.raises(ValueError, match="rows: need an integer >= 1"):
        TaxelSensor(name="s", rows=2.5, cols=4, pitch=0.005)
    with pytest.raises(ValueError, match="pitch: need a finite number > 0"):
        TaxelSensor(name="s", rows=4, cols=4, pitch="0.005")
    with pytest.raises(ValueError, match="stiffness: need a finite number > 0"):
        TactileConfig(stiffness="stiff")
    with pytest.raises(ValueError, match="min_contacts: need an integer >= 1"):
        TactileConfig(min_contacts=0)
    with pytest.raises(ValueError, match="scale: need a finite number > 0"):
        scene.add_mesh(BOX, scale="2")
    shear = np.eye(4)
    shear[0, 1] = 0.3
    with pytest.raises(ValueError, match="T_world_camera: the 3x3 block is not a proper rotation"):
        RGBDCamera(width=32, height=24).render(scene, shear)
    sim = TactileSimulator(scene)
    with pytest.raises(ValueError, match="T_world_pad: the 3x3 block is not a proper rotation"):
        sim.touch_from(shear)


def test_scene_gravity_and_body_ids_are_checked(scene):
    with pytest.raises(ValueError, match="gravity: need a finite number"):
        Scene(gravity=float("nan"))
    with pytest.raises(ValueError, match="gravity: need a finite number"):
        Scene(gravity="down")
    with pytest.raises(ValueError, match="body_id"):
        scene.T_world_object(99)
    with pytest.raises(ValueError, match="body_id"):
        scene.remove(scene.table_id)  # the table is not an object
    body = scene.add_mesh(BOX)
    scene.remove(body)
    assert body not in scene.objects
    with pytest.raises(ValueError, match="body_id"):
        scene.remove(body)


def test_articulated_object_checks_pose_joints_and_model_points(scene):
    from vtlearn.sim_data.articulated import ArticulatedObject, make_articulated

    spec = make_articulated("drawer", 0)
    with pytest.raises(ValueError, match="n_model_points"):
        ArticulatedObject(scene, spec, n_model_points=-0.01)
    with pytest.raises(ValueError, match="n_model_points"):
        ArticulatedObject(scene, spec, n_model_points=True)
    assert scene.objects == {} and len(scene.ray_test(np.zeros((1, 3)), np.ones((1, 3)))[0]) == 1
    obj = ArticulatedObject(scene, spec, n_model_points=20)
    before = obj.part_poses()
    shear = np.eye(4)
    shear[0, 1] = 0.3
    for bad in (np.full((4, 4), np.nan), shear):
        with pytest.raises(ValueError, match="T_world_base"):
            obj.set_state(bad, np.array([0.5]))
    with pytest.raises(ValueError, match="q: "):
        obj.set_state(np.eye(4), np.array([np.nan]))
    np.testing.assert_array_equal(obj.part_poses(), before)  # nothing moved on bad input
    T = np.eye(4)
    T[:3, 3] = [0.1, 0.0, 0.0]
    obj.set_state(T, np.array([1.0]))
    np.testing.assert_allclose(obj.part_poses()[0], T, atol=1e-12)


def test_tracking_sequences_check_frames_and_probe():
    from vtlearn.sim_data.articulated import articulation_sequence, motion_sequence

    with pytest.raises(ValueError, match="n_frames"):
        articulation_sequence("drawer", 0, 0, width=16, height=12)
    with pytest.raises(ValueError, match="n_frames"):
        motion_sequence("single", 0, 0, width=16, height=12)
    with pytest.raises(ValueError, match="probe_radius"):
        motion_sequence("single", 0, 2, width=16, height=12, probe_radius=0.0)
    with pytest.raises(ValueError, match="kind: "):
        motion_sequence("several", 0, 2)


def test_bench_sim_counts_are_checked():
    from vtlearn.sim_data.bench import bench_camera, bench_shapes, bench_touches

    for fn, name in ((bench_touches, "n"), (bench_camera, "frames"), (bench_shapes, "n")):
        with pytest.raises(ValueError, match=f"{name}: need an integer >= 1"):
            fn(0)
    out = bench_shapes(2)
    assert out["shapes"] == 2 and out["categories"] == 2


def _connections() -> int:
    import pybullet as p

    return sum(p.isConnected(i) for i in range(1024))


def test_no_pybullet_connection_leaks():
    """Every pybullet client the simulation API opens is disconnected again, after errors too."""
    import gc

    from vtlearn.sim_data.articulated import articulation_sequence, motion_sequence
    from vtlearn.sim_data.tactile import TactileSimulator

    gc.collect()
    before = _connections()
    T_world_camera = sample_hemisphere_views([0, 0, 0], 0.4, 1, np.random.default_rng(0))[0]
    for _ in range(3):
        with Scene() as s:
            body = s.add_mesh(BOX, T_world_object=np.diag([1.0, 1.0, 1.0, 1.0]))
            TactileSimulator(s).touch([0.0, 0.0, 0.1], [0.0, 0.0, -1.0])
            RGBDCamera(16, 12).render(s, T_world_camera)
            s.remove(body)
        with pytest.raises(ValueError), Scene() as s:
            s.add_mesh(_nan_box())
        with pytest.raises(ValueError):
            Scene(gravity=float("nan"))
        Scene().add_mesh(BOX)  # dropped without close: garbage collection disconnects it
        articulation_sequence("drawer", 0, 1, width=16, height=12, n_model_points=10)
        motion_sequence("single", 0, 1, width=16, height=12, n_model_points=10)
    gc.collect()
    assert _connections() == before
