"""Tactile simulator: sensor models, exact contacts with noise off, noise/dropout knobs, pinch, samplers."""

import numpy as np
import pytest
import trimesh

from vtlearn.sim_data.scene import Scene
from vtlearn.sim_data.sensors import SENSORS, get_sensor
from vtlearn.sim_data.shapes import generate_shape
from vtlearn.sim_data.tactile import (
    TactileConfig,
    TactileSimulator,
    pad_frame,
    sample_pinches,
    sample_touches,
)


def _setup(category="mug", seed=1, config=None, sensor="xela_4x4"):
    mesh, rec = generate_shape(category, seed, sections=32)
    scene = Scene()
    T = np.eye(4)
    T[2, 3] = -mesh.bounds[0, 2] * rec.scale_m
    body = scene.add_mesh(mesh, rec.scale_m, T)
    mesh_w = scene.objects[body].mesh_m.copy()
    mesh_w.apply_transform(T)
    return scene, TactileSimulator(scene, sensor, config, objects=[body]), mesh_w


def _surface_distance(mesh_w, pts):
    from scipy.spatial import cKDTree

    ref, _ = trimesh.sample.sample_surface(mesh_w, 300_000, seed=0)
    return cKDTree(ref).query(pts)[0]


def test_sensor_models():
    s = SENSORS["xela_4x4"]
    pos = s.taxel_positions()
    assert pos.shape == (16, 3) and np.allclose(pos.mean(0), 0)
    d = np.linalg.norm(pos[1] - pos[0])
    assert np.isclose(d, 0.0047)
    assert get_sensor("contactile_3x3").pitch == 0.007 and get_sensor("xela_6x1").num_taxels == 6
    assert get_sensor("2x5@3mm").num_taxels == 10
    with pytest.raises(ValueError, match="spec"):
        get_sensor("banana")


def test_flat_face_touch_exact():
    """A 4x4 pad pressed flat onto a box face: all 16 taxels touch, on the face, with its normal."""
    scene = Scene(table=False)
    body = scene.add_mesh(trimesh.creation.box(extents=[0.1, 0.1, 0.1]))
    sim = TactileSimulator(scene, "xela_4x4", objects=[body])
    res = sim.touch([0.2, 0.0, 0.0], [-1.0, 0.0, 0.0])
    assert res.num_contacts == 16
    np.testing.assert_allclose(res.points[:, 0], 0.05, atol=1e-6)
    np.testing.assert_allclose(res.normals, np.tile([1.0, 0, 0], (16, 1)), atol=1e-6)
    # the pad stops tau_f / k past first contact, so every taxel carries the threshold force
    np.testing.assert_allclose(res.forces, 1.1, rtol=1e-6)
    np.testing.assert_allclose(res.T_world_pad[0, 3], 0.05 - 1.1 / 500.0, atol=1e-6)
    assert sim.touch([0.2, 0.0, 0.0], [1.0, 0.0, 0.0]).num_contacts == 0  # moving away


def test_contacts_lie_on_surface_noise_off():
    """Acceptance: median distance of tactile points to the mesh < 1 mm with noise off."""
    scene, sim, mesh_w = _setup("mug")
    lo, hi = mesh_w.bounds
    rng = np.random.default_rng(0)
    pts = [sim.touch(*a).points for a in sample_touches(lo, hi, 60, rng)]
    pts += [sim.pinch(*a).points for a in sample_pinches(lo, hi, 10, rng)]
    pts = np.concatenate(pts)
    assert len(pts) > 50
    assert np.median(_surface_distance(mesh_w, pts)) < 1e-3


def test_noise_and_dropout_knobs():
    cfg = TactileConfig(position_noise=0.002, dropout=0.5)
    scene, sim, mesh_w = _setup("can", config=cfg)
    _, exact, _ = _setup("can")
    lo, hi = mesh_w.bounds
    acts = sample_touches(lo, hi, 40, np.random.default_rng(1))
    rng = np.random.default_rng(2)
    noisy = [sim.touch(*a, rng=rng) for a in acts]
    clean = [exact.touch(*a) for a in acts]
    n_noisy = sum(r.num_contacts for r in noisy)
    n_clean = sum(r.num_contacts for r in clean)
    assert 0.3 * n_clean < n_noisy < 0.7 * n_clean  # dropout 0.5
    d = _surface_distance(mesh_w, np.concatenate([r.points for r in noisy]))
    assert 0.5e-3 < np.median(d) < 4e-3  # 2 mm Gaussian noise, bounded


def test_min_contacts_and_config_validation():
    scene, sim, mesh_w = _setup("box", config=TactileConfig(min_contacts=17))
    lo, hi = mesh_w.bounds
    assert all(sim.touch(*a).num_contacts == 0 for a in sample_touches(lo, hi, 10, np.random.default_rng(0)))
    with pytest.raises(ValueError, match="dropout"):
        TactileConfig(dropout=1.5)
    with pytest.raises(ValueError, match="direction"):
        pad_frame([0, 0, 0], [0, 0, 0])


