"""Datamodules over tiny generated datasets: batch contract, splits, active-learning pool."""

import numpy as np
import pytest
import torch

from vtlearn.datamodules import ActivePoolDataModule, CrossModalDataModule, ReconstructionDataModule
from vtlearn.datamodules.shards import load_split, random_voxel_subsample


def test_reconstruction_batch_contract(recon_dir):
    dm = ReconstructionDataModule(str(recon_dir), batch_size=2, min_points=40, max_points=120)
    dm.setup("fit")
    assert dm.num_classes == 3 and dm.class_names == ["mug", "bottle", "box"]
    for loader in (dm.train_dataloader(), dm.val_dataloader(), dm.test_dataloader()):
        b = next(iter(loader))
        assert set(b) == {"sparse", "lengths", "dense", "label"}
        B = len(b["label"])
        assert b["sparse"].dtype == torch.float32 and b["sparse"].shape[0] == B and b["sparse"].shape[2] == 3
        assert b["dense"].shape == (B, 2048, 3) and b["dense"].dtype == torch.float32
        assert b["lengths"].dtype == torch.int64 and b["label"].dtype == torch.int64
        assert ((b["lengths"] >= 40) & (b["lengths"] <= 120)).all()
        assert b["sparse"].shape[1] == b["lengths"].max()
        for i in range(B):  # padding is zeros beyond each length
            assert torch.all(b["sparse"][i, b["lengths"][i] :] == 0)


def test_reconstruction_sparse_lies_near_dense_and_rotation_is_about_z(recon_dir):
    dm = ReconstructionDataModule(str(recon_dir), batch_size=3)
    b = next(iter(dm.test_dataloader()))
    for i in range(len(b["label"])):
        s, d = b["sparse"][i, : b["lengths"][i]], b["dense"][i]
        # voxel centroids of a surface sample stay within a voxel of the dense points
        assert torch.cdist(s, d).min(1).values.max() < 0.1
    raw = load_split(recon_dir, "test")["dense"][0]
    # a z-rotation keeps heights and radial distances from the z-axis
    np.testing.assert_allclose(np.sort(b["dense"][0, :, 2].numpy()), np.sort(raw[:, 2]), atol=1e-5)
    np.testing.assert_allclose(
        np.sort(np.linalg.norm(b["dense"][0, :, :2].numpy(), axis=1)),
        np.sort(np.linalg.norm(raw[:, :2], axis=1)),
        atol=1e-5,
    )


def test_eval_batches_are_deterministic_train_batches_are_not(recon_dir):
    dm = ReconstructionDataModule(str(recon_dir), batch_size=3)
    a, b = next(iter(dm.test_dataloader())), next(iter(dm.test_dataloader()))
    assert torch.equal(a["sparse"], b["sparse"])
    torch.manual_seed(0)
    t1 = next(iter(dm.train_dataloader()))
    torch.manual_seed(1)
    t2 = next(iter(dm.train_dataloader()))
    assert not torch.equal(t1["dense"], t2["dense"])


def test_tactile_test_loader_feeds_stored_tactile_clouds(recon_dir):
    dm = ReconstructionDataModule(str(recon_dir), batch_size=3)
    b = next(iter(dm.tactile_test_dataloader()))
    assert (b["lengths"] > 0).all()
    # tactile points are in the canonical frame of the instance: inside the (rotated) unit cube
    assert b["sparse"].abs().max() < 0.75


