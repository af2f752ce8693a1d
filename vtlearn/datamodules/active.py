"""ActivePoolDataModule: a labelled / unlabelled pool for active learning (thesis ch.7, 7.2.1, eq. 7.3-7.4).

The pool is the training split of one modality (tactile by default). ``initial_labels`` random pool
items start labelled; an acquisition function (MC-dropout, eq. 7.3-7.4) scores
``unlabelled_dataloader()`` batches by their ``index`` and calls ``query(indices)``, which reveals
those labels and moves the items to the labelled set.

Shapes (batch dicts):
    train / val / test: {"points" (B, Nmax, 3), "lengths" (B,), "label" (B,)}
    unlabelled: {"points" (B, Nmax, 3), "lengths" (B,), "index" (B,)}  (pool indices)
"""

from __future__ import annotations

import numpy as np
import torch
from torch.utils.data import DataLoader

from vtlearn.datamodules.crossmodal import CloudDataset, modality_clouds
from vtlearn.datamodules.shards import ShardedDataModule, normalize_cloud
from vtlearn.validation import as_int


class ActivePoolDataModule(ShardedDataModule):
    """Args:
    data_dir: a `gen-data crossmodal` (tactile or visual) or `gen-data reconstruction` (tactile) dataset.
    initial_labels: pool items labelled at the start (n0), drawn at random with ``seed``.
    modality: ``tactile`` or ``visual``.
    batch_size, normalize, units, rotate_z, num_workers, verify: as in :class:`CrossModalDataModule`.

    ``data_dir`` must be a ``crossmodal`` or ``reconstruction`` dataset (``crossmodal`` for
    ``modality="visual"``), else a ValueError naming it; ``initial_labels`` (>= 0), ``batch_size`` (>= 1) and
    ``num_workers`` (>= 0) must be ints.
    """

    def __init__(
        self,
        data_dir: str,
        initial_labels: int = 10,
        seed: int = 0,
        modality: str = "tactile",
        batch_size: int = 32,
        normalize: str = "center",
        units: str = "canonical",
        rotate_z: bool = True,
        num_workers: int = 0,
        verify: bool = True,
    ):
        super().__init__()
        batch_size = as_int(batch_size, "batch_size")
        num_workers = as_int(num_workers, "num_workers", 0)
        initial_labels = as_int(initial_labels, "initial_labels", 0)
        if modality not in ("tactile", "visual"):
            raise ValueError(f"modality: expected 'tactile' or 'visual', got {modality!r}")
        if units not in ("canonical", "metres"):
            raise ValueError(f"units: expected 'canonical' or 'metres', got {units!r}")
        normalize_cloud(np.zeros((1, 3)), normalize)
        self.modality, self.batch_size = modality, batch_size
        self.normalize, self.units, self.rotate_z = normalize, units, rotate_z
        self.num_workers, self.seed = num_workers, seed
        manifest = self._open_dataset(data_dir, verify, kind=("crossmodal", "reconstruction"))
        if modality == "visual" and manifest.get("kind") != "crossmodal":
            raise ValueError(f"data_dir: {data_dir} is a {manifest.get('kind')!r} dataset with no visual "
                             "clouds; modality='visual' needs a 'crossmodal' one")
        clouds, labels, scales = modality_clouds(self._split("train"), modality, units == "metres")
        self._pool = (clouds, labels, scales)
        n = len(clouds)
        if not 0 <= initial_labels <= n:
            raise ValueError(f"initial_labels: need 0 <= n0 <= pool size {n}, got {initial_labels}")
        perm = np.random.default_rng(seed).permutation(n)
        self._labelled = np.zeros(n, dtype=bool)
        self._labelled[perm[:initial_labels]] = True

    @property
    def pool_size(self) -> int:
        return len(self._labelled)

    @property
    def labelled_indices(self) -> np.ndarray:
        return np.flatnonzero(self._labelled)

    @property
    def unlabelled_indices(self) -> np.ndarray:
        return np.flatnonzero(~self._labelled)

    def query(self, indices) -> torch.Tensor:
        """Reveal the labels of unlabelled pool ``indices`` (integers in ``[0, pool_size)``, e.g. the
        ``index`` entries of :meth:`unlabelled_dataloader` batches) and move them to the labelled set."""
        try:
            idx = np.asarray(indices.detach().cpu().numpy() if torch.is_tensor(indices) else indices)
        except (TypeError, ValueError):
            raise ValueError(f"indices: expected integer pool indices, got {indices!r}") from None
        idx = idx.reshape(-1)
        if len(idx) == 0:
            raise ValueError("indices: empty")
        if idx.dtype.kind not in "iu":
            raise ValueError(f"indices: expected integer pool indices, got {idx.dtype} {idx.tolist()[:8]}")
        idx = idx.astype(np.int64)
        if len(np.unique(idx)) != len(idx):
            raise ValueError(f"indices: duplicates in {idx.tolist()}")
        if idx.min() < 0 or idx.max() >= self.pool_size:
            raise ValueError(f"indices: out of the pool range [0, {self.pool_size})")
        if self._labelled[idx].any():
            raise ValueError(f"indices: already labelled {idx[self._labelled[idx]].tolist()}")
        self._labelled[idx] = True
        return torch.as_tensor(self._pool[1][idx], dtype=torch.int64)

    def _pool_dataset(self, indices, labelled: bool, train: bool) -> CloudDataset:
        clouds, labels, scales = self._pool
        return CloudDataset(
            clouds,
            labels,
            train=train,
            normalize=self.normalize,
            rotate_z=self.rotate_z,
            seed=self.seed,
            indices=indices,
            scales=scales,
            with_label=labelled,
            with_index=not labelled,
        )

    def _loader(self, ds, shuffle: bool) -> DataLoader:
        # the pool changes every round, so workers are not kept between epochs
        return super()._loader(ds, shuffle, persistent_workers=False)

    def train_dataloader(self) -> DataLoader:
        if not self._labelled.any():
            raise ValueError("initial_labels: no labelled items yet; query() some first")
        return self._loader(self._pool_dataset(self.labelled_indices, True, True), shuffle=True)

    def unlabelled_dataloader(self) -> DataLoader:
        return self._loader(self._pool_dataset(self.unlabelled_indices, False, False), shuffle=False)

    def _eval(self, split: str) -> DataLoader:
        clouds, labels, scales = modality_clouds(self._split(split), self.modality, self.units == "metres")
        ds = CloudDataset(
            clouds,
            labels,
            train=False,
            normalize=self.normalize,
            rotate_z=self.rotate_z,
            seed=self.seed,
            scales=scales,
        )
        return self._loader(ds, shuffle=False)

    def val_dataloader(self) -> DataLoader:
        return self._eval("val")

    def test_dataloader(self) -> DataLoader:
        return self._eval("test")
