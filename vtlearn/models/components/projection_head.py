"""The projection head of contrastive learning (beyond the thesis).

SimCLR (Chen et al., ICML 2020) reads its contrastive loss from a small MLP on top of the representation
rather than from the representation itself, which keeps in the representation what the loss's invariances
would otherwise remove (their section 4.2). ``XAVTNet(contrast_weight > 0)`` puts this head on the pooled
PointNet feature (:func:`~vtlearn.losses.contrastive.nt_xent`).
"""

from __future__ import annotations

import torch
from torch import nn

__all__ = ["ProjectionHead"]


class ProjectionHead(nn.Module):
    """Linear-ReLU-Linear from the pooled feature to the contrastive space (no batch norm, so the
    perturbed copies leave no statistics behind). The rotation task's head is the same MLP with four
    outputs (:class:`~vtlearn.models.components.rotation_task.RotationHead`).

    Shapes:
        global (B, in_dim) -> (B, out_dim)
    """

    def __init__(self, in_dim: int, hidden: int = 256, out_dim: int = 128):
        super().__init__()
        self.net = nn.Sequential(nn.Linear(in_dim, hidden), nn.ReLU(), nn.Linear(hidden, out_dim))

    def forward(self, g: torch.Tensor) -> torch.Tensor:
        return self.net(g)
