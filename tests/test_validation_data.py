"""Input validation of the datamodules (damaged datasets, bad settings) and of the checkpoint / inference
entry points: every bad input is a ValueError (FileNotFoundError for a missing file) naming the argument."""

import json
import shutil

import numpy as np
import pytest
import torch

from vtlearn.active.closed_loop import load_xavtnet
from vtlearn.datamodules import ActivePoolDataModule, CrossModalDataModule, ReconstructionDataModule
from vtlearn.datamodules.shards import load_manifest, load_split
from vtlearn.models.actor import ACTOR, load_actor
from vtlearn.models.actor_recognition import load_recognition
from vtlearn.models.xavtnet import XAVTNet
from vtlearn.models.xavtnet_inference import recognize_clouds
from vtlearn.sim_data.writer import sha256_file


def _copy(src, tmp_path, name="bad"):
    dst = tmp_path / name
    shutil.copytree(src, dst)
    return dst


def _edit_manifest(d, fn):
    m = json.loads((d / "manifest.json").read_text())
    m = fn(m)
    (d / "manifest.json").write_text(json.dumps(m))


def _train_shard(d):
    m = json.loads((d / "manifest.json").read_text())
    return next(s["file"] for s in m["shards"] if s["split"] == "train")


# ----------------------------------------------------------------- 1a: unreadable shard
@pytest.mark.parametrize("verify", [True, False])
def test_truncated_shard_is_named_value_error(cross_dir, tmp_path, verify):
    d = _copy(cross_dir, tmp_path)
    name = _train_shard(d)
    f = d / name
    f.write_bytes(f.read_bytes()[:100])

    def fix_sha(m):
        for s in m["shards"]:
            if s["file"] == name:
                s["sha256"] = sha256_file(f)
        return m

    _edit_manifest(d, fix_sha)
    with pytest.raises(ValueError, match=rf"data_dir: shard {name} is unreadable"):
        load_split(d, "train", verify=verify)
    dm = ReconstructionDataModule(str(d), batch_size=2, verify=verify)
    with pytest.raises(ValueError, match="data_dir: shard .* is unreadable"):
        dm.setup("fit")


# ----------------------------------------------------------------- 1b: manifest structure
@pytest.mark.parametrize(
    "text, match",
    [
        ("{not json", "not readable JSON"),
        ("[1, 2]", "JSON list, not an object"),
        (json.dumps({"kind": "crossmodal"}), "no 'class_names' key"),
        (json.dumps({"kind": "crossmodal", "class_names": ["a"], "shards": []}), "no 'splits' key"),
        (json.dumps({"kind": "crossmodal", "class_names": ["a"], "splits": {"train": {}}, "shards": "x"}),
         "'shards' that is not a JSON list"),
    ],
)
def test_bad_manifest_is_named_value_error(cross_dir, tmp_path, text, match):
    d = _copy(cross_dir, tmp_path)
    (d / "manifest.json").write_text(text)
    with pytest.raises(ValueError, match=f"data_dir: .*{match}"):
        load_manifest(d)
    with pytest.raises(ValueError, match=f"data_dir: .*{match}"):
        CrossModalDataModule(str(d))


def test_manifest_shard_outside_dataset_is_rejected(cross_dir, tmp_path):
    d = _copy(cross_dir, tmp_path)
    _edit_manifest(d, lambda m: {**m, "shards": [{**m["shards"][0], "file": "../x.npz"}]})
    with pytest.raises(ValueError, match="data_dir: .*outside the dataset directory"):
        load_manifest(d)


def test_data_dir_none_or_missing(tmp_path):
    with pytest.raises(ValueError, match="data_dir: expected a dataset directory"):
        ReconstructionDataModule(None)
    with pytest.raises(FileNotFoundError, match="data_dir: no manifest.json .*no such directory"):
        ReconstructionDataModule(str(tmp_path / "nope"))


# ----------------------------------------------------------------- 1c: missing shard
def test_missing_shard_names_data_dir_and_shard(cross_dir, tmp_path):
    d = _copy(cross_dir, tmp_path)
    name = _train_shard(d)
    (d / name).unlink()
    with pytest.raises(FileNotFoundError, match=rf"data_dir: shard {name} listed in the manifest is missing"):
        load_split(d, "train")
    dm = CrossModalDataModule(str(d), batch_size=2)
    with pytest.raises(FileNotFoundError, match=f"data_dir: shard {name}"):
        dm.setup("fit")


