"""Best-so-far validation metrics (ACTOR's ``val/cd_mm_best``, ACTORRecognition's ``val/acc_best``) across a
resume: the sanity check must not move them and the checkpoint must carry them.

The models' validation values are scripted per epoch, so the expected best is exact."""

import os

os.environ.setdefault("WANDB_MODE", "disabled")

import lightning as L
import pytest
import torch
from _tiny_models import TINY_ACTOR as TINY
from lightning.pytorch.callbacks import ModelCheckpoint

from vtlearn.models.actor import ACTOR, BEST_METRICS_KEY, load_actor
from vtlearn.models.actor_recognition import ACTORRecognition, load_recognition
from vtlearn.models.actor_synthetic import PrimitiveDataModule

torch.set_num_threads(1)

FIRST_EPOCHS, ALL_EPOCHS = 3, 5


def _dm() -> PrimitiveDataModule:
    return PrimitiveDataModule(batch_size=4, size=8, num_dense=64, min_points=20, max_points=60)


class _Record(L.Callback):
    """(epoch, value, best) after each real (non-sanity) validation."""

    def __init__(self, key: str) -> None:
        self.key, self.rows = key, []

    def on_validation_end(self, trainer, pl_module) -> None:
        if not trainer.sanity_checking:
            m = trainer.callback_metrics
            self.rows.append((trainer.current_epoch, float(m[self.key]), float(m[f"{self.key}_best"])))


def _fit_and_resume(model_fn, key: str, tmp_path):
    """Fit FIRST_EPOCHS epochs saving last.ckpt, then resume from it to ALL_EPOCHS (a fresh model object,
    as ``fit --ckpt_path last`` in a new process). Returns the recorded rows of both runs and last.ckpt."""
    rows = []
    for max_epochs, ckpt_path in ((FIRST_EPOCHS, None), (ALL_EPOCHS, tmp_path / "last.ckpt")):
        rec = _Record(key)
        trainer = L.Trainer(
            max_epochs=max_epochs,
            accelerator="cpu",
            logger=False,
            callbacks=[ModelCheckpoint(dirpath=tmp_path, save_last=True), rec],
            enable_progress_bar=False,
            enable_model_summary=False,
            num_sanity_val_steps=1,
        )
        trainer.fit(model_fn(), datamodule=_dm(), ckpt_path=ckpt_path)
        rows += rec.rows
    return rows, tmp_path / "last.ckpt"


# ------------------------------------------------------------------ ACTOR: val/cd_mm_best
CD_BY_EPOCH = [9.0, 2.0, 6.0, 7.0, 8.0]


class _ScriptedACTOR(ACTOR):
    sanity_cd = 0.5

    def _distances_mm(self, pred, batch):
        v = self.sanity_cd if self.trainer.sanity_checking else CD_BY_EPOCH[self.current_epoch]
        full = torch.full((pred.shape[0],), v, dtype=pred.dtype)
        return full, full, full


# 0.5: a sanity check better than any epoch; 100: worse than the last epoch (the reported resume bug,
# where the best restarted from the sanity check and became the last epochs' values)
@pytest.mark.parametrize("sanity_cd", [0.5, 100.0])
def test_actor_cd_best_ignores_sanity_check_and_survives_resume(tmp_path, sanity_cd):
    torch.manual_seed(0)

    def make():
        m = _ScriptedACTOR(log_figures=False, **TINY)
        m.sanity_cd = sanity_cd
        return m

    rows, last = _fit_and_resume(make, "val/cd_mm", tmp_path)
    assert [r[0] for r in rows] == list(range(ALL_EPOCHS))
    assert [r[1] for r in rows] == CD_BY_EPOCH
    # best = running min over the epochs of both runs: 9, 2, 2, 2, 2 (not 7 / 7 after the resume)
    assert [r[2] for r in rows] == [min(CD_BY_EPOCH[: i + 1]) for i in range(ALL_EPOCHS)]
    raw = torch.load(last, map_location="cpu", weights_only=True)
    assert raw[BEST_METRICS_KEY] == {"val/cd_mm_best": 2.0}
    assert not any("best" in k for k in raw["state_dict"])
    load_actor(last)  # strict state-dict load still works


@pytest.mark.parametrize(
    "make, key, attr, start",
    [
        (lambda: ACTOR(**TINY), "val/cd_mm_best", "val_cd_best", float("inf")),
        (lambda: ACTORRecognition(num_classes=3, encoder_channels=TINY["encoder_channels"]),
         "val/acc_best", "val_acc_best", float("-inf")),
    ],
    ids=["actor", "recognition"],
)
def test_checkpoint_without_best_loads_and_state_dict_is_unchanged(make, key, attr, start):
    model = make()
    assert not any("best" in k for k in model.state_dict())
    model.on_load_checkpoint({"state_dict": {}})  # a checkpoint written before the best was saved
    assert getattr(model, attr) == start
    ckpt: dict = {}
    setattr(model, attr, 0.5)
    model.on_save_checkpoint(ckpt)
    assert ckpt == {BEST_METRICS_KEY: {key: 0.5}} and isinstance(ckpt[BEST_METRICS_KEY][key], float)
    other = make()
    other.on_load_checkpoint(ckpt)
    assert getattr(other, attr) == 0.5


# ------------------------------------------------------------------ ACTORRecognition: val/acc_best
ACC_BY_EPOCH = [0.25, 0.75, 0.5, 0.5, 0.25]


class _ScriptedRecognition(ACTORRecognition):
    sanity_acc = 1.0

    def model_step(self, batch, augment=False):
        loss, preds, y = super().model_step(batch, augment)
        if not self.training:  # validation: exactly round(acc * B) right per batch of B = 4
            acc = self.sanity_acc if self.trainer.sanity_checking else ACC_BY_EPOCH[self.current_epoch]
            ok = torch.arange(len(y)) < round(acc * len(y))
            preds = torch.where(ok, y, (y + 1) % self.hparams.num_classes)
        return loss, preds, y


@pytest.mark.parametrize("sanity_acc", [1.0, 0.0])
def test_recognition_acc_best_ignores_sanity_check_and_survives_resume(tmp_path, sanity_acc):
    torch.manual_seed(0)

    def make():
        m = _ScriptedRecognition(num_classes=3, encoder_channels=TINY["encoder_channels"], lr=1e-2)
        m.sanity_acc = sanity_acc
        return m

    rows, last = _fit_and_resume(make, "val/acc", tmp_path)
    assert [r[0] for r in rows] == list(range(ALL_EPOCHS))
    assert [r[1] for r in rows] == ACC_BY_EPOCH
    assert [r[2] for r in rows] == [max(ACC_BY_EPOCH[: i + 1]) for i in range(ALL_EPOCHS)]
    raw = torch.load(last, map_location="cpu", weights_only=True)
    assert raw[BEST_METRICS_KEY] == {"val/acc_best": 0.75}
    assert not any("best" in k for k in raw["state_dict"])
    load_recognition(last)
