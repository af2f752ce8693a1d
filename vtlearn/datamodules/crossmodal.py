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
    check_split,
    load_manifest,
    load_split,
    normalize_cloud,
    random_voxel_subsample,
    rotation_z,
    split_clouds,
    worker_rng,
)
from vtlearn.validation import as_int, as_real


def _check_points_range(value, name: str) -> tuple[int, int]:
    """``(n_min, n_max)`` with ``1 <= n_min <= n_max``, or a ValueError naming ``name``."""
    try:
        lo, hi = (int(v) for v in value)
    except (TypeError, ValueError):
        raise ValueError(f"{name}: expected two integers [n_min, n_max], got {value!r}") from None
    if not 1 <= lo <= hi:
        raise ValueError(f"{name}: need 1 <= n_min <= n_max, got [{lo}, {hi}]")
    return lo, hi


class CloudDataset(Dataset):
    """Clouds with optional labels; items are {"points", "label"} or {"points", "index"}, with ``"group"``
    (the cloud's entry of ``groups``, e.g. its object instance) as well when ``with_group``.

    Training-time options (``train=True`` only): ``rotate_z``, a random yaw; ``subsample=(n_min, n_max)``,
    random voxel-grid thinning; ``fuse_views=k`` with ``groups`` (one instance id per cloud), the cloud
    fused with ``k - 1`` other clouds of its instance drawn at random (all are in the instance's frame),
    then resampled to the cloud's own point count; ``touch_pitch`` (one taxel pitch per cloud, in the
    cloud's units) with ``subsample``, the (fused) cloud replaced by the contacts of simulated pad touches
    (:func:`~vtlearn.sim_data.cloud_touch.touch_cloud`), as many as ``subsample`` draws.
    """

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
        subsample: tuple[int, int] | None = None,
        fuse_views: int = 1,
        groups: np.ndarray | None = None,
        touch_pitch: np.ndarray | None = None,
        with_group: bool = False,
    ):
        if len(clouds) == 0:
            raise ValueError("clouds: empty dataset")
        normalize_cloud(np.zeros((1, 3)), normalize)  # validates the mode early
        if subsample is not None:
            subsample = _check_points_range(subsample, "subsample")
        self.subsample, self.fuse_views = subsample, as_int(fuse_views, "fuse_views")
        if touch_pitch is not None:
            touch_pitch = np.asarray(touch_pitch, dtype=np.float64)
            if subsample is None or touch_pitch.shape != (len(clouds),) or not (touch_pitch > 0).all():
                raise ValueError("touch_pitch: needs subsample (the contact count) and one positive pitch "
                                 "per cloud")
        self.touch_pitch = touch_pitch
        self._members: dict[int, np.ndarray] = {}
        if (self.fuse_views > 1 or with_group) and (groups is None or len(groups) != len(clouds)):
            raise ValueError(f"groups: {'with_group' if with_group else 'fuse_views > 1'} needs one instance "
                             f"id per cloud")
        self.groups = None if groups is None else np.asarray(groups)
        self.with_group = with_group
        if self.fuse_views > 1:
            for g in np.unique(self.groups):
                self._members[int(g)] = np.flatnonzero(self.groups == g)
        self.clouds, self.labels = clouds, labels
        self.indices = np.arange(len(clouds)) if indices is None else np.asarray(indices)
        self.train, self.normalize, self.rotate_z, self.seed = train, normalize, rotate_z, seed
        self.scales, self.with_label, self.with_index = scales, with_label, with_index

    def __len__(self) -> int:
        return len(self.indices)

    def __getitem__(self, i: int) -> dict:
        j = int(self.indices[i])
        pts = self.clouds[j].astype(np.float64)
        fuse = self.train and self.fuse_views > 1
        touch = self.train and self.touch_pitch is not None
        if self.train and (self.rotate_z or self.subsample is not None or fuse or touch):
            rng = worker_rng(True, self.seed, j)
        if fuse:
            others = self._members[int(self.groups[j])]
            others = others[others != j]
            pick = rng.choice(others, size=min(self.fuse_views - 1, len(others)), replace=False)
            fused = np.concatenate([pts, *(self.clouds[int(o)] for o in pick)])
            pts = fused if self.touch_pitch is not None else fused[rng.choice(len(fused), len(pts), False)]
        touched = False
        if touch:
            from vtlearn.sim_data.cloud_touch import touch_cloud

            n = int(rng.integers(self.subsample[0], self.subsample[1] + 1))
            contacts = touch_cloud(pts, n, rng, float(self.touch_pitch[j]))
            if len(contacts) >= self.subsample[0]:  # else (every touch missed): thin the cloud instead
                pts, touched = contacts, True
        if self.scales is not None:
            pts = pts * float(self.scales[j])
        if self.train and (self.rotate_z or self.subsample is not None):
            if self.rotate_z:
                pts = pts @ rotation_z(rng.uniform(0, 2 * np.pi)).T
            if self.subsample is not None and not touched:
                pts = random_voxel_subsample(pts, *self.subsample, rng)
        item = {"points": normalize_cloud(pts, self.normalize).astype(np.float32)}
        if self.with_label:
            item["label"] = int(self.labels[j])
        if self.with_index:
            item["index"] = j
        if self.with_group:
            item["group"] = int(self.groups[j])
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
    return clouds, labels, instance_scales(d, inst) if metres else None


