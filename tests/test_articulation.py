"""Interactive articulation detection (thesis 6.2.2): relative motion, heuristics, belief, actions, sim."""

import dataclasses

import numpy as np
import pytest

from vtlearn.geometry import so3_exp
from vtlearn.runtime.articulation import (
    ArticulationBelief,
    HoldAction,
    HoldPullAction,
    KinematicArticulationSim,
    PullAction,
    PushAction,
    TrackedArticulationSim,
    action_evidence,
    choose_action,
    classify_relative_motion,
    detect_articulation,
    hold_pull_action,
    hold_pull_heuristic,
    prismatic_axis,
    push_action,
    push_heuristic,
    relative_pose,
    revolute_axis,
)
from vtlearn.sim_data.articulated import ArticulatedObject, ArticulatedSpec, make_articulated
from vtlearn.sim_data.scene import Scene


def _T(R=np.eye(3), t=(0.0, 0.0, 0.0)):
    T = np.eye(4)
    T[:3, :3], T[:3, 3] = np.asarray(R), t
    return T


def _rot_about(u, angle, c):
    """Rotation by ``angle`` about the line through ``c`` along unit ``u``: [R, (I - R) c]."""
    R = np.asarray(so3_exp(np.asarray(u, dtype=np.float64) * angle))
    return _T(R, (np.eye(3) - R) @ np.asarray(c))


T_WA = _T(np.asarray(so3_exp(np.array([0.1, -0.2, 0.7]))), (0.3, -0.1, 0.05))  # part a, anywhere
T_AB = _T(np.asarray(so3_exp(np.array([0.0, 0.3, 0.0]))), (0.05, 0.02, 0.1))  # part b in a


def test_pure_rotation_is_revolute_with_its_axis():
    u = np.array([1.0, 2.0, 2.0]) / 3.0
    c = np.array([0.02, -0.05, 0.04])
    after = _rot_about(u, 0.5, c) @ T_AB
    m = classify_relative_motion(T_AB, after)
    assert m.joint_type == "revolute"
    assert np.isclose(m.angle, 0.5)
    np.testing.assert_allclose(m.axis, u, atol=1e-6)
    # the pivot is the point of the axis line closest to a's origin
    np.testing.assert_allclose(m.pivot, c - (c @ u) * u, atol=1e-9)
    # the opposite rotation gives the opposite axis (the observed motion is a positive rotation)
    np.testing.assert_allclose(classify_relative_motion(after, T_AB).axis, -u, atol=1e-6)
    # the same in world poses of the parts: the relative pose removes a's pose
    np.testing.assert_allclose(relative_pose(T_WA, T_WA @ after), after, atol=1e-12)


def test_pure_translation_is_prismatic_and_no_change_is_rigid():
    d = np.array([0.0, -0.6, 0.8])
    after = _T(t=0.04 * d) @ T_AB
    m = classify_relative_motion(T_AB, after)
    assert m.joint_type == "prismatic" and m.pivot is None
    np.testing.assert_allclose(m.axis, d, atol=1e-12)
    assert np.isclose(m.translation, 0.04) and m.angle < 1e-7
    r = classify_relative_motion(T_AB, T_AB)
    assert r.joint_type == "rigid" and r.axis is None and r.translation == 0.0
    # below both thresholds: rigid; a 2 deg turn about b's own origin is not a joint motion
    small = T_AB @ _T(np.asarray(so3_exp(np.array([0.0, 0.0, np.deg2rad(2.0)]))))
    assert classify_relative_motion(T_AB, small).joint_type == "rigid"


def test_revolute_axis_from_several_observations():
    u = np.array([0.0, 0.0, 1.0])
    c = np.array([0.1, -0.2, 0.3])
    deltas = [_rot_about(u, a, c) for a in (0.3, -0.6, 1.1)]
    axis, pivot = revolute_axis(deltas)
    np.testing.assert_allclose(axis, u, atol=1e-9)  # oriented along the largest rotation (+1.1)
    np.testing.assert_allclose(pivot, [0.1, -0.2, 0.0], atol=1e-9)
    # noisy: 1 mm and 0.3 deg on each observation; the least squares stays within 2 deg and 5 mm
    rng = np.random.default_rng(0)
    noisy = []
    for D in deltas:
        N = _T(np.asarray(so3_exp(rng.normal(scale=np.deg2rad(0.3), size=3))), rng.normal(scale=1e-3, size=3))
        noisy.append(N @ D)
    axis_n, pivot_n = revolute_axis(noisy)
    assert np.degrees(np.arccos(axis_n @ u)) < 2.0
    assert np.linalg.norm((pivot_n - c)[:2]) < 0.005


