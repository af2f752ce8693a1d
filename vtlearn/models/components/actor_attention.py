"""ACTOR self-attention unit (thesis ch.8, Sec. 8.2.2, Fig. 8.3; after Zhang et al., 2019).

Two MLPs give features G and H, the weights are W = softmax(Gᵀ H); a third MLP gives K, and the
output is Wᵀ K summed with the input features (a residual connection).

With per-point features F = [f_1 ... f_N] (C x N), G = mlp_g(F), H = mlp_h(F) (C' x N each) and
K = mlp_k(F) (C x N), the score matrix is S = Gᵀ H (N x N, S_ji = g_j · h_i). The softmax runs over
the index j that Wᵀ K sums over, so every output is the input plus a convex combination of the
values of the valid points::

    W_ji = exp(S_ji) / sum_j' exp(S_j'i),      out_i = f_i + sum_j W_ji k_j

Padded points are excluded by setting their scores to -inf before the softmax; their own outputs
are meaningless and are masked out by the caller's max-pool.

Weights below ``MIN_WEIGHT`` (1e-12) are set to 0 after the softmax. Together they move an output by
less than ``N · 1e-12 · max|k|``, below float32 resolution, but left in place they become denormal
floats once training sharpens the scores (about 5 % of the weights after eight steps), and every
product with a denormal takes a slow path on x86 CPUs: the backward of ``mlp_k`` and of ``Wᵀ K``
then took 60 % of a CPU training step of ``configs/cpu/actor.yaml``, and zeroing them made the step
2.2× faster (docs/actor.md).
"""

from __future__ import annotations

import torch
from torch import Tensor, nn

from vtlearn.validation import as_int

__all__ = ["MIN_WEIGHT", "SelfAttentionUnit"]

MIN_WEIGHT = 1e-12


class SelfAttentionUnit(nn.Module):
    """Self-attention over the points of a cloud (thesis Fig. 8.3).

    Args:
        channels: C, the feature size of the input and output.
        reduction: C' = C // reduction for G and H (SAGAN uses 8).

    Shapes:
        x: (B, C, N); mask: (B, N) bool or None (all valid); returns (B, C, N).
    """

    def __init__(self, channels: int, reduction: int = 8) -> None:
        super().__init__()
        channels, reduction = as_int(channels, "channels"), as_int(reduction, "reduction")
        if channels // reduction < 1:
            raise ValueError(f"reduction: must be in [1, channels], got {reduction} for channels={channels}")
        self.channels = int(channels)
        self.reduction = int(reduction)
        inner = self.channels // self.reduction
        self.mlp_g = nn.Conv1d(self.channels, inner, kernel_size=1)
        self.mlp_h = nn.Conv1d(self.channels, inner, kernel_size=1)
        self.mlp_k = nn.Conv1d(self.channels, self.channels, kernel_size=1)

    def attention_weights(self, x: Tensor, mask: Tensor | None = None) -> Tensor:
        """W = softmax(Gᵀ H), normalised over the first index (the one Wᵀ K sums over), with weights
        below ``MIN_WEIGHT`` set to 0 (module docstring).

        Shapes:
            x: (B, C, N); returns (B, N, N) with ``W[b, j, i]``; columns sum to 1 over valid j.
        """
        g = self.mlp_g(x)  # B x C' x N
        h = self.mlp_h(x)  # B x C' x N
        scores = torch.bmm(g.transpose(1, 2), h)  # B x N x N, S_ji = g_j . h_i
        if mask is not None:
            scores = scores.masked_fill(~mask[:, :, None], float("-inf"))
        w = torch.softmax(scores, dim=1)
        return w.masked_fill(w < MIN_WEIGHT, 0.0)

    def forward(self, x: Tensor, mask: Tensor | None = None) -> Tensor:
        if x.dim() != 3 or x.shape[1] != self.channels:
            raise ValueError(f"x: expected (B, {self.channels}, N), got {tuple(x.shape)}")
        w = self.attention_weights(x, mask)  # B x N(j) x N(i)
        k = self.mlp_k(x)  # B x C x N
        # (Wᵀ K) in point-major form is out_i = sum_j W_ji k_j, i.e. K @ W in channel-major form.
        return x + torch.bmm(k, w)

    def __repr__(self) -> str:
        return f"{self.__class__.__name__}(channels={self.channels}, reduction={self.reduction})"
