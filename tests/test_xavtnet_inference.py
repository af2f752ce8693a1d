"""xAVTNet checkpoint inference: the input frame, MC-dropout uncertainty (eq. 7.3-7.4), the class names a
checkpoint keeps, and `vtlearn recognize`."""

import json
import os

import numpy as np
import pytest
import torch

from vtlearn.models.xavtnet import XAVTNet
from vtlearn.models.xavtnet_inference import (
    canonical_cloud,
    checkpoint_class_names,
    recognize_clouds,
)

os.environ.setdefault("WANDB_MODE", "disabled")


@pytest.fixture(scope="module")
def tiny_crossmodal(tmp_path_factory):
    from vtlearn.sim_data.fixtures import make_tiny_dataset

    return make_tiny_dataset("crossmodal", tmp_path_factory.mktemp("cross"))


def _model(num_classes=3, **kw):
    torch.manual_seed(0)
    return XAVTNet(num_classes=num_classes, global_dim=32, fc_dims=[16, 8], dropout=0.4, **kw).eval()


def _cloud(seed=0, n=40):
    rng = np.random.default_rng(seed)
    return rng.normal(size=(n, 3)) * [0.03, 0.03, 0.06] + [0.5, -0.2, 0.8]


def test_canonical_cloud_centres_on_the_box_and_divides_by_the_extent():
    pts = np.array([[0.0, 0.0, 0.0], [0.2, 0.1, 0.0], [0.1, 0.0, 0.4]])
    out = canonical_cloud(pts + [1.0, 2.0, 3.0], extent_m=0.5)
    np.testing.assert_allclose(out, (pts - [0.1, 0.05, 0.2]) / 0.5)
    np.testing.assert_allclose(canonical_cloud(pts), (pts - [0.1, 0.05, 0.2]) / 0.4)  # own extent: z
    np.testing.assert_allclose(canonical_cloud(pts, extent_m=9.0, units="canonical"), pts - [0.1, 0.05, 0.2])


@pytest.mark.parametrize(
    "kwargs, match",
    [
        ({"points": np.zeros((0, 3))}, "points: point cloud is empty"),
        ({"points": np.ones((2, 3))}, "points: point cloud has only 2 points"),
        ({"points": np.array([[0, 0, 0], [1, 1, np.nan], [0, 1, 0]])}, "points: contains NaN"),
        ({"points": np.zeros((5, 2))}, r"points: expected shape \(N, 3\)"),
        ({"points": np.ones((5, 3))}, "points coincide"),
        ({"points": _cloud(), "extent_m": 0.0}, r"extent_m: need a finite number > 0 \(m\)"),
        ({"points": _cloud(), "extent_m": float("nan")}, r"extent_m: need a finite number > 0 \(m\)"),
        ({"points": _cloud(), "units": "mm"}, "units: expected one of"),
    ],
)
def test_canonical_cloud_rejects_bad_input_by_name(kwargs, match):
    with pytest.raises(ValueError, match=match):
        canonical_cloud(**kwargs)


def test_deterministic_pass_is_the_softmax_of_the_centred_canonical_cloud():
    model = _model()
    clouds = [_cloud(0), _cloud(1, n=25)]
    res = recognize_clouds(model, clouds, extent_m=0.3, mc_samples=0)
    assert res.mutual_information is None and res.std is None
    for i, c in enumerate(clouds):
        x = canonical_cloud(c, 0.3)
        x = torch.as_tensor(x - x.mean(0), dtype=torch.float32)[None]
        with torch.no_grad():
            p = torch.softmax(model(x).logits, -1).numpy()[0]
        np.testing.assert_allclose(res.probs[i], p, atol=1e-5)
        assert res.entropy[i] == pytest.approx(-(p * np.log(p)).sum(), abs=1e-5)
    assert res.class_names == ["class_0", "class_1", "class_2"]


def test_metres_with_the_object_extent_equal_the_canonical_cloud():
    model = _model()
    canon, extent = _cloud(2) / 0.3, 0.3  # the same cloud, canonical and in metres
    a = recognize_clouds(model, [canon], units="canonical").probs
    b = recognize_clouds(model, [canon * extent + [2.0, 1.0, 0.5]], extent_m=extent).probs
    np.testing.assert_allclose(a, b, atol=1e-5)


