"""Input validation shared by every public entry point.

Every public function in vtlearn validates what a user passes it and raises a ``ValueError`` that names the
argument and says what was wrong, instead of a traceback from deep inside numpy, Open3D or torch.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

__all__ = ["ConfigMismatchError", "as_bool", "as_int", "as_pair", "as_points", "as_real",
           "as_stored_transform", "as_surface_mesh", "as_transform", "as_vector", "check_class_scores",
           "check_not_collinear", "load_named", "to_numpy"]


class ConfigMismatchError(ValueError):
    """The model and the datamodule of one run disagree (class count, class names, input normalisation).

    Raised from a LightningModule's ``setup``, where the two first meet; ``train.py`` reports it as one line
    that names the argument, like an argument it could not instantiate.
    """


def as_int(value: Any, name: str, minimum: int = 1) -> int:
    """``value`` as a Python int; a ``ValueError`` naming ``name`` unless it is an integer (Python or numpy;
    not a bool, a float or a string) ``>= minimum``."""
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < minimum:
        raise ValueError(f"{name}: need an integer >= {minimum}, got {value!r}")
    return int(value)


def as_bool(value: Any, name: str) -> bool:
    """``value`` if it is ``True`` or ``False``; a ``ValueError`` naming ``name`` otherwise (also for 0 / 1,
    numpy bools and strings, which a config could mean as a number or a word)."""
    if not isinstance(value, bool):
        raise ValueError(f"{name}: expected True or False, got {value!r}")
    return value


def as_real(value: Any, name: str, *, low: float = -math.inf, high: float = math.inf,
            open_low: bool = False, open_high: bool = False, unit: str | None = None) -> float:
    """``value`` as a finite float in ``[low, high]`` (the end excluded with ``open_low`` / ``open_high``); a
    ``ValueError`` naming ``name`` otherwise, and for a bool or a string.

    ``unit`` (e.g. ``"m"``, ``"rad"``, ``"deg"``, ``"s"``, ``"N"``), when given, is the unit ``value`` is read
    in; the message states it after the bound: ``"voxel: need a finite number > 0 (m), got 'a'"``. It changes
    nothing else (no conversion)."""
    v = math.nan
    if not isinstance(value, (bool, str, bytes)):
        try:
            v = float(value)
        except (TypeError, ValueError):
            pass
    above = v > low if open_low else v >= low
    below = v < high if open_high else v <= high
    if not (math.isfinite(v) and above and below):
        lo = "" if low == -math.inf else f"{'(' if open_low else '['}{low:g}, "
        hi = "" if high == math.inf else f"{high:g}{')' if open_high else ']'}"
        bound = (f" in {lo}{hi}" if lo and hi else f" {'>' if open_low else '>='} {low:g}" if lo
                 else f" {'<' if open_high else '<='} {high:g}" if hi else "")
        in_unit = f" ({unit})" if unit else ""
        raise ValueError(f"{name}: need a finite number{bound}{in_unit}, got {value!r}")
    return v


def as_surface_mesh(mesh: Any, name: str):
    """``mesh`` if it is a ``trimesh.Trimesh`` with faces, finite vertices and a positive total area; a
    ``ValueError`` naming ``name`` otherwise (open and non-manifold surfaces are allowed)."""
    import trimesh

    if not isinstance(mesh, trimesh.Trimesh):
        raise ValueError(f"{name}: need a trimesh.Trimesh, got {type(mesh).__name__}")
    if len(mesh.faces) == 0:
        raise ValueError(f"{name}: has no faces")
    if not np.isfinite(np.asarray(mesh.vertices, dtype=np.float64)).all():
        raise ValueError(f"{name}: vertices contain NaN or inf")
    if not (np.isfinite(mesh.area) and mesh.area > 0):
        raise ValueError(f"{name}: degenerate (total face area {mesh.area}); need a surface with area > 0")
    return mesh


def as_vector(x: Any, name: str, n: int, what: str | None = None) -> np.ndarray:
    """``x`` as a finite ``(n,)`` float64 array; a ``ValueError`` ``"{name}: need {what}, got {x!r}"``
    otherwise (``what`` defaults to ``"n finite numbers"``).

    Shapes:
        x: (n,) -> (n,)
    """
    try:
        a = np.asarray(x, dtype=np.float64)
    except (TypeError, ValueError):
        a = np.zeros(0)
    if a.shape != (n,) or not np.isfinite(a).all():
        raise ValueError(f"{name}: need {what or f'{n} finite numbers'}, got {x!r}")
    return a


def as_pair(x: Any, name: str, what: str = "a (low, high) pair of numbers") -> tuple[float, float]:
    """Two numbers, e.g. a ``(low, high)`` range or a ``(horizontal, vertical)`` field of view; a
    ``ValueError`` naming ``name`` for anything else (one number, three, a string).

    Shapes:
        x: 2 numbers -> (float, float)
    """
    try:
        a, b = (float(v) for v in x)
    except (TypeError, ValueError):
        raise ValueError(f"{name}: expected {what}, got {x!r}") from None
    return a, b


def load_named(load, path: Any, name: str):
    """``load(path)``, with a ``FileNotFoundError`` or ``ValueError`` re-raised under ``name``, the caller's
    argument or command-line flag (``actor_ckpt``, ``--actor``), in place of the loader's own ``ckpt:``."""
    try:
        return load(path)
    except FileNotFoundError as exc:
        raise FileNotFoundError(f"{name}: {str(exc).removeprefix('ckpt: ')}") from exc
    except ValueError as exc:
        raise ValueError(f"{name}: {str(exc).removeprefix('ckpt: ')}") from exc


