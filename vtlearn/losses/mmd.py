"""Multi-kernel Maximum Mean Discrepancy (MK-MMD), thesis ch.7, eq. (7.5)-(7.6).

MMD between two distributions is the RKHS distance between their mean embeddings (eq. 7.5),
``MMD²(p_s, p_t) = ‖E_s[φ(x_s)] − E_t[φ(x_t)]‖²_H``. MK-MMD (Gretton et al., 2012) uses a convex
combination of ``b`` kernels (eq. 7.6), ``k = Σ_u β_u k_u`` with ``Σ β_u = 1``; here ``β_u = 1/b`` unless
``kernel_weights`` are given (Gretton et al.'s optimal weights: :mod:`vtlearn.losses.kernel_choice`).

Kernel family (documented bandwidths). Gaussian kernels

    k_u(x, y) = exp(−‖x − y‖² / h_u),   h_u = h₀ · m^(u − ⌊b/2⌋),   u = 0 … b−1,

with multiplier ``m = kernel_mul`` (default 2) and ``b = num_kernels`` (default 5), so by default
``h ∈ {h₀/4, h₀/2, h₀, 2h₀, 4h₀}``. The base bandwidth ``h₀`` is the mean pairwise squared distance
of the pooled source+target sample (the "mean heuristic" of DAN, Long et al., 2015), computed without
gradient so the kernels do not chase their own bandwidth. Fixed bandwidths can be passed instead.

Estimators (stated explicitly):

* biased (default, a V-statistic): ``mean(K_ss) + mean(K_tt) − 2·mean(K_st)``, diagonals included.
  It is always ≥ 0 and exactly 0 when the two samples are identical.
* unbiased (``unbiased=True``, a U-statistic, Gretton et al. 2012 eq. 3): diagonals of ``K_ss`` and
  ``K_tt`` are excluded. It can be slightly negative and needs at least 2 samples per domain.
* linear-time (``linear_time=True``, Gretton et al. 2012 eq. 5; the estimator DAN trains with, Long et al.
  2015 eq. 6): the mean over ``n = min(n_s, n_t) // 2`` disjoint quadruples
  ``z_i = (x_{2i}, x_{2i+1}, y_{2i}, y_{2i+1})`` of consecutive source (x) and target (y) rows of
  ``k(x_{2i}, x_{2i+1}) + k(y_{2i}, y_{2i+1}) − k(x_{2i}, y_{2i+1}) − k(x_{2i+1}, y_{2i})``
  (:func:`linear_time_terms`). It is unbiased, costs O(n) kernel evaluations instead of O(n²), and has a
  larger variance: each row meets one other row of its own domain and one of the other. Rows past ``2n``
  are not used, so it needs at least 2 samples per domain, and rows should come in random order (a
  shuffled batch).

Beyond eq. 7.6's Gaussian family, :func:`linear_kernel_mmd` is the MMD of the linear kernel
``k(x, y) = xᵀy`` that Deep Domain Confusion trains with (DDC, Tzeng et al. 2014, the first deep "MMD loss"
and the one Deep CORAL compares against): ``MMD² = ‖mean_s(x) − mean_t(y)‖²`` (biased), the distance
between the two means alone, with no kernel bandwidth. It is another reading of Table 7.2's "MMD only" row.
"""

from __future__ import annotations

from collections.abc import Sequence

import torch

from vtlearn.validation import as_int, as_real

__all__ = ["gaussian_bandwidths", "multi_kernel_matrix", "mk_mmd", "check_features", "check_feature_pair",
           "kernel_bandwidths", "linear_time_terms", "linear_kernel_mmd"]


def check_features(x: torch.Tensor, name: str, min_rows: int = 1, why: str = "") -> None:
    """A ValueError naming ``name`` unless ``x`` is a finite (n, d) tensor with ``n >= min_rows``, d >= 1
    (``why``, e.g. " (a covariance)", is said after the row count)."""
    if not isinstance(x, torch.Tensor):
        raise ValueError(f"{name} must be a torch.Tensor, got {type(x).__name__}")
    if x.dim() != 2:
        raise ValueError(f"{name} must have shape (n, d), got {tuple(x.shape)}")
    if x.shape[0] < min_rows or x.shape[1] < 1:
        raise ValueError(f"{name} needs at least {min_rows} rows{why} and 1 column, got {tuple(x.shape)}")
    if not torch.isfinite(x).all():
        raise ValueError(f"{name} contains NaN or inf")


def check_feature_pair(source: torch.Tensor, target: torch.Tensor, min_rows: int = 1, why: str = "") -> None:
    """:func:`check_features` for each domain, and the same feature size d in both."""
    check_features(source, "source", min_rows, why)
    check_features(target, "target", min_rows, why)
    if source.shape[1] != target.shape[1]:
        raise ValueError(
            f"source and target must have the same feature size, got {tuple(source.shape)} "
            f"and {tuple(target.shape)}"
        )


