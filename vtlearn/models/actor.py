"""ACTOR: category-level shape reconstruction from sparse touches (thesis ch.8, Sec. 8.2.2).

Murali, "Visuo-tactile perception and learning for robots", ch.8 (Murali et al., IROS 2023). An
auto-encoder trained self-supervised on synthetic shapes: a PointNet encoder with a self-attention
unit (Fig. 8.2(a), Fig. 8.3) maps a sparse cloud of 20-1024 points to a 1024-d global vector, and an
upsampling decoder (FC 1024 + five transposed convolutions) emits a dense cloud of 2048 points.

Loss (eq. 8.1): ``L_rec = alpha * L_CD(P_in, P_out)`` with alpha = 100, where ``L_CD`` is the
symmetric mean nearest-neighbour L2 distance. Adam, learning rate 1e-4, momentum 0.9 (Sec. 8.3.1).
Batch norm follows the PointNet/TensorFlow schedule of Sec. 8.3.1: decay 0.5 rising to 0.99, halving
``1 - decay`` every 2e5 training samples; PyTorch's ``momentum`` is ``1 - decay``.

Validation and test log Chamfer (eq. 8.1), Hausdorff (eq. 8.6) and EMD (eq. 8.7) in millimetres.

Input normalisation (an implementation choice, documented): each sparse cloud is centred on the mean
of its valid points and divided by ``input_scale`` before the encoder; the dense output is mapped back,
so the module works in the data's own frame and units.
"""

from __future__ import annotations

import math
import warnings
from pathlib import Path
from typing import Any

import lightning as L
import numpy as np
import torch
from torch import Tensor
from torchmetrics import MeanMetric

from vtlearn.geometry.metrics import earth_movers_distance
from vtlearn.models.components.actor_decoder import ActorDecoder
from vtlearn.models.components.actor_encoder import ActorEncoder
from vtlearn.models.components.actor_pointnet import lengths_to_mask
from vtlearn.models.components.best_metric import BEST_METRICS_KEY, BestMetricMixin  # noqa: F401 (re-export)
from vtlearn.validation import as_points, as_real

__all__ = [
    "ACTOR",
    "actor_loss",
    "chamfer_hausdorff",
    "load_actor",
    "reconstruct",
    "read_lightning_checkpoint",
    "bn_momentum_at",
]


def _nearest_indices(x: Tensor, y: Tensor, y_lengths: Tensor | None) -> tuple[Tensor, Tensor]:
    """Nearest-neighbour indices both ways, without autograd: k-d trees on a CPU, else one
    squared-distance matrix (:func:`_nearest_indices_dense`).

    On a CPU the B x N x M matrix, its masked copy and its two argmins took 0.7 s of a 1.05 s training
    step of ``configs/cpu/actor.yaml`` (B = 16, N = M = 2048); scipy's k-d trees find the neighbours in
    0.05 s. The trees compare float64 distances. The matrix's expanded form ``|x|² + |y|² − 2 x·y``
    loses about four digits to cancellation at neighbour distances in float32, so where two candidates
    are that close it may pick the farther one; the trees pick the nearest (the two are tested equal on
    clouds without such near-ties).

    Shapes: x (B, N, 3), y (B, M, 3) -> idx_xy (B, N) into y (valid y only), idx_yx (B, M) into x.
    """
    if x.device.type != "cpu" or y.device.type != "cpu":
        return _nearest_indices_dense(x, y, y_lengths)
    from scipy.spatial import cKDTree

    xs = x.detach().double().numpy()
    ys = y.detach().double().numpy()
    if not (np.isfinite(xs).all() and np.isfinite(ys).all()):
        return _nearest_indices_dense(x, y, y_lengths)  # a diverged step: let the loss turn NaN as before
    valid = [y.shape[1]] * y.shape[0] if y_lengths is None else y_lengths.tolist()
    idx_xy = np.empty(xs.shape[:2], dtype=np.int64)
    idx_yx = np.empty(ys.shape[:2], dtype=np.int64)
    for b in range(xs.shape[0]):
        idx_xy[b] = cKDTree(ys[b, : valid[b]]).query(xs[b])[1]
        idx_yx[b] = cKDTree(xs[b]).query(ys[b])[1]
    return torch.from_numpy(idx_xy), torch.from_numpy(idx_yx)


