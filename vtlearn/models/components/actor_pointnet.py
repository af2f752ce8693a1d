"""ACTOR feature-extraction encoder: a PointNet with masked batch norm (thesis ch.8, Sec. 8.2.2).

Murali, "Visuo-tactile perception and learning for robots", ch.8, Fig. 8.2(a): the encoder is a
modified PointNet (Qi et al., 2017). Four shared 1x1 convolutions with output channels
(64, 64, 128, 1024), the first acting on the raw xyz, each followed by batch norm and ReLU.

Clouds in a batch have different sizes (20 to 1024 points in ACTOR), so they travel padded as
``(B, N, 3)`` plus ``lengths``. Batch norm in training mode must not see the padding, or the output
for a cloud would depend on how much padding its batch happened to carry; :class:`MaskedBatchNorm1d`
therefore computes its statistics over the valid points only.
"""

from __future__ import annotations

import torch
from torch import Tensor, nn

from vtlearn.models.components.pointnet_tnet import lengths_to_mask  # one padded-batch mask for both nets

__all__ = ["MaskedBatchNorm1d", "PointNetFeatures", "lengths_to_mask"]


class MaskedBatchNorm1d(nn.BatchNorm1d):
    """``nn.BatchNorm1d`` over (B, C, N) features whose statistics ignore padded points.

    In training mode the mean and biased variance are taken over the valid points of the whole
    batch (the unbiased variance updates the running statistics, as in PyTorch). In eval mode it
    is an ordinary per-point affine map with the running statistics. ``momentum`` is PyTorch's
    (``1 - decay`` in TensorFlow's convention), so a scheduler may change it between steps.

    Shapes:
        x: (B, C, N); mask: (B, N) bool or None (all valid); returns (B, C, N).
    """

    def forward(self, x: Tensor, mask: Tensor | None = None) -> Tensor:  # type: ignore[override]
        if mask is None or not self.training:
            return super().forward(x)
        m = mask[:, None, :].to(x.dtype)  # B x 1 x N
        count = m.sum()
        if count < 2:
            raise ValueError(f"mask: batch norm in training mode needs at least 2 valid points, got {count}")
        mean = (x * m).sum(dim=(0, 2)) / count  # C
        centred = (x - mean[None, :, None]) * m
        var = (centred**2).sum(dim=(0, 2)) / count
        with torch.no_grad():
            if self.track_running_stats and self.running_mean is not None:
                self.num_batches_tracked += 1
                momentum = self.momentum if self.momentum is not None else 0.1
                self.running_mean.mul_(1 - momentum).add_(momentum * mean)
                self.running_var.mul_(1 - momentum).add_(momentum * var * count / (count - 1))
        y = (x - mean[None, :, None]) / torch.sqrt(var[None, :, None] + self.eps)
        if self.affine:
            y = y * self.weight[None, :, None] + self.bias[None, :, None]
        return y


class PointNetFeatures(nn.Module):
    """Per-point PointNet features of ACTOR's encoder (thesis Sec. 8.2.2, Fig. 8.2(a)).

    Shared 1x1 convolutions 3 -> 64 -> 64 -> 128 -> 1024, each with (masked) batch norm and ReLU.
    Global pooling is left to the caller (:class:`vtlearn.models.components.actor_encoder.ActorEncoder`)
    so that the self-attention unit can act on the per-point features first.

    Args:
        channels: output channels of the four convolutions; the thesis uses (64, 64, 128, 1024).

    Shapes:
        points: (B, N, 3) padded; mask: (B, N) bool or None; returns (B, C_last, N).
    """

    def __init__(self, channels: tuple[int, ...] = (64, 64, 128, 1024)) -> None:
        super().__init__()
        if len(channels) < 1 or any(int(c) < 1 for c in channels):
            raise ValueError(f"channels: need positive sizes, got {channels}")
        self.channels = tuple(int(c) for c in channels)
        c_in = 3
        self.convs = nn.ModuleList()
        self.norms = nn.ModuleList()
        for c in self.channels:
            self.convs.append(nn.Conv1d(c_in, c, kernel_size=1, bias=False))
            self.norms.append(MaskedBatchNorm1d(c))
            c_in = c

    @property
    def out_channels(self) -> int:
        return self.channels[-1]

    def forward(self, points: Tensor, mask: Tensor | None = None) -> Tensor:
        if points.dim() != 3 or points.shape[-1] != 3:
            raise ValueError(f"points: expected (B, N, 3), got {tuple(points.shape)}")
        x = points.transpose(1, 2)  # B x 3 x N
        for conv, norm in zip(self.convs, self.norms, strict=True):
            x = torch.relu(norm(conv(x), mask))
        return x

    def __repr__(self) -> str:
        return f"{self.__class__.__name__}(channels={self.channels})"