def test_tactile_fraction_mixes_stored_touches_into_training_only(recon_dir):
    d = load_split(recon_dir, "train")
    from vtlearn.datamodules.shards import split_clouds

    clouds = split_clouds(d["tactile_points"], d["tactile_offsets"])
    dm = ReconstructionDataModule(
        str(recon_dir), batch_size=2, min_points=5, max_points=10, rotate_z=False, tactile_fraction=1.0
    )
    ds = dm._dataset("train")
    for i in range(len(ds)):
        sparse = ds[i]["sparse"].astype(np.float64)
        inst = d["instance"][i]
        own = np.concatenate([c for c, j in zip(clouds, d["tactile_instance"], strict=True) if j == inst])
        assert 5 <= len(sparse) <= 10 or len(sparse) == len(own)
        # every input point is one of the instance's stored tactile points (not a voxel centroid)
        dist = np.linalg.norm(sparse[:, None] - own[None], axis=-1).min(1)
        assert dist.max() < 1e-6
    # the test split keeps the voxel protocol: its points are voxel centroids of the dense cloud
    test = dm._dataset("test")
    assert test.tactile_fraction == 0.0 and test.tactile is None
    with pytest.raises(ValueError, match="tactile_fraction"):
        ReconstructionDataModule(str(recon_dir), tactile_fraction=1.5)


def test_random_voxel_subsample_range_and_validation():
    rng = np.random.default_rng(0)
    pts = rng.normal(size=(2048, 3))
    for _ in range(20):
        out = random_voxel_subsample(pts, 40, 120, rng)
        assert 40 <= len(out) <= 120
    with pytest.raises(ValueError, match="n_min"):
        random_voxel_subsample(pts, 50, 10, rng)


def test_crossmodal_batches(cross_dir):
    dm = CrossModalDataModule(str(cross_dir), batch_size=2)
    dm.setup("fit")
    assert dm.num_classes == 3
    batch = next(iter(dm.train_dataloader()))[0]
    assert set(batch) == {"source", "target"}
    src, tgt = batch["source"], batch["target"]
    assert (
        src["points"].shape == (2, 1024, 3)
        and (src["lengths"] == 1024).all()
        and src["label"].dtype == torch.int64
    )
    assert set(tgt) == {"points", "lengths", "index", "group"}  # target labels never reach training
    assert sorted(tgt["index"].tolist()) == sorted(set(tgt["index"].tolist()))  # positions in the stream
    assert ((tgt["lengths"] >= 30) & (tgt["lengths"] <= 120)).all()
    for loader in (dm.val_dataloader(), dm.test_dataloader(), dm.source_test_dataloader()):
        b = next(iter(loader))
        assert set(b) == {"points", "lengths", "label"}
        assert torch.allclose(
            b["points"].sum(1) / b["lengths"][:, None], torch.zeros(3), atol=1e-5
        )  # centred


def test_crossmodal_target_batch_size_sets_the_target_stream_only(cross_dir):
    dm = CrossModalDataModule(str(cross_dir), batch_size=2, target_batch_size=3)
    dm.setup("fit")
    batch = next(iter(dm.train_dataloader()))[0]
    assert batch["source"]["points"].shape[0] == 2 and batch["target"]["points"].shape[0] == 3
    assert dm.target_dataloader().batch_size == 3  # AdaBN reads the same stream
    assert dm.test_dataloader().batch_size == dm.source_test_dataloader().batch_size == 2
    assert CrossModalDataModule(str(cross_dir), batch_size=2).target_dataloader().batch_size == 2
    with pytest.raises(ValueError, match="target_batch_size"):
        CrossModalDataModule(str(cross_dir), target_batch_size=0)


def test_crossmodal_target_split(cross_dir):
    """The unlabelled target stream holds the chosen split's tactile clouds (yaw-augmented, no labels);
    the labelled test loader is unchanged."""
    def target_sizes(dm):
        target = dm.train_dataloader().iterables["target"]
        assert target.dataset.train and not target.dataset.with_label
        return sorted(len(c) for c in target.dataset.clouds)

    inductive = CrossModalDataModule(str(cross_dir), batch_size=2)
    transductive = CrossModalDataModule(str(cross_dir), batch_size=2, target_split="test")
    test_sizes = sorted(len(c) for c in transductive.dataset("test", "tactile").clouds)
    assert target_sizes(transductive) == test_sizes != target_sizes(inductive)
    assert len(transductive.test_dataloader().dataset) == len(inductive.test_dataloader().dataset)
    with pytest.raises(ValueError, match="target_split"):
        CrossModalDataModule(str(cross_dir), target_split="val")


