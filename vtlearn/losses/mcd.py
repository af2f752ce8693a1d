"""Maximum classifier discrepancy, MCD (beyond the thesis).

Saito, Watanabe, Ushiku and Harada, "Maximum Classifier Discrepancy for Unsupervised Domain Adaptation"
(CVPR 2018), eq. 1-5. Two classifiers F₁ and F₂ read the same feature G(x):

    d(p₁, p₂) = (1/K)·Σ_k |p₁ₖ − p₂ₖ|                       (eq. 1, averaged over the target batch)
    step A:  min_{G,F₁,F₂}  L_s = CE(F₁∘G) + CE(F₂∘G)       on labelled source clouds (eq. 2)
    step B:  min_{F₁,F₂}    L_s − L_adv,  L_adv = d(F₁∘G(x_t), F₂∘G(x_t))   (eq. 3-4)
    step C:  min_G          L_adv                           (eq. 5)

Where thesis eq. 7.8's MK-MMD and CORAL (and DANN's discriminator) align the marginal feature
distributions without looking at the classifier, MCD uses the classifiers themselves as the critic: the
two classifiers, both right on the source, are pulled apart on the target clouds that lie outside the
source support (the clouds where they can disagree), and the feature extractor moves those clouds to
where both agree, inside the class regions. It is the global alignment of PointDAN (Qin et al., NeurIPS
2019), the method of the PointDA-10 benchmark of point-cloud adaptation.

MCD alternates the three steps with three optimisers (and repeats step C four times). Here they are one
simultaneous step: the discrepancy enters the loss as ``−w·d`` with the feature passed through a gradient
reversal layer (:func:`vtlearn.losses.dann.grad_reverse`) before both classifiers, so the classifiers
descend ``−w·d`` (they raise d, step B) while the reversed gradient makes the feature extractor descend
``+w·d`` (it lowers d, step C), as DANN's reversal turns its alternating minimax into one step. The
classifiers' step-A cross-entropy is the model's own. :func:`mcd_adversarial_loss` is that loss term.
"""

from __future__ import annotations

import torch
from torch import nn

from vtlearn.losses.dann import grad_reverse
from vtlearn.validation import as_real, check_class_scores

__all__ = ["classifier_discrepancy", "mcd_adversarial_loss"]


def classifier_discrepancy(logits_1: torch.Tensor, logits_2: torch.Tensor) -> torch.Tensor:
    """MCD's discrepancy ``d(p₁, p₂)`` (Saito et al. 2018 eq. 1): the mean absolute difference of the two
    classifiers' softmax probabilities, over classes and clouds. It lies in [0, 2/K]: 0 when the two agree
    on every cloud, 2/K when each cloud gets two different one-hot predictions.

    Shapes:
        logits_1 (n, K), logits_2 (n, K) -> ()
    """
    check_class_scores(logits_1, "logits_1")
    check_class_scores(logits_2, "logits_2")
    if logits_1.shape != logits_2.shape:
        raise ValueError(f"logits_2: shape {tuple(logits_2.shape)} differs from logits_1's "
                         f"{tuple(logits_1.shape)}")
    return (logits_1.softmax(-1) - logits_2.softmax(-1)).abs().mean()


def mcd_adversarial_loss(features: torch.Tensor, classifier_1: nn.Module, classifier_2: nn.Module,
                         weight: float, reversal: float = 1.0) -> tuple[torch.Tensor, torch.Tensor]:
    """MCD's steps B and C in one loss: ``−weight·d(F₁(R(z)), F₂(R(z)))`` with ``R`` the gradient reversal
    of coefficient ``reversal``. Its gradient raises the discrepancy in the classifiers' weights and, through
    the reversal, lowers it in everything that made ``features``.

    Returns:
        (the loss term, the discrepancy d detached).

    Shapes:
        features (n, d) target features (fc2 after dropout here) -> ((), ())
    """
    if features.ndim != 2 or features.shape[0] < 1:
        raise ValueError(f"features: expected a non-empty (n, d) batch, got shape {tuple(features.shape)}")
    weight = as_real(weight, "weight", low=0.0)
    reversed_features = grad_reverse(features, as_real(reversal, "reversal", low=0.0))
    d = classifier_discrepancy(classifier_1(reversed_features), classifier_2(reversed_features))
    return -weight * d, d.detach()