def _nearest_indices_dense(x: Tensor, y: Tensor, y_lengths: Tensor | None) -> tuple[Tensor, Tensor]:
    """:func:`_nearest_indices` from one squared-distance matrix (any device). Shapes: as there."""
    with torch.no_grad():
        d2 = torch.baddbmm(
            (x * x).sum(-1)[:, :, None] + (y * y).sum(-1)[:, None, :], x, y.transpose(1, 2), alpha=-2.0
        )  # B x N x M
        idx_yx = d2.argmin(dim=1)
        if y_lengths is not None:
            d2.masked_fill_(~lengths_to_mask(y_lengths, y.shape[1])[:, None, :], float("inf"))
        idx_xy = d2.argmin(dim=2)
    return idx_xy, idx_yx


def _gather_points(points: Tensor, idx: Tensor) -> Tensor:
    return torch.gather(points, 1, idx[..., None].expand(-1, -1, points.shape[-1]))


def actor_loss(
    pred: Tensor, target: Tensor, alpha: float = 100.0, target_lengths: Tensor | None = None
) -> Tensor:
    """Reconstruction loss ``L_rec = alpha * L_CD(P_in, P_out)`` (thesis eq. 8.1), mean over the batch.

    ``L_CD`` is the symmetric mean nearest-neighbour Euclidean distance, the same value as
    :func:`vtlearn.geometry.metrics.chamfer_distance` (tested). The nearest neighbours are found without
    autograd and only the matched pairs are differentiated: the gradient of a minimum is the gradient
    at its argmin, so the result is the same as differentiating the full distance matrix, at a fraction
    of the memory and time (the full B x N x M backward dominated CPU training).

    Shapes:
        pred: (B, M, 3); target: (B, N, 3) (padded, with ``target_lengths`` (B,)); returns a scalar.
    """
    if pred.dim() != 3 or target.dim() != 3 or pred.shape[0] != target.shape[0]:
        raise ValueError(
            f"pred, target: expected (B, M, 3) and (B, N, 3), got {tuple(pred.shape)}, {tuple(target.shape)}"
        )
    target = target.to(pred.dtype)
    idx_pt, idx_tp = _nearest_indices(pred, target, target_lengths)
    pred_to_target = (pred - _gather_points(target, idx_pt)).norm(dim=-1).mean(dim=1)
    t2p = (target - _gather_points(pred, idx_tp)).norm(dim=-1)
    if target_lengths is None:
        target_to_pred = t2p.mean(dim=1)
    else:
        mask = lengths_to_mask(target_lengths, target.shape[1]).to(pred.dtype)
        target_to_pred = (t2p * mask).sum(dim=1) / target_lengths.to(pred.dtype)
    return alpha * (pred_to_target + target_to_pred).mean()


@torch.no_grad()
def chamfer_hausdorff(x: Tensor, y: Tensor) -> tuple[Tensor, Tensor]:
    """Per-sample Chamfer (eq. 8.1) and Hausdorff (eq. 8.6) distances from one distance matrix.

    Same values as :func:`vtlearn.geometry.metrics.chamfer_distance` / ``hausdorff_distance`` with
    ``reduction="none"`` (tested), at a quarter of their distance-matrix work; used for logging.

    Shapes:
        x (B, N, 3), y (B, M, 3) -> cd (B,), hd (B,)
    """
    d = torch.cdist(x, y)  # B x N x M
    dx, dy = d.min(dim=2).values, d.min(dim=1).values
    return dx.mean(dim=1) + dy.mean(dim=1), torch.maximum(dx.amax(dim=1), dy.amax(dim=1))


def bn_momentum_at(
    samples_seen: int, init: float = 0.5, rate: float = 0.5, step: int = 200_000, decay_max: float = 0.99
) -> float:
    """PyTorch batch-norm momentum of the thesis schedule (Sec. 8.3.1, staircase as in PointNet).

    TensorFlow decay = 1 - momentum starts at ``1 - init`` = 0.5 and rises to ``decay_max`` = 0.99:
    ``momentum = max(1 - decay_max, init * rate ** floor(samples_seen / step))``.
    """
    return max(1.0 - decay_max, init * rate ** math.floor(samples_seen / step))


def _masked_centre(points: Tensor, lengths: Tensor) -> Tensor:
    """Mean of the valid points. Shapes: (B, N, 3), (B,) -> (B, 1, 3)."""
    mask = lengths_to_mask(lengths, points.shape[1]).to(points.dtype)[:, :, None]
    return (points * mask).sum(dim=1, keepdim=True) / lengths.to(points.dtype)[:, None, None]


