"""Point-cloud and pose metrics used across the thesis.

Conventions (every function states its own):

* distances are Euclidean (never squared) in the units of the input (metres in vtlearn; multiply by 1000 for
  the millimetres reported in ch.8);
* symmetric set distances add the two directions, as thesis eq. 5.23 / 8.1 do;
* batched set metrics take padded clouds ``(B, N, 3)`` plus optional ``lengths`` ``(B,)``.
"""

from __future__ import annotations

import numpy as np
import torch
from scipy.optimize import linear_sum_assignment
from scipy.spatial import cKDTree

from vtlearn.geometry._compat import as_tensor
from vtlearn.geometry.sampling import knn, lengths_mask
from vtlearn.validation import as_points, as_transform, to_numpy

__all__ = [
    "chamfer_distance",
    "hausdorff_distance",
    "earth_movers_distance",
    "adi",
    "add",
    "rotation_error_deg",
    "translation_error",
    "scale_error",
]


def _batched(x, y, x_lengths, y_lengths):
    """Two clouds or two batches as ``(B, N, 3)`` tensors with lengths, and whether the input was single."""
    was_numpy = not (isinstance(x, torch.Tensor) or isinstance(y, torch.Tensor))  # numpy or lists: numpy out
    x = as_tensor(x, "x", last_dims=(3,))
    y = as_tensor(y, "y", last_dims=(3,)).to(x.dtype)
    single = x.dim() == 2
    if single:
        if y.dim() != 2:
            raise ValueError(
                f"x, y: expected both (N, 3) or both (B, N, 3), got {tuple(x.shape)} and {tuple(y.shape)}"
            )
        x, y = x[None], y[None]
    if x.dim() != 3 or y.dim() != 3 or x.shape[0] != y.shape[0]:
        raise ValueError(f"x, y: expected (B, N, 3) and (B, M, 3), got {tuple(x.shape)} and {tuple(y.shape)}")
    for name, c, ln in (("x", x, x_lengths), ("y", y, y_lengths)):
        if c.shape[1] == 0 or (ln is not None and int(ln.min()) < 1):
            raise ValueError(f"{name}: point cloud is empty")
        if not bool(torch.isfinite(c).all()):
            raise ValueError(f"{name}: contains NaN or inf")
    if x_lengths is None:
        x_lengths = torch.full((x.shape[0],), x.shape[1], dtype=torch.int64, device=x.device)
    if y_lengths is None:
        y_lengths = torch.full((y.shape[0],), y.shape[1], dtype=torch.int64, device=y.device)
    return x, y, x_lengths, y_lengths, single, was_numpy


def _finish(val: torch.Tensor, single: bool, was_numpy: bool, reduction: str):
    if reduction not in ("mean", "sum", "none"):
        raise ValueError(f"reduction: expected 'mean', 'sum' or 'none', got {reduction!r}")
    if single:
        val = val[0]
    elif reduction == "mean":
        val = val.mean()
    elif reduction == "sum":
        val = val.sum()
    if was_numpy:
        val = val.detach().cpu().numpy()
        return float(val) if val.ndim == 0 else val
    return val


def _directed(x, y, x_lengths, y_lengths):
    """Nearest-neighbour distance of every valid x point to y, plus the validity mask. (B, N), (B, N)."""
    d, _ = knn(x, y, 1, x_lengths, y_lengths)
    return d[..., 0], lengths_mask(x_lengths, x.shape[1])


def chamfer_distance(x, y, x_lengths=None, y_lengths=None, reduction: str = "mean"):
    """Chamfer distance, thesis eq. 5.23 / 8.1.

    ``CD(X, Y) = 1/|X| sum_{x in X} min_{y in Y} ||x - y||_2 + 1/|Y| sum_{y in Y} min_{x in X} ||x - y||_2``

    Euclidean, not squared; mean over each set, the two directions summed. Differentiable (torch input).

    Args:
        x, y: clouds ``(N, 3)``/``(M, 3)`` or padded batches ``(B, N, 3)``/``(B, M, 3)``.
        x_lengths, y_lengths: valid points per cloud ``(B,)``; ``None`` means all.
        reduction: for batches, ``"mean"``, ``"sum"`` or ``"none"`` over the batch.

    Shapes:
        single clouds -> scalar; batches -> ``(B,)`` with ``"none"``, else scalar. numpy input -> float.
    """
    x, y, xl, yl, single, was_numpy = _batched(x, y, x_lengths, y_lengths)
    dx, mx = _directed(x, y, xl, yl)
    dy, my = _directed(y, x, yl, xl)
    val = (dx * mx).sum(1) / xl.to(x.dtype) + (dy * my).sum(1) / yl.to(x.dtype)
    return _finish(val, single, was_numpy, reduction)


def hausdorff_distance(x, y, x_lengths=None, y_lengths=None, reduction: str = "mean"):
    """Symmetric Hausdorff distance, thesis eq. 8.6: ``max(max_x min_y ||x-y||, max_y min_x ||y-x||)``.

    Euclidean, not squared. Shapes and arguments as :func:`chamfer_distance`.
    """
    x, y, xl, yl, single, was_numpy = _batched(x, y, x_lengths, y_lengths)
    dx, mx = _directed(x, y, xl, yl)
    dy, my = _directed(y, x, yl, xl)
    val = torch.maximum(dx.masked_fill(~mx, -1).amax(1), dy.masked_fill(~my, -1).amax(1))
    return _finish(val, single, was_numpy, reduction)


