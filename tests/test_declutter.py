"""Declutter graph (thesis 5.2.2): Definition 1 overlap (exact rotated-rectangle IoU), Definition 2 proximity,
eq. 5.1 edge weights, eq. 5.2 actions, the push direction, depth-first traversal, and a pybullet scene."""

import json

import numpy as np
import pytest
import trimesh

from vtlearn.runtime.declutter import (
    DeclutterGraph,
    GraspAction,
    MinAreaRect,
    PushAction,
    action_kind,
    clip_convex_polygon,
    edge_weight,
    grasp_quality,
    instance_clouds_from_rgbd,
    min_area_rect,
    occupancy_masks,
    polygon_area,
    proximity,
    push_direction,
    rect_iou,
    segmented_cloud,
)
from vtlearn.runtime.runtime_bench import declutter_figure, singulated_within


def box_cloud(cx, cy, sx, sy, h=0.04, yaw=0.0, spacing=0.002):
    """Points on the top face (at height h) of an sx x sy box centred at (cx, cy), rotated by yaw."""
    u = np.linspace(-sx / 2, sx / 2, int(round(sx / spacing)) + 1)
    v = np.linspace(-sy / 2, sy / 2, int(round(sy / spacing)) + 1)
    U, V = np.meshgrid(u, v)
    c, s = np.cos(yaw), np.sin(yaw)
    x, y = cx + c * U - s * V, cy + s * U + c * V
    return np.stack([x.ravel(), y.ravel(), np.full(U.size, h)], axis=1)


def inside_rect(rect, xy):
    u, v = rect.axes
    d = xy - rect.center
    return (np.abs(d @ u) <= rect.size[0] / 2) & (np.abs(d @ v) <= rect.size[1] / 2)


# ------------------------------------------------------------------------- Definition 1: overlap
def test_rect_iou_of_two_axis_aligned_squares_is_exact():
    a = min_area_rect(box_cloud(0.0, 0.0, 0.04, 0.04))
    b = min_area_rect(box_cloud(0.02, 0.01, 0.04, 0.04))
    np.testing.assert_allclose(a.center, [0, 0], atol=1e-12)
    np.testing.assert_allclose(sorted(a.size), [0.04, 0.04], atol=1e-12)
    inter = 0.02 * 0.03
    assert abs(rect_iou(a, b) - inter / (2 * 0.04**2 - inter)) < 1e-9
    assert rect_iou(a, a) == pytest.approx(1.0, abs=1e-12)
    far = min_area_rect(box_cloud(0.5, 0.0, 0.04, 0.04))
    assert rect_iou(a, far) == 0.0


def test_min_area_rect_recovers_a_rotated_box():
    rect = min_area_rect(box_cloud(0.1, -0.2, 0.06, 0.02, yaw=0.3))
    np.testing.assert_allclose(rect.center, [0.1, -0.2], atol=1e-12)
    np.testing.assert_allclose(rect.size, [0.06, 0.02], atol=1e-12)
    assert rect.angle == pytest.approx(0.3, abs=1e-12)
    assert polygon_area(rect.corners) == pytest.approx(0.06 * 0.02, rel=1e-9)
    # the long axis is undirected: yaw 0.3 + pi is the same rectangle
    assert min_area_rect(box_cloud(0, 0, 0.06, 0.02, yaw=0.3 + np.pi)).angle == pytest.approx(0.3, abs=1e-9)
    flat = min_area_rect(np.array([[0.0, 0.0, 0.0], [0.01, 0.01, 0.0], [0.03, 0.03, 0.0]]))
    assert flat.size[1] == 0.0 and flat.size[0] == pytest.approx(0.03 * np.sqrt(2))


