"""CrossModalDataModule: visual source + unlabelled tactile target for domain adaptation (thesis ch.7).

xAVTNet (ch.7, 7.2.2-7.2.3) trains a classifier on labelled visual clouds (source domain) while
aligning features with unlabelled tactile clouds (target domain) through VTLoss; tactile labels are
used only for evaluation. Training batches combine one source and one target batch with
``CombinedLoader(mode="max_size_cycle")``: the shorter loader cycles.

Clouds are in the instance's canonical frame (``units="canonical"``) or in metres
(``units="metres"``), then normalised per cloud (``normalize``: ``none``, ``center`` or
``unit_sphere``) and, in training, rotated by a random angle about z (objects stand upright on the
table, their yaw is unknown).

Shapes (batch dicts):
    train: {"source": {"points" (B, 1024, 3), "lengths" (B,), "label" (B,)},
            "target": {"points" (B, Nmax, 3), "lengths" (B,)}}
    val/test (tactile) and source_test (visual): {"points" (B, Nmax, 3), "lengths" (B,), "label" (B,)}
"""

from __future__ import annotations

import numpy as np
from lightning.pytorch.utilities import CombinedLoader
from torch.utils.data import DataLoader, Dataset

from vtlearn.datamodules.shards import (
    ShardedDataModule,
    normalize_cloud,
    rotation_z,
    split_clouds,
    worker_rng,
)


class CloudDataset(Dataset):
    """Clouds with optional labels; items are {"points", "label"} or {"points", "index"}."""

    def __init__(
        self,
        clouds: list[np.ndarray],
        labels: np.ndarray | None,
        train: bool,
        normalize: str = "center",
        rotate_z: bool = True,
        seed: int = 0,
        indices: np.ndarray | None = None,
        scales: np.ndarray | None = None,
        with_label: bool = True,
        with_index: bool = False,
    ):
        if len(clouds) == 0:
            raise ValueError("clouds: empty dataset")
        normalize_cloud(np.zeros((1, 3)), normalize)  # validates the mode early
        self.clouds, self.labels = clouds, labels
        self.indices = np.arange(len(clouds)) if indices is None else np.asarray(indices)
        self.train, self.normalize, self.rotate_z, self.seed = train, normalize, rotate_z, seed
        self.scales, self.with_label, self.with_index = scales, with_label, with_index

    def __len__(self) -> int:
        return len(self.indices)

    def __getitem__(self, i: int) -> dict:
        j = int(self.indices[i])
        pts = self.clouds[j].astype(np.float64)
        if self.scales is not None:
            pts = pts * float(self.scales[j])
        if self.rotate_z and self.train:
            pts = pts @ rotation_z(worker_rng(True, self.seed, j).uniform(0, 2 * np.pi)).T
        item = {"points": normalize_cloud(pts, self.normalize).astype(np.float32)}
        if self.with_label:
            item["label"] = int(self.labels[j])
        if self.with_index:
            item["index"] = j
        return item


def modality_clouds(
    d: dict, modality: str, metres: bool
) -> tuple[list[np.ndarray], np.ndarray, np.ndarray | None]:
    """(clouds, labels, per-cloud metres scale or None) of one modality from a loaded split."""
    if modality == "visual":
        if "visual" not in d:
            raise ValueError(
                "modality: this dataset has no visual clouds (generate it with `gen-data crossmodal`)"
            )
        clouds, labels, inst = list(d["visual"]), d["visual_label"], d["visual_instance"]
    elif modality == "tactile":
        clouds = split_clouds(d["tactile_points"], d["tactile_offsets"])
        labels, inst = d["tactile_label"], d["tactile_instance"]
    else:
        raise ValueError(f"modality: expected 'visual' or 'tactile', got {modality!r}")
    scales = None
    if metres:
        lookup = dict(zip(d["instance"].tolist(), d["scale_m"].tolist(), strict=True))
        scales = np.array([lookup[int(k)] for k in inst])
    return clouds, labels, scales


