"""Minimum class confusion on unlabelled target predictions (beyond the thesis).

Jin, Wang, Long and Wang, "Minimum Class Confusion for Versatile Domain Adaptation" (ECCV 2020), eq. 1-6:

    Ŷ = softmax(Z / T)                                   (temperature-rescaled target predictions)
    H_i = −Σ_j Ŷ_ij log Ŷ_ij,  W_ii = n·(1 + e^{−H_i}) / Σ_i' (1 + e^{−H_i'})  (entropy weights, no gradient)
    C_jj' = Σ_i W_ii Ŷ_ij Ŷ_ij'                          (class correlation, k × k)
    C̃_jj' = C_jj' / Σ_j'' C_j''j'                        (category normalisation, each column sums to 1)
    L_MCC = (1/k)·Σ_j Σ_{j'≠j} C̃_jj'

A target cloud confused between two classes puts weight on the off-diagonal entry of both; minimising the
sum asks every target prediction to commit to one class. Unlike the conditional entropy of
:mod:`vtlearn.losses.info_max`, the confusion is normalised per class, so a class that the batch predicts
rarely weighs as much as a frequent one, and the temperature (MCC's T = 2.5) keeps the loss from rewarding
over-confident logits. Where thesis eq. 7.8 aligns the marginal feature distributions only, this term acts
on the classifier's target decisions. The loss lies in [0, (k − 1)/k]: 0 when every cloud is one-hot and
every class is some cloud's, and (k − 1)/k when every prediction is uniform. A class that no cloud predicts
keeps its whole normalised column off the diagonal (1/k of loss), so the term also keeps the predictions
spread over the classes, as information maximisation's marginal entropy does.
"""

from __future__ import annotations

import torch
import torch.nn.functional as F

from vtlearn.validation import as_real, check_class_scores

__all__ = ["MCC_TEMPERATURE", "minimum_class_confusion"]

MCC_TEMPERATURE = 2.5
"""Jin et al.'s temperature, the one they use on every benchmark."""


def minimum_class_confusion(logits: torch.Tensor, temperature: float = MCC_TEMPERATURE
                            ) -> tuple[torch.Tensor, dict[str, torch.Tensor]]:
    """L_MCC of a batch of target logits (Jin et al. 2020, eq. 1-6 in the module docstring).

    Shapes:
        logits (n, k), n ≥ 1, k ≥ 2 -> (scalar L_MCC, {"mcc_diagonal": scalar mean of the normalised
        confusion's diagonal, detached})
    """
    check_class_scores(logits, "logits")
    as_real(temperature, "temperature", low=0.0, open_low=True)
    n, k = logits.shape
    log_p = F.log_softmax(logits / temperature, dim=1)
    p = log_p.exp()
    with torch.no_grad():
        weight = 1.0 + torch.exp((p * log_p).sum(1))  # 1 + e^{−H_i}
        weight = n * weight / weight.sum()
    confusion = (p * weight[:, None]).T @ p
    # column sums; eps only guards a class no cloud gives any probability (softmax makes that underflow)
    confusion = confusion / confusion.sum(0, keepdim=True).clamp_min(torch.finfo(p.dtype).tiny)
    diagonal = torch.diagonal(confusion)
    loss = (confusion.sum() - diagonal.sum()) / k
    return loss, {"mcc_diagonal": diagonal.mean().detach()}
