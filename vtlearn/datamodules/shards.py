"""Reading `vtlearn gen-data` datasets: manifest, sha256 check, one split's arrays, cloud transforms.

Batching convention for every vtlearn datamodule: variable-size clouds are padded with zeros to the
largest cloud in the batch, ``(B, Nmax, 3)`` float32, plus ``lengths`` ``(B,)`` int64 (pytorch3d style,
see :func:`vtlearn.geometry.pad_clouds`).
"""

from __future__ import annotations

import json
from pathlib import Path

import lightning.pytorch as pl
import numpy as np
import torch

from vtlearn.geometry import pad_clouds


def load_manifest(data_dir: str | Path) -> dict:
    path = Path(data_dir) / "manifest.json"
    if not path.exists():
        raise FileNotFoundError(
            f"data_dir: no manifest.json in {data_dir} (run `vtlearn gen-data` first, "
            "or finish an interrupted run by rerunning it)"
        )
    return json.loads(path.read_text())


def load_split(data_dir: str | Path, split: str, verify: bool = True) -> dict[str, np.ndarray]:
    """Concatenate the shards of ``split``; ``tactile_offsets`` are rebased. Checks sha256 if ``verify``."""
    from vtlearn.sim_data.writer import sha256_file

    data_dir = Path(data_dir)
    manifest = load_manifest(data_dir)
    if split not in manifest["splits"]:
        raise ValueError(f"split: {split!r} not in {sorted(manifest['splits'])}")
    parts: dict[str, list[np.ndarray]] = {}
    base = 0
    for meta in manifest["shards"]:
        if meta["split"] != split:
            continue
        path = data_dir / meta["file"]
        if verify and sha256_file(path) != meta["sha256"]:
            raise ValueError(f"data_dir: shard {path} does not match its manifest sha256 (corrupt or edited)")
        with np.load(path, allow_pickle=False) as z:
            for k in z.files:
                a = z[k]
                if k == "tactile_offsets":
                    a = a[1:] + base if parts.get(k) else a + base
                    base = int(a[-1])
                parts.setdefault(k, []).append(a)
    return {k: np.concatenate(v) for k, v in parts.items()}


def split_clouds(points: np.ndarray, offsets: np.ndarray) -> list[np.ndarray]:
    return [points[offsets[i] : offsets[i + 1]] for i in range(len(offsets) - 1)]


def rotation_z(theta: float) -> np.ndarray:
    c, s = np.cos(theta), np.sin(theta)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def normalize_cloud(points: np.ndarray, mode: str) -> np.ndarray:
    """``none``; ``center``: subtract the centroid; ``unit_sphere``: centre, then max radius 1."""
    if mode == "none":
        return points
    c = points - points.mean(0)
    if mode == "center":
        return c
    if mode == "unit_sphere":
        r = np.linalg.norm(c, axis=1).max()
        return c / r if r > 0 else c
    raise ValueError(f"normalize: expected 'none', 'center' or 'unit_sphere', got {mode!r}")


def random_voxel_subsample(
    points: np.ndarray, n_min: int, n_max: int, rng: np.random.Generator, iters: int = 12
) -> np.ndarray:
    """Random voxel-grid subsampling to a size drawn uniformly from ``[n_min, n_max]``.

    A target ``n`` is drawn, then the voxel size is bisected (in log scale, with a random grid offset)
    to the coarsest grid with at least ``n`` occupied voxels; each voxel gives the centroid of its
    points (PCL VoxelGrid), and a random ``n`` of those are kept. Clouds with fewer than ``n``
    points are returned whole.
    """
    if not 1 <= n_min <= n_max:
        raise ValueError(f"n_min/n_max: need 1 <= n_min <= n_max, got {n_min}, {n_max}")
    n = int(rng.integers(n_min, n_max + 1))
    if len(points) <= n:
        return points.copy()
    offset = rng.uniform(0, 1, size=3)
    extent = float(np.max(points.max(0) - points.min(0))) or 1.0
    lo, hi = np.log(extent * 1e-4), np.log(extent)

    def voxels(v):
        keys = np.floor(points / v + offset).astype(np.int64)
        _, inv = np.unique(keys, axis=0, return_inverse=True)
        return inv.reshape(-1)

    for _ in range(iters):
        mid = (lo + hi) / 2
        if voxels(np.exp(mid)).max() + 1 >= n:
            lo = mid
        else:
            hi = mid
    inv = voxels(np.exp(lo))
    m = inv.max() + 1
    sums = np.zeros((m, 3))
    np.add.at(sums, inv, points)
    cents = sums / np.bincount(inv, minlength=m)[:, None]
    if len(cents) < n:  # the bisection bracket ended below n: fall back to raw points
        return points[rng.choice(len(points), size=n, replace=False)]
    return cents[rng.choice(len(cents), size=n, replace=False)]