def to_numpy(x: Any, dtype=np.float64) -> np.ndarray:
    """Convert a list, numpy array or torch tensor to a numpy array of ``dtype`` (no copy if possible)."""
    if hasattr(x, "detach") and hasattr(x, "cpu"):  # torch.Tensor without importing torch here
        x = x.detach().cpu().numpy()
    return np.asarray(x, dtype=dtype)


def as_points(
    x: Any,
    name: str,
    *,
    min_points: int = 1,
    dim: int = 3,
    dtype=np.float64,
) -> np.ndarray:
    """Validate a point cloud and return it as a numpy array.

    Args:
        x: points, array-like of shape ``(N, dim)``.
        name: the argument name used in error messages.
        min_points: the smallest acceptable ``N``.
        dim: the number of coordinates per point.
        dtype: output dtype.

    Shapes:
        x: ``(N, dim)`` -> ``(N, dim)``.

    Raises:
        ValueError: wrong shape, fewer than ``min_points`` points, or NaN/inf values.
    """
    if x is None:
        raise ValueError(f"{name}: expected an ({'N'}, {dim}) point array, got None")
    try:
        arr = to_numpy(x, dtype=dtype)
    except (TypeError, ValueError) as exc:
        raise ValueError(f"{name}: cannot be converted to a float array ({exc})") from None
    if arr.ndim != 2 or arr.shape[1] != dim:
        raise ValueError(f"{name}: expected shape (N, {dim}), got {tuple(arr.shape)}")
    if arr.shape[0] < min_points:
        n = arr.shape[0]
        what = "is empty" if n == 0 else f"has only {n} point{'s' if n != 1 else ''}"
        raise ValueError(f"{name}: point cloud {what}; at least {min_points} required")
    if not np.isfinite(arr).all():
        bad = int((~np.isfinite(arr)).any(axis=1).sum())
        raise ValueError(f"{name}: contains NaN or inf in {bad} of {arr.shape[0]} points")
    return arr


def as_transform(T: Any, name: str, *, atol: float = 1e-5) -> np.ndarray:
    """Validate a rigid transform ``T_a_b`` and return it as a ``(4, 4)`` float64 array.

    Raises:
        ValueError: wrong shape, NaN/inf, a non-orthonormal rotation block, or a last row other than 0 0 0 1.
    """
    try:
        arr = to_numpy(T)
    except (TypeError, ValueError) as exc:
        raise ValueError(f"{name}: cannot be converted to a float array ({exc})") from None
    if arr.shape != (4, 4):
        raise ValueError(f"{name}: expected a (4, 4) homogeneous transform, got shape {tuple(arr.shape)}")
    if not np.isfinite(arr).all():
        raise ValueError(f"{name}: contains NaN or inf")
    if not np.allclose(arr[3], [0.0, 0.0, 0.0, 1.0], atol=atol):
        raise ValueError(f"{name}: last row must be (0, 0, 0, 1), got {arr[3].tolist()}")
    R = arr[:3, :3]
    if not np.allclose(R.T @ R, np.eye(3), atol=atol) or np.linalg.det(R) < 0:
        raise ValueError(f"{name}: the 3x3 block is not a proper rotation (R^T R != I or det(R) < 0)")
    return arr


def as_stored_transform(T: Any, name: str, *, atol: float = 1e-3) -> np.ndarray:
    """A rigid transform read from a file (robot logs, hand-written poses): :func:`as_transform` with the
    looser tolerance ``atol`` that numbers printed with 4 decimals need, and the rotation block replaced by
    the nearest rotation (SVD), so that downstream algebra gets an exact one.

    Shapes:
        T: (4, 4) -> (4, 4)
    """
    arr = as_transform(T, name, atol=atol).copy()
    U, _, Vt = np.linalg.svd(arr[:3, :3])
    arr[:3, :3] = U @ Vt  # det > 0: as_transform refused a reflection
    arr[3] = (0.0, 0.0, 0.0, 1.0)
    return arr


def check_not_collinear(points: np.ndarray, name: str, *, tol: float = 1e-9) -> None:
    """Raise ``ValueError`` if ``points`` (N, 3) lie on a single point or a line (rank < 2 after centring)."""
    centred = points - points.mean(axis=0)
    s = np.linalg.svd(centred, compute_uv=False)
    scale = max(float(s[0]), 1e-300)
    if s[0] <= tol or s[1] / scale <= tol:
        raise ValueError(f"{name}: points are degenerate (all coincident or collinear); need a 2-D spread")


def check_class_scores(z: Any, name: str) -> None:
    """A ValueError naming ``name`` unless ``z`` is a finite torch tensor of per-class scores (logits or
    probabilities) of shape (n >= 1, k >= 2).

    Shapes:
        z (n, k)
    """
    import torch

    if not isinstance(z, torch.Tensor):
        raise ValueError(f"{name} must be a torch.Tensor, got {type(z).__name__}")
    if z.dim() != 2 or z.shape[0] < 1 or z.shape[1] < 2:
        raise ValueError(f"{name} must have shape (n >= 1, k >= 2), got {tuple(z.shape)}")
    if not torch.isfinite(z).all():
        raise ValueError(f"{name} contains NaN or inf")