def test_rotated_rect_iou_matches_a_fine_raster():
    a = MinAreaRect(np.array([0.0, 0.0]), (0.08, 0.03), 0.4)
    b = MinAreaRect(np.array([0.015, 0.01]), (0.06, 0.04), -0.7)
    g = np.linspace(-0.06, 0.06, 1500)
    X, Y = np.meshgrid(g, g)
    xy = np.stack([X.ravel(), Y.ravel()], axis=1)
    ia, ib = inside_rect(a, xy), inside_rect(b, xy)
    raster = (ia & ib).sum() / (ia | ib).sum()
    assert 0.1 < raster < 0.9
    assert rect_iou(a, b) == pytest.approx(raster, abs=2e-3)
    assert rect_iou(a, b) == pytest.approx(rect_iou(b, a), abs=1e-12)


def test_clip_convex_polygon_hand_case():
    square = np.array([[0, 0], [2, 0], [2, 2], [0, 2]], dtype=float)
    diamond = np.array([[1, -0.5], [2.5, 1], [1, 2.5], [-0.5, 1]])  # |x - 1| + |y - 1| <= 1.5
    inter = clip_convex_polygon(square, diamond[::-1])  # clockwise input is accepted too
    assert polygon_area(inter) == pytest.approx(4.0 - 4 * 0.125)  # the square less four corner triangles
    assert len(inter) == 8
    assert len(clip_convex_polygon(square, square + 5)) == 0


# ---------------------------------------------------------------------- Definition 2: proximity
def test_proximity_of_two_boxes_a_known_gap_apart():
    a = box_cloud(0.0, 0.0, 0.04, 0.04)
    b = box_cloud(0.04 + 0.017, 0.005, 0.04, 0.04)  # facing sides 0.017 m apart
    assert abs(proximity(a, b) - 0.017) <= 0.004
    assert proximity(a, box_cloud(0.03, 0.0, 0.04, 0.04)) == 0.0  # overlapping footprints


def test_occupancy_masks_fill_sparse_points():
    grid, masks = occupancy_masks({3: box_cloud(0.0, 0.0, 0.04, 0.04, spacing=0.006)}, cell=0.004)
    area = masks[3].sum() * grid.cell**2
    assert 0.8 * 0.04**2 < area < 1.4 * 0.04**2
    assert not masks[3][0].any() and not masks[3][:, -1].any()  # a free border


# ----------------------------------------------------------------------------- eq. 5.1 and 5.2
def test_edge_weight_eq_5_1_branches():
    assert edge_weight(0.3, 0.0) == (0.3, "overlap")
    w, kind = edge_weight(0.02, 0.01)
    assert kind == "proximity" and w == pytest.approx(100.0)
    assert edge_weight(0.05, 0.01)[1] == "proximity"  # IoU = mu_o is not an overlap
    assert edge_weight(0.0, 0.0, d_floor=0.004) == (pytest.approx(250.0), "proximity")  # touching: 1/cell
    assert edge_weight(0.0, 0.05) == (0.0, None)
    assert edge_weight(0.0, 0.05, mu_d=0.1)[1] == "proximity"
    assert edge_weight(0.0, np.inf) == (0.0, None)


def test_action_kind_eq_5_2():
    assert action_kind(0.1) == "grasp" and action_kind(0.5) == "grasp"
    assert action_kind(0.0999) == "push"
    assert action_kind(0.3, mu_q=0.4) == "push"


def test_graph_edge_action_follows_grasp_quality_threshold():
    clouds = {1: box_cloud(0.0, 0.0, 0.05, 0.05), 2: box_cloud(0.05, 0.0, 0.03, 0.05)}
    graph = DeclutterGraph.build(clouds, 1, grasp_quality={2: 0.11})
    action = graph.next_action()
    assert isinstance(action, GraspAction) and action.object_id == 2 and action.quality == 0.11
    np.testing.assert_allclose(action.p_grasp, [0.05, 0.0, 0.02], atol=1e-12)  # half the 4 cm height
    assert abs(np.cos(action.alpha_grasp)) == pytest.approx(1.0)  # jaws close across the 3 cm side (x)
    assert action.width == pytest.approx(0.03)
    graph = DeclutterGraph.build(clouds, 1, grasp_quality=lambda k, pts: 0.09)
    assert isinstance(graph.next_action(), PushAction)


