"""The two-arm robot runtime (vtlearn.runtime.robot): IK feasibility, arm-carried touches, observation,
decluttering, the whole run with models, and the CLI."""

import json

import numpy as np
import pytest

from vtlearn.active.actions import OrientedBox, sample_touch_actions
from vtlearn.active.closed_loop import TouchWorld, make_object
from vtlearn.cli import main
from vtlearn.runtime.declutter import DeclutterGraph
from vtlearn.runtime.robot import (
    ArmTouchWorld,
    IKFeasibility,
    TwoArmRuntime,
    clutter_scene,
    save_report,
    symmetric_rolls,
)
from vtlearn.sim_data.sensors import get_sensor


def _down(xyz, yaw=0.0):
    """A pad pose pressing straight down at ``xyz``, rolled by ``yaw`` about its z-axis."""
    c, s = np.cos(yaw), np.sin(yaw)
    T = np.eye(4)
    T[:3, :3] = np.diag([1.0, -1.0, -1.0]) @ np.array([[c, -s, 0], [s, c, 0], [0, 0, 1.0]])
    T[:3, 3] = xyz
    return T


@pytest.fixture(scope="module")
def scene_objects():
    return clutter_scene(seed=0)


def test_symmetric_rolls():
    assert symmetric_rolls(get_sensor("xela_4x4").taxel_positions()) == (0.0, np.pi / 2, np.pi, -np.pi / 2)
    assert symmetric_rolls(get_sensor("xela_6x4").taxel_positions()) == (0.0, np.pi)
    assert symmetric_rolls(np.array([[0.01, 0.0, 0.0], [0.02, 0.0, 0.0]])) == (0.0,)
    with pytest.raises(ValueError, match="taxels"):
        symmetric_rolls(np.zeros((0, 3)))


def test_ik_feasibility_exact_unreachable_and_rolls():
    with TwoArmRuntime(seed=0) as rt:
        f = rt.touch_feasibility
        arm = rt.tactile_arm
        q_home = arm.q.copy()
        # noiseless: a pose that forward kinematics gives for known joints is reached exactly
        q_known = q_home + np.array([0.2, 0.1, -0.1, 0.2, 0.1, -0.2, 0.3])
        q, ok, pos, ang = f.solve(arm.T_world_pad(q_known))
        assert ok and pos < 1e-4 and ang < 0.05
        np.testing.assert_allclose(arm.q, q_home)  # queries leave the arm where it was
        # 2 m away is out of reach whatever the roll
        assert not f(_down([2.5, 0.0, 0.1])[None])[0]
        # pressing down over the table centre: the tactile arm (facing -x) misses the wrist roll 0 from its
        # rest posture, and reaches the quarter-turn roll of the same touch
        only_zero = IKFeasibility(arm, rolls=(0.0,))
        assert not only_zero(_down([0.0, 0.0, 0.12])[None])[0]
        q, ok, pos, ang = f.solve(_down([0.0, 0.0, 0.12]))
        assert ok and pos < 0.005 and ang < 3.0
        assert f.queries >= 3
        with pytest.raises(ValueError, match="T_world_sensor"):
            f(np.eye(4))
        with pytest.raises(ValueError, match="position_tol"):
            IKFeasibility(arm, position_tol=0.0)
        with pytest.raises(ValueError, match="rolls"):
            IKFeasibility(arm, rolls=())
        with pytest.raises(ValueError, match="arm"):
            IKFeasibility("panda")


