"""Next-best-touch for recognition: the classifier's expected information (vtlearn.active.recognition_nbt)
and the expected contact novelty (vtlearn.active.recognition_novelty)."""

import json

import numpy as np
import pytest
import torch

from vtlearn.active.actions import OrientedBox, sample_touch_actions
from vtlearn.active.closed_loop import TouchWorld, classify_clouds, held_out_objects, run_episode
from vtlearn.active.recognition_nbt import ExpectedClassEntropyGain, fit_to_box
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


def test_fit_to_box_maps_the_bounds():
    v = np.random.default_rng(0).normal(size=(50, 3))
    out = fit_to_box(v, [0.0, 1.0, 2.0], [1.0, 3.0, 2.5])
    np.testing.assert_allclose(out.min(0), [0.0, 1.0, 2.0], atol=1e-12)
    np.testing.assert_allclose(out.max(0), [1.0, 3.0, 2.5], atol=1e-12)
    with pytest.raises(ValueError, match="vertices"):
        fit_to_box(np.zeros((10, 3)), [0, 0, 0], [1, 1, 1])
    with pytest.raises(ValueError, match="vertices"):
        fit_to_box(np.zeros((10, 2)), [0, 0, 0], [1, 1, 1])
    with pytest.raises(ValueError, match="lo, hi"):
        fit_to_box(v, [0, 0, 0], [1, 0, 1])


def test_expected_contacts_on_the_true_shape_equal_the_simulated_touch(mug, model):
    """Noiseless case: with the object itself as the template, the predicted contacts are the ones the
    pybullet guarded touch reports."""
    gain = ExpectedClassEntropyGain(model, NAMES)
    gain._templates[(0, 0)] = mug.mesh  # class 0 ("mug") hypothesis = the object itself
    sensor, T = _candidates(mug, 40, seed=3)
    # pads whose housing reaches into the table slab are outside the replayed model (see its docstring)
    local = np.concatenate([sensor.layout.taxel_positions(), sensor.layout.housing_positions()])
    T = T[(np.einsum("nj,aij->ani", local, T[:, :3, :3])[..., 2] + T[:, None, 2, 3]).min(1) >= 0][:12]
    with TouchWorld(mug) as world:
        predicted = gain.expected_contacts(mug, 0, sensor, T, world.sim.config)
        n_touching = 0
        for a in range(len(T)):
            _, _, measured = world.press(T[a : a + 1], sensor.ray_length)
            assert len(predicted[a]) == len(measured)
            if len(measured):
                n_touching += 1
                np.testing.assert_allclose(np.sort(predicted[a], 0), np.sort(measured, 0), atol=1e-4)
    assert n_touching >= 3  # the check is not vacuous


def test_gains_criteria_hand_cases(mug, model):
    sensor, T = _candidates(mug, 6, seed=1)
    with TouchWorld(mug) as world:
        cfg = world.sim.config
        _, _, P = world.press(T[:1], sensor.ray_length)
        one = ExpectedClassEntropyGain(model, NAMES, top_m=1)
        # one hypothesis: nothing to tell apart
        np.testing.assert_allclose(one.gains(mug, P, sensor, T, cfg), 0.0, atol=1e-12)
        ee = ExpectedClassEntropyGain(model, NAMES, top_m=1, criterion="expected_entropy")
        p0 = ee.posterior(mug, P)
        c = int(np.argmax(p0))
        ys = ee.expected_contacts(mug, c, sensor, T, cfg)
        q = classify_clouds(model, mug, [np.concatenate([P, y]) for y in ys], 256, seed=0)

        def h(p):
            return -(p * np.log(np.clip(p, 1e-12, 1))).sum(-1)

        np.testing.assert_allclose(ee.gains(mug, P, sensor, T, cfg), h(p0) - h(q), atol=1e-5)
        mi = ExpectedClassEntropyGain(model, NAMES, top_m=3)
        g = mi.gains(mug, P, sensor, T, cfg)
        assert g.shape == (6,) and (g >= -1e-9).all()  # mutual information is >= 0
        # batched candidates score as one at a time
        single = [mi.gains(mug, P, sensor, T[a : a + 1], cfg)[0] for a in range(len(T))]
        np.testing.assert_allclose(g, single, atol=1e-5)
        # two templates per class: hypotheses are (class, template) pairs at half their class's weight
        two = ExpectedClassEntropyGain(model, NAMES, top_m=2, templates_per_class=2)
        hyp = [int(c) for c in np.argsort(-two.posterior(mug, P))[:2]]
        qs = []
        for c in hyp:
            for j in range(2):
                ys = two.expected_contacts(mug, c, sensor, T, cfg, template=j)
                qs.append(classify_clouds(model, mug, [np.concatenate([P, y]) if len(y) else P for y in ys],
                                          256, seed=0))
        qs = np.stack(qs)  # (4, A, C)
        expected = h(qs.mean(0)) - h(qs).mean(0)
        np.testing.assert_allclose(two.gains(mug, P, sensor, T, cfg), expected, atol=1e-5)
        assert two._template(hyp[0], 0) is not two._template(hyp[0], 1)


