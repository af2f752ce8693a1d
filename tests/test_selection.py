"""Tests for vtlearn.active.selection: eq. 5.10 sensor selection and IoU-based transparency detection."""

import numpy as np
import pytest

from vtlearn.active.actions import ActionSet
from vtlearn.active.occupancy import OccupancyGrid, logit
from vtlearn.active.selection import (
    EnergyCosts,
    box_iou_2d,
    cloud_top_down_box,
    detect_transparent,
    energy_costs,
    mask_box,
    next_best_action,
    pixel_box_to_plane,
    pixels_to_plane,
    select_next_best_action,
)
from vtlearn.active.sensors import TactileArray, ToFCamera


def test_select_maximises_gain_over_cost():
    gains = np.array([3.0, 5.0, 4.0])
    assert select_next_best_action(gains) == 1  # eq. 5.9
    assert select_next_best_action(gains, [1.0, 4.0, 1.0]) == 2  # 3, 1.25, 4
    assert select_next_best_action(gains, [1.0, 1.0, 1.0]) == select_next_best_action(gains)


def test_energy_costs_prefer_touch_for_transparent_objects():
    kinds = ["view", "touch", "pinch"]
    opaque = energy_costs(kinds, transparent=False)
    clear = energy_costs(kinds, transparent=True)
    assert opaque[0] < opaque[1] and clear[1] < clear[0]
    # Same information gain for a view and a touch: the view wins on opaque, the touch on transparent.
    gains = np.array([2.0, 2.0, 0.5])
    assert select_next_best_action(gains, opaque) == 0
    assert select_next_best_action(gains, clear) == 1
    custom = EnergyCosts(opaque=(("view", 2.0), ("touch", 1.0), ("pinch", 1.0)))
    assert energy_costs(["view"], False, custom)[0] == 2.0


def test_box_iou_hand_computed():
    assert box_iou_2d([0, 0, 2, 2], [1, 1, 3, 3]) == pytest.approx(1 / 7)
    assert box_iou_2d([0, 0, 1, 1], [0, 0, 1, 1]) == pytest.approx(1.0)
    assert box_iou_2d([0, 0, 1, 1], [2, 2, 3, 3]) == 0.0


def test_mask_box_picks_largest_component():
    m = np.zeros((20, 30), bool)
    m[5:10, 8:20] = True  # object: rows 5..9, columns 8..19
    m[0, 0] = True  # speckle
    assert mask_box(m).tolist() == [8, 5, 20, 10]


def test_pixel_box_to_plane_top_down_camera():
    cam = ToFCamera(width=100, height=100, fov_deg=(90, 90))
    T = np.eye(4)
    T[:3, :3] = np.diag([1.0, -1.0, -1.0])  # looking straight down, image x = world x, image y = -world y
    T[:3, 3] = [0.0, 0.0, 1.0]
    cx = cam.cx
    # A pixel box symmetric about the principal point, 20 px wide: half-width 10 px at f = 50 px and 1 m.
    box = pixel_box_to_plane([cx - 10, cx - 10, cx + 10, cx + 10], cam.intrinsics, T, plane_z=0.0)
    assert np.allclose(box, [-0.2, -0.2, 0.2, 0.2])


