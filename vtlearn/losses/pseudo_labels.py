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

Thesis eq. 7.8 aligns the marginal feature distributions; these labels add a class-wise signal on the
target clouds (:class:`~vtlearn.models.xavtnet.XAVTNet` ``pseudo_label_weight``). At the 45-55 %
tactile accuracy that VTLoss reaches here, 33-41 % of the kept labels are wrong (docs/xavtnet.md).
"""

from __future__ import annotations

import math

import torch
import torch.nn.functional as F

from vtlearn.losses.mmd import check_features

__all__ = ["centroid_pseudo_labels"]


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
    confidence = probs.max(1).values
    kept = torch.full((n,), -1, dtype=torch.long, device=features.device)
    for c in labels.unique():
        members = torch.nonzero(labels == c).flatten()
        order = torch.argsort(confidence[members], descending=True)
        kept[members[order[: math.ceil(fraction * len(members))]]] = c
    return kept
