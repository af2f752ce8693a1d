"""Class-prior matching on the target stream (models/components/class_balance.py): ReMixMatch's
distribution alignment and the Sinkhorn-Knopp balanced assignment."""

import pytest
import torch

from vtlearn.models.components.class_balance import align_distribution, sinkhorn_balance


def _biased_probs(n_per_class=10, k=4, bias=2.0, seed=0):
    """Probabilities of a classifier that ranks each cloud's class above the others by 2 logits, plus
    noise, but adds ``bias`` to class 0 for every cloud: the argmax over-predicts class 0."""
    g = torch.Generator().manual_seed(seed)
    y = torch.arange(n_per_class * k) % k
    logits = 2.0 * torch.nn.functional.one_hot(y, k).float() + 0.5 * torch.randn(len(y), k, generator=g)
    logits[:, 0] += bias
    return logits.softmax(-1), y


def test_sinkhorn_balance_meets_both_marginals_and_undoes_a_class_bias():
    probs, y = _biased_probs()
    assert (probs.argmax(-1) == y).float().mean() < 0.7  # the bias costs the argmax
    q = sinkhorn_balance(probs)
    assert torch.allclose(q.sum(-1), torch.ones(len(y)), atol=1e-5)
    assert torch.allclose(q.sum(0), torch.full((4,), 10.0), atol=1e-3)
    assert (q.argmax(-1) == y).float().mean() >= 0.95
    # a non-uniform prior sets the column sums
    prior = torch.tensor([0.4, 0.2, 0.2, 0.2])
    assert torch.allclose(sinkhorn_balance(probs, prior).sum(0), 40 * prior, atol=1e-3)


def test_sinkhorn_balance_keeps_an_assignment_that_is_already_balanced():
    """Exactly balanced, confident predictions are a fixed point: the scaling is uniform."""
    y = torch.arange(12) % 3
    probs = 0.8 * torch.nn.functional.one_hot(y, 3).float() + 0.1 * (1 - torch.nn.functional.one_hot(y, 3))
    q = sinkhorn_balance(probs)
    assert torch.allclose(q, probs, atol=1e-6)


@pytest.mark.parametrize("probs,prior,match", [
    (torch.rand(5), None, "probs must have shape"),
    (torch.rand(5, 1), None, "probs must have shape"),
    (torch.full((2, 3), float("nan")), None, "probs contains NaN"),
    (-torch.rand(2, 3), None, "negative"),
    (torch.rand(4, 3), torch.tensor([0.5, 0.5]), r"prior must have shape \(3,\)"),
    (torch.rand(4, 3), torch.tensor([0.5, 0.5, 0.0]), "positive"),
    (torch.rand(4, 3), torch.tensor([0.5, 0.5, 0.5]), "sum to 1"),
    ([[0.5, 0.5]], None, "torch.Tensor"),
])
def test_sinkhorn_balance_rejects_bad_input(probs, prior, match):
    with pytest.raises(ValueError, match=match):
        sinkhorn_balance(probs, prior)


def test_sinkhorn_balance_rejects_bad_settings():
    with pytest.raises(ValueError, match="iters"):
        sinkhorn_balance(torch.rand(4, 3), iters=0)
    with pytest.raises(ValueError, match="tol"):
        sinkhorn_balance(torch.rand(4, 3), tol=0.0)


def test_align_distribution_scales_by_the_prior_ratio():
    probs, y = _biased_probs()
    uniform = torch.full((4,), 0.25)
    # the identity when the target mean is the source prior
    assert torch.allclose(align_distribution(probs, uniform, uniform), probs, atol=1e-6)
    # a hand case: p ⊙ ρ_s / ρ_t, renormalised
    p = torch.tensor([[0.6, 0.3, 0.1]])
    out = align_distribution(p, torch.tensor([0.5, 0.25, 0.25]), torch.tensor([0.25, 0.5, 0.25]))
    expected = torch.tensor([0.6 * 2, 0.3 * 0.5, 0.1 * 1.0])
    assert torch.allclose(out, (expected / expected.sum())[None], atol=1e-6)
    # aligned to the batch's own mean, the over-predicted class loses its lead and the argmax recovers
    aligned = align_distribution(probs, uniform, probs.mean(0))
    assert torch.allclose(aligned.sum(-1), torch.ones(len(y)), atol=1e-6)
    assert aligned.mean(0)[0] < probs.mean(0)[0]
    assert (aligned.argmax(-1) == y).float().mean() > (probs.argmax(-1) == y).float().mean()


@pytest.mark.parametrize("kwargs,match", [
    (dict(source_prior=torch.full((3,), 1 / 3)), r"source_prior must have shape \(4,\)"),
    (dict(target_mean=torch.tensor([0.5, 0.5, 0.0, 0.0])), "target_mean must be finite and positive"),
    (dict(probs=torch.full((2, 4), float("inf"))), "probs contains NaN or inf"),
])
def test_align_distribution_rejects_bad_input(kwargs, match):
    args = dict(probs=torch.full((2, 4), 0.25), source_prior=torch.full((4,), 0.25),
                target_mean=torch.full((4,), 0.25))
    with pytest.raises(ValueError, match=match):
        align_distribution(**{**args, **kwargs})
