"""Closed-loop tactile clouds as xAVTNet's target stream (vtlearn.active.episode_data)."""

import json

import numpy as np
import open3d as o3d
import pytest

from vtlearn.active.closed_loop import TouchWorld, make_object, run_episode
from vtlearn.active.episode_data import EpisodeDataConfig, generate_episode_dataset
from vtlearn.datamodules import CrossModalDataModule
from vtlearn.datamodules.shards import load_split, split_clouds
from vtlearn.sim_data.writer import GenConfig, plan_instances


@pytest.fixture(scope="module")
def episodes(cross_dir, tmp_path_factory):
    out = tmp_path_factory.mktemp("episodes")
    cfg = EpisodeDataConfig(source=str(cross_dir), split="train", strategies=["active", "random"], touches=6,
                            prefixes=[2, 6], min_points=3, n_candidates=12, cells=16, shard_size=2)
    return cfg, out, generate_episode_dataset(cfg, out, progress=False)


def test_episode_clouds_are_nested_prefixes_on_the_instance_surface(cross_dir, episodes):
    cfg, out, manifest = episodes
    assert manifest["kind"] == "tactile-episodes" and manifest["strategies"] == ["active", "random"]
    src = json.loads((cross_dir / "manifest.json").read_text())
    assert manifest["class_names"] == src["class_names"]
    d = load_split(out, "train")
    clouds = split_clouds(d["tactile_points"], d["tactile_offsets"])
    assert len(clouds) == manifest["splits"]["train"]["tactile_clouds"] > 0
    assert all(len(c) >= cfg.min_points for c in clouds)
    items = {it["instance"]: it for it in plan_instances(GenConfig(**src["config"]))["train"]}
    assert sorted(d["instance"].tolist()) == sorted(items)
    for inst in d["instance"]:
        item = items[int(inst)]
        assert d["label"][d["instance"] == inst][0] == item["label"]
        obj = make_object(item["category"], item["seed"], src["config"]["sections"])
        scene = o3d.t.geometry.RaycastingScene()
        scene.add_triangles(o3d.core.Tensor(np.asarray(obj.mesh.vertices, np.float32)),
                            o3d.core.Tensor(np.asarray(obj.mesh.faces, np.uint32)))
        for s in (0, 1):
            sel = np.flatnonzero((d["tactile_instance"] == inst) & (d["tactile_strategy"] == s))
            assert (d["tactile_label"][sel] == item["label"]).all()
            by_k = {int(d["tactile_actions"][i]): clouds[i] for i in sel}
            if 2 in by_k and 6 in by_k:  # the first 2 actions' points are the first points of 6
                assert np.array_equal(by_k[6][: len(by_k[2])], by_k[2])
            for c in by_k.values():
                # canonical frame (unit cube): contacts lie on the surface, up to the pad's compression
                dist = scene.compute_distance(o3d.core.Tensor(c.astype(np.float32))).numpy()
                assert np.max(dist) * obj.scale_m < 3e-3


def test_episode_dataset_matches_run_episode_and_resumes(cross_dir, episodes):
    cfg, out, manifest = episodes
    d = load_split(out, "train")
    clouds = split_clouds(d["tactile_points"], d["tactile_offsets"])
    src = json.loads((cross_dir / "manifest.json").read_text())
    item = plan_instances(GenConfig(**src["config"]))["train"][0]
    obj = make_object(item["category"], item["seed"], src["config"]["sections"])
    with TouchWorld(obj) as world:
        ep = run_episode(world, "random", 6, pinch=False, n_candidates=12, cells=16, n_init=1,
                         seed=item["instance"])
    i = np.flatnonzero((d["tactile_instance"] == item["instance"]) & (d["tactile_strategy"] == 1)
                       & (d["tactile_actions"] == 6))
    want = (ep.prefix(6, "tactile") - obj.T_world_object[:3, 3]) / obj.scale_m
    assert len(i) == 1 and np.allclose(clouds[i[0]], want, atol=1e-6)
    # A rerun skips every finished shard; another config in the same folder is refused.
    stamps = {p.name: p.stat().st_mtime_ns for p in out.glob("*.npz")}
    assert generate_episode_dataset(cfg, out, progress=False) == manifest
    assert {p.name: p.stat().st_mtime_ns for p in out.glob("*.npz")} == stamps
    with pytest.raises(ValueError, match="out_dir"):
        generate_episode_dataset(EpisodeDataConfig(**{**vars(cfg), "touches": 7}), out, progress=False)


