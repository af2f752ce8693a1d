"""Sharded, atomic, resumable dataset writer for `vtlearn gen-data` (thesis ch.7 7.3.1, ch.8 8.3.1 data).

Two dataset kinds:

* ``reconstruction`` (ACTOR, ch.8): per instance a dense cloud of 2048 surface points (the training
  target) plus a tactile cloud from simulated touches and pinches (evaluation input).
* ``crossmodal`` (xAVTNet, ch.7): per instance ``views`` partial visual clouds of 1024 points from the
  simulated RGB-D camera, labelled by category, and ``tactile_clouds`` tactile clouds of 30-120 points
  whose labels are kept for evaluation only.

All clouds are in the instance's canonical frame (z-up, centred, unit cube; metres = x * scale_m).

Layout of ``out_dir``::

    config.json                      the generation config (a rerun must use the same one)
    <split>-<k:05d>.npz              a shard: whole instances of one split (allow_pickle=False)
    <split>-<k:05d>.npz.json         sidecar written after the shard: its sha256 and counts
    manifest.json                    written last: class names, splits, every shard with sha256

Splits are by instance: an instance, and every sample drawn from it, lives in exactly one split.
Every shard is a pure function of ``(config, split, shard index)``: its own seed sequence, no clock, a
deterministic zip layout, so a rerun reproduces it byte for byte. Files are written to a temporary
name and renamed, so a kill never leaves a corrupt shard. A rerun keeps shards whose sidecar matches
their sha256 and regenerates the rest.

Variable-size clouds are stored flat with offsets: ``tactile_points (T, 3)`` and
``tactile_offsets (n + 1,)``; cloud i is ``tactile_points[offsets[i]:offsets[i+1]]``.
"""

from __future__ import annotations

import json
import logging
from collections import Counter
from collections.abc import Mapping
from concurrent.futures import as_completed
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np

from vtlearn.bench_utils import host_info
from vtlearn.io import atomic_path, atomic_write_npz, remove_stale_temporaries_in, sha256_file
from vtlearn.sim_data.shapes import CATEGORIES, check_out_dir, generate_shape, instance_seed
from vtlearn.validation import as_bool, as_int, as_real
from vtlearn.worker_pool import worker_pool

log = logging.getLogger(__name__)

FORMAT = "vtlearn-sim/1"
SPLITS = ("train", "val", "test")
KINDS = ("reconstruction", "crossmodal")
#: the touch sampler generation uses; see ``GenConfig.touch_sampler``
TOUCH_SAMPLER = 2


