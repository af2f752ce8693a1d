"""ACTORRecognition (thesis Sec. 8.2.2, Table 8.1): frozen encoder, head, Lightning smoke, checkpoints."""

import os

os.environ.setdefault("WANDB_MODE", "disabled")

import lightning as L
import numpy as np
import pytest
import torch
from _tiny_models import TINY_ACTOR as TINY
from lightning.pytorch.callbacks import ModelCheckpoint
from lightning.pytorch.loggers import CSVLogger

from vtlearn.models.actor import ACTOR
from vtlearn.models.actor_recognition import (
    ACTORRecognition,
    classify,
    load_recognition,
    random_rotation_matrices,
)
from vtlearn.models.actor_synthetic import PrimitiveDataModule

torch.set_num_threads(1)


def _dm() -> PrimitiveDataModule:
    return PrimitiveDataModule(batch_size=4, size=12, num_dense=64, min_points=20, max_points=60)


@pytest.fixture(scope="module")
def actor_ckpt(tmp_path_factory):
    """A (briefly trained) ACTOR checkpoint with non-trivial batch-norm statistics."""
    torch.manual_seed(0)
    path = tmp_path_factory.mktemp("actor") / "actor.ckpt"
    model = ACTOR(**TINY)
    trainer = L.Trainer(
        max_steps=2,
        accelerator="cpu",
        logger=False,
        enable_checkpointing=False,
        enable_progress_bar=False,
        enable_model_summary=False,
        limit_val_batches=0,
    )
    trainer.fit(model, datamodule=_dm())
    trainer.save_checkpoint(path)
    return path


def test_rotations_are_rotations():
    for mode in ("z", "so3"):
        R = random_rotation_matrices(5, mode, torch.Generator().manual_seed(0))
        torch.testing.assert_close(R @ R.transpose(1, 2), torch.eye(3).expand(5, 3, 3), atol=1e-6, rtol=0)
        torch.testing.assert_close(torch.linalg.det(R), torch.ones(5), atol=1e-6, rtol=0)
    Rz = random_rotation_matrices(3, "z")
    torch.testing.assert_close(Rz[:, 2], torch.tensor([0.0, 0.0, 1.0]).expand(3, 3))
    with pytest.raises(ValueError, match="mode"):
        random_rotation_matrices(2, "x")
    assert random_rotation_matrices(0).shape == (0, 3, 3)
    for n in (-1, 1.5, "2"):
        with pytest.raises(ValueError, match="^n: "):
            random_rotation_matrices(n)


def test_head_shape_and_encoder_loaded(actor_ckpt):
    actor = ACTOR.load_from_checkpoint(actor_ckpt, weights_only=True).eval()
    rec = ACTORRecognition(actor_ckpt=str(actor_ckpt), num_classes=3)
    assert rec.hparams.encoder_channels == list(TINY["encoder_channels"])
    x, lengths = torch.randn(4, 30, 3), torch.tensor([30, 20, 25, 30])
    assert rec(x, lengths).shape == (4, 3)
    with torch.no_grad():
        z_actor, _ = actor.encode(x, lengths)
        from vtlearn.models.actor import _masked_centre

        z_rec = rec.encoder((x - _masked_centre(x, lengths)) / rec.hparams.input_scale, lengths)
    torch.testing.assert_close(z_rec, z_actor)
    head = [m for m in rec.head if isinstance(m, torch.nn.Linear)]
    assert [m.out_features for m in head] == [512, 256, 3]
    assert [m.p for m in rec.head if isinstance(m, torch.nn.Dropout)] == [pytest.approx(0.3)]


def test_encoder_is_frozen(actor_ckpt):
    """No gradient reaches the encoder and a training step leaves it (weights and BN stats) unchanged."""
    rec = ACTORRecognition(actor_ckpt=str(actor_ckpt), num_classes=3)
    rec.train()
    assert not rec.encoder.training
    before = {k: v.clone() for k, v in rec.encoder.state_dict().items()}
    head_before = {k: v.clone() for k, v in rec.head.state_dict().items()}
    assert all(not p.requires_grad for p in rec.encoder.parameters())
    opt = rec.configure_optimizers()
    batch = next(iter(_dm().train_dataloader()))
    loss, _, _ = rec.model_step(batch, augment=True)
    loss.backward()
    assert all(p.grad is None for p in rec.encoder.parameters())
    opt.step()
    for k, v in rec.encoder.state_dict().items():
        assert torch.equal(v, before[k]), k
    assert any(not torch.equal(v, head_before[k]) for k, v in rec.head.state_dict().items())