def test_mc_dropout_mean_entropy_and_mutual_information():
    model = _model()
    model.train()  # recognize_clouds must not depend on, nor change, the caller's mode
    clouds = [_cloud(3), _cloud(4)]
    res = recognize_clouds(model, clouds, mc_samples=16, seed=5)
    assert model.training
    assert res.probs.shape == (2, 3) and np.allclose(res.probs.sum(1), 1.0)
    assert (res.mutual_information >= 0).all() and (res.mutual_information <= res.entropy + 1e-9).all()
    assert (res.std > 0).any()  # dropout on: passes differ
    again = recognize_clouds(model, clouds, mc_samples=16, seed=5)
    np.testing.assert_array_equal(res.probs, again.probs)  # the seed fixes the masks
    other = recognize_clouds(model, clouds, mc_samples=16, seed=6)
    assert not np.array_equal(res.probs, other.probs)
    model.eval()
    det = recognize_clouds(model, clouds, mc_samples=0).probs
    assert np.abs(res.probs - det).max() < 0.5  # the MC mean stays near the deterministic pass


def test_recognize_rejects_bad_arguments_by_name():
    model = _model()
    with pytest.raises(ValueError, match="clouds: empty"):
        recognize_clouds(model, [])
    with pytest.raises(ValueError, match="clouds: expected a list"):
        recognize_clouds(model, _cloud())
    with pytest.raises(ValueError, match=r"clouds\[1\]: contains NaN"):
        recognize_clouds(model, [_cloud(), np.full((4, 3), np.nan)])
    with pytest.raises(ValueError, match="mc_samples"):
        recognize_clouds(model, [_cloud()], mc_samples=-1)
    with pytest.raises(ValueError, match="extent_m: 1 extents for 2 clouds"):
        recognize_clouds(model, [_cloud(), _cloud(1)], extent_m=[0.2])
    with pytest.raises(ValueError, match="class_names: 2 names"):
        recognize_clouds(model, [_cloud()], class_names=["a", "b"])


def test_checkpoint_keeps_the_datamodule_class_names(tmp_path, tiny_crossmodal):
    import lightning as L

    from vtlearn.datamodules import CrossModalDataModule
    from vtlearn.models.xavtnet import load_xavtnet

    with pytest.raises(ValueError, match="class_names: 1 names for num_classes=3"):
        XAVTNet(num_classes=3, class_names=["a"])
    dm = CrossModalDataModule(str(tiny_crossmodal), batch_size=4)
    model = XAVTNet(num_classes=dm.num_classes, global_dim=32, fc_dims=[16, 8], max_points=64)
    trainer = L.Trainer(fast_dev_run=1, accelerator="cpu", logger=False, enable_progress_bar=False,
                        enable_model_summary=False, default_root_dir=tmp_path)
    trainer.fit(model, datamodule=dm)
    path = tmp_path / "m.ckpt"
    trainer.save_checkpoint(path)
    hp = torch.load(path, weights_only=True, map_location="cpu")["hyper_parameters"]
    assert hp["class_names"] == dm.class_names
    loaded = load_xavtnet(path)
    assert checkpoint_class_names(dict(loaded.hparams)) == dm.class_names
    assert checkpoint_class_names(dict(loaded.hparams), ["x"] * dm.num_classes) == ["x"] * dm.num_classes
    # a model that already names its classes refuses a datamodule with other names
    wrong = XAVTNet(num_classes=dm.num_classes, global_dim=32, fc_dims=[16, 8],
                    class_names=[f"n{i}" for i in range(dm.num_classes)])
    with pytest.raises(ValueError, match="differ from the datamodule"):
        L.Trainer(fast_dev_run=1, accelerator="cpu", logger=False, enable_progress_bar=False,
                  enable_model_summary=False, default_root_dir=tmp_path).fit(wrong, datamodule=dm)


