"""Closed-loop active perception in pybullet (vtlearn.active.closed_loop)."""

import numpy as np
import pytest
import torch

from vtlearn.active.actions import OrientedBox, sample_pinch_actions, sample_touch_actions
from vtlearn.active.closed_loop import (
    STRATEGIES,
    Episode,
    TouchWorld,
    choose_action,
    classify_prefixes,
    held_out_objects,
    make_object,
    network_input,
    reconstruct_prefixes,
    run_episode,
)
from vtlearn.active.occupancy import OccupancyGrid
from vtlearn.active.selection import energy_costs
from vtlearn.active.sensors import PinchSensor, Rays, TactileArray
from vtlearn.sim_data.shapes import instance_seed

FAST = dict(n_candidates=8, cells=16)


@pytest.fixture(scope="module")
def glass():
    return held_out_objects(["wineglass"], 1, transparent=True, sections=16)[0]


@pytest.fixture(scope="module")
def mug():
    return held_out_objects(["mug"], 1, transparent=False, sections=16)[0]


def test_held_out_objects_are_unseen_and_filtered(glass, mug):
    assert glass.transparent and not mug.transparent
    train_seeds = {instance_seed(0, "wineglass", i) for i in range(200)}
    assert glass.seed not in train_seeds
    lo, hi = glass.bounds
    assert lo[2] == pytest.approx(0.0, abs=1e-9)  # standing on the table
    assert (hi - lo).max() == pytest.approx(glass.scale_m)
    # the canonical frame is the unit cube of the dataset
    c = glass.to_canonical(glass.surface_world)
    assert np.abs(c).max() <= 0.5 + 1e-6
    np.testing.assert_allclose(glass.from_canonical(c), glass.surface_world, atol=1e-12)


def test_press_reports_taxel_evidence(glass):
    lo, hi = glass.bounds
    centre = (lo + hi) / 2
    T = np.eye(4)  # pad above the glass pressing down (+z of the pad is world -z)
    T[:3, :3] = np.diag([1.0, -1.0, -1.0])
    T[:3, 3] = [centre[0], centre[1], hi[2] + 0.02]
    taxels = TactileArray("xela_4x4", ray_length=0.3).rays(T[None])
    with TouchWorld(glass) as world:
        ranges, hit, pts = world.press(T[None], 0.3)
        assert ranges.shape == hit.shape == (16,)
        assert hit.sum() == len(pts) > 0
        # a hit ray ends at its contact point; free rays end where the pad stopped, before the ray length
        ends = taxels.origins[hit] + ranges[hit, None] * taxels.directions[hit]
        np.testing.assert_allclose(np.sort(ends, axis=0), np.sort(pts, axis=0), atol=1e-6)
        assert (ranges[~hit] < 0.3).all()
        T_away = T.copy()
        T_away[:3, 3] = [centre[0] + 0.5, centre[1], 0.4]  # far to the side: meets nothing but the table
        T_away[:3, :3] = np.diag([1.0, 1.0, 1.0])  # presses up, into the sky
        ranges, hit, pts = world.press(T_away[None], 0.3)
        assert not hit.any() and len(pts) == 0 and np.all(ranges == 0.3)


@pytest.mark.parametrize("strategy", STRATEGIES)
def test_episode_outputs(glass, strategy):
    with TouchWorld(glass) as world:
        ep = run_episode(world, strategy, 4, seed=3, **FAST)
    assert ep.strategy == strategy and ep.n_steps == 4 and len(ep.entropy) == 5
    assert set(ep.kinds) <= {"touch", "pinch"} and ep.kinds[0] == "touch"
    n = ep.n_points()
    assert n[0] == 0 and (np.diff(n) >= 0).all() and n[-1] == len(ep.points)
    assert ep.points.shape == (n[-1], 3) and ep.tactile.all()
    assert ((ep.step >= 0) & (ep.step < 4)).all()
    assert len(ep.prefix(2)) == n[2] and len(ep.prefix(4, "visual")) == 0
    assert np.isnan(ep.gains[0])  # the shared random initial touch is not scored
    if strategy == "random_pinch":
        assert ep.kinds[1:] == ["pinch"] * 3  # after the shared touch, pinches only
    if strategy == "active":
        assert all(np.isfinite(g) and g >= 0 for g in ep.gains[1:])
    else:
        assert all(np.isnan(g) for g in ep.gains)
    assert ep.entropy[-1] < ep.entropy[0]
    d = ep.to_dict()
    assert d["n_points"] == n.tolist() and len(d["gains"]) == 4


