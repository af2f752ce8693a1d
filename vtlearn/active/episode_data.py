"""Tactile clouds collected by the closed loop's own policies: a target stream for xAVTNet's adaptation.

Thesis 7.2.3-7.2.4 and Algorithm 5 adapt the classifier (VTLoss) with tactile clouds from *random*
tactile actions and then recognise with *actively* chosen ones. `vtlearn gen-data crossmodal` follows
that: its tactile clouds come from random box-face touches and pinches. In simulation the classifier
then works on random touches and poorly on active ones (docs/active_perception.md): active touches
cluster and touch-only prefixes have fewer points, so the recognition-time clouds are off the
distribution the features were aligned to. Algorithm 5 does not depend on how the unlabelled tactile
clouds were collected (thesis 7.3.3: "independent of the method of tactile data collection"), so this
module collects them with the policies the robot will use at recognition time.

For every instance of one split of a crossmodal dataset (the same procedural mesh: category, seed and
``sections`` and the sensor from the dataset's config) and for every strategy, one episode of
:func:`~vtlearn.active.closed_loop.run_episode` is run: touch only, ``touches`` actions, the first a
random touch (as in ``bench active-recognition``). The tactile points of the first ``k`` actions, for
each ``k`` in ``prefixes``, form one cloud when they hold at least ``min_points`` points. Clouds are
stored in the instance's canonical frame (as `gen-data` stores them) with their labels, which UDA
training never reads (they are kept for evaluation and for the ``tactile_oracle`` bound).

Output is a dataset folder in the `gen-data` format (``vtlearn-sim/1``, kind ``tactile-episodes``):
shards ``<split>-NNNNN.npz`` written atomically with ``allow_pickle=False``, a ``.json`` side file per
shard with its sha256 (finished shards are skipped on a rerun), and ``manifest.json``. The
:class:`~vtlearn.datamodules.CrossModalDataModule` reads it through ``target_data_dir``.

Shapes (per shard):
    tactile_points (P, 3) float32 canonical frame; tactile_offsets (T + 1,); tactile_label,
    tactile_instance, tactile_strategy (index into the manifest's ``strategies``), tactile_actions
    (the prefix length k) (T,); label, instance, scale_m, transparent (I,) per instance.
"""

from __future__ import annotations

import logging
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np

from vtlearn.validation import as_int

log = logging.getLogger(__name__)

KIND = "tactile-episodes"
SOURCE_SPLITS = ("train", "val", "test")


@dataclass
class EpisodeDataConfig:
    """What :func:`generate_episode_dataset` collects (see the module docstring).

    Args:
        source: a `gen-data crossmodal` dataset folder; its instances and class names are used.
        split: the source split whose instances are explored.
        strategies: closed-loop strategies (:data:`~vtlearn.active.closed_loop.TOUCH_STRATEGIES`), one
            episode each per instance.
        touches: actions per episode.
        prefixes: prefix lengths k (1 <= k <= touches) that each give one cloud.
        min_points: a prefix with fewer tactile points gives no cloud (the recognition stop rule's
            minimum, thesis 7.3.3: 10).
        n_candidates, cells, gain_mode: as in :func:`~vtlearn.active.closed_loop.run_episode`.
        seed: base seed of the episodes (episode seed = seed * 10_000_000 + instance id).
        shard_size: instances per shard.
    """

    source: str
    split: str = "train"
    strategies: list[str] = field(default_factory=lambda: ["active", "random"])
    touches: int = 20
    prefixes: list[int] = field(default_factory=lambda: [4, 10, 20])
    min_points: int = 10
    n_candidates: int = 100
    cells: int = 40
    gain_mode: str = "probabilistic"
    seed: int = 0
    shard_size: int = 16

    def validate(self) -> None:
        from vtlearn.active.closed_loop import GAIN_MODES, TOUCH_STRATEGIES

        if self.split not in SOURCE_SPLITS:
            raise ValueError(f"split: expected one of {SOURCE_SPLITS}, got {self.split!r}")
        bad = [s for s in self.strategies if s not in TOUCH_STRATEGIES]  # the episodes are touch-only
        if not self.strategies or bad:
            raise ValueError(
                f"strategies: expected a non-empty list of {TOUCH_STRATEGIES}, got {self.strategies}"
            )
        if len(set(self.strategies)) != len(self.strategies):
            raise ValueError(f"strategies: repeated names in {self.strategies}")
        if self.gain_mode not in ("raycast", "probabilistic"):
            raise ValueError(
                f"gain_mode: expected 'raycast' or 'probabilistic' (of {GAIN_MODES}), got {self.gain_mode!r}"
            )
        as_int(self.touches, "touches")
        if not self.prefixes or any(not 1 <= int(k) <= int(self.touches) for k in self.prefixes):
            raise ValueError(f"prefixes: need values in [1, touches={self.touches}], got {self.prefixes}")
        as_int(self.min_points, "min_points")
        as_int(self.n_candidates, "n_candidates", minimum=2)
        as_int(self.cells, "cells", minimum=2)
        as_int(self.shard_size, "shard_size")
        as_int(self.seed, "seed", minimum=0)


