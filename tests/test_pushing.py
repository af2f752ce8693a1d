"""Goal-driven pushing (thesis 6.2.4, eq. 6.12-6.17): hand cases, the OBB, and a pybullet closed loop."""

import numpy as np
import pytest
import trimesh

from vtlearn.runtime.obb import oriented_bounding_box
from vtlearn.runtime.pushing import (
    GoalPusher,
    PushPID,
    bearing_angle,
    distance_to_goal,
    push_pose,
    shift_sensor,
)
from vtlearn.sim_data.scene import Scene


def _thesis_theta(O, P, T):
    """Eq. 6.12-6.14 with the slope (non-vertical lines, goal ahead of O), 6.13 solved from the two lines."""
    m = (P[1] - O[1]) / (P[0] - O[0])
    Ix = (T[0] + m**2 * O[0] - m * (O[1] - T[1])) / (1 + m**2)
    Iy = T[1] - (Ix - T[0]) / m
    return np.arctan(np.hypot(T[0] - Ix, T[1] - Iy) / np.hypot(O[0] - Ix, O[1] - Iy))


def test_bearing_hand_cases():
    O, P = np.zeros(2), np.array([-1.0, 0.0])
    assert bearing_angle(O, P, [2.0, 0.0]) == 0.0  # goal on the push line
    assert bearing_angle(O, P, [2.0, 0.0], signed=True) == 0.0
    assert np.isclose(bearing_angle(O, P, [1.0, 1.0]), np.pi / 4)
    assert np.isclose(bearing_angle(O, P, [0.0, 3.0]), np.pi / 2)  # right angle at O
    assert np.isclose(bearing_angle(O, P, [-2.0, 0.0]), np.pi)  # behind O along the line
    assert np.isclose(bearing_angle(O, P, [-1.0, 1.0]), 3 * np.pi / 4)
    assert bearing_angle(O, P, O) == 0.0  # at the goal


def test_bearing_sign_flips_with_the_mirror_image():
    O, P = np.array([0.1, 0.2]), np.array([0.0, 0.1])
    T = np.array([0.3, 0.5])
    left = bearing_angle(O, P, T, signed=True)
    assert left > 0  # T is counter-clockwise of the push direction (1, 1)
    # mirror about the push line y - 0.2 = x - 0.1: (x, y) -> (y - 0.1, x + 0.1)
    T_m = np.array([T[1] - 0.1, T[0] + 0.1])
    assert np.isclose(bearing_angle(O, P, T_m, signed=True), -left)
    assert np.isclose(bearing_angle(O, P, T_m), abs(left))


def test_bearing_vertical_line_and_3d_points():
    O, P = np.array([0.0, 0.0, 0.05]), np.array([0.0, -0.1, 0.05])  # m = inf in eq. 6.12
    assert np.isclose(bearing_angle(O, P, [1.0, 1.0, 0.0]), np.pi / 4)
    assert np.isclose(bearing_angle(O, P, [1.0, 1.0, 7.0], signed=True), -np.pi / 4)  # right of +y
    assert np.isclose(bearing_angle(O, P, [-1.0, 1.0], signed=True), np.pi / 4)
    assert bearing_angle(O, P, [0.0, 0.3]) == 0.0


def test_bearing_equals_the_slope_form_of_eq_6_13():
    rng = np.random.default_rng(0)
    n = 0
    for _ in range(400):
        O, P, T = rng.normal(size=(3, 2))
        if np.dot(T - O, O - P) <= 0 or abs(P[0] - O[0]) < 1e-3 or abs(P[1] - O[1]) < 1e-3:
            continue
        assert np.isclose(bearing_angle(O, P, T), _thesis_theta(O, P, T), atol=1e-12)
        n += 1
    assert n > 50


def test_pid_p_only_and_clipping():
    pid = PushPID(kp=0.05, ki=0.0, kd=0.0)
    assert np.isclose(pid(0.2), 0.01)
    assert np.isclose(pid(-0.4), -0.02)
    assert pid(1.0) == 0.03  # 0.05 clipped at +3 cm
    assert pid(-10.0) == -0.03
    assert repr(PushPID()) == "PushPID(kp=0.05, ki=0.0, kd=0.03, limit=0.03)"


def test_pid_derivative_on_a_step_and_reset():
    pid = PushPID(kp=0.0, ki=0.0, kd=0.03)
    assert pid(0.0, 0.5) == 0.0
    assert np.isclose(pid(0.2, 0.5), 0.03 * 0.2 / 0.5)  # step of 0.2 in 0.5
    assert pid(0.2, 0.5) == 0.0  # constant error: no derivative
    pid.reset()
    assert pid(0.2) == 0.0  # no previous error after reset
    thesis = PushPID()
    assert np.isclose(thesis(0.4), 0.02)
    assert np.isclose(thesis(0.0), -0.012)  # 0.05 * 0 + 0.03 * (0 - 0.4) / 1


def test_pid_integral():
    pid = PushPID(kp=0.0, ki=0.1, kd=0.0, limit=1.0)
    pid(0.1, 2.0)
    assert np.isclose(pid(0.1, 1.0), 0.1 * 0.3)
    pid.reset()
    assert pid.integral == 0.0 and pid.prev_error is None