def test_pixels_to_plane_hits_known_points_and_rejects_rays_that_miss():
    """Project world points on z = 0.02 into a tilted camera, and back: the exact points return; a ray
    that meets the plane behind the camera, and one parallel to it, are not valid."""
    cam = ToFCamera(width=120, height=90, fov_deg=(70, 55))
    K = cam.intrinsics
    T = np.eye(4)
    a = np.deg2rad(30.0)  # optical axis 30 degrees off straight down, towards +y
    T[:3, :3] = np.diag([1.0, -1.0, -1.0]) @ np.array([[1, 0, 0], [0, np.cos(a), -np.sin(a)],
                                                       [0, np.sin(a), np.cos(a)]])
    T[:3, 3] = [0.1, -0.3, 0.8]
    rng = np.random.default_rng(0)
    world = np.c_[rng.uniform(-0.1, 0.3, (20, 2)), np.full(20, 0.02)]
    cam_pts = (world - T[:3, 3]) @ T[:3, :3]
    assert (cam_pts[:, 2] > 0).all()
    uv = (cam_pts @ K.T)[:, :2] / cam_pts[:, 2:]
    points, valid = pixels_to_plane(uv, K, T, plane_z=0.02)
    assert valid.all()
    np.testing.assert_allclose(points, world, atol=1e-9)
    up = np.eye(4)
    up[:3, :3] = np.diag([1.0, 1.0, 1.0])  # looking straight up from z = 0.5: the plane z = 0 is behind
    up[2, 3] = 0.5
    _, valid = pixels_to_plane([[cam.cx, cam.cy]], K, up, plane_z=0.0)
    assert not valid.any()
    level = np.eye(4)
    level[:3, :3] = np.array([[1.0, 0, 0], [0, 0, 1.0], [0, -1.0, 0]])  # optical axis along world y
    points, valid = pixels_to_plane([[cam.cx, cam.cy]], K, level, plane_z=0.0)
    assert not valid.any() and np.isnan(points).all()
    with pytest.raises(ValueError, match="T_world_camera"):
        pixel_box_to_plane([cam.cx - 5, cam.cy - 5, cam.cx + 5, cam.cy + 5], K, up, plane_z=0.0)
    with pytest.raises(ValueError, match="uv"):
        pixels_to_plane([[np.nan, 1.0]], K, T)
    with pytest.raises(ValueError, match="K"):
        pixels_to_plane(uv, K[:2], T)


def table_and_object(rng, object_points=True):
    table = np.c_[rng.uniform(-0.3, 0.3, (3000, 2)), rng.normal(0, 0.0005, 3000)]
    obj = np.c_[rng.uniform(-0.04, 0.04, (800, 2)) + [0.1, 0.0], rng.uniform(0.01, 0.12, 800)]
    return np.concatenate([table, obj]) if object_points else table


def test_transparency_detection_by_iou():
    rng = np.random.default_rng(0)
    rgb_box = [0.06, -0.04, 0.14, 0.04]
    box = cloud_top_down_box(table_and_object(rng))
    assert np.allclose(box, rgb_box, atol=0.003)
    is_clear, iou = detect_transparent(rgb_box, table_and_object(rng))
    assert not is_clear and iou > 0.9
    # A transparent object leaves only a few stray points in the depth image.
    stray = np.concatenate([table_and_object(rng, False), [[0.1, 0.0, 0.05], [0.11, 0.01, 0.06]]])
    is_clear, iou = detect_transparent(rgb_box, stray)
    assert is_clear and iou == 0.0
    # A partly seen object: the cloud covers a third of the RGB box.
    partial = table_and_object(rng)
    partial = partial[(partial[:, 2] < 0.005) | (partial[:, 0] < 0.087)]
    is_clear, iou = detect_transparent(rgb_box, partial)
    assert is_clear and 0.2 < iou < 0.45