class ACTOR(BestMetricMixin, L.LightningModule):
    """ACTOR reconstruction auto-encoder (thesis Sec. 8.2.2, eq. 8.1).

    Args:
        num_points: points of the dense output (thesis 2048); the decoder strides must multiply to it.
        attention: use the self-attention unit (False: the ablation of Table 8.2).
        alpha: loss weight of eq. 8.1 (thesis 100).
        lr: Adam learning rate (thesis 1e-4).
        weight_decay: Adam weight decay (thesis: none).
        lr_schedule: "constant" (thesis) or "cosine": cosine decay per step to ``lr * lr_min_ratio`` over
            the trainer's estimated total steps (for short CPU budgets at a larger ``lr``).
        lr_min_ratio: final learning rate of the cosine schedule, relative to ``lr``.
        encoder_channels: PointNet conv channels (thesis 64, 64, 128, 1024).
        fc_channels: decoder FC size (thesis 1024).
        deconv_channels: channels of the first four transposed convolutions.
        deconv_strides: kernel = stride of the five transposed convolutions.
        bn_momentum_init, bn_decay_rate, bn_decay_step, bn_decay_max: batch-norm schedule (Sec. 8.3.1);
            ``bn_decay_step`` counts training samples.
        input_scale: sparse clouds are centred and divided by this before the encoder.
        mm_per_unit: millimetres per data unit for the logged metrics (1000 for metres). A batch may
            carry ``"scale_m"`` (B,) metres per unit, which then takes precedence per sample.
        emd_points: EMD (exact assignment, O(n^3)) is computed on this many random points of each
            cloud during validation/test; 0 uses every point.
        log_figures: send an input / reconstruction / ground-truth figure each validation epoch.

    Shapes:
        forward: sparse (B, N, 3) padded, lengths (B,) int64 or None -> dense (B, num_points, 3).
        batches: dict with "sparse" (B, N, 3), "lengths" (B,), "dense" (B, M, 3); optional "label".
    """

    # the best validation CD so far, ``self.val_cd_best``, carried across resumes (BestMetricMixin)
    best_metric_name, best_metric_attr, best_metric_mode = "val/cd_mm_best", "val_cd_best", "min"

    def __init__(
        self,
        num_points: int = 2048,
        attention: bool = True,
        alpha: float = 100.0,
        lr: float = 1e-4,
        weight_decay: float = 0.0,
        lr_schedule: str = "constant",
        lr_min_ratio: float = 0.01,
        encoder_channels: tuple[int, ...] = (64, 64, 128, 1024),
        fc_channels: int = 1024,
        deconv_channels: tuple[int, ...] = (512, 256, 256, 128),
        deconv_strides: tuple[int, ...] = (4, 4, 4, 4, 8),
        bn_momentum_init: float = 0.5,
        bn_decay_rate: float = 0.5,
        bn_decay_step: int = 200_000,
        bn_decay_max: float = 0.99,
        input_scale: float = 1.0,
        mm_per_unit: float = 1000.0,
        emd_points: int = 512,
        log_figures: bool = True,
    ) -> None:
        super().__init__()
        if math.prod(deconv_strides) != num_points:
            raise ValueError(
                f"deconv_strides: product {math.prod(deconv_strides)} != num_points {num_points}"
            )
        as_real(input_scale, "input_scale", low=0.0, open_low=True)
        if lr_schedule not in ("constant", "cosine"):
            raise ValueError(f"lr_schedule: 'constant' or 'cosine', got {lr_schedule!r}")
        as_real(lr_min_ratio, "lr_min_ratio", low=0.0, high=1.0)
        self.save_hyperparameters()
        self.encoder = ActorEncoder(tuple(encoder_channels), attention=attention)
        self.decoder = ActorDecoder(
            self.encoder.out_channels, fc_channels, tuple(deconv_channels), tuple(deconv_strides)
        )
        self.train_loss = MeanMetric()
        self.val_loss = MeanMetric()
        self.test_loss = MeanMetric()
        self.val_cd = MeanMetric()
        self.val_hd = MeanMetric()
        self.val_emd = MeanMetric()
        self.test_cd = MeanMetric()
        self.test_hd = MeanMetric()
        self.test_emd = MeanMetric()
        self.reset_best_metric()
        self._figure_batch: dict[str, Tensor] | None = None

    # ---------------------------------------------------------------- forward
    def encode(self, sparse: Tensor, lengths: Tensor | None = None) -> tuple[Tensor, Tensor]:
        """Global feature vector and the centre used to normalise. Shapes: (B, 1024), (B, 1, 3)."""
        if sparse.dim() != 3 or sparse.shape[-1] != 3:
            raise ValueError(f"sparse: expected (B, N, 3), got {tuple(sparse.shape)}")
        if lengths is None:
            lengths = torch.full((sparse.shape[0],), sparse.shape[1], dtype=torch.long, device=sparse.device)
        centre = _masked_centre(sparse, lengths)
        x = (sparse - centre) / self.hparams.input_scale
        return self.encoder(x, lengths), centre

    def forward(self, sparse: Tensor, lengths: Tensor | None = None) -> Tensor:
        """Dense reconstruction (Sec. 8.2.2, Fig. 8.2a): encoder, decoder, and the input normalisation undone.

        Shapes:
            sparse (B, N, 3) padded, lengths (B,) int64 or None (every row a point) -> (B, num_points, 3).
        """
        z, centre = self.encode(sparse, lengths)
        return self.decoder(z) * self.hparams.input_scale + centre

    # ---------------------------------------------------------------- steps
    def model_step(self, batch: dict[str, Tensor]) -> tuple[Tensor, Tensor]:
        """The one shared step: reconstruction and ``alpha * L_CD`` (eq. 8.1)."""
        pred = self(batch["sparse"], batch.get("lengths"))
        loss = actor_loss(pred, batch["dense"], self.hparams.alpha)
        return loss, pred

    def on_train_batch_start(self, batch: Any, batch_idx: int) -> None:
        samples = self.global_step * int(batch["sparse"].shape[0])
        momentum = bn_momentum_at(
            samples,
            self.hparams.bn_momentum_init,
            self.hparams.bn_decay_rate,
            self.hparams.bn_decay_step,
            self.hparams.bn_decay_max,
        )
        for m in self.modules():
            if isinstance(m, torch.nn.modules.batchnorm._BatchNorm):
                m.momentum = momentum

    def training_step(self, batch: dict[str, Tensor], batch_idx: int) -> Tensor:
        loss, _ = self.model_step(batch)
        self.train_loss(loss)
        self.log(
            "train/loss",
            self.train_loss,
            on_step=False,
            on_epoch=True,
            prog_bar=True,
            batch_size=batch["sparse"].shape[0],
        )
        return loss

    def _distances_mm(self, pred: Tensor, batch: dict[str, Tensor]) -> tuple[Tensor, Tensor, Tensor]:
        """Per-sample CD, HD, EMD in millimetres (eq. 8.1, 8.6, 8.7). Shapes: 3 x (B,)."""
        dense = batch["dense"].to(pred.dtype)
        cd, hd = chamfer_hausdorff(pred.detach(), dense)
        emd = []
        gen = torch.Generator().manual_seed(0)
        n_emd = int(self.hparams.emd_points)
        for b in range(pred.shape[0]):
            p, d = pred[b].detach().cpu().double(), dense[b].detach().cpu().double()
            if 0 < n_emd < min(len(p), len(d)):
                p = p[torch.randperm(len(p), generator=gen)[:n_emd]]
                d = d[torch.randperm(len(d), generator=gen)[:n_emd]]
            emd.append(float(earth_movers_distance(p, d)))
        emd_t = torch.tensor(emd, dtype=pred.dtype, device=pred.device)
        scale = torch.full_like(cd, float(self.hparams.mm_per_unit))
        if "scale_m" in batch:
            scale = batch["scale_m"].to(pred.dtype) * 1000.0
        return cd * scale, hd * scale, emd_t * scale

    def validation_step(self, batch: dict[str, Tensor], batch_idx: int) -> None:
        loss, pred = self.model_step(batch)
        cd, hd, emd = self._distances_mm(pred, batch)
        bs = batch["sparse"].shape[0]
        self.val_loss(loss)
        self.val_cd(cd.mean())
        self.val_hd(hd.mean())
        self.val_emd(emd.mean())
        self.log("val/loss", self.val_loss, on_step=False, on_epoch=True, prog_bar=True, batch_size=bs)
        self.log("val/cd_mm", self.val_cd, on_step=False, on_epoch=True, prog_bar=True, batch_size=bs)
        self.log("val/hd_mm", self.val_hd, on_step=False, on_epoch=True, batch_size=bs)
        self.log("val/emd_mm", self.val_emd, on_step=False, on_epoch=True, batch_size=bs)
        if batch_idx == 0:
            n = int(batch["lengths"][0]) if "lengths" in batch else batch["sparse"].shape[1]
            self._figure_batch = {
                "sparse": batch["sparse"][0, :n].detach().cpu(),
                "pred": pred[0].detach().cpu(),
                "dense": batch["dense"][0].detach().cpu(),
            }

    def on_validation_epoch_start(self) -> None:
        self._figure_batch = None

    def on_validation_epoch_end(self) -> None:
        # the sanity check is no epoch of this run: it neither moves the best nor logs a figure
        if not self.update_best_metric(float(self.val_cd.compute())):
            return
        if self.hparams.log_figures and self._figure_batch is not None and self.logger is not None:
            from vtlearn.models.actor_figures import log_figure, reconstruction_figure

            fb = self._figure_batch
            fig = reconstruction_figure([[fb["sparse"].numpy(), fb["pred"].numpy(), fb["dense"].numpy()]])
            log_figure(self.logger, "val/reconstruction", fig, self.global_step)

    def test_step(self, batch: dict[str, Tensor], batch_idx: int) -> None:
        loss, pred = self.model_step(batch)
        cd, hd, emd = self._distances_mm(pred, batch)
        bs = batch["sparse"].shape[0]
        self.test_loss(loss)
        self.test_cd(cd.mean())
        self.test_hd(hd.mean())
        self.test_emd(emd.mean())
        self.log("test/loss", self.test_loss, on_step=False, on_epoch=True, batch_size=bs)
        self.log("test/cd_mm", self.test_cd, on_step=False, on_epoch=True, batch_size=bs)
        self.log("test/hd_mm", self.test_hd, on_step=False, on_epoch=True, batch_size=bs)
        self.log("test/emd_mm", self.test_emd, on_step=False, on_epoch=True, batch_size=bs)

    def predict_step(self, batch: dict[str, Tensor], batch_idx: int, dataloader_idx: int = 0) -> Tensor:
        return self(batch["sparse"], batch.get("lengths"))

    def configure_optimizers(self):
        opt = torch.optim.Adam(
            self.parameters(), lr=self.hparams.lr, betas=(0.9, 0.999), weight_decay=self.hparams.weight_decay
        )
        if self.hparams.get("lr_schedule", "constant") == "constant":
            return opt
        total = max(1, int(self.trainer.estimated_stepping_batches))
        sched = torch.optim.lr_scheduler.CosineAnnealingLR(
            opt, T_max=total, eta_min=self.hparams.lr * self.hparams.lr_min_ratio
        )
        return {"optimizer": opt, "lr_scheduler": {"scheduler": sched, "interval": "step"}}


