"""A first-in-first-out memory of detached features, for alignment statistics over more clouds than a batch.

Beyond the thesis. VTLoss (eq. 7.8) estimates MK-MMD (eq. 7.5-7.6) and CORAL (eq. 7.7) from one source and
one target batch. docs/xavtnet_results.md measured that larger batches raise VTLoss's tactile accuracy by
about 1.7 points per doubling at about equal steps, but the work doubles with them. A queue of the features
of the last ``capacity`` clouds of each domain, appended to the current batch without gradient, gives the
loss the statistics of ``batch + capacity`` clouds at the cost of one batch, as MoCo's queue (He et al.,
CVPR 2020) holds more negative keys than a batch. Measured there: at batch 32 a 224-cloud queue does not
give batch 256's gain, so that gain is not the alignment statistics'.

Only the current batch carries gradient. In a batch of ``n`` clouds each row's share of the gradient of
a mean statistic is about ``1/n``, so the ``b`` current rows of ``n = b + capacity`` carry ``b/n`` of what
a real batch of ``n`` would. :func:`scale_grad` multiplies their gradient by ``n/b`` (the value is
unchanged), which makes the update an estimate of the large batch's, up to the queue's staleness (its
rows were computed by the weights of up to ``capacity/b`` steps ago).
"""

from __future__ import annotations

from collections.abc import Mapping

import torch

from vtlearn.validation import as_int, as_real

__all__ = ["FeatureQueue", "scale_grad"]


def scale_grad(x: torch.Tensor, scale: float) -> torch.Tensor:
    """``x`` in value, ``scale · ∂L/∂x`` in the backward pass.

    Shapes:
        x (...) -> (...)
    """
    if not isinstance(x, torch.Tensor):
        raise ValueError(f"x must be a torch.Tensor, got {type(x).__name__}")
    scale = as_real(scale, "scale", low=0.0, open_low=True)
    if scale == 1.0:
        return x
    return x * scale - (x * (scale - 1.0)).detach()


class FeatureQueue:
    """Detached features of the last ``capacity`` rows pushed, per named layer, oldest dropped first.

    Not saved in checkpoints: after a resume it refills within ``capacity / batch`` steps.

    Args:
        capacity: rows kept per layer (≥ 1).

    Shapes:
        push(features): features[name] (b, d_name)
        extend(features) -> {name: (b + m, d_name)}: the current rows first, then the ``m ≤ capacity``
        queued ones (oldest last), without gradient
    """

    def __init__(self, capacity: int) -> None:
        self.capacity = as_int(capacity, "capacity")
        self._rows: dict[str, torch.Tensor] = {}

    def __len__(self) -> int:
        """Rows queued (the same for every layer)."""
        return next(iter(self._rows.values())).shape[0] if self._rows else 0

    def clear(self) -> None:
        self._rows = {}

    def _check(self, features: Mapping[str, torch.Tensor]) -> None:
        if not features:
            raise ValueError("features: need at least one layer")
        rows = {name: f.shape[0] if f.dim() == 2 else None for name, f in features.items()}
        if any(r is None for r in rows.values()) or len(set(rows.values())) != 1:
            raise ValueError(
                f"features: need (b, d) tensors with one b for every layer, got "
                f"{ {name: tuple(f.shape) for name, f in features.items()} }"
            )
        if self._rows:
            if set(features) != set(self._rows):
                raise ValueError(f"features: layers {sorted(features)}, the queue holds {sorted(self._rows)}")
            for name, f in features.items():
                if f.shape[1] != self._rows[name].shape[1]:
                    raise ValueError(
                        f"features[{name!r}]: width {f.shape[1]}, the queue holds {self._rows[name].shape[1]}"
                    )

    def extend(self, features: Mapping[str, torch.Tensor]) -> dict[str, torch.Tensor]:
        """The current rows followed by the queued ones (the current rows keep their gradient)."""
        self._check(features)
        if not self._rows:
            return dict(features)
        return {name: torch.cat([f, self._rows[name].to(f)]) for name, f in features.items()}

    @torch.no_grad()
    def push(self, features: Mapping[str, torch.Tensor]) -> None:
        """Queue detached copies of the rows, newest first, keeping at most ``capacity``."""
        self._check(features)
        new = {name: f.detach()[: self.capacity] for name, f in features.items()}
        if self._rows:
            new = {name: torch.cat([new[name], self._rows[name]])[: self.capacity] for name in new}
        self._rows = {name: f.clone() for name, f in new.items()}
