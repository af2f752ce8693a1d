"""Deep CORAL loss, thesis ch.7, eq. (7.7) (Sun and Saenko, 2016).

    CORAL(x_s, x_t) = ‖C_s − C_t‖²_F / (4 d²)

``C`` is the unbiased sample covariance ``C = (Xᵀ X − (1ᵀX)ᵀ(1ᵀX)/n) / (n − 1)`` of each domain's
``(n, d)`` feature matrix, exactly as in Deep CORAL.
"""

from __future__ import annotations

import torch

from vtlearn.losses.mmd import check_feature_pair, check_features

__all__ = ["covariance", "coral"]


def covariance(x: torch.Tensor) -> torch.Tensor:
    """Unbiased sample covariance of the rows of ``x``: the ``C_s`` and ``C_t`` of eq. 7.7.

    Shapes:
        x (n, d) -> (d, d)
    """
    check_features(x, "x", 2, " (a covariance)")
    n = x.shape[0]
    centred = x - x.mean(0, keepdim=True)
    return centred.T @ centred / (n - 1)


def coral(source: torch.Tensor, target: torch.Tensor) -> torch.Tensor:
    """Deep CORAL distance between two feature samples (eq. 7.7).

    Shapes:
        source (n_s, d), target (n_t, d) -> scalar; ``n_s``, ``n_t`` ≥ 2 and may differ.
    """
    check_feature_pair(source, target, 2, " (a covariance)")
    d = source.shape[1]
    diff = covariance(source) - covariance(target)
    return (diff * diff).sum() / (4.0 * d * d)
