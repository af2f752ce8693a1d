"""xAVTNet network: PointNet encoder + fc1/fc2/fc3 head, thesis ch.7, section 7.2.2 and 7.3.1
("Network Implementation"), plus the DANN domain discriminator used by the DANN baseline.

Encoder (Qi et al. 2017): input T-net (3×3) → per-point MLP 64 → feature T-net (64×64) → per-point MLP
(128, global_dim) → masked max-pool to the global feature (1024 in the thesis). Beyond the thesis,
``sa_nodes > 0`` puts PointDAN's self-adaptive nodes after the feature T-net
(:mod:`~vtlearn.models.components.sa_nodes`), so the per-point MLP reads 64 + 64 channels.
Head: fc1 (512, BN, ReLU) → fc2 (256, BN, ReLU) → dropout 0.4 → fc3 (k). The activations after fc1 and
fc2 (post-ReLU, before dropout) are the features that VTLoss adapts (Fig. 7.2b).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import torch
from torch import nn

from vtlearn.models.components.pointnet_tnet import MaskedPointMLP, TNet, lengths_to_mask, packed_max_pool
from vtlearn.models.components.sa_nodes import SelfAdaptiveNodes
from vtlearn.validation import as_bool, as_int, as_real

__all__ = ["PointNetEncoder", "XAVTNetHead", "XAVTNetOutput", "DomainDiscriminator", "check_cloud_batch"]


def check_cloud_batch(points: torch.Tensor, lengths: torch.Tensor | None, name: str = "points"):
    """Validate a padded batch and return ``(points, lengths)`` with lengths filled in.

    Shapes:
        points (B, N, 3) float, lengths (B,) int in [1, N] or None (all N) -> same
    """
    if not isinstance(points, torch.Tensor) or points.dim() != 3 or points.shape[-1] != 3:
        shape = tuple(points.shape) if isinstance(points, torch.Tensor) else type(points).__name__
        raise ValueError(f"{name} must have shape (B, N, 3), got {shape}")
    if points.shape[0] == 0 or points.shape[1] == 0:
        raise ValueError(f"{name} is empty, got shape {tuple(points.shape)}")
    if lengths is None:
        lengths = torch.full((points.shape[0],), points.shape[1], dtype=torch.long, device=points.device)
    if lengths.shape != points.shape[:1]:
        raise ValueError(f"lengths of {name} must have shape ({points.shape[0]},), got "
                         f"{tuple(lengths.shape)}")
    if (lengths < 1).any() or (lengths > points.shape[1]).any():
        raise ValueError(f"lengths of {name} must lie in [1, {points.shape[1]}], got {lengths.tolist()}")
    mask = lengths_to_mask(lengths, points.shape[1])
    if not torch.isfinite(points[mask]).all():
        raise ValueError(f"{name} contains NaN or inf in its valid points")
    return points, lengths


class PointNetEncoder(nn.Module):
    """PointNet global-feature extractor for padded clouds.

    Args:
        global_dim: size of the max-pooled global feature (thesis: 1024).
        input_transform: use the 3×3 input T-net.
        feature_transform: use the 64×64 feature T-net.
        sa_nodes: PointDAN's self-adaptive nodes per cloud after the feature T-net (PointDAN: 64); 0: none,
            the thesis's encoder.
        sa_group, sa_radius, sa_feature_ball: each node's group size and radius (a fraction of the cloud's
            radius), and whether its feature reads only the group's points within the radius, for
            :class:`~vtlearn.models.components.sa_nodes.SelfAdaptiveNodes`.

    Shapes:
        points (B, N, 3), lengths (B,) -> (global (B, global_dim), trans_input (B, 3, 3) or None,
        trans_feat (B, 64, 64) or None)
    """

    def __init__(self, global_dim: int = 1024, input_transform: bool = True, feature_transform: bool = True,
                 sa_nodes: int = 0, sa_group: int = 64, sa_radius: float = 0.3,
                 sa_feature_ball: bool = False):
        super().__init__()
        self.input_tnet = TNet(3, global_dim) if input_transform else None
        self.mlp1 = MaskedPointMLP((3, 64))
        self.feature_tnet = TNet(64, global_dim) if feature_transform else None
        self.sa = (SelfAdaptiveNodes(64, sa_nodes, sa_group, sa_radius, feature_ball=sa_feature_ball)
                   if sa_nodes > 0 else None)
        width = 64 if self.sa is None else self.sa.out_channels
        self.mlp2 = MaskedPointMLP((width, 128, global_dim))
        self.point_dim = width + 128  # the width of :meth:`point_features`'s per-point features

    def forward(self, points: torch.Tensor, lengths: torch.Tensor):
        g, trans_input, trans_feat, _ = self.forward_nodes(points, lengths)
        return g, trans_input, trans_feat  # B x global_dim

    def forward_nodes(self, points: torch.Tensor, lengths: torch.Tensor):
        """:meth:`forward` plus the self-adaptive nodes' features (``None`` without ``sa_nodes``).

        Shapes:
            points (B, N, 3), lengths (B,) -> (global (B, global_dim), (B, 3, 3) or None,
            (B, 64, 64) or None, nodes (B, sa_nodes, 64) or None)
        """
        h, mask, trans_input, trans_feat, nodes = self._aligned(points, lengths)
        return self.mlp2.pooled(h, mask), trans_input, trans_feat, nodes

    def point_features(self, points: torch.Tensor, lengths: torch.Tensor
                       ) -> tuple[torch.Tensor, torch.Tensor]:
        """Each point's features (the 64 after the feature T-net, or 64 + 64 with the self-adaptive nodes,
        and the 128 of the next layer) and the pooled feature, as DefRec's decoder reads them (Achituve et
        al. 2021 concatenate PointNet's per-point layers; :mod:`~vtlearn.models.components.deformation_task`).
        Padded rows are 0.

        Shapes:
            points (B, N, 3), lengths (B,) -> (per-point (B, N, point_dim), global (B, global_dim))
        """
        h, mask, _, _, _ = self._aligned(points, lengths)
        packed = h[mask]
        stages = self.mlp2.packed_stages(packed)
        local = torch.cat([packed, stages[0]], 1)
        per_point = local.new_zeros(h.shape[0], h.shape[1], local.shape[1])
        per_point[mask] = local
        return per_point, packed_max_pool(stages[-1], mask)

    def _aligned(self, points: torch.Tensor, lengths: torch.Tensor):
        """The per-point features after both T-nets (and the self-adaptive nodes), the validity mask, the
        two T-net matrices and the node features.

        Shapes:
            points (B, N, 3), lengths (B,) -> ((B, N, 64) or (B, N, 128) with nodes, (B, N) bool,
            (B, 3, 3) or None, (B, 64, 64) or None, (B, sa_nodes, 64) or None)
        """
        mask = lengths_to_mask(lengths, points.shape[1])
        x = points.masked_fill(~mask[..., None], 0.0)
        x_loc = x  # the input points, where PointDAN's nodes sit (before the input T-net)
        trans_input = trans_feat = None
        if self.input_tnet is not None:
            trans_input = self.input_tnet(x, mask)
            x = x @ trans_input  # B x N x 3, row-vector convention of PointNet
        h = self.mlp1(x, mask)  # B x N x 64
        if self.feature_tnet is not None:
            trans_feat = self.feature_tnet(h, mask)
            h = h @ trans_feat  # padded rows stay 0 (mlp1 zeroes them), and the pool reads valid rows only
        nodes = None
        if self.sa is not None:
            h, nodes, _ = self.sa(h, x_loc, mask)
        return h, mask, trans_input, trans_feat, nodes


@dataclass
class XAVTNetOutput:
    """Forward result: class logits, the adapted features and the T-net matrices."""

    logits: torch.Tensor  # B x k
    features: dict[str, torch.Tensor]  # "global": B x global_dim, "fc1": B x 512, "fc2": B x 256
    trans_input: torch.Tensor | None
    trans_feat: torch.Tensor | None
    nodes: torch.Tensor | None = None  # B x M x 64, PointDAN's node features (sa_nodes > 0 only)


class XAVTNetHead(nn.Module):
    """fc1 → fc2 → dropout → fc3 (thesis 7.3.1).

    ``l2_preserved_dropout``: Xu et al.'s (SAFN, ICCV 2019) L2-preserved dropout. While the dropout is on
    (training, MC-dropout), its output ``m ⊙ f / (1 − p)`` is multiplied by ``√(1 − p)``, so that
    ``E‖m ⊙ f / √(1 − p)‖² = ‖f‖²``, the squared norm evaluation reads, where plain dropout keeps the mean
    instead. fc3 reads it, and it is returned as ``"fc2_dropout"`` for the adaptive feature norm.

    Shapes:
        global (B, in_dim) -> (logits (B, k), {"fc1": (B, fc_dims[0]), "fc2": (B, fc_dims[1])}, with
        "fc2_dropout" (B, fc_dims[1]) too under ``l2_preserved_dropout``)
    """

    def __init__(
        self, in_dim: int, num_classes: int, fc_dims: Sequence[int] = (512, 256), dropout: float = 0.4,
        l2_preserved_dropout: bool = False,
    ):
        super().__init__()
        if len(fc_dims) != 2:
            raise ValueError(f"fc_dims must give the sizes of fc1 and fc2, got {fc_dims}")
        fc_dims = [as_int(d, f"fc_dims[{i}]") for i, d in enumerate(fc_dims)]
        dropout = as_real(dropout, "dropout", low=0.0, high=1.0, open_high=True)
        self.l2_preserved_dropout = as_bool(l2_preserved_dropout, "l2_preserved_dropout")
        self.fc1 = nn.Sequential(nn.Linear(in_dim, fc_dims[0]), nn.BatchNorm1d(fc_dims[0]), nn.ReLU())
        self.fc2 = nn.Sequential(nn.Linear(fc_dims[0], fc_dims[1]), nn.BatchNorm1d(fc_dims[1]), nn.ReLU())
        self.dropout = nn.Dropout(dropout)
        self.fc3 = nn.Linear(fc_dims[1], num_classes)

    def forward(self, g: torch.Tensor):
        f1 = self.fc1(g)
        f2 = self.fc2(f1)
        dropped = self.dropout(f2)
        if not self.l2_preserved_dropout:
            return self.fc3(dropped), {"fc1": f1, "fc2": f2}
        if self.dropout.training:
            dropped = dropped * math.sqrt(1.0 - self.dropout.p)
        return self.fc3(dropped), {"fc1": f1, "fc2": f2, "fc2_dropout": dropped}


class DomainDiscriminator(nn.Module):
    """DANN domain classifier (Ganin et al. 2016): Linear-ReLU-Linear-ReLU-Linear(1); CDAN's (Long et al.
    2018) with ``hidden=1024`` on the multilinear map of fc2 and the softmax.

    Shapes:
        features (B, in_dim) -> logits (B,) (source = 1, target = 0)
    """

    def __init__(self, in_dim: int, hidden: int = 256):
        super().__init__()
        self.net = nn.Sequential(
            nn.Linear(in_dim, hidden), nn.ReLU(), nn.Linear(hidden, hidden), nn.ReLU(), nn.Linear(hidden, 1)
        )

    def forward(self, features: torch.Tensor) -> torch.Tensor:
        return self.net(features).squeeze(-1)