@dataclass
class GenConfig:
    """Everything that determines a dataset's bytes (saved as config.json).

    Field checks run on construction (``ValueError`` naming the field): counts ``per_category``,
    ``shard_size``, ``dense_points``, ``touches``, ``views``, ``visual_points``, ``image_width``,
    ``image_height``, ``tactile_clouds`` are integers >= 1, ``pinches`` and ``seed`` integers >= 0,
    ``sections`` >= 8, ``keep_split`` a bool that needs a ``mesh_source``, ``transparency`` a bool.
    :meth:`validate` (called by :func:`generate_dataset`) also checks ``sensor`` and that ``mesh_source``
    is ``"procedural"``, ``"pybullet_data"`` or an existing directory.
    ``categories=None`` means all: the 12 procedural ones, or every category of ``mesh_source`` with a usable
    mesh (:func:`generate_dataset` records the list it found).
    """

    kind: str = "reconstruction"
    categories: list[str] | None = field(default_factory=lambda: list(CATEGORIES))
    per_category: int = 10
    seed: int = 0
    split_fractions: list[float] = field(default_factory=lambda: [0.7, 0.15, 0.15])
    shard_size: int = 16
    sections: int = 48
    dense_points: int = 2048
    sensor: str = "xela_4x4"
    touches: int = 40  # reconstruction: touches per instance for its tactile cloud
    pinches: int = 10  # reconstruction: pinches per instance
    position_noise: float = 0.0  # tactile noise (m); 0 = exact contact points
    dropout: float = 0.0
    views: int = 4  # crossmodal: visual clouds per instance
    visual_points: int = 1024
    image_width: int = 320
    image_height: int = 240
    depth_noise: bool = True
    # crossmodal: the camera's glass failure (:class:`~vtlearn.sim_data.camera.TransparencyModel`) applies to
    # the instances drawn as glass (shapes.TRANSPARENT_PROB: every wineglass, half the bottles and jars, a
    # third of the cups); False renders every instance opaque, so each class has a dense visual source.
    # The draw of which instance is glass is kept, so the shapes are those of the default.
    transparency: bool = True
    # crossmodal: segment each view by the object's world bounding box grown by this fraction of its
    # largest extent (the PCL segmentation of thesis 7.3.1); None keeps every pixel of the body's mask,
    # including the see-through returns of transparent objects (datasets made before this option).
    visual_crop_margin: float | None = 0.05
    tactile_clouds: int = 4  # crossmodal: tactile clouds per instance
    tactile_min_points: int = 30
    tactile_max_points: int = 120
    mesh_source: str = "procedural"  # or a directory of meshes, one subfolder per category
    # keep mesh_source's own train/test split (ModelNet): see plan_instances; per_category then caps each
    # of a category's source splits
    keep_split: bool = False
    # the version of the touch sampler (vtlearn.sim_data.tactile.bbox_faces): 1 pressed the +x and +y faces
    # from inside the box in place of the -x and -y faces; a folder made with 1 is refused on resume
    touch_sampler: int = TOUCH_SAMPLER

    def __post_init__(self):
        if self.categories is None and self.mesh_source == "procedural":
            self.categories = list(CATEGORIES)
        self._check_fields()

    def validate(self) -> None:
        """All field checks plus ``sensor`` and ``mesh_source`` (ValueError / FileNotFoundError)."""
        self._check_fields()
        from vtlearn.sim_data.sensors import get_sensor

        try:
            get_sensor(self.sensor)
        except ValueError as exc:
            raise ValueError(f"sensor: {exc}") from None
        if not isinstance(self.mesh_source, str | Path) or not str(self.mesh_source):
            raise ValueError(f"mesh_source: need 'procedural', 'pybullet_data' or a directory, got "
                             f"{self.mesh_source!r}")
        src = str(self.mesh_source)
        if src not in ("procedural", "pybullet_data") and not Path(src).is_dir():
            raise FileNotFoundError(f"mesh_source: no such mesh directory {self.mesh_source}")

    def _check_fields(self) -> None:
        if self.kind not in KINDS:
            raise ValueError(f"kind: expected one of {KINDS}, got {self.kind!r}")
        if self.touch_sampler != TOUCH_SAMPLER:
            raise ValueError(f"touch_sampler: this vtlearn generates with touch sampler {TOUCH_SAMPLER} "
                             f"only, got {self.touch_sampler!r} (sampler 1 pressed the -x and -y faces from "
                             "inside)")
        if self.mesh_source == "procedural":
            bad = [c for c in self.categories or [] if c not in CATEGORIES]
            if bad or not self.categories:
                raise ValueError(f"categories: unknown {bad} or empty; expected some of {CATEGORIES}")
        elif self.categories is not None and (
                not isinstance(self.categories, list | tuple) or not self.categories
                or not all(isinstance(c, str) and c for c in self.categories)):
            raise ValueError(f"categories: need a non-empty list of category names or None (all), got "
                             f"{self.categories!r}")
        for name in ("per_category", "shard_size", "dense_points", "touches", "views", "visual_points",
                     "image_width", "image_height", "tactile_clouds"):
            as_int(getattr(self, name), name, 1)
        for name in ("pinches", "seed"):
            as_int(getattr(self, name), name, 0)
        as_int(self.sections, "sections", 8)
        f = np.asarray(self.split_fractions, dtype=float)
        if f.shape != (3,) or (f < 0).any() or not np.isclose(f.sum(), 1.0):
            raise ValueError(f"split_fractions: need three non-negative fractions summing to 1, got {f}")
        as_bool(self.keep_split, "keep_split")
        as_bool(self.transparency, "transparency")
        if self.keep_split and self.mesh_source == "procedural":
            raise ValueError("keep_split: keeps a mesh dataset's own train/test split, but procedural shapes "
                             "have none; use it with mesh_source (--meshes) a ModelNet40/10 tree")
        if self.keep_split and not f[0] + f[1] > 0:
            raise ValueError(f"keep_split: the train meshes are split into train and val in the ratio of the "
                             f"train and val split_fractions, which are both 0 (got {f})")
        if self.visual_crop_margin is not None:
            as_real(self.visual_crop_margin, "visual_crop_margin", low=0.0)
        as_int(self.tactile_min_points, "tactile_min_points")
        as_int(self.tactile_max_points, "tactile_max_points")
        if not self.tactile_min_points <= self.tactile_max_points:
            raise ValueError(
                "tactile_min_points/tactile_max_points: need 1 <= min <= max, "
                f"got {self.tactile_min_points}, {self.tactile_max_points}"
            )


# --------------------------------------------------------------------------- planning
def _split_counts(n: int, fractions) -> list[int]:
    """Instances per split for one category; every split with a positive fraction gets at least one
    instance when ``n`` allows, taken from the largest split."""
    counts = [int(np.floor(n * f)) for f in fractions]
    while sum(counts) < n:
        counts[int(np.argmax(fractions))] += 1
    for i, f in enumerate(fractions):
        if f > 0 and counts[i] == 0:
            j = int(np.argmax(counts))
            if counts[j] > 1:
                counts[j] -= 1
                counts[i] = 1
    return counts


def min_per_category(fractions) -> int:
    """The fewest instances per category for which every split with a positive fraction gets at least one
    (under :func:`_split_counts`): one per such split (3 for the default ``[0.7, 0.15, 0.15]``)."""
    n = 1
    while any(f > 0 and c == 0 for f, c in zip(fractions, _split_counts(n, fractions), strict=True)):
        n += 1
    return n


