"""Expected box-fit gain for next-best touches and pinches (vtlearn.active.reconstruction_nbt)."""

import numpy as np
import pytest
import torch

from vtlearn.active.actions import ActionSet
from vtlearn.active.closed_loop import TouchWorld, make_object, run_episode
from vtlearn.active.reconstruction_nbt import ExpectedBoxFitGain, box_fit_error, predict_tactile_contacts
from vtlearn.active.sensors import TactileArray
from vtlearn.sim_data.tactile import TactileConfig, pad_frame


def _naive_ranges(points, origins, directions, max_range, radius):
    out = np.full(len(origins), np.inf)
    for i, (o, d, m) in enumerate(zip(origins, directions, max_range, strict=True)):
        for p in points:
            v = p - o
            along = v @ d
            perp2 = v @ v - along**2
            if along > 0 and perp2 < radius**2:
                t = along - np.sqrt(radius**2 - perp2)
                if t <= m:
                    out[i] = min(out[i], t)
    return out


def test_predict_contacts_matches_a_naive_loop():
    rng = np.random.default_rng(0)
    points = rng.uniform(-0.05, 0.05, (60, 3))
    origins = rng.uniform(-0.1, 0.1, (40, 3))
    directions = -origins / np.linalg.norm(origins, axis=1, keepdims=True)
    max_range = np.full(40, 0.12)
    t, contact = predict_tactile_contacts(points, origins, directions, max_range, np.arange(40), 0.01, 0.0)
    ref = _naive_ranges(points, origins, directions, max_range, 0.01)
    np.testing.assert_allclose(t, ref, rtol=1e-12)
    assert np.isfinite(ref).any() and not np.isfinite(ref).all()
    np.testing.assert_array_equal(contact, np.isfinite(ref))  # one ray per pad: every hit is its pad's first


def test_predict_contacts_on_a_step_stops_each_pad_at_its_first_contact():
    # Surface points at x = 0.05 for y < 0 and x = 0.06 for y > 0; rays along +x from x = 0.
    points = np.array([[0.05, -0.01, 0.0], [0.05, -0.02, 0.0], [0.06, 0.01, 0.0], [0.06, 0.02, 0.0]])
    origins = np.array([[0.0, -0.01, 0.0], [0.0, 0.01, 0.0], [0.0, 0.01, 0.0], [0.0, 0.5, 0.0]])
    directions = np.tile([1.0, 0.0, 0.0], (4, 1))
    pad = np.array([0, 0, 1, 1])
    t, contact = predict_tactile_contacts(points, origins, directions, np.full(4, 0.1), pad, 0.002, 0.005)
    np.testing.assert_allclose(t[:3], [0.048, 0.058, 0.058])
    assert t[3] == np.inf
    # pad 0 stops 5 mm past 0.048: its ray at 0.058 does not touch; pad 1 meets only 0.058
    np.testing.assert_array_equal(contact, [True, False, True, False])


def test_box_fit_error_hand_computed():
    extents = np.array([1.0, 0.5, 0.8])
    corners = np.stack(np.meshgrid(*[[-e / 2, e / 2] for e in extents], indexing="ij"), -1).reshape(-1, 3)
    shifted = corners + [0.1, 0.0, 0.0]
    shrunk = corners * [1.0, 0.5, 1.0]
    err = box_fit_error(np.stack([corners, shifted, shrunk]), extents, percentile=0.0)
    np.testing.assert_allclose(err, [0.0, 0.2, 0.25], atol=1e-12)


class _CentroidSphere(torch.nn.Module):
    """Stand-in reconstruction network: a fixed sphere centred on the mean of the valid input points
    (ACTOR centres its input the same way), so a reconstruction is only as well placed as its input."""

    def __init__(self, radius: float = 0.3, n: int = 400):
        super().__init__()
        i = np.arange(n) + 0.5
        phi, theta = np.arccos(1 - 2 * i / n), np.pi * (1 + 5**0.5) * i
        sphere = radius * np.stack([np.cos(theta) * np.sin(phi), np.sin(theta) * np.sin(phi), np.cos(phi)], 1)
        self.register_buffer("sphere", torch.tensor(sphere, dtype=torch.float32))
        self.dummy = torch.nn.Parameter(torch.zeros(1))

    def forward(self, x, lengths=None):
        n = x.shape[1]
        lengths = torch.full((x.shape[0],), n) if lengths is None else lengths
        mask = (torch.arange(n)[None] < lengths[:, None]).float()[..., None]
        mean = (x * mask).sum(1) / mask.sum(1)
        return self.sphere[None] + mean[:, None]


