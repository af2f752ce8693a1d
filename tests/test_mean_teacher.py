"""Tests for the mean teacher's parts: the softmax consistency loss, the weight average, the ramp-up and
the input perturbation (vtlearn/losses/consistency.py, vtlearn/models/components/mean_teacher.py)."""

import math

import pytest
import torch
from torch import nn

from vtlearn.losses.consistency import confident_cross_entropy, probability_consistency, softmax_consistency
from vtlearn.models.components.mean_teacher import ema_update, perturb_padded, sigmoid_rampup


def _naive_consistency(zs, zt, threshold=0.0):
    total = 0.0
    for i in range(zs.shape[0]):
        es = [math.exp(v) for v in zs[i].tolist()]
        et = [math.exp(v) for v in zt[i].tolist()]
        if max(et) / sum(et) >= threshold:
            total += sum((a / sum(es) - b / sum(et)) ** 2 for a, b in zip(es, et, strict=True))
    return total / zs.shape[0]


@pytest.mark.parametrize("threshold", [0.0, 0.6, 0.8])
def test_softmax_consistency_matches_a_naive_loop_and_a_hand_case(threshold):
    g = torch.Generator().manual_seed(0)
    zs, zt = torch.randn(7, 5, generator=g), 2 * torch.randn(7, 5, generator=g)
    naive = _naive_consistency(zs, zt, threshold)
    assert softmax_consistency(zs, zt, threshold).item() == pytest.approx(naive, rel=1e-6)
    if threshold > 0:  # some clouds, not all, fall under the threshold
        assert 0 < naive < _naive_consistency(zs, zt)
    # hand case: one-hot-like softmaxes on different classes differ by 1 twice -> 2; equal logits -> 0
    big = torch.tensor([[50.0, 0.0]])
    assert softmax_consistency(big, big.flip(-1)).item() == pytest.approx(2.0, abs=1e-6)
    assert softmax_consistency(zs, zs + 3.0).item() == pytest.approx(0.0, abs=1e-7)  # softmax shift-invariant
    # uniform teacher, student (log 3, 0): p = (3/4, 1/4) against (1/2, 1/2) -> 2·(1/4)² = 1/8
    assert softmax_consistency(torch.tensor([[math.log(3.0), 0.0]]), torch.zeros(1, 2)).item() == \
        pytest.approx(0.125, rel=1e-6)


def test_probability_consistency_is_softmax_consistency_on_the_teacher_softmax():
    torch.manual_seed(0)
    zs, zt = torch.randn(6, 4), 2 * torch.randn(6, 4)
    for threshold in (0.0, 0.6):
        assert torch.allclose(probability_consistency(zs, zt.softmax(-1), threshold),
                              softmax_consistency(zs, zt, threshold))
    with pytest.raises(ValueError, match="same shape"):
        probability_consistency(zs, torch.rand(5, 4))
    with pytest.raises(ValueError, match="teacher_probs contains NaN"):
        probability_consistency(zs, torch.full((6, 4), float("nan")))


def test_softmax_consistency_gradient_reaches_the_student_only():
    zs = torch.randn(4, 3, dtype=torch.float64, requires_grad=True)
    zt = torch.randn(4, 3, dtype=torch.float64, requires_grad=True)
    assert torch.autograd.gradcheck(lambda a: softmax_consistency(a, zt), (zs,))
    softmax_consistency(zs, zt).backward()
    assert zs.grad is not None and zs.grad.abs().sum() > 0
    assert zt.grad is None


