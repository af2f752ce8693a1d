"""ESF descriptor (vtlearn.geometry.esf): a PCL-style loop reference, invariances, blocks, validation."""

import math

import numpy as np
import pytest

from vtlearn.geometry.esf import (
    ESF_BINS,
    ESF_BLOCK_SLICES,
    ESF_BLOCKS,
    ESF_DIM,
    _esf_from_triplets,
    _sample_triplets,
    _scale_to_grid,
    _trace_lines,
    _voxelise,
    esf_descriptor,
    esf_descriptors,
)


def _sphere(n, seed=0, squash=(1.0, 1.5, 0.7)):
    pts = np.random.default_rng(seed).normal(size=(n, 3))
    return pts / np.linalg.norm(pts, axis=1, keepdims=True) * squash


def _bowl(n, seed=0):
    pts = _sphere(n, seed, squash=(1.0, 1.0, 1.0))
    pts[:, 2] = -np.abs(pts[:, 2])
    return pts


# --- a deliberately plain transliteration of PCL's ESFEstimation, one triplet and one voxel at a time ---


def _ref_voxel(c):
    return int(math.floor(c) + 32) if c < 0.0 else int(math.ceil(c) + 31)


def _ref_lci(lut, x1, y1, z1, x2, y2, z2):
    """PCL's ``lci``: returns (class, ratio, in_count, point_count)."""
    act = [x1, y1, z1]
    dx, dy, dz = x2 - x1, y2 - y1, z2 - z1
    inc = [-1 if dx < 0 else 1, -1 if dy < 0 else 1, -1 if dz < 0 else 1]
    lmn = [abs(dx), abs(dy), abs(dz)]
    l, m, n = lmn
    if l >= m and l >= n:
        drive, others = 0, (1, 2)
    elif m >= l and m >= n:
        drive, others = 1, (0, 2)
    else:
        drive, others = 2, (1, 0)
    big = lmn[drive]
    err = [2 * lmn[o] - big for o in others]
    count = inside = 0
    for _ in range(1, big):
        count += 1
        inside += int(lut[act[0]][act[1]][act[2]])
        for j, o in enumerate(others):
            if err[j] > 0:
                act[o] += inc[o]
                err[j] -= 2 * big
            err[j] += 2 * lmn[o]
        act[drive] += inc[drive]
    count += 1
    inside += int(lut[act[0]][act[1]][act[2]])
    if inside >= count - 1:
        return 0, 0.0, inside, count
    if inside <= 7:
        return 1, 0.0, inside, count
    return 2, inside / count, inside, count


def _ref_esf(pts, lut, triplets):
    lut = lut.tolist()
    h = {name: [0.0] * 64 for name in ESF_BLOCKS}
    d2v, wt_d2, d3v, wt_d3 = [], [], [], []
    for i1, i2, i3 in triplets.tolist():
        p1, p2, p3 = pts[i1].tolist(), pts[i2].tolist(), pts[i3].tolist()
        v21 = [p2[k] - p1[k] for k in range(3)]
        v31 = [p3[k] - p1[k] for k in range(3)]
        v23 = [p2[k] - p3[k] for k in range(3)]
        a, b, c = (math.sqrt(sum(x * x for x in v)) for v in (v21, v31, v23))
        s = (a + b + c) * 0.5
        assert s * (s - a) * (s - b) * (s - c) > 0.001
        u21, u31, u23 = [x / a for x in v21], [x / b for x in v31], [x / c for x in v23]

        def th(u, v):
            cos = min(abs(sum(u[k] * v[k] for k in range(3))), 1.0)
            return int(math.floor(math.acos(cos) / (math.pi / 2) * 63 + 0.5))

        th1, th2, th3 = th(u21, u31), th(u23, u31), th(u23, u21)
        d2v += [a, b, c]
        vsum = psum = 0
        pcnt = []
        for pa, pb in ((p1, p2), (p1, p3), (p2, p3)):
            ends = [_ref_voxel(x) for x in pa] + [_ref_voxel(x) for x in pb]
            cls, ratio, inside, count = _ref_lci(lut, *ends)
            wt_d2.append(cls)
            if cls == 2:
                h["d2_mix_ratio"][int(math.floor(ratio * 63 + 0.5))] += 1
            vsum += inside
            psum += count
            pcnt.append(count)
        d3v.append(math.sqrt(math.sqrt(s * (s - a) * (s - b) * (s - c))))
        if vsum <= 21:
            key, w = "a3_out", 0.0
        elif psum - vsum < 4:
            key, w = "a3_in", 1.0
        else:
            key, w = "a3_mix", vsum / psum
        wt_d3.append(w)
        h[key][th1] += pcnt[2] / 32.0
        h[key][th2] += pcnt[0] / 32.0
        h[key][th3] += pcnt[1] / 32.0
    maxd2, maxd3 = max(d2v), max(d3v)
    for d, w in zip(d3v, wt_d3, strict=True):
        key = "d3_in" if w >= 0.999 else "d3_out" if w <= 0.001 else "d3_mix"
        h[key][int(math.floor(d / maxd3 * 63 + 0.5))] += 1
    for d, cls in zip(d2v, wt_d2, strict=True):
        h[("d2_in", "d2_out", "d2_mix")[cls]][int(math.floor(d / maxd2 * 63 + 0.5))] += 1
    weights = [0.5, 0.5, 0.5, 0.5, 0.5, 1.0, 0.5 * 1.0, 2.0, 2.0, 0.5 * 2.0]
    hist = [x * w for name, w in zip(ESF_BLOCKS, weights, strict=True) for x in h[name]]
    total = sum(hist)
    return np.array([x / total for x in hist])