def _check_split_sizes(cfg: GenConfig, per_category: int, what: str = "per_category",
                       why: str = "") -> None:
    """A ValueError naming ``what`` when ``per_category`` instances leave a split with a positive fraction
    empty (every consumer of that split would then have no data); ``why`` says where the count comes from.
    With ``cfg.keep_split`` the instances are a category's train meshes, split into train and val only."""
    splits, fractions = SPLITS, cfg.split_fractions
    if cfg.keep_split:
        splits, fractions = SPLITS[:2], _train_val_fractions(cfg.split_fractions)
    counts = _split_counts(per_category, fractions)
    empty = [s for s, f, c in zip(splits, fractions, counts, strict=True) if f > 0 and c == 0]
    if empty:
        need = min_per_category(fractions)
        shown = ", ".join(f"{s} {f:g}" for s, f in zip(splits, cfg.split_fractions, strict=False))
        if cfg.keep_split:
            shown += "; keep_split splits the train meshes alone into train and val"
        raise ValueError(
            f"{what}: {why}{per_category} instance(s) per category leave split {empty[0]!r} with none "
            f"(split fractions {shown}); need at least {need}, one per split with a non-zero fraction, "
            f"or fractions that leave that split out (--splits, e.g. 1,0,0 for a training set only)"
        )


def _train_val_fractions(fractions) -> list[float]:
    """The train and val ``fractions``, rescaled to sum to 1: how ``keep_split`` splits the train meshes."""
    train, val = float(fractions[0]), float(fractions[1])
    return [train / (train + val), val / (train + val)]


def _kept_split_items(cfg: GenConfig, items: list[dict]) -> list[dict]:
    """The first ``per_category`` of each source split of one category's ``items``, in their order."""
    kept = {"train": 0, "test": 0}
    out = []
    for m in items:
        if kept[m["source_split"]] < cfg.per_category:
            kept[m["source_split"]] += 1
            out.append(m)
    return out


def _check_kept_split(cfg: GenConfig, category: str, items: list[dict], usable: str = "") -> None:
    """A ValueError naming ``keep_split`` when ``category``'s mesh ``items`` (with their ``source_split``)
    have no test or no train meshes, or too few train meshes for a val split with a positive fraction;
    ``usable`` is ``"usable "`` once the meshes were read."""
    n = Counter(m.get("source_split") for m in items)
    for split in ("test", "train"):
        if n[split] == 0:
            raise ValueError(f"keep_split: {cfg.mesh_source} has no {usable}{split} meshes of {category!r} "
                             f"({category}/{split}/*.off), so its own split cannot be kept; leave the "
                             "category out (--categories) or drop --keep-split")
    _check_split_sizes(cfg, n["train"], "keep_split",
                       f"{cfg.mesh_source} has only {n['train']} {usable}train mesh(es) of {category!r}: ")


def plan_instances(cfg: GenConfig, mesh_items: list[dict] | None = None) -> dict[str, list[dict]]:
    """Assign every instance to one split (by instance, deterministic per seed).

    Each category's instances are split by ``cfg.split_fractions`` in a seeded random order. With
    ``cfg.keep_split`` the mesh items keep their ``"source_split"``: every test mesh is a test instance,
    and the train meshes are split into train and val in the ratio of the train and val fractions (the
    test fraction is not used); ``per_category`` caps each source split of a category.
    """
    rng = np.random.default_rng([cfg.seed, 7919])
    plan: dict[str, list[dict]] = {s: [] for s in SPLITS}
    for label, cat in enumerate(cfg.categories):
        if mesh_items is None:
            items = [
                {"category": cat, "label": label, "index": i, "seed": instance_seed(cfg.seed, cat, i)}
                for i in range(cfg.per_category)
            ]
        else:
            cat_items = [m for m in mesh_items if m["category"] == cat]
            cat_items = _kept_split_items(cfg, cat_items) if cfg.keep_split else cat_items[: cfg.per_category]
            items = [dict(m, label=label, index=i) for i, m in enumerate(cat_items)]
        if cfg.keep_split:
            plan["test"] += [it for it in items if it["source_split"] == "test"]
            items = [it for it in items if it["source_split"] == "train"]
        order = rng.permutation(len(items))
        if cfg.keep_split:
            counts = [*_split_counts(len(items), _train_val_fractions(cfg.split_fractions)), 0]
        else:
            counts = _split_counts(len(items), cfg.split_fractions)
        start = 0
        for split, c in zip(SPLITS, counts, strict=True):
            plan[split] += [items[j] for j in sorted(order[start : start + c])]
            start += c
    for i, items in enumerate(plan.values()):
        for j, it in enumerate(items):
            it["instance"] = i * 1_000_000 + j
    return plan


def plan_shards(cfg: GenConfig, plan: dict[str, list[dict]]) -> list[dict]:
    jobs = []
    for split in SPLITS:
        items = plan[split]
        for k in range(0, len(items), cfg.shard_size):
            jobs.append(
                {
                    "name": f"{split}-{k // cfg.shard_size:05d}.npz",
                    "split": split,
                    "shard": k // cfg.shard_size,
                    "items": items[k : k + cfg.shard_size],
                }
            )
    return jobs


# --------------------------------------------------------------------------- deterministic I/O
def write_npz_atomic(path: Path, arrays: dict[str, np.ndarray]) -> str:
    """Write a shard with :func:`vtlearn.io.atomic_write_npz` (atomic, reproducible); return its sha256."""
    return sha256_file(atomic_write_npz(path, **arrays))


def write_json_atomic(path: Path, obj) -> None:
    with atomic_path(path) as tmp:
        tmp.write_text(json.dumps(obj, indent=1, sort_keys=True))


def _shard_done(out: Path, name: str) -> dict | None:
    shard, side = out / name, out / (name + ".json")
    if not (shard.exists() and side.exists()):
        return None
    try:
        meta = json.loads(side.read_text())
    except (json.JSONDecodeError, OSError):
        return None
    return meta if meta.get("sha256") == sha256_file(shard) else None