def test_grasp_quality_width_score_times_clearance():
    narrow = box_cloud(0.0, 0.0, 0.02, 0.06)
    assert grasp_quality(narrow) == pytest.approx(1 - 0.02 / 0.08)  # nothing around: clearance 1
    assert grasp_quality(box_cloud(0.0, 0.0, 0.09, 0.12)) == 0.0  # wider than the opening
    # a wall along one side fills one fingertip footprint: clearance 1/2
    wall = box_cloud(0.01 + 0.02, 0.0, 0.04, 0.2)  # x in [0.01, 0.05]: over the +x fingertip
    assert grasp_quality(narrow, [wall]) == pytest.approx(0.5 * (1 - 0.02 / 0.08), abs=0.02)


# ---------------------------------------------------------------------------------- push action
def test_push_direction_weights_closer_neighbours_more():
    d = push_direction([0.0, 0.0], [[0.1, 0.0], [0.0, 0.2]])
    # w = (1/0.1, 1/0.2) / sum = (2/3, 1/3) on the unit vectors +x and +y
    np.testing.assert_allclose(d, -np.array([2.0, 1.0, 0.0]) / np.sqrt(5.0), atol=1e-12)
    # neighbours that cancel: push away from the target instead
    d = push_direction([0.0, 0.0], [[0.1, 0.0], [-0.1, 0.0]], away_from=[0.0, -0.1])
    np.testing.assert_allclose(d, [0.0, 1.0, 0.0], atol=1e-12)


def test_push_away_from_a_single_neighbour_on_plus_x():
    obj = box_cloud(0.0, 0.0, 0.05, 0.05)
    target = box_cloud(0.025 + 0.025 + 0.02, 0.0, 0.04, 0.04)  # 2.5 cm gap: room for a 2 cm fingertip
    graph = DeclutterGraph.build({1: target, 2: obj}, 1, grasp_quality={2: 0.0})
    push = graph.next_action()
    assert isinstance(push, PushAction) and push.object_id == 2
    np.testing.assert_allclose(push.d_push, [-1.0, 0.0, 0.0], atol=1e-12)
    assert push.p_push[0] == pytest.approx(0.025, abs=1e-9)  # on the +x side, behind the object
    assert push.p_push[1] == pytest.approx(0.0, abs=1e-9)  # through the centre, as the thesis intends
    assert push.fingertip[0] == pytest.approx(0.035, abs=1e-9) and push.overlap == 0.0
    np.testing.assert_allclose(push.p_end, push.p_push + [-0.1, 0.0, 0.0], atol=1e-12)


def test_push_point_avoids_an_object_behind_the_centre():
    # a 1 cm cube sits in the gap right behind the centre of object 2's +x side: all neighbours lie on the
    # +x axis, so d_push stays -x, but the centred fingertip would land on the cube
    clouds = {1: box_cloud(0.065, 0.0, 0.04, 0.04), 2: box_cloud(0.0, 0.0, 0.04, 0.04)}
    clouds[3] = box_cloud(0.035, 0.0, 0.01, 0.01)
    graph = DeclutterGraph.build(clouds, 1, grasp_quality={2: 0.0, 3: 1.0})
    (push,) = [e.action for e in graph.edges if e.child == 2]
    np.testing.assert_allclose(push.d_push, [-1.0, 0.0, 0.0], atol=1e-12)
    assert push.p_push[0] == pytest.approx(0.02, abs=1e-9) and abs(push.p_push[1]) >= 0.01
    assert push.overlap < 0.1


# ------------------------------------------------------------------------ graph and traversal
def clutter():
    """Target 1; object 2 at +x (8 mm gap) cluttered by 4 further out; object 3 at -x (12 mm gap); 5 far."""
    return {
        1: box_cloud(0.0, 0.0, 0.06, 0.06),
        2: box_cloud(0.03 + 0.008 + 0.02, 0.0, 0.04, 0.04),
        3: box_cloud(-0.03 - 0.012 - 0.02, 0.0, 0.04, 0.04),
        4: box_cloud(0.078 + 0.01 + 0.02, 0.0, 0.04, 0.04),  # 1 cm beyond 2, 5.8 cm from 1
        5: box_cloud(0.3, 0.3, 0.05, 0.05),
    }