# --- tests ---


def test_shape_normalisation_and_seeding():
    pts = _sphere(300)
    d = esf_descriptor(pts, n_samples=3000, seed=1)
    assert d.shape == (ESF_DIM,) == (640,) and d.dtype == np.float64
    assert ESF_BINS == 64 and len(ESF_BLOCKS) == 10
    assert (d >= 0).all() and d.sum() == pytest.approx(1.0, abs=1e-12)
    np.testing.assert_array_equal(d, esf_descriptor(pts, n_samples=3000, seed=1))
    np.testing.assert_array_equal(d, esf_descriptor(pts, n_samples=3000, rng=np.random.default_rng(1)))
    assert np.abs(d - esf_descriptor(pts, n_samples=3000, seed=2)).sum() > 1e-3


def test_voxelise_marks_3x3x3_neighbourhood():
    occ = _voxelise(np.array([[0.5, -0.5, 0.0]]))  # PCL mapping: ceil(.5)+31, floor(-.5)+32, ceil(0)+31
    expected = np.zeros((64, 64, 64), dtype=bool)
    expected[31:34, 30:33, 30:33] = True
    np.testing.assert_array_equal(occ, expected)
    corner = _voxelise(np.array([[-32.0, 32.0, -31.5]]))  # voxel (0, 63, 0): the neighbourhood is clipped
    assert corner.sum() == 8 and corner[:2, 62:, :2].all()


def test_trace_lines_matches_pcl_bresenham():
    rng = np.random.default_rng(3)
    occ = rng.random((64, 64, 64)) < 0.5
    start = rng.integers(0, 64, size=(400, 3))
    end = rng.integers(0, 64, size=(400, 3))
    end[:40] = start[:40]  # zero-length lines
    end[40:80, 1] = start[40:80, 1] + (end[40:80, 0] - start[40:80, 0])  # ties between axes
    end = np.clip(end, 0, 63)
    end[80:90] = start[80:90] + 1  # one-voxel diagonal steps
    end = np.clip(end, 0, 63)
    # Every (driving length L, secondary |d|) pair, walking towards -y, with a random z.
    pairs = np.array([(big, d) for big in range(1, 64) for d in range(big + 1)])
    z0, z1 = rng.integers(0, 64, size=(2, len(pairs)))
    start = np.concatenate([start, np.stack([np.zeros_like(z0), np.full_like(z0, 63), z0], axis=1)])
    end = np.concatenate([end, np.stack([pairs[:, 0], 63 - pairs[:, 1], z1], axis=1)])
    got_in, got_count = _trace_lines(occ, start, end)
    lut = occ.tolist()
    ref = np.array([_ref_lci(lut, *s, *e)[2:] for s, e in zip(start.tolist(), end.tolist(), strict=True)])
    np.testing.assert_array_equal(got_in, ref[:, 0])
    np.testing.assert_array_equal(got_count, ref[:, 1])


@pytest.mark.parametrize("n_points", [12, 500])  # 12: the all-ordered-pairs path; 500: lines traced directly
def test_vectorised_matches_loop_reference_on_same_triplets(n_points):
    scaled = _scale_to_grid(_bowl(n_points, seed=n_points))
    occ = _voxelise(scaled)
    triplets = _sample_triplets(scaled, 250, np.random.default_rng(0), "points")
    got = _esf_from_triplets(scaled, occ, triplets)
    np.testing.assert_allclose(got, _ref_esf(scaled, occ, triplets), rtol=0, atol=1e-14)
    if n_points == 500:  # the bowl exercises all three line classes
        assert all(got[ESF_BLOCK_SLICES[name]].sum() > 0 for name in ("d2_in", "d2_out", "d2_mix"))