_MISSING = object()


def _short(value, limit: int = 60) -> str:
    text = json.dumps(value)
    return text if len(text) <= limit else text[: limit - 3] + "..."


def _difference(a, b) -> str:
    """How ``b`` (asked) differs from ``a`` (in the folder), readably: the items added and removed for two
    lists, the differing ends of two long strings, else both values (shortened)."""
    if isinstance(a, list) and isinstance(b, list):
        removed = [x for x in a if x not in b]
        added = [x for x in b if x not in a]
        if removed or added:
            parts = ([f"{_short(removed)} only in the folder"] if removed else []) + (
                [f"{_short(added)} only asked"] if added else [])
            return ", ".join(parts)
    if isinstance(a, str) and isinstance(b, str) and max(len(a), len(b)) > 60:
        k = next((i for i, (x, y) in enumerate(zip(a, b, strict=False)) if x != y), min(len(a), len(b)))
        start = max(0, k - 20)
        return f"...{_short(a[start:])} in the folder, ...{_short(b[start:])} asked"
    a = "not set" if a is _MISSING else _short(a)
    b = "not set" if b is _MISSING else _short(b)
    return f"{a} in the folder, {b} asked"


def config_differences(old: dict, new: dict, names: Mapping[str, str] | None = None) -> str:
    """The settings that differ between a folder's ``config.json`` (``old``) and the run asked for (``new``),
    one ``key: A in the folder, B asked`` each, ``;``-separated (e.g. ``per_category: 6 in the folder, 5
    asked``). ``names`` renames keys in the text (a command's flags: ``--per-category: 6 in the folder, 5
    asked``); keys it lacks keep their own name."""
    parts = []
    for key in sorted(set(old) | set(new)):
        a, b = old.get(key, _MISSING), new.get(key, _MISSING)
        if a != b:
            parts.append(f"{(names or {}).get(key, key)}: {_difference(a, b)}")
    return "; ".join(parts)


class OutDirConfigError(ValueError):
    """A folder holds data made with another config (:func:`claim_out_dir`). :meth:`with_names` gives the same
    error with the folder and the settings named by a command's flags, so the user reads the flags typed."""

    def __init__(self, out: Path, what: str, old: dict, new: dict, names: Mapping[str, str] | None = None,
                 out_name: str = "out_dir") -> None:
        self.out, self.what, self.old, self.new = out, what, old, new
        super().__init__(f"{out_name}: {out} holds a {what} made with another config "
                         f"({config_differences(old, new, names)}); use a new directory, or the folder's "
                         "settings to resume it")

    def with_names(self, names: Mapping[str, str], out_name: str = "--out") -> OutDirConfigError:
        """This error with config keys named by ``names`` (keys it lacks keep their name) and the folder by
        ``out_name``."""
        return OutDirConfigError(self.out, self.what, self.old, self.new, names, out_name)


def claim_out_dir(out: Path, cfg_dict: dict, old_defaults: dict | None = None, what: str = "dataset") -> None:
    """Create ``out`` and record ``config.json``, or refuse (:class:`OutDirConfigError`, a ValueError) a
    folder made with another config.

    ``old_defaults`` fills keys that older config files lack, so their datasets still resume. The temporary
    files of a killed run are removed (:func:`~vtlearn.io.remove_stale_temporaries_in`: those of a writer
    still running, and files of other names, are kept); their shards are redone.
    """
    out = check_out_dir(out)
    out.mkdir(parents=True, exist_ok=True)
    cfg_path = out / "config.json"
    if cfg_path.exists():
        old = {**(old_defaults or {}), **json.loads(cfg_path.read_text())}
        new = json.loads(json.dumps(cfg_dict))
        if old != new:
            raise OutDirConfigError(out, what, old, new)
    else:
        write_json_atomic(cfg_path, cfg_dict)
    for stale in remove_stale_temporaries_in(out):
        log.info("removed %s, a partial file of a stopped run", stale.name)


def _run_in_pool(todo: list[dict], worker, worker_args: tuple, out: Path, workers: int, done: dict,
                 bar) -> None:
    """:func:`run_shard_jobs`'s jobs in ``workers`` spawned processes, filling ``done``. A failed shard
    drops the queued ones and is raised once the running ones are written; Ctrl-C, then or at any time,
    stops the workers at once (:func:`~vtlearn.worker_pool.worker_pool`)."""
    with worker_pool(workers) as ex:
        try:
            futs = [ex.submit(worker, *worker_args, j, str(out)) for j in todo]
            for f in as_completed(futs):
                meta = f.result()
                done[meta["file"]] = meta
                bar.update()
        except Exception as exc:
            log.error("a shard failed (%s: %s); waiting for the running shards, the queued ones are dropped",
                      type(exc).__name__, exc)
            raise


