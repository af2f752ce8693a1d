"""Class-prior matching on the unlabelled target stream (beyond the thesis).

A classifier trained on one domain and applied to another is biased towards some classes: on the tactile
test clouds the teacher row of ``bench crossmodal`` predicts wine glass 16-28 times among 144 clouds that
hold 12 of each class, and detergent bottle 4-8 times (seeds 0-3, docs/xavtnet_results.md). Two standard
label-free corrections assume that the target stream's classes occur as often as the source's (which
holds for the benchmark's balanced classes, and is AdaMatch's assumption):

* **Distribution alignment** (Berthelot et al., ReMixMatch, ICLR 2020; AdaMatch, ICLR 2022), for the
  targets of a consistency loss during training::

      p̃ = normalise(p ⊙ ρ_s / ρ_t),

  with ``ρ_s`` the source class frequencies and ``ρ_t`` a running mean of the predictions on the target
  stream; a class the target predictions favour is scaled down, one they neglect is scaled up.
* **Balanced assignment** (Sinkhorn-Knopp; Cuturi, NeurIPS 2013; the equipartition of Asano et al.'s
  SeLa, ICLR 2020), for the predictions of a whole target set at once: the probability matrix ``P`` of
  ``n`` clouds is rescaled to ``Q = diag(u)·P·diag(v)`` whose rows sum to 1 and whose columns sum to
  ``n·ρ_s``, and each cloud takes the argmax of its row of ``Q``. This is transductive: it needs the
  set, not one cloud.

Neither uses a target label.
"""

from __future__ import annotations

import torch

from vtlearn.validation import as_int, as_real, check_class_scores

__all__ = ["align_distribution", "sinkhorn_balance", "check_prior"]


def _check_probs(probs: torch.Tensor, name: str) -> None:
    check_class_scores(probs, name)
    if (probs < 0).any():
        raise ValueError(f"{name} has negative entries; expected probabilities")


def check_prior(prior: torch.Tensor, k: int, name: str = "prior") -> torch.Tensor:
    """``prior`` as a float tensor of ``k`` positive class frequencies summing to 1, or a ValueError
    naming ``name``."""
    prior = torch.as_tensor(prior, dtype=torch.float64)
    if prior.shape != (k,):
        raise ValueError(f"{name} must have shape ({k},), got {tuple(prior.shape)}")
    if not torch.isfinite(prior).all() or (prior <= 0).any():
        raise ValueError(f"{name} must be finite and positive (every class occurs), got {prior.tolist()}")
    if abs(float(prior.sum()) - 1.0) > 1e-4:
        raise ValueError(f"{name} must sum to 1, got {float(prior.sum()):.6f}")
    return prior


def align_distribution(probs: torch.Tensor, source_prior: torch.Tensor,
                       target_mean: torch.Tensor) -> torch.Tensor:
    """ReMixMatch's distribution alignment ``p̃ = normalise(p ⊙ ρ_s / ρ_t)`` of each row of ``probs``.

    Shapes:
        probs (n, k) rows of probabilities, source_prior (k,), target_mean (k,) -> (n, k) rows summing
        to 1
    """
    _check_probs(probs, "probs")
    k = probs.shape[1]
    ratio = check_prior(source_prior, k, "source_prior") / check_prior(target_mean, k, "target_mean")
    aligned = probs * ratio.to(probs)
    total = aligned.sum(-1, keepdim=True)
    if (total <= 0).any():
        raise ValueError("probs: a row sums to 0")
    return aligned / total


def sinkhorn_balance(probs: torch.Tensor, prior: torch.Tensor | None = None, iters: int = 500,
                     tol: float = 1e-6) -> torch.Tensor:
    """Rescale ``probs`` to ``Q = diag(u)·probs·diag(v)`` whose rows sum to 1 and whose columns sum to
    ``n·prior`` (uniform when ``None``), by alternating column and row normalisation (Sinkhorn-Knopp),
    until the column sums are within ``tol·n`` of their targets or ``iters`` rounds have run. Entries
    are floored at 1e-12 so that every class can be reached. ``Q.argmax(-1)`` is the balanced
    assignment.

    Shapes:
        probs (n, k) nonnegative, prior (k,) -> (n, k) rows summing to 1
    """
    _check_probs(probs, "probs")
    n, k = probs.shape
    prior = torch.full((k,), 1.0 / k) if prior is None else check_prior(prior, k)
    iters = as_int(iters, "iters")
    tol = as_real(tol, "tol", low=0.0, open_low=True)
    q = probs.to(torch.float64).clamp_min(1e-12)
    q = q / q.sum(-1, keepdim=True)
    cols = n * prior.to(q)
    for _ in range(int(iters)):
        q = q * (cols / q.sum(0))
        q = q / q.sum(-1, keepdim=True)
        if (q.sum(0) - cols).abs().max() <= tol * n:
            break
    return q.to(probs.dtype)
