"""PointNet building blocks for padded point-cloud batches (Qi et al., CVPR 2017), used by xAVTNet
(thesis ch.7, section 7.2.2 "Network Architecture").

Clouds arrive padded, ``(B, N, C)`` plus ``lengths`` (the vtlearn batching format). Padding must not
change any output, so:

* the shared per-point MLP runs on the *packed* valid points only, which keeps batch-norm statistics
  in training mode free of padded rows (a masked ``Conv1d`` + ``BatchNorm1d`` would not be);
* max-pooling fills padded rows with −inf before the max (:func:`masked_max_pool`), or, in the encoders,
  reduces the packed points of each cloud directly (:func:`packed_max_pool`), so the widest layers never
  exist as padded ``(B, N, C)`` tensors. On a CPU the padded tensors, their copies and their backward
  cost about a third of an xAVTNet training step.

The T-net predicts a ``k × k`` alignment matrix (3×3 for the input, 64×64 for features) as identity +
a learned residual; :func:`feature_transform_regularizer` is PointNet's ``‖I − A Aᵀ‖²_F`` term that keeps
the feature transform close to orthogonal.
"""

from __future__ import annotations

from collections.abc import Sequence

import torch
from torch import nn

from vtlearn.validation import as_int

__all__ = [
    "lengths_to_mask",
    "random_valid_order",
    "masked_max_pool",
    "packed_max_pool",
    "MaskedPointMLP",
    "TNet",
    "feature_transform_regularizer",
]


def lengths_to_mask(lengths: torch.Tensor, n: int) -> torch.Tensor:
    """Boolean validity mask of a padded batch, ``mask[b, i] = i < lengths[b]`` (xAVTNet and ACTOR).

    Shapes:
        lengths (B,) int -> (B, n) bool
    """
    return torch.arange(n, device=lengths.device)[None, :] < lengths[:, None]


def random_valid_order(lengths: torch.Tensor, n: int,
                       generator: torch.Generator | None = None) -> torch.Tensor:
    """Per row of a padded batch, a random permutation of its ``lengths[b]`` valid slots first, then its
    padding slots: one ``torch.rand(B, n)`` draw from ``generator``, the padding keys set above every valid
    key, sorted. Gathering a row by its first ``k`` entries takes a random subset of ``k`` valid points.

    Shapes:
        lengths (B,) int -> (B, n) int64
    """
    keys = torch.rand(lengths.shape[0], n, generator=generator, device=lengths.device)
    return keys.masked_fill(~lengths_to_mask(lengths, n), 2.0).argsort(dim=1)


def masked_max_pool(x: torch.Tensor, mask: torch.Tensor) -> torch.Tensor:
    """Max over valid points only. Shapes: x (B, N, C), mask (B, N) -> (B, C)."""
    return x.masked_fill(~mask[..., None], float("-inf")).amax(dim=1)


def packed_max_pool(packed: torch.Tensor, mask: torch.Tensor) -> torch.Tensor:
    """Max over each cloud's valid points, given those points packed (``x[mask]``).

    Equal to ``masked_max_pool`` of the padded tensor, without building it. Every cloud needs at
    least one valid point (:func:`~vtlearn.models.components.xavtnet_backbone.check_cloud_batch`).

    Shapes:
        packed (P, C) with P = mask.sum(), mask (B, N) bool -> (B, C)
    """
    counts = mask.sum(1).tolist()  # x[mask] is row-major: cloud 0's points, then cloud 1's, ...
    if packed.shape[0] != sum(counts):
        raise ValueError(f"packed: need {sum(counts)} rows (mask.sum()), got {packed.shape[0]}")
    # One max per cloud is the fastest form on a CPU (a scatter_reduce or segment_reduce is 2-4x slower).
    return torch.stack([part.amax(0) for part in packed.split(counts)])