def test_recognize_command_on_files_and_on_stored_clouds(tmp_path, tiny_crossmodal, capsys):
    from vtlearn.cli import main
    from vtlearn.datamodules.crossmodal import modality_clouds
    from vtlearn.datamodules.shards import load_manifest, load_split
    from vtlearn.io import write_cloud

    model = _model(num_classes=len(load_manifest(tiny_crossmodal)["class_names"]))
    ckpt = tmp_path / "x.ckpt"
    torch.save({"state_dict": model.state_dict(), "hyper_parameters": dict(model.hparams)}, ckpt)
    clouds, labels, _ = modality_clouds(load_split(tiny_crossmodal, "test"), "tactile", False)
    names = load_manifest(tiny_crossmodal)["class_names"]

    out = tmp_path / "stored.json"
    assert main(["recognize", "--ckpt", str(ckpt), "--data", str(tiny_crossmodal), "--index", "0", "1",
                 "--mc-samples", "4", "--json", str(out), "--figure", str(tmp_path / "f.png")]) == 0
    text = capsys.readouterr().out
    assert f"(true: {names[int(labels[0])]})" in text and "/2 right" in text
    rows = json.loads(out.read_text())["results"]
    assert [r["true"] for r in rows] == [names[int(labels[i])] for i in (0, 1)]
    assert set(rows[0]["class_probabilities"]) == set(names) and "mutual_information_nats" in rows[0]
    assert (tmp_path / "f.png").stat().st_size > 0

    # the same cloud from a file in metres, with the object's extent, gives the same probabilities
    assert main(["recognize", "--ckpt", str(ckpt), "--data", str(tiny_crossmodal), "--index", "0",
                 "--mc-samples", "0", "--json", str(out)]) == 0
    stored = json.loads(out.read_text())["results"][0]
    assert "mutual_information_nats" not in stored
    f = tmp_path / "c.npy"
    write_cloud(f, clouds[0] * 0.25 + [0.4, 0.1, 0.7])
    out2 = tmp_path / "file.json"
    assert main(["recognize", "--ckpt", str(ckpt), str(f), "--extent-m", "0.25", "--mc-samples", "0",
                 "--class-names", ",".join(names), "--json", str(out2)]) == 0
    row = json.loads(out2.read_text())["results"][0]
    for k, v in stored["class_probabilities"].items():
        assert row["class_probabilities"][k] == pytest.approx(v, abs=1e-5)

    capsys.readouterr()
    assert main(["recognize", "--ckpt", str(ckpt)]) == 2
    assert "inputs: give cloud files" in capsys.readouterr().err
    assert main(["recognize", "--ckpt", str(ckpt), "--data", str(tiny_crossmodal), "--index", "999"]) == 2
    assert "--index: [999] out of range" in capsys.readouterr().err
    assert main(["recognize", "--ckpt", str(tmp_path / "none.ckpt"), str(f)]) == 2
    assert "--ckpt: no checkpoint" in capsys.readouterr().err
    assert main(["recognize", "--ckpt", str(ckpt), str(tmp_path / "missing.ply")]) == 2
    assert main(["recognize", "--ckpt", str(ckpt), str(f), "--class-names", "a,b"]) == 2
    assert "--class-names: 2 names" in capsys.readouterr().err
    bad = tmp_path / "bad.json"
    bad.write_text("{}")
    assert main(["recognize", "--ckpt", str(ckpt), str(f), "--class-names", str(bad)]) == 2
    assert "has no 'class_names' list" in capsys.readouterr().err


def _object_frame_cloud(seed=0, n=40):
    """Touches near the top rim of a unit box, in the object frame: far from centred on themselves."""
    rng = np.random.default_rng(seed)
    return rng.normal(size=(n, 3)) * [0.05, 0.05, 0.02] + [0.3, 0.0, 0.45]