def test_crossmodal_target_split_train_plus_test_is_one_indexed_stream_of_both(cross_dir):
    """``target_split="train+test"``: the target stream holds every tactile cloud of both splits, the
    training ones first, each with its own index (pseudo-labels and neighbour banks key on it); the
    labelled test loader is unchanged."""
    both = CrossModalDataModule(str(cross_dir), batch_size=2, target_split="train+test")
    ds = both.target_dataset()
    train = [len(c) for c in both.dataset("train", "tactile").clouds]
    test = [len(c) for c in both.dataset("test", "tactile").clouds]
    assert [len(c) for c in ds.clouds] == train + test
    assert not ds.with_label and ds.train
    assert sorted(int(ds[i]["index"]) for i in range(len(ds))) == list(range(len(train) + len(test)))
    assert len(both.test_dataloader().dataset) == len(test)
    with pytest.raises(ValueError, match="target_split"):
        CrossModalDataModule(str(cross_dir), target_split="test+val")


def test_crossmodal_target_items_carry_their_object_instance(cross_dir):
    """Every target stream's item carries ``"group"``, the instance its tactile cloud was touched on (no
    label), for each way of drawing the stream: one split, both splits, and with clouds held out."""
    tr, te = load_split(cross_dir, "train"), load_split(cross_dir, "test")
    for kwargs, expected in [
        ({"target_split": "test"}, te["tactile_instance"]),
        ({"target_split": "train"}, tr["tactile_instance"]),
        ({"target_split": "train+test"}, np.concatenate([tr["tactile_instance"], te["tactile_instance"]])),
    ]:
        ds = CrossModalDataModule(str(cross_dir), **kwargs).target_dataset()
        assert [ds[i]["group"] for i in range(len(ds))] == expected.tolist()
        assert "label" not in ds[0]
    held = CrossModalDataModule(str(cross_dir), target_split="test", target_holdout=0.5)
    ds = held.target_dataset()
    assert [ds[i]["group"] for i in range(len(ds))] == te["tactile_instance"][~held.holdout_mask()].tolist()
    batch = next(iter(held.target_dataloader(shuffle=False)))
    assert batch["group"].dtype == torch.int64
    kept = te["tactile_instance"][~held.holdout_mask()]
    assert batch["group"].tolist() == kept[: len(batch["group"])].tolist()
    assert "group" not in held.dataset("test", "tactile")[0]  # the labelled loaders are unchanged
    from vtlearn.datamodules.crossmodal import CloudDataset

    with pytest.raises(ValueError, match="groups: with_group"):
        CloudDataset([np.zeros((4, 3))], None, train=False, with_label=False, with_group=True)


def test_crossmodal_source_splits_add_the_test_objects_to_the_labelled_source(cross_dir):
    """``source_splits=["train", "test"]`` (the thesis's known-objects protocol) puts every visual cloud of
    both splits, with its label and instance, into the source; the tactile test clouds stay the same."""
    plain = CrossModalDataModule(str(cross_dir), batch_size=2, rotate_z=False, normalize="none")
    known = CrossModalDataModule(str(cross_dir), batch_size=2, rotate_z=False, normalize="none",
                                 source_splits=["train", "test"], target_split="test")
    tr, te = load_split(cross_dir, "train"), load_split(cross_dir, "test")
    ds = known.source_train_dataset()
    assert len(ds) == len(tr["visual"]) + len(te["visual"])
    assert len(plain.source_train_dataset()) == len(tr["visual"])
    np.testing.assert_array_equal(ds.labels, np.concatenate([tr["visual_label"], te["visual_label"]]))
    np.testing.assert_array_equal(ds[len(tr["visual"])]["points"], te["visual"][0].astype(np.float32))
    fused = CrossModalDataModule(str(cross_dir), rotate_z=False, normalize="none", source_views=2,
                                 source_splits=["train", "test"]).source_train_dataset()
    mates = te["visual"][te["visual_instance"] == te["visual_instance"][0]]
    pts = {tuple(q) for q in np.round(fused[len(tr["visual"])]["points"], 5)}
    assert pts <= {tuple(q) for v in mates for q in np.round(v, 5)}  # fused with its own instance's views
    a, b = next(iter(plain.test_dataloader())), next(iter(known.test_dataloader()))
    assert torch.equal(a["points"], b["points"])
    # the class frequencies of the source, as the balanced predictions assume them
    both = np.concatenate([tr["visual_label"], te["visual_label"]])
    prior = known.source_class_prior()
    assert prior.shape == (known.num_classes,)
    np.testing.assert_allclose(prior, np.bincount(both, minlength=known.num_classes) / len(both))
    for bad in (["val2"], [], ["train", "train"]):
        with pytest.raises(ValueError, match="source_splits"):
            CrossModalDataModule(str(cross_dir), source_splits=bad)