def test_next_best_action_joint_view_and_touch():
    grid = OccupancyGrid([0.0, 0.0, 0.0], 0.02, (10, 10, 10))
    grid.log_odds[:] = logit(0.1192)  # explored and free ...
    grid.log_odds[:, :, 5:] = 0.0  # ... except the upper half
    T_touch = np.eye(4)
    T_touch[:3, 3] = [0.1, 0.1, 0.25]
    T_touch[:3, :3] = np.diag([1.0, -1.0, -1.0])  # pressing down through the unknown half
    T_low = T_touch.copy()
    T_low[:3, 3] = [0.1, 0.1, 0.09]  # pressing down through the explored half only
    T_view = np.eye(4)
    T_view[:3, 3] = [0.1, 0.1, 0.6]
    T_view[:3, :3] = np.diag([1.0, -1.0, -1.0])
    touches = ActionSet("touch", np.stack([T_low, T_touch]), np.zeros((2, 3)), np.array([4, 4]))
    views = ActionSet("view", T_view[None], np.zeros((1, 3)), np.array([-1]))
    cam = ToFCamera(width=32, height=32, fov_deg=(30, 30), stride=16, max_range=1.0)  # 2 x 2 beams
    tactile = TactileArray("xela_4x4", ray_length=0.3)
    sel = next_best_action(grid, [(touches, tactile), (views, cam)], transparent=False)
    assert sel.gains.shape == (3,) and sel.gains[1] > sel.gains[0]
    assert sel.kinds == ["touch", "touch", "view"]
    assert sel.kind == "view"  # more unexplored volume in view, and views are cheap
    sel_t = next_best_action(grid, [(touches, tactile), (views, cam)], transparent=True)
    assert sel_t.kind == "touch" and sel_t.index == 1
    assert np.allclose(sel_t.T_world_sensor, T_touch)


def test_bad_input_raises_value_error():
    with pytest.raises(ValueError, match="gains"):
        select_next_best_action([])
    with pytest.raises(ValueError, match="costs"):
        select_next_best_action([1.0, 2.0], [1.0, 0.0])
    with pytest.raises(ValueError, match="costs"):
        select_next_best_action([1.0, 2.0], [1.0])
    with pytest.raises(ValueError, match="box_a"):
        box_iou_2d([0, 0, -1, 1], [0, 0, 1, 1])
    with pytest.raises(ValueError, match="kind"):
        energy_costs(["wave"], False)
    with pytest.raises(ValueError, match="mask"):
        mask_box(np.zeros((4, 4), bool))
    with pytest.raises(ValueError, match="omega"):
        detect_transparent([0, 0, 1, 1], np.zeros((0, 3)), omega=0.0)
    with pytest.raises(ValueError, match="candidates"):
        next_best_action(OccupancyGrid([0, 0, 0], 0.1, (2, 2, 2)), [])


def test_default_costs_pick_views_for_opaque_and_touches_for_transparent():
    from vtlearn.active.actions import OrientedBox, sample_touch_actions, sample_view_actions

    box = OrientedBox.from_aabb([-0.04, -0.04, 0.0], [0.04, 0.04, 0.15])
    grid = OccupancyGrid.from_bounds(box.center - 0.1, box.center + 0.1, cells_per_axis=32)
    touches = sample_touch_actions(box, 20, seed=0)
    views = sample_view_actions(box.center, 0.5, 5, seed=0)
    cands = [(touches, TactileArray("xela_4x4", ray_length=0.2)), (views, ToFCamera())]
    assert next_best_action(grid, cands, transparent=False).kind == "view"
    assert next_best_action(grid, cands, transparent=True).kind == "touch"


def test_next_best_action_names_bad_grid_and_candidates():
    from vtlearn.active.actions import OrientedBox, sample_touch_actions

    box = OrientedBox.from_aabb([-0.05, -0.05, 0.0], [0.05, 0.05, 0.1])
    grid = OccupancyGrid.from_bounds([-0.1, -0.1, -0.05], [0.1, 0.1, 0.15], cells_per_axis=10)
    touches = sample_touch_actions(box, 4, seed=0)
    with pytest.raises(ValueError, match="grid: expected an OccupancyGrid"):
        next_best_action(None, [(touches, TactileArray())])
    with pytest.raises(ValueError, match=r"candidates\[0\]"):
        next_best_action(grid, [touches])
    with pytest.raises(ValueError, match=r"candidates\[1\]"):
        next_best_action(grid, [(touches, TactileArray()), (TactileArray(), touches)])
    assert next_best_action(grid, [(touches, TactileArray())]).kind == "touch"