def test_the_checkpoint_records_the_datamodule_normalisation(tmp_path, tiny_crossmodal):
    import lightning as L

    from vtlearn.active.closed_loop import load_xavtnet
    from vtlearn.datamodules import CrossModalDataModule
    from vtlearn.models.xavtnet_inference import checkpoint_normalize

    with pytest.raises(ValueError, match="input_normalize: expected one of"):
        XAVTNet(num_classes=3, input_normalize="centroid")
    assert checkpoint_normalize({}) == "center"  # checkpoints from before the record
    dm = CrossModalDataModule(str(tiny_crossmodal), batch_size=4, normalize="none")

    def fit(model):
        L.Trainer(fast_dev_run=1, accelerator="cpu", logger=False, enable_progress_bar=False,
                  enable_model_summary=False, default_root_dir=tmp_path).fit(model, datamodule=dm)
        return model

    model = fit(XAVTNet(num_classes=dm.num_classes, global_dim=32, fc_dims=[16, 8], max_points=64))
    path = tmp_path / "m.ckpt"
    torch.save({"state_dict": model.state_dict(), "hyper_parameters": dict(model.hparams)}, path)
    assert torch.load(path, weights_only=True)["hyper_parameters"]["input_normalize"] == "none"
    assert checkpoint_normalize(dict(load_xavtnet(path).hparams)) == "none"
    with pytest.raises(ValueError, match="input_normalize: the model's 'center' differs from the datamodule"):
        fit(XAVTNet(num_classes=dm.num_classes, global_dim=32, fc_dims=[16, 8], input_normalize="center"))


def test_an_object_frame_checkpoint_reads_clouds_in_the_object_frame():
    model = _model(input_normalize="none")
    canon = _object_frame_cloud()
    res = recognize_clouds(model, [canon], units="canonical")
    x = torch.as_tensor(canon, dtype=torch.float32)[None]
    with torch.no_grad():
        p = torch.softmax(model(x).logits, -1).numpy()[0]
        p_centred = torch.softmax(model(x - x.mean(1, keepdim=True)).logits, -1).numpy()[0]
    np.testing.assert_allclose(res.probs[0], p, atol=1e-5)  # not centred on itself
    assert np.abs(p - p_centred).max() > 1e-4  # centring would change it (50 times the tolerance above)
    # in metres: the object's box, a table 0.7 m up and 0.4 m off, 0.25 m tall
    scale, offset = 0.25, np.array([0.4, 0.1, 0.7])
    box = np.array([[-0.3, -0.3, -0.5], [0.3, 0.3, 0.5]]) * scale + offset
    metres = canon * scale + offset
    b = recognize_clouds(model, [metres, metres], units="metres", box_m=box).probs
    np.testing.assert_allclose(b, [p, p], atol=1e-5)
    b = recognize_clouds(model, [metres], units="metres", box_m=[box]).probs
    np.testing.assert_allclose(b[0], p, atol=1e-5)
    with pytest.raises(ValueError, match="box_m: this checkpoint was trained in the object frame"):
        recognize_clouds(model, [metres])
    # a centred checkpoint takes the box too: the same answer as with its largest extent
    centred = _model()
    np.testing.assert_allclose(recognize_clouds(centred, [metres], box_m=box).probs,
                               recognize_clouds(centred, [metres], extent_m=scale).probs, atol=1e-5)


@pytest.mark.parametrize(
    "kwargs, match",
    [
        ({"box_m": np.zeros((3, 2))}, r"box_m: expected a \(2, 3\) box \[lo, hi\] in metres, got shape \(3,"),
        ({"box_m": [[0, 0, 0], [1, 1, float("nan")]]}, "box_m: the box has NaN"),
        ({"box_m": [[0, 0, 1], [1, 1, 0]]}, "box_m: need lo <= hi"),
        ({"box_m": [[0, 0, 0], [0, 0, 0]]}, "box_m: need lo <= hi on every axis and a positive extent"),
        ({"box_m": "abc"}, "box_m: expected a"),
        ({"box_m": [[0, 0, 0], [1, 1, 1]], "extent_m": 1.0}, "extent_m: give extent_m or box_m, not both"),
        ({"box_m": [[0, 0, 0], [1, 1, 1]], "units": "canonical"}, "box_m: only for units='metres'"),
    ],
)
def test_canonical_cloud_rejects_bad_boxes_by_name(kwargs, match):
    with pytest.raises(ValueError, match=match):
        canonical_cloud(_cloud(), **kwargs)