def test_arm_touch_gives_the_free_sensor_evidence_in_commanded_order():
    obj = make_object("mug", 3, sections=16)
    with TwoArmRuntime(seed=0) as rt, TouchWorld(obj) as free:
        body = rt.add_object(obj, fixed=True)
        world = ArmTouchWorld(rt, obj, body)
        box = OrientedBox.from_aabb(*obj.bounds)
        cands = sample_touch_actions(box, 12, seed=1).T_world_sensor
        # poses the arm reaches exactly (IK error below 0.1 mm): the touch must be the free sensor's
        exact = [T for T in cands if rt.touch_feasibility.solve(T)[2] < 1e-4]
        assert len(exact) >= 6
        # the top-down touch over the centre is reached only at a quarter-turn roll: the evidence must
        # still come back in the taxel order of the commanded pose
        top = _down(box.center + [0.0, 0.0, box.extents[2] / 2 + 0.02])
        assert rt.touch_feasibility.solve(top)[2] < 1e-4
        for T in [*exact, top]:
            r_arm, h_arm, pts_arm = world.press(T[None], 0.2)
            r_free, h_free, pts_free = free.press(T[None], 0.2)
            np.testing.assert_allclose(r_arm, r_free, atol=1e-6)
            np.testing.assert_array_equal(h_arm, h_free)
            assert len(pts_arm) == len(pts_free)
        assert world.unreached == 0
        assert h_free.any()  # the top touch lands on the mug
        with pytest.raises(ValueError, match="pinch"):
            world.press(np.stack([top, top]), 0.2)


def test_observe_detects_transparency_and_finds_footprints(scene_objects):
    target, clutter = scene_objects
    with TwoArmRuntime(seed=0) as rt:
        tb = rt.add_object(target, fixed=True)
        ids = [rt.add_object(c) for c in clutter]
        obs = rt.observe()
        assert obs.transparent[tb] and target.transparent
        assert not any(obs.transparent[i] for i in ids)
        for body, obj in zip([tb, *ids], [target, *clutter], strict=True):
            true_centre = obj.bounds.mean(0)[:2]
            np.testing.assert_allclose(obs.clouds[body][:, :2].mean(0), true_centre, atol=0.015)
        assert obs.depth_valid[tb] < 0.5 and min(obs.depth_valid[i] for i in ids) > 0.9


def test_declutter_pushes_leaf_first_then_finishes(scene_objects):
    target, clutter = scene_objects  # the last clutter object stands behind the first one (a chain)
    with TwoArmRuntime(seed=0) as rt:
        tb = rt.add_object(target, fixed=True)
        ids = [rt.add_object(c) for c in clutter]
        rt.scene.step(120)
        first = DeclutterGraph.build(rt.observe().clouds, tb)
        assert {e.child for e in first.children(tb)} == set(ids[:-1])
        assert [e.child for e in first.children(ids[0])] == [ids[-1]]
        T_target = rt.scene.T_world_object(tb)
        calls = []
        actions, done = rt.declutter(tb, max_actions=8, progress=lambda *a: calls.append(a))
        assert done and 1 <= len(actions) <= 8
        assert calls == [(k, 8) for k in range(1, len(actions) + 1)]  # one report per executed action
        assert actions[0]["object_id"] == ids[-1]  # the deepest leaf goes first
        assert all(a["kind"] == "push" and a["reachable"] and a["contact"] for a in actions)
        assert {a["arm"] for a in actions} <= {"tactile", "vision"}
        np.testing.assert_allclose(rt.scene.T_world_object(tb), T_target)  # the target is never moved
        assert DeclutterGraph.build(rt.observe().clouds, tb).is_done


def test_declutter_grasps_place_objects_out_of_the_way(scene_objects):
    target, clutter = scene_objects
    with TwoArmRuntime(seed=0) as rt:
        tb = rt.add_object(target, fixed=True)
        ids = [rt.add_object(c) for c in clutter]
        actions, done = rt.declutter(tb, max_actions=6, mu_q=0.0)  # every action a grasp
        assert done and {a["kind"] for a in actions} == {"grasp"}
        for a in actions:
            assert a["reachable"]
            xy = rt.scene.T_world_object(int(a["object_id"]))[:2, 3]
            assert abs(xy[1]) > 0.4  # at a place position, beside the table centre
        assert set(ids) - {a["object_id"] for a in actions} <= {ids[-1]}
        with pytest.raises(ValueError, match="place_position"):
            rt.declutter(tb, place_position=[0, 0, 0])
        with pytest.raises(ValueError, match="target"):
            rt.declutter(999)