def test_crossmodal_target_holdout_splits_each_test_instance_between_stream_and_test(cross_dir):
    """``target_holdout`` (the thesis's 900 + 300 split of the tactile clouds of its objects) puts every
    test tactile cloud in exactly one of the target stream and the test set, holds out at least one and
    keeps at least one per instance, repeats for a seed, and is refused by name where it cannot apply."""
    te = load_split(cross_dir, "test")
    everything = {c.astype(np.float32).tobytes() for c in
                  CrossModalDataModule(str(cross_dir), rotate_z=False, normalize="none", target_split="test")
                  .dataset("test", "tactile").clouds}

    def parts(seed):
        dm = CrossModalDataModule(str(cross_dir), rotate_z=False, normalize="none", target_split="test",
                                  target_holdout=0.5, seed=seed)
        stream = [c.astype(np.float32).tobytes() for c in dm.target_dataset().clouds]
        test = dm.test_dataloader().dataset
        return dm, stream, [c.astype(np.float32).tobytes() for c in test.clouds], test

    dm, stream, test, test_ds = parts(0)
    assert set(stream).isdisjoint(test) and set(stream) | set(test) == everything
    mask = dm.holdout_mask()
    assert mask.shape == (len(te["tactile_label"]),)
    for k in np.unique(te["tactile_instance"]):  # two clouds per instance: one each way
        assert mask[te["tactile_instance"] == k].sum() == 1
    np.testing.assert_array_equal(test_ds.labels, te["tactile_label"][mask])
    assert "label" not in dm.target_dataset()[0]
    # the tactile_oracle bound trains on the stream's own clouds, labelled, and never on the held-out ones
    oracle = dm.labelled_target_train_dataloader().dataset
    assert sorted(c.astype(np.float32).tobytes() for c in oracle.clouds) == sorted(stream)
    np.testing.assert_array_equal(oracle.labels, te["tactile_label"][~mask])
    assert parts(0)[2] == test  # the same seed holds out the same clouds
    assert not CrossModalDataModule(str(cross_dir), target_split="test").holdout_mask().any()
    for kwargs in ({"target_holdout": 1.0, "target_split": "test"}, {"target_holdout": -0.1},
                   {"target_holdout": 0.25, "target_split": "train"}):
        with pytest.raises(ValueError, match="target_holdout"):
            CrossModalDataModule(str(cross_dir), **kwargs)