# -------------------------------------------------------------------- checkpoint inference API
def read_lightning_checkpoint(ckpt: str | Path) -> dict[str, Any]:
    """``torch.load(weights_only=True)`` with clear errors for missing, corrupted or non-Lightning files, and
    for a checkpoint whose weights hold NaN or inf (a diverged training), which would otherwise give NaN
    reconstructions and class scores downstream."""
    path = Path(ckpt)
    if not path.is_file():
        raise FileNotFoundError(f"ckpt: no such file: {path}")
    try:
        data = torch.load(path, map_location="cpu", weights_only=True)
    except Exception as exc:  # corrupted, truncated, or pickles that weights_only refuses
        # torch's own text for a refused pickle advises weights_only=False, which would run the file's code
        raise ValueError(
            f"ckpt: {path} is not a readable PyTorch checkpoint ({type(exc).__name__}: corrupted, truncated, "
            "or holding objects that a weights_only=True load refuses)"
        ) from exc
    if not isinstance(data, dict) or "state_dict" not in data or "hyper_parameters" not in data:
        raise ValueError(
            f"ckpt: {path} is not a Lightning checkpoint (needs 'state_dict' and 'hyper_parameters')"
        )
    bad = [k for k, v in data["state_dict"].items()
           if isinstance(v, torch.Tensor) and v.is_floating_point() and not torch.isfinite(v).all()]
    if bad:
        raise ValueError(
            f"ckpt: {path} has NaN or inf weights in {len(bad)} tensor(s), first {bad[0]!r}; the training "
            f"that wrote it diverged (use an earlier checkpoint)"
        )
    return data