def test_rotation_by_90_degrees_about_z_is_exact():
    # PCL's voxel map sends c and -c to mirrored voxels (63 - i) except at c == 0 exactly, and the Bresenham
    # walk is symmetric under axis swaps and flips, so (x, y, z) -> (-y, x, z) maps voxels to voxels.
    pts = _bowl(400, seed=5)
    rotated = np.stack([-pts[:, 1], pts[:, 0], pts[:, 2]], axis=1)
    expected = esf_descriptor(pts, n_samples=4000, seed=7)
    np.testing.assert_allclose(esf_descriptor(rotated, n_samples=4000, seed=7), expected, rtol=0, atol=1e-12)


def test_rigid_motion_and_scale_change_it_little():
    # A general rotation re-voxelises the cloud on the axis-aligned grid, so only closeness holds. With the
    # same triplets, the L1 distance over 20 random rotations measured 0.027-0.049; two seeds on the same
    # cloud differ by ~0.09-0.10 at 4000 samples. Translation + scale measured exactly 0.
    pts = _bowl(400, seed=6)
    ref = esf_descriptor(pts, n_samples=4000, seed=7)
    for k in range(3):
        q = np.linalg.qr(np.random.default_rng(k).normal(size=(3, 3)))[0]
        moved = 3.7 * pts @ q.T + np.array([10.0, -4.0, 2.5])
        assert np.abs(esf_descriptor(moved, n_samples=4000, seed=7) - ref).sum() < 0.08
    shifted = 0.01 * pts + 100.0  # translation + scale alone keep the shape up to rounding
    assert np.abs(esf_descriptor(shifted, n_samples=4000, seed=7) - ref).sum() < 0.01


def _d2_fractions(d):
    mass = {name: d[ESF_BLOCK_SLICES[name]].sum() for name in ("d2_in", "d2_out", "d2_mix")}
    total = sum(mass.values())
    return {name: m / total for name, m in mass.items()}


def test_dense_plane_is_in_sparse_cloud_is_out():
    rng = np.random.default_rng(4)
    uv = rng.uniform(-1, 1, size=(1000, 2))
    plane = uv @ np.array([[1.0, 0.3, 0.2], [0.0, 0.8, -0.5]])
    assert _d2_fractions(esf_descriptor(plane, n_samples=3000, seed=0))["d2_in"] > 0.8
    sparse = rng.uniform(-1, 1, size=(30, 3))
    assert _d2_fractions(esf_descriptor(sparse, n_samples=3000, seed=0))["d2_out"] > 0.8


@pytest.mark.parametrize(
    ("points", "match"),
    [
        (np.zeros((5, 2)), r"points: .*\(5, 2\)"),
        (np.array([[0.0, 0, 0], [1, 0, 0], [0, np.nan, 1]]), "points: contains NaN or inf"),
        (np.eye(3)[:2], "points: .*2 points.*at least 3"),
        (np.ones((10, 3)), "points: all 10 points are identical"),
        (np.outer(np.arange(10.0), [1.0, 2.0, 3.0]), "points: all points are collinear"),
    ],
)
def test_bad_points_raise(points, match):
    with pytest.raises(ValueError, match=match):
        esf_descriptor(points, n_samples=100, seed=0)


def test_bad_arguments_raise():
    pts = _sphere(50)
    for bad in (0, -3, 2.5, True):
        with pytest.raises(ValueError, match="n_samples"):
            esf_descriptor(pts, n_samples=bad, seed=0)
    with pytest.raises(ValueError, match="rng, seed"):
        esf_descriptor(pts, rng=np.random.default_rng(0), seed=0)
    with pytest.raises(ValueError, match="clouds: is empty"):
        esf_descriptors([])
    with pytest.raises(ValueError, match=r"clouds\[1\]: contains NaN"):
        esf_descriptors([pts, np.full((5, 3), np.nan)], n_samples=100)
    with pytest.raises(ValueError, match="n_samples"):
        esf_descriptors([pts], n_samples=0)


def test_too_few_valid_triplets_raises():
    # Not collinear, but 998 of 1000 points coincide: almost no triplet spans a triangle.
    pts = np.zeros((1000, 3))
    pts[0], pts[1] = [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]
    with pytest.raises(ValueError, match="points: only .* non-degenerate triangle"):
        esf_descriptor(pts, n_samples=50, seed=0)


def test_batch_rows_equal_single_calls_with_per_cloud_generator():
    clouds = [_sphere(40, seed=1), _bowl(200, seed=2), _sphere(90, seed=3)]
    out = esf_descriptors(clouds, n_samples=1500, seed=11)
    assert out.shape == (3, ESF_DIM)
    for i, cloud in enumerate(clouds):
        np.testing.assert_array_equal(out[i], esf_descriptor(cloud, n_samples=1500, seed=[11, i]))
    # Dropping a cloud does not change the others' rows.
    np.testing.assert_array_equal(esf_descriptors(clouds[:1], n_samples=1500, seed=11)[0], out[0])
