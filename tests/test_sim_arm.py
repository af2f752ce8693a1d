"""Arm mode: pytorch-kinematics FK of the Panda agrees with pybullet's link state; arm touches land on
the surface."""

import numpy as np
import pytest
import trimesh

from vtlearn.sim_data.arm import PandaArm
from vtlearn.sim_data.scene import Scene
from vtlearn.sim_data.shapes import generate_shape
from vtlearn.sim_data.tactile import sample_touches


@pytest.fixture(scope="module")
def setup():
    scene = Scene()
    mesh, rec = generate_shape("can", 0)
    T = np.eye(4)
    T[2, 3] = -mesh.bounds[0, 2] * rec.scale_m
    body = scene.add_mesh(mesh, rec.scale_m, T)
    mesh_w = scene.objects[body].mesh_m.copy()
    mesh_w.apply_transform(T)
    yield scene, PandaArm(scene, objects=[body]), mesh_w
    scene.close()


def test_fk_matches_pybullet_random_configurations(setup):
    """Acceptance: FK agrees with pybullet to 1 mm (hand pose and every taxel)."""
    _, arm, _ = setup
    rng = np.random.default_rng(0)
    for _ in range(10):
        q = rng.uniform(arm.lower, arm.upper)
        arm.set_joints(q)
        T_pb = arm.pybullet_hand()
        T_fk = arm.fk_hand(q)
        assert np.linalg.norm(T_fk[:3, 3] - T_pb[:3, 3]) < 1e-3
        assert np.abs(T_fk[:3, :3] - T_pb[:3, :3]).max() < 1e-3
        taxels_pb = (
            arm.sim.sensor.taxel_positions() @ (T_pb @ arm.T_hand_pad)[:3, :3].T
            + (T_pb @ arm.T_hand_pad)[:3, 3]
        )
        assert np.linalg.norm(arm.taxel_positions_world(q) - taxels_pb, axis=1).max() < 1e-3


def test_arm_touches_reach_and_land_on_surface(setup):
    from scipy.spatial import cKDTree

    _, arm, mesh_w = setup
    lo, hi = mesh_w.bounds
    rng = np.random.default_rng(0)
    results = [arm.touch(*a, rng=rng) for a in sample_touches(lo, hi, 24, rng)]
    pts = np.concatenate([r.points for r in results])
    assert sum(r.num_contacts > 0 for r in results) >= 3
    ref, _ = trimesh.sample.sample_surface(mesh_w, 200_000, seed=0)
    assert np.median(cKDTree(ref).query(pts)[0]) < 1e-3
    # after the motion, the arm's FK pose is the pad stop pose pybullet also reports
    assert np.linalg.norm(arm.fk_hand(arm.q)[:3, 3] - arm.pybullet_hand()[:3, 3]) < 1e-3


def test_set_joints_validates(setup):
    _, arm, _ = setup
    with pytest.raises(ValueError, match="q"):
        arm.set_joints([0.0] * 6)
