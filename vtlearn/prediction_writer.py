"""What ``python train.py predict`` computes, kept: one ``.npz`` of every model's ``predict_step`` output.

``predict_step`` returns a tensor per batch: ACTOR's dense reconstructions ``(B, P, 3)`` in the canonical
frame, xAVTNet's and ACTOR-recognition's class probabilities ``(B, C)``. :class:`NpzPredictionWriter`
gathers them over the predict set, in order, with the batches' labels when they carry them, and writes
``predictions.npz`` atomically (loads with ``allow_pickle=False``). ``train.py predict`` adds one, writing
into the run's log folder, unless the config has a prediction writer of its own.

Several predict dataloaders give one array per loader (``predictions_0``, ``label_0``, ``predictions_1``
...). On several devices each process writes its own share, ``predictions.rank<r>.npz`` (no gather). A
``predict_step`` that returns something other than a tensor (a dict, a list) is not kept: a warning says so,
and predict runs on.

Shapes:
    predictions ``(N, ...)`` float32 (N clouds of the predict set); label ``(N,)`` int64 when the batches
    have one; class_names ``(C,)`` str when the model recorded them.
"""

from __future__ import annotations

import logging
from collections import defaultdict
from pathlib import Path

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
        self.written: Path | None = None
        self._reset()

    def _reset(self) -> None:
        self._outputs: dict[int, list[np.ndarray]] = defaultdict(list)
        self._labels: dict[int, list[np.ndarray]] = defaultdict(list)
        self._skipped: str | None = None
        self.written = None  # this run's file, once written

    def on_predict_epoch_start(self, trainer, pl_module) -> None:
        self._reset()

    def write_on_batch_end(self, trainer, pl_module, prediction, batch_indices, batch, batch_idx: int,
                           dataloader_idx: int) -> None:
        if not isinstance(prediction, torch.Tensor):
            self._skipped = type(prediction).__name__
            return
        self._outputs[dataloader_idx].append(prediction.detach().float().cpu().numpy())
        if isinstance(batch, dict) and isinstance(batch.get("label"), torch.Tensor):
            self._labels[dataloader_idx].append(batch["label"].detach().cpu().numpy().astype(np.int64))

    def on_predict_epoch_end(self, trainer, pl_module) -> None:
        from vtlearn.io import atomic_write_npz

        if self._skipped is not None:
            log.warning("predict: predict_step returned a %s, not a tensor; NpzPredictionWriter wrote "
                        "nothing", self._skipped)
            return
        if not self._outputs:
            return
        several = len(self._outputs) > 1
        arrays: dict[str, np.ndarray] = {}
        for idx, outs in sorted(self._outputs.items()):
            suffix = f"_{idx}" if several else ""
            arrays[f"predictions{suffix}"] = np.concatenate(outs)
            if len(self._labels[idx]) == len(outs):
                arrays[f"label{suffix}"] = np.concatenate(self._labels[idx])
        names = dict(getattr(pl_module, "hparams", {}) or {}).get("class_names")
        if names:
            arrays["class_names"] = np.asarray([str(n) for n in names])
        path = self.path or Path(trainer.log_dir or trainer.default_root_dir) / "predictions.npz"
        if trainer.world_size > 1:
            path = path.with_name(f"{path.stem}.rank{trainer.global_rank}{path.suffix}")
        self.written = atomic_write_npz(path, **arrays)
        counts = ", ".join(f"{v.shape[0]} {tuple(v.shape[1:])}" for k, v in arrays.items()
                           if k.startswith("predictions"))
        log.info("predict: wrote predictions %s to %s", counts, path)
        print(f"predict: predictions {counts} written to {path}")