def collate_clouds(items: list[dict], cloud_keys: tuple[str, ...] = ("points",)) -> dict[str, torch.Tensor]:
    """Stack a list of per-sample dicts; the clouds named in ``cloud_keys`` are padded (+ ``lengths``).

    With one cloud key the lengths are ``lengths``; with several, ``<key>_lengths`` for all but the first.
    """
    out: dict[str, torch.Tensor] = {}
    for j, key in enumerate(cloud_keys):
        pts, lengths = pad_clouds([it[key] for it in items])
        out[key] = pts
        out["lengths" if j == 0 else f"{key}_lengths"] = lengths
    for key in items[0]:
        if key in cloud_keys:
            continue
        vals = [it[key] for it in items]
        if isinstance(vals[0], np.ndarray):
            out[key] = torch.as_tensor(np.stack(vals), dtype=torch.float32)
        else:
            out[key] = torch.as_tensor(vals, dtype=torch.int64)
    return out


def worker_rng(train: bool, seed: int, index: int) -> np.random.Generator:
    """Training draws from torch's RNG (seeded by Lightning per worker); evaluation is fixed per index."""
    if train:
        return np.random.default_rng(int(torch.randint(0, 2**62, (1,)).item()))
    return np.random.default_rng([seed, index])


class ShardedDataModule(pl.LightningDataModule):
    """Shared base of the vtlearn datamodules: reads a ``gen-data`` manifest once and caches its splits.

    Subclasses call :meth:`_open_dataset` in ``__init__``; ``class_names`` and ``num_classes`` come from the
    manifest, and :meth:`_split` loads (and, with ``verify``, checksums) a split on first use.
    """

    def _open_dataset(self, data_dir: str | Path, verify: bool, kind: str | None = None) -> dict:
        manifest = load_manifest(data_dir)
        if kind is not None and manifest.get("kind") != kind:
            raise ValueError(f"data_dir: {data_dir} is a {manifest.get('kind')!r} dataset, need {kind!r}")
        self.data_dir, self.verify = data_dir, verify
        self.class_names: list[str] = list(manifest["class_names"])
        self.num_classes: int = len(self.class_names)
        self._splits: dict[str, dict] = {}
        return manifest

    def _split(self, split: str) -> dict:
        if split not in self._splits:
            self._splits[split] = load_split(self.data_dir, split, self.verify)
        return self._splits[split]

    def _loader(self, ds, shuffle: bool, collate_fn=None, persistent_workers: bool = True,
                batch_size: int | None = None):
        """A ``DataLoader`` over ``ds`` with the subclass's ``batch_size`` (unless given) and ``num_workers``.

        ``collate_fn`` defaults to :func:`collate_clouds`; ``persistent_workers`` keeps worker processes
        between epochs (only when there are workers).
        """
        from torch.utils.data import DataLoader

        return DataLoader(
            ds,
            batch_size=self.batch_size if batch_size is None else batch_size,
            shuffle=shuffle,
            num_workers=self.num_workers,
            collate_fn=collate_clouds if collate_fn is None else collate_fn,
            persistent_workers=persistent_workers and self.num_workers > 0,
        )

    def setup(self, stage: str | None = None) -> None:
        for split in ("train", "val", "test"):
            self._split(split)
