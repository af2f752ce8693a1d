"""Conditional domain adversarial training, CDAN+E (beyond the thesis).

Long, Cao, Wang and Jordan, "Conditional Adversarial Domain Adaptation" (NeurIPS 2018), section 3:

    T⊗(f, g) = f ⊗ g = vec(f gᵀ)                        (multilinear map, eq. 4; d·k entries)
    w(H(g)) = 1 + e^{−H(g)},  H(g) = −Σ_c g_c log g_c    (entropy conditioning, eq. 9)
    min_D  E_s[w·(−log D(T⊗(f, g)))] + E_t[w·(−log(1 − D(T⊗(f, g))))]
    min_G  E_s[CE(g, y)] − λ_adv·(the same discriminator loss)     (through a gradient reversal layer)

with ``f`` the fc2 feature and ``g`` the softmax of the logits. Where DANN's discriminator
(:mod:`vtlearn.losses.dann`) sees the feature alone and so aligns the marginal feature distributions, as
thesis eq. 7.8's MK-MMD and CORAL terms do, CDAN's sees the feature *with* the classifier's prediction, so
it aligns the joint distribution of features and predicted classes: a tactile cloud whose feature sits
among the visual clouds of another class still stands out. Entropy conditioning weights the confident
predictions up, since an uncertain ``g`` is a poor condition. The weights are normalised within each domain
and carry no gradient, and ``g`` enters the map without gradient (Long et al.'s code detaches it; the
Transfer-Learning-Library detaches the weights too). With ``d·k ≤ 4096`` (256 × 12 here) the map is the
full outer product; CDAN's randomized map for larger products is not needed and not built.
"""

from __future__ import annotations

import torch

from vtlearn.validation import check_class_scores

__all__ = ["multilinear_map", "entropy_weights"]


def multilinear_map(features: torch.Tensor, probs: torch.Tensor) -> torch.Tensor:
    """CDAN's multilinear conditioning ``vec(f gᵀ)`` (Long et al. 2018 eq. 4), one row per cloud.

    Entry ``i·k + c`` of a row is ``features[i] · probs[c]`` (row-major flattening of ``f gᵀ``).

    Shapes:
        features (B, d), probs (B, k) -> (B, d·k)
    """
    if features.ndim != 2 or features.shape[0] == 0 or features.shape[1] == 0:
        raise ValueError(f"features: expected a non-empty (B, d) array, got shape {tuple(features.shape)}")
    check_class_scores(probs, "probs")
    if probs.shape[0] != features.shape[0]:
        raise ValueError(f"probs: {probs.shape[0]} rows for {features.shape[0]} feature rows")
    if not torch.isfinite(features).all():
        raise ValueError("features: must be finite (NaN or inf found)")
    return (features[:, :, None] * probs[:, None, :]).reshape(features.shape[0], -1)


def entropy_weights(probs: torch.Tensor) -> torch.Tensor:
    """CDAN+E's per-cloud weights ``1 + e^{−H(g)}`` (Long et al. 2018 eq. 9), without gradient.

    They lie in [1 + 1/k, 2]: 2 for a one-hot prediction, 1 + 1/k for a uniform one.

    Shapes:
        probs (B, k) rows on the simplex -> (B,)
    """
    check_class_scores(probs, "probs")
    if (probs < 0).any() or not torch.allclose(probs.sum(1), torch.ones_like(probs[:, 0]), atol=1e-4):
        raise ValueError("probs: each row must be a probability vector (non-negative, summing to 1)")
    with torch.no_grad():
        entropy = -(probs * probs.clamp_min(torch.finfo(probs.dtype).tiny).log()).sum(1)
        return 1.0 + torch.exp(-entropy)
