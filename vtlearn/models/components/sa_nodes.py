"""PointDAN's self-adaptive (SA) node module and its node attention (Qin et al., "PointDAN: A Multi-Scale 3D
Domain Adaption Network for Point Cloud Representation", NeurIPS 2019, section 3.2), beyond the thesis.

PointDAN aligns two levels. Its global alignment is MCD (:mod:`vtlearn.losses.mcd`). Its local alignment
matches the features of a few local regions of each cloud, the *nodes*, between the domains
(:mod:`vtlearn.losses.pointdan`). :class:`SelfAdaptiveNodes` builds those nodes inside the PointNet encoder,
after the feature T-net, for padded clouds:

1. ``M`` nodes by farthest-point sampling of the cloud's points (:func:`farthest_point_indices`), started
   from each cloud's first point;
2. each node's group: its ``k`` nearest points that lie within ``radius`` of it, where ``radius`` is a
   fraction of the cloud's own radius (the largest distance of a point from the centroid). PointDAN's
   clouds lie in the unit ball and its radius is 0.3, so the fraction 0.3 is PointDAN's ball here too, on
   clouds in metres;
3. each node moves by a learned offset (their ``adapt_layer_off``),
   ``Δ = mean_j tanh(W·(h_j − h_node)) ⊙ (x_j − x_node)`` over the group's points ``j``, with ``W`` a
   bias-free linear map of the 64-d point features to 3 (their ``pred_offset``);
4. each moved node's feature is the max, over its ``k`` nearest points, of a per-point ``Linear → BN →
   ReLU`` of the point features (their ``residual``): ``(B, M, node_dim)``. With ``feature_ball`` (not
   PointDAN's) only those of the ``k`` that lie within the radius of the moved node count, the nearest
   always;
5. the node features are interpolated back to every point from its 3 nearest moved nodes, with weights
   ``1/d²`` normalised to 1, and concatenated to the point features, so the next layer reads
   ``64 + node_dim`` channels per point. The offsets get their gradient through these weights.

Departures from PointDAN's code besides step 1's first-point start, for padded clouds of 30-256 points:
step 3 averages over the group's members within the radius, where PointDAN fills a short group with
copies of its first member and averages over all 64, so a cloud's output does not depend on how far it is
padded. A cloud with fewer points than ``M`` or ``k`` repeats nodes or neighbours, which leaves the maxima
and the interpolation as they are.

Sparse clouds: step 4's ``k`` nearest points are PointDAN's fixed-size region, made for 1024-point clouds
in both domains. A tactile cloud of 30-120 contacts has ``k`` = 64 nearest points that are most or all of
the cloud, so its nodes read (nearly) the same global maximum, while a 256-point visual cloud's nodes read
a quarter of it each. ``feature_ball`` bounds the region by the same fraction of each cloud's radius in
both domains instead, so a tactile node reads the few contacts near it.

:class:`NodeAttention` is PointDAN's node attention ahead of the local MMD (their ``CALayer``): the
flattened node features ``z`` of one domain are gated by a squeeze-and-excitation MLP, ``z ⊙ σ(W₂ ReLU(W₁
z)) + z``, then batch-normalised; each domain has its own.
"""

from __future__ import annotations

import torch
from torch import nn

from vtlearn.models.components.pointnet_tnet import MaskedPointMLP
from vtlearn.validation import as_bool, as_int, as_real

__all__ = ["farthest_point_indices", "SelfAdaptiveNodes", "NodeAttention"]


def _gather(x: torch.Tensor, idx: torch.Tensor) -> torch.Tensor:
    """``x[b, idx[b, ...]]`` for every cloud ``b``.

    Shapes:
        x (B, N, C), idx (B, ...) int64 -> (B, ..., C)
    """
    batch = torch.arange(x.shape[0], device=x.device).view(-1, *([1] * (idx.dim() - 1)))
    return x[batch, idx]