def _plain_hparams(hparams: dict[str, Any], cls) -> dict[str, Any]:
    import inspect

    names = set(inspect.signature(cls.__init__).parameters) - {"self"}
    out = {}
    for k, v in hparams.items():
        if k in names:
            out[k] = tuple(v) if isinstance(v, list) else v
    return out


def _check_map_location(map_location) -> torch.device:
    """``map_location`` as a ``torch.device``, or a ValueError naming it (e.g. ``"bogus"``)."""
    try:
        return torch.device(map_location)
    except (RuntimeError, TypeError, ValueError) as exc:
        raise ValueError(
            f"map_location: expected a torch device such as 'cpu' or 'cuda:0', got {map_location!r} "
            f"({str(exc).splitlines()[0] if str(exc) else type(exc).__name__})"
        ) from None


def _to_device(model, map_location):
    """``model`` moved to the checked ``map_location`` (a ValueError naming it for a device this machine
    does not have)."""
    try:
        return model.to(map_location)
    except (AssertionError, RuntimeError) as exc:
        raise ValueError(f"map_location: cannot move the model to {map_location!r} "
                         f"({str(exc).splitlines()[0] if str(exc) else type(exc).__name__})") from None


def load_actor(ckpt: str | Path, map_location: str | torch.device = "cpu") -> ACTOR:
    """Load an :class:`ACTOR` from a Lightning checkpoint with ``weights_only=True``, in eval mode.

    Raises:
        FileNotFoundError: missing file.
        ValueError: corrupted file, a checkpoint of another model (the message says which), or a
            ``map_location`` that is not a torch device of this machine.
    """
    map_location = _check_map_location(map_location)
    data = read_lightning_checkpoint(ckpt)
    state = data["state_dict"]
    if not any(k.startswith("encoder.features.") for k in state) or not any(
        k.startswith("decoder.") for k in state
    ):
        raise ValueError(
            f"ckpt: {ckpt} is not an ACTOR checkpoint (no encoder.features.* / decoder.* weights)"
        )
    try:
        model = ACTOR(**_plain_hparams(dict(data["hyper_parameters"]), ACTOR))
        model.load_state_dict(state, strict=True)
    except (RuntimeError, TypeError, ValueError) as exc:
        raise ValueError(
            f"ckpt: {ckpt} does not match the ACTOR architecture: {str(exc).splitlines()[0]}"
        ) from exc
    return _to_device(model, map_location).eval()


