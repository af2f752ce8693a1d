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


def _bad_manifest(name: str, data_dir, what: str) -> ValueError:
    return ValueError(
        f"{name}: manifest.json in {data_dir} {what}; the dataset is damaged or not a `vtlearn gen-data` "
        "dataset (regenerate it)"
    )


def load_manifest(data_dir: str | Path, name: str = "data_dir") -> dict:
    """The ``manifest.json`` of a `gen-data` dataset, with its structure checked.

    Raises:
        FileNotFoundError: ``data_dir`` or its manifest does not exist.
        ValueError (naming ``name``, the caller's argument): the manifest is not JSON, not an object, lacks
            ``class_names`` / ``splits`` / ``shards``, lists no split, or lists a malformed shard.
    """
    if data_dir is None or not isinstance(data_dir, (str, Path)) or str(data_dir) == "":
        raise ValueError(f"{name}: expected a dataset directory, got {data_dir!r}")
    path = Path(data_dir) / "manifest.json"
    if not path.is_file():
        where = "" if Path(data_dir).is_dir() else " (no such directory)"
        raise FileNotFoundError(
            f"{name}: no manifest.json in {data_dir}{where} (run `vtlearn gen-data` first, "
            "or finish an interrupted run by rerunning it)"
        )
    try:
        manifest = json.loads(path.read_text())
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise _bad_manifest(name, data_dir, f"is not readable JSON ({exc})") from None
    if not isinstance(manifest, dict):
        raise _bad_manifest(name, data_dir, f"is a JSON {type(manifest).__name__}, not an object")
    for key, typ in (("class_names", list), ("splits", dict), ("shards", list)):
        if key not in manifest:
            raise _bad_manifest(name, data_dir, f"has no {key!r} key")
        if not isinstance(manifest[key], typ):
            raise _bad_manifest(name, data_dir, f"has a {key!r} that is not a JSON {typ.__name__}")
    if not manifest["class_names"] or not all(isinstance(c, str) for c in manifest["class_names"]):
        raise _bad_manifest(name, data_dir, "has no class names (need a list of strings)")
    if not manifest["splits"]:
        raise ValueError(f"{name}: the dataset in {data_dir} has no splits (its manifest.json lists none); "
                         "regenerate it")
    for i, meta in enumerate(manifest["shards"]):
        if not isinstance(meta, dict) or not all(isinstance(meta.get(k), str) for k in ("file", "split")):
            raise _bad_manifest(name, data_dir, f"has a malformed shard entry {i} (needs 'file' and 'split')")
        f = Path(meta["file"])
        if f.is_absolute() or ".." in f.parts:
            raise _bad_manifest(name, data_dir, f"lists shard {meta['file']!r} outside the dataset directory")
    return manifest


def read_class_names(manifest_json: str | Path, name: str = "class_names") -> list[str]:
    """The ``class_names`` of a crossmodal dataset's ``manifest.json`` file (an xAVTNet's class names).

    Raises:
        FileNotFoundError (naming ``name``): no such file.
        ValueError (naming ``name``): not JSON, or no non-empty ``class_names`` list of strings.
    """
    path = Path(manifest_json)
    if not path.is_file():
        raise FileNotFoundError(f"{name}: no manifest at {path}")
    try:
        names = json.loads(path.read_text())["class_names"]
    except (OSError, UnicodeDecodeError, json.JSONDecodeError, KeyError, TypeError):
        names = None
    if not isinstance(names, list) or not names or not all(isinstance(c, str) for c in names):
        raise ValueError(f"{name}: {path} has no 'class_names' list (a crossmodal manifest.json)")
    return list(names)


# the commands that make each dataset kind, for the messages that refuse a dataset of the wrong kind
DATASET_MAKERS = {
    "reconstruction": "`vtlearn gen-data reconstruction`",
    "crossmodal": "`vtlearn gen-data crossmodal`",
    "tactile-episodes": "`vtlearn gen-episodes`",
}


