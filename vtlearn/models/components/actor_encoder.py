"""ACTOR feature-extraction encoder (thesis ch.8, Sec. 8.2.2, Fig. 8.2(a) and Fig. 8.3).

PointNet per-point features (64, 64, 128, 1024) are max-pooled into a global vector; the
self-attention unit acts on the same per-point features, its output is max-pooled too, and the two
pooled vectors are aggregated by summation into the 1024-d global feature vector. With
``attention=False`` (the ablation of Table 8.2) the global vector is the plain max-pool.

Padded points never win a max-pool: they are set to -inf first, so the global vector of a cloud
does not depend on how much padding it carries.
"""

from __future__ import annotations

from torch import Tensor, nn

from vtlearn.models.components.actor_attention import SelfAttentionUnit
from vtlearn.models.components.actor_pointnet import PointNetFeatures, lengths_to_mask

__all__ = ["ActorEncoder", "masked_max_pool"]


def masked_max_pool(x: Tensor, mask: Tensor | None) -> Tensor:
    """Max over the valid points.

    Shapes:
        x: (B, C, N); mask: (B, N) bool or None; returns (B, C).
    """
    if mask is not None:
        x = x.masked_fill(~mask[:, None, :], float("-inf"))
    return x.max(dim=2).values


class ActorEncoder(nn.Module):
    """Sparse cloud -> 1024-d global shape descriptor.

    Args:
        channels: PointNet conv channels, thesis (64, 64, 128, 1024).
        attention: include the self-attention unit (thesis default True; False for Table 8.2).
        attention_reduction: C / C' of the attention's G and H.

    Shapes:
        points: (B, N, 3) padded with anything; lengths: (B,) int64 or None (all N valid);
        returns (B, channels[-1]).
    """

    def __init__(
        self,
        channels: tuple[int, ...] = (64, 64, 128, 1024),
        attention: bool = True,
        attention_reduction: int = 8,
    ) -> None:
        super().__init__()
        self.features = PointNetFeatures(channels)
        self.attention = (
            SelfAttentionUnit(self.features.out_channels, attention_reduction) if attention else None
        )

    @property
    def out_channels(self) -> int:
        return self.features.out_channels

    def forward(self, points: Tensor, lengths: Tensor | None = None) -> Tensor:
        if points.dim() != 3 or points.shape[-1] != 3:
            raise ValueError(f"points: expected (B, N, 3), got {tuple(points.shape)}")
        mask = None
        if lengths is not None:
            if lengths.shape != points.shape[:1]:
                raise ValueError(f"lengths: expected shape ({points.shape[0]},), got {tuple(lengths.shape)}")
            if (lengths < 1).any() or (lengths > points.shape[1]).any():
                raise ValueError(f"lengths: values must be in [1, {points.shape[1]}], got {lengths.tolist()}")
            mask = lengths_to_mask(lengths, points.shape[1])
        feats = self.features(points, mask)  # B x 1024 x N
        global_feat = masked_max_pool(feats, mask)
        if self.attention is not None:
            global_feat = global_feat + masked_max_pool(self.attention(feats, mask), mask)
        return global_feat
