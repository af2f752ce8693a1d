"""NpzPredictionWriter: what `train.py predict` keeps (vtlearn/prediction_writer.py)."""

import logging

import lightning as L
import numpy as np
import pytest
import torch
from torch.utils.data import DataLoader

from vtlearn.prediction_writer import NpzPredictionWriter


class _Doubler(L.LightningModule):
    def __init__(self, as_dict: bool = False):
        super().__init__()
        self.save_hyperparameters()
        self.hparams.class_names = ["a", "b"]
        self.w = torch.nn.Parameter(torch.ones(1))

    def predict_step(self, batch, batch_idx, dataloader_idx=0):
        out = batch["x"] * 2 * self.w
        return {"out": out} if self.hparams.as_dict else out


def _loader(values):
    items = [{"x": torch.tensor([float(v), 0.0]), "label": torch.tensor(int(v) % 2)} for v in values]
    return DataLoader(items, batch_size=2)


def _trainer(tmp_path, writer):
    return L.Trainer(accelerator="cpu", logger=False, callbacks=[writer], default_root_dir=tmp_path,
                     enable_progress_bar=False, enable_model_summary=False)


def test_one_array_per_predict_dataloader_in_order_with_labels(tmp_path):
    writer = NpzPredictionWriter()
    _trainer(tmp_path, writer).predict(_Doubler(), dataloaders=[_loader(range(5)), _loader([7, 8, 9])])
    with np.load(tmp_path / "predictions.npz", allow_pickle=False) as out:
        assert sorted(out.files) == ["class_names", "label_0", "label_1", "predictions_0", "predictions_1"]
        np.testing.assert_array_equal(out["predictions_0"][:, 0], [0, 2, 4, 6, 8])
        np.testing.assert_array_equal(out["predictions_1"][:, 0], [14, 16, 18])
        np.testing.assert_array_equal(out["label_1"], [1, 0, 1])
        assert out["class_names"].tolist() == ["a", "b"]
    one = NpzPredictionWriter(tmp_path / "one.npz")
    _trainer(tmp_path, one).predict(_Doubler(), dataloaders=_loader(range(3)))
    with np.load(one.written, allow_pickle=False) as out:
        assert out["predictions"].shape == (3, 2) and out["label"].tolist() == [0, 1, 0]


def test_a_predict_step_that_returns_no_tensor_is_said_and_does_not_stop_predict(tmp_path, caplog):
    writer = NpzPredictionWriter()
    with caplog.at_level(logging.WARNING, logger="vtlearn.prediction_writer"):
        out = _trainer(tmp_path, writer).predict(_Doubler(as_dict=True), dataloaders=_loader(range(3)))
    assert len(out) == 2 and writer.written is None and not (tmp_path / "predictions.npz").exists()
    trainer = _trainer(tmp_path, writer)
    trainer.predict(_Doubler(), dataloaders=_loader(range(3)))
    assert writer.written == tmp_path / "predictions.npz"
    trainer.predict(_Doubler(as_dict=True), dataloaders=_loader(range(3)))
    assert writer.written is None  # not the earlier run's file
    assert "predict_step returned a dict, not a tensor" in caplog.text


def test_path_must_be_npz():
    with pytest.raises(ValueError, match="path: need a .npz file"):
        NpzPredictionWriter("out.csv")