def kernel_bandwidths(
    source: torch.Tensor,
    target: torch.Tensor,
    num_kernels: int = 5,
    kernel_mul: float = 2.0,
    bandwidths: Sequence[float] | torch.Tensor | None = None,
) -> torch.Tensor:
    """The ``h_u`` of the kernels ``k_u`` of eq. 7.6 for one MK-MMD estimate: fixed ``bandwidths``
    (checked), or the family of :func:`gaussian_bandwidths` around the pooled sample's mean squared
    distance.

    Shapes:
        source (n_s, d), target (n_t, d) -> (b,)
    """
    if bandwidths is None:
        return gaussian_bandwidths(torch.cat([source, target]), num_kernels, kernel_mul)
    h = torch.as_tensor(bandwidths, dtype=source.dtype, device=source.device).reshape(-1)
    if h.numel() == 0 or not torch.isfinite(h).all() or (h <= 0).any():
        raise ValueError(f"bandwidths must be non-empty, finite and > 0, got {h.tolist()}")
    return h


def gaussian_bandwidths(
    pooled: torch.Tensor, num_kernels: int = 5, kernel_mul: float = 2.0
) -> torch.Tensor:
    """Bandwidth family ``h_u = h₀ · kernel_mul^(u − ⌊b/2⌋)`` of the module docstring, the ``b`` Gaussian
    kernels ``k_u`` that eq. 7.6 combines.

    Args:
        pooled: source and target features stacked.
        num_kernels: ``b``, the number of Gaussian kernels.
        kernel_mul: ``m``, the ratio between neighbouring bandwidths.

    Shapes:
        pooled (n, d) -> (b,), detached from the graph.
    """
    num_kernels = as_int(num_kernels, "num_kernels")
    kernel_mul = as_real(kernel_mul, "kernel_mul", low=0.0, open_low=True)
    with torch.no_grad():
        n = pooled.shape[0]
        sq = torch.cdist(pooled, pooled).pow(2)
        h0 = sq.sum() / max(n * n - n, 1)
        # Identical points give h0 = 0; any positive value then gives k = 1 everywhere, MMD = 0.
        h0 = torch.clamp(h0, min=torch.finfo(pooled.dtype).eps)
        exps = torch.arange(num_kernels, dtype=pooled.dtype, device=pooled.device) - num_kernels // 2
        return h0 * kernel_mul**exps


def multi_kernel_matrix(
    x: torch.Tensor, y: torch.Tensor, bandwidths: torch.Tensor, weights: torch.Tensor | None = None
) -> torch.Tensor:
    """``K_ij = Σ_u β_u exp(−‖x_i − y_j‖² / h_u)`` (eq. 7.6), with ``β_u = 1/b`` unless ``weights`` are given.

    Args:
        x, y: 2-D feature matrices with the same feature dimension ``d``.
        bandwidths: non-empty 1-D tensor (shapes only are checked: this runs every training step).
        weights: the ``β_u`` (checked by :func:`mk_mmd`), or ``None`` for equal weights.

    Shapes:
        x (n, d), y (m, d), bandwidths (b,), weights (b,) -> (n, m)
    """
    if x.dim() != 2 or y.dim() != 2:
        raise ValueError(
            f"x, y: expected 2-D (n, d) and (m, d) features, got {tuple(x.shape)} and {tuple(y.shape)}"
        )
    if x.shape[1] != y.shape[1]:
        raise ValueError(f"y: feature dimension {y.shape[1]} does not match x's {x.shape[1]}")
    if bandwidths.dim() != 1 or bandwidths.numel() == 0:
        raise ValueError(f"bandwidths: expected a non-empty 1-D tensor, got shape {tuple(bandwidths.shape)}")
    # Squared distances written out (not cdist) so the float64 gradcheck sees a smooth function at 0.
    sq = (x * x).sum(-1, keepdim=True) + (y * y).sum(-1)[None, :] - 2.0 * x @ y.T
    sq = sq.clamp_min(0.0)
    k = torch.exp(-sq[None] / bandwidths[:, None, None])  # b x n x m
    if weights is None:
        return k.mean(0)
    if weights.shape != bandwidths.shape:
        raise ValueError(f"weights: expected shape {tuple(bandwidths.shape)} (one per bandwidth), "
                         f"got {tuple(weights.shape)}")
    return torch.tensordot(weights.to(k), k, dims=1)


def linear_time_terms(source: torch.Tensor, target: torch.Tensor, bandwidths: torch.Tensor) -> torch.Tensor:
    """Each Gaussian kernel's linear-time MMD² term ``h_u(z_i)`` for each quadruple ``z_i`` of consecutive
    rows (module docstring; Gretton et al. 2012 eq. 5), with gradient. Their mean over ``i`` is kernel u's
    linear-time MMD² estimate.

    Args:
        source, target: feature samples with at least 2 rows each (checked by the callers); rows past
            ``2·(min(n_s, n_t) // 2)`` are not used.
        bandwidths: the ``h_u`` of the kernels ``exp(−‖x − y‖² / h_u)``, non-empty 1-D.

    Shapes:
        source (n_s, d), target (n_t, d), bandwidths (b,) -> (n, b) with n = min(n_s, n_t) // 2
    """
    n = min(source.shape[0], target.shape[0]) // 2
    x0, x1 = source[0:2 * n:2], source[1:2 * n:2]
    y0, y1 = target[0:2 * n:2], target[1:2 * n:2]

    def k(a: torch.Tensor, b: torch.Tensor) -> torch.Tensor:  # (n, d), (n, d) -> (n, b)
        return torch.exp(-(a - b).pow(2).sum(-1, keepdim=True) / bandwidths[None, :])

    return k(x0, x1) + k(y0, y1) - k(x0, y1) - k(x1, y0)


