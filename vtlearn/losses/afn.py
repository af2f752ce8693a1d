"""Stepwise adaptive feature norm (beyond the thesis).

Xu, Li, Yang and Lin, "Larger Norm More Transferable: An Adaptive Feature Norm Approach for Unsupervised
Domain Adaptation" (ICCV 2019), SAFN, eq. 6:

    L_SAFN = (1/n)·Σ_i ( ‖f_i‖₂ − (‖f_i‖₂|_{θ_{k−1}} + Δr) )²

where ‖f_i‖₂|_{θ_{k−1}} is the norm the cloud's feature had under the current weights, held fixed (no
gradient), and Δr the residual step. The value is always Δr²; its gradient, −2Δr·∂‖f_i‖/∂θ averaged, asks
every feature's norm to grow by Δr, step after step, on source and target alike. Their finding: the
target features of a source-trained network have much smaller norms than the source ones, and the
classifier's decisions on small-norm features are the ones that transfer badly, so both domains are pushed
to large norms together rather than aligned to each other. A PointNet fits that picture: its global feature
is a max over the cloud's points, so a tactile cloud of 30-120 points gives smaller maxima, hence smaller
norms further up, than a visual cloud of 1024. They add ``λ·(L_SAFN(source) + L_SAFN(target))`` with
λ = 0.05 and Δr = 1 (their Office-31 and VisDA setting) to a cross-entropy of weight 1, on the bottleneck
feature that their classifier reads.
"""

from __future__ import annotations

import torch

from vtlearn.losses.mmd import check_features
from vtlearn.validation import as_real

__all__ = ["AFN_STEP", "adaptive_feature_norm"]

AFN_STEP = 1.0
"""Xu et al.'s residual step Δr (Office-31, VisDA)."""


def adaptive_feature_norm(features: torch.Tensor, step: float = AFN_STEP
                          ) -> tuple[torch.Tensor, torch.Tensor]:
    """L_SAFN of one domain's batch of features (Xu et al. 2019, eq. 6 in the module docstring), and the
    batch's mean feature norm.

    Shapes:
        features (n, d), n ≥ 1, d ≥ 1 -> (scalar L_SAFN, equal to step² with a gradient that raises every
        norm; scalar mean ‖f_i‖₂, detached)
    """
    check_features(features, "features")
    as_real(step, "step", low=0.0, open_low=True)
    norms = features.norm(p=2, dim=1)
    loss = ((norms - (norms.detach() + step)) ** 2).mean()
    return loss, norms.mean().detach()
