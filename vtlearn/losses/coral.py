"""Deep CORAL loss, thesis ch.7, eq. (7.7) (Sun and Saenko, 2016).

    CORAL(x_s, x_t) = ‖C_s − C_t‖²_F / (4 d²)

``C`` is the unbiased sample covariance ``C = (Xᵀ X − (1ᵀX)ᵀ(1ᵀX)/n) / (n − 1)`` of each domain's
``(n, d)`` feature matrix, exactly as in Deep CORAL.
"""

from __future__ import annotations

import torch

__all__ = ["covariance", "coral"]


def _check(x: torch.Tensor, name: str) -> None:
    if not isinstance(x, torch.Tensor):
        raise ValueError(f"{name} must be a torch.Tensor, got {type(x).__name__}")
    if x.dim() != 2:
        raise ValueError(f"{name} must have shape (n, d), got {tuple(x.shape)}")
    if x.shape[0] < 2 or x.shape[1] < 1:
        raise ValueError(f"{name} needs at least 2 rows (a covariance) and 1 column, got {tuple(x.shape)}")
    if not torch.isfinite(x).all():
        raise ValueError(f"{name} contains NaN or inf")


def covariance(x: torch.Tensor) -> torch.Tensor:
    """Unbiased sample covariance of the rows of ``x``.

    Shapes:
        x (n, d) -> (d, d)
    """
    _check(x, "x")
    n = x.shape[0]
    centred = x - x.mean(0, keepdim=True)
    return centred.T @ centred / (n - 1)


def coral(source: torch.Tensor, target: torch.Tensor) -> torch.Tensor:
    """Deep CORAL distance between two feature samples (eq. 7.7).

    Shapes:
        source (n_s, d), target (n_t, d) -> scalar; ``n_s``, ``n_t`` ≥ 2 and may differ.
    """
    _check(source, "source")
    _check(target, "target")
    if source.shape[1] != target.shape[1]:
        raise ValueError(
            f"source and target must have the same feature size, got {tuple(source.shape)} "
            f"and {tuple(target.shape)}"
        )
    d = source.shape[1]
    diff = covariance(source) - covariance(target)
    return (diff * diff).sum() / (4.0 * d * d)