def test_crossmodal_source_points_thins_training_visual_clouds_only(cross_dir):
    """``source_points`` thins each drawn visual training cloud to the tactile density; the labelled
    visual and tactile evaluation clouds stay as stored, and a bad range is refused by name."""
    dense = CrossModalDataModule(str(cross_dir), batch_size=4)
    thin = CrossModalDataModule(str(cross_dir), batch_size=4, source_points=[30, 60])
    src = next(iter(thin.train_dataloader()))[0]["source"]
    assert ((src["lengths"] >= 30) & (src["lengths"] <= 60)).all()
    assert src["label"].dtype == torch.int64
    for a, b in ((dense.source_test_dataloader(), thin.source_test_dataloader()),
                 (dense.test_dataloader(), thin.test_dataloader())):
        ba, bb = next(iter(a)), next(iter(b))
        assert torch.equal(ba["lengths"], bb["lengths"]) and torch.equal(ba["points"], bb["points"])
    # The thinned points are voxel centroids of the (rotated, then centred) dense cloud: inside its hull.
    cloud = thin.source_train_dataset().clouds[0]
    r_dense = np.linalg.norm(cloud - cloud.mean(0), axis=1).max()
    item = thin.source_train_dataset()[0]["points"]
    assert 30 <= len(item) <= 60 and np.linalg.norm(item, axis=1).max() <= 2 * r_dense
    for bad, match in (([60, 30], "source_points"), ([0, 10], "source_points"), ("x", "source_points")):
        with pytest.raises(ValueError, match=match):
            CrossModalDataModule(str(cross_dir), source_points=bad)


def test_crossmodal_source_views_fuses_views_of_the_same_instance(cross_dir):
    """``source_views=k`` joins each drawn visual training cloud with other views of its own instance (never
    another instance's), keeps its point count, and leaves the evaluation clouds alone."""
    dm = CrossModalDataModule(str(cross_dir), batch_size=4, source_views=2, rotate_z=False, normalize="none")
    d = load_split(cross_dir, "train")
    ds = dm.source_train_dataset()
    inst = d["visual_instance"]
    for j in range(len(inst)):
        item = ds[j]["points"]
        assert item.shape == d["visual"][j].shape
        own = {tuple(p) for p in np.round(d["visual"][j], 5)}
        mates = {tuple(p) for o in np.flatnonzero(inst == inst[j]) for p in np.round(d["visual"][o], 5)}
        pts = {tuple(p) for p in np.round(item, 5)}
        assert pts <= mates  # only views of the same instance
        if (inst == inst[j]).sum() > 1:
            assert not pts <= own  # another view was fused in
    plain = CrossModalDataModule(str(cross_dir), batch_size=4)
    a, b = next(iter(plain.source_test_dataloader())), next(iter(dm.source_test_dataloader()))
    assert torch.equal(a["lengths"], b["lengths"])
    with pytest.raises(ValueError, match="source_views"):
        CrossModalDataModule(str(cross_dir), source_views=0)


def test_crossmodal_source_touch_turns_visual_clouds_into_pad_contacts(cross_dir):
    """``source_touch``: each visual training cloud becomes 30-120 pad contacts on its fused views (points
    of the instance's surface, up to the cell averaging), with the Xela pitch in canonical units."""
    from scipy.spatial import cKDTree

    dm = CrossModalDataModule(str(cross_dir), source_views=2, source_touch=True, rotate_z=False,
                              normalize="none")
    ds = dm.source_train_dataset()
    d = load_split(cross_dir, "train")
    scale = dict(zip(d["instance"].tolist(), d["scale_m"].tolist(), strict=True))
    assert ds.touch_pitch[0] == pytest.approx(0.0047 / scale[int(d["visual_instance"][0])])
    for j in range(len(ds)):
        pts = ds[j]["points"]
        assert 30 <= len(pts) <= 120
        views = np.concatenate([d["visual"][o] for o in np.flatnonzero(d["visual_instance"] ==
                                                                      d["visual_instance"][j])])
        # a contact is the mean of a taxel cell's points: within a cell's diagonal of the views
        assert cKDTree(views).query(pts)[0].max() <= 1.5 * ds.touch_pitch[j]
    with pytest.raises(ValueError, match="touch_pitch"):
        from vtlearn.datamodules.crossmodal import CloudDataset

        CloudDataset([np.zeros((4, 3))], np.zeros(1), train=True, touch_pitch=np.ones(1))


def test_crossmodal_rejects_reconstruction_dataset(recon_dir):
    with pytest.raises(ValueError, match="data_dir"):
        CrossModalDataModule(str(recon_dir))
    with pytest.raises(ValueError, match="normalize"):
        CrossModalDataModule(str(recon_dir), normalize="bogus")