@torch.no_grad()
def reconstruct(model: ACTOR, points, lengths=None) -> np.ndarray:
    """Dense reconstruction of one sparse cloud or a padded batch, as numpy.

    The clouds are in ACTOR's canonical frame, not in metres: centred on the object's bounding box and
    divided by its largest extent, so a whole object spans 1
    (:func:`vtlearn.geometry.transforms.canonical_box`; the README's "Models in your own loop" shows the
    round trip ``(points - centre) / L`` in and ``dense * L + centre`` out). A cloud spanning more than 2 is
    refused as not canonical (e.g. millimetres). A cloud in metres is not detectable (a partial canonical
    cloud is small too) and gives a wrong shape.

    Args:
        model: an :class:`ACTOR` (put in eval mode here); anything that is not a torch module returning
            ``(B, P, 3)`` clouds (e.g. None or an XAVTNet classifier) is refused.
        points: one cloud (N, 3) (numpy, torch or list) with N >= 3, or a padded batch (B, N, 3) with
            ``lengths``, B >= 1 and N >= 1.
        lengths: (B,) valid points per cloud, batch input only. Without it every row is a point, zero padding
            included (a warning says so when a cloud ends in all-zero rows).

    Shapes:
        (N, 3) -> (num_points, 3); (B, N, 3) -> (B, num_points, 3).
    """
    if not isinstance(model, torch.nn.Module):
        raise ValueError(f"model: expected an ACTOR (e.g. from load_actor), got {type(model).__name__}")
    model.eval()

    def run(x, *lt):
        out = model(x, *lt)
        # A network whose forward gives (B, P, 3) point clouds is accepted (test stand-ins); others are not.
        if not isinstance(out, Tensor) or out.dim() != 3 or out.shape[-1] != 3:
            raise ValueError(
                f"model: expected an ACTOR (a network returning (B, P, 3) clouds), got "
                f"{type(model).__name__} returning {type(out).__name__}"
            )
        return out.cpu().numpy()

    x, lt, single = _model_input(model, points, lengths, "reconstruct")
    return run(x)[0] if single else run(x, lt)