def test_shift_sensor_exact():
    T = np.eye(4)
    T[:3, :3] = [[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]]
    T[:3, 3] = [0.1, 0.2, 0.3]
    out = shift_sensor(T, 0.02)
    expected = T.copy()
    expected[:3, 3] = [0.1, 0.22, 0.3]  # 2 cm along x_S = world +y
    np.testing.assert_array_equal(out, expected)
    np.testing.assert_array_equal(shift_sensor(T, 0.0), T)


def test_distance_to_goal():
    assert distance_to_goal([0.0, 0.0], [0.3, 0.4]) == 0.5
    assert distance_to_goal([1.0, 1.0, 5.0], [1.0, 0.0, -2.0]) == 1.0


def _rectangle(L=0.2, W=0.1, H=0.04, yaw=np.pi / 6, centre=(0.1, 0.2), n=21):
    """Top and bottom faces of an L x W x H box as symmetric grids, yawed and moved."""
    u, v = np.meshgrid(np.linspace(-L / 2, L / 2, n), np.linspace(-W / 2, W / 2, n))
    grid = np.stack([u.ravel(), v.ravel()], 1)
    pts = np.concatenate([np.c_[grid, np.zeros(len(grid))], np.c_[grid, np.full(len(grid), H)]])
    c, s = np.cos(yaw), np.sin(yaw)
    pts[:, :2] = pts[:, :2] @ np.array([[c, -s], [s, c]]).T + centre
    return pts, np.array([c, s]), np.array([-s, c])


def test_obb_of_a_rectangle():
    pts, vx, vy = _rectangle()
    obb = oriented_bounding_box(pts, planar=True)
    np.testing.assert_allclose(obb.centre, [0.1, 0.2, 0.02], atol=1e-12)
    np.testing.assert_allclose(obb.half_extents, [0.1, 0.05, 0.02], atol=1e-12)
    np.testing.assert_allclose(obb.V_x[:2], vx, atol=1e-12)
    np.testing.assert_allclose(obb.V_y[:2], vy, atol=1e-12)
    full = oriented_bounding_box(pts)  # 3-D PCA: the minor axis is the table normal
    np.testing.assert_allclose(np.abs(full.V_z), [0, 0, 1], atol=1e-12)
    np.testing.assert_allclose(full.axes.T @ full.axes, np.eye(3), atol=1e-12)
    assert np.isclose(np.linalg.det(full.axes), 1.0)


def test_push_pose_pushes_along_vy_through_the_centre():
    pts, vx, vy = _rectangle()
    O = np.array([0.1, 0.2])
    T_W_S, pp = push_pose(pts, O + 0.3 * vy + 0.1 * vx)
    z = T_W_S[:3, 2]
    np.testing.assert_allclose(z, [*vy, 0.0], atol=1e-12)  # push direction +V_y, towards the goal
    np.testing.assert_allclose(pp, [*(O - 0.05 * vy), 0.02], atol=1e-12)  # entry face, mid height
    np.testing.assert_allclose(T_W_S[:3, 0], [vy[1], -vy[0], 0.0], atol=1e-12)  # x_S right of the push
    np.testing.assert_allclose(T_W_S[:3, 1], [0, 0, -1], atol=1e-12)
    # the push line P -> O passes through O
    assert abs(np.cross(O - pp[:2], z[:2])) < 1e-12
    # a goal on the other side flips it; a goal along V_x still gets +-V_y with face="y"
    T2, _ = push_pose(pts, O - 0.3 * vy)
    np.testing.assert_allclose(T2[:3, 2], [*-vy, 0.0], atol=1e-12)
    T3, pp3 = push_pose(pts, O + 0.3 * vx, face="best")
    np.testing.assert_allclose(T3[:3, 2], [*vx, 0.0], atol=1e-12)
    np.testing.assert_allclose(pp3[:2], O - 0.1 * vx, atol=1e-12)
    # eq. 6.16 offset along x_S, clipped so that a 1.5 cm pad stays on the 20 cm face
    T4, pp4 = push_pose(pts, O + 0.3 * vy, offset=0.02)
    np.testing.assert_allclose(pp4, pp + 0.02 * T_W_S[:3, 0], atol=1e-12)
    _, pp5 = push_pose(pts, O + 0.3 * vy, offset=0.5)
    np.testing.assert_allclose(pp5, pp + 0.085 * T_W_S[:3, 0], atol=1e-12)


def _box_scene(yaw: float):
    scene = Scene()
    T = np.eye(4)
    c, s = np.cos(yaw), np.sin(yaw)
    T[:2, :2] = [[c, -s], [s, c]]
    T[2, 3] = 0.025
    body = scene.add_mesh(trimesh.creation.box(extents=[0.10, 0.06, 0.05]), T_world_object=T, fixed=False)
    scene.step(60)
    return scene, body


