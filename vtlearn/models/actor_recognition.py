"""ACTOR recognition head: category from a sparse cloud with ACTOR's frozen encoder (thesis Sec. 8.2.2).

Murali, "Visuo-tactile perception and learning for robots", ch.8: "The pretrained encoder layers for
reconstruction task were frozen for the task of category-level classification. Three fully-connected
layers with parameters 512, 256, and n ... softmax cross-entropy ... subsampled sparse point clouds
... with random rotations", and (Sec. 8.3.1) "dropout with keep probability 0.7 ... on the fc-256 layer".
Results: Table 8.1 (confusion matrix), 87.16 % accuracy on real tactile clouds.

The frozen encoder stays in eval mode for good (its batch-norm statistics are part of what is frozen)
and has ``requires_grad=False``; only the head trains.
"""

from __future__ import annotations

import math
from pathlib import Path

import lightning as L
import numpy as np
import torch
from torch import Tensor, nn
from torchmetrics import MeanMetric
from torchmetrics.classification import MulticlassAccuracy, MulticlassConfusionMatrix

from vtlearn.models.actor import (
    _masked_centre,
    _model_input,
    _plain_hparams,
    load_actor,
    read_lightning_checkpoint,
)
from vtlearn.models.components.actor_encoder import ActorEncoder
from vtlearn.models.components.best_metric import BestMetricMixin
from vtlearn.validation import ConfigMismatchError, as_int, as_real

__all__ = ["ACTORRecognition", "classify", "load_recognition", "random_rotation_matrices"]


def random_rotation_matrices(n: int, mode: str = "z", generator: torch.Generator | None = None) -> Tensor:
    """Random rotations for augmentation: about the world z axis (``"z"``, objects stay upright) or
    uniform on SO(3) (``"so3"``, via unit quaternions (w, x, y, z), Hamilton). Shapes: (n, 3, 3)."""
    n = as_int(n, "n", minimum=0)
    if mode == "z":
        theta = torch.rand(n, generator=generator) * 2 * math.pi
        c, s = torch.cos(theta), torch.sin(theta)
        R = torch.zeros(n, 3, 3)
        R[:, 0, 0], R[:, 0, 1], R[:, 1, 0], R[:, 1, 1], R[:, 2, 2] = c, -s, s, c, 1.0
        return R
    if mode == "so3":
        q = torch.randn(n, 4, generator=generator)
        w, x, y, z = (q / q.norm(dim=1, keepdim=True)).unbind(1)
        return torch.stack(
            [
                1 - 2 * (y * y + z * z),
                2 * (x * y - w * z),
                2 * (x * z + w * y),
                2 * (x * y + w * z),
                1 - 2 * (x * x + z * z),
                2 * (y * z - w * x),
                2 * (x * z - w * y),
                2 * (y * z + w * x),
                1 - 2 * (x * x + y * y),
            ],
            dim=1,
        ).reshape(n, 3, 3)
    raise ValueError(f"mode: expected 'z' or 'so3', got {mode!r}")


