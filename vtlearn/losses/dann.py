"""Gradient reversal for DANN (Ganin et al., JMLR 2016), a UDA baseline beyond thesis ch.7.

The gradient reversal layer R_λ is the identity forward and multiplies the gradient by −λ backward,
so a domain classifier placed after it trains the feature extractor to *confuse* the domains
(Ganin et al. 2016, eq. 13-14). ``dann_lambda`` is their schedule ``λ_p = 2/(1+exp(−γp)) − 1``
with ``γ = 10`` and training progress ``p ∈ [0, 1]``. The same reversal and ramp train CDAN's
conditional discriminator (:mod:`vtlearn.losses.cdan`).
"""

from __future__ import annotations

import math

import torch
import torch.nn.functional as F
from torch import nn

from vtlearn.validation import as_real

__all__ = ["grad_reverse", "GradientReversal", "dann_lambda", "domain_adversarial_loss"]


class _GradReverse(torch.autograd.Function):
    @staticmethod
    def forward(ctx, x: torch.Tensor, lambd: float) -> torch.Tensor:
        ctx.lambd = lambd
        return x.view_as(x)

    @staticmethod
    def backward(ctx, grad_output: torch.Tensor):
        return -ctx.lambd * grad_output, None


def grad_reverse(x: torch.Tensor, lambd: float = 1.0) -> torch.Tensor:
    """Identity forward, gradient × (−lambd) backward. Shapes: any -> same."""
    return _GradReverse.apply(x, as_real(lambd, "lambd", low=0.0))


class GradientReversal(nn.Module):
    """Module form of :func:`grad_reverse`; set ``lambd`` between steps to follow a schedule."""

    def __init__(self, lambd: float = 1.0) -> None:
        super().__init__()
        self.lambd = float(lambd)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return grad_reverse(x, self.lambd)

    def extra_repr(self) -> str:
        return f"lambd={self.lambd}"


def dann_lambda(progress: float, gamma: float = 10.0) -> float:
    """Ganin et al.'s ramp ``2/(1+exp(−γp)) − 1`` for progress ``p`` in [0, 1]."""
    progress = as_real(progress, "progress", low=0.0, high=1.0)
    return 2.0 / (1.0 + math.exp(-gamma * progress)) - 1.0


def domain_adversarial_loss(logits_source: torch.Tensor, logits_target: torch.Tensor,
                            weights_source: torch.Tensor | None = None,
                            weights_target: torch.Tensor | None = None) -> torch.Tensor:
    """Binary cross-entropy of a domain classifier: source labelled 1, target 0.

    Both domains are weighted equally (mean of the two per-domain means), so unequal batch sizes do not
    tilt the discriminator. Optional per-cloud weights (CDAN+E's entropy weights,
    :func:`vtlearn.losses.cdan.entropy_weights`) turn each domain's mean into a weighted mean, the
    weights normalised within their domain as in Long et al.'s code; they carry no gradient.

    Shapes:
        logits_source (n_s,) or (n_s, 1), logits_target (n_t,) or (n_t, 1), weights_source (n_s,),
        weights_target (n_t,) -> scalar
    """
    for name, t in (("logits_source", logits_source), ("logits_target", logits_target)):
        if t.numel() == 0 or not torch.isfinite(t).all():
            raise ValueError(f"{name} must be non-empty and finite, got shape {tuple(t.shape)}")
    ls = logits_source.reshape(-1)
    lt = logits_target.reshape(-1)
    return 0.5 * (_weighted_bce(ls, 1.0, weights_source, "weights_source")
                  + _weighted_bce(lt, 0.0, weights_target, "weights_target"))


def _weighted_bce(logits: torch.Tensor, label: float, weights: torch.Tensor | None, name: str
                  ) -> torch.Tensor:
    losses = F.binary_cross_entropy_with_logits(logits, torch.full_like(logits, label), reduction="none")
    if weights is None:
        return losses.mean()
    weights = weights.detach().reshape(-1)
    if weights.shape != losses.shape or not torch.isfinite(weights).all() or (weights < 0).any() \
            or weights.sum() <= 0:
        raise ValueError(f"{name}: expected {losses.numel()} finite non-negative weights with a positive "
                         f"sum, got shape {tuple(weights.shape)}")
    return (weights * losses).sum() / weights.sum()
