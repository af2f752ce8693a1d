"""Attracting and dispersing: neighbourhood clustering of the unlabelled target clouds (beyond the thesis).

AaD (Yang, Wang, Wang, Jui and van de Weijer, NeurIPS 2022, eq. 6) asks each target sample's prediction
to agree with those of its nearest neighbours in feature space and to differ from the rest of the batch:

    L_AaD = (1/n)·Σ_i [ −Σ_{j ∈ C_i} p_iᵀ s_j  +  λ·Σ_{m ∈ B_i} p_iᵀ p_m ]

``p_i`` is the softmax of target sample i in the batch, ``C_i`` its K nearest neighbours by cosine
similarity in a memory bank of the whole target set's features, ``s_j`` the softmax that the bank holds
for neighbour j (no gradient), and ``B_i`` the other samples of the batch. The first term pulls a sample
towards the class of its neighbourhood, the second pushes the batch's predictions apart, so the classes
do not collapse onto one. The objective is AaD's upper bound of a clustering objective in which nearby
features share predictions and far ones do not; it needs no labels and no class prior. Where the
network's decision boundary cuts through a cluster of tactile features, the neighbours' predictions
move the boundary off the cluster. Thesis eq. 7.8 aligns the marginal distributions instead.

:func:`neighbour_probs` looks the neighbours up; :func:`attract_disperse` is the loss. The bank itself,
its filling and its per-batch update, belong to :class:`~vtlearn.models.xavtnet.XAVTNet`
(``neighbour_weight``).
"""

from __future__ import annotations

import torch
import torch.nn.functional as F

from vtlearn.losses.mmd import check_features
from vtlearn.validation import as_int, as_real, check_class_scores

__all__ = ["neighbour_probs", "attract_disperse"]


@torch.no_grad()
def neighbour_probs(features: torch.Tensor, bank_features: torch.Tensor, bank_probs: torch.Tensor,
                    k: int, self_index: torch.Tensor | None = None,
                    valid: torch.Tensor | None = None) -> torch.Tensor:
    """The bank's probabilities ``s_j`` of each query's ``k`` nearest bank rows by cosine similarity.

    Args:
        features: the query samples' features (any layer; compared after scaling to unit length).
        bank_features, bank_probs: the bank's feature and softmax rows.
        k: neighbours per query, K of eq. 6.
        self_index: each query's own row in the bank, left out of its neighbours; ``None``: none.
        valid: the bank rows that hold a sample (rows not filled yet are never neighbours); ``None``: all.

    Shapes:
        features (n, d), bank_features (N, d), bank_probs (N, c), self_index (n,) int64, valid (N,) bool
        -> (n, k, c)
    """
    check_features(features, "features")
    check_features(bank_features, "bank_features")
    check_features(bank_probs, "bank_probs")
    n, big_n = features.shape[0], bank_features.shape[0]
    if bank_features.shape[1] != features.shape[1]:
        raise ValueError(f"features {tuple(features.shape)} and bank_features {tuple(bank_features.shape)} "
                         f"must have the same feature size")
    if bank_probs.shape[0] != big_n:
        raise ValueError(f"bank_probs has {bank_probs.shape[0]} rows, bank_features {big_n}")
    sim = F.normalize(features, dim=1) @ F.normalize(bank_features, dim=1).T
    if valid is not None:
        if valid.shape != (big_n,) or valid.dtype != torch.bool:
            raise ValueError(f"valid must be a bool tensor of shape ({big_n},), got {valid.dtype} "
                             f"{tuple(valid.shape)}")
        sim = sim.masked_fill(~valid[None, :], float("-inf"))
    if self_index is not None:
        if self_index.shape != (n,) or not (0 <= self_index).all() or not (self_index < big_n).all():
            raise ValueError(f"self_index must hold one bank row in [0, {big_n}) per query, got "
                             f"{tuple(self_index.shape)}")
        sim[torch.arange(n, device=sim.device), self_index] = float("-inf")
    available = int(torch.isfinite(sim).sum(1).min())
    if as_int(k, "k") > available:
        raise ValueError(f"k: need 1 <= k <= {available} (the bank rows each query can have as neighbours), "
                         f"got {k}")
    return bank_probs[sim.topk(k, dim=1).indices]


def attract_disperse(probs: torch.Tensor, neighbour_probs: torch.Tensor, dispersion: float = 1.0
                     ) -> torch.Tensor:
    """L_AaD of a batch (eq. 6): the gradient flows into ``probs`` only.

    Args:
        probs: the batch's softmax rows ``p_i``.
        neighbour_probs: each row's neighbours' bank probabilities ``s_j`` (:func:`neighbour_probs`).
        dispersion: λ, the weight of the batch term (AaD: 1 on Office-Home, no decay).

    Shapes:
        probs (n, c), n ≥ 1, neighbour_probs (n, K, c) -> scalar in [−K, λ·(n − 1)]
    """
    check_class_scores(probs, "probs")
    if neighbour_probs.dim() != 3 or neighbour_probs.shape[0] != probs.shape[0] \
            or neighbour_probs.shape[2] != probs.shape[1] or neighbour_probs.shape[1] < 1:
        raise ValueError(f"neighbour_probs must have shape (n, K >= 1, c) = ({probs.shape[0]}, K, "
                         f"{probs.shape[1]}), got {tuple(neighbour_probs.shape)}")
    if not torch.isfinite(neighbour_probs).all():
        raise ValueError("neighbour_probs contains NaN or inf")
    dispersion = as_real(dispersion, "dispersion", low=0.0)
    attract = torch.einsum("nc,nkc->n", probs, neighbour_probs.detach())
    gram = probs @ probs.T
    disperse = gram.sum(1) - gram.diagonal()
    return (dispersion * disperse - attract).mean()