@pytest.mark.parametrize(
    ("yaw", "goal", "face", "max_n"),
    [(0.3, (0.25, 0.1), "best", 12), (0.0, (0.3, 0.0), "y", 18)],  # the second starts at 90 deg bearing
)
def test_closed_loop_pushes_a_box_to_the_goal(tmp_path, yaw, goal, face, max_n):
    scene, body = _box_scene(yaw)
    with scene:
        start = scene.T_world_object(body)[:2, 3]
        assert 0.25 <= distance_to_goal(start, goal) <= 0.35
        res = GoalPusher(scene, body, face=face, max_pushes=max_n).run(goal)
        assert res.success and res.final_distance < 0.02, (res.n_pushes, res.final_distance)
        assert res.n_pushes <= max_n
        # the result's final centre is the simulated object's (model cloud OBB of the true pose)
        assert distance_to_goal(scene.T_world_object(body)[:3, 3], goal) < 0.025
        assert all(r.contact and not r.contact_lost for r in res.records)
        assert all(abs(r.c) <= 0.03 + 1e-12 for r in res.records)
        assert np.all(np.diff([r.d for r in res.records]) < 0.01)  # every push gets closer, or nearly
        assert res.path.shape == (res.n_pushes + 1, 2)
        out = res.figure(tmp_path / "push.png")
        assert out.exists() and out.stat().st_size > 1000


def test_a_rolling_ball_loses_contact_and_the_push_is_recomputed():
    """A ball rolls ahead of the pad: the pad reports the loss of contact, the push stops early."""
    scene = Scene()
    with scene:
        T = np.eye(4)
        T[2, 3] = 0.03
        body = scene.add_mesh(trimesh.creation.icosphere(2, 0.03), T_world_object=T, fixed=False, mass=0.1)
        scene.step(60)
        res = GoalPusher(scene, body, max_pushes=3).run((0.25, 0.1))
        lost = [r for r in res.records if r.contact_lost]
        assert lost and all(r.contact and r.pushed < 0.03 for r in lost)
        assert not res.success and res.n_pushes == 3
        # every iteration re-estimates the pose: the push points follow the ball
        assert np.linalg.norm(res.records[-1].push_point - res.records[0].push_point) > 0.02


def test_bad_input():
    with pytest.raises(ValueError, match="P"):
        bearing_angle([0, 0], [0, 0], [1, 1])
    with pytest.raises(ValueError, match="T"):
        bearing_angle([0, 0], [1, 0], [np.nan, 1])
    with pytest.raises(ValueError, match="O"):
        bearing_angle([0, 0, 0, 0], [1, 0], [1, 1])
    with pytest.raises(ValueError, match="kp"):
        PushPID(kp=-1.0)
    with pytest.raises(ValueError, match="limit"):
        PushPID(limit=0.0)
    with pytest.raises(ValueError, match="dt"):
        PushPID()(0.1, 0.0)
    with pytest.raises(ValueError, match="error"):
        PushPID()(np.inf)
    with pytest.raises(ValueError, match="T_W_S"):
        shift_sensor(np.eye(3), 0.1)
    with pytest.raises(ValueError, match="c"):
        shift_sensor(np.eye(4), np.nan)
    with pytest.raises(ValueError, match="T"):
        distance_to_goal([0, 0], [1])
    pts, _, _ = _rectangle()
    with pytest.raises(ValueError, match="points_world"):
        push_pose(pts[:2], [0, 0])
    with pytest.raises(ValueError, match="face"):
        push_pose(pts, [0, 0], face="z")
    with pytest.raises(ValueError, match="points"):
        oriented_bounding_box(np.ones((5, 3)))
    scene, body = _box_scene(0.0)
    with scene:
        with pytest.raises(ValueError, match="body"):
            GoalPusher(scene, body + 10)
        with pytest.raises(ValueError, match="tolerance"):
            GoalPusher(scene, body, tolerance=0.0)
        with pytest.raises(ValueError, match="pad_size"):
            GoalPusher(scene, body, pad_size=(0.03, 0.03))
        with pytest.raises(ValueError, match="target_xy"):
            GoalPusher(scene, body).run([np.nan, 0.0])
        fixed = scene.add_mesh(trimesh.creation.box(extents=[0.05] * 3), fixed=True)
        with pytest.raises(ValueError, match="fixed"):
            GoalPusher(scene, fixed)


def test_millimetres_are_refused_naming_the_argument():
    pts, _, _ = _rectangle()
    with pytest.raises(ValueError, match="^points_world: .*millimetres"):
        push_pose(1000 * pts, [200.0, 0.0])
    scene, body = _box_scene(0.0)
    with scene:
        with pytest.raises(ValueError, match="^model_points: .*millimetres"):
            GoalPusher(scene, body, model_points=1000 * pts)
        pusher = GoalPusher(scene, body)
        O = pusher.object_cloud().mean(0)
        # a goal 25 cm away given in millimetres: refused before any push, not 30 pushes that get nowhere
        with pytest.raises(ValueError, match="^target_xy: the goal is .* m from the object.*millimetres"):
            pusher.run([250.0, 100.0])
        np.testing.assert_allclose(pusher.object_cloud().mean(0), O, atol=1e-9)
        pusher.close()
