"""The optimal kernel weights of MK-MMD, thesis ch.7, eq. (7.6) (Gretton et al., 2012).

Eq. 7.6 combines ``b`` Gaussian kernels, ``k = Σ_u β_u k_u`` with ``Σ β_u = 1``, ``β_u ≥ 0``, and the
thesis reads it with Gretton et al. (2012): "the optimal kernel is obtained by the linear combination of
many kernels". :func:`~vtlearn.losses.mmd.mk_mmd` takes equal weights ``β_u = 1/b`` unless told
otherwise; this module finds Gretton et al.'s optimal ones, the weights that DAN (Long et al., 2015,
eq. 6-7) re-estimates while it trains.

The optimal kernel maximises the power of the two-sample test, the ratio ``β·η / sqrt(βᵀQβ)`` of the
squared MMD to the standard deviation of its linear-time estimate. With ``n = min(n_s, n_t) // 2``
quadruples ``z_i = (x_{2i}, x_{2i+1}, y_{2i}, y_{2i+1})`` of source (x) and target (y) rows, kernel u gives
(Gretton et al. 2012, eq. 5)

    h_u(z_i) = k_u(x_{2i}, x_{2i+1}) + k_u(y_{2i}, y_{2i+1}) − k_u(x_{2i}, y_{2i+1}) − k_u(x_{2i+1}, y_{2i}),

``η_u = mean_i h_u(z_i)`` (each kernel's linear-time MMD²) and ``Q = cov_i h(z_i)`` (b × b). The weights
solve the quadratic programme (Gretton et al. 2012, eq. 13; DAN eq. 7)

    min_β βᵀ(Q + εI)β   subject to   ηᵀβ = 1,  β ≥ 0,

and are then scaled to ``Σ β_u = 1`` (eq. 7.6); ``ε`` is a ridge of ``ridge · mean(diag Q)``. With
``b ≤ 12`` kernels, :func:`optimal_kernel_weights` solves it exactly by enumerating the supports of β.
If no kernel has ``η_u > 0``, the constraint ``ηᵀβ = 1`` has no solution with ``β ≥ 0`` (no kernel tells
the samples apart), and the weights stay equal.
"""

from __future__ import annotations

import functools
import itertools

import torch

from vtlearn.losses.mmd import check_feature_pair, linear_time_terms
from vtlearn.validation import as_real

__all__ = ["linear_time_statistics", "optimal_kernel_weights", "MAX_KERNELS"]

#: the most kernels whose weights :func:`optimal_kernel_weights` finds (it visits 2^b − 1 supports)
MAX_KERNELS = 12


def linear_time_statistics(
    source: torch.Tensor, target: torch.Tensor, bandwidths: torch.Tensor
) -> torch.Tensor:
    """The ``h_u(z_i)`` of the module docstring: each kernel's linear-time MMD² term for each quadruple of
    consecutive rows (a source row pair and a target row pair), without gradient.

    Args:
        source, target: feature samples with at least 2 rows each; rows past ``2·min(n_s, n_t) // 2`` are
            not used.
        bandwidths: the ``h_u`` of the Gaussian kernels ``exp(−‖x − y‖² / h_u)``, each > 0.

    Shapes:
        source (n_s, d), target (n_t, d), bandwidths (b,) -> (n, b) with n = min(n_s, n_t) // 2
    """
    check_feature_pair(source, target, 2, " (one quadruple is two rows of each)")
    if bandwidths.dim() != 1 or bandwidths.numel() == 0 or not bool((bandwidths > 0).all()):
        raise ValueError(f"bandwidths: expected a non-empty 1-D tensor of values > 0, got {bandwidths}")
    with torch.no_grad():
        return linear_time_terms(source, target, bandwidths)