def test_strategies_share_the_initial_touch(glass):
    with TouchWorld(glass) as world:
        eps = [run_episode(world, s, 2, n_init=1, seed=5, **FAST) for s in STRATEGIES]
    for ep in eps[1:]:
        np.testing.assert_allclose(ep.T_world_sensor[0], eps[0].T_world_sensor[0])
    assert not np.allclose(eps[0].T_world_sensor[1], eps[1].T_world_sensor[1])


def test_views_and_touches_on_opaque_and_transparent(glass, mug):
    with TouchWorld(mug) as world:
        for s in ("active", "random", "uniform"):  # random_pinch has no views
            ep = run_episode(
                world, s, 2, n_views=2, n_init=0, pinch=False, n_view_candidates=4, seed=1, **FAST
            )
            assert sorted(ep.kinds) == ["touch", "touch", "view", "view"]
            assert len(ep.prefix(4, "visual")) > 0
            assert len(ep.prefix(4, "visual")) + len(ep.prefix(4, "tactile")) == len(ep.points)
    with TouchWorld(glass) as world:  # a transparent object returns no depth
        ep = run_episode(world, "uniform", 1, n_views=2, n_init=0, pinch=False, seed=1, **FAST)
        assert len(ep.prefix(3, "visual")) == 0


def test_auto_gain_mode_uses_the_reconstructor_only_without_views(glass, mug):
    """``gain_mode="auto"``: box fit (the ``reconstructor``) on a touch-only episode, the grid gain with
    views."""
    calls = []

    class Recorder:
        def gains(self, obj, measured, candidates, touch_config, seed=0):
            calls.append(len(measured))
            return np.arange(sum(len(a) for a, _ in candidates), dtype=float)  # the last candidate wins

    with TouchWorld(glass) as world:
        ep = run_episode(world, "active", 3, gain_mode="auto", reconstructor=Recorder(), seed=2, **FAST)
    assert len(calls) == 2 and ep.gains[1:] == [float(FAST["n_candidates"] - 1)] * 2
    calls.clear()
    with TouchWorld(mug) as world:
        ep = run_episode(world, "active", 2, n_views=1, n_init=0, gain_mode="auto", reconstructor=Recorder(),
                         n_view_candidates=4, seed=2, **FAST)
    assert calls == [] and all(g >= 0 for g in ep.gains)  # the grid gain scored every step
    with TouchWorld(mug) as world:  # without a reconstructor "auto" is the grid gain
        ep = run_episode(world, "active", 2, gain_mode="auto", seed=2, **FAST)
    assert all(np.isfinite(g) and g >= 0 for g in ep.gains[1:])


def test_feasibility_hook_constrains_every_sampled_action(mug):
    def top_only(T):  # only pads pressing straight down are reachable
        return np.asarray(T)[:, 2, 2] < -0.99

    with TouchWorld(mug) as world:
        for s in ("active", "random"):
            ep = run_episode(world, s, 4, pinch=False, n_init=1, seed=3, feasible={"touch": top_only}, **FAST)
            assert all(T[2, 2] < -0.99 for T in ep.T_world_sensor)
        # without the hook the same seeds press from the sides too
        ep = run_episode(world, "random", 4, pinch=False, n_init=1, seed=3, **FAST)
        assert any(T[2, 2] > -0.99 for T in ep.T_world_sensor)
        with pytest.raises(ValueError, match="feasible"):
            run_episode(world, "random", 2, pinch=False, feasible=lambda T: np.zeros(len(T), bool), **FAST)
        with pytest.raises(ValueError, match="feasible"):
            run_episode(world, "random", 2, feasible={"grasp": top_only}, **FAST)
        with pytest.raises(ValueError, match="feasible"):
            run_episode(world, "random", 2, feasible=3, **FAST)


def _grid_and_box():
    box = OrientedBox.from_aabb([-0.03, -0.03, 0.0], [0.03, 0.03, 0.1])
    grid = OccupancyGrid(box.center - 0.06, 0.12 / 16, (16, 16, 16))
    # known free space on the +x half: touches from +x gain little there
    o = np.stack([np.full(50, 0.06), np.linspace(-0.05, 0.05, 50), np.full(50, 0.05)], 1)
    d = np.tile([-1.0, 0.0, 0.0], (50, 1))
    grid.insert_rays(o, d, np.full(50, 0.06), np.zeros(50, dtype=bool))
    return grid, box