def test_fast_dev_run(actor_ckpt):
    rec = ACTORRecognition(actor_ckpt=str(actor_ckpt), num_classes=3)
    trainer = L.Trainer(
        fast_dev_run=True, accelerator="cpu", enable_progress_bar=False, enable_model_summary=False
    )
    trainer.fit(rec, datamodule=_dm())
    trainer.test(rec, datamodule=_dm())


def test_num_classes_mismatch_is_reported(actor_ckpt):
    rec = ACTORRecognition(actor_ckpt=str(actor_ckpt), num_classes=5)
    trainer = L.Trainer(
        fast_dev_run=True, accelerator="cpu", enable_progress_bar=False, enable_model_summary=False
    )
    with pytest.raises(ValueError, match="num_classes"):
        trainer.fit(rec, datamodule=_dm())


def test_logs_and_checkpoint_round_trip(actor_ckpt, tmp_path):
    torch.manual_seed(0)
    rec = ACTORRecognition(actor_ckpt=str(actor_ckpt), num_classes=3, lr=1e-2)
    cb = ModelCheckpoint(dirpath=tmp_path, save_last=True)
    trainer = L.Trainer(
        max_epochs=1,
        accelerator="cpu",
        logger=CSVLogger(tmp_path, name="rec"),
        callbacks=[cb],
        enable_progress_bar=False,
        enable_model_summary=False,
        log_every_n_steps=1,
    )
    trainer.fit(rec, datamodule=_dm())
    assert {"val/acc", "val/loss", "val/acc_best", "train/acc"} <= set(trainer.callback_metrics)
    assert 0.0 <= float(trainer.callback_metrics["val/acc"]) <= 1.0
    trainer.test(rec, datamodule=_dm())
    assert "test/acc" in trainer.callback_metrics
    assert list((tmp_path / "rec").rglob("val_confusion_step*.png"))
    assert list((tmp_path / "rec").rglob("test_confusion_step*.png"))
    loaded = load_recognition(tmp_path / "last.ckpt")
    x = torch.randn(3, 25, 3)
    rec.eval()
    with torch.no_grad():
        torch.testing.assert_close(loaded(x), rec(x))
    # the datamodule's class names are recorded in the checkpoint, for classify() users
    assert loaded.hparams.class_names == _dm().class_names
    with pytest.raises(ValueError, match="is an ACTOR reconstruction checkpoint, not an ACTORRecognition"
                                         " checkpoint .*load_actor"):
        load_recognition(actor_ckpt)


def test_classify_matches_the_head_and_refuses_bad_clouds(actor_ckpt):
    torch.manual_seed(0)
    rec = ACTORRecognition(actor_ckpt=str(actor_ckpt), num_classes=3).eval()
    cloud = 0.3 * torch.rand(30, 3) - 0.15
    with torch.no_grad():
        expected = rec(cloud[None]).softmax(dim=1)[0].numpy()
    p = classify(rec, cloud.numpy())
    assert p.shape == (3,) and abs(p.sum() - 1.0) < 1e-6
    np.testing.assert_allclose(p, expected, atol=1e-6)
    # a padded batch: the padding does not change a cloud's probabilities
    padded = torch.zeros(2, 40, 3)
    padded[0, :30], padded[1, :20] = cloud, cloud[:20]
    pb = classify(rec, padded, torch.tensor([30, 20]))
    assert pb.shape == (2, 3)
    np.testing.assert_allclose(pb[0], expected, atol=1e-6)
    np.testing.assert_allclose(pb[1], classify(rec, cloud[:20].numpy()), atol=1e-6)
    for bad, match in [
        (np.zeros((0, 3)), "^points: .*empty"),
        (np.full((10, 3), np.nan), "^points: .*NaN"),
        (np.zeros((10, 2)), r"^points: expected shape \(N, 3\)"),
        (np.zeros((2, 0, 3)), "^points: the batch has no clouds or the clouds are empty"),
        (100.0 * np.random.default_rng(0).random((20, 3)), "^points: spans .* canonical"),
    ]:
        with pytest.raises(ValueError, match=match):
            classify(rec, bad)
    with pytest.raises(ValueError, match="^lengths: expected integer"):
        classify(rec, padded, np.array([30.0, 20.5]))
    with pytest.raises(ValueError, match="^model: expected an ACTORRecognition"):
        classify(ACTOR(**TINY), cloud.numpy())
