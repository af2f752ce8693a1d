"""Sub-sample correspondences on a model cloud's local tangent planes (used by S-TIQF and sequential TIQF).

Not a thesis equation: an implementation choice of the correspondence step of thesis 4.2.3 / 5.2.4 (see
:class:`TangentPlanes`). Kept apart so that :mod:`vtlearn.classical.tiqf` and :mod:`vtlearn.classical.stiqf`
can both use it.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree

__all__ = ["TangentPlanes"]


class TangentPlanes:
    """Local tangent planes of a model cloud, for sub-sample correspondences (S-TIQF refinement option).

    A point-to-point correspondence with a sparse model cloud is off by up to half the sample spacing along
    the surface. With ``tangent=True`` the model point of a pair is moved to the foot of the scene point on
    the model point's tangent plane (normal from PCA of its ``k`` neighbours), the move capped at the
    median sample spacing. The pair is still a point pair, so eq. 4.13 applies unchanged.

    Shapes:
        model: ``(M, 3)``.
    """

    def __init__(self, model: np.ndarray, tree: cKDTree, k: int = 10):
        d, nbr = tree.query(model, k=min(k, len(model)))
        nb = model[nbr] - model[nbr].mean(1, keepdims=True)  # MxKx3
        _, vecs = np.linalg.eigh(np.einsum("mki,mkj->mij", nb, nb))
        self.normals = vecs[:, :, 0]
        self.model = model
        self.cap = float(np.median(d[:, 1])) if d.shape[1] > 1 else 0.0

    def project(self, q: np.ndarray, idx: np.ndarray) -> np.ndarray:
        """Feet of ``q`` ``(K, 3)`` on the tangent planes of model points ``idx`` ``(K,)`` -> ``(K, 3)``."""
        o, n = self.model[idx], self.normals[idx]
        v = q - o
        tang = v - np.einsum("kd,kd->k", v, n)[:, None] * n
        norm = np.linalg.norm(tang, axis=1, keepdims=True)
        return o + tang * np.minimum(1.0, self.cap / np.maximum(norm, 1e-12))

    def distance(self, q: np.ndarray, tree: cKDTree) -> np.ndarray:
        """Distance of ``q`` ``(K, 3)`` to the tangent-plane patch of its nearest model point."""
        _, idx = tree.query(q, k=1)
        return np.linalg.norm(q - self.project(q, idx), axis=1)
