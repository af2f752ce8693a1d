"""numpy/torch interoperability for the geometry kernels.

The kernels are written once in torch. ``numpy_compatible`` lets a user pass numpy arrays, or nested lists of
numbers, instead: inputs are converted to float64 tensors and outputs back to numpy, so
``quat_to_matrix(np_array)`` returns an ndarray. The rule: torch in, torch out; otherwise numpy out.
"""

from __future__ import annotations

import functools
from collections.abc import Callable
from typing import Any

import numpy as np
import torch


def _to_numpy_tree(x: Any) -> Any:
    if isinstance(x, torch.Tensor):
        return x.detach().cpu().numpy()
    if isinstance(x, tuple):
        return tuple(_to_numpy_tree(v) for v in x)
    if isinstance(x, list):
        return [_to_numpy_tree(v) for v in x]
    return x


def numpy_compatible(fn: Callable) -> Callable:
    """Decorator: numpy inputs, and lists or tuples of numbers, become float64 tensors; tensor outputs become
    numpy unless some input was a torch tensor."""

    @functools.wraps(fn)
    def wrapper(*args, **kwargs):
        was_numpy = saw_torch = False

        def conv(v):
            nonlocal was_numpy, saw_torch
            if isinstance(v, torch.Tensor):
                saw_torch = True
            elif isinstance(v, (list, tuple)) and v and not any(isinstance(e, torch.Tensor) for e in v):
                try:
                    a = np.asarray(v)
                except (TypeError, ValueError):  # ragged: left to the kernel's own check
                    return v
                v = a.astype(np.float64) if a.dtype.kind in "iubf" else v  # [1, 0, 0] is a float64 vector
            if isinstance(v, np.ndarray):
                was_numpy = True
                if v.dtype.kind in "iub":
                    return torch.from_numpy(np.ascontiguousarray(v))
                return torch.from_numpy(np.ascontiguousarray(v, dtype=np.float64))
            return v

        args = tuple(conv(a) for a in args)
        kwargs = {k: conv(v) for k, v in kwargs.items()}
        out = fn(*args, **kwargs)
        return _to_numpy_tree(out) if was_numpy and not saw_torch else out

    return wrapper


def as_tensor(
    x: Any, name: str, *, last_dims: tuple[int, ...], dtype: torch.dtype | None = None
) -> torch.Tensor:
    """``x`` as a floating tensor with checked trailing dimensions; ``ValueError`` naming ``name`` if not."""
    if not isinstance(x, torch.Tensor):
        try:
            x = torch.as_tensor(np.asarray(x, dtype=np.float64))
        except (TypeError, ValueError) as exc:
            raise ValueError(f"{name}: cannot be converted to a tensor ({exc})") from None
    if not torch.is_floating_point(x):
        x = x.to(torch.get_default_dtype() if dtype is None else dtype)
    elif dtype is not None:
        x = x.to(dtype)
    n = len(last_dims)
    if x.dim() < n or tuple(x.shape[-n:]) != tuple(last_dims):
        want = "(..., " + ", ".join(str(d) for d in last_dims) + ")"
        raise ValueError(f"{name}: expected shape {want}, got {tuple(x.shape)}")
    return x