@pytest.mark.parametrize("transparent", [False, True])
def test_choose_action_picks_highest_gain_over_cost(transparent):
    grid, box = _grid_and_box()
    touch = TactileArray("xela_4x4", ray_length=0.15)
    pinch = PinchSensor("xela_4x4", opening=0.12)
    cands = [(sample_touch_actions(box, 12, seed=0), touch), (sample_pinch_actions(box, 6, seed=1), pinch)]
    for mode in ("raycast", "probabilistic"):
        which, idx, gains = choose_action(grid, cands, transparent, gain_mode=mode)
        # naive reference: score every candidate separately
        ref = []
        for actions, sensor in cands:
            for i in range(len(actions)):
                r = sensor.rays(actions.T_world_sensor[i : i + 1])
                ref.append(
                    grid.expected_information_gain(r.origins, r.directions, r.max_range, mode=mode).sum()
                    if mode == "probabilistic"
                    else grid.expected_information_gain(
                        r.origins, r.directions, r.max_range, np.zeros(len(r), dtype=np.int64), 1, mode=mode
                    )[0]
                )
        np.testing.assert_allclose(gains, ref, rtol=1e-9, atol=1e-12)
        kinds = ["touch"] * 12 + ["pinch"] * 6
        best = int(np.argmax(np.asarray(ref) / energy_costs(kinds, transparent)))
        assert (which, idx) == ((0, best) if best < 12 else (1, best - 12))


def test_bad_input():
    with pytest.raises(ValueError, match="per_category"):
        held_out_objects(["mug"], 0)
    with pytest.raises(ValueError, match="categories"):
        held_out_objects(["teapot"], 1)
    with pytest.raises(ValueError, match="categories"):
        held_out_objects(["can"], 1, transparent=True, max_tries=3)  # cans are never transparent
    obj = make_object("mug", 1, sections=12)
    with TouchWorld(obj) as world:
        with pytest.raises(ValueError, match="strategy"):
            run_episode(world, "greedy", 2)
        with pytest.raises(ValueError, match="n_tactile"):
            run_episode(world, "random", -1)
        with pytest.raises(ValueError, match="n_tactile"):
            run_episode(world, "random", 0, n_views=0)
        with pytest.raises(ValueError, match="n_init"):
            run_episode(world, "random", 2, n_init=3)
        with pytest.raises(ValueError, match="gain_mode"):
            run_episode(world, "active", 2, gain_mode="entropy")
        with pytest.raises(ValueError, match="n_candidates"):
            run_episode(world, "active", 2, n_candidates=1)
        with pytest.raises(ValueError, match="random_pinch"):
            run_episode(world, "random_pinch", 2, pinch=False)
    with pytest.raises(ValueError, match="modality"):
        Episode("random").prefix(1, "sound")
    with pytest.raises(ValueError, match="max_points"):
        network_input(obj, np.zeros((4, 3)), max_points=0)
    grid, _ = _grid_and_box()
    with pytest.raises(ValueError, match="candidates"):
        choose_action(grid, [], False)
    assert isinstance(Rays, type)


def test_network_scoring_of_prefixes(glass):
    from vtlearn.models.actor import ACTOR
    from vtlearn.models.xavtnet import XAVTNet

    torch.manual_seed(0)
    actor = ACTOR(
        num_points=64,
        encoder_channels=(16, 16, 32, 32),
        fc_channels=32,
        deconv_channels=(16, 16, 8, 8),
        deconv_strides=(2, 2, 2, 2, 4),
    ).eval()
    xav = XAVTNet(num_classes=3, global_dim=32, fc_dims=[16, 8], da_method="none").eval()
    with TouchWorld(glass) as world:
        ep = run_episode(world, "random", 3, seed=0, **FAST)
    ks = [0, 1, 3]
    recon, cd = reconstruct_prefixes(actor, glass, ep, ks, max_points=40)
    assert recon[0] is None and np.isnan(cd[0])  # no action, no points
    for k, r, c in zip(ks[1:], recon[1:], cd[1:], strict=True):
        if len(ep.prefix(k)) >= 3:
            assert r.shape == (64, 3) and np.isfinite(c) and c > 0
    probs = classify_prefixes(xav, glass, ep, ks)
    assert probs.shape == (3, 3) and np.isnan(probs[0]).all()
    ok = np.isfinite(probs).all(1)
    np.testing.assert_allclose(probs[ok].sum(1), 1.0, atol=1e-5)
    x = network_input(glass, np.random.default_rng(0).uniform(0, 0.1, (500, 3)), max_points=50)
    assert len(x) == 50