def test_prismatic_axis_aligns_signs():
    d = np.array([0.6, 0.8, 0.0])
    np.testing.assert_allclose(prismatic_axis(np.stack([0.03 * d, -0.05 * d, 0.01 * d])), -d, atol=1e-12)


def _world(T_ab_before, T_ab_after, move_a=np.eye(4)):
    """(2, 4, 4) world poses before and after: a at T_WA (moved by move_a), b from its relative pose."""
    Ta1 = move_a @ T_WA
    return np.stack([T_WA, T_WA @ T_ab_before]), np.stack([Ta1, Ta1 @ T_ab_after])


SHIFT = _T(t=(0.08, 0.03, 0.0))  # a 10 cm-ish push of the whole object


def test_push_heuristic_branches():
    hinge = _rot_about([0.0, 0.0, 1.0], 0.4, [0.0, 0.0, 0.0]) @ T_AB
    b0, b1 = _world(T_AB, hinge)  # only b moved (turned about its hinge)
    assert push_heuristic(b0, b1, pushed=1) == "revolute"
    assert push_heuristic(b0, b1, pushed=0) == "no_motion"
    t0, t1 = _world(T_AB, T_AB, SHIFT)  # both moved, relative pose kept
    assert push_heuristic(t0, t1, pushed=0) == "rigid_or_prismatic"
    assert push_heuristic(t0, t1, pushed=1) == "rigid_or_prismatic"
    m0, m1 = _world(T_AB, hinge, SHIFT)  # both moved and b turned: outside the heuristic
    assert push_heuristic(m0, m1, pushed=0) == "inconclusive"
    slide = _T(t=(0.0, 0.05, 0.0)) @ T_AB
    s0, s1 = _world(T_AB, slide)
    assert hold_pull_heuristic(s0, s1, hold=0, pull=1) == "prismatic"
    assert hold_pull_heuristic(t0, t1, hold=0, pull=1) == "rigid"


def _push(part):
    return PushAction(part, np.zeros(3), np.array([1.0, 0.0, 0.0]))


def _hold_pull():
    return HoldPullAction(
        HoldAction(0, np.zeros(3), np.array([0, 0, -1.0])), PullAction(1, np.zeros(3), np.ones(3))
    )


def test_action_evidence_goes_beyond_the_heuristic():
    slide = _T(t=(0.0, 0.05, 0.0)) @ T_AB
    s0, s1 = _world(T_AB, slide)
    # a drawer pushed along its axis moves alone: the heuristic says revolute, the relative motion prismatic
    assert push_heuristic(s0, s1, pushed=1) == "revolute"
    ev, m = action_evidence(_push(1), s0, s1)
    assert ev == "prismatic" and m.joint_type == "prismatic"
    t0, t1 = _world(T_AB, T_AB, SHIFT)
    assert action_evidence(_push(0), t0, t1)[0] == "together"
    assert action_evidence(_push(1), t0, t0)[0] == "none"
    assert action_evidence(_hold_pull(), t0, t0)[0] == "rigid"
    assert action_evidence(_hold_pull(), s0, s1)[0] == "prismatic"


def test_belief_stops_after_three_unchanged_updates():
    b = ArticulationBelief()
    assert b.state == "unknown" and not b.explored
    assert b.update("together", pushed=0) and b.state == "rigid_or_prismatic"
    assert not b.update("together", pushed=1) and b.unchanged == 1
    assert b.update("rigid") and b.state == "rigid" and b.unchanged == 0
    for k in range(1, 4):
        assert not b.explored
        assert not b.update("rigid")
        assert b.unchanged == k
    assert b.explored
    assert repr(b).startswith("ArticulationBelief(parts=(0, 1), state='rigid'")


