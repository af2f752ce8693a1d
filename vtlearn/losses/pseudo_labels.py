"""Centroid pseudo-labels for self-training on the unlabelled target domain (beyond the thesis).

SHOT (Liang, Hu and Feng, ICML 2020, eqs. 4-6) labels the target samples without their labels:

    c_k⁽⁰⁾ = Σ_i p_ik·f̂_i / Σ_i p_ik,        ŷ_i = argmax_k cos(f̂_i, c_k⁽⁰⁾)
    c_k⁽¹⁾ = Σ_i [ŷ_i = k]·f̂_i / Σ_i [ŷ_i = k],  ŷ_i = argmax_k cos(f̂_i, c_k⁽¹⁾)

with ``f̂_i`` a target sample's feature (here scaled to unit length) and ``p_i`` its softmax. Each
class centroid is first the softmax-weighted mean of the target features, then the mean of the
samples assigned to it, and each sample takes the nearest centroid by cosine. Where the network's
decision boundary cuts through a cluster of target features, the centroid labels follow the cluster
instead.

Not every label is kept. Class-balanced self-training (CBST; Zou, Yu, Kumar and Wang, ECCV 2018)
keeps, within each pseudo-class, the ``fraction`` of its samples that the network is most confident
about (the largest softmax probability). The balance per class stops the easy classes from filling
the selection, and the confidence ranks within a class. The rest get the label ``-1``, for
``F.cross_entropy(..., ignore_index=-1)``.

Where the target samples come in groups known to share a class (a robot knows which of its touches fell
on one object, not what the object is), :func:`group_vote_pseudo_labels` labels each group by the argmax
of its members' mean softmax instead, with the same class-balanced selection over groups.

Thesis eq. 7.8 aligns the marginal feature distributions; these labels add a class-wise signal on the
target clouds (:class:`~vtlearn.models.xavtnet.XAVTNet` ``pseudo_label_weight``). At the 45-55 %
tactile accuracy that VTLoss reaches here, 33-41 % of the kept labels are wrong (docs/xavtnet_results.md).
"""

from __future__ import annotations

import math

import torch
import torch.nn.functional as F

from vtlearn.losses.mmd import check_features

__all__ = ["centroid_pseudo_labels", "group_vote_pseudo_labels"]


def centroid_pseudo_labels(
    features: torch.Tensor, probs: torch.Tensor, fraction: float = 1.0
) -> torch.Tensor:
    """SHOT's centroid labels of a target set, with CBST's class-balanced selection.

    Args:
        features: one feature row per target sample (any layer; rows are scaled to unit length).
        probs: the network's softmax for the same samples; rows sum to 1.
        fraction: the share of each pseudo-class kept, in (0, 1]; at least one sample is kept per
            non-empty pseudo-class. 1 keeps every label.

    Returns:
        The pseudo-label of each sample, or ``-1`` where it is not kept.

    Shapes:
        features (n, d), probs (n, k), n ≥ 1, k ≥ 2 -> (n,) int64 in {-1, 0, ..., k-1}
    """
    check_features(features, "features")
    check_features(probs, "probs")
    n, k = probs.shape
    if features.shape[0] != n or k < 2:
        raise ValueError(f"features {tuple(features.shape)} and probs {tuple(probs.shape)}: need (n, d) and "
                         f"(n, k >= 2) with the same n")
    if (probs < 0).any() or not torch.allclose(probs.sum(1), probs.new_ones(n), atol=1e-4):
        raise ValueError("probs: rows must be probabilities (>= 0, summing to 1)")
    if not (isinstance(fraction, (int, float)) and 0 < fraction <= 1):
        raise ValueError(f"fraction must be in (0, 1], got {fraction!r}")
    f = F.normalize(features.to(probs.dtype), dim=1)
    weights = probs
    for _ in range(2):  # eq. 4 (soft weights), then eq. 6 (the hard labels of eq. 5)
        centroids = F.normalize(weights.T @ f, dim=1)  # an empty class's centroid is 0: cosine 0 to all
        labels = (f @ centroids.T).argmax(1)
        weights = F.one_hot(labels, k).to(f.dtype)
    return _class_balanced(labels, probs.max(1).values, fraction)


def _class_balanced(labels: torch.Tensor, confidence: torch.Tensor, fraction: float) -> torch.Tensor:
    """CBST's selection: within each pseudo-class the ``fraction`` of its members with the largest
    ``confidence`` keep their label (at least one), the rest get ``-1``.

    Shapes:
        labels (n,) int64, confidence (n,) -> (n,) int64
    """
    kept = torch.full_like(labels, -1)
    for c in labels.unique():
        members = torch.nonzero(labels == c).flatten()
        order = torch.argsort(confidence[members], descending=True)
        kept[members[order[: math.ceil(fraction * len(members))]]] = c
    return kept


def group_vote_pseudo_labels(
    probs: torch.Tensor, groups: torch.Tensor, fraction: float = 1.0
) -> torch.Tensor:
    """Pseudo-labels voted over groups of target samples known to share a class, with CBST's selection.

    A robot knows which of its touches fell on the same object, though not what the object is. The
    touches of one object (a group) take one label, the argmax of their mean softmax,

        p̄_g = (1 / |g|) Σ_{i ∈ g} p_i,        ŷ_i = argmax_k p̄_gk  for every i ∈ g,

    the accumulation of evidence over touches that thesis 7.2.4 uses to recognise an object actively,
    here used to label the unlabelled target stream for self-training. A group's confidence is
    ``max_k p̄_gk``; within each pseudo-class the ``fraction`` of its *groups* with the largest confidence
    keep their label (at least one group per non-empty pseudo-class), so a group is kept or dropped whole.

    Args:
        probs: the network's softmax for each target sample; rows sum to 1.
        groups: one integer group id per sample (e.g. the tactile cloud's object instance).
        fraction: the share of each pseudo-class's groups kept, in (0, 1]. 1 keeps every label.

    Returns:
        The pseudo-label of each sample, or ``-1`` where its group is not kept.

    Shapes:
        probs (n, k), groups (n,) int64, n ≥ 1, k ≥ 2 -> (n,) int64 in {-1, 0, ..., k-1}
    """
    check_features(probs, "probs")
    n, k = probs.shape
    if k < 2:
        raise ValueError(f"probs {tuple(probs.shape)}: need (n, k >= 2)")
    if (probs < 0).any() or not torch.allclose(probs.sum(1), probs.new_ones(n), atol=1e-4):
        raise ValueError("probs: rows must be probabilities (>= 0, summing to 1)")
    if groups.shape != (n,) or groups.is_floating_point() or groups.is_complex():
        raise ValueError(f"groups: need one integer group id per sample, shape ({n},), got "
                         f"{tuple(groups.shape)} {groups.dtype}")
    if not (isinstance(fraction, (int, float)) and 0 < fraction <= 1):
        raise ValueError(f"fraction must be in (0, 1], got {fraction!r}")
    ids, member_of = torch.unique(groups.to(probs.device), return_inverse=True)
    mean = torch.zeros(len(ids), k, dtype=probs.dtype, device=probs.device).index_add_(0, member_of, probs)
    mean = mean / torch.bincount(member_of, minlength=len(ids)).to(probs.dtype)[:, None]
    confidence, group_labels = mean.max(1)
    return _class_balanced(group_labels, confidence, fraction)[member_of]