def test_confident_cross_entropy_matches_a_naive_loop_and_a_hand_case():
    """FixMatch's term: −log softmax(z_i)[argmax p'_i] on the clouds whose teacher peak reaches τ, summed and
    divided by the whole batch; the gradient reaches the student only."""
    g = torch.Generator().manual_seed(0)
    zs, pt = torch.randn(9, 4, generator=g), (3 * torch.randn(9, 4, generator=g)).softmax(-1)
    for threshold in (0.0, 0.85, 0.99):
        total = 0.0
        for i in range(9):
            if pt[i].max() >= threshold:
                es = [math.exp(v) for v in zs[i].tolist()]
                total -= math.log(es[int(pt[i].argmax())] / sum(es))
        naive = total / 9
        assert confident_cross_entropy(zs, pt, threshold).item() == pytest.approx(naive, rel=1e-6)
        if threshold > 0:  # some clouds, not all, count
            assert 0 < (pt.amax(-1) >= threshold).sum() < 9
    # hand case: student (log 3, 0) against a teacher sure of class 1 -> −log(1/4) over a batch of one
    student = torch.tensor([[math.log(3.0), 0.0]])
    assert confident_cross_entropy(student, torch.tensor([[0.1, 0.9]]), 0.8).item() == \
        pytest.approx(math.log(4.0), rel=1e-6)
    # a hard target: a confident wrong student costs far more than the bounded squared difference (≤ 2)
    assert confident_cross_entropy(torch.tensor([[20.0, 0.0]]), torch.tensor([[0.0, 1.0]])).item() > 19
    # no confident cloud: 0, and no gradient to follow
    zs_g = zs.clone().requires_grad_(True)
    none = confident_cross_entropy(zs_g, torch.full((9, 4), 0.25), 0.5)
    none.backward()
    assert none.item() == 0 and torch.all(zs_g.grad == 0)
    zs_g.grad = None
    pt_g = pt.clone().requires_grad_(True)
    confident_cross_entropy(zs_g, pt_g).backward()
    assert zs_g.grad.abs().sum() > 0 and pt_g.grad is None
    with pytest.raises(ValueError, match="threshold"):
        confident_cross_entropy(zs, pt, 1.0)
    with pytest.raises(ValueError, match="same shape"):
        confident_cross_entropy(zs, pt[:3])
    with pytest.raises(ValueError, match="teacher_probs contains NaN"):
        confident_cross_entropy(zs, torch.full((9, 4), float("nan")))


@pytest.mark.parametrize("zs,zt,match", [
    (torch.randn(3), torch.randn(3), "student_logits"),
    (torch.randn(2, 3), torch.randn(2, 1), "teacher_logits"),
    (torch.full((2, 3), float("nan")), torch.randn(2, 3), "student_logits contains NaN"),
    (torch.randn(2, 3), torch.randn(3, 3), "same shape"),
    (torch.randn(2, 3), torch.randn(2, 3), "threshold"),
    ([[1.0, 2.0]], torch.randn(1, 2), "torch.Tensor"),
])
def test_softmax_consistency_rejects_bad_input(zs, zt, match):
    with pytest.raises(ValueError, match=match):
        softmax_consistency(zs, zt, 1.0 if match == "threshold" else 0.0)


def test_ema_update_averages_parameters_and_statistics_and_copies_counts():
    torch.manual_seed(0)
    student = nn.Sequential(nn.Linear(3, 2), nn.BatchNorm1d(2))
    teacher = nn.Sequential(nn.Linear(3, 2), nn.BatchNorm1d(2))
    student.train()(torch.randn(5, 3))  # moves the student's running statistics and batch count
    before = {k: v.clone() for k, v in teacher.state_dict().items()}
    ema_update(teacher, student, 0.75)
    for k, v in teacher.state_dict().items():
        s = student.state_dict()[k]
        if v.is_floating_point():
            assert torch.allclose(v, 0.75 * before[k] + 0.25 * s), k
        else:
            assert torch.equal(v, s), k
    ema_update(teacher, student, 0.0)
    for k, v in teacher.state_dict().items():
        assert torch.equal(v, student.state_dict()[k]), k
    with pytest.raises(ValueError, match="decay"):
        ema_update(teacher, student, 1.5)
    with pytest.raises(ValueError, match="differ"):
        ema_update(nn.Linear(3, 2), nn.Linear(3, 4), 0.5)
    with pytest.raises(ValueError, match="differ"):
        ema_update(nn.Linear(3, 2), nn.Sequential(nn.Linear(3, 2), nn.Linear(2, 2)), 0.5)