def test_episode_config_rejects_bad_input(cross_dir, tmp_path):
    for kwargs, name in [({"strategies": ["greedy"]}, "strategies"),
                         ({"strategies": ["random_pinch"]}, "strategies"), ({"prefixes": [0]}, "prefixes"),
                         ({"prefixes": [9], "touches": 8}, "prefixes"), ({"split": "dev"}, "split"),
                         ({"gain_mode": "recognition"}, "gain_mode"), ({"min_points": 0}, "min_points")]:
        with pytest.raises(ValueError, match=name):
            generate_episode_dataset(EpisodeDataConfig(source=str(cross_dir), **kwargs), tmp_path / "x",
                                     progress=False)
    with pytest.raises(FileNotFoundError, match="source: no manifest.json in"):
        generate_episode_dataset(EpisodeDataConfig(source=str(tmp_path / "none")), tmp_path / "y",
                                 progress=False)


def test_crossmodal_target_data_dir_streams_the_episode_clouds(cross_dir, episodes, tmp_path):
    _, out, manifest = episodes
    dm = CrossModalDataModule(str(cross_dir), batch_size=2, target_data_dir=str(out))
    target = dm.train_dataloader().iterables["target"].dataset
    assert target.train and not target.with_label
    d = load_split(out, "train")
    assert sorted(len(c) for c in target.clouds) == sorted(np.diff(d["tactile_offsets"]).tolist())
    batch = next(iter(dm.train_dataloader()))[0]
    # no label; the index for pseudo-labels, the group (the episode's object instance) for their votes
    assert set(batch["target"]) == {"points", "lengths", "index", "group"}
    assert target.groups.tolist() == np.asarray(d["tactile_instance"]).tolist()
    # evaluation still reads data_dir's tactile test clouds
    plain = CrossModalDataModule(str(cross_dir))
    assert len(dm.test_dataloader().dataset) == len(plain.test_dataloader().dataset)
    with pytest.raises(ValueError, match="target_data_dir"):
        CrossModalDataModule(str(cross_dir), target_data_dir=str(out), target_split="test")
    bad = json.loads((out / "manifest.json").read_text())
    bad["class_names"] = bad["class_names"][::-1]
    (tmp_path / "manifest.json").write_text(json.dumps(bad))
    with pytest.raises(ValueError, match="class names"):
        CrossModalDataModule(str(cross_dir), target_data_dir=str(tmp_path))


def test_train_on_tactile_trains_on_labelled_touches_and_adds_episode_clouds(cross_dir, episodes, tmp_path):
    """``train_on="tactile"``: the training stream is the labelled tactile training clouds (plus the labelled
    episode clouds of ``target_data_dir``), with the dataset's true labels; it fits through Lightning."""
    import lightning as L

    from vtlearn.models.xavtnet import XAVTNet

    _, out, _ = episodes
    plain = CrossModalDataModule(str(cross_dir), batch_size=4, train_on="tactile")
    both = CrossModalDataModule(str(cross_dir), batch_size=4, train_on="tactile", target_data_dir=str(out))
    d_train, d_ep = load_split(cross_dir, "train"), load_split(out, "train")
    n_train, n_ep = len(d_train["tactile_label"]), len(d_ep["tactile_label"])
    assert len(plain.train_dataloader().dataset) == n_train
    assert len(both.train_dataloader().dataset) == n_train + n_ep
    labels = sorted(int(both.train_dataloader().dataset[i]["label"]) for i in range(n_train + n_ep))
    assert labels == sorted(np.concatenate([d_train["tactile_label"], d_ep["tactile_label"]]).tolist())
    batch = next(iter(plain.train_dataloader()))
    assert set(batch) == {"points", "lengths", "label"} and (batch["lengths"] <= 120).all()
    with pytest.raises(ValueError, match="train_on"):
        CrossModalDataModule(str(cross_dir), train_on="audio")
    model = XAVTNet(num_classes=plain.num_classes, global_dim=32, fc_dims=[32, 16], max_points=32)
    trainer = L.Trainer(fast_dev_run=1, accelerator="cpu", logger=False, enable_progress_bar=False,
                        enable_model_summary=False, default_root_dir=tmp_path)
    trainer.fit(model, datamodule=both)
    # the single-stream branch of training_step: cross-entropy only, no domain terms
    assert "train/ce" in trainer.callback_metrics and "train/mmd" not in trainer.callback_metrics


def test_gen_episodes_default_prefixes_fit_the_touch_budget():
    """`vtlearn gen-episodes --touches 4` used to fail on its own default prefixes 4,10,20; unset, they are
    cut to the budget, and given ones are parsed as given (the config checks them against the budget)."""
    from vtlearn.active.experiments_cli import _episode_prefixes

    assert _episode_prefixes(None, 20) == [4, 10, 20]
    assert _episode_prefixes(None, 12) == [4, 10]
    assert _episode_prefixes(None, 4) == [4]
    assert _episode_prefixes(None, 3) == [3]
    assert _episode_prefixes("2,6", 4) == [2, 6]
    with pytest.raises(ValueError, match="--prefixes"):
        _episode_prefixes("2,x", 4)