def _warn_other_hosts(done: dict, todo: list[dict], desc: str) -> None:
    """Warn, before a resumed run writes ``todo``, that finished shards in ``done`` were written on a host
    whose floating point may round otherwise (another :func:`~vtlearn.bench_utils.host_info`): the dataset
    will then mix two hosts' bytes, and the same command run whole on either host would give other
    checksums (docs/sim_data.md)."""
    kept = {name: meta for name, meta in done.items() if meta is not None and meta.get("host")}
    if not (kept and todo):
        return
    here = host_info()
    other = sorted(name for name, meta in kept.items() if meta["host"] != here)
    if other:
        first = kept[other[0]]["host"]
        log.warning("%s: resuming on %s (%s, %s) the shards %s finished on %s (%s, %s): the dataset mixes "
                    "two hosts' rounding, so its checksums match neither host's whole run", desc,
                    here["platform"], here["cpu_model"], here["cpu_capability"], ", ".join(other),
                    first.get("platform"), first.get("cpu_model"), first.get("cpu_capability"))


def run_shard_jobs(out: Path, jobs: list[dict], worker, worker_args: tuple, workers: int = 1,
                   max_shards: int | None = None, desc: str = "shards", progress: bool = True) -> list | None:
    """Run ``worker(*worker_args, job, str(out))`` for every job whose shard is not already on disk.

    A shard counts as done when its side file's sha256 matches the shard, so a rerun resumes. With
    ``workers > 1`` the jobs run in spawned processes. Returns every shard's side-file metadata in job
    order, or None when ``max_shards`` stopped the run before the end.
    """
    from tqdm.auto import tqdm

    done = {j["name"]: _shard_done(out, j["name"]) for j in jobs}
    todo = [j for j in jobs if done[j["name"]] is None]
    if max_shards is not None:
        todo = todo[: int(max_shards)]
    log.info("%s: %d shards, %d already done", desc, len(jobs), len(jobs) - len(todo))
    _warn_other_hosts(done, todo, desc)
    bar = tqdm(total=len(jobs), initial=len(jobs) - len(todo), desc=desc, disable=not progress)
    try:
        if workers <= 1:
            for j in todo:
                done[j["name"]] = worker(*worker_args, j, str(out))
                bar.update()
        else:
            _run_in_pool(todo, worker, worker_args, out, int(workers), done, bar)
    finally:
        bar.close()  # also on Ctrl-C, so that the CLI's "interrupted" line starts a line of its own
    if any(v is None for v in done.values()):
        return None
    return [done[j["name"]] for j in jobs]


# --------------------------------------------------------------------------- one shard
def _load_mesh(item: dict, cfg: GenConfig):
    if "file" in item:
        from vtlearn.sim_data.loaders import load_mesh_item

        return load_mesh_item(item), float(item.get("scale_m", 0.2)), bool(item.get("transparent", False))
    mesh, rec = generate_shape(item["category"], item["seed"], cfg.sections)
    return mesh, rec.scale_m, rec.transparent


def _place(scene, mesh, scale, transparent):
    """Put the object on the table (bottom at z = 0); returns body id and T_world_object."""
    T = np.eye(4)
    T[2, 3] = -mesh.bounds[0, 2] * scale
    body = scene.add_mesh(mesh, scale, T, transparent=transparent)
    return body, T


def _to_canonical(points_world: np.ndarray, T_world_object: np.ndarray, scale: float) -> np.ndarray:
    from vtlearn.geometry import se3_inverse, transform_points

    if len(points_world) == 0:
        return np.zeros((0, 3))
    return transform_points(se3_inverse(T_world_object), points_world) / scale


def crop_to_box(points: np.ndarray, lo: np.ndarray, hi: np.ndarray, margin: float | None) -> np.ndarray:
    """Points inside the box ``[lo, hi]`` grown by ``margin`` times its largest extent (``None``: all).

    Models the segmentation step of thesis 7.3.1 (table removal and clustering in PCL give the object's
    bounding box): a transparent object's see-through returns land on or below the table, far behind
    the object, and are discarded, so its visual cloud is sparse rather than a cloud of background.

    ``lo``/``hi`` are finite (3,) corners with ``lo <= hi``, ``margin`` None or finite and >= 0, ``points``
    a finite (N, 3) array (``ValueError`` naming the argument otherwise).

    Shapes:
        points (N, 3), lo (3,), hi (3,) -> (M, 3) with M <= N
    """
    from vtlearn.sim_data.tactile import _check_box
    from vtlearn.validation import as_points, as_real

    as_points(points, "points", min_points=0)
    points = np.asarray(points)
    lo, hi = _check_box(lo, hi)
    if margin is not None:
        margin = as_real(margin, "margin", low=0.0)
    if margin is None or len(points) == 0:
        return points
    pad = margin * float(np.max(np.asarray(hi) - np.asarray(lo)))
    keep = np.all((points >= np.asarray(lo) - pad) & (points <= np.asarray(hi) + pad), axis=1)
    return points[keep]


def _tactile_cloud(sim, lo, hi, rng, touches: int, pinches: int, target: int | None = None, max_actions=400):
    """Touch (and pinch) until ``target`` points are collected (or the fixed budget is spent)."""
    from vtlearn.sim_data.tactile import sample_pinches, sample_touches

    pts = []
    total = 0
    n_actions = 0
    while True:
        acts = [("t", a) for a in sample_touches(lo, hi, touches, rng)]
        if pinches:
            acts += [("p", a) for a in sample_pinches(lo, hi, pinches, rng)]
        order = rng.permutation(len(acts))
        for i in order:
            kind, a = acts[i]
            res = sim.touch(*a, rng=rng) if kind == "t" else sim.pinch(*a, rng=rng)
            n_actions += 1
            if res.num_contacts:
                pts.append(res.points)
                total += res.num_contacts
            if target is not None and total >= target:
                return np.concatenate(pts)
        if target is None or n_actions >= max_actions:
            return np.concatenate(pts) if pts else np.zeros((0, 3))


