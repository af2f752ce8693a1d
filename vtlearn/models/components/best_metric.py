"""The best-so-far value of one validation metric, carried across a resume (ACTOR's ``val/cd_mm_best``,
ACTORRecognition's ``val/acc_best``).

The value is a plain float attribute, not a buffer, so it stays out of the state dict and checkpoints
written before it existed still load with ``strict=True``. It travels in the checkpoint dict under
:data:`BEST_METRICS_KEY` as ``{metric name: float}``. The validation of Lightning's sanity check is no epoch
of the run (it evaluates the untrained model, or on a resume the checkpoint's weights again), so it never
moves the best.
"""

from __future__ import annotations

import math
from typing import Any

__all__ = ["BEST_METRICS_KEY", "BestMetricMixin"]

#: The checkpoint-dict key holding the best-so-far validation metrics (``{"val/cd_mm_best": float}``,
#: plain floats), written by ``on_save_checkpoint`` and read back on a resume. Not in the state dict.
BEST_METRICS_KEY = "vtlearn_best_metrics"


class BestMetricMixin:
    """Mixin for a ``LightningModule`` (put it first among the bases, so that its checkpoint hooks are used).

    A subclass sets three class attributes: ``best_metric_name`` (the logged key and the checkpoint entry,
    e.g. ``"val/cd_mm_best"``), ``best_metric_attr`` (the float attribute holding the value, e.g.
    ``"val_cd_best"``) and ``best_metric_mode`` (``"min"`` or ``"max"``); it calls
    :meth:`reset_best_metric` in ``__init__`` and :meth:`update_best_metric` at the end of each validation
    epoch.
    """

    best_metric_name: str
    best_metric_attr: str
    best_metric_mode: str

    def reset_best_metric(self) -> None:
        """No best yet: +inf for ``"min"``, -inf for ``"max"``."""
        if self.best_metric_mode not in ("min", "max"):
            raise ValueError(f"best_metric_mode: expected 'min' or 'max', got {self.best_metric_mode!r}")
        setattr(self, self.best_metric_attr, math.inf if self.best_metric_mode == "min" else -math.inf)

    def update_best_metric(self, value: float) -> bool:
        """Fold this validation epoch's ``value`` into the best (a NaN leaves it) and log the best.

        Returns False, doing nothing, during the sanity check; True otherwise.
        """
        if self.trainer.sanity_checking:
            return False
        best = getattr(self, self.best_metric_attr)
        if not math.isnan(value):
            best = min(best, value) if self.best_metric_mode == "min" else max(best, value)
            setattr(self, self.best_metric_attr, best)
        self.log(self.best_metric_name, best, sync_dist=True, prog_bar=True)
        return True

    def on_save_checkpoint(self, checkpoint: dict[str, Any]) -> None:
        best = float(getattr(self, self.best_metric_attr))
        checkpoint.setdefault(BEST_METRICS_KEY, {})[self.best_metric_name] = best

    def on_load_checkpoint(self, checkpoint: dict[str, Any]) -> None:
        # checkpoints written before the best was saved have no entry: the best restarts from this run
        best = checkpoint.get(BEST_METRICS_KEY, {}).get(self.best_metric_name)
        if best is not None:
            setattr(self, self.best_metric_attr, float(best))