def optimal_kernel_weights(eta: torch.Tensor, q: torch.Tensor, ridge: float = 1e-3) -> torch.Tensor:
    """Gretton et al.'s optimal MK-MMD weights (module docstring): the solution of
    ``min βᵀ(Q + εI)β s.t. ηᵀβ = 1, β ≥ 0``, scaled to sum to 1, or equal weights if no ``η_u > 0``.

    The programme is convex (``Q + εI`` is positive definite), so its minimiser is the best feasible one
    among the minimisers of the equality-constrained problem on each support S of β,
    ``β_S ∝ (Q + εI)_S⁻¹ η_S``; all ``2^b − 1`` supports are tried. They are screened in one batched
    solve; the few whose objective is within rounding of the best are then solved one by one, so the
    result is that of trying each support alone (the first on a tie), at a fraction of its cost.

    Args:
        eta: ``η``, each kernel's MMD² estimate; finite.
        q: ``Q``, the covariance of the kernels' estimates; symmetric positive semi-definite, finite.
        ridge: ``ε / mean(diag Q)``, > 0 (Gretton et al. add a small ridge for a stable solution).

    Shapes:
        eta (b,), q (b, b) with 1 ≤ b ≤ :data:`MAX_KERNELS` -> (b,) float64, ≥ 0, summing to 1
    """
    ridge = as_real(ridge, "ridge", low=0.0, open_low=True)
    if not isinstance(eta, torch.Tensor) or eta.dim() != 1 or not 1 <= eta.numel() <= MAX_KERNELS:
        raise ValueError(f"eta: expected a 1-D tensor of 1 to {MAX_KERNELS} kernels' MMD², got "
                         f"{tuple(eta.shape) if isinstance(eta, torch.Tensor) else type(eta).__name__}")
    b = eta.numel()
    if not isinstance(q, torch.Tensor) or tuple(q.shape) != (b, b):
        raise ValueError(f"q: expected a ({b}, {b}) covariance, got "
                         f"{tuple(q.shape) if isinstance(q, torch.Tensor) else type(q).__name__}")
    if not bool(torch.isfinite(eta).all()) or not bool(torch.isfinite(q).all()):
        raise ValueError("eta, q: contain NaN or inf")
    eta64, q64 = eta.detach().to(torch.float64).cpu(), q.detach().to(torch.float64).cpu()
    q64 = 0.5 * (q64 + q64.T)
    scale = float(q64.diagonal().clamp_min(0.0).mean())
    a = q64 + (ridge * scale if scale > 0 else ridge) * torch.eye(b, dtype=torch.float64)
    equal = torch.full((b,), 1.0 / b, dtype=torch.float64)
    if not bool((eta64 > 0).any()):
        return equal
    # Screen every support at once: support S's system, padded to b x b with the identity outside S,
    # has the solution (Q + εI)_S⁻¹ η_S on S and 0 elsewhere.
    masks = _support_masks(b)
    masks = masks[(masks & (eta64 > 0)).any(1)]  # a support without η_u > 0 cannot meet ηᵀβ = 1
    inside = masks.to(torch.float64)
    g = torch.linalg.solve(a * (inside[:, :, None] * inside[:, None, :]) + torch.diag_embed(1.0 - inside),
                           eta64 * inside)  # (m, b)
    denom = (eta64 * inside * g).sum(1)
    # feasible up to rounding (the exact check follows), and within rounding of the smallest βᵀAβ = 1/denom
    near = (denom > 0) & ((g >= -_SCREEN_TOL * g.abs().amax(1, keepdim=True)) | ~masks).all(1)
    if bool(near.any()):
        obj = torch.where(near, 1.0 / denom.clamp_min(torch.finfo(torch.float64).tiny), torch.inf)
        candidates = torch.nonzero(obj <= float(obj.min()) * (1 + _SCREEN_TOL)).flatten().tolist()
        best = _best_support(a, eta64, [masks[i].nonzero().flatten().tolist() for i in candidates])
        if best is not None:
            return best
    # the screen found no support that the exact check accepts (a tie with rounding): try every support
    best = _best_support(a, eta64, [m.nonzero().flatten().tolist() for m in _support_masks(b)])
    return equal if best is None else best


#: relative slack of the batched screen of :func:`optimal_kernel_weights`, far above its rounding error
_SCREEN_TOL = 1e-9


@functools.lru_cache(maxsize=MAX_KERNELS)
def _support_masks(b: int) -> torch.Tensor:
    """The ``2^b − 1`` non-empty supports of ``b`` weights, by size and then in
    :func:`itertools.combinations` order (the order :func:`_best_support` breaks ties in). Read only.

    Shapes:
        -> (2^b − 1, b) bool
    """
    return torch.tensor([[u in s for u in range(b)] for size in range(1, b + 1)
                         for s in itertools.combinations(range(b), size)], dtype=torch.bool)


def _best_support(a: torch.Tensor, eta: torch.Tensor, supports: list[list[int]]) -> torch.Tensor | None:
    """The weights of the best feasible support among ``supports`` (the first on a tie): on each, the
    minimiser of ``βᵀAβ`` s.t. ``ηᵀβ = 1`` is ``β_S = A_S⁻¹η_S / (η_Sᵀ A_S⁻¹ η_S)``, feasible when it is
    ≥ 0, with ``βᵀAβ = 1 / (η_Sᵀ A_S⁻¹ η_S)``. Scaled to sum to 1; None if no support is feasible.

    Shapes:
        a (b, b) float64, eta (b,) float64 -> (b,) float64 or None
    """
    best, best_obj = None, float("inf")
    for s in supports:
        e_s = eta[s]
        if not bool((e_s > 0).any()):
            continue
        g = torch.linalg.solve(a[s][:, s], e_s)  # (Q + εI)_S⁻¹ η_S
        denom = float(e_s @ g)
        if denom <= 0 or not bool((g >= 0).all()):
            continue
        obj = 1.0 / denom  # βᵀAβ at β_S = g / denom
        if obj < best_obj:
            best_obj = obj
            best = torch.zeros(eta.numel(), dtype=torch.float64)
            best[s] = g / denom
    return None if best is None else best / best.sum()
