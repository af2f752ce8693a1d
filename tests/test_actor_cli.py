"""`vtlearn reconstruct` and `vtlearn bench actor` end to end on tiny checkpoints and a tiny dataset."""

import json
import os

os.environ.setdefault("WANDB_MODE", "disabled")

import lightning as L
import numpy as np
import pytest
import torch
from _tiny_models import TINY_ACTOR_256 as TINY  # 256 output points: the reconstruct test meshes them

from vtlearn.cli import main
from vtlearn.io import read_cloud, read_mesh, write_cloud
from vtlearn.models.actor import ACTOR
from vtlearn.models.actor_recognition import ACTORRecognition
from vtlearn.models.actor_synthetic import primitive_surface

torch.set_num_threads(1)


def _save(model: L.LightningModule, path) -> str:
    trainer = L.Trainer(
        max_steps=0,
        logger=False,
        enable_checkpointing=False,
        enable_progress_bar=False,
        enable_model_summary=False,
        accelerator="cpu",
    )
    trainer.strategy.connect(model)
    trainer.save_checkpoint(path)
    return str(path)


@pytest.fixture(scope="module")
def ckpts(tmp_path_factory):
    root = tmp_path_factory.mktemp("ckpts")
    torch.manual_seed(0)
    actor = _save(ACTOR(**TINY), root / "actor.ckpt")
    noattn = _save(ACTOR(attention=False, **TINY), root / "noattn.ckpt")
    rec = _save(ACTORRecognition(actor_ckpt=actor, num_classes=3), root / "rec.ckpt")
    return {"actor": actor, "noattn": noattn, "rec": rec}


@pytest.fixture(scope="module")
def tiny_data(tmp_path_factory):
    from vtlearn.sim_data.fixtures import make_tiny_dataset

    return make_tiny_dataset("reconstruction", tmp_path_factory.mktemp("data"))


def test_reconstruct_command(ckpts, tmp_path, capsys):
    rng = np.random.default_rng(0)
    sparse, gt = tmp_path / "sparse.ply", tmp_path / "gt.ply"
    write_cloud(sparse, primitive_surface("sphere", 80, rng))
    write_cloud(gt, primitive_surface("sphere", 256, rng))
    out, mesh, fig = tmp_path / "dense.ply", tmp_path / "mesh.obj", tmp_path / "fig.png"
    rc = main(
        [
            "reconstruct",
            "--ckpt",
            ckpts["actor"],
            "--input",
            str(sparse),
            "--out",
            str(out),
            "--mesh",
            str(mesh),
            "--gt",
            str(gt),
            "--figure",
            str(fig),
        ]
    )
    assert rc == 0
    assert read_cloud(out).shape == (256, 3)
    assert len(read_mesh(mesh).faces) > 0
    assert fig.stat().st_size > 0
    assert "Chamfer distance" in capsys.readouterr().out


def test_reconstruct_metres_with_extent_equals_the_canonical_cloud_scaled_back(ckpts, tmp_path, caplog):
    """``--extent-m L``: a cloud in metres goes into the canonical frame and the reconstruction comes back in
    metres, so it is the canonical reconstruction scaled by L and moved like the input."""
    canon = primitive_surface("sphere", 80, np.random.default_rng(1))
    shift = np.array([0.4, -0.2, 0.75])
    a, b = tmp_path / "c.npy", tmp_path / "m.npy"
    write_cloud(a, canon)
    write_cloud(b, canon * 0.2 + shift)
    out_c = tmp_path / "dc.npy"
    assert main(["reconstruct", "--ckpt", ckpts["actor"], "--input", str(a), "--out", str(out_c)]) == 0
    args = ["reconstruct", "--ckpt", ckpts["actor"], "--input", str(b), "--out", str(tmp_path / "dm.npy")]
    assert main([*args, "--extent-m", "0.2"]) == 0
    np.testing.assert_allclose(
        read_cloud(tmp_path / "dm.npy"), read_cloud(out_c) * 0.2 + shift, atol=1e-5
    )
    caplog.clear()
    assert main(args) == 0  # metres without the extent: reconstructed as canonical, with a warning
    assert "--extent-m" in caplog.text
    assert main([*args, "--extent-m", "-1"]) == 2