def _squared_distances(a: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
    """Squared distances written as differences (smooth at 0, unlike ``cdist``'s square root).

    Shapes:
        a (B, P, 3), b (B, Q, 3) -> (B, P, Q)
    """
    return (a[:, :, None, :] - b[:, None, :, :]).pow(2).sum(-1)


def farthest_point_indices(xyz: torch.Tensor, mask: torch.Tensor, num: int) -> torch.Tensor:
    """Farthest-point sampling of each cloud's valid points, started from its first point: each pick is
    the valid point farthest from the points picked so far. A cloud with fewer than ``num`` valid points
    repeats picks once every point is taken.

    Shapes:
        xyz (B, N, 3), mask (B, N) bool with mask[:, 0] true, num int -> (B, num) int64
    """
    num = as_int(num, "num")
    b, n, _ = xyz.shape
    picks = torch.zeros(b, num, dtype=torch.long, device=xyz.device)
    # padded points sit at -1, below every valid distance (>= 0), so they are never picked
    nearest = torch.full((b, n), float("inf"), dtype=xyz.dtype, device=xyz.device).masked_fill(~mask, -1.0)
    current = torch.zeros(b, dtype=torch.long, device=xyz.device)
    rows = torch.arange(b, device=xyz.device)
    with torch.no_grad():
        for i in range(num):
            picks[:, i] = current
            d = (xyz - xyz[rows, current][:, None, :]).pow(2).sum(-1)
            nearest = torch.where(mask, torch.minimum(nearest, d), nearest)
            current = nearest.argmax(1)
    return picks


class SelfAdaptiveNodes(nn.Module):
    """PointDAN's SA node module (module docstring) on padded per-point features.

    Args:
        channels: width of the point features it reads (64 after xAVTNet's feature T-net).
        num_nodes: ``M``, the nodes per cloud (PointDAN: 64).
        group_size: ``k``, the points per node's group (PointDAN: 64).
        radius: the group radius as a fraction of each cloud's radius (PointDAN: 0.3 in the unit ball), > 0.
        node_dim: width of a node's feature (PointDAN: 64).
        feature_ball: step 4's max over the ``k`` nearest points within ``radius`` of the moved node (the
            nearest always) instead of over all ``k`` (PointDAN's); module docstring, "Sparse clouds".

    Shapes:
        features (B, N, channels), xyz (B, N, 3), mask (B, N) bool -> (per-point (B, N, channels + node_dim)
        with padded rows 0, nodes (B, M, node_dim), offsets (B, M, 3))
    """

    def __init__(self, channels: int = 64, num_nodes: int = 64, group_size: int = 64, radius: float = 0.3,
                 node_dim: int = 64, feature_ball: bool = False) -> None:
        super().__init__()
        self.channels = as_int(channels, "channels")
        self.num_nodes = as_int(num_nodes, "num_nodes")
        self.group_size = as_int(group_size, "group_size")
        self.radius = as_real(radius, "radius", low=0.0, open_low=True)
        self.node_dim = as_int(node_dim, "node_dim")
        self.feature_ball = as_bool(feature_ball, "feature_ball")
        self.offset = nn.Linear(self.channels, 3, bias=False)
        self.residual = MaskedPointMLP((self.channels, self.node_dim))
        self.out_channels = self.channels + self.node_dim

    def forward(self, features: torch.Tensor, xyz: torch.Tensor, mask: torch.Tensor
                ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        b, n, c = features.shape
        if c != self.channels or xyz.shape != (b, n, 3) or mask.shape != (b, n):
            raise ValueError(f"features, xyz, mask: expected (B, N, {self.channels}), (B, N, 3) and (B, N), "
                             f"got {tuple(features.shape)}, {tuple(xyz.shape)} and {tuple(mask.shape)}")
        k = min(self.group_size, n)
        far = torch.finfo(xyz.dtype).max
        node_idx = farthest_point_indices(xyz, mask, self.num_nodes)
        node_xyz = _gather(xyz, node_idx)
        # each cloud's radius: the largest distance of a valid point from its centroid
        count = mask.sum(1, keepdim=True).to(xyz.dtype)
        centroid = (xyz * mask[..., None]).sum(1) / count
        spread = ((xyz - centroid[:, None]).pow(2).sum(-1) * mask).amax(1)  # (B,) squared
        ball = (self.radius ** 2) * spread[:, None, None]
        with torch.no_grad():
            d2 = _squared_distances(node_xyz, xyz).masked_fill(~mask[:, None, :], far)
            dk, group = d2.topk(k, dim=-1, largest=False)  # nearest first; the node itself is first
        inside = (dk <= ball).to(xyz.dtype)  # (B, M, k): the group's members
        # step 3: Δ = mean over members of tanh(W (h_j − h_node)) ⊙ (x_j − x_node); W is linear, so W h is
        # taken per point first and the groups gather 3 channels instead of 64
        wh = self.offset(features)  # (B, N, 3)
        rel_x = _gather(xyz, group) - node_xyz[:, :, None]
        step = torch.tanh(_gather(wh, group) - _gather(wh, node_idx)[:, :, None]) * rel_x * inside[..., None]
        offsets = step.sum(2) / inside.sum(2, keepdim=True).clamp_min(1.0)
        moved = node_xyz + offsets
        with torch.no_grad():
            d2 = _squared_distances(moved, xyz).masked_fill(~mask[:, None, :], far)
            dk, group = d2.topk(k, dim=-1, largest=False)
            member = dk < far
            if self.feature_ball:
                member &= dk <= ball
                member[..., 0] = True
            group = torch.where(member, group, group[..., :1])  # the others repeat the nearest point
        # max (with its argmax, whose backward is a scatter) rather than amax (whose backward splits ties)
        nodes = _gather(self.residual(features, mask), group).max(2).values  # (B, M, node_dim)
        # back to the points: 1/d² weights of each point's 3 nearest moved nodes
        d2 = _squared_distances(xyz, moved)  # (B, N, M), with gradient to the offsets
        near = d2.detach().topk(min(3, self.num_nodes), dim=-1, largest=False).indices
        w = 1.0 / d2.gather(2, near).clamp_min(1e-10)
        w = w / w.sum(-1, keepdim=True)
        interpolated = (_gather(nodes, near) * w[..., None]).sum(2)
        out = torch.cat([features, interpolated], -1).masked_fill(~mask[..., None], 0.0)
        return out, nodes, offsets


class NodeAttention(nn.Module):
    """PointDAN's node attention for one domain (module docstring): ``BN(z ⊙ σ(W₂ ReLU(W₁ z)) + z)`` of the
    flattened node features ``z``.

    Args:
        num_nodes, node_dim: the node tensor's shape, flattened to ``num_nodes·node_dim`` channels.
        reduction: the squeeze ratio of ``W₁`` (PointDAN: 8).

    Shapes:
        nodes (B, num_nodes, node_dim) -> (B, num_nodes·node_dim)
    """

    def __init__(self, num_nodes: int = 64, node_dim: int = 64, reduction: int = 8) -> None:
        super().__init__()
        self.shape = (as_int(num_nodes, "num_nodes"), as_int(node_dim, "node_dim"))
        width = self.shape[0] * self.shape[1]
        hidden = max(1, width // as_int(reduction, "reduction"))
        self.gate = nn.Sequential(nn.Linear(width, hidden), nn.ReLU(), nn.Linear(hidden, width), nn.Sigmoid())
        self.norm = nn.BatchNorm1d(width)

    def forward(self, nodes: torch.Tensor) -> torch.Tensor:
        if nodes.dim() != 3 or tuple(nodes.shape[1:]) != self.shape:
            raise ValueError(f"nodes: expected shape (B, {self.shape[0]}, {self.shape[1]}), got "
                             f"{tuple(nodes.shape)}")
        z = nodes.flatten(1)
        return self.norm(z * self.gate(z) + z)