def generate_shard(cfg: GenConfig, job: dict) -> dict[str, np.ndarray]:
    """All arrays of one shard; a pure function of (cfg, job)."""
    from vtlearn.geometry import random_subsample, sample_surface
    from vtlearn.sim_data.camera import DepthNoise, RGBDCamera, sample_hemisphere_views
    from vtlearn.sim_data.scene import Scene
    from vtlearn.sim_data.tactile import TactileConfig, TactileSimulator

    rng = np.random.default_rng([cfg.seed, SPLITS.index(job["split"]), job["shard"], 104729])
    tcfg = TactileConfig(position_noise=cfg.position_noise, dropout=cfg.dropout)
    cam = None
    if cfg.kind == "crossmodal":
        cam = RGBDCamera(
            cfg.image_width, cfg.image_height, noise=DepthNoise() if cfg.depth_noise else DepthNoise.off()
        )
    out: dict[str, list] = {
        k: []
        for k in (
            "dense",
            "label",
            "instance",
            "scale_m",
            "transparent",
            "tactile",
            "tactile_label",
            "tactile_instance",
            "visual",
            "visual_label",
            "visual_instance",
        )
    }
    with Scene() as scene:
        for item in job["items"]:
            mesh, scale, transparent = _load_mesh(item, cfg)
            transparent = transparent and cfg.transparency
            body, T = _place(scene, mesh, scale, transparent)
            sim = TactileSimulator(scene, cfg.sensor, tcfg, objects=[body])
            lo, hi = scene.objects[body].mesh_m.bounds + T[:3, 3]
            out["label"].append(item["label"])
            out["instance"].append(item["instance"])
            out["scale_m"].append(scale)
            out["transparent"].append(transparent)
            dense, _ = sample_surface(mesh, cfg.dense_points, rng)
            out["dense"].append(dense)
            if cfg.kind == "reconstruction":
                cloud = _tactile_cloud(sim, lo, hi, rng, cfg.touches, cfg.pinches)
                out["tactile"].append(_to_canonical(cloud, T, scale))
                out["tactile_label"].append(item["label"])
                out["tactile_instance"].append(item["instance"])
            else:
                centre = (lo + hi) / 2
                radius = 3.0 * float(np.max(hi - lo)) + 0.3
                views = sample_hemisphere_views(centre, radius, 4 * cfg.views, rng)
                got = 0
                for V in views:
                    frame = cam.render(scene, V, rng)
                    pts = crop_to_box(cam.point_cloud(frame, body, rng), lo, hi, cfg.visual_crop_margin)
                    if len(pts) < 16:
                        continue  # a view where the object is (nearly) invisible or lost to transparency
                    pts = random_subsample(pts, cfg.visual_points, rng)
                    out["visual"].append(_to_canonical(pts, T, scale))
                    out["visual_label"].append(item["label"])
                    out["visual_instance"].append(item["instance"])
                    got += 1
                    if got == cfg.views:
                        break
                for _ in range(cfg.tactile_clouds):
                    n = int(rng.integers(cfg.tactile_min_points, cfg.tactile_max_points + 1))
                    cloud = _tactile_cloud(sim, lo, hi, rng, 20, 5, target=n)
                    if len(cloud) < cfg.tactile_min_points:
                        continue
                    cloud = cloud[rng.permutation(len(cloud))[:n]]
                    out["tactile"].append(_to_canonical(cloud, T, scale))
                    out["tactile_label"].append(item["label"])
                    out["tactile_instance"].append(item["instance"])
            scene.remove(body)
    arrays = {
        "dense": np.asarray(out["dense"], dtype=np.float32).reshape(-1, cfg.dense_points, 3),
        "label": np.asarray(out["label"], dtype=np.int64),
        "instance": np.asarray(out["instance"], dtype=np.int64),
        "scale_m": np.asarray(out["scale_m"], dtype=np.float32),
        "transparent": np.asarray(out["transparent"], dtype=bool),
    }
    tac = out["tactile"]
    arrays["tactile_points"] = (np.concatenate(tac) if tac else np.zeros((0, 3))).astype(np.float32)
    arrays["tactile_offsets"] = np.concatenate([[0], np.cumsum([len(c) for c in tac])]).astype(np.int64)
    arrays["tactile_label"] = np.asarray(out["tactile_label"], dtype=np.int64)
    arrays["tactile_instance"] = np.asarray(out["tactile_instance"], dtype=np.int64)
    if cfg.kind == "crossmodal":
        arrays["visual"] = np.asarray(out["visual"], dtype=np.float32).reshape(-1, cfg.visual_points, 3)
        arrays["visual_label"] = np.asarray(out["visual_label"], dtype=np.int64)
        arrays["visual_instance"] = np.asarray(out["visual_instance"], dtype=np.int64)
    return arrays


def _run_job(cfg_dict: dict, job: dict, out_dir: str) -> dict:
    cfg = GenConfig(**cfg_dict)
    return write_shard(out_dir, job, generate_shard(cfg, job))


