"""Mean-teacher consistency between two predictions of the same unlabelled clouds (beyond the thesis).

    L_cons = (1/n)·Σ_i m_i·Σ_c (softmax(z_i)_c − softmax(z'_i)_c)²,    m_i = [max_c softmax(z'_i)_c ≥ τ]

``z`` are the student network's logits of a perturbed copy of each target cloud and ``z'`` the logits of
an exponential moving average of its weights (the teacher) on another perturbed copy, without gradient.
This is the squared-difference consistency of Mean Teacher (Tarvainen and Valpola, NeurIPS 2017),
which French, Mackiewicz and Fisher (ICLR 2018) used for unsupervised domain adaptation: the target
clouds, which carry no labels, ask the student to agree with a smoothed version of itself under input
noise. Thesis eq. 7.8 has no such term. The squared difference is bounded (0 ≤ L_cons ≤ 2), so a wrong
teacher cannot pull the student as hard as a cross-entropy against its argmax would. French et al. count
only the clouds on which the teacher is confident (``threshold`` τ; 0 counts every cloud), averaging over
the whole batch.

FixMatch (Sohn et al., NeurIPS 2020) and AdaMatch (Berthelot et al., ICLR 2022, its domain-adaptation
form) use a cross-entropy against the teacher's argmax instead, on a strongly perturbed student copy:

    L_hard = (1/n)·Σ_i m_i·CE(z_i, argmax_c p'_ic)

(:func:`confident_cross_entropy`). It is unbounded: a confident wrong teacher pulls as hard as a label.
"""

from __future__ import annotations

import torch
import torch.nn.functional as F

from vtlearn.validation import as_real, check_class_scores

__all__ = ["softmax_consistency", "probability_consistency", "confident_cross_entropy"]


def softmax_consistency(student_logits: torch.Tensor, teacher_logits: torch.Tensor,
                        threshold: float = 0.0) -> torch.Tensor:
    """L_cons of a batch, counting the clouds whose teacher confidence is at least ``threshold``; the
    gradient flows into ``student_logits`` only.

    Shapes:
        student_logits (n, k), teacher_logits (n, k), n ≥ 1, k ≥ 2 -> scalar in [0, 2]
    """
    if not isinstance(teacher_logits, torch.Tensor):
        raise ValueError(f"teacher_logits must be a torch.Tensor, got {type(teacher_logits).__name__}")
    return probability_consistency(student_logits, teacher_logits.detach().softmax(-1), threshold,
                                   name="teacher_logits")


def probability_consistency(student_logits: torch.Tensor, teacher_probs: torch.Tensor,
                            threshold: float = 0.0, name: str = "teacher_probs") -> torch.Tensor:
    """L_cons against the teacher's probabilities ``p'`` themselves (for instance after distribution
    alignment, :func:`~vtlearn.models.components.class_balance.align_distribution`); ``m_i`` reads the
    peak of ``p'``. ``name`` is the argument the errors name.

    Shapes:
        student_logits (n, k), teacher_probs (n, k) rows of probabilities -> scalar in [0, 2]
    """
    p_teacher, confident = _confident(student_logits, teacher_probs, threshold, name)
    per_cloud = (student_logits.softmax(-1) - p_teacher).pow(2).sum(-1)
    return (per_cloud * confident).mean()


def confident_cross_entropy(student_logits: torch.Tensor, teacher_probs: torch.Tensor,
                            threshold: float = 0.0, name: str = "teacher_probs") -> torch.Tensor:
    """L_hard: FixMatch's cross-entropy of the student's logits against the teacher's argmax, on the clouds
    whose teacher peak is at least ``threshold``, averaged over the whole batch (a batch with no confident
    cloud gives 0); the gradient flows into ``student_logits`` only.

    Shapes:
        student_logits (n, k), teacher_probs (n, k) rows of probabilities -> scalar >= 0
    """
    p_teacher, confident = _confident(student_logits, teacher_probs, threshold, name)
    per_cloud = F.cross_entropy(student_logits, p_teacher.argmax(-1), reduction="none")
    return (per_cloud * confident).mean()


def _confident(student_logits: torch.Tensor, teacher_probs: torch.Tensor, threshold: float,
               name: str) -> tuple[torch.Tensor, torch.Tensor]:
    """The checked, detached teacher probabilities and the mask ``m`` of the clouds they are confident on."""
    check_class_scores(student_logits, "student_logits")
    check_class_scores(teacher_probs, name)
    if student_logits.shape != teacher_probs.shape:
        raise ValueError(f"student_logits {tuple(student_logits.shape)} and {name} "
                         f"{tuple(teacher_probs.shape)} must have the same shape")
    threshold = as_real(threshold, "threshold", low=0.0, high=1.0, open_high=True)
    p_teacher = teacher_probs.detach()
    return p_teacher, (p_teacher.amax(-1) >= threshold).to(student_logits.dtype)