class MaskedPointMLP(nn.Module):
    """Shared per-point ``Linear → BatchNorm → ReLU`` stack (PointNet's 1×1 convolutions).

    Args:
        channels: ``(C_in, C_1, …, C_L)``.
        last_activation: apply BN + ReLU after the last layer too.

    Shapes:
        x (B, N, C_in), mask (B, N) bool -> (B, N, C_L) with padded rows set to 0.
    """

    def __init__(self, channels: Sequence[int], last_activation: bool = True) -> None:
        super().__init__()
        if len(channels) < 2:
            raise ValueError(f"channels needs at least an input and an output size, got {channels}")
        layers: list[nn.Module] = []
        for i, (c_in, c_out) in enumerate(zip(channels[:-1], channels[1:], strict=True)):
            layers.append(nn.Linear(c_in, c_out))
            if i < len(channels) - 2 or last_activation:
                layers += [nn.BatchNorm1d(c_out), nn.ReLU()]
        self.net = nn.Sequential(*layers)
        self.out_channels = int(channels[-1])

    def forward(self, x: torch.Tensor, mask: torch.Tensor) -> torch.Tensor:
        packed = self.net(x[mask])  # P x C_out, P = number of valid points in the batch
        out = x.new_zeros(x.shape[0], x.shape[1], self.out_channels)
        out[mask] = packed
        return out

    def pooled(self, x: torch.Tensor, mask: torch.Tensor) -> torch.Tensor:
        """``masked_max_pool(self(x, mask), mask)`` without the padded ``(B, N, C_L)`` tensor.

        Shapes:
            x (B, N, C_in), mask (B, N) bool -> (B, C_L)
        """
        return packed_max_pool(self.net(x[mask]), mask)

    def packed_stages(self, packed: torch.Tensor) -> list[torch.Tensor]:
        """Each layer's output (after its BN + ReLU where it has them) for packed points, first to last; the
        last is ``self.net(packed)``.

        Shapes:
            packed (P, C_in) -> [(P, C_1), …, (P, C_L)]
        """
        out, x = [], packed
        for layer in self.net:
            x = layer(x)
            if not isinstance(layer, nn.Linear | nn.BatchNorm1d):  # the ReLU closes a stage
                out.append(x)
        if isinstance(self.net[-1], nn.Linear):
            out.append(x)
        return out


class TNet(nn.Module):
    """PointNet alignment network predicting a ``k × k`` matrix per cloud.

    Per-point MLP (k, 64, 128, global_dim), masked max-pool, FC (global_dim/2, global_dim/4) with BN +
    ReLU, then a linear layer to ``k²`` initialised at zero, added to the identity, so an untrained
    T-net is the identity transform.

    Shapes:
        x (B, N, k), mask (B, N) -> (B, k, k)
    """

    def __init__(self, k: int, global_dim: int = 1024) -> None:
        super().__init__()
        k, global_dim = as_int(k, "k"), as_int(global_dim, "global_dim", minimum=4)
        self.k = k
        self.mlp = MaskedPointMLP((k, 64, 128, global_dim))
        self.fc = nn.Sequential(
            nn.Linear(global_dim, global_dim // 2),
            nn.BatchNorm1d(global_dim // 2),
            nn.ReLU(),
            nn.Linear(global_dim // 2, global_dim // 4),
            nn.BatchNorm1d(global_dim // 4),
            nn.ReLU(),
        )
        self.out = nn.Linear(global_dim // 4, k * k)
        nn.init.zeros_(self.out.weight)
        nn.init.zeros_(self.out.bias)

    def forward(self, x: torch.Tensor, mask: torch.Tensor) -> torch.Tensor:
        g = self.mlp.pooled(x, mask)
        residual = self.out(self.fc(g)).view(-1, self.k, self.k)
        return residual + torch.eye(self.k, dtype=x.dtype, device=x.device)


def feature_transform_regularizer(trans: torch.Tensor) -> torch.Tensor:
    """PointNet orthogonality regulariser ``mean_b ‖I − A_b A_bᵀ‖²_F`` (Qi et al. 2017, eq. 2).

    Zero exactly when every ``A_b`` is orthogonal.

    Shapes:
        trans (B, k, k) -> scalar
    """
    if trans.dim() != 3 or trans.shape[1] != trans.shape[2]:
        raise ValueError(f"trans must have shape (B, k, k), got {tuple(trans.shape)}")
    eye = torch.eye(trans.shape[1], dtype=trans.dtype, device=trans.device)
    diff = eye - trans @ trans.transpose(1, 2)
    return (diff * diff).sum(dim=(1, 2)).mean()
