"""Tests for the ArtReg part segmentation (thesis 6.2.2)."""

import numpy as np
import pytest

from vtlearn.classical.segmentation import (
    region_growing,
    remove_plane,
    remove_statistical_outliers,
    segment_parts,
)


def _box_surface(center, size, spacing=0.005, skip_bottom=True):
    """Grid-sampled box surface (faces at 90 degrees, which normal smoothness alone splits)."""
    c, s = np.asarray(center, float), np.asarray(size, float) / 2
    pts = []
    for ax in range(3):
        for sign in (-1, 1):
            if skip_bottom and ax == 2 and sign == -1:
                continue
            u, v = [a for a in range(3) if a != ax]
            gu = np.arange(-s[u], s[u] + 1e-9, spacing)
            gv = np.arange(-s[v], s[v] + 1e-9, spacing)
            U, V = np.meshgrid(gu, gv)
            p = np.zeros((U.size, 3))
            p[:, u], p[:, v], p[:, ax] = U.ravel(), V.ravel(), sign * s[ax]
            pts.append(p + c)
    return np.unique(np.round(np.concatenate(pts), 6), axis=0)


def _table(extent=0.3, spacing=0.006, z=0.0):
    g = np.arange(-extent, extent, spacing)
    X, Y = np.meshgrid(g, g)
    return np.stack([X.ravel(), Y.ravel(), np.full(X.size, z)], 1)


def test_region_growing_separates_two_touching_boxes_of_different_colours():
    a = _box_surface([0.0, 0.0, 0.03], [0.06, 0.06, 0.06])
    b = _box_surface([0.06, 0.0, 0.03], [0.06, 0.06, 0.06])  # shares the face x = 0.03
    b = b[b[:, 0] > 0.0305]  # the shared face belongs to box a
    pts = np.concatenate([a, b])
    col = np.concatenate([np.tile([0.9, 0.1, 0.1], (len(a), 1)), np.tile([0.1, 0.2, 0.9], (len(b), 1))])
    labels = region_growing(pts, col)
    assert labels.max() + 1 == 2
    # each box is (almost entirely) one label, and the two labels differ
    la = np.bincount(labels[: len(a)][labels[: len(a)] >= 0]).argmax()
    lb = np.bincount(labels[len(a) :][labels[len(a) :] >= 0]).argmax()
    assert la != lb
    assert np.mean(labels[: len(a)] == la) > 0.95 and np.mean(labels[len(a) :] == lb) > 0.95


def test_same_colour_faces_merge_but_normals_alone_split_them():
    a = _box_surface([0.0, 0.0, 0.03], [0.06, 0.06, 0.06])
    col = np.tile([0.2, 0.7, 0.2], (len(a), 1))
    without_colour = region_growing(a, None)
    assert without_colour.max() + 1 >= 5  # five visible faces at right angles
    assert region_growing(a, col).max() + 1 == 1


def test_segment_parts_removes_table_and_outliers():
    rng = np.random.default_rng(0)
    a = _box_surface([0.0, 0.0, 0.03], [0.06, 0.06, 0.06])
    b = _box_surface([0.15, 0.05, 0.04], [0.05, 0.08, 0.08])
    table = _table()
    table = table[~((np.abs(table[:, 0]) < 0.035) & (np.abs(table[:, 1]) < 0.035))]
    outliers = rng.uniform([-0.2, -0.2, 0.2], [0.2, 0.2, 0.4], size=(15, 3))
    pts = np.concatenate([a, b, table, outliers]) + rng.normal(
        scale=0.0005, size=(len(a) + len(b) + len(table) + 15, 3)
    )
    col = np.concatenate(
        [
            np.tile([0.9, 0.1, 0.1], (len(a), 1)),
            np.tile([0.1, 0.1, 0.9], (len(b), 1)),
            np.tile([0.5, 0.5, 0.5], (len(table), 1)),
            rng.uniform(size=(15, 3)),
        ]
    )
    res = segment_parts(pts, col)
    assert res.n_parts == 2
    sizes = sorted(len(p) for p in res.parts)
    # the bottom rows of the boxes lie within the plane threshold and go with the table
    expected = sorted(int(np.sum(x[:, 2] > 0.006)) for x in (a, b))
    np.testing.assert_allclose(sizes, expected, rtol=0.08)
    assert abs(res.plane[2]) > 0.99  # z-up table normal
    assert np.all(np.concatenate(res.parts)[:, 2] > 0.003)  # no table point survived
    assert np.all(np.concatenate(res.parts)[:, 2] < 0.1)  # no outlier survived


def test_plane_and_outlier_removal_and_bad_input():
    rng = np.random.default_rng(1)
    table = _table()
    blob = rng.normal(scale=0.01, size=(200, 3)) + [0, 0, 0.1]
    far = np.array([[1.0, 1.0, 1.0]])
    rest, _, plane = remove_plane(np.concatenate([table, blob]))
    assert len(rest) == 200 and abs(plane[2]) > 0.999
    kept, _ = remove_statistical_outliers(np.concatenate([blob, far]))
    assert len(kept) < 201 and not np.any(np.all(kept == far, axis=1))
    with pytest.raises(ValueError, match="points"):
        remove_plane(np.zeros((2, 3)))
    with pytest.raises(ValueError, match="colors"):
        region_growing(blob, np.ones((3, 3)))
    with pytest.raises(ValueError, match="colors"):
        region_growing(blob, np.full((200, 3), 255.0))
