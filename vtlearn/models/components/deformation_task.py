"""Deformation reconstruction (DefRec), a self-supervised task that both domains share (beyond the thesis).

Achituve, Maron and Chechik (WACV 2021, "Self-Supervised Learning for Domain Adaptation on Point
Clouds") deform one region of each cloud and train a small per-point decoder to put the region's points
back. Their volume-based deformation splits the shape's cube into ``3 × 3 × 3`` voxels, picks a voxel at
random among those holding at least 40 of the 1,024 points, and replaces that voxel's points by draws from
an isotropic Gaussian at the voxel's centre (variance 0.001 of the unit-sphere shape). The loss is the
symmetric Chamfer distance (squared distances) between the decoded and the original points of the region.
It needs no class label, so the unlabelled tactile clouds train the encoder too
(``XAVTNet(defrec_weight > 0)``).

Differences from their code, for clouds of 30 to 1,024 points in any frame:

* the voxel grid spans each cloud's own bounding box, and the Gaussian's standard deviation and the
  Chamfer distance are measured in half the box's longest side (their unit-sphere scale), so the task is
  the same in metres or in a box frame;
* the threshold is their share of the points, 40/1024, of each cloud (at least 2 points); a cloud with no
  voxel that full deforms its fullest voxel (theirs leaves such a shape undeformed);
* each cloud draws its own voxel order (theirs is one order per batch);
* the decoder reads the points of the deformed region only, as only they enter the loss, and has no
  dropout.
"""

from __future__ import annotations

import math

import torch

from vtlearn.models.components.pointnet_tnet import MaskedPointMLP, lengths_to_mask
from vtlearn.validation import as_int, as_real

__all__ = ["DEFREC_MIN_SHARE", "DEFREC_VARIANCE", "deform_region", "region_chamfer", "RegionDecoder"]

DEFREC_MIN_SHARE = 40 / 1024  # their 40 points of a 1,024-point shape
DEFREC_VARIANCE = 1e-3  # their isotropic variance, in unit-sphere units