def write_shard(out_dir: str | Path, job: dict, arrays: dict[str, np.ndarray]) -> dict:
    """Write one finished shard of ``job`` (its ``name`` and ``split``): the ``.npz`` atomically, then its
    side file, whose sha256 marks it done for :func:`run_shard_jobs`. The side file also names the host
    that wrote the bytes (:func:`~vtlearn.bench_utils.host_info`; not part of the fingerprint). Returns the
    side file's content.

    Shapes:
        arrays: ``label`` (n,), ``tactile_label`` (m,), ``visual_label`` (v,) if any, ... -> dict
    """
    out = Path(out_dir)
    meta = {
        "file": job["name"],
        "split": job["split"],
        "sha256": write_npz_atomic(out / job["name"], arrays),
        "instances": int(len(arrays["label"])),
        "tactile_clouds": int(len(arrays["tactile_label"])),
        "visual_clouds": int(len(arrays.get("visual_label", ()))),
        "host": host_info(),
    }
    write_json_atomic(out / (job["name"] + ".json"), meta)
    return meta


# --------------------------------------------------------------------------- real meshes
MESH_LIST = "meshes.json"


def _usable_meshes(cfg: GenConfig, progress: bool) -> tuple[GenConfig, list[dict]]:
    """``cfg`` with its categories resolved (all of ``mesh_source`` when None), and the first
    ``per_category`` usable meshes of each category, or with ``keep_split`` of each category's train and
    test meshes (ValueError / FileNotFoundError naming the field)."""
    from dataclasses import replace

    from vtlearn.sim_data.loaders import scan_mesh_folder

    try:
        scanned = scan_mesh_folder(cfg.mesh_source, check=False, categories=cfg.categories)
    except ValueError as exc:
        raise ValueError(f"mesh_source: {str(exc).removeprefix('spec: ')}") from None
    except FileNotFoundError as exc:
        raise FileNotFoundError(f"mesh_source: {str(exc).removeprefix('spec: ')}") from None
    found = list(dict.fromkeys(m["category"] for m in scanned))
    if cfg.categories is not None:
        missing = [c for c in cfg.categories if c not in found]
        if missing:
            every = sorted({m["category"] for m in scan_mesh_folder(cfg.mesh_source, check=False)})
            raise ValueError(f"categories: no meshes of {missing} in mesh_source {cfg.mesh_source} (it has: "
                             f"{', '.join(every)})")
    if cfg.keep_split:
        if any("source_split" not in m for m in scanned):
            raise ValueError(f"keep_split: the meshes of {cfg.mesh_source} have no train/test split of their "
                             "own (only ModelNet40/10 trees, <category>/{train,test}/*.off, have one); drop "
                             "--keep-split to split them by --splits")
        for cat in found:
            _check_kept_split(cfg, cat, [m for m in scanned if m["category"] == cat])
    mesh_items = scan_mesh_folder(cfg.mesh_source, categories=cfg.categories, per_category=cfg.per_category,
                                  progress=progress, check=True, by_source_split=cfg.keep_split)
    usable = list(dict.fromkeys(m["category"] for m in mesh_items))
    categories = cfg.categories
    if categories is None:
        unusable = [c for c in found if c not in usable]
        if unusable:
            log.warning("categories %s of %s have no usable mesh and are left out", unusable, cfg.mesh_source)
        categories = sorted(usable)
    missing = [c for c in categories if c not in usable]
    if missing or not categories:
        raise ValueError(f"categories: no usable meshes of {missing or 'any category'} in mesh_source "
                         f"{cfg.mesh_source} (the skipped meshes are logged above)")
    for cat in categories:
        cat_items = [m for m in mesh_items if m["category"] == cat]
        if cfg.keep_split:  # per_category caps each source split
            _check_kept_split(cfg, cat, cat_items, "usable ")
            n = Counter(m["source_split"] for m in cat_items)
            short = [f"{n[s]} usable {s}" for s in ("train", "test") if n[s] < cfg.per_category]
        else:
            have = len(cat_items)
            if have < cfg.per_category:
                _check_split_sizes(cfg, have, "mesh_source",
                                   f"{cfg.mesh_source} has only {have} usable mesh(es) of {cat!r}: ")
            short = [f"{have} usable"] if have < cfg.per_category else []
        if short:
            log.warning("%s has only %s mesh(es) of %r, fewer than per_category=%d: using them all",
                        cfg.mesh_source, " and ".join(short), cat, cfg.per_category)
    return replace(cfg, categories=list(categories)), mesh_items