class ACTORRecognition(BestMetricMixin, L.LightningModule):
    """Frozen ACTOR encoder + FC 512-256-n classifier (thesis Sec. 8.2.2, Table 8.1).

    Args:
        actor_ckpt: ACTOR checkpoint whose encoder is loaded and frozen. ``None`` builds an encoder
            from the arguments below (used when restoring a recognition checkpoint, whose state dict
            already holds the encoder weights).
        num_classes: number of categories n; checked against the datamodule's ``num_classes``.
        class_names: optional category names (else the datamodule's, recorded here at ``setup`` so that the
            checkpoint carries them); used by the confusion-matrix figure.
        lr: Adam learning rate of the head.
        dropout_keep: keep probability of the dropout on fc-256 (thesis 0.7).
        rotation: training augmentation, ``"z"``, ``"so3"`` or ``"none"``.
        attention, encoder_channels, input_scale: encoder architecture when ``actor_ckpt`` is None
            (overwritten from the ACTOR checkpoint otherwise).

    Shapes:
        forward: sparse (B, N, 3) padded, lengths (B,) or None -> logits (B, num_classes).
        batches: dict with "sparse", "lengths", "label" (B,) int64.
    """

    # the best validation accuracy so far, ``self.val_acc_best``, carried across resumes (BestMetricMixin)
    best_metric_name, best_metric_attr, best_metric_mode = "val/acc_best", "val_acc_best", "max"

    def __init__(
        self,
        actor_ckpt: str | None = None,
        num_classes: int = 12,
        class_names: list[str] | None = None,
        lr: float = 1e-3,
        dropout_keep: float = 0.7,
        rotation: str = "z",
        attention: bool = True,
        encoder_channels: tuple[int, ...] = (64, 64, 128, 1024),
        input_scale: float = 1.0,
    ) -> None:
        super().__init__()
        as_int(num_classes, "num_classes", minimum=2)
        as_real(dropout_keep, "dropout_keep", low=0.0, high=1.0, open_low=True)
        if rotation not in ("z", "so3", "none"):
            raise ValueError(f"rotation: expected 'z', 'so3' or 'none', got {rotation!r}")
        if actor_ckpt is not None:
            actor = load_actor(actor_ckpt)
            attention = actor.encoder.attention is not None
            encoder_channels = tuple(actor.hparams.encoder_channels)
            input_scale = float(actor.hparams.input_scale)
            self.encoder = actor.encoder
        else:
            self.encoder = ActorEncoder(tuple(encoder_channels), attention=attention)
        self.save_hyperparameters(
            {
                "actor_ckpt": None if actor_ckpt is None else str(actor_ckpt),
                "num_classes": int(num_classes),
                "class_names": None if class_names is None else [str(c) for c in class_names],
                "lr": float(lr),
                "dropout_keep": float(dropout_keep),
                "rotation": rotation,
                "attention": bool(attention),
                "encoder_channels": [int(c) for c in encoder_channels],
                "input_scale": float(input_scale),
            }
        )
        # in the state dict, so that a checkpoint restores it whatever hparams a CLI recorded
        self.register_buffer("encoder_input_scale", torch.tensor(float(input_scale)))
        self.encoder.requires_grad_(False)
        self.encoder.eval()
        c = self.encoder.out_channels
        self.head = nn.Sequential(
            nn.Linear(c, 512, bias=False),
            nn.BatchNorm1d(512),
            nn.ReLU(),
            nn.Linear(512, 256, bias=False),
            nn.BatchNorm1d(256),
            nn.ReLU(),
            nn.Dropout(p=1.0 - dropout_keep),
            nn.Linear(256, num_classes),
        )
        self.criterion = nn.CrossEntropyLoss()
        self.train_loss, self.val_loss, self.test_loss = MeanMetric(), MeanMetric(), MeanMetric()
        self.train_acc = MulticlassAccuracy(num_classes, average="micro")
        self.val_acc = MulticlassAccuracy(num_classes, average="micro")
        self.test_acc = MulticlassAccuracy(num_classes, average="micro")
        self.val_confusion = MulticlassConfusionMatrix(num_classes)
        self.test_confusion = MulticlassConfusionMatrix(num_classes)
        self.reset_best_metric()

    def train(self, mode: bool = True):
        super().train(mode)
        self.encoder.eval()  # frozen: batch-norm statistics must not move either
        return self

    def setup(self, stage: str) -> None:
        dm = getattr(self.trainer, "datamodule", None) if self._trainer is not None else None
        n = getattr(dm, "num_classes", None)
        if n is not None and int(n) != self.hparams.num_classes:
            raise ConfigMismatchError(
                f"num_classes: model has {self.hparams.num_classes}, datamodule has {n} (set "
                f"model.init_args.num_classes: {n} in the config, or --model.init_args.num_classes {n})")
        names = getattr(dm, "class_names", None)
        if not self.hparams.class_names and names and len(names) == self.hparams.num_classes:
            # recorded in the checkpoint, so that load_recognition / classify users get the names too
            self.hparams.class_names = [str(c) for c in names]

    def _class_names(self) -> list[str]:
        if self.hparams.class_names:
            return list(self.hparams.class_names)
        dm = getattr(self.trainer, "datamodule", None) if self._trainer is not None else None
        names = getattr(dm, "class_names", None)
        return list(names) if names else [str(i) for i in range(self.hparams.num_classes)]

    def forward(self, sparse: Tensor, lengths: Tensor | None = None) -> Tensor:
        """Class logits of the FC 512-256-n head on the frozen encoder's global vector (Sec. 8.2.2); the
        softmax of Table 8.1 is :func:`classify`'s.

        Shapes:
            sparse (B, N, 3) padded, lengths (B,) int64 or None (every row a point) -> (B, num_classes).
        """
        if sparse.dim() != 3 or sparse.shape[-1] != 3:
            raise ValueError(f"sparse: expected (B, N, 3), got {tuple(sparse.shape)}")
        if lengths is None:
            lengths = torch.full((sparse.shape[0],), sparse.shape[1], dtype=torch.long, device=sparse.device)
        x = (sparse - _masked_centre(sparse, lengths)) / self.encoder_input_scale
        with torch.no_grad():
            z = self.encoder(x, lengths)
        return self.head(z)

    def model_step(self, batch: dict[str, Tensor], augment: bool = False) -> tuple[Tensor, Tensor, Tensor]:
        sparse = batch["sparse"]
        if augment and self.hparams.rotation != "none":
            R = random_rotation_matrices(sparse.shape[0], self.hparams.rotation).to(sparse)
            sparse = sparse @ R.transpose(1, 2)
        logits = self(sparse, batch.get("lengths"))
        loss = self.criterion(logits, batch["label"])
        return loss, logits.argmax(dim=1), batch["label"]

    def training_step(self, batch: dict[str, Tensor], batch_idx: int) -> Tensor:
        loss, preds, targets = self.model_step(batch, augment=True)
        bs = len(targets)
        self.train_loss(loss)
        self.train_acc(preds, targets)
        self.log("train/loss", self.train_loss, on_step=False, on_epoch=True, prog_bar=True, batch_size=bs)
        self.log("train/acc", self.train_acc, on_step=False, on_epoch=True, prog_bar=True, batch_size=bs)
        return loss

    def validation_step(self, batch: dict[str, Tensor], batch_idx: int) -> None:
        loss, preds, targets = self.model_step(batch)
        bs = len(targets)
        self.val_loss(loss)
        self.val_acc(preds, targets)
        self.val_confusion.update(preds, targets)
        self.log("val/loss", self.val_loss, on_step=False, on_epoch=True, prog_bar=True, batch_size=bs)
        self.log("val/acc", self.val_acc, on_step=False, on_epoch=True, prog_bar=True, batch_size=bs)

    def on_validation_epoch_end(self) -> None:
        self.update_best_metric(float(self.val_acc.compute()))  # not moved by the sanity check
        matrix = self.val_confusion.compute().cpu().numpy()
        self.val_confusion.reset()
        self._log_confusion("val/confusion", matrix)

    def test_step(self, batch: dict[str, Tensor], batch_idx: int) -> None:
        loss, preds, targets = self.model_step(batch)
        bs = len(targets)
        self.test_loss(loss)
        self.test_acc(preds, targets)
        self.test_confusion.update(preds, targets)
        self.log("test/loss", self.test_loss, on_step=False, on_epoch=True, batch_size=bs)
        self.log("test/acc", self.test_acc, on_step=False, on_epoch=True, batch_size=bs)

    def on_test_epoch_end(self) -> None:
        matrix = self.test_confusion.compute().cpu().numpy()
        self.test_confusion.reset()
        self._log_confusion("test/confusion", matrix)

    def _log_confusion(self, key: str, matrix: np.ndarray) -> None:
        if self.trainer.sanity_checking or self.logger is None:
            return
        from vtlearn.models.actor_figures import confusion_figure, log_figure

        log_figure(self.logger, key, confusion_figure(matrix, self._class_names()), self.global_step)

    def predict_step(self, batch: dict[str, Tensor], batch_idx: int, dataloader_idx: int = 0) -> Tensor:
        return self(batch["sparse"], batch.get("lengths")).softmax(dim=1)

    def configure_optimizers(self):
        return torch.optim.Adam(self.head.parameters(), lr=self.hparams.lr)