def _source_plan(cfg: EpisodeDataConfig) -> tuple[dict, list[dict]]:
    """The source manifest and the instances (category, seed, label, instance id) of ``cfg.split``."""
    from vtlearn.datamodules.shards import check_kind, check_split, load_manifest
    from vtlearn.sim_data.writer import GenConfig, plan_instances

    manifest = load_manifest(cfg.source, "source")
    check_kind(manifest, cfg.source, "crossmodal", "source")
    check_split(manifest, cfg.source, cfg.split, "source")  # an empty split would give an empty episode set
    gen = GenConfig(**manifest["config"])
    if gen.mesh_source != "procedural":
        raise ValueError(
            f"source: only procedural datasets can be re-explored, got meshes {gen.mesh_source!r}"
        )
    return manifest, plan_instances(gen)[cfg.split]


def _episode_shard(cfg_dict: dict, sections: int, sensor: str, items: list[dict]) -> dict[str, np.ndarray]:
    """All arrays of one shard: a pure function of the config and the instances."""
    from vtlearn.active.closed_loop import TouchWorld, make_object, run_episode

    cfg = EpisodeDataConfig(**cfg_dict)
    clouds, lab, inst, strat, acts = [], [], [], [], []
    per = {"label": [], "instance": [], "scale_m": [], "transparent": []}
    for item in items:
        obj = make_object(item["category"], item["seed"], sections)
        per["label"].append(item["label"])
        per["instance"].append(item["instance"])
        per["scale_m"].append(obj.scale_m)
        per["transparent"].append(obj.transparent)
        t = obj.T_world_object[:3, 3]
        with TouchWorld(obj, sensor) as world:
            for si, strategy in enumerate(cfg.strategies):
                ep = run_episode(
                    world, strategy, int(cfg.touches), pinch=False, n_candidates=int(cfg.n_candidates),
                    cells=int(cfg.cells), gain_mode=cfg.gain_mode, n_init=1,
                    seed=int(cfg.seed) * 10_000_000 + int(item["instance"]),
                )
                for k in cfg.prefixes:
                    pts = ep.prefix(int(k), "tactile")
                    if len(pts) < int(cfg.min_points):
                        continue
                    clouds.append((pts - t) / obj.scale_m)  # T_world_object is a pure translation
                    lab.append(item["label"])
                    inst.append(item["instance"])
                    strat.append(si)
                    acts.append(int(k))
    return {
        "tactile_points": (np.concatenate(clouds) if clouds else np.zeros((0, 3))).astype(np.float32),
        "tactile_offsets": np.concatenate([[0], np.cumsum([len(c) for c in clouds])]).astype(np.int64),
        "tactile_label": np.asarray(lab, dtype=np.int64),
        "tactile_instance": np.asarray(inst, dtype=np.int64),
        "tactile_strategy": np.asarray(strat, dtype=np.int64),
        "tactile_actions": np.asarray(acts, dtype=np.int64),
        "label": np.asarray(per["label"], dtype=np.int64),
        "instance": np.asarray(per["instance"], dtype=np.int64),
        "scale_m": np.asarray(per["scale_m"], dtype=np.float32),
        "transparent": np.asarray(per["transparent"], dtype=bool),
    }


def _run_shard(cfg_dict: dict, sections: int, sensor: str, job: dict, out_dir: str) -> dict:
    from vtlearn.sim_data.writer import write_shard

    return write_shard(out_dir, job, _episode_shard(cfg_dict, sections, sensor, job["items"]))


def generate_episode_dataset(
    cfg: EpisodeDataConfig, out_dir: str | Path, workers: int = 1, progress: bool = True,
    max_shards: int | None = None,
) -> dict:
    """Collect (or resume collecting) closed-loop tactile clouds; returns the manifest ({} if
    ``max_shards`` stopped it before the end).

    A rerun skips every shard whose side file's sha256 matches; a folder made with another config is
    refused (ValueError), so two configs never mix.
    """
    from vtlearn.sim_data.writer import FORMAT, claim_out_dir, run_shard_jobs, write_json_atomic

    cfg.validate()
    source_manifest, items = _source_plan(cfg)
    sections = int(source_manifest["config"]["sections"])
    sensor = str(source_manifest["config"]["sensor"])
    out = Path(out_dir)
    cfg_dict = asdict(cfg)
    claim_out_dir(out, cfg_dict, what="set of episodes")
    size = int(cfg.shard_size)
    jobs = [
        {"name": f"{cfg.split}-{k // size:05d}.npz", "split": cfg.split, "items": items[k : k + size]}
        for k in range(0, len(items), size)
    ]
    shards = run_shard_jobs(out, jobs, _run_shard, (cfg_dict, sections, sensor), workers, max_shards,
                            desc="gen-episodes", progress=progress)
    if shards is None:
        return {}
    manifest = {
        "format": FORMAT,
        "kind": KIND,
        "class_names": list(source_manifest["class_names"]),
        "num_classes": int(source_manifest["num_classes"]),
        "strategies": list(cfg.strategies),
        "config": cfg_dict,
        "splits": {
            cfg.split: {
                "instances": sum(m["instances"] for m in shards),
                "tactile_clouds": sum(m["tactile_clouds"] for m in shards),
                "visual_clouds": 0,
                "shards": [m["file"] for m in shards],
            }
        },
        "shards": shards,
    }
    write_json_atomic(out / "manifest.json", manifest)
    return manifest