class CrossModalDataModule(ShardedDataModule):
    """Visual (labelled source) and tactile (unlabelled target) clouds from `vtlearn gen-data crossmodal`.

    Args:
        data_dir: dataset directory holding manifest.json.
        batch_size: clouds per source batch and per target batch.
        normalize: per-cloud normalisation, ``none`` | ``center`` | ``unit_sphere``.
        units: ``canonical`` (unit cube per instance) or ``metres``.
        rotate_z: random yaw augmentation in training.
        target_split: the split whose tactile clouds, without labels, form the target stream.
            ``"train"`` (default, inductive): the test instances are never seen in training at all.
            ``"test"`` (transductive, the usual UDA protocol of DAN / Deep CORAL / DANN and the
            thesis's 900 + 300 tactile clouds of the same 12 objects): the unlabelled tactile clouds of
            the test instances adapt the model that is then scored on them with their labels.
        num_workers, seed, verify: see :class:`ReconstructionDataModule`.
    """

    def __init__(
        self,
        data_dir: str,
        batch_size: int = 32,
        normalize: str = "center",
        units: str = "canonical",
        rotate_z: bool = True,
        target_split: str = "train",
        target_data_dir: str | None = None,
        num_workers: int = 0,
        seed: int = 0,
        verify: bool = True,
    ):
        super().__init__()
        if target_split not in ("train", "test"):
            raise ValueError(f"target_split: expected 'train' or 'test', got {target_split!r}")
        if batch_size < 1:
            raise ValueError(f"batch_size: need >= 1, got {batch_size}")
        if units not in ("canonical", "metres"):
            raise ValueError(f"units: expected 'canonical' or 'metres', got {units!r}")
        normalize_cloud(np.zeros((1, 3)), normalize)
        self.batch_size, self.normalize, self.units = batch_size, normalize, units
        self.rotate_z, self.num_workers, self.seed = rotate_z, num_workers, seed
        self.target_split = target_split
        self._open_dataset(data_dir, verify, kind="crossmodal")
        self.target_data_dir = target_data_dir
        self._target_split_data: dict | None = None
        if target_data_dir is not None:
            from vtlearn.datamodules.shards import load_manifest

            other = load_manifest(target_data_dir)
            if list(other["class_names"]) != self.class_names:
                raise ValueError(
                    f"target_data_dir: class names {other['class_names']} differ from data_dir's "
                    f"{self.class_names}"
                )
            if target_split not in other["splits"]:
                raise ValueError(
                    f"target_data_dir: no {target_split!r} split in {target_data_dir} "
                    f"(it has {sorted(other['splits'])}); set target_split to one of them"
                )

    def dataset(
        self, split: str, modality: str, with_label: bool = True, train: bool | None = None
    ) -> CloudDataset:
        """Clouds of one split and modality; ``train`` (default: ``split == "train"``) turns on the
        random yaw augmentation."""
        clouds, labels, scales = modality_clouds(self._split(split), modality, self.units == "metres")
        return CloudDataset(
            clouds,
            labels,
            train=split == "train" if train is None else train,
            normalize=self.normalize,
            rotate_z=self.rotate_z,
            seed=self.seed,
            scales=scales,
            with_label=with_label,
        )

    def target_dataset(self) -> CloudDataset:
        """The unlabelled, yaw-augmented tactile clouds of the target stream (``target_split`` of
        ``data_dir``, or of ``target_data_dir`` when set)."""
        if self.target_data_dir is None:
            return self.dataset(self.target_split, "tactile", with_label=False, train=True)
        if self._target_split_data is None:
            from vtlearn.datamodules.shards import load_split

            self._target_split_data = load_split(self.target_data_dir, self.target_split, self.verify)
        clouds, labels, scales = modality_clouds(self._target_split_data, "tactile", self.units == "metres")
        return CloudDataset(clouds, labels, train=True, normalize=self.normalize, rotate_z=self.rotate_z,
                            seed=self.seed, scales=scales, with_label=False)

    def train_dataloader(self) -> CombinedLoader:
        source = self._loader(self.dataset("train", "visual"), shuffle=True)
        target = self._loader(self.target_dataset(), shuffle=True)
        return CombinedLoader({"source": source, "target": target}, mode="max_size_cycle")

    def val_dataloader(self) -> DataLoader:
        return self._loader(self.dataset("val", "tactile"), shuffle=False)

    def test_dataloader(self) -> DataLoader:
        return self._loader(self.dataset("test", "tactile"), shuffle=False)

    def predict_dataloader(self) -> DataLoader:
        """``trainer.predict`` classifies the test tactile clouds (the cross-modal target domain)."""
        return self.test_dataloader()

    def source_test_dataloader(self) -> DataLoader:
        """Labelled visual clouds of the test instances."""
        return self._loader(self.dataset("test", "visual"), shuffle=False)

    def labelled_target_train_dataloader(self) -> DataLoader:
        """Labelled, yaw-augmented tactile training clouds. Only for the train-on-target upper bound
        (``bench crossmodal --variants tactile_oracle``); UDA training never sees tactile labels."""
        return self._loader(self.dataset("train", "tactile"), shuffle=True)

    def source_val_dataloader(self) -> DataLoader:
        return self._loader(self.dataset("val", "visual"), shuffle=False)