def test_sigmoid_rampup_values():
    assert sigmoid_rampup(0.0, 0.5) == pytest.approx(math.exp(-5.0))
    assert sigmoid_rampup(0.25, 0.5) == pytest.approx(math.exp(-1.25))
    assert sigmoid_rampup(0.5, 0.5) == 1.0 and sigmoid_rampup(0.9, 0.5) == 1.0
    assert sigmoid_rampup(0.0, 0.0) == 1.0
    with pytest.raises(ValueError, match="length"):
        sigmoid_rampup(0.1, -1.0)


def test_perturb_padded_keeps_a_random_subset_of_each_cloud():
    g = torch.Generator().manual_seed(0)
    lengths = torch.tensor([10, 1, 7])
    points = torch.zeros(3, 10, 3)
    for b, n in enumerate(lengths.tolist()):
        points[b, :n] = torch.randn(n, 3, generator=g)
    for keep_min in (0.5, 1.0):
        out, new = perturb_padded(points, lengths, keep_min, 0.0, generator=g)
        assert out.shape == points.shape
        assert torch.all(new <= lengths) and torch.all(new >= torch.ceil(keep_min * lengths).long())
        assert new[1] == 1
        for b in range(3):
            kept, orig = out[b, : new[b]], points[b, : lengths[b]]
            # every kept point is one of the cloud's own, each at most once; padding is zero
            d = torch.cdist(kept, orig)
            assert torch.all(d.min(1).values == 0) and len(set(d.argmin(1).tolist())) == int(new[b])
            assert torch.all(out[b, new[b]:] == 0)
        if keep_min == 1.0:
            assert torch.equal(new, lengths)
    # jitter moves every kept point by noise of the stated spread, and nothing else
    big = torch.randn(1, 4000, 3, generator=g)
    out, new = perturb_padded(big, torch.tensor([4000]), 1.0, 0.01, generator=g)
    moved = out[0] - big[0, torch.cdist(out[0], big[0]).argmin(1)]
    assert moved.std().item() == pytest.approx(0.01, rel=0.05)


def test_perturb_padded_stretches_each_axis_within_the_bound():
    """scale > 1: every cloud is multiplied by one factor per axis in [1/scale, scale], the factors differ
    between clouds and axes, and padding stays zero; scale 1 draws nothing, so the copy is the plain one."""
    g = torch.Generator().manual_seed(0)
    lengths = torch.tensor([6, 4, 6, 5])
    points = torch.zeros(4, 6, 3)
    for b, n in enumerate(lengths.tolist()):
        points[b, :n] = torch.rand(n, 3, generator=g) + 0.5  # away from 0, so ratios are defined
    out, new = perturb_padded(points, lengths, 1.0, 0.0, generator=torch.Generator().manual_seed(1),
                              scale=1.5)
    plain, _ = perturb_padded(points, lengths, 1.0, 0.0, generator=torch.Generator().manual_seed(1))
    assert torch.equal(new, lengths)
    factors = []
    for b, n in enumerate(lengths.tolist()):
        ratio = out[b, :n] / plain[b, :n]  # the same subset order: the stretch draws come after it
        assert torch.allclose(ratio, ratio[0].expand_as(ratio), atol=1e-6)
        assert torch.all(ratio[0] >= 1 / 1.5 - 1e-6) and torch.all(ratio[0] <= 1.5 + 1e-6)
        assert torch.all(out[b, n:] == 0)
        factors.append(ratio[0])
    assert torch.stack(factors).std() > 0.05
    again, _ = perturb_padded(points, lengths, 1.0, 0.0, generator=torch.Generator().manual_seed(1),
                              scale=1.0)
    assert torch.equal(again, plain)


@pytest.mark.parametrize("kwargs,match", [
    (dict(points=torch.zeros(2, 5)), "points"),
    (dict(lengths=torch.tensor([5])), "lengths"),
    (dict(keep_min=0.0), "keep_min"),
    (dict(jitter=-0.1), "jitter"),
    (dict(jitter=float("nan")), "jitter"),
    (dict(scale=0.5), "scale"),
    (dict(scale=float("inf")), "scale"),
])
def test_perturb_padded_rejects_bad_input(kwargs, match):
    args = dict(points=torch.zeros(2, 5, 3), lengths=torch.tensor([5, 3]), keep_min=0.5, jitter=0.0)
    with pytest.raises(ValueError, match=match):
        perturb_padded(**{**args, **kwargs})