def check_kind(manifest: dict, data_dir, kind: str | tuple[str, ...] | list[str],
               name: str = "data_dir") -> str:
    """The dataset kind of ``manifest`` (its ``"kind"``), or a ValueError naming ``name`` (``data_dir``,
    ``--data``) when it is not ``kind`` (one kind or several accepted ones), saying which was found, which
    is needed and which command makes each: a ``gen-episodes`` folder has no dense clouds, a
    ``gen-data reconstruction`` one no visual clouds."""
    kinds = (kind,) if isinstance(kind, str) else tuple(kind)
    found = manifest.get("kind")
    if found not in kinds:
        makers = [DATASET_MAKERS[k] for k in kinds if k in DATASET_MAKERS]
        notes = [f"one made by {' or '.join(makers)}"] if makers else []
        if found in DATASET_MAKERS:
            notes.append(f"this one was made by {DATASET_MAKERS[found]}")
        note = f" ({'; '.join(notes)})" if notes else ""
        need = " or ".join(repr(k) for k in kinds)
        raise ValueError(f"{name}: {data_dir} is a {found!r} dataset, need {need}{note}")
    return found


def split_is_empty(manifest: dict, split: str) -> bool:
    """True when the manifest lists no shard of ``split``, or only shards that hold no instance (for a
    ``tactile-episodes`` set: no tactile cloud), from the counts recorded with each shard."""
    metas = [m for m in manifest["shards"] if m["split"] == split]
    key = "tactile_clouds" if manifest.get("kind") == "tactile-episodes" else "instances"
    counts = [m.get(key) for m in metas]
    return not metas or all(isinstance(c, int) and c == 0 for c in counts)


def empty_split_error(manifest: dict, data_dir, split: str, name: str = "data_dir") -> ValueError:
    """The ValueError (naming ``name``) for a ``split`` of ``data_dir`` that holds no samples, with the cause
    and the fix: for ``gen-data`` datasets, a ``--splits`` fraction of 0 or too few ``--per-category``
    instances for the split fractions."""
    config = manifest.get("config") if isinstance(manifest.get("config"), dict) else {}
    per = config.get("per_category")
    fractions = config.get("split_fractions")
    splits = ("train", "val", "test")  # vtlearn.sim_data.writer.SPLITS, the order of --splits
    zero = (isinstance(fractions, list) and len(fractions) == len(splits) and split in splits
            and fractions[splits.index(split)] == 0)
    if manifest.get("kind") in ("reconstruction", "crossmodal") and zero:
        why = "its --splits fraction is 0, so it was made empty on purpose"
        fix = f"regenerate with a {split} fraction above 0 in --splits, or use another split"
    elif manifest.get("kind") in ("reconstruction", "crossmodal") and isinstance(per, int):
        fix = "regenerate with more --per-category"
        try:
            from vtlearn.sim_data.writer import min_per_category

            fix += f" (at least {min_per_category([float(f) for f in config['split_fractions']])})"
        except (KeyError, TypeError, ValueError):
            pass
        why = f"{per} instance(s) per category left none for it"
    elif manifest.get("kind") == "tactile-episodes":
        why = ("no episode gave a tactile cloud: its source split had no instances, or every prefix had "
               "fewer than --min-points points")
        fix = "regenerate it with `vtlearn gen-episodes` from a split with instances"
    else:
        why, fix = "its manifest lists no samples for it", "regenerate the dataset"
    return ValueError(f"{name}: split {split!r} of {data_dir} is empty ({why}); {fix}")


def check_split(manifest: dict, data_dir, split: str, name: str = "data_dir") -> None:
    """A ValueError unless ``split`` is a split of the manifest (naming ``split``) that holds samples
    (naming ``name``, see :func:`empty_split_error`). Reads only the manifest, so a command can check its
    data before any long work."""
    if not isinstance(split, str) or split not in manifest["splits"]:
        raise ValueError(f"split: {split!r} not in {sorted(manifest['splits'])}")
    if split_is_empty(manifest, split):
        raise empty_split_error(manifest, data_dir, split, name)


# splits of at least this many bytes of shards load under a progress bar (sha256 and decompression take
# seconds per GB)
PROGRESS_BYTES = 256 << 20


