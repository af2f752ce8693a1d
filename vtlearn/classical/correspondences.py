"""Sub-sample correspondences on a model cloud's local tangent planes (used by S-TIQF and sequential TIQF).

Not a thesis equation: an implementation choice of the correspondence step of thesis 4.2.3 / 5.2.4 (see
:class:`TangentPlanes`). Kept apart so that :mod:`vtlearn.classical.tiqf` and :mod:`vtlearn.classical.stiqf`
can both use it.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree

from vtlearn.validation import as_int, as_real

__all__ = ["TangentPlanes"]


class TangentPlanes:
    """Local tangent planes of a model cloud, for sub-sample correspondences (S-TIQF refinement option).

    A point-to-point correspondence with a sparse model cloud is off by up to half the sample spacing along
    the surface. With ``tangent=True`` the model point of a pair is moved to the foot of the scene point on
    the model point's tangent plane (normal from PCA of its ``k`` neighbours), the move capped at
    ``cap_factor`` times the median sample spacing. The pair is still a point pair, so eq. 4.13 applies
    unchanged. A cap of one spacing leaves holes: with uniform random sampling the chance that no sample lies
    within a radius ``r`` of a surface point is ``exp(-rho pi r^2)`` (``rho`` samples per area). With
    ``h`` the median sample spacing (Poisson sampling: ``rho ~ 1 / (4 h^2)``) that is ``exp(-pi / 4) ~ 46%``
    for ``r = h`` and ``exp(-pi) ~ 4%`` for ``r = 2 h``; with a one-spacing cap, surface points in the holes
    look far from the model even at the true pose.

    Args:
        model: the model cloud.
        tree: KD-tree of ``model``.
        k: neighbours of the PCA normal.
        cap_factor: the tangent patch radius in median sample spacings.
        n_patches: a query point is matched to the closest of the patches of its ``n_patches`` nearest
            samples, not only the nearest sample's. On thin-walled objects (a mug wall is about one sample
            spacing thick) the nearest sample is often on the opposite side of the wall, whose patch is a
            wall thickness away.

    Shapes:
        model: ``(M, 3)``.
    """

    def __init__(
        self, model: np.ndarray, tree: cKDTree, k: int = 10, cap_factor: float = 1.0, n_patches: int = 1
    ):
        cap_factor = as_real(cap_factor, "cap_factor", low=0.0)
        n_patches = as_int(n_patches, "n_patches")
        self.n_patches = min(n_patches, len(model))
        d, nbr = tree.query(model, k=min(k, len(model)))
        nb = model[nbr] - model[nbr].mean(1, keepdims=True)  # MxKx3
        _, vecs = np.linalg.eigh(np.einsum("mki,mkj->mij", nb, nb))
        self.normals = vecs[:, :, 0]
        self.model = model
        self.cap = cap_factor * float(np.median(d[:, 1])) if d.shape[1] > 1 else 0.0

    def project(self, q: np.ndarray, idx: np.ndarray) -> np.ndarray:
        """Feet of ``q`` ``(K, 3)`` on the tangent planes of model points ``idx`` ``(K,)`` -> ``(K, 3)``."""
        o, n = self.model[idx], self.normals[idx]
        v = q - o
        tang = v - np.einsum("kd,kd->k", v, n)[:, None] * n
        norm = np.linalg.norm(tang, axis=1, keepdims=True)
        return o + tang * np.minimum(1.0, self.cap / np.maximum(norm, 1e-12))

    def closest(self, q: np.ndarray, tree: cKDTree) -> tuple[np.ndarray, np.ndarray]:
        """The closest patch among those of the ``n_patches`` nearest samples of each ``q`` ``(K, 3)``.

        Returns:
            ``(idx (K,), foot (K, 3))``: the patch's sample index and the foot of ``q`` on it.
        """
        q = np.asarray(q, dtype=np.float64)
        _, nbr = tree.query(q, k=self.n_patches)
        nbr = nbr.reshape(len(q), -1)  # KxP
        v = q[:, None] - self.model[nbr]  # KxPx3
        h = np.einsum("kpd,kpd->kp", v, self.normals[nbr])  # offset along the normal
        tang = np.sqrt(np.maximum((v * v).sum(-1) - h * h, 0.0))  # tangential distance to the sample
        best = np.argmin(h * h + np.maximum(tang - self.cap, 0.0) ** 2, axis=1)
        idx = nbr[np.arange(len(q)), best]
        return idx, self.project(q, idx)

    def distance(self, q: np.ndarray, tree: cKDTree) -> np.ndarray:
        """Distance of ``q`` ``(K, 3)`` to the closest tangent-plane patch (see :meth:`closest`)."""
        return np.linalg.norm(np.asarray(q, dtype=np.float64) - self.closest(q, tree)[1], axis=1)