def test_graph_singulates_the_deepest_leaf_first():
    clouds = clutter()
    graph = DeclutterGraph.build(clouds, 1)
    assert {(e.parent, e.child) for e in graph.edges} == {(1, 2), (1, 3), (2, 4)}
    assert set(graph.nodes) == {1, 2, 3, 4} and graph.nodes[4].depth == 2
    assert [e.child for e in graph.children(1)] == [2, 3]  # 1/0.008 before 1/0.012
    assert graph.children(1)[0].weight == pytest.approx(1 / 0.008, rel=1e-6)
    assert all(e.kind == "proximity" for e in graph.edges)
    order = []
    while not graph.is_done:
        action = graph.next_action()
        order.append(action.object_id)
        del clouds[action.object_id]
        graph = DeclutterGraph.build(clouds, 1)
    assert order == [4, 2, 3]
    assert graph.next_action() is None and graph.next_edge() is None


def test_overlap_edge_for_stacked_objects():
    clouds = {1: box_cloud(0.0, 0.0, 0.06, 0.06), 2: box_cloud(0.02, 0.0, 0.06, 0.04, h=0.08)}
    (edge,) = DeclutterGraph.build(clouds, 1).edges
    assert edge.kind == "overlap" and edge.weight == pytest.approx(edge.iou) and edge.iou > 0.05
    assert edge.distance == 0.0


def test_isolated_target_is_done():
    graph = DeclutterGraph.build({7: box_cloud(0, 0, 0.05, 0.05), 8: box_cloud(0.2, 0, 0.05, 0.05)}, 7)
    assert graph.is_done and graph.next_action() is None and graph.edges == []
    assert graph.to_dict()["outside_graph"] == [8]


def test_to_dict_is_json_and_figures_draw(tmp_path):
    clouds = clutter()
    graph = DeclutterGraph.build(clouds, 1, grasp_quality={2: 0.5, 3: 0.5, 4: 0.0, 5: 0.5})
    d = json.loads(json.dumps(graph.to_dict(), allow_nan=False))
    assert d["next_action"]["kind"] == "push" and d["next_action"]["object_id"] == 4
    assert len(d["edges"]) == 3 and d["params"]["mu_d"] == 0.03
    path = graph.figure(tmp_path / "declutter.png")
    assert path.stat().st_size > 10_000
    import matplotlib.pyplot as plt

    ax = DeclutterGraph.build(clouds, 1).plot()  # a grasp as the next action
    assert "grasp" in ax.get_title()
    plt.close(ax.figure)


# ------------------------------------------------------------------------------ segmented clouds
def test_instance_clouds_from_rgbd_hand_case():
    pts = np.arange(27, dtype=float).reshape(9, 3)
    ids = np.array([-1, 0, 0, 0, 5, 5, 5, 5, 7])
    out = instance_clouds_from_rgbd(pts, ids, exclude=(0,), min_points=3)
    assert list(out) == [5]
    np.testing.assert_array_equal(out[5], pts[4:8])


