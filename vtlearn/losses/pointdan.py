"""PointDAN's local alignment: MMD of the node features (Qin et al., NeurIPS 2019), beyond the thesis.

PointDAN aligns a cloud's local regions between the domains as well as its global feature. The
self-adaptive nodes (:class:`~vtlearn.models.components.sa_nodes.SelfAdaptiveNodes`) give each cloud
``M`` node features; each domain's are flattened, passed through that domain's node attention
(:class:`~vtlearn.models.components.sa_nodes.NodeAttention`), and the two samples are compared by a biased
multi-kernel MMD (eq. 7.5-7.6's estimator, :func:`~vtlearn.losses.mmd.mk_mmd`) with PointDAN's five
fixed Gaussian kernels ``exp(−‖x − y‖² / (2σ²))``, σ ∈ {0.01, 0.1, 1, 10, 100}, so
``h = 2σ² ∈ {2·10⁻⁴, 2·10⁻², 2, 200, 2·10⁴}``.

PointDAN sums the five kernels where eq. 7.6 averages them, so its weight of 1 on the node MMD is 5 here.
It minimises the node MMD in a second optimiser step after each MCD step; here it is a term of the one
loss (as MCD's own steps are, :mod:`vtlearn.losses.mcd`).
"""

from __future__ import annotations

import torch
from torch import nn

from vtlearn.losses.mmd import mk_mmd

__all__ = ["POINTDAN_BANDWIDTHS", "node_alignment_loss"]

POINTDAN_BANDWIDTHS = tuple(2.0 * s * s for s in (0.01, 0.1, 1.0, 10.0, 100.0))


def node_alignment_loss(nodes_source: torch.Tensor, nodes_target: torch.Tensor, attention_source: nn.Module,
                        attention_target: nn.Module) -> torch.Tensor:
    """PointDAN's local alignment: ``MK-MMD²(A_s(nodes_s), A_t(nodes_t))`` with PointDAN's bandwidths and
    each domain's node attention ``A``.

    Shapes:
        nodes_source (B_s, M, C), nodes_target (B_t, M, C) -> ()
    """
    for name, nodes in (("nodes_source", nodes_source), ("nodes_target", nodes_target)):
        if nodes.dim() != 3 or nodes.shape[0] < 2:
            raise ValueError(f"{name}: expected (B, M, C) node features of at least 2 clouds (batch "
                             f"normalisation), got shape {tuple(nodes.shape)}")
    if nodes_source.shape[1:] != nodes_target.shape[1:]:
        raise ValueError(f"nodes_target: nodes of shape {tuple(nodes_target.shape[1:])} differ from "
                         f"nodes_source's {tuple(nodes_source.shape[1:])}")
    return mk_mmd(attention_source(nodes_source), attention_target(nodes_target),
                  bandwidths=POINTDAN_BANDWIDTHS)