def test_recognize_rejects_a_box_count_that_does_not_match():
    box = [[0, 0, 0], [1, 1, 1]]
    with pytest.raises(ValueError, match="box_m: 3 boxes for 2 clouds"):
        recognize_clouds(_model(), [_cloud(), _cloud(1)], box_m=[box, box, box])


def test_the_closed_loop_classifies_in_the_checkpoint_frame():
    from vtlearn.active.closed_loop import classify_clouds, make_object

    obj = make_object("can", 0)
    lo, hi = obj.bounds
    world = obj.from_canonical(_object_frame_cloud(1, n=30))
    for mode in ("none", "center"):
        model = _model(input_normalize=mode)
        p = classify_clouds(model, obj, [world], max_points=256)[0]
        x = obj.to_canonical(world)
        x = x if mode == "none" else x - x.mean(0)
        with torch.no_grad():
            q = torch.softmax(model(torch.as_tensor(x, dtype=torch.float32)[None]).logits, -1).numpy()[0]
        np.testing.assert_allclose(p, q, atol=1e-5)
        np.testing.assert_allclose(recognize_clouds(model, [world], box_m=[lo, hi]).probs[0], q, atol=1e-5)


def test_recognize_command_takes_the_object_box(tmp_path, tiny_crossmodal, capsys):
    from vtlearn.cli import main
    from vtlearn.datamodules.crossmodal import modality_clouds
    from vtlearn.datamodules.shards import load_manifest, load_split
    from vtlearn.io import write_cloud

    names = load_manifest(tiny_crossmodal)["class_names"]
    model = _model(num_classes=len(names), input_normalize="none")
    ckpt = tmp_path / "x.ckpt"
    torch.save({"state_dict": model.state_dict(), "hyper_parameters": dict(model.hparams)}, ckpt)
    clouds, _, _ = modality_clouds(load_split(tiny_crossmodal, "test"), "tactile", False)
    out = tmp_path / "stored.json"
    assert main(["recognize", "--ckpt", str(ckpt), "--data", str(tiny_crossmodal), "--index", "0",
                 "--mc-samples", "0", "--json", str(out)]) == 0
    stored = json.loads(out.read_text())["results"][0]
    f = tmp_path / "c.npy"
    write_cloud(f, clouds[0] * 0.25 + [0.4, 0.1, 0.7])
    box = ["0.275", "-0.025", "0.575", "0.525", "0.225", "0.825"]  # the unit box about 0, in metres
    out2 = tmp_path / "file.json"
    assert main(["recognize", "--ckpt", str(ckpt), str(f), "--box-m", *box, "--mc-samples", "0",
                 "--class-names", ",".join(names), "--json", str(out2)]) == 0
    got = json.loads(out2.read_text())
    assert got["box_m"] == [[0.275, -0.025, 0.575], [0.525, 0.225, 0.825]]
    for k, v in stored["class_probabilities"].items():
        assert got["results"][0]["class_probabilities"][k] == pytest.approx(v, abs=1e-5)
    capsys.readouterr()
    assert main(["recognize", "--ckpt", str(ckpt), str(f), "--mc-samples", "0"]) == 2
    assert "box_m: this checkpoint was trained in the object frame" in capsys.readouterr().err
    assert main(["recognize", "--ckpt", str(ckpt), "--data", str(tiny_crossmodal), "--box-m", *box]) == 2
    assert "--box-m: only for cloud files" in capsys.readouterr().err


def test_checkpoint_class_names_names_a_wrong_argument():
    from vtlearn.models.xavtnet_inference import checkpoint_class_names

    assert checkpoint_class_names({"num_classes": 2}) == ["class_0", "class_1"]
    assert checkpoint_class_names({"num_classes": 2, "class_names": ["a", "b"]}) == ["a", "b"]
    for bad in ("runs/quickstart/xavtnet.ckpt", {"lr": 1e-3}):  # a path; another dict
        with pytest.raises(ValueError, match="hparams: need a checkpoint's hyper-parameters"):
            checkpoint_class_names(bad)