def test_pybullet_scene_end_to_end():
    from vtlearn.sim_data.camera import DepthNoise, RGBDCamera, viewpoint_rotation
    from vtlearn.sim_data.scene import Scene

    layout = {  # name: (extents, xy); 1 cm between target and neighbour, the far box 15 cm away
        "target": ((0.06, 0.06, 0.05), (0.0, 0.0)),
        "neighbour": ((0.04, 0.04, 0.04), (0.06, 0.0)),
        "far": ((0.04, 0.04, 0.06), (-0.05, 0.15)),
    }
    with Scene() as scene:
        body = {}
        for name, (ext, (x, y)) in layout.items():
            T = np.eye(4)
            T[:3, 3] = [x, y, ext[2] / 2]
            body[name] = scene.add_mesh(trimesh.creation.box(extents=ext), T_world_object=T)
        camera = RGBDCamera(320, 240, fov_y_deg=60.0, noise=DepthNoise.off())
        T_world_camera = np.eye(4)
        T_world_camera[:3, 3] = [0.0, 0.05, 0.55]
        T_world_camera[:3, :3] = viewpoint_rotation(T_world_camera[:3, 3], [0.0, 0.05, 0.0])
        frame = camera.render(scene, T_world_camera, np.random.default_rng(0))
        points, seg_ids = segmented_cloud(camera, frame)
        table = scene.table_id
    clouds = instance_clouds_from_rgbd(points, seg_ids, exclude=(table,))
    assert set(clouds) == set(body.values())
    graph = DeclutterGraph.build(clouds, body["target"])
    assert [(e.parent, e.child) for e in graph.edges] == [(body["target"], body["neighbour"])]
    (edge,) = graph.edges
    assert edge.kind == "proximity" and abs(edge.distance - 0.01) <= 0.004
    assert body["far"] not in graph.nodes
    rect = graph.rects[body["target"]]
    np.testing.assert_allclose(rect.center, [0.0, 0.0], atol=0.004)
    np.testing.assert_allclose(rect.size, [0.06, 0.06], atol=0.006)


# ------------------------------------------------------------------------------------ bad input
def test_bad_input_raises_value_error_naming_the_argument():
    good = {1: box_cloud(0, 0, 0.04, 0.04), 2: box_cloud(0.05, 0, 0.04, 0.04)}
    with pytest.raises(ValueError, match="clouds"):
        DeclutterGraph.build({}, 1)
    with pytest.raises(ValueError, match="target"):
        DeclutterGraph.build(good, 3)
    bad = good[2].copy()
    bad[0, 0] = np.nan
    with pytest.raises(ValueError, match=r"clouds\[2\].*NaN"):
        DeclutterGraph.build({**good, 2: bad}, 1)
    with pytest.raises(ValueError, match=r"clouds\[2\]"):
        DeclutterGraph.build({**good, 2: good[2][:, :2]}, 1)
    with pytest.raises(ValueError, match=r"clouds\[2\]"):
        DeclutterGraph.build({**good, 2: good[2][:2]}, 1)
    with pytest.raises(ValueError, match="cell"):
        DeclutterGraph.build(good, 1, cell=0.0)
    with pytest.raises(ValueError, match="cell"):
        DeclutterGraph.build(good, 1, cell=1e-6)  # too many cells
    with pytest.raises(ValueError, match="mu_d"):
        DeclutterGraph.build(good, 1, mu_d=-0.01)
    with pytest.raises(ValueError, match="grasp_quality"):
        DeclutterGraph.build(good, 1, grasp_quality={3: 0.5})
    with pytest.raises(ValueError, match="grasp_quality"):
        DeclutterGraph.build(good, 1, grasp_quality=0.5)
    with pytest.raises(ValueError, match="fingertip"):
        DeclutterGraph.build(good, 1, fingertip=(0.03, -0.02))
    with pytest.raises(ValueError, match="place_position"):
        DeclutterGraph.build(good, 1, place_position=[0.3, 0.0])
    with pytest.raises(ValueError, match="push_distance"):
        DeclutterGraph.build(good, 1, push_distance=0)
    with pytest.raises(ValueError, match="points_world"):
        instance_clouds_from_rgbd(np.zeros((4, 2)), np.zeros(4, int))
    with pytest.raises(ValueError, match="seg_ids"):
        instance_clouds_from_rgbd(np.zeros((4, 3)), np.zeros(3, int))
    with pytest.raises(ValueError, match="min_points"):
        instance_clouds_from_rgbd(np.zeros((4, 3)), np.zeros(4, int), min_points=1)
    with pytest.raises(ValueError, match="iou"):
        edge_weight(1.5, 0.01)
    with pytest.raises(ValueError, match="distance"):
        edge_weight(0.1, -0.01)
    with pytest.raises(ValueError, match="points"):
        min_area_rect(np.zeros((0, 3)))
    with pytest.raises(ValueError, match="a"):
        rect_iou("rect", min_area_rect(good[1]))
    with pytest.raises(ValueError, match="others"):
        grasp_quality(good[1], [good[2][:1]])
    with pytest.raises(ValueError, match="v"):
        DeclutterGraph.build(good, 1).children(9)