def test_box_fit_gain_prefers_the_touch_that_recentres_the_reconstruction():
    obj = make_object("mug", 1, sections=12)
    lo, hi = obj.bounds
    s = float((hi - lo).max())
    measured = obj.from_canonical(np.array([[-0.45, 0.0, 0.0], [-0.45, 0.02, 0.0], [-0.45, 0.0, 0.02]]))
    # The reconstruction is a sphere of radius 0.3 around x = -0.45 (canonical): far off the box centre.
    starts = obj.from_canonical(np.array([[0.6, 0.0, 0.0], [-1.2, 0.0, 0.0], [0.45, 0.45, 0.8]]))
    dirs = np.array([[-1.0, 0, 0], [1.0, 0, 0], [0, 0, -1.0]])
    T = np.stack([pad_frame(p, d) for p, d in zip(starts, dirs, strict=True)])
    touches = ActionSet("touch", T, starts, np.zeros(3, dtype=np.int64))
    gain = ExpectedBoxFitGain(_CentroidSphere(), max_points=120)
    g = gain.gains(obj, measured, [(touches, TactileArray("xela_4x4", ray_length=s))], TactileConfig())
    assert g.shape == (3,)
    # +x side: contacts right of the centroid pull the sphere towards the centre; -x side pushes it away;
    # the corner touch misses the sphere, so the input and the reconstruction do not change.
    assert g[0] > 0 > g[1]
    assert g[2] == 0.0
    assert int(np.argmax(g)) == 0
    np.testing.assert_array_equal(gain.gains(obj, measured[:2], [(touches, TactileArray())], TactileConfig()),
                                  np.zeros(3))  # fewer than 3 points: no reconstruction, no preference


def test_box_fit_gain_in_the_closed_loop_and_bad_input():
    obj = make_object("wineglass", 1, sections=12)
    gain = ExpectedBoxFitGain(_CentroidSphere())
    with TouchWorld(obj) as world:
        ep = run_episode(
            world, "active", 3, gain_mode="box_fit", reconstructor=gain, n_candidates=8, cells=16
        )
        assert ep.n_steps == 3 and set(ep.kinds) <= {"touch", "pinch"} and len(ep.gains) == 3
        with pytest.raises(ValueError, match="reconstructor"):
            run_episode(world, "active", 2, gain_mode="box_fit", n_candidates=8, cells=16)
        with pytest.raises(ValueError, match="gain_mode"):
            run_episode(world, "active", 2, n_views=1, gain_mode="box_fit", reconstructor=gain, cells=16)
    with pytest.raises(ValueError, match="points"):
        predict_tactile_contacts(np.zeros((0, 3)), np.zeros((1, 3)), np.ones((1, 3)), [1.0], [0], 0.01, 0.0)
    with pytest.raises(ValueError, match="radius"):
        predict_tactile_contacts(np.zeros((2, 3)), np.zeros((1, 3)), np.ones((1, 3)), [1.0], [0], 0.0, 0.0)
    with pytest.raises(ValueError, match="extents"):
        box_fit_error(np.zeros((1, 4, 3)), [1.0, 0.0, 1.0])
    with pytest.raises(ValueError, match="clouds"):
        box_fit_error(np.zeros((4, 3)), [1.0, 1.0, 1.0])
    with pytest.raises(ValueError, match="radius_factor"):
        ExpectedBoxFitGain(_CentroidSphere(), radius_factor=0.0)
    with pytest.raises(ValueError, match="candidates"):
        gain.gains(obj, np.zeros((4, 3)), [], TactileConfig())


# ------------------------------------------------------------------ touch/pinch exploration inputs
# (vtlearn.active.exploration; here because its own tests, test_active_actions_exploration.py, are
# outside this change)
@pytest.mark.parametrize(
    "kwargs, name",
    [
        ({"n_candidates": 0}, "n_candidates"),
        ({"n_candidates": 1, "pinch": True}, "n_candidates"),  # half touches, half pinches: needs 2
        ({"cells": 0}, "cells"),  # was a ZeroDivisionError
        ({"cells": 1.5}, "cells"),
        ({"coverage_radius": -0.01}, "coverage_radius"),  # was accepted: coverage 0 throughout
        ({"coverage_radius": float("nan")}, "coverage_radius"),
        ({"standoff": -0.01}, "standoff"),
        ({"compliance": -0.001}, "compliance"),
        ({"gain_mode": "greedy"}, "gain_mode"),
        ({"pinch": True, "pinch_opening": 0.0}, "pinch_opening"),
    ],
)
def test_explore_names_a_bad_argument_before_touching(kwargs, name):
    import trimesh

    from vtlearn.active.exploration import explore

    strategy = "active" if "n_candidates" in kwargs or "gain_mode" in kwargs else "random"
    with pytest.raises(ValueError, match=f"^{name}: "):
        explore(trimesh.creation.box(extents=[0.1, 0.1, 0.1]), strategy, 3, **kwargs)


def test_uniform_schedules_take_n_touches():
    from vtlearn.active.actions import OrientedBox
    from vtlearn.active.exploration import uniform_pinch_schedule, uniform_touch_schedule

    box = OrientedBox.from_points(np.random.default_rng(0).uniform(-0.05, 0.05, (50, 3)))
    assert len(uniform_touch_schedule(box, 7, 0.02)) == 7 and len(uniform_pinch_schedule(box, 7)) == 7
    for bad in (0, -1, 2.5):
        with pytest.raises(ValueError, match="^n: "):
            uniform_touch_schedule(box, bad, 0.02)
        with pytest.raises(ValueError, match="^n: "):
            uniform_pinch_schedule(box, bad)
    with pytest.raises(ValueError, match="^standoff: "):
        uniform_touch_schedule(box, 3, -0.01)
