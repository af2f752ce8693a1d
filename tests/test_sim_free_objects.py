"""Free objects moved by actions (issue 3): the physical touch and pinch versus the ray model."""

import numpy as np
import pytest
import trimesh

from vtlearn.sim_data.scene import Scene
from vtlearn.sim_data.tactile import TactileConfig, TactileSimulator

EDGE = 0.04  # box edge (m)


def _box_scene(fixed: bool, mass: float = 0.05):
    """A box resting on the table, centred at the origin, settled if free."""
    scene = Scene()
    T = np.eye(4)
    T[2, 3] = EDGE / 2
    body = scene.add_mesh(trimesh.creation.box(extents=[EDGE] * 3), T_world_object=T, fixed=fixed, mass=mass)
    scene.step(60)
    mesh_w = scene.objects[body].mesh_m.copy()
    mesh_w.apply_transform(scene.T_world_object(body))
    return scene, body, mesh_w


def _surface_distance(mesh_w, pts):
    """Exact distance to the surface of the axis-aligned box ``mesh_w`` (signed-distance formula)."""
    lo, hi = mesh_w.bounds
    q = np.abs(pts - (lo + hi) / 2) - (hi - lo) / 2
    return np.abs(np.linalg.norm(np.maximum(q, 0), axis=1) + np.minimum(q.max(axis=1), 0))


PUSH = ([-0.08, 0.0, EDGE / 2], [1.0, 0.0, 0.0])  # from the -x side, along +x, at mid height


def test_free_box_is_pushed_along_the_touch():
    scene, body, _ = _box_scene(fixed=False)
    before = scene.T_world_object(body)
    sim = TactileSimulator(scene, "xela_4x4", objects=[body])
    assert sim.physical  # auto mode: a free object gets the physical touch
    res = sim.touch(*PUSH)
    after = scene.T_world_object(body)
    moved = after[:3, 3] - before[:3, 3]
    # max_push = 5 cm past first contact: the light box slides with the pad most of that way
    assert moved[0] > 0.02, moved
    assert abs(moved[1]) < 0.005 and abs(moved[2]) < 0.002, moved
    np.testing.assert_allclose(res.T_world_objects[body], after, atol=1e-9)
    assert res.num_contacts >= 1 and np.all(res.body_ids == body)
    np.testing.assert_allclose(res.normals[:, 0], -1.0, atol=0.05)  # the pushed -x face
    # the contacts sit on the box face as it was when the pad stopped (left of the final pose)
    assert np.all(res.points[:, 0] < after[0, 3] - EDGE / 2 + 1e-3)


def test_ray_mode_never_moves_a_free_box():
    scene, body, _ = _box_scene(fixed=False)
    before = scene.T_world_object(body)
    res = TactileSimulator(scene, "xela_4x4", objects=[body], mode="ray").touch(*PUSH)
    assert res.num_contacts == 16 and res.T_world_objects == {}
    np.testing.assert_allclose(scene.T_world_object(body), before, atol=1e-12)


@pytest.mark.parametrize("mode", ["auto", "physics"])
def test_fixed_box_stays_and_contacts_lie_on_its_surface(mode):
    """The same push on a fixed box: it does not move, and the taxels report points on its face."""
    scene, body, mesh_w = _box_scene(fixed=True)
    before = scene.T_world_object(body)
    sim = TactileSimulator(scene, "xela_4x4", TactileConfig(position_noise=0.0), objects=[body], mode=mode)
    assert sim.physical == (mode == "physics")
    res = sim.touch(*PUSH)
    np.testing.assert_allclose(scene.T_world_object(body), before, atol=1e-12)
    assert res.num_contacts >= 12  # a flat pad on a flat face: (nearly) every taxel
    assert np.median(_surface_distance(mesh_w, res.points)) < 1e-3
    np.testing.assert_allclose(res.points[:, 0], -EDGE / 2, atol=1e-3)
    assert np.all(res.forces >= sim.config.min_force)
    # the pad stopped at the face (within the elastomer's compression), not beyond it
    assert abs(res.T_world_pad[0, 3] - (-EDGE / 2)) < 3e-3


def test_physical_pinch_squeezes_a_free_box_in_place():
    scene, body, _ = _box_scene(fixed=False, mass=0.1)
    before = scene.T_world_object(body)
    sim = TactileSimulator(scene, "xela_4x4", objects=[body])
    res = sim.pinch([0.0, 0.0, EDGE / 2], axis_angle=0.0, width=0.1)
    assert (res.points[:, 0] < 0).any() and (res.points[:, 0] > 0).any()  # both fingers touch
    assert np.linalg.norm(res.T_world_objects[body][:3, 3] - before[:3, 3]) < 0.01


def test_bad_input():
    scene, body, _ = _box_scene(fixed=False)
    with pytest.raises(ValueError, match="mode"):
        TactileSimulator(scene, mode="magic")
    with pytest.raises(ValueError, match="objects"):
        TactileSimulator(scene, objects=[body + 100])
    sim = TactileSimulator(scene, objects=[body])
    with pytest.raises(ValueError, match="T_world_pad"):
        sim.touch_from(np.full((4, 4), np.nan))
    with pytest.raises(ValueError, match="T_world_pad"):
        sim.touch_from(np.diag([2.0, 1.0, 1.0, 1.0]))
    with pytest.raises(ValueError, match="direction"):
        sim.touch([0.0, 0.0, 0.1], [0.0, 0.0, 0.0])
    with pytest.raises(ValueError, match="physics_step"):
        TactileConfig(physics_step=0.0)
    with pytest.raises(ValueError, match="settle_steps"):
        TactileConfig(settle_steps=-1)
    with pytest.raises(ValueError, match="n"):
        scene.step(-1)