def load_recognition(ckpt: str | Path, map_location: str | torch.device = "cpu") -> ACTORRecognition:
    """Load an :class:`ACTORRecognition` checkpoint (``weights_only=True``), in eval mode.

    Raises:
        FileNotFoundError: missing file.
        ValueError (naming ``ckpt`` or ``map_location``): a corrupted file, a checkpoint of another model
            (an xAVTNet or ACTOR one: the message says which), or a ``map_location`` that is not a device.
    """
    from vtlearn.models.actor import _check_map_location, _to_device

    map_location = _check_map_location(map_location)
    data = read_lightning_checkpoint(ckpt)
    state = data["state_dict"]
    if not any(k.startswith("head.") for k in state) and any(k.startswith("decoder.") for k in state):
        raise ValueError(
            f"ckpt: {ckpt} is an ACTOR reconstruction checkpoint, not an ACTORRecognition checkpoint (load "
            "it with vtlearn.models.actor.load_actor; a recognition head is trained on it with "
            "configs/quick/actor_recognition.yaml)"
        )
    if not any(k.startswith("head.") for k in state) or not any(k.startswith("encoder.") for k in state):
        raise ValueError(
            f"ckpt: {ckpt} is not an ACTORRecognition checkpoint (no head.* / encoder.* weights)"
        )
    head_numbered = all(k.split(".")[1].isdigit() for k in state if k.startswith("head."))
    if not head_numbered or not any(k.startswith("encoder.features.convs.") for k in state):
        if any(k.startswith("head.fc") for k in state) or any(k.startswith("encoder.mlp1.") for k in state):
            raise ValueError(
                f"ckpt: {ckpt} is an XAVTNet checkpoint, not an ACTOR recognition one (load it with "
                "vtlearn.models.xavtnet.load_xavtnet)"
            )
        raise ValueError(
            f"ckpt: {ckpt} is not an ACTORRecognition checkpoint (no encoder.features.convs.* weights, or "
            "head.* weights that are not an nn.Sequential)"
        )
    hp = _plain_hparams(dict(data["hyper_parameters"]), ACTORRecognition)
    hp["actor_ckpt"] = None  # the encoder weights are in the state dict
    # The encoder architecture is read from the weights: LightningCLI records the config's init args,
    # not the values copied from the ACTOR checkpoint.
    convs = sorted(
        (k for k in state if k.startswith("encoder.features.convs.")), key=lambda k: int(k.split(".")[3])
    )
    hp["encoder_channels"] = tuple(int(state[k].shape[0]) for k in convs)
    hp["attention"] = any(k.startswith("encoder.attention.") for k in state)
    head_out = [k for k in state if k.startswith("head.") and k.endswith(".bias")]
    hp["num_classes"] = int(state[max(head_out, key=lambda k: int(k.split(".")[1]))].shape[0])
    try:
        model = ACTORRecognition(**hp)
        model.load_state_dict(state, strict=True)
    except (RuntimeError, TypeError, ValueError) as exc:
        raise ValueError(f"ckpt: {ckpt} does not match ACTORRecognition: {str(exc).splitlines()[0]}") from exc
    return _to_device(model, map_location).eval()