def load_split(
    data_dir: str | Path, split: str, verify: bool = True, name: str = "data_dir",
    kind: str | tuple[str, ...] | None = None, manifest: dict | None = None,
) -> dict[str, np.ndarray]:
    """Concatenate the shards of ``split``; ``tactile_offsets`` are rebased. Checks sha256 if ``verify``.

    Errors name ``name`` (the caller's argument for ``data_dir``): a FileNotFoundError for a shard listed
    in the manifest but missing, a ValueError for a checksum mismatch or a shard numpy cannot read, for a
    split that holds no samples (``split 'test' of DIR is empty (...)``) and, with ``kind`` (one dataset
    kind or several accepted ones, see :func:`check_kind`), for a dataset of another kind. A split the
    manifest does not list is a ValueError naming ``split``. Splits of :data:`PROGRESS_BYTES` or more load
    under a progress bar. ``manifest``: the folder's manifest, when the caller has already read it with
    :func:`load_manifest` (it is not read again; the kind and split checks still run).
    """
    from vtlearn.sim_data.writer import sha256_file

    if manifest is None:
        manifest = load_manifest(data_dir, name)
    if kind is not None:
        check_kind(manifest, data_dir, kind, name)
    check_split(manifest, data_dir, split, name)
    from tqdm.auto import tqdm

    data_dir_path = Path(data_dir)
    metas = [m for m in manifest["shards"] if m["split"] == split]
    files = [data_dir_path / m["file"] for m in metas]
    size = sum(f.stat().st_size for f in files if f.is_file())
    parts: dict[str, list[np.ndarray]] = {}
    base = 0
    for meta in tqdm(metas, desc=f"loading {split} of {data_dir_path.name}", unit="shard", leave=False,
                     disable=size < PROGRESS_BYTES):
        path = data_dir_path / meta["file"]
        if not path.is_file():
            raise FileNotFoundError(
                f"{name}: shard {meta['file']} listed in the manifest is missing from {data_dir}; "
                "regenerate the dataset (or rerun the interrupted `vtlearn gen-data`)"
            )
        if verify and sha256_file(path) != meta.get("sha256"):
            raise ValueError(f"{name}: shard {path} does not match its manifest sha256 (corrupt or edited)")
        try:
            with np.load(path, allow_pickle=False) as z:
                arrays = {k: z[k] for k in z.files}
        except Exception as exc:  # BadZipFile, zlib / CRC errors, truncated headers, pickled arrays
            raise ValueError(
                f"{name}: shard {meta['file']} is unreadable ({type(exc).__name__}: {exc}); regenerate it "
                "(rerun `vtlearn gen-data`)"
            ) from None
        for k, a in arrays.items():
            if k == "tactile_offsets":
                a = a[1:] + base if parts.get(k) else a + base
                base = int(a[-1])
            parts.setdefault(k, []).append(a)
    out = {k: np.concatenate(v) for k, v in parts.items()}
    samples = "tactile_label" if manifest.get("kind") == "tactile-episodes" else "label"
    if len(out.get(samples, ())) == 0:  # shards whose side counts were missing or wrong
        raise empty_split_error(manifest, data_dir, split, name)
    return out


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

    def _open_dataset(
        self, data_dir: str | Path, verify: bool, kind: str | tuple[str, ...] | None = None
    ) -> dict:
        """Read and check ``data_dir``'s manifest; ``kind``: the dataset kind(s) accepted (a ValueError
        naming ``data_dir`` for another)."""
        manifest = load_manifest(data_dir)
        if kind is not None:
            check_kind(manifest, data_dir, kind)
        # an empty split is refused where it is read (load_split), so a dataset whose unused test split is
        # empty still trains; subclasses check the splits they train on here (CrossModalDataModule)
        self.data_dir, self.verify = data_dir, verify
        self._manifest = manifest
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
        # an empty split (a zero --splits fraction, or too few instances) is loaded, and refused, only if used
        for split in ("train", "val", "test"):
            if not (split in self._manifest["splits"] and split_is_empty(self._manifest, split)):
                self._split(split)