def test_splits_are_by_instance(cross_dir):
    inst = {s: set(load_split(cross_dir, s)["instance"].tolist()) for s in ("train", "val", "test")}
    assert inst["train"] and inst["val"] and inst["test"]
    assert (
        not (inst["train"] & inst["val"])
        and not (inst["train"] & inst["test"])
        and not (inst["val"] & inst["test"])
    )
    d = load_split(cross_dir, "train")
    assert (
        set(d["tactile_instance"].tolist()) <= inst["train"]
        and set(d["visual_instance"].tolist()) <= inst["train"]
    )


def test_active_pool_query(cross_dir):
    dm = ActivePoolDataModule(str(cross_dir), initial_labels=2, seed=0, batch_size=64)
    n = dm.pool_size
    assert len(dm.labelled_indices) == 2 and len(dm.unlabelled_indices) == n - 2
    b = next(iter(dm.unlabelled_dataloader()))
    assert set(b) == {"points", "lengths", "index"}
    assert sorted(b["index"].tolist()) == dm.unlabelled_indices.tolist()
    truth = load_split(cross_dir, "train")["tactile_label"]
    pick = b["index"][:2]
    labels = dm.query(pick)
    assert labels.tolist() == truth[pick.numpy()].tolist()
    assert len(dm.labelled_indices) == 4 and not set(pick.tolist()) & set(dm.unlabelled_indices.tolist())
    tb = next(iter(dm.train_dataloader()))
    assert len(tb["label"]) == 4 and set(tb) == {"points", "lengths", "label"}
    with pytest.raises(ValueError, match="indices"):
        dm.query(pick)  # already labelled
    with pytest.raises(ValueError, match="indices"):
        dm.query([n + 5])
    assert set(next(iter(dm.test_dataloader()))) == {"points", "lengths", "label"}
    with pytest.raises(ValueError, match="initial_labels"):
        ActivePoolDataModule(str(cross_dir), initial_labels=n + 1)


def test_a_large_split_loads_under_a_progress_bar(recon_dir, monkeypatch, capsys):
    import vtlearn.datamodules.shards as shards

    load_split(recon_dir, "train")
    assert "loading train" not in capsys.readouterr().err  # small: no bar
    monkeypatch.setattr(shards, "PROGRESS_BYTES", 1)
    a = load_split(recon_dir, "train")
    assert "loading train" in capsys.readouterr().err and len(a["label"]) > 0


def test_dataset_fingerprint_follows_the_shards_not_the_folder(cross_dir, tmp_path):
    """The fingerprint is the same for a copy of a dataset, changes when a shard's recorded checksum does,
    and is refused (by name) for a manifest whose shards carry no checksum."""
    import json
    import shutil

    from vtlearn.datamodules.shards import dataset_fingerprint

    fp = dataset_fingerprint(cross_dir)
    assert len(fp) == 16 and int(fp, 16) >= 0
    copy = tmp_path / "copy"
    shutil.copytree(cross_dir, copy)
    assert dataset_fingerprint(copy) == fp
    manifest = json.loads((copy / "manifest.json").read_text())
    manifest["shards"].reverse()  # the order the manifest lists them in does not matter
    (copy / "manifest.json").write_text(json.dumps(manifest))
    assert dataset_fingerprint(copy) == fp
    manifest["shards"][0]["sha256"] = "0" * 64
    (copy / "manifest.json").write_text(json.dumps(manifest))
    assert dataset_fingerprint(copy) != fp
    del manifest["shards"][0]["sha256"]
    (copy / "manifest.json").write_text(json.dumps(manifest))
    with pytest.raises(ValueError, match="data_dir: .*no sha256 for shard"):
        dataset_fingerprint(copy)
    with pytest.raises(FileNotFoundError, match="target_data_dir"):
        dataset_fingerprint(tmp_path / "none", "target_data_dir")