def test_declutter_policies_and_bench(tmp_path, capsys):
    from vtlearn.runtime.runtime_bench import run_declutter_benchmark

    r = run_declutter_benchmark(scenes=1, n_clutter=2, max_actions=4, seed=3)
    assert [x["policy"] for x in r["runs"]] == ["graph", "nearest", "random"]
    assert all(x["scene"] == 0 and x["actions"] <= 4 for x in r["runs"])
    assert set(r["summary"]) == {"graph", "nearest", "random"}
    for bad, match in (
        (dict(scenes=0), "scenes"),
        (dict(n_clutter=0), "n_clutter"),
        (dict(policies=["x"]), "policies"),
    ):
        with pytest.raises(ValueError, match=match):
            run_declutter_benchmark(**bad)
    out = tmp_path / "d.json"
    assert (
        main(
            [
                "bench",
                "declutter",
                "--scenes",
                "1",
                "--clutter",
                "1",
                "--policies",
                "graph",
                "--json",
                str(out),
            ]
        )
        == 0
    )
    assert json.loads(out.read_text())["summary"]["graph"]["scenes"] == 1
    assert "Decluttering, 1 scenes" in capsys.readouterr().out
    with TwoArmRuntime(seed=0) as rt:
        body = rt.add_object(make_object("mug", 3, sections=16), fixed=True)
        with pytest.raises(ValueError, match="policy"):
            rt.declutter(body, policy="farthest")


def test_two_arm_articulation_detection():
    import pybullet as p

    from vtlearn.sim_data.articulated import make_articulated

    with TwoArmRuntime(seed=0) as rt:
        n_bodies = p.getNumBodies(physicsClientId=rt.scene.client)
        r = rt.detect_articulation(make_articulated("drawer", 0), np.eye(4), tracker="truth")
        assert r["joint_type"] == "prismatic" and r["explored"] and r["unreachable"] is None
        # the thesis's hold-pull: the camera robot holds, the tactile robot pulls
        assert ["vision", "tactile"] in [a["arms"] for a in r["actions"] if a["kind"] == "hold_pull"]
        r = rt.detect_articulation(make_articulated("dishwasher", 0), np.eye(4), tracker="truth")
        assert r["joint_type"] == "revolute" and all(a["kind"] == "push" for a in r["actions"])
        # a push at the small glasses' temple is out of both arms' reach: detection stops and says so
        r = rt.detect_articulation(make_articulated("glasses", 0), np.eye(4), tracker="truth")
        assert r["joint_type"] is None and r["unreachable"] == "push" and r["actions"][-1]["arms"] == [None]
        assert p.getNumBodies(physicsClientId=rt.scene.client) == n_bodies  # each object was removed again
        with pytest.raises(ValueError, match="tracker"):
            rt.detect_articulation(make_articulated("drawer", 0), np.eye(4), tracker="vicon")


@pytest.fixture(scope="module")
def tiny_models(tmp_path_factory):
    from vtlearn.pipeline import run_quickstart, tiny_quickstart_config

    out = tmp_path_factory.mktemp("qs")
    run_quickstart(out, tiny_quickstart_config(), stop_after="train")
    return out


def test_run_with_checkpoints_perceives_and_reports(tiny_models, tmp_path):
    target = make_object("wineglass", 11, sections=16)
    with TwoArmRuntime.from_checkpoints(
        tiny_models / "actor.ckpt",
        tiny_models / "xavtnet.ckpt",
        tiny_models / "data" / "crossmodal" / "manifest.json",
        seed=1,
    ) as rt:
        tb = rt.add_object(target, fixed=True)
        report = rt.run(tb, n_touches=5, n_candidates=8, cells=16, stiqf_restarts=0)
    assert report.declutter_done and report.declutter_actions == []
    assert report.episode.n_steps == 5 + (0 if report.transparent_detected else 3)
    assert report.transparent_detected == target.transparent
    s = report.perception
    assert s["true_category"] == "wineglass" and s["predicted_category"] in ("wineglass", "mug")
    assert np.isfinite(s["chamfer_mm"]) and np.isfinite(s["adi_cm"])
    assert report.ik_queries > 0 and report.unreached_touches == 0
    d = json.loads(save_report(report, tmp_path).read_text())
    assert d["episode"]["kinds"] == report.episode.kinds and "arrays" not in d


