"""Next-best-touch for recognition by expected contact novelty (vtlearn.active.recognition_novelty)."""

import json

import numpy as np
import pytest
import torch

from vtlearn.active.actions import OrientedBox, sample_touch_actions
from vtlearn.active.closed_loop import TouchWorld, held_out_objects, run_episode
from vtlearn.active.recognition_novelty import ExpectedContactNovelty, contact_novelty
from vtlearn.active.sensors import TactileArray
from vtlearn.cli import main
from vtlearn.models.xavtnet import XAVTNet

NAMES = ["mug", "wineglass", "box"]


@pytest.fixture(scope="module")
def mug():
    return held_out_objects(["mug"], 1, transparent=False, sections=16)[0]


@pytest.fixture(scope="module")
def model():
    torch.manual_seed(0)
    return XAVTNet(num_classes=3, global_dim=32, fc_dims=[16, 8], da_method="none").eval()


def _candidates(obj, n, seed=0):
    lo, hi = obj.bounds
    box = OrientedBox.from_aabb(lo - 0.003, hi + 0.003)
    sensor = TactileArray("xela_4x4", ray_length=0.02 + float(box.extents.max()) + 0.01)
    return sensor, sample_touch_actions(box, n, standoff=0.02, seed=seed).T_world_sensor


def test_contact_novelty_hand_case_and_naive_reference():
    P = np.zeros((1, 3))
    Y = np.array([[3.0, 4.0, 0.0], [0.0, 0.0, 1.0]])
    assert contact_novelty(P, Y) == pytest.approx((5.0 + 1.0) / 2)
    assert contact_novelty(P, np.zeros((0, 3))) == 0.0  # a miss adds nothing
    assert contact_novelty(np.zeros((0, 3)), Y) == 1.0  # anything is new while nothing is measured
    rng = np.random.default_rng(0)
    P, Y = rng.normal(size=(17, 3)), rng.normal(size=(5, 3))
    naive = np.mean([min(np.linalg.norm(y - x) for x in P) for y in Y])
    assert contact_novelty(P, Y) == pytest.approx(naive, abs=1e-12)
    assert contact_novelty(Y, Y) == 0.0


def test_contact_novelty_bad_input():
    with pytest.raises(ValueError, match="measured"):
        contact_novelty(np.zeros((4, 2)), np.zeros((1, 3)))
    with pytest.raises(ValueError, match="contacts"):
        contact_novelty(np.zeros((4, 3)), np.array([[0.0, np.nan, 0.0]]))


def test_gains_match_a_naive_loop_and_prefer_unexplored_spots(mug, model):
    sensor, T = _candidates(mug, 8, seed=2)
    gain = ExpectedContactNovelty(model, NAMES, top_m=2)
    for c in range(len(NAMES)):  # every class hypothesis is the object itself (fit_to_box: identity)
        gain.templates._templates[(c, 0)] = mug.mesh
    with TouchWorld(mug) as world:
        cfg = world.sim.config
        touching = [a for a in range(len(T)) if len(world.press(T[a : a + 1], sensor.ray_length)[2]) >= 3]
        assert len(touching) >= 2  # the check is not vacuous
        first = touching[0]
        _, _, P = world.press(T[first : first + 1], sensor.ray_length)
        g = gain.gains(mug, P, sensor, T, cfg)
        assert g.shape == (len(T),)
        hyp = gain.hypotheses(mug, P)
        assert len(hyp) == 2
        naive = np.zeros(len(T))
        for c in hyp:
            for a, y in enumerate(gain.templates.expected_contacts(mug, c, sensor, T, cfg)):
                naive[a] += contact_novelty(mug.to_canonical(P), mug.to_canonical(y)) / len(hyp)
        np.testing.assert_allclose(g, naive, atol=1e-12)
        # the template is the true shape, so pressing the measured spot again is predicted to add nothing
        # new, and another touch that meets the object is preferred
        assert g[first] == pytest.approx(0.0, abs=1e-4)
        assert max(g[a] for a in touching[1:]) > 1e-3
        assert int(np.argmax(g)) != first
        # batched candidates score as one at a time
        single = [gain.gains(mug, P, sensor, T[a : a + 1], cfg)[0] for a in range(len(T))]
        np.testing.assert_allclose(g, single, atol=1e-12)
        # procedural templates differ per class: the gain is the mean over the hypotheses, not any one of them
        three = ExpectedContactNovelty(model, NAMES, top_m=3)
        per_class = np.array([[contact_novelty(mug.to_canonical(P), mug.to_canonical(y))
                               for y in three.templates.expected_contacts(mug, c, sensor, T, cfg)]
                              for c in range(3)])
        assert np.ptp(per_class, axis=0).max() > 1e-3  # the templates disagree somewhere
        np.testing.assert_allclose(three.gains(mug, P, sensor, T, cfg), per_class.mean(0), atol=1e-12)


def test_bad_arguments(mug, model):
    with pytest.raises(ValueError, match="top_m"):
        ExpectedContactNovelty(model, NAMES, top_m=0)
    with pytest.raises(ValueError, match="class_names"):
        ExpectedContactNovelty(model, ["mug", "box"])
    g = ExpectedContactNovelty(model, NAMES)
    sensor, T = _candidates(mug, 2)
    with pytest.raises(ValueError, match="T_world_pad"):
        g.gains(mug, np.zeros((0, 3)), sensor, np.eye(4), None)
    with pytest.raises(ValueError, match="points_world"):
        g.gains(mug, np.zeros((3, 2)), sensor, T, None)


def test_novelty_episode_runs_and_validates(mug, model):
    gain = ExpectedContactNovelty(model, NAMES, top_m=2)
    with TouchWorld(mug) as world:
        ep = run_episode(world, "active", 3, pinch=False, n_candidates=6, cells=16, gain_mode="novelty",
                         recognizer=gain, seed=0)
        assert ep.n_steps == 3 and np.isnan(ep.gains[0]) and np.isfinite(ep.gains[1:]).all()
        assert all(k == "touch" for k in ep.kinds)
        with pytest.raises(ValueError, match="recognizer"):
            run_episode(world, "active", 2, pinch=False, gain_mode="novelty")
        with pytest.raises(ValueError, match="pinch"):
            run_episode(world, "active", 2, pinch=True, gain_mode="novelty", recognizer=gain)


def test_active_recognition_bench_novelty_row(tmp_path):
    torch.manual_seed(0)
    xav = XAVTNet(num_classes=12, global_dim=32, fc_dims=[16, 8], da_method="none")
    ckpt = tmp_path / "xavtnet.ckpt"
    torch.save({"state_dict": xav.state_dict(), "hyper_parameters": dict(xav.hparams)}, ckpt)
    out = tmp_path / "recog.json"
    rc = main(["bench", "active-recognition", "--ckpt", str(ckpt), "--categories", "mug",
               "--max-actions", "10", "--strategies", "random", "--novelty-gain", "--recognition-top-m", "2",
               "--object-seed", "7",
               "--objects-per-category", "1", "--candidates", "6", "--cells", "12", "--json", str(out)])
    assert rc == 0
    r = json.loads(out.read_text())
    assert set(r["summary"]) == {"random", "active_novelty"} and r["object_seed"] == 7
    assert set(r["paired_actions"]) == {"active_novelty vs random"}
    assert len(r["per_object"][0]["active_novelty"]["confidence"]) == 10
