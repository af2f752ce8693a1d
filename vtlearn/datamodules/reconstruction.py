"""ReconstructionDataModule: sparse-to-dense shape completion data for ACTOR (thesis ch.8, 8.2.1, 8.3.1).

Training input is a sparse cloud drawn on the fly from an instance's dense 2048-point cloud by random
voxel-grid subsampling to ``[min_points, max_points]`` points (ch.8: 40-120; ch.5 style: 60-1024),
rotated together with its target by a random angle about z. The target is the dense cloud. The
``tactile_test_dataloader`` instead feeds the simulated tactile clouds stored with each test
instance, for evaluating reconstruction from real-like touches.

``tactile_fraction`` (default 0, the thesis protocol) replaces that fraction of the training and
validation inputs by the instance's own stored simulated tactile cloud, randomly subsampled to
``[min_points, max_points]``. Touches come in taxel patches rather than voxel-uniform samples, and a
network trained only on voxel subsamples loses accuracy on them; mixing them in is this framework's
option (not in the thesis) for closing that gap. Test data are never mixed.

Shapes (batch dict):
    sparse (B, Nmax, 3) float32, zero-padded; lengths (B,) int64; dense (B, 2048, 3) float32;
    label (B,) int64
"""

from __future__ import annotations

from functools import partial

import numpy as np
from torch.utils.data import DataLoader, Dataset

from vtlearn.datamodules.shards import (
    ShardedDataModule,
    collate_clouds,
    random_voxel_subsample,
    rotation_z,
    split_clouds,
    worker_rng,
)
from vtlearn.validation import as_int, as_real

DATASET_KINDS = ("reconstruction", "crossmodal")  # `gen-data` kinds with dense clouds per instance


class ReconstructionDataset(Dataset):
    """Per instance: a random voxel-subsampled sparse cloud and the dense target (canonical frame)."""

    def __init__(
        self,
        dense: np.ndarray,
        labels: np.ndarray,
        min_points: int,
        max_points: int,
        train: bool,
        seed: int = 0,
        rotate_z: bool = True,
        sparse: list[np.ndarray] | None = None,
        tactile: list[list[np.ndarray]] | None = None,
        tactile_fraction: float = 0.0,
    ):
        if dense.ndim != 3 or dense.shape[-1] != 3 or len(dense) == 0:
            raise ValueError(f"dense: need a non-empty (N, P, 3) array, got shape {dense.shape}")
        self.dense, self.labels = dense.astype(np.float32), labels.astype(np.int64)
        self.min_points, self.max_points = int(min_points), int(max_points)
        self.train, self.seed, self.rotate_z = train, seed, rotate_z
        self.sparse = sparse
        tactile_fraction = as_real(tactile_fraction, "tactile_fraction", low=0.0, high=1.0)
        if tactile_fraction > 0 and (tactile is None or len(tactile) != len(self.dense)):
            raise ValueError("tactile: tactile_fraction > 0 needs one list of tactile clouds per instance")
        self.tactile, self.tactile_fraction = tactile, float(tactile_fraction)

    def __len__(self) -> int:
        return len(self.dense)

    def __getitem__(self, i: int) -> dict:
        rng = worker_rng(self.train, self.seed, i)
        dense = self.dense[i].astype(np.float64)
        if self.sparse is not None:
            sparse = self.sparse[i].astype(np.float64)
        elif self.tactile_fraction > 0 and self.tactile[i] and rng.random() < self.tactile_fraction:
            clouds = self.tactile[i]
            sparse = clouds[int(rng.integers(len(clouds)))].astype(np.float64)
            n = int(rng.integers(self.min_points, self.max_points + 1))
            if len(sparse) > n:
                sparse = sparse[rng.choice(len(sparse), size=n, replace=False)]
        else:
            sparse = random_voxel_subsample(dense, self.min_points, self.max_points, rng)
        if self.rotate_z:
            R = rotation_z(rng.uniform(0, 2 * np.pi))
            dense, sparse = dense @ R.T, sparse @ R.T
        return {
            "sparse": sparse.astype(np.float32),
            "dense": dense.astype(np.float32),
            "label": int(self.labels[i]),
        }


