"""Tests for vtlearn.active.actions: NBT face sampling, pinch from above, NBV hemisphere + eq. 5.3-5.5."""

import numpy as np
import pytest

from vtlearn.active.actions import (
    FACE_NAMES,
    OrientedBox,
    ReachFeasibility,
    marsaglia_sphere,
    sample_pinch_actions,
    sample_touch_actions,
    sample_view_actions,
    view_rotation,
)


def rotated_box():
    c, s = np.cos(0.4), np.sin(0.4)
    T = np.eye(4)
    T[:3, :3] = [[c, -s, 0], [s, c, 0], [0, 0, 1]]
    T[:3, 3] = [0.3, -0.1, 0.05]
    return OrientedBox(T, [0.08, 0.06, 0.1])


def test_touch_actions_lie_on_faces_except_bottom_and_point_inward():
    box = rotated_box()
    acts = sample_touch_actions(box, 400, standoff=0.02, seed=0)
    assert len(acts) == 400 and acts.kind == "touch"
    assert set(np.unique(acts.face)) == set(range(5))  # +x -x +y -y +z; never the bottom
    T_box_world = np.linalg.inv(box.T_world_box)
    origin_b = acts.T_world_sensor[:, :3, 3] @ T_box_world[:3, :3].T + T_box_world[:3, 3]
    press_b = acts.T_world_sensor[:, :3, 2] @ T_box_world[:3, :3].T
    half = box.extents / 2
    normals = {0: [1, 0, 0], 1: [-1, 0, 0], 2: [0, 1, 0], 3: [0, -1, 0], 4: [0, 0, 1]}
    for f in range(5):
        sel = acts.face == f
        n = np.array(normals[f], float)
        assert np.allclose(press_b[sel], -n)  # pressing direction = inward face normal
        axis = int(np.argmax(np.abs(n)))
        # 2 cm outside the face plane, within the face rectangle on the other axes
        assert np.allclose(origin_b[sel, axis] * n[axis], half[axis] + 0.02)
        others = [i for i in range(3) if i != axis]
        assert (np.abs(origin_b[sel][:, others]) <= half[others] + 1e-12).all()
    assert (origin_b[:, 2] > -half[2]).all()
    R = acts.T_world_sensor[:, :3, :3]
    assert np.allclose(R.transpose(0, 2, 1) @ R, np.eye(3)) and np.allclose(np.linalg.det(R), 1)
    assert FACE_NAMES[4] == "+z"


def test_touch_faces_follow_area_weights():
    box = OrientedBox.from_aabb([0, 0, 0], [0.1, 0.1, 0.4])  # sides 0.04 m^2 each, top 0.01 m^2
    acts = sample_touch_actions(box, 4000, seed=1)
    frac_top = (acts.face == 4).mean()
    assert abs(frac_top - 0.01 / 0.17) < 0.02
    uniform = sample_touch_actions(box, 4000, seed=1, area_weighted=False)
    assert abs((uniform.face == 4).mean() - 0.2) < 0.03


def test_pinch_actions_come_from_above_and_close_horizontally():
    box = OrientedBox.from_aabb([0, 0, 0], [0.1, 0.06, 0.2])
    acts = sample_pinch_actions(box, 200, approach_height=0.1, seed=0)
    T = acts.T_world_sensor
    assert np.allclose(T[:, :3, 2], [0, 0, -1])  # approach straight down
    assert np.allclose(T[:, 2, 0], 0)  # closing axis horizontal
    c = T[:, :3, 3]
    assert (
        (c[:, 0] >= 0).all() and (c[:, 0] <= 0.1).all() and (c[:, 1] >= 0).all() and (c[:, 1] <= 0.06).all()
    )
    assert (c[:, 2] >= 0.2 * 0.2 - 1e-12).all() and (c[:, 2] <= 0.9 * 0.2 + 1e-12).all()
    assert np.allclose(acts.start[:, 2], 0.3) and np.allclose(acts.start[:, :2], c[:, :2])


def test_marsaglia_points_are_uniform_on_sphere():
    p = marsaglia_sphere(20000, np.random.default_rng(0))
    assert np.allclose(np.linalg.norm(p, axis=1), 1.0)
    assert np.abs(p.mean(axis=0)).max() < 0.02  # centred
    assert np.allclose((p**2).mean(axis=0), 1 / 3, atol=0.01)  # isotropic


def test_view_rotation_hand_computed_and_looks_at_centroid():
    # Camera on the +x axis: h = (1, 0, 0), theta = 90 deg, e = h x Z = (0, -1, 0).
    R = view_rotation([[2.0, 0.0, 0.0]], [0.0, 0.0, 0.0])[0]
    R_v = np.array([[0, 0, -1], [0, 1, 0], [1, 0, 0]], float)  # Rodrigues(e=(0,-1,0), 90 deg), hand-expanded
    assert np.allclose(R_v @ [1, 0, 0], [0, 0, 1])
    assert np.allclose(R, R_v.T @ np.diag([1, -1, -1]))
    assert np.allclose(R[:, 2], [-1, 0, 0])
    # Straight above: e undefined, camera looks down.
    R_top = view_rotation([[0.0, 0.0, 1.0]], [0.0, 0.0, 0.0])[0]
    assert np.allclose(R_top[:, 2], [0, 0, -1]) and np.isclose(np.linalg.det(R_top), 1)


