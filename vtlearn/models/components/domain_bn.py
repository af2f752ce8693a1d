"""Batch normalisation with one set of running statistics per domain (beyond the thesis).

Li et al., "Adaptive Batch Normalization for practical domain adaptation" (AdaBN, Pattern Recognition
2018) observed that the batch-norm statistics of a network carry the domain: a network trained on one
domain and normalised at test time with the *other* domain's statistics transfers better. Chang et al.,
"Domain-Specific Batch Normalization for Unsupervised Domain Adaptation" (DSBN, CVPR 2019) keep the
statistics apart during training as well: each domain is normalised with its own batch statistics, and
the network is tested with the running statistics of the test domain.

For xAVTNet (thesis ch.7) the two domains are dense visual clouds (source) and sparse tactile clouds
(target). A max-pool over 30-120 tactile points is systematically smaller than one over 256-1024 visual
points, so the global feature, and every layer after it, has a different mean and spread per domain;
pooled statistics (one forward of both batches, as in DAN and Deep CORAL) normalise the tactile clouds
with a mixture dominated by neither.

:class:`DomainBatchNorm` keeps the affine parameters γ, β shared (AdaBN; the network has the same
parameters as with plain batch norm) and one running mean and variance per domain:

    y = γ · (x − μ_d) / sqrt(σ²_d + ε) + β,   d = the domain of the batch

with (μ_d, σ²_d) the batch statistics in training mode and domain d's running statistics in eval mode.
:func:`convert_batchnorm` swaps every ``BatchNorm1d`` of a module for one; :func:`set_bn_domain` picks the
domain of all of them.

Shapes:
    DomainBatchNorm: x (B, C) or (B, C, L) -> same shape.
"""

from __future__ import annotations

import torch
import torch.nn.functional as F
from torch import nn

from vtlearn.validation import as_int

__all__ = ["DOMAINS", "DomainBatchNorm", "convert_batchnorm", "set_bn_domain"]

DOMAINS = ("source", "target")


class DomainBatchNorm(nn.Module):
    """``BatchNorm1d`` with shared γ, β and running statistics per domain (module docstring).

    Args:
        num_features: C.
        eps, momentum: as in ``torch.nn.BatchNorm1d``.

    Attributes:
        domain: ``"source"`` or ``"target"``; the statistics used (and updated in training mode).

    Shapes:
        x (B, C) or (B, C, L) -> same shape.
    """

    def __init__(self, num_features: int, eps: float = 1e-5, momentum: float = 0.1) -> None:
        super().__init__()
        self.num_features = as_int(num_features, "num_features")
        self.eps, self.momentum = float(eps), float(momentum)
        self.weight = nn.Parameter(torch.ones(self.num_features))
        self.bias = nn.Parameter(torch.zeros(self.num_features))
        for d in DOMAINS:
            self.register_buffer(f"running_mean_{d}", torch.zeros(self.num_features))
            self.register_buffer(f"running_var_{d}", torch.ones(self.num_features))
        self.domain = "source"

    @classmethod
    def from_batchnorm(cls, bn: nn.BatchNorm1d) -> DomainBatchNorm:
        """A copy of ``bn`` whose statistics start from ``bn``'s in both domains."""
        if not bn.affine or not bn.track_running_stats:
            raise ValueError("bn: need affine=True and track_running_stats=True")
        out = cls(bn.num_features, bn.eps, 0.1 if bn.momentum is None else bn.momentum)
        with torch.no_grad():
            out.weight.copy_(bn.weight)
            out.bias.copy_(bn.bias)
            for d in DOMAINS:
                getattr(out, f"running_mean_{d}").copy_(bn.running_mean)
                getattr(out, f"running_var_{d}").copy_(bn.running_var)
        return out.to(bn.weight.device)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        if self.domain not in DOMAINS:
            raise ValueError(f"domain: expected one of {DOMAINS}, got {self.domain!r}")
        if x.dim() not in (2, 3) or x.shape[1] != self.num_features:
            raise ValueError(f"x: need shape (B, {self.num_features}) or (B, {self.num_features}, L), "
                             f"got {tuple(x.shape)}")
        return F.batch_norm(x, getattr(self, f"running_mean_{self.domain}"),
                            getattr(self, f"running_var_{self.domain}"), self.weight, self.bias,
                            self.training, self.momentum, self.eps)

    def extra_repr(self) -> str:
        return f"{self.num_features}, eps={self.eps}, momentum={self.momentum}, domain={self.domain}"


def convert_batchnorm(module: nn.Module) -> nn.Module:
    """Replace every ``BatchNorm1d`` inside ``module`` (in place) by a :class:`DomainBatchNorm` copy.

    Returns ``module``, or the replacement if ``module`` itself is a ``BatchNorm1d``.
    """
    if isinstance(module, nn.BatchNorm1d):
        return DomainBatchNorm.from_batchnorm(module)
    for name, child in module.named_children():
        new = convert_batchnorm(child)
        if new is not child:
            setattr(module, name, new)
    return module


def set_bn_domain(module: nn.Module, domain: str) -> int:
    """Set the domain of every :class:`DomainBatchNorm` in ``module``; returns how many there are."""
    if domain not in DOMAINS:
        raise ValueError(f"domain: expected one of {DOMAINS}, got {domain!r}")
    n = 0
    for m in module.modules():
        if isinstance(m, DomainBatchNorm):
            m.domain = domain
            n += 1
    return n