def deform_region(points: torch.Tensor, lengths: torch.Tensor, regions: int = 3,
                  min_share: float = DEFREC_MIN_SHARE, variance: float = DEFREC_VARIANCE,
                  generator: torch.Generator | None = None
                  ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """Each cloud with one voxel's points replaced by Gaussian draws at the voxel's centre (module
    docstring): the deformed clouds, which points were replaced, and each cloud's scale (half its bounding
    box's longest side; 1 for a cloud of coincident points). Padding stays as it was.

    Shapes:
        points (B, N, 3), lengths (B,) int in [1, N] -> (deformed (B, N, 3), region (B, N) bool,
        scale (B,))
    """
    regions = as_int(regions, "regions")
    as_real(min_share, "min_share", low=0.0, high=1.0)
    as_real(variance, "variance", low=0.0)
    if points.ndim != 3 or points.shape[-1] != 3:
        raise ValueError(f"points: expected (B, N, 3), got {tuple(points.shape)}")
    if lengths.shape != points.shape[:1]:
        raise ValueError(f"lengths: expected ({points.shape[0]},), got {tuple(lengths.shape)}")
    b, n = points.shape[:2]
    valid = lengths_to_mask(lengths, n)
    big = torch.finfo(points.dtype).max
    lo = points.masked_fill(~valid[..., None], big).amin(1)  # (B, 3)
    hi = points.masked_fill(~valid[..., None], -big).amax(1)
    side = hi - lo
    scale = side.amax(1) / 2
    scale = torch.where(scale > 0, scale, torch.ones_like(scale))
    cell = side.clamp_min(torch.finfo(points.dtype).tiny) / regions  # a flat axis is one slab of cells
    idx = ((points - lo[:, None]) / cell[:, None]).floor().clamp(0, regions - 1).long()  # (B, N, 3)
    voxel = (idx[..., 0] * regions + idx[..., 1]) * regions + idx[..., 2]
    voxel = voxel.masked_fill(~valid, regions ** 3)  # padding counts in a spare bin
    counts = torch.zeros(b, regions ** 3 + 1, dtype=torch.long, device=points.device)
    counts.scatter_add_(1, voxel, torch.ones_like(voxel))
    counts = counts[:, :-1]
    need = (lengths.to(torch.float64) * min_share).ceil().long().clamp_min(2)
    keys = torch.rand(b, regions ** 3, generator=generator).to(points.device)
    eligible = counts >= need[:, None]
    pick = torch.where(eligible.any(1), keys.masked_fill(~eligible, -1.0).argmax(1), counts.argmax(1))
    region = (voxel == pick[:, None]) & valid
    centre_idx = torch.stack([pick // regions ** 2, (pick // regions) % regions, pick % regions], -1)
    centre = lo + (centre_idx.to(points.dtype) + 0.5) * side / regions  # (B, 3)
    noise = torch.randn(b, n, 3, generator=generator).to(points)
    draws = centre[:, None] + math.sqrt(variance) * scale[:, None, None] * noise
    return torch.where(region[..., None], draws, points), region, scale


def region_chamfer(pred: torch.Tensor, target: torch.Tensor, region: torch.Tensor,
                   scale: torch.Tensor) -> torch.Tensor:
    """DefRec's loss: per cloud, the symmetric Chamfer distance (mean squared nearest-neighbour distance
    each way) between the decoded and the original points of its deformed region, in units of the
    cloud's ``scale``, averaged over the clouds. Clouds with an empty region are left out; with none left
    the loss is 0 (and still part of the graph).

    Shapes:
        pred (B, N, 3), target (B, N, 3), region (B, N) bool, scale (B,) -> ()
    """
    if pred.shape != target.shape or pred.shape[:2] != region.shape or scale.shape != pred.shape[:1]:
        raise ValueError(f"pred, target, region, scale: need (B, N, 3), (B, N, 3), (B, N), (B,), got "
                         f"{tuple(pred.shape)}, {tuple(target.shape)}, {tuple(region.shape)}, "
                         f"{tuple(scale.shape)}")
    count = region.sum(1)
    keep = count > 0
    if not keep.any():
        return pred.sum() * 0.0
    pred, target, region, scale, count = pred[keep], target[keep], region[keep], scale[keep], count[keep]
    m = int(count.max())
    order = (~region).to(torch.uint8).argsort(dim=1, stable=True)[:, :m]  # each cloud's region points first
    inside = torch.arange(m, device=pred.device)[None] < count[:, None]  # (B', m)
    p = pred.gather(1, order[..., None].expand(-1, -1, 3)) / scale[:, None, None]
    t = target.gather(1, order[..., None].expand(-1, -1, 3)) / scale[:, None, None]
    d = torch.cdist(p, t).square()
    d = d.masked_fill(~inside[:, None, :], float("inf")).masked_fill(~inside[:, :, None], float("inf"))
    to_target = d.amin(2).masked_fill(~inside, 0.0).sum(1) / count
    to_pred = d.amin(1).masked_fill(~inside, 0.0).sum(1) / count
    return (to_target + to_pred).mean()


class RegionDecoder(MaskedPointMLP):
    """DefRec's region-reconstruction head: a per-point MLP (256, 256, 128, BN + ReLU) to 3 coordinates,
    on each point's encoder features concatenated with its cloud's pooled feature. It runs on the points
    of ``region`` only (zeros elsewhere), so the padded ``(B, N, point_dim + global_dim)`` input is never
    built.

    Shapes:
        point_features (B, N, point_dim), pooled (B, global_dim), region (B, N) bool -> (B, N, 3)
    """

    def __init__(self, point_dim: int, global_dim: int):
        point_dim, global_dim = as_int(point_dim, "point_dim"), as_int(global_dim, "global_dim")
        super().__init__((point_dim + global_dim, 256, 256, 128, 3), last_activation=False)
        self.point_dim, self.global_dim = point_dim, global_dim

    def forward(self, point_features: torch.Tensor, pooled: torch.Tensor,  # type: ignore[override]
                region: torch.Tensor) -> torch.Tensor:
        if region.ndim != 2 or region.dtype != torch.bool:
            raise ValueError(f"region must be a (B, N) bool mask, got {tuple(region.shape)} {region.dtype}")
        b, n = region.shape
        if point_features.shape != (b, n, self.point_dim):
            raise ValueError(f"point_features must have shape ({b}, {n}, {self.point_dim}), "
                             f"got {tuple(point_features.shape)}")
        if pooled.shape != (b, self.global_dim):
            raise ValueError(f"pooled must have shape ({b}, {self.global_dim}), got {tuple(pooled.shape)}")
        cloud = region.nonzero(as_tuple=True)[0]  # the cloud of each region point, in x[region]'s order
        packed = self.net(torch.cat([point_features[region], pooled[cloud]], -1))
        out = point_features.new_zeros(b, n, 3)
        out[region] = packed
        return out
