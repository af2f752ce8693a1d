"""Rotation prediction, a self-supervised task that both domains share (beyond the thesis).

Each cloud is turned by ``k·90°`` about the canonical x axis, which lies in the table plane (the clouds'
yaw about z is random, so a turn about z could not be told), and a small head on the pooled feature
predicts ``k``. Telling an upright object from one on its side or upside down takes its shape, and the task
needs no class label, so the tactile clouds train the encoder too. Gidaris, Singh and Komodakis (ICLR
2018) proposed the task for images; Sun et al. (arXiv 1909.11825, 2019) shared it between the domains
for unsupervised domain adaptation; GAST (Zou et al., ICCV 2021) classifies quarter turns of object point
clouds for the same purpose (``XAVTNet(rotation_weight > 0)``).
"""

from __future__ import annotations

import math

import torch

from vtlearn.models.components.projection_head import ProjectionHead

__all__ = ["QUARTER_TURNS", "RotationHead", "turn_about_x", "random_quarter_turns"]

QUARTER_TURNS = 4


def turn_about_x(points: torch.Tensor, turns: torch.Tensor) -> torch.Tensor:
    """Each cloud ``b`` rotated by ``turns[b]·90°`` about the x axis through the origin (right-handed:
    one turn takes +y to +z). Zero padding stays zero.

    Shapes:
        points (B, N, 3), turns (B,) int in [0, 4) -> (B, N, 3)
    """
    if points.ndim != 3 or points.shape[-1] != 3:
        raise ValueError(f"points: expected (B, N, 3), got {tuple(points.shape)}")
    if turns.shape != points.shape[:1]:
        raise ValueError(f"turns: expected ({points.shape[0]},), got {tuple(turns.shape)}")
    if turns.numel() and (int(turns.min()) < 0 or int(turns.max()) >= QUARTER_TURNS):
        raise ValueError(f"turns: need quarter turns in [0, {QUARTER_TURNS}), got {turns.tolist()}")
    angle = turns.to(points.dtype) * (math.pi / 2)
    c, s = torch.cos(angle).round(), torch.sin(angle).round()  # exact for quarter turns
    one, zero = torch.ones_like(c), torch.zeros_like(c)
    R = torch.stack([torch.stack([one, zero, zero], -1), torch.stack([zero, c, -s], -1),
                     torch.stack([zero, s, c], -1)], -2)  # (B, 3, 3), R_x(angle)
    return points @ R.transpose(1, 2)


def random_quarter_turns(points: torch.Tensor, generator: torch.Generator | None = None
                         ) -> tuple[torch.Tensor, torch.Tensor]:
    """The clouds turned by a uniformly drawn number of quarter turns each, and those numbers (the labels).

    Shapes:
        points (B, N, 3) -> (B, N, 3), (B,) int64
    """
    turns = torch.randint(QUARTER_TURNS, (points.shape[0],), generator=generator).to(points.device)
    return turn_about_x(points, turns), turns


class RotationHead(ProjectionHead):
    """:class:`~vtlearn.models.components.projection_head.ProjectionHead`'s Linear-ReLU-Linear from the
    pooled feature, read as logits of the four quarter turns (no batch norm, so the rotated batches leave no
    statistics behind).

    Shapes:
        global (B, in_dim) -> logits (B, 4)
    """

    def __init__(self, in_dim: int, hidden: int = 256):
        super().__init__(in_dim, hidden, QUARTER_TURNS)