def test_bad_arguments(mug, model):
    with pytest.raises(ValueError, match="class_names"):
        ExpectedClassEntropyGain(model, ["mug", "box"])
    with pytest.raises(ValueError, match="criterion"):
        ExpectedClassEntropyGain(model, NAMES, criterion="margin")
    with pytest.raises(ValueError, match="top_m"):
        ExpectedClassEntropyGain(model, NAMES, top_m=0)
    with pytest.raises(ValueError, match="templates_per_class"):
        ExpectedClassEntropyGain(model, NAMES, templates_per_class=0)
    g = ExpectedClassEntropyGain(model, NAMES)
    with pytest.raises(ValueError, match="T_world_pad"):
        g.gains(mug, np.zeros((0, 3)), TactileArray(), np.eye(4), None)


@pytest.mark.parametrize("criterion, mode", [(ExpectedClassEntropyGain, "recognition"),
                                             (ExpectedContactNovelty, "novelty")])
def test_recognition_criteria_episodes_run_and_validate(mug, model, criterion, mode):
    gain = criterion(model, NAMES, top_m=2)
    with TouchWorld(mug) as world:
        ep = run_episode(world, "active", 3, pinch=False, n_candidates=6, cells=16, gain_mode=mode,
                         recognizer=gain, seed=0)
        assert ep.n_steps == 3 and np.isnan(ep.gains[0]) and np.isfinite(ep.gains[1:]).all()
        assert all(k == "touch" for k in ep.kinds)
        with pytest.raises(ValueError, match="recognizer"):
            run_episode(world, "active", 2, pinch=False, gain_mode=mode)
        with pytest.raises(ValueError, match="pinch"):
            run_episode(world, "active", 2, pinch=True, gain_mode=mode, recognizer=gain)


# ---------------------------------------------------------------- contact novelty (recognition_novelty)
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
        # a novelty criterion that takes its templates from a recognition criterion's library scores alike
        # and builds no template of its own
        library = ExpectedClassEntropyGain(model, NAMES, top_m=3, templates_per_class=2)
        shared = ExpectedContactNovelty(model, NAMES, top_m=3, library=library)
        assert shared.templates is library
        np.testing.assert_allclose(shared.gains(mug, P, sensor, T, cfg), per_class.mean(0), atol=1e-12)
        assert set(library._templates) == {(c, 0) for c in range(3)}


def test_novelty_bad_arguments(mug, model):
    with pytest.raises(ValueError, match="top_m"):
        ExpectedContactNovelty(model, NAMES, top_m=0)
    with pytest.raises(ValueError, match="class_names"):
        ExpectedContactNovelty(model, ["mug", "box"])
    with pytest.raises(ValueError, match="library"):
        ExpectedContactNovelty(model, NAMES, top_m=2, library=ExpectedClassEntropyGain(model, NAMES, top_m=3))
    with pytest.raises(ValueError, match="library"):
        ExpectedContactNovelty(model, NAMES, library=object())
    g = ExpectedContactNovelty(model, NAMES)
    sensor, T = _candidates(mug, 2)
    with pytest.raises(ValueError, match="T_world_pad"):
        g.gains(mug, np.zeros((0, 3)), sensor, np.eye(4), None)
    with pytest.raises(ValueError, match="points_world"):
        g.gains(mug, np.zeros((3, 2)), sensor, T, None)


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