class ReconstructionDataModule(ShardedDataModule):
    """Lightning data for ACTOR from a `vtlearn gen-data reconstruction` (or crossmodal) directory.

    Args:
        data_dir: dataset directory holding manifest.json.
        batch_size: clouds per batch.
        min_points, max_points: range of the sparse input size (ch.8: 40-120).
        rotate_z: random rotation about z (training always; evaluation with a fixed angle per sample).
        num_workers: DataLoader worker processes.
        seed: fixes the evaluation subsampling and rotations.
        tactile_fraction: fraction of training / validation inputs taken from the instance's stored
            simulated tactile clouds instead of voxel subsampling (0: thesis protocol; see module doc).
        verify: check shard sha256 sums against the manifest when loading.

    ``data_dir`` must be a ``reconstruction`` or ``crossmodal`` dataset (another kind, e.g.
    ``tactile-episodes``, has no dense clouds: a ValueError naming ``data_dir``); ``batch_size``,
    ``min_points``, ``max_points`` (>= 1) and ``num_workers`` (>= 0) must be ints.
    """

    def __init__(
        self,
        data_dir: str,
        batch_size: int = 32,
        min_points: int = 40,
        max_points: int = 120,
        rotate_z: bool = True,
        num_workers: int = 0,
        seed: int = 0,
        tactile_fraction: float = 0.0,
        verify: bool = True,
    ):
        super().__init__()
        number = isinstance(tactile_fraction, (int, float, np.integer, np.floating))
        if not number or not 0.0 <= tactile_fraction <= 1.0:
            raise ValueError(f"tactile_fraction: need a value in [0, 1], got {tactile_fraction!r}")
        self.tactile_fraction = float(tactile_fraction)
        self.batch_size = as_int(batch_size, "batch_size")
        min_points, max_points = as_int(min_points, "min_points"), as_int(max_points, "max_points")
        if not 1 <= min_points <= max_points:
            raise ValueError(f"min_points/max_points: need 1 <= min <= max, got {min_points}, {max_points}")
        self.min_points, self.max_points = min_points, max_points
        self.rotate_z, self.num_workers, self.seed = rotate_z, as_int(num_workers, "num_workers", 0), seed
        self._open_dataset(data_dir, verify, kind=DATASET_KINDS)

    def _dataset(self, split: str, tactile: bool = False) -> ReconstructionDataset:
        d = self._split(split)
        if "dense" not in d:
            raise ValueError(f"data_dir: split {split!r} of {self.data_dir} is empty")
        sparse, mix = None, None
        mixed = split != "test" and self.tactile_fraction > 0
        if tactile or mixed:
            clouds = split_clouds(d["tactile_points"], d["tactile_offsets"])
            per_instance: dict[int, list[np.ndarray]] = {}
            for j, inst in enumerate(d["tactile_instance"]):
                per_instance.setdefault(int(inst), []).append(clouds[j])
            if tactile:
                # one tactile cloud per instance: crossmodal datasets store several, keep the first
                sparse = [per_instance[int(inst)][0] for inst in d["instance"]]
            else:
                mix = [per_instance.get(int(inst), []) for inst in d["instance"]]
        return ReconstructionDataset(
            d["dense"],
            d["label"],
            self.min_points,
            self.max_points,
            train=split == "train",
            seed=self.seed,
            rotate_z=self.rotate_z,
            sparse=sparse,
            tactile=mix,
            tactile_fraction=self.tactile_fraction if mix is not None else 0.0,
        )

    def _loader(self, ds, shuffle: bool) -> DataLoader:
        return super()._loader(ds, shuffle, collate_fn=partial(collate_clouds, cloud_keys=("sparse",)))

    def train_dataloader(self) -> DataLoader:
        return self._loader(self._dataset("train"), shuffle=True)

    def val_dataloader(self) -> DataLoader:
        return self._loader(self._dataset("val"), shuffle=False)

    def test_dataloader(self) -> DataLoader:
        return self._loader(self._dataset("test"), shuffle=False)

    def tactile_test_dataloader(self) -> DataLoader:
        """Test instances with their simulated tactile cloud as the sparse input (not voxel-subsampled)."""
        return self._loader(self._dataset("test", tactile=True), shuffle=False)

    def predict_dataloader(self) -> DataLoader:
        """``trainer.predict`` reconstructs the test instances from their simulated tactile clouds."""
        return self.tactile_test_dataloader()