def test_class_names_come_from_the_xavtnet_checkpoint(tiny_models):
    names = json.loads((tiny_models / "data" / "crossmodal" / "manifest.json").read_text())["class_names"]
    with TwoArmRuntime.from_checkpoints(None, tiny_models / "xavtnet.ckpt", seed=0) as rt:
        assert rt.class_names == names
    # a checkpoint error names the runtime's argument: the ACTOR checkpoint given as the xAVTNet one
    with pytest.raises(ValueError, match="^xavtnet_ckpt: "):
        TwoArmRuntime.from_checkpoints(None, tiny_models / "actor.ckpt")
    with pytest.raises(FileNotFoundError, match="^actor_ckpt: "):
        TwoArmRuntime.from_checkpoints(tiny_models / "none.ckpt", None)


def test_cli_runtime_explores_without_models(tmp_path, tiny_models, capsys):
    out = tmp_path / "rt"
    args = ["runtime", "--out", str(out), "--n-touches", "2", "--n-candidates", "4", "--max-declutter", "1"]
    args += ["--strategy", "random"]
    assert main(args) == 0
    d = json.loads((out / "runtime.json").read_text())
    assert d["perception"] == {} and len(d["episode"]["kinds"]) == 2
    assert (out / "declutter.png").stat().st_size > 0 and (out / "scene.png").stat().st_size > 0
    capsys.readouterr()
    assert main([*args, "--actor", str(tiny_models / "actor.ckpt")]) == 2
    assert "--actor, --xavtnet: give both" in capsys.readouterr().err
    assert main([*args, "--models", str(tmp_path / "none")]) == 2
    assert "--models: no directory" in capsys.readouterr().err


def test_bad_input(scene_objects):
    target, _ = scene_objects
    with pytest.raises(ValueError, match="class_names"):
        TwoArmRuntime(xavtnet=object())
    with pytest.raises(ValueError, match="camera_height"):
        TwoArmRuntime(camera_height=2.0)
    with pytest.raises(ValueError, match="clutter_categories"):
        clutter_scene("mug", ["mug"])
    with pytest.raises(ValueError, match="clutter_categories"):
        clutter_scene("mug", ["teapot"])
    with pytest.raises(ValueError, match="gap"):
        clutter_scene("mug", ["can"], gap=-0.01)
    with TwoArmRuntime(seed=0) as rt:
        with pytest.raises(ValueError, match="obj"):
            rt.add_object("mug")
        free = rt.add_object(target, fixed=False)
        with pytest.raises(ValueError, match="target"):
            rt.explore(free, 2)
        fixed = rt.add_object(make_object("can", 3, sections=12), fixed=True)
        with pytest.raises(ValueError, match="gain_mode"):  # box fit needs ACTOR
            rt.explore(fixed, 2, gain_mode="box_fit")
        with pytest.raises(ValueError, match="max_actions"):
            rt.declutter(free, max_actions=-1)
        for bad in ((np.nan, 0.0), (0.1,), "xy"):
            with pytest.raises(ValueError, match="center_xy: need an \\(x, y\\) pair"):
                rt.observe(center_xy=bad)
        with pytest.raises(ValueError, match="omega: need a finite number in \\(0, 1\\]"):
            rt.observe(omega=0.0)


def test_bench_runtime_smoke(tmp_path, tiny_models, capsys):
    out = tmp_path / "bench.json"
    args = ["bench", "runtime", "--models", str(tiny_models), "--scenes", "1", "--n-touches", "3"]
    assert main([*args, "--n-candidates", "4", "--json", str(out)]) == 0
    d = json.loads(out.read_text())
    assert set(d["summary"]) == {"active", "random"} and len(d["runs"]) == 2
    a, r = d["runs"]
    # both strategies explore the same decluttered scene
    same = ("scene", "category", "pushes", "grasps", "transparent_detected")
    assert [a[k] for k in same] == [r[k] for k in same]
    assert a["category"] == "wineglass" and a["actions"] == 3 + (0 if a["transparent_detected"] else 3)
    assert 0.0 <= d["summary"]["active"]["success_rate"] <= 1.0 and out.with_suffix(".png").is_file()
    assert d["figure"] == str(out.with_suffix(".png"))
    assert "thesis (real robots)" in capsys.readouterr().out
    # the figure is drawn from the JSON read back too (null for a failed perception), and --figure moves it
    from vtlearn.runtime.runtime_bench import runtime_figure

    d["runs"][0]["adi_cm"] = None
    assert runtime_figure(d, tmp_path / "again.png").stat().st_size > 10_000
    fig = tmp_path / "figs" / "runtime.pdf"
    assert main([*args, "--n-candidates", "4", "--strategies", "random", "--json", str(tmp_path / "b2.json"),
                 "--figure", str(fig)]) == 0
    assert fig.is_file() and not (tmp_path / "b2.png").exists()
    assert json.loads((tmp_path / "b2.json").read_text())["figure"] == str(fig)
    assert main([*args, "--strategies", "greedy", "--json", str(out)]) == 2
    assert "strategies" in capsys.readouterr().err