# ----------------------------------------------------------------- 1d: dataset kind
def test_dataset_kind_is_checked(cross_dir, recon_dir, tmp_path):
    with pytest.raises(ValueError, match="data_dir: .* is a 'reconstruction' dataset, need 'crossmodal'"):
        CrossModalDataModule(str(recon_dir))
    d = _copy(recon_dir, tmp_path)
    _edit_manifest(d, lambda m: {**m, "kind": "tactile-episodes"})
    with pytest.raises(ValueError, match="data_dir: .* 'tactile-episodes' dataset, need 'reconstruction'"):
        ReconstructionDataModule(str(d))
    with pytest.raises(ValueError, match="data_dir: .* is a 'tactile-episodes' dataset"):
        ActivePoolDataModule(str(d), initial_labels=1)
    with pytest.raises(ValueError, match="data_dir: .* no visual clouds; modality='visual'"):
        ActivePoolDataModule(str(recon_dir), initial_labels=1, modality="visual")
    # documented: both datamodules read either gen-data kind
    ReconstructionDataModule(str(cross_dir), batch_size=2)
    ActivePoolDataModule(str(recon_dir), initial_labels=1)


# ----------------------------------------------------------------- 1e: integer settings
@pytest.mark.parametrize("value", ["4", None, 2.5, True, 0])
@pytest.mark.parametrize("cls", ["cross", "recon", "active"])
def test_batch_size_must_be_int(cross_dir, recon_dir, cls, value):
    make = {
        "cross": lambda **k: CrossModalDataModule(str(cross_dir), **k),
        "recon": lambda **k: ReconstructionDataModule(str(recon_dir), **k),
        "active": lambda **k: ActivePoolDataModule(str(cross_dir), initial_labels=1, **k),
    }[cls]
    with pytest.raises(ValueError, match="batch_size: .*integer >= 1"):
        make(batch_size=value)
    with pytest.raises(ValueError, match="num_workers: .*integer >= 0"):
        make(num_workers=-1 if value == 0 else value)


def test_other_int_settings(cross_dir, recon_dir):
    with pytest.raises(ValueError, match="target_batch_size: .*integer >= 1"):
        CrossModalDataModule(str(cross_dir), target_batch_size="8")
    with pytest.raises(ValueError, match="source_views: .*integer >= 1"):
        CrossModalDataModule(str(cross_dir), source_views=1.5)
    with pytest.raises(ValueError, match="min_points: .*integer >= 1"):
        ReconstructionDataModule(str(recon_dir), min_points=2.5)
    with pytest.raises(ValueError, match="max_points: .*integer >= 1"):
        ReconstructionDataModule(str(recon_dir), max_points=None)
    with pytest.raises(ValueError, match="tactile_fraction"):
        ReconstructionDataModule(str(recon_dir), tactile_fraction="0.5")
    dm = CrossModalDataModule(str(cross_dir), batch_size=np.int64(2))  # numpy integers are fine
    assert dm.batch_size == 2 and type(dm.batch_size) is int


# ----------------------------------------------------------------- 1f: active pool
def test_active_pool_initial_labels_and_query_indices(cross_dir):
    with pytest.raises(ValueError, match="initial_labels: .*integer >= 0"):
        ActivePoolDataModule(str(cross_dir), initial_labels=2.5)
    dm = ActivePoolDataModule(str(cross_dir), initial_labels=1)
    free = int(dm.unlabelled_indices[0])
    for bad in ([0.5], np.array([float(free)]), torch.tensor([0.5]), [True], None, "0"):
        with pytest.raises(ValueError, match="indices: "):
            dm.query(bad)
    with pytest.raises(ValueError, match="indices: out of the pool range"):
        dm.query([dm.pool_size])
    assert dm._labelled.sum() == 1  # nothing was labelled by the rejected queries
    dm.query(torch.tensor([free]))
    assert dm._labelled[free]


# ----------------------------------------------------------------- 1g: target_data_dir, empty splits
def test_target_data_dir_is_named(cross_dir, tmp_path):
    with pytest.raises(FileNotFoundError, match="target_data_dir: no manifest.json"):
        CrossModalDataModule(str(cross_dir), target_data_dir=str(tmp_path / "nope"))
    d = _copy(cross_dir, tmp_path)
    (d / _train_shard(d)).unlink()
    dm = CrossModalDataModule(str(cross_dir), target_data_dir=str(d), batch_size=2)
    with pytest.raises(FileNotFoundError, match="target_data_dir: shard"):
        dm.target_dataset()


