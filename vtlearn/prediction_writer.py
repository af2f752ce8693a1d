"""What ``python train.py predict`` computes, kept: one ``.npz`` of every model's ``predict_step`` output.

``predict_step`` returns a tensor per batch: ACTOR's dense reconstructions ``(B, P, 3)`` in the canonical
frame, xAVTNet's and ACTOR-recognition's class probabilities ``(B, C)``. :class:`NpzPredictionWriter`
gathers them over the predict set, in order, with the batches' labels when they carry them, and writes
``predictions.npz`` atomically (loads with ``allow_pickle=False``). ``train.py predict`` adds one, writing
into the run's log folder, unless the config has a prediction writer of its own.

Shapes:
    predictions ``(N, ...)`` float32 (N clouds of the predict set); label ``(N,)`` int64 when the batches
    have one; class_names ``(C,)`` str when the model recorded them.
"""

from __future__ import annotations

import logging
from pathlib import Path
from typing import Any

import numpy as np
import torch
from lightning.pytorch.callbacks import BasePredictionWriter

__all__ = ["NpzPredictionWriter"]

log = logging.getLogger(__name__)


class NpzPredictionWriter(BasePredictionWriter):
    """Gathers ``predict_step``'s outputs and writes them to one ``.npz`` when the predict epoch ends.

    Args:
        path: the file to write; ``None``: ``predictions.npz`` in the trainer's ``log_dir`` (its
            ``default_root_dir`` without a logger).
    """

    def __init__(self, path: str | Path | None = None) -> None:
        super().__init__(write_interval="batch")
        if path is not None and Path(path).suffix != ".npz":
            raise ValueError(f"path: need a .npz file, got {path}")
        self.path = None if path is None else Path(path)
        self._outputs: list[np.ndarray] = []
        self._labels: list[np.ndarray] = []
        self.written: Path | None = None

    def on_predict_epoch_start(self, trainer, pl_module) -> None:
        self._outputs, self._labels = [], []

    def write_on_batch_end(self, trainer, pl_module, prediction: Any, batch_indices, batch, batch_idx: int,
                           dataloader_idx: int) -> None:
        if not isinstance(prediction, torch.Tensor):
            raise ValueError(f"predict_step: NpzPredictionWriter keeps tensors, got "
                             f"{type(prediction).__name__}")
        self._outputs.append(prediction.detach().float().cpu().numpy())
        if isinstance(batch, dict) and isinstance(batch.get("label"), torch.Tensor):
            self._labels.append(batch["label"].detach().cpu().numpy().astype(np.int64))

    def on_predict_epoch_end(self, trainer, pl_module) -> None:
        from vtlearn.io import atomic_write_npz

        if not self._outputs:
            return
        arrays: dict[str, np.ndarray] = {"predictions": np.concatenate(self._outputs)}
        if len(self._labels) == len(self._outputs):
            arrays["label"] = np.concatenate(self._labels)
        names = dict(getattr(pl_module, "hparams", {}) or {}).get("class_names")
        if names:
            arrays["class_names"] = np.asarray([str(n) for n in names])
        folder = trainer.log_dir or trainer.default_root_dir
        path = self.path or Path(folder) / "predictions.npz"
        if trainer.is_global_zero:
            self.written = atomic_write_npz(path, **arrays)
            shape = arrays["predictions"].shape
            log.info("predict: wrote predictions %s to %s", shape, path)
            print(f"predict: {shape[0]} predictions {shape[1:]} written to {path}")
