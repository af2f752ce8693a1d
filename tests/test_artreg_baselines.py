"""Tests for the tracking baselines (particle filter, frame-to-frame ICP) of thesis 6.3.5."""

import numpy as np
import pytest

from vtlearn.classical.tracking_baselines import FrameToFrameICPTracker, ParticleFilterTracker
from vtlearn.geometry import se3_exp


def _box_cloud(n=500, size=(0.12, 0.08, 0.05), seed=0):
    rng = np.random.default_rng(seed)
    s = np.asarray(size) / 2
    pts = rng.uniform(-1, 1, size=(n, 3)) * s
    axis = rng.integers(0, 3, size=n)
    pts[np.arange(n), axis] = np.sign(rng.uniform(-1, 1, size=n)) * s[axis]
    return pts


@pytest.mark.parametrize("cls", [ParticleFilterTracker, FrameToFrameICPTracker])
def test_baseline_follows_slow_motion(cls):
    rng = np.random.default_rng(0)
    model = _box_cloud()
    T0 = se3_exp(np.array([0.3, 0.0, 0.025, 0, 0, 0]))
    tracker = cls([model], [T0])
    for k in range(30):
        T_gt = T0 @ se3_exp(np.array([0.002 * k, 0.001 * k, 0, 0, 0, 0.01 * k]))
        scene = model @ T_gt[:3, :3].T + T_gt[:3, 3] + rng.normal(scale=0.001, size=model.shape)
        (T_est,) = tracker.step(scene)
    assert np.linalg.norm(T_est[:3, 3] - T_gt[:3, 3]) < 0.01
    before = tracker.poses[0].copy()
    np.testing.assert_allclose(tracker.step(np.zeros((0, 3)))[0], before)


@pytest.mark.parametrize("cls", [ParticleFilterTracker, FrameToFrameICPTracker])
def test_baseline_bad_input(cls):
    with pytest.raises(ValueError, match=r"models\[0\]"):
        cls([np.zeros((2, 3))], [np.eye(4)])
    tracker = cls([_box_cloud(50)], [np.eye(4)])
    with pytest.raises(ValueError, match="scene_cloud"):
        tracker.step(np.full((5, 3), np.inf))