def test_bench_runtime_bad_input():
    from vtlearn.runtime.runtime_bench import run_runtime_benchmark

    with pytest.raises(ValueError, match="scenes"):
        run_runtime_benchmark(None, None, ["mug"], scenes=0)
    with pytest.raises(ValueError, match="strategies"):
        run_runtime_benchmark(None, None, ["mug"], strategies=[])
    with pytest.raises(ValueError, match="strategies"):  # the tactile arm cannot pinch
        run_runtime_benchmark(None, None, ["mug"], strategies=["random_pinch"])
    with pytest.raises(ValueError, match="class_names"):
        run_runtime_benchmark(None, None, ["teapot"])


def test_class_names_must_match_the_xavtnet_classes(tiny_models):
    # three names for a two-class checkpoint would mislabel every prediction: refused, naming the argument
    n = len(json.loads((tiny_models / "data" / "crossmodal" / "manifest.json").read_text())["class_names"])
    msg = f"^class_names: {n + 1} class names but the xAVTNet checkpoint has {n} classes"
    with pytest.raises(ValueError, match=msg):
        TwoArmRuntime.from_checkpoints(None, tiny_models / "xavtnet.ckpt", [f"c{i}" for i in range(n + 1)])


def test_run_checks_its_exploration_arguments_before_the_arms_move(scene_objects):
    target, clutter = scene_objects
    with TwoArmRuntime(seed=0) as rt:
        tb = rt.add_object(target, fixed=True)
        bodies = [rt.add_object(c) for c in clutter]
        rt.scene.step(120)
        before = np.stack([rt.scene.T_world_object(b) for b in bodies])
        with pytest.raises(ValueError, match="^strategy: expected one of .*no pinch"):
            rt.run(tb, strategy="random_pinch", n_touches=2)
        with pytest.raises(ValueError, match="^n_touches: need an integer >= 1, got 0"):
            rt.run(tb, n_touches=0)
        with pytest.raises(ValueError, match="^n_touches"):
            rt.explore(tb, n_touches=-1)
        # refused before decluttering: no clutter was pushed or grasped
        after = np.stack([rt.scene.T_world_object(b) for b in bodies])
        np.testing.assert_allclose(after, before, atol=1e-6)


def test_detect_articulation_refuses_bad_input_and_leaves_no_body():
    import pybullet as p

    from vtlearn.sim_data.articulated import make_articulated

    drawer = make_articulated("drawer", 0)
    with TwoArmRuntime(seed=0) as rt:
        n_bodies = p.getNumBodies(physicsClientId=rt.scene.client)
        with pytest.raises(ValueError, match="^q: "):  # refused after the object was loaded
            rt.detect_articulation(drawer, np.eye(4), q=[4.0], tracker="truth")
        assert p.getNumBodies(physicsClientId=rt.scene.client) == n_bodies
        with pytest.raises(ValueError, match="^spec: need an ArticulatedSpec"):
            rt.detect_articulation("drawer", np.eye(4), tracker="truth")
        T_mm = np.eye(4)
        T_mm[:3, 3] = [100.0, 0.0, 0.0]  # 10 cm in millimetres
        with pytest.raises(ValueError, match="^T_world_base: .*millimetres"):
            rt.detect_articulation(drawer, T_mm, tracker="truth")
        with pytest.raises(ValueError, match="^max_actions"):
            rt.detect_articulation(drawer, np.eye(4), tracker="truth", max_actions=0)
        assert p.getNumBodies(physicsClientId=rt.scene.client) == n_bodies