def test_clouds_in_millimetres_are_refused_naming_the_cloud():
    good = {1: box_cloud(0, 0, 0.04, 0.04), 2: box_cloud(0.05, 0, 0.04, 0.04)}
    # the same scene in millimetres used to be refused as a grid too fine for the scene ("use a larger
    # cell"), which points at the wrong argument
    with pytest.raises(ValueError, match=r"^clouds\[1\]: spans .* m, more than the 2 m.*millimetres"):
        DeclutterGraph.build({k: 1000 * v for k, v in good.items()}, 1)
    with pytest.raises(ValueError, match=r"^clouds\[2\]: .*millimetres"):
        occupancy_masks({1: good[1], 2: 1000 * good[2]})
    # a large object in metres is fine
    DeclutterGraph.build({**good, 3: box_cloud(0.5, 0, 0.8, 0.4)}, 1)


# ------------------------------------------------------------------------------ the bench's figure
def _declutter_result():
    """`run_declutter_benchmark`'s result for 3 scenes, two policies, at most 4 actions (hand-made)."""
    def run(scene, policy, done, actions, grasps, unreachable=0):
        return {"scene": scene, "target": "mug", "clutter": ["can"], "policy": policy, "done": done,
                "actions": actions, "grasps": grasps, "pushes": actions - grasps, "unreachable": unreachable,
                "seconds": 1.0}

    runs = [run(0, "graph", True, 0, 0), run(1, "graph", True, 2, 1), run(2, "graph", True, 3, 1),
            run(0, "random", True, 1, 1), run(1, "random", False, 4, 0, 2), run(2, "random", True, 3, 2)]
    summary = {p: {"scenes": 3} for p in ("graph", "random")}
    settings = {"scenes": 3, "n_clutter": 1, "policies": ["graph", "random"], "max_actions": 4, "seed": 0}
    return {"runs": runs, "summary": summary, "settings": settings}


def test_singulated_within_counts_finished_scenes_by_action_budget():
    r = _declutter_result()
    # graph finished after 0, 2 and 3 actions; random after 1 and 3, and failed one scene after 4
    np.testing.assert_allclose(singulated_within(r, "graph"), [1 / 3, 1 / 3, 2 / 3, 1, 1])
    np.testing.assert_allclose(singulated_within(r, "random"), [0, 1 / 3, 1 / 3, 2 / 3, 2 / 3])
    with pytest.raises(ValueError, match="policy: no runs of 'nearest'"):
        singulated_within(r, "nearest")


def test_declutter_figure_draws_a_hand_made_result(tmp_path):
    path = declutter_figure(_declutter_result(), tmp_path / "sub" / "declutter.png")
    assert path == tmp_path / "sub" / "declutter.png" and path.stat().st_size > 10_000
    with pytest.raises(ValueError, match="result: no runs"):
        declutter_figure({**_declutter_result(), "runs": []}, tmp_path / "empty.png")
    assert not (tmp_path / "empty.png").exists()
    # a result without its settings (another bench's JSON, or one from before they were recorded)
    old = {k: v for k, v in _declutter_result().items() if k != "settings"}
    with pytest.raises(ValueError, match=r"^result: no settings; not a `vtlearn bench declutter` result"):
        declutter_figure(old, tmp_path / "old.png")
    with pytest.raises(ValueError, match=r"^result: no settings.max_actions"):
        singulated_within({**old, "settings": {"scenes": 3}}, "graph")
    assert not (tmp_path / "old.png").exists()