def mk_mmd(
    source: torch.Tensor,
    target: torch.Tensor,
    *,
    num_kernels: int = 5,
    kernel_mul: float = 2.0,
    bandwidths: Sequence[float] | torch.Tensor | None = None,
    unbiased: bool = False,
    kernel_weights: Sequence[float] | torch.Tensor | None = None,
    linear_time: bool = False,
) -> torch.Tensor:
    """Squared MK-MMD between two feature samples (thesis eq. 7.5-7.6).

    Args:
        source: source-domain features (e.g. fc1 activations of visual clouds).
        target: target-domain features (e.g. fc1 activations of tactile clouds).
        num_kernels, kernel_mul: the Gaussian family of the module docstring (ignored if
            ``bandwidths`` is given).
        bandwidths: optional fixed ``h_u`` values (each > 0).
        unbiased: U-statistic instead of the default biased V-statistic.
        kernel_weights: the ``β_u`` of eq. 7.6, one per kernel, each ≥ 0 and summing to 1 (e.g.
            :func:`~vtlearn.losses.kernel_choice.optimal_kernel_weights`); ``None``: equal weights.
        linear_time: the linear-time estimator of the module docstring (DAN's) instead of the quadratic
            ones; not with ``unbiased`` (it is unbiased already). The bandwidths still come from the whole
            pooled sample.

    Shapes:
        source (n_s, d), target (n_t, d), kernel_weights (b,) -> scalar. ``n_s`` and ``n_t`` may differ.
    """
    if linear_time and unbiased:
        raise ValueError("unbiased, linear_time: choose one estimator (the linear-time one is unbiased)")
    check_feature_pair(source, target, 2 if unbiased or linear_time else 1,
                       " (one quadruple is two rows of each)" if linear_time else "")
    h = kernel_bandwidths(source, target, num_kernels, kernel_mul, bandwidths)
    w = None
    if kernel_weights is not None:
        w = torch.as_tensor(kernel_weights, dtype=source.dtype, device=source.device).reshape(-1)
        if w.numel() != h.numel() or not bool(torch.isfinite(w).all()) or bool((w < 0).any()) \
                or abs(float(w.sum()) - 1.0) > 1e-5:
            raise ValueError(f"kernel_weights: expected {h.numel()} finite weights >= 0 summing to 1 "
                             f"(eq. 7.6), got {w.tolist()}")
    if linear_time:
        terms = linear_time_terms(source, target, h)  # (n, b)
        return terms.mean(0).mean() if w is None else terms.mean(0) @ w
    k_ss = multi_kernel_matrix(source, source, h, w)
    k_tt = multi_kernel_matrix(target, target, h, w)
    k_st = multi_kernel_matrix(source, target, h, w)
    if not unbiased:
        return k_ss.mean() + k_tt.mean() - 2.0 * k_st.mean()
    n_s, n_t = source.shape[0], target.shape[0]
    ss = (k_ss.sum() - k_ss.diagonal().sum()) / (n_s * (n_s - 1))
    tt = (k_tt.sum() - k_tt.diagonal().sum()) / (n_t * (n_t - 1))
    return ss + tt - 2.0 * k_st.mean()


def linear_kernel_mmd(source: torch.Tensor, target: torch.Tensor, *, unbiased: bool = False) -> torch.Tensor:
    """Squared MMD of the linear kernel ``k(x, y) = xᵀy`` (DDC, Tzeng et al. 2014; eq. 7.5 with that
    kernel in place of eq. 7.6's Gaussian family).

    The biased estimator (default, the V-statistic of the module docstring) is
    ``mean(K_ss) + mean(K_tt) − 2·mean(K_st) = ‖x̄_s − x̄_t‖²``: only the means are compared, so it is 0
    for any two samples with equal means. The unbiased one drops the diagonals of ``K_ss`` and ``K_tt``
    (``Σ_{i≠j} x_iᵀx_j / (n(n − 1))``), can be slightly negative and needs 2 rows per domain. Both cost
    O((n_s + n_t)·d): no Gram matrix is formed.

    Shapes:
        source (n_s, d), target (n_t, d) -> scalar. ``n_s`` and ``n_t`` may differ.
    """
    check_feature_pair(source, target, 2 if unbiased else 1)
    sum_s, sum_t = source.sum(0), target.sum(0)
    n_s, n_t = source.shape[0], target.shape[0]
    if not unbiased:
        return (sum_s / n_s - sum_t / n_t).square().sum()
    ss = (sum_s.square().sum() - source.square().sum()) / (n_s * (n_s - 1))
    tt = (sum_t.square().sum() - target.square().sum()) / (n_t * (n_t - 1))
    return ss + tt - 2.0 * (sum_s @ sum_t) / (n_s * n_t)