def earth_movers_distance(x, y) -> float:
    """Earth Mover's distance, thesis eq. 8.7: ``min_phi 1/|X| sum_x ||x - phi(x)||_2``.

    * ``|X| == |Y|``: exact, the optimal bijection by the Hungarian algorithm (``linear_sum_assignment``).
    * ``|X| < |Y|``: exact minimum over injections ``X -> Y`` (rectangular assignment).
    * ``|X| > |Y|`` (approximation): ``Y`` is replicated ``ceil(|X|/|Y|)`` times, so each ``y`` may
      receive at most that many ``x``; the optimal such assignment is returned. It equals the bijective
      EMD when ``|X|`` is a multiple of ``|Y|`` and upper-bounds the balanced transport cost otherwise.

    Cost is O(n^3): about a second for 2048 points. Not differentiable (use :func:`chamfer_distance`).

    Shapes:
        x: ``(N, 3)``, y: ``(M, 3)`` -> float (mean Euclidean distance, input units).
    """
    X = as_points(x, "x")
    Y = as_points(y, "y")
    if len(X) > len(Y):
        Y = np.tile(Y, (int(np.ceil(len(X) / len(Y))), 1))
    cost = np.linalg.norm(X[:, None, :] - Y[None, :, :], axis=-1)
    rows, cols = linear_sum_assignment(cost)
    return float(cost[rows, cols].mean())


def adi(model_points, T_est, T_gt) -> float:
    """ADI (average closest-point distance, symmetric-object aware), thesis eq. 5.24.

    ``ADI = 1/|O| sum_{p1 in O} min_{p2 in O} ||(R_gt p1 + t_gt) - (R_est p2 + t_est)||_2``

    Args:
        model_points: the object model ``O`` in its own frame, ``(N, 3)``.
        T_est, T_gt: ``T_scene_model`` estimates, ``(4, 4)`` each.

    Returns:
        float, in the units of ``model_points``.
    """
    O = as_points(model_points, "model_points")
    Te = as_transform(T_est, "T_est")
    Tg = as_transform(T_gt, "T_gt")
    gt = O @ Tg[:3, :3].T + Tg[:3, 3]
    est = O @ Te[:3, :3].T + Te[:3, 3]
    d, _ = cKDTree(est).query(gt, k=1)
    return float(np.mean(d))


def add(model_points, T_est, T_gt) -> float:
    """ADD (average distance of corresponding model points): ``1/|O| sum_p ||T_gt p - T_est p||_2``.

    Shapes:
        model_points: ``(N, 3)``; transforms ``(4, 4)`` -> float.
    """
    O = as_points(model_points, "model_points")
    Te = as_transform(T_est, "T_est")
    Tg = as_transform(T_gt, "T_gt")
    diff = O @ (Tg[:3, :3] - Te[:3, :3]).T + (Tg[:3, 3] - Te[:3, 3])
    return float(np.linalg.norm(diff, axis=1).mean())


def rotation_error_deg(R_est, R_gt) -> float:
    """Geodesic rotation error in degrees: the angle of ``R_est^T R_gt``, in ``[0, 180]``.

    Shapes:
        R_est, R_gt: ``(3, 3)`` -> float.
    """
    from vtlearn.geometry.lie import so3_log

    Re, Rg = to_numpy(R_est), to_numpy(R_gt)
    if Re.shape != (3, 3) or Rg.shape != (3, 3):
        raise ValueError(f"R_est, R_gt: expected (3, 3) each, got {Re.shape} and {Rg.shape}")
    if not (np.isfinite(Re).all() and np.isfinite(Rg).all()):
        raise ValueError("R_est, R_gt: contain NaN or inf")
    return float(np.degrees(np.linalg.norm(so3_log(Re.T @ Rg))))


def translation_error(t_est, t_gt) -> float:
    """Euclidean translation error ``||t_est - t_gt||_2`` in input units. Shapes: ``(3,)`` each -> float."""
    te, tg = to_numpy(t_est).reshape(-1), to_numpy(t_gt).reshape(-1)
    if te.shape != (3,) or tg.shape != (3,):
        raise ValueError(f"t_est, t_gt: expected 3-vectors, got {te.shape} and {tg.shape}")
    if not (np.isfinite(te).all() and np.isfinite(tg).all()):
        raise ValueError("t_est, t_gt: contain NaN or inf")
    return float(np.linalg.norm(te - tg))


def scale_error(s_est, s_gt) -> float:
    """Scale error, thesis eq. 5.25: ``sqrt(sum_axis (s_gt - s_est)^2)`` over the per-axis scales.

    Args:
        s_est, s_gt: finite, strictly positive scales.

    Shapes:
        s_est, s_gt: ``(3,)`` (a scalar is broadcast to all three axes) -> float.
    """
    se = np.broadcast_to(to_numpy(s_est).reshape(-1), (3,)) if np.size(s_est) == 1 else to_numpy(s_est)
    sg = np.broadcast_to(to_numpy(s_gt).reshape(-1), (3,)) if np.size(s_gt) == 1 else to_numpy(s_gt)
    if se.shape != (3,) or sg.shape != (3,):
        raise ValueError(f"s_est, s_gt: expected per-axis scales (3,), got {se.shape} and {sg.shape}")
    if not (np.isfinite(se).all() and np.isfinite(sg).all()):
        raise ValueError("s_est, s_gt: contain NaN or inf")
    for name, s in (("s_est", se), ("s_gt", sg)):
        if not (s > 0).all():
            raise ValueError(f"{name}: scales must be > 0, got {s.tolist()}")
    return float(np.linalg.norm(sg - se))