def test_pinch_contacts_both_fingers():
    scene = Scene()
    body = scene.add_mesh(
        trimesh.creation.box(extents=[0.06, 0.06, 0.1]),
        T_world_object=np.array([[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0.05], [0, 0, 0, 1.0]]),
    )
    sim = TactileSimulator(scene, "xela_4x4", objects=[body])
    res = sim.pinch([0, 0, 0.06], axis_angle=0.0, width=0.2)
    assert res.num_contacts == 32
    assert set(np.round(np.abs(res.points[:, 0]), 6)) == {0.03}
    # a pinch whose descent hits the object top fails
    assert sim.pinch([0, 0, 0.06], axis_angle=0.0, width=0.05).num_contacts == 0


def test_samplers_exclude_bottom_face():
    rng = np.random.default_rng(0)
    acts = sample_touches([-1, -1, 0], [1, 1, 2], 200, rng)
    dirs = np.array([d for _, d, _ in acts])
    assert not np.any(np.all(np.isclose(dirs, [0, 0, 1]), axis=1))  # never pushes up from below
    assert len(sample_touches([-1, -1, 0], [1, 1, 2], 20, rng, mode="grid")) == 20
    for c, _, w in sample_pinches([-1, -1, 0], [1, 1, 2], 10, rng):
        assert 0 <= c[2] <= 2 and w > 2 * np.sqrt(2)


def test_sampled_touches_press_each_face_from_outside():
    """Every sampled touch starts ``standoff`` outside its face and presses inward; the -x and -y faces
    are touched on the lo side (they were once placed on the hi side, so the pad started inside the box)."""
    lo, hi = np.array([-0.05, -0.04, 0.0]), np.array([0.07, 0.02, 0.06])
    c, h = (lo + hi) / 2, (hi - lo) / 2
    for mode in ("random", "grid"):
        acts = sample_touches(lo, hi, 40, np.random.default_rng(0), standoff=0.03, mode=mode)
        faces = set()
        for start, d, _ in acts:
            axis = int(np.argmax(np.abs(d)))
            faces.add((axis, float(np.sign(d[axis]))))
            # the face the pad presses lies on the side it comes from: at c - h * d along the axis
            assert np.isclose(start[axis], c[axis] - h[axis] * d[axis] - 0.03 * d[axis])
            others = [a for a in range(3) if a != axis]
            assert np.all(np.abs(start[others] - c[others]) <= h[others] + 1e-12)
        assert faces == {(0, 1.0), (0, -1.0), (1, 1.0), (1, -1.0), (2, -1.0)}


def test_sampled_touches_on_a_box_report_the_faces_they_press():
    """Contacts of the touches sampled on a box's bounding box lie on the face facing the pad."""
    scene = Scene(table=False)
    extents = np.array([0.06, 0.05, 0.04])
    body = scene.add_mesh(trimesh.creation.box(extents=extents))
    sim = TactileSimulator(scene, "xela_4x4", objects=[body])
    n = 0
    for start, d, roll in sample_touches(-extents / 2, extents / 2, 20, np.random.default_rng(0)):
        res = sim.touch(start, d, roll)
        axis = int(np.argmax(np.abs(d)))
        np.testing.assert_allclose(res.points[:, axis], -np.sign(d[axis]) * extents[axis] / 2, atol=1e-9)
        n += res.num_contacts
    assert n > 20
    scene.close()


def test_sensor_spec_errors_name_spec():
    for bad in ("4x4@1.2.3mm", "0x4@4.7mm", "4x0@4.7mm", "4x4@0mm"):
        with pytest.raises(ValueError, match="^spec: "):
            get_sensor(bad)
    assert get_sensor("3x2@.5mm").pitch == 0.0005


def test_same_seed_same_touches_with_noise_and_dropout():
    """Noise, dropout and the physical mode are reproducible from the rng given."""

    def run():
        scene = Scene()
        T = np.eye(4)
        T[2, 3] = 0.02
        free = scene.add_mesh(trimesh.creation.box(extents=[0.04] * 3), T_world_object=T, fixed=False)
        sim = TactileSimulator(scene, "xela_4x4", TactileConfig(position_noise=1e-3, dropout=0.3))
        rng = np.random.default_rng(5)
        out = [sim.touch([-0.08, 0.0, 0.02], [1.0, 0.0, 0.0], rng=rng).points]
        out.append(sim.pinch([0.0, 0.0, 0.02], 0.3, 0.1, rng=rng).points)
        out.append(scene.T_world_object(free))
        scene.close()
        return out

    a, b = run(), run()
    assert len(a[0]) > 0
    for x, y in zip(a, b, strict=True):
        np.testing.assert_array_equal(x, y)