def test_reconstruct_rejects_foreign_checkpoint(ckpts, tmp_path, capsys):
    sparse = tmp_path / "sparse.xyz"
    write_cloud(sparse, np.random.default_rng(1).normal(size=(30, 3)))
    rc = main(
        ["reconstruct", "--ckpt", ckpts["rec"], "--input", str(sparse), "--out", str(tmp_path / "o.ply")]
    )
    assert rc != 0 and "not an ACTOR checkpoint" in capsys.readouterr().err
    bad = tmp_path / "bad.ckpt"
    bad.write_bytes(b"PK\x03\x04 truncated")
    rc = main(["reconstruct", "--ckpt", str(bad), "--input", str(sparse), "--out", str(tmp_path / "o.ply")])
    assert rc != 0 and "not a readable PyTorch checkpoint" in capsys.readouterr().err
    assert not (tmp_path / "o.ply").exists()


def test_bench_actor_tiny(ckpts, tiny_data, tmp_path, capsys):
    data = tiny_data
    out = tmp_path / "bench"
    rc = main(
        [
            "bench",
            "actor",
            "--ckpt",
            ckpts["actor"],
            "--ckpt-noattn",
            ckpts["noattn"],
            "--recognition-ckpt",
            ckpts["rec"],
            "--data",
            str(data),
            "--max-clouds",
            "2",
            "--per-category",
            "1",
            "--min-points",
            "20",
            "--max-points",
            "40",
            "--emd-points",
            "64",
            "--gpis-resolution",
            "12",
            "--json",
            str(out / "a.json"),
        ]
    )
    assert rc == 0
    assert (out / "a.md").is_file() and (out / "a.png").is_file()  # the table and figure beside the JSON
    res = json.loads((out / "a.json").read_text())
    methods = {r["method"] for r in res["summary"] if r["group"] == "all"}
    assert {"ACTOR", "ACTOR (no attention)", "GPIS", "GPIS (true normals)"} <= methods
    # the 40 % target is measured against GPIS on ACTOR's exact input; the oracle-normal GPIS is reported too
    assert {"actor_cd_reduction_vs_gpis", "actor_cd_reduction_vs_gpis_dense_normals"} <= set(res["targets"])
    assert res["clouds"] == 2
    assert all(np.isfinite(r["CD_mm"]) and r["CD_mm"] > 0 for r in res["rows"])
    assert all(20 <= r["n_input"] <= 40 for r in res["rows"])
    assert len({r["category"] for r in res["rows"]}) == 2  # one instance per category
    assert res["input_source"] == "tactile"
    assert res["inference_ms"]["ACTOR"] > 0
    assert 0 <= res["recognition"]["accuracy"] <= 1
    assert np.array(res["recognition"]["confusion"]).sum() == 2
    assert (out / "a.md").read_text().count("|") > 10
    assert (out / "a.png").is_file() and (out / "a_confusion.png").is_file()
    printed = capsys.readouterr().out
    assert "targets:" in printed and "GPIS failures: " in printed
    # without GPIS there are no GPIS failures to report
    assert main(["bench", "actor", "--ckpt", ckpts["actor"], "--data", str(data), "--max-clouds", "1",
                 "--min-points", "20", "--max-points", "40", "--emd-points", "64", "--no-gpis",
                 "--json", str(out / "b.json")]) == 0
    printed = capsys.readouterr().out
    assert "targets:" in printed and "GPIS failures" not in printed
    assert "GPIS failures" not in (out / "b.md").read_text()


def test_gpis_variants_parse_and_reject_unknown():
    from vtlearn.models.actor_cli import _gpis_variants

    assert _gpis_variants("estimated,dense") == [("GPIS", "estimated"), ("GPIS (true normals)", "dense")]
    with pytest.raises(ValueError, match="gpis_normals"):
        _gpis_variants("mesh")
    with pytest.raises(ValueError, match="gpis_normals"):
        _gpis_variants(" , ")


def test_reconstruct_from_generated_data(ckpts, tiny_data, tmp_path, capsys):
    data = tiny_data
    out, fig = tmp_path / "dense.ply", tmp_path / "fig.png"
    rc = main(
        [
            "reconstruct",
            "--ckpt",
            ckpts["actor"],
            "--data",
            str(data),
            "--index",
            "1",
            "--out",
            str(out),
            "--figure",
            str(fig),
        ]
    )
    assert rc == 0 and fig.is_file()
    text = capsys.readouterr().out
    assert "test instance" in text and "mm at" in text
    assert (
        main(["reconstruct", "--ckpt", ckpts["actor"], "--out", str(out)]) != 0
    )  # neither --input nor --data
