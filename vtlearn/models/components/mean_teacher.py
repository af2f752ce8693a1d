"""Mean teacher (Tarvainen and Valpola, NeurIPS 2017): a network whose weights are an exponential moving
average of a student's, the ramp-up of the consistency weight, and the input noise the two networks see.

French, Mackiewicz and Fisher (ICLR 2018) used it for unsupervised domain adaptation; xAVTNet uses it on
the tactile stream (``XAVTNet(consistency_weight > 0)``, beyond the thesis). The noise is the one a
tactile cloud has anyway: which touches it got (point dropout) and where on the pad a contact landed
(jitter).
"""

from __future__ import annotations

import math

import torch
from torch import nn

from vtlearn.models.components.pointnet_tnet import lengths_to_mask, random_valid_order
from vtlearn.validation import as_real

__all__ = ["ema_update", "sigmoid_rampup", "perturb_padded"]


@torch.no_grad()
def ema_update(teacher: nn.Module, student: nn.Module, decay: float) -> None:
    """θ' ← d·θ' + (1 − d)·θ for every parameter and floating-point buffer (batch-norm running
    statistics); other buffers (batch counts) are copied. ``decay = 0`` copies the student."""
    decay = as_real(decay, "decay", low=0.0, high=1.0)
    pairs = []
    for t_items, s_items in ((list(teacher.named_parameters()), list(student.named_parameters())),
                             (list(teacher.named_buffers()), list(student.named_buffers()))):
        if len(t_items) != len(s_items):
            raise ValueError(f"teacher and student differ: {len(t_items)} against {len(s_items)} tensors")
        pairs += zip(t_items, s_items, strict=True)
    for (name_t, t), (name_s, s) in pairs:
        if name_t != name_s or t.shape != s.shape:
            raise ValueError(f"teacher and student differ: {name_t} {tuple(t.shape)} against "
                             f"{name_s} {tuple(s.shape)}")
        if t.is_floating_point():
            t.mul_(decay).add_(s.detach(), alpha=1 - decay)
        else:
            t.copy_(s)


def sigmoid_rampup(progress: float, length: float) -> float:
    """Tarvainen and Valpola's ramp-up ``exp(−5·(1 − t)²)``, ``t = min(1, progress / length)``; 1 when
    ``length`` is 0 (no ramp)."""
    length = as_real(length, "length", low=0.0)
    if length == 0:
        return 1.0
    t = min(1.0, max(0.0, progress) / length)
    return float(math.exp(-5.0 * (1.0 - t) ** 2))


def perturb_padded(points: torch.Tensor, lengths: torch.Tensor, keep_min: float, jitter: float,
                   generator: torch.Generator | None = None,
                   scale: float = 1.0) -> tuple[torch.Tensor, torch.Tensor]:
    """A random perturbation of each cloud: it keeps a share drawn uniformly from ``[keep_min, 1]`` of its
    valid points (at least one, a random subset, packed to the front) and each kept point moves by
    isotropic Gaussian noise of standard deviation ``jitter`` (in the clouds' units). With ``scale > 1``
    each cloud is then stretched about the origin by a factor per axis drawn uniformly from
    ``[1/scale, scale]`` (DGCNN's anisotropic scaling, ``[2/3, 3/2]`` at ``scale = 1.5``). The origin is
    the clouds' own frame's: their centroid when the datamodule centres them (CrossModalDataModule's
    ``normalize="center"``, the bench configs'). Padding stays zero.

    Shapes:
        points (B, N, 3) zero-padded, lengths (B,) int64 -> (B, N, 3), (B,)
    """
    if points.dim() != 3 or points.shape[-1] != 3:
        raise ValueError(f"points must have shape (B, N, 3), got {tuple(points.shape)}")
    if lengths.shape != points.shape[:1]:
        raise ValueError(f"lengths must have shape ({points.shape[0]},), got {tuple(lengths.shape)}")
    keep_min = as_real(keep_min, "keep_min", low=0.0, high=1.0, open_low=True)
    jitter = as_real(jitter, "jitter", low=0.0)
    scale = as_real(scale, "scale", low=1.0)
    b, n, _ = points.shape
    dev = points.device
    share = keep_min + (1 - keep_min) * torch.rand(b, generator=generator, device=dev)
    new_lengths = torch.ceil(share * lengths.to(share.dtype)).long().clamp(min=1).minimum(lengths)
    order = random_valid_order(lengths, n, generator)
    out = torch.gather(points, 1, order[..., None].expand(-1, -1, 3))
    if jitter > 0:
        out = out + jitter * torch.randn(out.shape, generator=generator, device=dev, dtype=out.dtype)
    if scale > 1:  # no draw at scale 1, so the unscaled copies keep their random streams
        u = torch.rand(b, 1, 3, generator=generator, device=dev, dtype=out.dtype)
        out = out * (1 / scale + (scale - 1 / scale) * u)
    return out.masked_fill(~lengths_to_mask(new_lengths, n)[..., None], 0.0), new_lengths
