"""Local (class-conditional) MK-MMD, the LMMD of DSAN (Zhu et al. 2020), beyond thesis ch.7.

VTLoss's MK-MMD (eq. 7.5-7.6, :mod:`vtlearn.losses.mmd`) matches the *marginal* feature distributions of
vision and touch. When each class is a broad cluster (many instances per category), a matched marginal
can still put the tactile clouds of one class on the visual clouds of another. LMMD matches each class's
source and target distributions instead, weighting every cloud by its class membership:

    LMMD² = (1/|C|) Σ_{c∈C} ‖ Σ_i w^s_ic φ(x^s_i) − Σ_j w^t_jc φ(x^t_j) ‖²_H

    w^s_ic = y_ic / Σ_i' y_i'c            (one-hot source labels)
    w^t_jc = p_jc / Σ_j' p_j'c            (target class probabilities: the pseudo-labels, no gradient)

Expanded with the kernel of eq. 7.6 (the same Gaussian family and mean-heuristic bandwidths as
:func:`~vtlearn.losses.mmd.mk_mmd`), each class term is ``w_sᵀ K_ss w_s + w_tᵀ K_tt w_t − 2 w_sᵀ K_st w_t``,
the biased (V-statistic) estimator with diagonals included, so it is ≥ 0 and 0 for identical weighted
samples. ``C`` holds the classes present in the source batch *and* predicted (argmax) for at least one
target cloud, as in DSAN's reference code; the others carry no estimate in this batch. With one class
(``k = 1``) LMMD is the biased MK-MMD.
"""

from __future__ import annotations

from collections.abc import Sequence

import torch
import torch.nn.functional as F

from vtlearn.losses.mmd import check_feature_pair, kernel_bandwidths, multi_kernel_matrix

__all__ = ["local_mmd"]


def local_mmd(
    source: torch.Tensor,
    target: torch.Tensor,
    source_labels: torch.Tensor,
    target_probs: torch.Tensor,
    *,
    num_kernels: int = 5,
    kernel_mul: float = 2.0,
    bandwidths: Sequence[float] | torch.Tensor | None = None,
) -> torch.Tensor:
    """Class-conditional squared MK-MMD (module docstring; DSAN's LMMD).

    Args:
        source: source-domain features (e.g. fc1 activations of visual clouds).
        target: target-domain features.
        source_labels: class index of each source row, in ``[0, k)``.
        target_probs: class probabilities of each target row (softmax of the target logits); detached,
            as pseudo-labels. Rows need not sum to 1 but must be finite and ≥ 0.
        num_kernels, kernel_mul, bandwidths: the Gaussian family of :func:`~vtlearn.losses.mmd.mk_mmd`.

    Shapes:
        source (n_s, d), target (n_t, d), source_labels (n_s,) int, target_probs (n_t, k) -> scalar.
    """
    check_feature_pair(source, target)
    if not isinstance(target_probs, torch.Tensor) or target_probs.shape[:1] != target.shape[:1] \
            or target_probs.dim() != 2:
        shape = tuple(target_probs.shape) if isinstance(target_probs, torch.Tensor) else type(target_probs)
        raise ValueError(f"target_probs must have shape ({target.shape[0]}, k), got {shape}")
    if not torch.isfinite(target_probs).all() or (target_probs < 0).any():
        raise ValueError("target_probs must be finite and >= 0")
    k = target_probs.shape[1]
    if not isinstance(source_labels, torch.Tensor) or source_labels.shape != source.shape[:1] \
            or source_labels.dtype.is_floating_point:
        shape = tuple(source_labels.shape) if isinstance(source_labels, torch.Tensor) else type(source_labels)
        raise ValueError(f"source_labels must be integers of shape ({source.shape[0]},), got {shape}")
    if ((source_labels < 0) | (source_labels >= k)).any():
        raise ValueError(f"source_labels must lie in [0, {k}) (target_probs has k = {k} columns)")
    ws = F.one_hot(source_labels.long(), k).to(source.dtype)
    wt = target_probs.detach().to(source.dtype)
    predicted = F.one_hot(wt.argmax(1), k).sum(0) > 0
    present = (ws.sum(0) > 0) & predicted
    if not present.any():  # no class with an estimate in both domains: nothing to align in this batch
        return (source.sum() + target.sum()) * 0.0
    ws = ws[:, present] / ws[:, present].sum(0)
    wt = wt[:, present] / wt[:, present].sum(0).clamp_min(torch.finfo(wt.dtype).tiny)
    h = kernel_bandwidths(source, target, num_kernels, kernel_mul, bandwidths)
    k_ss = multi_kernel_matrix(source, source, h)
    k_tt = multi_kernel_matrix(target, target, h)
    k_st = multi_kernel_matrix(source, target, h)
    per_class = (
        torch.einsum("ic,ij,jc->c", ws, k_ss, ws)
        + torch.einsum("ic,ij,jc->c", wt, k_tt, wt)
        - 2.0 * torch.einsum("ic,ij,jc->c", ws, k_st, wt)
    )
    return per_class.mean()
