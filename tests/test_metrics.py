"""Metrics against deliberately naive loop references, gradchecks, and hand-computed cases."""

import itertools

import numpy as np
import pytest
import torch

from vtlearn.geometry import (
    add,
    adi,
    chamfer_distance,
    earth_movers_distance,
    hausdorff_distance,
    make_transform,
    pad_clouds,
    random_pose,
    rotation_error_deg,
    scale_error,
    so3_exp,
    translation_error,
)


def naive_directed(a, b):
    return [min(float(np.sqrt(((p - q) ** 2).sum())) for q in b) for p in a]


def naive_chamfer(a, b):
    return np.mean(naive_directed(a, b)) + np.mean(naive_directed(b, a))


def naive_hausdorff(a, b):
    return max(max(naive_directed(a, b)), max(naive_directed(b, a)))


def naive_emd(a, b):
    best = np.inf
    for perm in itertools.permutations(range(len(b))):
        best = min(best, np.mean([np.linalg.norm(a[i] - b[j]) for i, j in enumerate(perm)]))
    return best


@pytest.fixture
def clouds():
    rng = np.random.default_rng(0)
    return rng.random((30, 3)), rng.random((17, 3))


def test_chamfer_matches_naive(clouds):
    a, b = clouds
    assert abs(chamfer_distance(a, b) - naive_chamfer(a, b)) < 1e-6
    assert abs(chamfer_distance(a, b) - chamfer_distance(b, a)) < 1e-12


def test_chamfer_hand_computed():
    # x = {0}, y = {1, 3} on a line: x->y mean = 1, y->x mean = (1 + 3) / 2 = 2 -> CD = 3
    x = np.array([[0.0, 0, 0]])
    y = np.array([[1.0, 0, 0], [3.0, 0, 0]])
    assert chamfer_distance(x, y) == pytest.approx(3.0)
    assert hausdorff_distance(x, y) == pytest.approx(3.0)
    assert earth_movers_distance(x, y) == pytest.approx(1.0)  # injection picks the nearer point
    assert chamfer_distance(x, x) == 0.0


def test_hausdorff_matches_naive(clouds):
    a, b = clouds
    assert abs(hausdorff_distance(a, b) - naive_hausdorff(a, b)) < 1e-6


def test_batched_padded_matches_per_cloud():
    rng = np.random.default_rng(1)
    xs = [rng.random((n, 3)) for n in (20, 5, 13)]
    ys = [rng.random((n, 3)) for n in (8, 30, 13)]
    x, xl = pad_clouds(xs, dtype=torch.float64)
    y, yl = pad_clouds(ys, dtype=torch.float64)
    cd = chamfer_distance(x, y, xl, yl, reduction="none")
    hd = hausdorff_distance(x, y, xl, yl, reduction="none")
    for i in range(3):
        assert abs(float(cd[i]) - naive_chamfer(xs[i], ys[i])) < 1e-6
        assert abs(float(hd[i]) - naive_hausdorff(xs[i], ys[i])) < 1e-6
    assert abs(float(chamfer_distance(x, y, xl, yl)) - float(cd.mean())) < 1e-12
    # padding values do not matter
    x2 = x.clone()
    x2[1, 5:] = 100.0
    assert torch.allclose(chamfer_distance(x2, y, xl, yl, reduction="none"), cd)


def test_chamfer_gradcheck():
    rng = np.random.default_rng(2)
    x = torch.tensor(rng.random((1, 6, 3)), requires_grad=True)
    y = torch.tensor(rng.random((1, 5, 3)), requires_grad=True)
    assert torch.autograd.gradcheck(lambda a, b: chamfer_distance(a, b), (x, y))
    assert torch.autograd.gradcheck(lambda a, b: hausdorff_distance(a, b), (x, y))


