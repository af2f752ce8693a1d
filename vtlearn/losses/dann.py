"""Gradient reversal for DANN (Ganin et al., JMLR 2016), a UDA baseline beyond thesis ch.7.

The gradient reversal layer R_λ is the identity forward and multiplies the gradient by −λ backward,
so a domain classifier placed after it trains the feature extractor to *confuse* the domains
(Ganin et al. 2016, eq. 13-14). ``dann_lambda`` is their schedule ``λ_p = 2/(1+exp(−γp)) − 1``
with ``γ = 10`` and training progress ``p ∈ [0, 1]``.
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


def domain_adversarial_loss(logits_source: torch.Tensor, logits_target: torch.Tensor) -> torch.Tensor:
    """Binary cross-entropy of a domain classifier: source labelled 1, target 0.

    Both domains are weighted equally (mean of the two per-domain means), so unequal batch sizes do not
    tilt the discriminator.

    Shapes:
        logits_source (n_s,) or (n_s, 1), logits_target (n_t,) or (n_t, 1) -> scalar
    """
    for name, t in (("logits_source", logits_source), ("logits_target", logits_target)):
        if t.numel() == 0 or not torch.isfinite(t).all():
            raise ValueError(f"{name} must be non-empty and finite, got shape {tuple(t.shape)}")
    ls = logits_source.reshape(-1)
    lt = logits_target.reshape(-1)
    return 0.5 * (
        F.binary_cross_entropy_with_logits(ls, torch.ones_like(ls))
        + F.binary_cross_entropy_with_logits(lt, torch.zeros_like(lt))
    )