@torch.no_grad()
def classify(model: ACTORRecognition, points, lengths=None) -> np.ndarray:
    """Category probabilities of one sparse cloud or a padded batch: the softmax of the head on ACTOR's
    frozen encoder (thesis Sec. 8.2.2, Table 8.1), as numpy.

    The clouds are in ACTOR's canonical frame (see :func:`vtlearn.models.actor.reconstruct`, which takes the
    same input and refuses the same bad input: empty, NaN or inf, wrong shape, not canonical).

    Args:
        model: an :class:`ACTORRecognition` (e.g. from :func:`load_recognition`); put in eval mode here.
        points: one cloud (N, 3) with N >= 3, or a padded batch (B, N, 3) with ``lengths``.
        lengths: (B,) valid points per cloud, batch input only.

    Shapes:
        (N, 3) -> (num_classes,); (B, N, 3) -> (B, num_classes). Class names: ``model.hparams.class_names``.
    """
    if not isinstance(model, ACTORRecognition):
        raise ValueError(
            f"model: expected an ACTORRecognition (e.g. from load_recognition), got {type(model).__name__}"
        )
    model.eval()
    x, lt, single = _model_input(model, points, lengths, "classify")
    probs = model(x, lt).softmax(dim=1).cpu().numpy()
    return probs[0] if single else probs