def test_belief_keeps_an_observed_joint_and_estimates_its_axis():
    u, c = np.array([1.0, 0.0, 0.0]), np.array([0.0, -0.15, 0.012])
    b = ArticulationBelief(patience=2)
    m1 = classify_relative_motion(T_AB, _rot_about(u, 0.6, c) @ T_AB)
    assert b.update("revolute", m1) and b.state == "revolute"
    assert not b.update("together")  # a joint at its limit moves with the rest: still revolute
    assert not b.update("rigid")
    assert b.explored
    np.testing.assert_allclose(b.axis, u, atol=1e-9)
    np.testing.assert_allclose(b.pivot, c, atol=1e-9)
    p = ArticulationBelief()
    p.update("none")
    assert p.state == "unknown" and p.unchanged == 1 and p.axis is None
    assert p.update("prismatic", classify_relative_motion(T_AB, _T(t=(0, 0, 0.02)) @ T_AB))
    np.testing.assert_allclose(p.axis, [0, 0, 1], atol=1e-12)
    assert p.pivot is None


def test_choose_action_follows_the_thesis_order():
    b = ArticulationBelief(parts=(1, 0))
    assert choose_action(b) == ("push", 1)  # push a first
    b.update("together", pushed=1)
    assert choose_action(b) == ("push", 0)  # then the other part
    b.update("together", pushed=0)
    assert choose_action(b) == ("hold_pull", None)  # pushes inconclusive: hold-pull
    b.update("prismatic")
    assert choose_action(b) == ("hold_pull", None)
    r = ArticulationBelief()
    r.update("revolute", pushed=0)
    assert choose_action(r) == ("push", 1)  # revolute: confirmed by pushing the other part
    r.update("together", pushed=1)
    assert choose_action(r) == ("push", 0)


def _box_cloud(centre, size, n=9):
    """Surface grid of an axis-aligned box (symmetric, so its PCA axes are the box axes)."""
    g = np.linspace(-0.5, 0.5, n)
    faces = []
    for ax in range(3):
        for s in (-0.5, 0.5):
            u, v = np.meshgrid(g, g)
            f = np.zeros((n * n, 3))
            f[:, ax] = s
            f[:, [i for i in range(3) if i != ax]] = np.stack([u.ravel(), v.ravel()], 1)
            faces.append(f)
    return np.concatenate(faces) * np.asarray(size) + np.asarray(centre)


def test_push_action_from_the_obb():
    # part 0: 20 x 8 x 4 cm along x, at the origin; part 1 beside it in +y
    clouds = [_box_cloud([0, 0, 0.02], [0.2, 0.08, 0.04]), _box_cloud([0.05, 0.15, 0.02], [0.1, 0.1, 0.04])]
    a = push_action(clouds, 0, zeta=0.01)
    assert a.part == 0 and a.distance == 0.10 and a.kind == "push"
    np.testing.assert_allclose(a.direction, [0, -1, 0], atol=1e-12)  # +-V_y, away from part 1
    # on the face the pad enters (y = +4 cm), 1 cm from the box end away from part 1 (x = -10 cm)
    np.testing.assert_allclose(a.point, [-0.09, 0.04, 0.02], atol=1e-12)


def test_hold_pull_action_from_the_obbs():
    # a handle (12 x 3 x 2 cm) and a blade (8 x 2 x 0.4 cm) sticking out of it along +x
    clouds = [_box_cloud([0, 0, 0.01], [0.12, 0.03, 0.02]), _box_cloud([0.08, 0, 0.02], [0.08, 0.02, 0.004])]
    hp = hold_pull_action(clouds, hold=0, pull=1, zeta=0.01)
    assert hp.kind == "hold_pull" and hp.pull.distance == 0.05
    np.testing.assert_allclose(hp.hold.direction, [0, 0, -1], atol=1e-12)  # V_z of the handle, pressing down
    np.testing.assert_allclose(hp.hold.point, [-0.05, 0, 0.02], atol=1e-12)  # top face, far end, zeta in
    np.testing.assert_allclose(hp.pull.direction, [1, 0, 0], atol=1e-12)  # V_x of the blade, away
    np.testing.assert_allclose(hp.pull.point, [0.11, 0, 0.02], atol=1e-12)
    # a part wide across the separation: the pull takes the axis closest to it (here V_y)
    wide = [clouds[0], _box_cloud([0, 0.1, 0.01], [0.2, 0.1, 0.02])]
    np.testing.assert_allclose(hold_pull_action(wide, 0, 1).pull.direction, [0, 1, 0], atol=1e-12)


