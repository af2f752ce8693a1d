"""Tests for vtlearn.active.exploration: rigid-pad touch simulation and the closed NBT loop."""

import numpy as np
import pytest
import trimesh

from vtlearn.active.actions import OrientedBox
from vtlearn.active.exploration import explore, simulate_touch, uniform_touch_schedule
from vtlearn.active.sensors import Rays, TactileArray


def test_rigid_pad_stops_at_first_contact():
    mesh = trimesh.creation.box(extents=[0.1, 0.1, 0.1])
    mesh.apply_transform(trimesh.transformations.rotation_matrix(0.3, [0, 1, 0]))  # slanted face
    T = np.eye(4)
    T[:3, :3] = [[0, 0, 1], [1, 0, 0], [0, 1, 0]]  # pad z = world +x
    T[:3, 3] = [-0.2, 0.0, 0.0]
    rays = TactileArray("xela_4x4", ray_length=0.3).rays(T)
    ranges, hit = simulate_touch(mesh, rays, compliance=0.002)
    assert 0 < hit.sum() < 16  # the slanted face touches some taxels only
    stop = ranges[hit].min()
    assert (ranges[hit] <= stop + 0.002 + 1e-12).all()
    assert np.allclose(ranges[~hit], stop + 0.002)  # free space only up to where the pad stopped
    away = Rays(np.array([[0.0, 0.5, 0.0]]), np.array([[0.0, 1.0, 0.0]]), np.array([0.2]), np.array([0]), 1)
    r2, h2 = simulate_touch(mesh, away)
    assert not h2.any() and r2[0] == pytest.approx(0.2)


def test_uniform_schedule_cycles_faces():
    box = OrientedBox.from_aabb([0, 0, 0], [0.1, 0.1, 0.2])
    sched = uniform_touch_schedule(box, 12, standoff=0.02)
    assert len(sched) == 12 and sched.face[:5].tolist() == [0, 1, 2, 3, 4]
    assert len({tuple(np.round(p, 6)) for p in sched.T_world_sensor[:, :3, 3]}) == 12


@pytest.mark.parametrize("strategy", ["active", "random", "uniform"])
def test_exploration_loop_reduces_entropy_and_collects_contacts(strategy):
    mesh = trimesh.creation.cylinder(radius=0.03, height=0.1, sections=24)
    mesh.apply_translation([0, 0, 0.05])
    res = explore(mesh, strategy, n_touches=6, n_candidates=20, cells=16, seed=0)
    assert res.entropy.shape == (7,) and res.coverage.shape == (7,)
    assert res.entropy[-1] < res.entropy[0]
    assert (np.diff(res.n_points) >= 0).all() and res.n_points[-1] == len(res.contacts)
    # contact points lie on the cylinder surface
    if len(res.contacts):
        radial = np.linalg.norm(res.contacts[:, :2], axis=1)
        on_side = np.abs(radial - 0.03) < 2e-3
        on_top = np.abs(res.contacts[:, 2] - 0.1) < 1e-6
        assert (on_side | on_top).all()


def test_active_raycast_removes_most_entropy_on_hand_built_scene():
    mesh = trimesh.creation.box(extents=[0.04, 0.04, 0.12])
    mesh.apply_translation([0, 0, 0.06])
    kw = dict(n_touches=8, n_candidates=40, cells=16, n_init=1, seed=1)
    active = explore(mesh, "active", **kw)
    random = explore(mesh, "random", **kw)
    assert active.entropy[-1] < random.entropy[-1]


def test_bad_input_raises_value_error():
    mesh = trimesh.creation.box(extents=[0.1, 0.1, 0.1])
    with pytest.raises(ValueError, match="strategy"):
        explore(mesh, "greedy")
    with pytest.raises(ValueError, match="n_touches"):
        explore(mesh, "random", n_touches=0)
    with pytest.raises(ValueError, match="compliance"):
        simulate_touch(mesh, TactileArray().rays(np.eye(4)), compliance=-1.0)


def test_pinch_pads_stop_independently_and_loop_runs_with_pinches():
    mesh = trimesh.creation.box(extents=[0.06, 0.04, 0.1])
    mesh.apply_translation([0.005, 0, 0.05])  # off-centre: the +x pad reaches the surface later
    from vtlearn.active.sensors import PinchSensor

    T = np.eye(4)
    T[:3, :3] = np.diag([1.0, -1.0, -1.0])  # approach down, closing along world x
    T[:3, 3] = [0.0, 0.0, 0.05]
    rays = PinchSensor("xela_4x4", opening=0.14).rays(T)
    ranges, hit = simulate_touch(mesh, rays, compliance=0.001, pad_size=16)
    assert hit.all()
    assert np.allclose(ranges[:16], 0.07 - 0.035)  # +x pad at x = 0.07 meets the face at x = 0.035
    assert np.allclose(ranges[16:], 0.07 - 0.025)  # -x pad at x = -0.07 meets the face at x = -0.025
    with pytest.raises(ValueError, match="pad_size"):
        simulate_touch(mesh, rays, pad_size=5)
    cyl = trimesh.creation.cylinder(radius=0.03, height=0.1, sections=24)
    cyl.apply_translation([0, 0, 0.05])
    for strategy in ("active", "random", "uniform"):
        res = explore(cyl, strategy, n_touches=6, n_candidates=20, cells=16, pinch=True, seed=0)
        assert set(res.chosen_kinds) <= {"touch", "pinch"} and len(res.chosen_kinds) == 6
        assert res.entropy[-1] < res.entropy[0]
    assert "pinch" in explore(cyl, "uniform", n_touches=6, cells=16, pinch=True, seed=0).chosen_kinds


def test_bench_active_exploration_compares_with_random_in_the_same_run(tmp_path, capsys):
    import json

    from vtlearn.cli import main

    out = tmp_path / "ex.json"
    assert main(["bench", "active-exploration", "--objects", "mug", "--seeds", "1", "--touches", "3",
                 "--candidates", "4", "--cells", "10", "--pinch", "--json", str(out)]) == 0
    captured = capsys.readouterr()
    assert "active-exploration episodes" in captured.err  # progress bar
    assert "dH/random@3" in captured.out and f"wrote {out.with_suffix('.png')}" in captured.out
    rows = {r["strategy"]: r for r in json.loads(out.read_text())["rows"]}
    assert rows["random"]["dH/random@3"] == 1.0
    act = rows["active (raycast)"]
    assert act["dH/random@3"] == pytest.approx(act["dH@3 (nats)"] / rows["random"]["dH@3 (nats)"])
    assert act["coverage/random@3"] == pytest.approx(act["coverage@3"] / rows["random"]["coverage@3"])
    assert out.with_suffix(".png").stat().st_size > 0
