"""SimCLR's NT-Xent contrastive loss (beyond the thesis).

For a batch of ``n`` clouds seen as two perturbed copies, with projections ``z_i`` and ``z'_i`` scaled to
unit length, every one of the ``2n`` projections must pick its own partner out of the other ``2n − 1``:

    ℓ(i, j) = −log( exp(s_ij / τ) / Σ_{m ≠ i} exp(s_im / τ) ),    s_ij = z_iᵀ z_j
    L = (1 / 2n)·Σ_i [ℓ(i, i') + ℓ(i', i)]

the normalised temperature-scaled cross-entropy of Chen, Kornblith, Norouzi and Hinton (ICML 2020, eq. 1),
with the other ``2(n − 1)`` copies of the batch as negatives. It needs no label, so on the tactile stream it
makes the encoder tell the sparse clouds apart by their own shape, the supervision that the visual source
gives only to dense clouds. Bounds: ``L ≥ 0``, and ``L = log(2n − 1)`` when every projection is the same.
"""

from __future__ import annotations

import torch
import torch.nn.functional as F

from vtlearn.validation import as_real

__all__ = ["nt_xent"]


def nt_xent(z1: torch.Tensor, z2: torch.Tensor, temperature: float = 0.5) -> torch.Tensor:
    """NT-Xent of two views' projections, row ``i`` of ``z1`` and of ``z2`` the same cloud.

    Shapes:
        z1 (n, d), z2 (n, d), n ≥ 2 -> ()
    """
    if z1.dim() != 2 or z1.shape != z2.shape:
        raise ValueError(f"z1, z2: need two (n, d) projections of one shape, got {tuple(z1.shape)} and "
                         f"{tuple(z2.shape)}")
    if z1.shape[0] < 2:
        raise ValueError(f"z1: need n >= 2 clouds (the others are the negatives), got {z1.shape[0]}")
    temperature = as_real(temperature, "temperature", low=0.0, open_low=True)
    n = z1.shape[0]
    z = F.normalize(torch.cat([z1, z2]), dim=1)
    sim = z @ z.T / temperature
    sim = sim.masked_fill(torch.eye(2 * n, dtype=torch.bool, device=z.device), float("-inf"))
    partner = torch.cat([torch.arange(n, 2 * n), torch.arange(n)]).to(z.device)
    return F.cross_entropy(sim, partner)