def _yaw(x, y, yaw):
    c, s = np.cos(yaw), np.sin(yaw)
    return _T([[c, -s, 0], [s, c, 0], [0, 0, 1]], (x, y, 0.0))


def _rigid_dishwasher(seed):
    spec = make_articulated("dishwasher", seed)
    return ArticulatedSpec("rigid", [spec.links[0], dataclasses.replace(spec.links[1], joint_type="fixed")])


def _detect(spec, noise=(0.0, 0.0), seed=0):
    with Scene() as scene:
        obj = ArticulatedObject(scene, spec, n_model_points=0.01)
        T_base = _yaw(0.05, -0.03, 0.4)
        sim = KinematicArticulationSim(obj, T_base, np.full(spec.n_joints, 0.4), pose_noise=noise, seed=seed)
        return detect_articulation(sim.observe, sim.execute), T_base


def _check_axis(res, spec, T_base, tol_deg, tol_pivot):
    link = spec.links[1]
    u = np.asarray(link.axis, dtype=np.float64)
    u /= np.linalg.norm(u)
    assert np.degrees(np.arccos(min(1.0, abs(res.axis_a @ u)))) <= tol_deg
    assert np.degrees(np.arccos(min(1.0, abs(res.axis_world @ (T_base[:3, :3] @ u))))) <= tol_deg + 1e-6
    if link.joint_type == "revolute":
        v = res.pivot_a - np.asarray(link.joint_xyz)
        assert np.linalg.norm(v - (v @ u) * u) <= tol_pivot  # the pivot lies on the hinge line


@pytest.mark.parametrize(
    ("category", "joint_type"),
    [("dishwasher", "revolute"), ("glasses", "revolute"), ("drawer", "prismatic"), ("blade", "prismatic")],
)
@pytest.mark.parametrize("seed", [0, 1])
def test_pybullet_categories_are_recovered_exactly(category, joint_type, seed):
    spec = make_articulated(category, seed)
    res, T_base = _detect(spec)
    assert res.joint_type == joint_type and res.explored
    assert res.n_actions <= 7
    assert res.steps[0].action.kind == "push"  # the thesis starts with a push
    if joint_type == "revolute":
        assert all(s.action.kind == "push" for s in res.steps)  # pushes settle a revolute joint
    else:
        assert any(s.action.kind == "hold_pull" for s in res.steps)
    # noiseless poses: the joint axis to 1e-6 (angle), the pivot on the hinge line to 1e-6 m
    _check_axis(res, spec, T_base, np.degrees(1e-6), 1e-6)


def test_pybullet_rigid_object_needs_the_hold_pull():
    res, _ = _detect(_rigid_dishwasher(0))
    assert res.joint_type == "rigid" and res.explored and res.axis_a is None
    kinds = [s.action.kind for s in res.steps]
    assert kinds[:3] == ["push", "push", "hold_pull"]  # both pushes move the parts together
    assert [s.heuristic for s in res.steps[:2]] == ["rigid_or_prismatic"] * 2


@pytest.mark.parametrize(
    ("category", "joint_type"),
    [("dishwasher", "revolute"), ("glasses", "revolute"), ("drawer", "prismatic"), ("blade", "prismatic")],
)
def test_pybullet_categories_with_pose_noise(category, joint_type):
    """1 mm and 0.3 deg of tracking noise per part pose: the type is right, the axis within 8 deg."""
    spec = make_articulated(category, 1)
    res, T_base = _detect(spec, noise=(0.001, np.deg2rad(0.3)), seed=3)
    assert res.joint_type == joint_type and res.explored
    _check_axis(res, spec, T_base, 8.0, 0.015)