def _claim_mesh_list(out: Path, cfg: GenConfig, plan: dict[str, list[dict]]) -> None:
    """Record which mesh file each instance comes from in ``out/meshes.json`` (with ``keep_split``, also the
    ``source_split`` it was kept from), or refuse (ValueError naming ``mesh_source``) to resume a dataset
    whose mesh folder has changed since: its finished shards hold another plan's instances, so kept shards
    and new ones could share an instance across splits."""
    from vtlearn.sim_data.loaders import _relative, mesh_root

    root = mesh_root(cfg.mesh_source)
    rows = []
    for split, items in plan.items():
        for it in items:
            f = Path(it["file"])
            rows.append({"instance": it["instance"], "split": split, "category": it["category"],
                         "file": _relative(f, root),
                         "bytes": f.stat().st_size})
            if cfg.keep_split:  # only then: meshes.json of datasets made without it stay as they were
                rows[-1]["source_split"] = it["source_split"]
    new = {"mesh_source": str(cfg.mesh_source), "instances": rows}
    path = out / MESH_LIST
    if not path.exists() and any(out.glob("*.npz")):
        raise ValueError(
            f"out_dir: {out} holds shards made from {cfg.mesh_source} before vtlearn recorded their meshes "
            f"({MESH_LIST}); this vtlearn reads meshes otherwise (z-up, scale-free, double-sided faces "
            "kept), so its shards would not match the finished ones: use a new output folder"
        )
    if path.exists():
        old = json.loads(path.read_text())
        if old.get("instances") != rows:
            was = {(r["file"], r["bytes"]) for r in old.get("instances", [])}
            now = {(r["file"], r["bytes"]) for r in rows}
            diff = sorted(now ^ was)[:3]
            raise ValueError(
                f"mesh_source: the usable meshes in {cfg.mesh_source} are not those {out} was made from "
                f"({len(now - was)} new or changed, {len(was - now)} gone or changed, e.g. "
                f"{', '.join(f for f, _ in diff) or 'a different order'}); use a new output folder, or "
                "restore the mesh folder"
            )
    else:
        write_json_atomic(path, new)


def planned_instances(data_dir: str | Path, cfg: GenConfig) -> dict[int, dict]:
    """Instance id -> the item generation made it from (its procedural ``seed``, or its mesh ``file``), for
    the dataset in ``data_dir`` made with ``cfg``. Procedural instances replay :func:`plan_instances`; mesh
    instances come from the dataset's ``meshes.json`` (datasets made before it: the plan of a rescan of
    ``mesh_source``, which matches only if the folder and the mesh reading are unchanged)."""
    from vtlearn.sim_data.loaders import DEFAULT_SIZE_M, NOMINAL_SIZE_M, mesh_root, scan_mesh_folder

    path = Path(data_dir) / MESH_LIST
    if cfg.mesh_source == "procedural" or not path.exists():
        items = None if cfg.mesh_source == "procedural" else scan_mesh_folder(
            cfg.mesh_source, categories=cfg.categories, per_category=cfg.per_category,
            by_source_split=cfg.keep_split)
        return {it["instance"]: it for split in plan_instances(cfg, items).values() for it in split}
    root = mesh_root(cfg.mesh_source)
    scanned = scan_mesh_folder(cfg.mesh_source, check=False, categories=cfg.categories)
    scanned = {m["file"]: m for m in scanned}
    out = {}
    for r in json.loads(path.read_text())["instances"]:
        f = str(root / r["file"])
        item = scanned.get(f) or {"category": r["category"], "file": f,
                                  "scale_m": NOMINAL_SIZE_M.get(r["category"], DEFAULT_SIZE_M)}
        if "source_split" in r:
            item = {**item, "source_split": r["source_split"]}
        out[int(r["instance"])] = {**item, "instance": int(r["instance"])}
    return out


# --------------------------------------------------------------------------- driver
def generate_dataset(
    cfg: GenConfig,
    out_dir: str | Path,
    workers: int = 1,
    progress: bool = True,
    max_shards: int | None = None,
) -> dict:
    """Generate (or resume) a dataset; returns the manifest. ``max_shards`` stops early (for tests).

    ``out_dir`` must be a directory or not exist yet, ``workers`` an integer >= 1 and ``max_shards`` None or
    an integer >= 0 (``ValueError`` naming the argument, before anything is written).
    """
    cfg.validate()
    out = check_out_dir(out_dir)
    as_int(workers, "workers", 1)
    if max_shards is not None:
        as_int(max_shards, "max_shards", 0)
    _check_split_sizes(cfg, cfg.per_category)
    mesh_items = None
    if cfg.mesh_source != "procedural":
        cfg, mesh_items = _usable_meshes(cfg, progress)
    cfg_dict = asdict(cfg)
    # pre-crop and pre-keep_split datasets resume; those of touch sampler 1 (no such key) are refused
    claim_out_dir(out, cfg_dict, old_defaults={"visual_crop_margin": None, "touch_sampler": 1,
                                               "keep_split": False, "transparency": True})
    plan = plan_instances(cfg, mesh_items)
    if mesh_items is not None:
        _claim_mesh_list(out, cfg, plan)
    jobs = plan_shards(cfg, plan)
    shards = run_shard_jobs(out, jobs, _run_job, (cfg_dict,), workers, max_shards,
                            desc=f"gen-data {cfg.kind}", progress=progress)
    if shards is None:
        return {}
    manifest = {
        "format": FORMAT,
        "kind": cfg.kind,
        "class_names": list(cfg.categories),
        "num_classes": len(cfg.categories),
        "config": cfg_dict,
        "splits": {
            s: {
                "instances": sum(m["instances"] for m in shards if m["split"] == s),
                "tactile_clouds": sum(m["tactile_clouds"] for m in shards if m["split"] == s),
                "visual_clouds": sum(m["visual_clouds"] for m in shards if m["split"] == s),
                "shards": [m["file"] for m in shards if m["split"] == s],
            }
            for s in SPLITS
        },
        "shards": shards,
    }
    write_json_atomic(out / "manifest.json", manifest)
    return manifest