def test_emd_exact_matches_brute_force():
    rng = np.random.default_rng(3)
    a, b = rng.random((6, 3)), rng.random((6, 3))
    assert abs(earth_movers_distance(a, b) - naive_emd(a, b)) < 1e-9
    # a permuted copy has zero EMD but non-zero under identity pairing
    assert earth_movers_distance(a, a[::-1]) == pytest.approx(0.0, abs=1e-12)


def test_emd_unequal_sizes_documented_approximation():
    rng = np.random.default_rng(4)
    a = rng.random((4, 3))
    # |X| > |Y| with |X| a multiple of |Y|: equals EMD against the duplicated set
    b = rng.random((2, 3))
    assert abs(earth_movers_distance(a, b) - naive_emd(a, np.vstack([b, b]))) < 1e-9


def test_adi_and_add():
    rng = np.random.default_rng(5)
    model = rng.random((200, 3))
    T = random_pose(seed=1)
    assert adi(model, T, T) == 0.0 and add(model, T, T) == 0.0
    shift = make_transform(np.eye(3), np.array([0.0, 0.0, 0.01]))
    assert add(model, shift @ T, T) == pytest.approx(0.01)
    # ADI <= ADD always (closest point vs corresponding point)
    T2 = random_pose(seed=2, trans_range=(-0.05, 0.05))
    assert adi(model, T2, T) <= add(model, T2, T) + 1e-12
    # naive ADI (eq. 5.24)
    gt = model @ T[:3, :3].T + T[:3, 3]
    est = model @ T2[:3, :3].T + T2[:3, 3]
    ref = np.mean([np.min(np.linalg.norm(est - p, axis=1)) for p in gt])
    assert abs(adi(model, T2, T) - ref) < 1e-9
    # symmetric object: a rotation about the symmetry axis has ADI ~ 0 but ADD > 0
    theta = np.linspace(0, 2 * np.pi, 360, endpoint=False)
    ring = np.stack([np.cos(theta), np.sin(theta), np.zeros_like(theta)], 1)
    Rz = make_transform(so3_exp(np.array([0, 0, np.pi / 3])), np.zeros(3))
    assert adi(ring, Rz, np.eye(4)) < 1e-9 and add(ring, Rz, np.eye(4)) > 0.5


def test_pose_errors_hand_computed():
    R = so3_exp(np.array([0.0, 0.0, np.deg2rad(30)]))
    assert rotation_error_deg(R, np.eye(3)) == pytest.approx(30.0)
    assert rotation_error_deg(np.eye(3), so3_exp(np.array([np.pi, 0, 0]))) == pytest.approx(180.0)
    assert translation_error([1, 2, 3], [1, 2, 5]) == pytest.approx(2.0)
    assert scale_error([1, 2, 2], [1, 1, 1]) == pytest.approx(np.sqrt(2))
    assert scale_error(2.0, [1, 1, 1]) == pytest.approx(np.sqrt(3))


@pytest.mark.parametrize("fn", [chamfer_distance, hausdorff_distance, earth_movers_distance])
def test_set_metrics_reject_bad_input(fn):
    good = np.random.default_rng(0).random((5, 3))
    with pytest.raises(ValueError, match="empty"):
        fn(np.empty((0, 3)), good)
    with pytest.raises(ValueError, match="NaN"):
        fn(good, np.full((3, 3), np.nan))
    with pytest.raises(ValueError, match="shape"):
        fn(good[:, :2], good)


def test_pose_metrics_reject_bad_input():
    with pytest.raises(ValueError, match="T_est"):
        adi(np.ones((3, 3)), np.eye(3), np.eye(4))
    with pytest.raises(ValueError, match="T_gt"):
        add(np.ones((3, 3)), np.eye(4), np.diag([2.0, 1, 1, 1]))
    with pytest.raises(ValueError, match="model_points"):
        adi(np.empty((0, 3)), np.eye(4), np.eye(4))
    with pytest.raises(ValueError, match="R_est"):
        rotation_error_deg(np.eye(4), np.eye(3))
    with pytest.raises(ValueError, match="s_est"):
        scale_error([1, 2], [1, 1, 1])