@pytest.mark.parametrize(("category", "joint_type"), [("dishwasher", "revolute"), ("drawer", "prismatic")])
def test_articulation_from_artreg_tracked_depth(category, joint_type):
    """The thesis's loop: actions replayed as camera frames, part poses tracked by ArtReg from simulated
    depth. Large parts are tracked within 2 cm and their joint type is found."""
    with Scene() as scene:
        obj = ArticulatedObject(scene, make_articulated(category, 0), n_model_points=0.01)
        sim = KinematicArticulationSim(obj, np.eye(4), q=[0.4] * obj.spec.n_joints)
        tracked = TrackedArticulationSim(sim, seed=0)
        assert all(0 < len(m) < len(full) for m, full in zip(tracked.models, obj.models, strict=True))
        res = detect_articulation(tracked.observe, tracked.execute)
        assert res.joint_type == joint_type and res.explored
        assert tracked.frames == 1 + res.n_actions * (tracked.frames_per_action + tracked.settle_frames)
        assert np.median(tracked.errors_mm) < 20.0
        with pytest.raises(ValueError, match="sim"):
            TrackedArticulationSim(obj)
        with pytest.raises(ValueError, match="frames_per_action"):
            TrackedArticulationSim(sim, frames_per_action=0)


def test_bad_input():
    with pytest.raises(ValueError, match="T_a_b_before"):
        classify_relative_motion(np.eye(3), np.eye(4))
    with pytest.raises(ValueError, match="rot_threshold"):
        classify_relative_motion(np.eye(4), np.eye(4), rot_threshold=0.0)
    with pytest.raises(ValueError, match="T_world_b"):
        relative_pose(np.eye(4), np.full((4, 4), np.nan))
    with pytest.raises(ValueError, match="deltas"):
        revolute_axis([np.eye(4)])
    with pytest.raises(ValueError, match="displacements"):
        prismatic_axis(np.zeros((2, 3)))
    t0, t1 = _world(T_AB, T_AB, SHIFT)
    with pytest.raises(ValueError, match="T_before"):
        push_heuristic(t0[:1], t1, pushed=0)
    with pytest.raises(ValueError, match="T_after"):
        push_heuristic(t0, np.stack([t1[0]] * 3), pushed=0)
    with pytest.raises(ValueError, match="pushed"):
        push_heuristic(t0, t1, pushed=2)
    with pytest.raises(ValueError, match="hold, pull"):
        hold_pull_heuristic(t0, t1, hold=1, pull=1)
    with pytest.raises(ValueError, match="action"):
        action_evidence("push", t0, t1)
    with pytest.raises(ValueError, match="parts"):
        ArticulationBelief(parts=(0, 0))
    with pytest.raises(ValueError, match="evidence"):
        ArticulationBelief().update("maybe")
    with pytest.raises(ValueError, match="belief"):
        choose_action("unknown")
    clouds = [_box_cloud([0, 0, 0], [0.1, 0.05, 0.02]), _box_cloud([0.2, 0, 0], [0.1, 0.05, 0.02])]
    with pytest.raises(ValueError, match="clouds"):
        push_action(clouds[:1], 0)
    with pytest.raises(ValueError, match="part"):
        push_action(clouds, 5)
    with pytest.raises(ValueError, match="zeta"):
        hold_pull_action(clouds, 0, 1, zeta=-1.0)
    with pytest.raises(ValueError, match="observe, execute"):
        detect_articulation(None, None)
    with Scene() as scene:
        obj = ArticulatedObject(scene, make_articulated("drawer", 0), n_model_points=200)
        with pytest.raises(ValueError, match="q"):
            KinematicArticulationSim(obj, np.eye(4), [2.0])
        with pytest.raises(ValueError, match="pose_noise"):
            KinematicArticulationSim(obj, np.eye(4), pose_noise=(-1.0, 0.0))
        with pytest.raises(ValueError, match="action"):
            KinematicArticulationSim(obj, np.eye(4)).execute("pull")


def test_part_clouds_in_millimetres_are_refused():
    clouds = [_box_cloud([0, 0, 0], [0.1, 0.05, 0.02]), _box_cloud([0.2, 0, 0], [0.1, 0.05, 0.02])]
    mm = [1000 * c for c in clouds]
    with pytest.raises(ValueError, match=r"^clouds\[0\]: spans .*millimetres"):
        push_action(mm, 0)
    with pytest.raises(ValueError, match=r"^clouds\[0\]: spans .*millimetres"):
        hold_pull_action(mm, 0, 1)
