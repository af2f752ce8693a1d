"""Cross-domain mixup of point clouds: a visual and a tactile cloud mixed into one cloud of the tactile
density, with a label mixed in the same proportion (beyond the thesis).

Mixup between the domains (Xu et al., AAAI 2020, "Adversarial domain adaptation with domain mixup"; Wu et
al., "Dual mixup regularized learning", 2020) trains the classifier on samples between the source and the
target, so that its decision boundaries run linearly between them. On point clouds the mix is a union of
random subsets of the two clouds (Achituve et al., WACV 2021, Point Cloud Mixup), which is meaningful here
because the datamodule puts both domains in the instance's canonical frame, centred. The mixed cloud has
as many points as its tactile cloud, so it has the target's density and the share of its points that came
from the visual cloud is its label weight.

``XAVTNet(mix_weight > 0)`` uses it; its target half of the label is the mean teacher's (or the network's)
probability of the tactile cloud.
"""

from __future__ import annotations

import torch

from vtlearn.models.components.pointnet_tnet import lengths_to_mask, random_valid_order
from vtlearn.models.components.xavtnet_backbone import check_cloud_batch

__all__ = ["mix_clouds", "soft_cross_entropy"]


def mix_clouds(points_a: torch.Tensor, lengths_a: torch.Tensor, points_b: torch.Tensor,
               lengths_b: torch.Tensor, lam: torch.Tensor,
               generator: torch.Generator | None = None) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """Mix cloud ``a[i]`` into cloud ``b[i]``: the mixed cloud has ``m = lengths_b[i]`` points, of which
    ``k = round(lam[i]·m)`` (at most ``lengths_a[i]``) are a random subset of ``a[i]``'s valid points and
    ``m − k`` a random subset of ``b[i]``'s. Returns the mixed clouds (zero-padded), their lengths (``m``)
    and the share ``k / m`` of each that came from ``a``, the weight of ``a``'s label.

    Shapes:
        points_a (B, Na, 3), lengths_a (B,), points_b (B, Nb, 3), lengths_b (B,), lam (B,) in [0, 1]
        -> (B, Nb, 3), (B,) int64, (B,) float
    """
    check_cloud_batch(points_a, lengths_a, "points_a")
    check_cloud_batch(points_b, lengths_b, "points_b")
    if points_a.shape[0] != points_b.shape[0]:
        raise ValueError(f"points_a, points_b: need the same number of clouds, got {points_a.shape[0]} and "
                         f"{points_b.shape[0]}")
    if lam.shape != lengths_b.shape or not bool(((lam >= 0) & (lam <= 1)).all()):
        raise ValueError(f"lam: need one weight in [0, 1] per cloud, shape {tuple(lengths_b.shape)}, got "
                         f"{lam.tolist() if lam.numel() <= 8 else tuple(lam.shape)}")
    nb = points_b.shape[1]
    k = torch.round(lam.to(points_b.dtype) * lengths_b.to(points_b.dtype)).long()
    k = k.minimum(lengths_a).minimum(lengths_b)
    order_a = random_valid_order(lengths_a, points_a.shape[1], generator)
    order_b = random_valid_order(lengths_b, nb, generator)
    slot = torch.arange(nb, device=points_b.device)[None].expand(points_b.shape[0], nb)
    from_a = slot < k[:, None]  # slots 0..k-1 take a's first k shuffled points, the rest b's
    idx_a = order_a.gather(1, slot.clamp(max=points_a.shape[1] - 1))
    idx_b = order_b.gather(1, (slot - k[:, None]).clamp(min=0))
    pa = torch.gather(points_a, 1, idx_a[..., None].expand(-1, -1, 3))
    pb = torch.gather(points_b, 1, idx_b[..., None].expand(-1, -1, 3))
    out = torch.where(from_a[..., None], pa, pb)
    out = out.masked_fill(~lengths_to_mask(lengths_b, nb)[..., None], 0.0)
    return out, lengths_b.clone(), k.to(points_b.dtype) / lengths_b.to(points_b.dtype)


def soft_cross_entropy(logits: torch.Tensor, target: torch.Tensor) -> torch.Tensor:
    """−Σ_c q_c log softmax(z)_c, averaged over the batch: the cross-entropy against soft labels ``target``.

    Shapes:
        logits (B, k), target (B, k) rows summing to 1 -> ()
    """
    if logits.shape != target.shape or logits.dim() != 2:
        raise ValueError(f"logits, target: need the same (B, k) shape, got {tuple(logits.shape)} and "
                         f"{tuple(target.shape)}")
    return -(target * logits.log_softmax(-1)).sum(-1).mean()