def test_manifest_without_splits(cross_dir, tmp_path):
    d = _copy(cross_dir, tmp_path)
    _edit_manifest(d, lambda m: {**m, "splits": {}})
    with pytest.raises(ValueError, match="data_dir: the dataset in .* has no splits"):
        CrossModalDataModule(str(d))
    with pytest.raises(ValueError, match="target_data_dir: the dataset in .* has no splits"):
        CrossModalDataModule(str(cross_dir), target_data_dir=str(d))


# ----------------------------------------------------------------- 2: models
TINY_ACTOR = dict(num_points=64, encoder_channels=(8, 8, 16, 32), fc_channels=32,
                  deconv_channels=(16, 16, 8, 8), deconv_strides=(2, 2, 2, 2, 4), emd_points=32)


def _save(model, path):
    torch.save({"state_dict": model.state_dict(), "hyper_parameters": dict(model.hparams),
                "pytorch-lightning_version": "2.0"}, path)
    return path


@pytest.fixture(scope="module")
def ckpts(tmp_path_factory):
    d = tmp_path_factory.mktemp("ckpts")
    torch.manual_seed(0)
    actor = ACTOR(**TINY_ACTOR)
    xav = XAVTNet(num_classes=3, global_dim=32, fc_dims=[16, 8], dropout=0.4, class_names=["a", "b", "c"])
    return {"actor": _save(actor, d / "actor.ckpt"), "xavtnet": _save(xav, d / "x.ckpt"),
            "actor_model": actor.eval(), "xavtnet_model": xav.eval()}


def _cloud(n=40):
    return np.random.default_rng(0).normal(size=(n, 3)) * 0.05


def test_recognize_clouds_model_clouds_mc_samples(ckpts):
    model = ckpts["xavtnet_model"]
    with pytest.raises(ValueError, match="model: expected an XAVTNet"):
        recognize_clouds(ckpts["actor_model"], [_cloud()])
    for bad in (None, 3, "abc"):
        with pytest.raises(ValueError, match="clouds: expected a list of"):
            recognize_clouds(model, bad)
    for single in (_cloud(), torch.as_tensor(_cloud())):  # one cloud, numpy or torch, not a list of them
        with pytest.raises(ValueError, match="clouds: expected a list of .* wrap it in a list"):
            recognize_clouds(model, single)
    with pytest.raises(ValueError, match="extent_m: clouds\\[0\\] spans .* millimetres"):
        recognize_clouds(model, [_cloud() * 1000.0], extent_m=0.15)
    for bad in ("x", 2.5, -1, None):
        with pytest.raises(ValueError, match="mc_samples: need an integer >= 0"):
            recognize_clouds(model, [_cloud()], mc_samples=bad)
    assert recognize_clouds(model, [_cloud()], mc_samples=np.int64(2)).mc_samples == 2


def test_load_recognition_rejects_xavtnet_checkpoint(ckpts):
    with pytest.raises(ValueError, match="ckpt: .* is an XAVTNet checkpoint, not an ACTOR recognition one"):
        load_recognition(ckpts["xavtnet"])


def test_load_xavtnet_bad_hparams_named(ckpts, tmp_path):
    d = torch.load(ckpts["xavtnet"], weights_only=True)
    d["hyper_parameters"]["num_classes"] = 5
    torch.save(d, tmp_path / "bad.ckpt")
    with pytest.raises(ValueError, match="ckpt: .* does not match the xAVTNet architecture"):
        load_xavtnet(tmp_path / "bad.ckpt")


def test_map_location_is_checked(ckpts):
    with pytest.raises(ValueError, match="map_location: expected a torch device"):
        load_actor(ckpts["actor"], map_location="bogus")
    with pytest.raises(ValueError, match="map_location: expected a torch device"):
        load_recognition(ckpts["xavtnet"], map_location=3.5)
    assert isinstance(load_actor(ckpts["actor"], map_location=torch.device("cpu")), ACTOR)


@pytest.mark.parametrize("kind", ["actor", "xavtnet"])
def test_checkpoint_with_non_finite_weights_is_refused(ckpts, tmp_path, kind):
    d = torch.load(ckpts[kind], weights_only=True)
    key = next(k for k, v in d["state_dict"].items() if v.is_floating_point() and v.numel() > 1)
    d["state_dict"][key] = d["state_dict"][key].clone()
    d["state_dict"][key].view(-1)[0] = float("nan")
    torch.save(d, tmp_path / "nan.ckpt")
    load = load_actor if kind == "actor" else load_xavtnet
    with pytest.raises(ValueError, match=f"ckpt: .* NaN or inf weights in 1 tensor\\(s\\), first '{key}'"):
        load(tmp_path / "nan.ckpt")
    load(ckpts[kind])  # the finite original still loads
