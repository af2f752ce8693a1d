"""ACTORRecognition (thesis Sec. 8.2.2, Table 8.1): frozen encoder, head, Lightning smoke, checkpoints."""

import os

os.environ.setdefault("WANDB_MODE", "disabled")

import lightning as L
import pytest
import torch
from lightning.pytorch.callbacks import ModelCheckpoint
from lightning.pytorch.loggers import CSVLogger

from vtlearn.models.actor import ACTOR
from vtlearn.models.actor_recognition import ACTORRecognition, load_recognition, random_rotation_matrices
from vtlearn.models.actor_synthetic import PrimitiveDataModule

torch.set_num_threads(1)

TINY = dict(
    num_points=64,
    encoder_channels=(8, 8, 16, 32),
    fc_channels=32,
    deconv_channels=(16, 16, 8, 8),
    deconv_strides=(2, 2, 2, 2, 4),
    emd_points=32,
)


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


def test_head_shape_and_encoder_loaded(actor_ckpt):
    actor = ACTOR.load_from_checkpoint(actor_ckpt, weights_only=True).eval()
    rec = ACTORRecognition(actor_ckpt=str(actor_ckpt), num_classes=3)
    assert rec.hparams.encoder_channels == [8, 8, 16, 32]
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
    with pytest.raises(ValueError, match="not an ACTORRecognition checkpoint"):
        load_recognition(actor_ckpt)
