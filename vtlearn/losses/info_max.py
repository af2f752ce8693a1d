"""Information maximisation on unlabelled target predictions (beyond the thesis).

    L_IM = (1/n)·Σ_i H(p_i) − H(p̄),    p_i = softmax(z_i),    p̄ = (1/n)·Σ_i p_i

The first term (conditional entropy) asks each target cloud for a confident prediction; the second
(marginal entropy, subtracted) keeps the batch's predictions spread over the classes, so the first
cannot be met by putting every cloud in one class. This is the regularised information maximisation
of Krause, Perona and Gomes (NIPS 2010), used for unsupervised domain adaptation by Shi and Sha (ICML
2012) and as the "IM" loss of SHOT (Liang, Hu and Feng, ICML 2020). Thesis eq. 7.8 aligns the marginal
feature distributions only; this term adds what those papers found the alignment lacks, a target
decision boundary that avoids dense regions of target data. Entropies are in nats, and the entropy
is concave (H(p̄) ≥ mean H(p_i)), so for k classes ``−log k ≤ L_IM ≤ 0``: ``−log k`` for confident
predictions that use every class equally often, 0 for identical predictions (confident or uniform) on
every cloud.
"""

from __future__ import annotations

import torch
import torch.nn.functional as F

from vtlearn.validation import check_class_scores

__all__ = ["information_maximization"]


def information_maximization(logits: torch.Tensor) -> tuple[torch.Tensor, dict[str, torch.Tensor]]:
    """L_IM of a batch of target logits, and its two entropies.

    Shapes:
        logits (n, k), n ≥ 1, k ≥ 2 -> (scalar L_IM, {"cond_entropy": scalar, "marginal_entropy": scalar},
        the parts detached)
    """
    check_class_scores(logits, "logits")
    log_p = F.log_softmax(logits, dim=1)
    p = log_p.exp()
    cond = -(p * log_p).sum(1).mean()
    p_bar = p.mean(0)
    marginal = -(p_bar * torch.log(p_bar.clamp_min(torch.finfo(p_bar.dtype).tiny))).sum()
    return cond - marginal, {"cond_entropy": cond.detach(), "marginal_entropy": marginal.detach()}
