"""Touches simulated on a point cloud (vtlearn.sim_data.cloud_touch): exact pad contacts on hand-built
clouds, the outward surface only, and input checks."""

import numpy as np
import pytest

from vtlearn.sim_data.cloud_touch import touch_cloud


def test_flat_plate_from_above_gives_a_full_taxel_grid():
    """A plate has no height, so every touch comes from above; on a dense grid one touch fills all 4 x 4
    taxel cells, so 16 wanted contacts are exactly one touch: a 4 x 4 grid on the plate, one pitch apart."""
    g = np.linspace(-1, 1, 201)
    plate = np.stack([*np.meshgrid(g, g, indexing="ij"), np.zeros((201, 201))], -1).reshape(-1, 3)
    out = touch_cloud(plate, 16, np.random.default_rng(0), pitch=0.1)
    assert out.shape == (16, 3) and np.all(out[:, 2] == 0)
    # each contact is the mean of the ~10 x 10 grid points of its cell: neighbours are one pitch away
    d = np.linalg.norm(out[:, None] - out[None], axis=-1) + np.eye(16) * 9
    assert np.all(np.abs(d.min(1) - 0.1) <= 0.011)
    assert (d - np.eye(16) * 9).max() <= 0.3 * np.sqrt(2) + 0.02  # one pad: the taxel grid's diagonal


def test_contacts_lie_on_the_outward_surface_of_a_cylinder():
    """On a closed cylinder (side, top and bottom), a pad touches only what stands out towards it: side
    contacts are within ``depth_tol`` of the radius, top ones within it of the top cap."""
    rng = np.random.default_rng(1)
    r, h, n = 0.3, 0.8, 20000
    a = rng.uniform(0, 2 * np.pi, n)
    side = np.stack([r * np.cos(a), r * np.sin(a), rng.uniform(0, h, n)], 1)
    rad = r * np.sqrt(rng.uniform(0, 1, n))
    b = rng.uniform(0, 2 * np.pi, n)
    caps = np.stack([rad * np.cos(b), rad * np.sin(b), np.where(np.arange(n) % 2, h, 0.0)], 1)
    cloud = np.concatenate([side, caps])
    pitch, tol = 0.02, 0.01
    out = touch_cloud(cloud, 1000, np.random.default_rng(2), pitch=pitch, depth_tol=tol)
    assert len(out) == 1000
    # a contact is the mean of points within tol of the pad's first contact: from above it is within tol of
    # the top cap, from the side within tol of the radius (depth is linear, so the mean keeps the bound)
    from_top = out[:, 2] >= h - tol
    radius = np.linalg.norm(out[:, :2], axis=1)
    assert from_top.any() and (~from_top).any()
    assert np.all(radius[~from_top] >= r - tol) and np.all(radius <= r + 1e-9)
    # the bottom cap is never touched from below (the table): only its rim, from the side
    assert np.all(radius[out[:, 2] < tol] >= r - tol)


def test_touch_cloud_rejects_bad_input():
    rng = np.random.default_rng(0)
    with pytest.raises(ValueError, match="points"):
        touch_cloud(np.zeros((0, 3)), 10, rng, 0.01)
    with pytest.raises(ValueError, match="points"):
        touch_cloud(np.full((5, 3), np.nan), 10, rng, 0.01)
    with pytest.raises(ValueError, match="pitch"):
        touch_cloud(np.zeros((5, 3)), 10, rng, 0.0)
    with pytest.raises(ValueError, match="n:"):
        touch_cloud(np.zeros((5, 3)), 0, rng, 0.01)