def test_view_actions_on_hemisphere_facing_centroid():
    o = np.array([0.4, 0.1, 0.05])
    acts = sample_view_actions(o, 0.5, 300, min_elevation_deg=15, seed=0)
    p = acts.T_world_sensor[:, :3, 3]
    assert np.allclose(np.linalg.norm(p - o, axis=1), 0.5)
    assert ((p - o)[:, 2] >= 0.5 * np.sin(np.radians(15)) - 1e-12).all()
    look = acts.T_world_sensor[:, :3, 2]
    assert np.allclose(look, (o - p) / 0.5)
    R = acts.T_world_sensor[:, :3, :3]
    assert np.allclose(R.transpose(0, 2, 1) @ R, np.eye(3), atol=1e-9) and np.allclose(np.linalg.det(R), 1)


def test_feasibility_hook_filters_candidates():
    box = OrientedBox.from_aabb([0, 0, 0], [0.1, 0.1, 0.1])
    calls = []

    def only_positive_x(T):
        calls.append(T.shape)
        return T[:, 0, 3] > 0.05

    acts = sample_touch_actions(box, 50, seed=0, feasible=only_positive_x)
    assert len(acts) == 50 and (acts.T_world_sensor[:, 0, 3] > 0.05).all() and calls
    reach = ReachFeasibility([0.05, 0.05, 0.05], max_reach=0.45)
    views = sample_view_actions([0.05, 0.05, 0.05], 0.5, 10, seed=0, feasible=reach, max_rounds=3)
    assert len(views) == 0  # every viewpoint is 0.5 m away, out of reach
    with pytest.raises(ValueError, match="feasible"):
        sample_touch_actions(box, 5, feasible=lambda T: np.ones(3, bool))


def test_bad_input_raises_value_error():
    box = OrientedBox.from_aabb([0, 0, 0], [0.1, 0.1, 0.1])
    with pytest.raises(ValueError, match="extents"):
        OrientedBox(np.eye(4), [0.1, 0.0, 0.1])
    with pytest.raises(ValueError, match="T_world_box"):
        OrientedBox(np.ones((4, 4)), [0.1, 0.1, 0.1])
    with pytest.raises(ValueError, match="n"):
        sample_touch_actions(box, 0)
    with pytest.raises(ValueError, match="standoff"):
        sample_touch_actions(box, 3, standoff=-1.0)
    with pytest.raises(ValueError, match="height_range"):
        sample_pinch_actions(box, 3, height_range=(0.9, 0.2))
    with pytest.raises(ValueError, match="radius"):
        sample_view_actions([0, 0, 0], 0.0, 3)
    with pytest.raises(ValueError, match="p_view"):
        view_rotation([[0.0, 0.0, 0.0]], [0.0, 0.0, 0.0])
    with pytest.raises(ValueError, match="max_rounds"):
        sample_touch_actions(box, 3, max_rounds=0)
    with pytest.raises(ValueError, match="max_reach"):
        ReachFeasibility([0, 0, 0], max_reach=0.1, min_reach=0.2)
    far = np.eye(4)[None].repeat(2, 0)
    far[1, :3, 3] = [100.0, 0.0, 0.0]
    assert ReachFeasibility([0, 0, 0], max_reach=np.inf, min_reach=0.3)(far).tolist() == [False, True]


def test_box_and_sampler_input_is_named():
    pts = [[0, 0, 0], [0.1, 0.1, 0.1]]
    for bad in (np.nan, -0.01):
        with pytest.raises(ValueError, match="margin"):
            OrientedBox.from_points(pts, margin=bad)
    with pytest.raises(ValueError, match="points: all 2 points coincide"):
        OrientedBox.from_points([[0, 0, 0], [0, 0, 0]])
    assert np.allclose(OrientedBox.from_points([[0, 0, 0], [0, 0, 0]], margin=0.01).extents, 0.02)
    with pytest.raises(ValueError, match="lower"):
        OrientedBox.from_aabb([0, 0, np.nan], [1, 1, 1])
    with pytest.raises(ValueError, match="box: expected an OrientedBox"):
        sample_touch_actions(None, 3)
    with pytest.raises(ValueError, match="box: expected an OrientedBox"):
        sample_pinch_actions(np.eye(4), 3)
    # a seed works like a Generator
    np.testing.assert_allclose(marsaglia_sphere(5, 3), marsaglia_sphere(5, np.random.default_rng(3)))