def _model_input(model, points, lengths, caller: str) -> tuple[Tensor, Tensor | None, bool]:
    """``points`` (and ``lengths``) checked as :func:`reconstruct` documents them, for an ACTOR or a model on
    its encoder: float32 on the model's device, the lengths as int64 (None without), and whether ``points``
    was one cloud. ``caller`` names the function in the warning about unpadded zero rows.

    Shapes:
        (N, 3) -> (1, N, 3), None, True; (B, N, 3) and (B,) or None -> (B, N, 3), (B,) or None, False.
    """
    device = next(model.parameters(), torch.empty(0)).device
    if (
        isinstance(points, Tensor)
        and points.dim() == 3
        or isinstance(points, np.ndarray)
        and points.ndim == 3
    ):
        x = torch.as_tensor(
            np.asarray(points) if isinstance(points, np.ndarray) else points, dtype=torch.float32
        )
        if x.shape[-1] != 3:
            raise ValueError(f"points: expected a padded batch of shape (B, N, 3), got {tuple(x.shape)}")
        if x.shape[0] == 0 or x.shape[1] == 0:
            raise ValueError(
                f"points: the batch has no clouds or the clouds are empty, shape {tuple(x.shape)}"
            )
        if not torch.isfinite(x).all():
            raise ValueError("points: contains NaN or inf")
        if lengths is None and bool((x[:, -1] == 0).all(-1).any()):
            warnings.warn(f"{caller}: a cloud of the batch ends in all-zero rows, which count as points "
                          "without lengths; pass lengths for a padded batch",
                          stacklevel=4)  # the caller of reconstruct / classify, past torch.no_grad's wrapper
        if lengths is not None:
            lengths_np = np.asarray(lengths.cpu() if isinstance(lengths, Tensor) else lengths)
            if not np.issubdtype(lengths_np.dtype, np.integer):  # a cast would truncate 1.5 to 1
                raise ValueError(f"lengths: expected integer point counts, got dtype {lengths_np.dtype}")
        lt = None if lengths is None else torch.as_tensor(lengths, dtype=torch.long).to(device)
        valid = x.detach().cpu().numpy().astype(np.float64)
        if lt is not None and lt.shape == (len(valid),):
            valid[np.arange(valid.shape[1])[None, :] >= lt.cpu().numpy()[:, None]] = np.nan  # the padding
        _check_canonical(valid, _input_scale(model))
        return x.to(device), lt, False
    pts = as_points(points, "points", min_points=3)
    _check_canonical(pts[None], _input_scale(model))
    return torch.as_tensor(pts, dtype=torch.float32, device=device)[None], None, True


def _input_scale(model) -> float:
    """The units per canonical unit of ``model``'s input (``ACTOR(input_scale=...)``; 1 for the canonical
    frame and for stand-ins without the hyper-parameter)."""
    try:
        return float(dict(getattr(model, "hparams", {}) or {}).get("input_scale", 1.0) or 1.0)
    except (TypeError, ValueError):
        return 1.0


def _check_canonical(clouds: np.ndarray, input_scale: float = 1.0) -> None:
    """A ValueError naming ``points`` when a cloud of ``clouds`` (B, N, 3; NaN rows are padding) spans more
    than 2 along an axis, in units of ``input_scale`` when that is above 1 (a model trained with it takes its
    data's own units): ACTOR's canonical frame puts a whole object within 1."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)  # an all-padding cloud
        span = np.nanmax(np.nanmax(clouds, axis=1) - np.nanmin(clouds, axis=1), axis=-1)
    worst = int(np.nanargmax(span)) if np.isfinite(span).any() else 0
    if np.isfinite(span[worst]) and span[worst] > 2.0 * max(1.0, input_scale):
        where = "" if len(clouds) == 1 else f" (cloud {worst})"
        raise ValueError(f"points: spans {span[worst]:.4g}{where}, but ACTOR takes clouds in its canonical "
                         f"frame, where a whole object spans {max(1.0, input_scale):g} (1, or the model's "
                         "input_scale; are they in millimetres?); map a cloud in metres with "
                         "vtlearn.geometry.transforms.canonical_box(points, extent_m)")
