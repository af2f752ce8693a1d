"""MC-dropout uncertainty and query strategies for deep active learning, thesis ch.7, section 7.2.2,
eq. (7.3)-(7.4) (Gal and Ghahramani, 2016).

* Predictive probability (eq. 7.3): ``p(y|x) = (1/T) Σ_t p(y|x, W_t)`` over ``T`` stochastic forward
  passes with dropout **on** and batch norm in **eval** mode (running statistics), so the only source
  of randomness is the dropout mask.
* Uncertainty (eq. 7.4): the Shannon entropy ``H(y|x) = −Σ_c p(y=c|x) log p(y=c|x)`` of that average.
* Query: the top-κ samples by score. ``"entropy"`` is the thesis strategy, ``"bald"`` (Houlsby et al.
  2011; Gal et al. 2017) is the mutual information ``H[mean_t p_t] − mean_t H[p_t]``, and ``"random"``
  is the baseline.
* Stochastic batch query (beyond the thesis): ``"power_entropy"`` and ``"power_bald"`` draw the κ
  samples without replacement with probability ∝ score^β (Kirsch et al. 2023, "Stochastic Batch
  Acquisition: A Simple Baseline for Deep Active Learning", TMLR; β = 1 by default). Top-κ takes the κ
  highest scores of one model, and those are often near-duplicates (views of the same confusing
  instance); sampling spreads the batch at no extra cost.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable, Iterator
from contextlib import contextmanager

import torch
from torch import nn

from vtlearn.validation import as_int, as_real

__all__ = [
    "STRATEGIES",
    "mc_dropout_mode",
    "mc_dropout_probs",
    "predictive_entropy",
    "bald_score",
    "acquisition_scores",
    "select_top_k",
    "select_power",
    "QUERY_STRATEGIES",
    "split_strategy",
    "random_query",
    "score_pool",
]

STRATEGIES = ("entropy", "bald", "random")
# Strategies of the active-learning loop: a score (STRATEGIES) plus a selection rule.
QUERY_STRATEGIES = (*STRATEGIES, "power_entropy", "power_bald")


def split_strategy(strategy: str) -> tuple[str, str]:
    """``"power_bald"`` -> ``("bald", "power")``; ``"entropy"`` -> ``("entropy", "top_k")``."""
    if strategy not in QUERY_STRATEGIES:
        raise ValueError(f"strategy must be one of {QUERY_STRATEGIES}, got {strategy!r}")
    if strategy.startswith("power_"):
        return strategy.removeprefix("power_"), "power"
    return strategy, "top_k"


@contextmanager
def mc_dropout_mode(model: nn.Module) -> Iterator[nn.Module]:
    """Put ``model`` in eval mode except its dropout layers, the setting of eq. 7.3 (the weights ``W_t``
    differ only by their dropout masks; batch norm uses its running statistics); restore every module's
    flag afterwards. A ValueError naming ``model`` if it has no dropout layer."""
    flags = {m: m.training for m in model.modules()}
    dropouts = [m for m in model.modules() if isinstance(m, nn.modules.dropout._DropoutNd)]
    if not dropouts:
        raise ValueError("model has no dropout layer, so MC-dropout passes would all be identical")
    model.eval()
    for m in dropouts:
        m.train()
    try:
        yield model
    finally:
        for m, flag in flags.items():
            m.training = flag


def _logits_of(out) -> torch.Tensor:
    return out.logits if hasattr(out, "logits") else out


@torch.no_grad()
def mc_dropout_probs(
    model: nn.Module,
    points: torch.Tensor,
    lengths: torch.Tensor | None = None,
    num_passes: int = 20,
    dropout: bool = True,
) -> torch.Tensor:
    """Softmax outputs of ``num_passes`` stochastic passes (the terms of eq. 7.3).

    ``model(points, lengths)`` must return logits or an object with ``.logits``. With
    ``dropout=False`` the passes run in plain eval mode and are identical (a deterministic baseline).

    Shapes:
        points (B, N, 3), lengths (B,) -> probs (T, B, k)
    """
    num_passes = as_int(num_passes, "num_passes")
    if dropout:
        with mc_dropout_mode(model):
            return torch.stack([_logits_of(model(points, lengths)).softmax(-1) for _ in range(num_passes)])
    was_training = model.training
    model.eval()
    try:
        return torch.stack([_logits_of(model(points, lengths)).softmax(-1) for _ in range(num_passes)])
    finally:
        model.train(was_training)


def _check_probs(probs: torch.Tensor, name: str, dim: int) -> None:
    if probs.dim() != dim or probs.shape[-1] < 2:
        raise ValueError(f"{name} must have {dim} dims with >= 2 classes, got {tuple(probs.shape)}")
    if not torch.isfinite(probs).all() or (probs < 0).any():
        raise ValueError(f"{name} must be finite and non-negative")


def predictive_entropy(mean_probs: torch.Tensor) -> torch.Tensor:
    """Shannon entropy in nats (eq. 7.4), ``H(y|x) = −Σ_c p(y=c|x) log p(y=c|x)``, with ``0 log 0 = 0``.

    Shapes:
        mean_probs (B, k) (the mean over the passes, eq. 7.3) -> (B,)
    """
    _check_probs(mean_probs, "mean_probs", 2)
    return -torch.special.xlogy(mean_probs, mean_probs).sum(-1)


def bald_score(probs: torch.Tensor) -> torch.Tensor:
    """BALD mutual information ``H[mean_t p_t] − mean_t H[p_t]`` (≥ 0; beyond the thesis): the entropy of
    eq. 7.4 of the mean of eq. 7.3, less the mean entropy of the passes.

    Shapes:
        probs (T, B, k) -> (B,)
    """
    _check_probs(probs, "probs", 3)
    expected_entropy = -torch.special.xlogy(probs, probs).sum(-1).mean(0)
    return (predictive_entropy(probs.mean(0)) - expected_entropy).clamp_min(0.0)


def acquisition_scores(probs: torch.Tensor, strategy: str, generator: torch.Generator | None = None):
    """Score per sample for ``strategy`` (higher = query first): ``"entropy"`` is eq. 7.4 of the mean of
    the passes (eq. 7.3), ``"bald"`` :func:`bald_score`, ``"random"`` uniform draws from ``generator``.

    Shapes:
        probs (T, B, k) -> (B,)
    """
    if strategy not in STRATEGIES:
        raise ValueError(f"strategy must be one of {STRATEGIES}, got {strategy!r}")
    _check_probs(probs, "probs", 3)
    if strategy == "entropy":
        return predictive_entropy(probs.mean(0))
    if strategy == "bald":
        return bald_score(probs)
    return torch.rand(probs.shape[1], generator=generator)


def _check_scores(scores) -> None:
    """``ValueError`` naming ``scores`` unless it is a non-empty 1-D tensor."""
    if not isinstance(scores, torch.Tensor):
        raise ValueError(f"scores must be a 1-D torch.Tensor, got {type(scores).__name__}")
    if scores.dim() != 1:
        raise ValueError(f"scores must be 1-D, got {tuple(scores.shape)}")
    if scores.numel() == 0:
        raise ValueError("scores: empty (no unlabelled samples to select from)")


def select_top_k(scores: torch.Tensor, k: int) -> torch.Tensor:
    """Indices of the ``k`` highest scores, highest first (ties broken by lower index): the top-κ query
    of section 7.2.2 on the scores of eq. 7.4.

    Args:
        scores: non-empty, finite 1-D tensor.
        k: ``1 <= k <= len(scores)``.

    Shapes:
        scores (U,) -> (k,) int64 indices into ``scores``
    """
    _check_scores(scores)
    if as_int(k, "k") > scores.numel():
        raise ValueError(f"k must be in [1, {scores.numel()}], got {k}")
    if not torch.isfinite(scores).all():
        raise ValueError("scores: contains NaN or inf")
    order = torch.sort(-scores, stable=True).indices
    return order[:k]


def select_power(
    scores: torch.Tensor, k: int, beta: float = 1.0, generator: torch.Generator | None = None,
) -> torch.Tensor:
    """``k`` indices drawn without replacement with probability ∝ ``scores**beta`` (power acquisition,
    Kirsch et al. 2023), by the Gumbel-top-k trick: the top ``k`` of ``beta·log(score) + Gumbel``.

    Scores must be ≥ 0; a zero score is only drawn once every positive one is. β → ∞ gives top-k and
    β = 0 uniform sampling.

    Shapes:
        scores (U,) -> (k,) indices, in draw order (scores non-empty, finite, >= 0; ``1 <= k <= U``)
    """
    _check_scores(scores)
    if as_int(k, "k") > scores.numel():
        raise ValueError(f"k must be in [1, {scores.numel()}], got {k}")
    beta = as_real(beta, "beta", low=0.0)
    if not torch.isfinite(scores).all() or (scores < 0).any():
        raise ValueError("scores must be finite and >= 0 for power acquisition")
    u = torch.rand(scores.shape, generator=generator, dtype=torch.float64).clamp(1e-300, 1.0 - 1e-16)
    gumbel = -torch.log(-torch.log(u))
    log_s = torch.log(scores.to(torch.float64))  # -inf for zero scores: drawn last
    keys = torch.where(scores > 0, beta * log_s + gumbel, -1e300 + gumbel)
    return torch.sort(-keys, stable=True).indices[:k]


def random_query(pool_indices: torch.Tensor, k: int, generator: torch.Generator | None = None):
    """``k`` pool indices uniformly without replacement (the random-strategy baseline).

    Shapes:
        pool_indices (U,) -> (k,), a subset of ``pool_indices`` (``1 <= k <= U``)
    """
    if as_int(k, "k") > pool_indices.numel():
        raise ValueError(f"k must be in [1, {pool_indices.numel()}], got {k}")
    return pool_indices[torch.randperm(pool_indices.numel(), generator=generator)[:k]]


@torch.no_grad()
def score_pool(
    model: nn.Module,
    batches: Iterable[dict],
    strategy: str,
    num_passes: int = 20,
    generator: torch.Generator | None = None,
    progress: Callable[[Iterable], Iterable] | None = None,
) -> tuple[torch.Tensor, torch.Tensor]:
    """Acquisition score of every unlabelled cloud: MC-dropout passes (eq. 7.3) and their entropy
    (eq. 7.4) or BALD, or random scores.

    Args:
        batches: e.g. ``ActivePoolDataModule.unlabelled_dataloader()``; each batch is
            ``{"points", "lengths", "index"}`` with ``index`` the pool index.
        progress: optional wrapper such as ``tqdm``.

    Returns:
        (pool indices (U,), scores (U,))

    Shapes:
        batches: points (B, N, 3), lengths (B,), index (B,) -> (U,), (U,), U the clouds of all batches
    """
    if strategy not in STRATEGIES:
        raise ValueError(f"strategy must be one of {STRATEGIES}, got {strategy!r}")
    device = next(model.parameters()).device
    all_idx, all_scores = [], []
    for batch in progress(batches) if progress else batches:
        idx = torch.as_tensor(batch["index"]).reshape(-1)
        if strategy == "random":
            scores = torch.rand(idx.numel(), generator=generator)
        else:
            points = batch["points"].to(device)
            lengths = batch.get("lengths")
            lengths = lengths.to(device) if lengths is not None else None
            probs = mc_dropout_probs(model, points, lengths, num_passes)
            scores = acquisition_scores(probs, strategy).cpu()
        all_idx.append(idx.cpu())
        all_scores.append(scores)
    if not all_idx:
        raise ValueError("batches is empty: nothing left to score in the unlabelled pool")
    return torch.cat(all_idx), torch.cat(all_scores)