def instance_scales(d: dict, instances) -> np.ndarray:
    """Metres per canonical unit of each listed instance id, from a loaded split's ``scale_m``.

    Shapes:
        instances (n,) -> (n,)
    """
    lookup = dict(zip(d["instance"].tolist(), d["scale_m"].tolist(), strict=True))
    return np.array([lookup[int(k)] for k in instances], dtype=np.float64)


TARGET_SPLITS = ("train", "test", "train+test")


class CrossModalDataModule(ShardedDataModule):
    """Visual (labelled source) and tactile (unlabelled target) clouds from `vtlearn gen-data crossmodal`.

    Args:
        data_dir: dataset directory holding manifest.json.
        batch_size: clouds per source batch (and per target batch, unless ``target_batch_size`` is set).
        target_batch_size: clouds per batch of the unlabelled target stream (default: ``batch_size``).
            Tactile clouds hold 30-80 points against the visual clouds' hundreds, so a larger target batch
            costs little; each step's MMD, CORAL and the joint batch norm then see more tactile clouds.
        normalize: per-cloud normalisation, ``none`` | ``center`` | ``unit_sphere``.
        units: ``canonical`` (unit cube per instance) or ``metres``.
        rotate_z: random yaw augmentation in training.
        target_split: the split whose tactile clouds, without labels, form the target stream.
            ``"train"`` (default, inductive): the test instances are never seen in training at all.
            ``"test"`` (transductive, the usual UDA protocol of DAN / Deep CORAL / DANN and the
            thesis's 900 + 300 tactile clouds of the same 12 objects): the unlabelled tactile clouds of
            the test instances adapt the model that is then scored on them with their labels.
            ``"train+test"`` (transductive): the unlabelled tactile clouds of both splits in one stream,
            each cloud with its own index, so that the target stream spans the training instances' shapes
            as well as the test instances' (the thesis adapted on 900 tactile clouds and tested on 300).
        target_data_dir: another dataset with the same class names (e.g. from ``vtlearn gen-episodes``)
            whose ``target_split`` tactile clouds form the target stream instead of ``data_dir``'s.
        source_points: ``[n_min, n_max]`` or None (default). When set, every visual training cloud is
            thinned, each time it is drawn, to a size drawn uniformly from that range by random voxel-grid
            subsampling (:func:`~vtlearn.datamodules.shards.random_voxel_subsample`), so the source has the
            tactile clouds' density (30-120 points, thesis 7.3.1). It uses no tactile data, only the
            sensor's known point count; visual test clouds stay dense.
        source_views: views fused into each visual training cloud (default 1: the single view, as in the
            thesis). With ``k > 1`` every drawn cloud is joined with ``k - 1`` other views of its instance,
            picked at random (views share the instance frame), and resampled to its point count: the
            coverage of a camera that looks from several sides. Visual test clouds stay single views.
        source_touch: replace each visual training cloud (fused over ``source_views`` first; use all
            views, since a touch on a one-sided cloud passes through its missing back) by the contacts of
            simulated Xela 4x4 pad touches on it (:func:`~vtlearn.sim_data.cloud_touch.touch_cloud`),
            ``source_points`` of them (default 30-120). No tactile data are used.
        source_splits: the splits whose labelled visual clouds form the source (default ``["train"]``).
            ``["train", "test"]`` with ``target_split="test"`` is the thesis's known-objects protocol
            (7.3.1): the test objects are seen, labelled, by the camera, and touch must then recognise
            the same objects without tactile labels, and ``source_test_dataloader`` is no longer a
            held-out score. ``["test"]`` on a dataset with one test instance per class is the thesis's
            twelve objects exactly (``configs/cpu/xavtnet_objects.yaml``). The default keeps the test
            instances unseen by vision (category-level recognition of new instances).
        target_holdout: fraction of each test instance's tactile clouds held out of the target stream and
            scored as the test set (default 0: the test set is every tactile cloud of the test split). The
            thesis split the tactile clouds of its 12 objects 900 for adaptation and 300 for the test
            (7.3.2); a fraction of 0.25 is that split, drawn per instance (at least one cloud held out
            and one kept; an instance with a single cloud stays in the stream) with ``seed``, and without the
            thesis's yaw-rotated copies of one touch falling on both sides. Needs ``target_split="test"``
            and no ``target_data_dir``. The ``tactile_oracle`` bound (``train_on="tactile"``) then trains on
            the target stream's clouds with their labels.
        train_on: ``"visual"`` (default, the thesis's UDA protocol: labelled visual source plus the
            unlabelled tactile target stream) or ``"tactile"``: supervised training on the *labelled*
            tactile training clouds of ``data_dir`` (and of ``target_data_dir``'s ``train`` split when it
            is set), with no target stream. In simulation the touch labels are free, so this gives the
            supervised upper bound of cross-modal transfer, a classifier that separates the quality of an
            active-touch criterion from the quality of the domain adaptation (docs/active_perception.md).
            Evaluation loaders are the same for both.
        num_workers, seed, verify: see :class:`ReconstructionDataModule`.

    Integer settings (``batch_size``, ``target_batch_size``, ``source_views``: >= 1, ``num_workers``: >= 0)
    must be ints; a damaged dataset (manifest, missing or unreadable shard) raises a ValueError naming
    ``data_dir`` or ``target_data_dir`` (FileNotFoundError when a file is missing).
    """

    def __init__(
        self,
        data_dir: str,
        batch_size: int = 32,
        target_batch_size: int | None = None,
        normalize: str = "center",
        units: str = "canonical",
        rotate_z: bool = True,
        target_split: str = "train",
        target_data_dir: str | None = None,
        source_points: tuple[int, int] | list[int] | None = None,
        source_views: int = 1,
        source_touch: bool = False,
        source_splits: list[str] | None = None,
        target_holdout: float = 0.0,
        train_on: str = "visual",
        num_workers: int = 0,
        seed: int = 0,
        verify: bool = True,
    ):
        super().__init__()
        if target_split not in TARGET_SPLITS:
            raise ValueError(f"target_split: expected one of {list(TARGET_SPLITS)}, got {target_split!r}")
        batch_size = as_int(batch_size, "batch_size")
        num_workers = as_int(num_workers, "num_workers", 0)
        if target_batch_size is not None:
            target_batch_size = as_int(target_batch_size, "target_batch_size")
        self.target_batch_size = target_batch_size
        if train_on not in ("visual", "tactile"):
            raise ValueError(f"train_on: expected 'visual' or 'tactile', got {train_on!r}")
        if units not in ("canonical", "metres"):
            raise ValueError(f"units: expected 'canonical' or 'metres', got {units!r}")
        normalize_cloud(np.zeros((1, 3)), normalize)
        self.batch_size, self.normalize, self.units = batch_size, normalize, units
        self.rotate_z, self.num_workers, self.seed = rotate_z, num_workers, seed
        self.target_split, self.train_on = target_split, train_on
        self.source_views, self.source_touch = as_int(source_views, "source_views"), bool(source_touch)
        self.source_points = (
            None if source_points is None else _check_points_range(source_points, "source_points")
        )
        manifest = self._open_dataset(data_dir, verify, kind="crossmodal")
        self.source_splits = ["train"] if source_splits is None else [str(x) for x in source_splits]
        missing = [x for x in self.source_splits if x not in manifest["splits"]]
        if not self.source_splits or missing or len(set(self.source_splits)) != len(self.source_splits):
            raise ValueError(
                f"source_splits: need distinct splits of {sorted(manifest['splits'])}, got {source_splits!r}"
            )
        self.target_holdout = as_real(target_holdout, "target_holdout", low=0.0, high=1.0, open_high=True)
        if self.target_holdout > 0 and (target_split != "test" or target_data_dir is not None):
            raise ValueError("target_holdout: holds test tactile clouds out of the target stream, so it "
                             f"needs target_split='test' and no target_data_dir (got {target_split!r}, "
                             f"{target_data_dir!r})")
        self.target_data_dir = target_data_dir
        self._target_splits: dict[str, dict] = {}
        if target_data_dir is not None:
            other = load_manifest(target_data_dir, name="target_data_dir")
            if list(other["class_names"]) != self.class_names:
                raise ValueError(
                    f"target_data_dir: class names {other['class_names']} differ from data_dir's "
                    f"{self.class_names}"
                )
            if train_on == "tactile" and "train" not in other["splits"]:
                raise ValueError(f"target_data_dir: train_on='tactile' needs its 'train' split, "
                                 f"{target_data_dir} has {sorted(other['splits'])}")
            missing = [x for x in target_split.split("+") if x not in other["splits"]]
            if missing:
                raise ValueError(
                    f"target_data_dir: no {missing[0]!r} split in {target_data_dir} "
                    f"(it has {sorted(other['splits'])}); set target_split to one of them"
                )
            for x in target_split.split("+") + (["train"] if train_on == "tactile" else []):
                check_split(other, target_data_dir, x, "target_data_dir")
        # the splits training reads, checked now rather than when the first batch is drawn
        for x in self.source_splits + ([] if target_data_dir is not None else target_split.split("+")):
            check_split(manifest, data_dir, x)

    def dataset(
        self, split: str, modality: str, with_label: bool = True, train: bool | None = None,
        keep: np.ndarray | None = None, with_index: bool = False, with_group: bool = False,
    ) -> CloudDataset:
        """Clouds of one split and modality; ``train`` (default: ``split == "train"``) turns on the
        random yaw augmentation; ``keep`` (a boolean mask over the split's clouds) selects some of them;
        ``with_index`` adds each item's position in the dataset (``"index"``), ``with_group`` the id of the
        object instance the cloud was taken of (``"group"``).

        Shapes:
            keep (n_clouds,) bool or None
        """
        d = self._split(split)
        clouds, labels, scales = modality_clouds(d, modality, self.units == "metres")
        groups = np.asarray(d[f"{modality}_instance"])
        if keep is not None:
            idx = np.flatnonzero(keep)
            clouds, labels, groups = [clouds[i] for i in idx], labels[idx], groups[idx]
            scales = None if scales is None else scales[idx]
        return CloudDataset(
            clouds,
            labels,
            train=split == "train" if train is None else train,
            normalize=self.normalize,
            rotate_z=self.rotate_z,
            seed=self.seed,
            scales=scales,
            with_label=with_label,
            with_index=with_index,
            groups=groups,
            with_group=with_group,
        )

    def target_dataset(self) -> CloudDataset:
        """The unlabelled, yaw-augmented tactile clouds of the target stream (``target_split`` of
        ``data_dir``, or of ``target_data_dir`` when set), less the ``target_holdout`` test clouds. Items
        are ``{"points", "index", "group"}``: the index lets a model keep per-cloud pseudo-labels
        (:meth:`~vtlearn.models.xavtnet.XAVTNet.label_target`), and the group, the id of the object instance
        the cloud was touched on (no label: which touches fell on one object), lets it vote them per object
        (``pseudo_label_groups``)."""
        if self.target_data_dir is not None:
            return self._target_data_dataset(self.target_split, with_label=False, with_index=True,
                                             with_group=True)
        if self.target_holdout > 0:
            return self.dataset("test", "tactile", with_label=False, train=True, keep=~self.holdout_mask(),
                                with_index=True, with_group=True)
        if "+" in self.target_split:  # one stream over both splits, indexed 0..n-1 across them
            return self._tactile_dataset([self._split(x) for x in self.target_split.split("+")],
                                         with_label=False, with_index=True, with_group=True)
        return self.dataset(self.target_split, "tactile", with_label=False, train=True, with_index=True,
                            with_group=True)

    def holdout_mask(self) -> np.ndarray:
        """Which tactile clouds of the test split are held out of the target stream (``target_holdout``).

        Shapes:
            -> (n_test_tactile,) bool
        """
        inst = np.asarray(self._split("test")["tactile_instance"])
        mask = np.zeros(len(inst), dtype=bool)
        if self.target_holdout == 0:
            return mask
        rng = np.random.default_rng([self.seed, 7300])
        for k in np.unique(inst):
            idx = np.flatnonzero(inst == k)
            if len(idx) < 2:
                continue
            n = min(max(int(round(self.target_holdout * len(idx))), 1), len(idx) - 1)
            mask[rng.choice(idx, size=n, replace=False)] = True
        return mask

    def target_dataloader(self, shuffle: bool = True) -> DataLoader:
        """The unlabelled target stream on its own (:meth:`target_dataset`), e.g. for
        :meth:`~vtlearn.models.xavtnet.XAVTNet.adapt_bn_statistics`."""
        return self._loader(self.target_dataset(), shuffle=shuffle, batch_size=self.target_batch_size)

    def _target_data_dataset(self, split: str, with_label: bool, with_index: bool = False,
                             with_group: bool = False) -> CloudDataset:
        """Yaw-augmented tactile clouds of ``target_data_dir``'s ``split`` (``"a+b"``: both, one stream)."""
        return self._tactile_dataset([self._target_data_split(x) for x in split.split("+")],
                                     with_label=with_label, with_index=with_index, with_group=with_group)

    def _tactile_dataset(self, splits: list[dict], with_label: bool, with_index: bool,
                         with_group: bool = False) -> CloudDataset:
        """Yaw-augmented tactile clouds of the loaded ``splits`` in one dataset, in that order
        (``with_group``: with each cloud's object instance, numbered uniquely across splits)."""
        metres = self.units == "metres"
        parts = [modality_clouds(d, "tactile", metres) for d in splits]
        clouds = [c for part in parts for c in part[0]]
        labels = np.concatenate([part[1] for part in parts])
        scales = np.concatenate([part[2] for part in parts]) if metres else None
        groups = np.concatenate([np.asarray(d["tactile_instance"]) for d in splits])
        return CloudDataset(clouds, labels, train=True, normalize=self.normalize, rotate_z=self.rotate_z,
                            seed=self.seed, scales=scales, with_label=with_label, with_index=with_index,
                            groups=groups, with_group=with_group)

    def _target_data_split(self, split: str) -> dict:
        """A split of ``target_data_dir``, loaded (and checksummed with ``verify``) once."""
        if split not in self._target_splits:
            self._target_splits[split] = load_split(self.target_data_dir, split, self.verify,
                                                    name="target_data_dir")
        return self._target_splits[split]

    def source_train_dataset(self) -> CloudDataset:
        """Labelled, yaw-augmented visual clouds of ``source_splits``; fused over ``source_views`` views and
        thinned to ``source_points`` when they are set."""
        metres = self.units == "metres"
        clouds, labels, scales, groups, unit_scales = [], [], [], [], []
        for split in self.source_splits:
            d = self._split(split)
            c, lab, sc = modality_clouds(d, "visual", metres)
            clouds += c
            labels.append(lab)
            scales.append(sc)
            groups.append(d["visual_instance"])
            unit_scales.append(instance_scales(d, d["visual_instance"]))
        labels, groups = np.concatenate(labels), np.concatenate(groups)
        scales = np.concatenate(scales) if metres else None
        subsample, pitch = self.source_points, None
        if self.source_touch:
            from vtlearn.sim_data.sensors import SENSORS

            subsample = subsample or (30, 120)
            # clouds are touched in the instance's canonical frame: the pitch in canonical units
            pitch = SENSORS["xela_4x4"].pitch / np.concatenate(unit_scales)
        return CloudDataset(clouds, labels, train=True, normalize=self.normalize, rotate_z=self.rotate_z,
                            seed=self.seed, scales=scales, subsample=subsample, fuse_views=self.source_views,
                            groups=groups, touch_pitch=pitch)

    def source_class_prior(self) -> np.ndarray:
        """The class frequencies of the labelled visual training clouds (``source_splits``), the prior
        that class-balanced predictions on the target stream assume
        (:mod:`vtlearn.models.components.class_balance`).

        Shapes:
            -> (num_classes,) summing to 1
        """
        labels = np.asarray(self.source_train_dataset().labels)
        return np.bincount(labels, minlength=self.num_classes) / len(labels)

    def train_dataloader(self) -> CombinedLoader | DataLoader:
        """Source and target streams (``train_on="visual"``), or the labelled tactile training clouds
        (``train_on="tactile"``)."""
        if self.train_on == "tactile":
            return self.labelled_target_train_dataloader()
        source = self._loader(self.source_train_dataset(), shuffle=True)
        target = self.target_dataloader(shuffle=True)
        return CombinedLoader({"source": source, "target": target}, mode="max_size_cycle")

    def val_dataloader(self) -> DataLoader:
        return self._loader(self.dataset("val", "tactile"), shuffle=False)

    def test_dataloader(self) -> DataLoader:
        """Labelled tactile clouds of the test split (only the ``target_holdout`` ones when it is set)."""
        if self.target_holdout > 0:
            return self._loader(self.dataset("test", "tactile", keep=self.holdout_mask()), shuffle=False)
        return self._loader(self.dataset("test", "tactile"), shuffle=False)

    def predict_dataloader(self) -> DataLoader:
        """``trainer.predict`` classifies the test tactile clouds (the cross-modal target domain)."""
        return self.test_dataloader()

    def source_test_dataloader(self) -> DataLoader:
        """Labelled visual clouds of the test instances."""
        return self._loader(self.dataset("test", "visual"), shuffle=False)

    def labelled_target_train_dataloader(self) -> DataLoader:
        """Labelled, yaw-augmented tactile training clouds. Only for the train-on-target upper bound
        (``bench crossmodal --variants tactile_oracle``, ``train_on="tactile"``); UDA training never sees
        tactile labels. With ``target_data_dir`` set, its labelled ``train`` tactile clouds are added. With
        ``target_holdout`` set, they are the target stream's own clouds, labelled (the test objects' touches
        that are not held out), so the bound is that of the thesis's twelve-object protocol."""
        if self.target_holdout > 0:
            return self._loader(self.dataset("test", "tactile", train=True, keep=~self.holdout_mask()),
                                shuffle=True)
        ds = self.dataset("train", "tactile")
        if self.target_data_dir is not None:
            from torch.utils.data import ConcatDataset

            ds = ConcatDataset([ds, self._target_data_dataset("train", with_label=True)])
        return self._loader(ds, shuffle=True)

    def source_val_dataloader(self) -> DataLoader:
        return self._loader(self.dataset("val", "visual"), shuffle=False)
