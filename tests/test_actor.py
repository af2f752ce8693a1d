"""ACTOR (thesis ch.8, Sec. 8.2.2): components, loss, padding invariance, Lightning smoke + checkpoints."""

import os

os.environ.setdefault("WANDB_MODE", "disabled")

import lightning as L
import numpy as np
import pytest
import torch
from _tiny_models import TINY_ACTOR as TINY
from lightning.pytorch.callbacks import ModelCheckpoint
from lightning.pytorch.loggers import CSVLogger

from vtlearn.models.actor import ACTOR, actor_loss, bn_momentum_at, load_actor, reconstruct
from vtlearn.models.actor_synthetic import PrimitiveDataModule
from vtlearn.models.components.actor_attention import MIN_WEIGHT, SelfAttentionUnit
from vtlearn.models.components.actor_decoder import ActorDecoder
from vtlearn.models.components.actor_encoder import ActorEncoder
from vtlearn.models.components.actor_pointnet import MaskedBatchNorm1d, PointNetFeatures

torch.set_num_threads(1)


def _pad(cloud: torch.Tensor, n: int, fill: float) -> torch.Tensor:
    out = torch.full((n, 3), fill, dtype=cloud.dtype)
    out[: len(cloud)] = cloud
    return out


# ------------------------------------------------------------------ components
def test_pointnet_features_shape_and_repr():
    net = PointNetFeatures()
    out = net(torch.randn(2, 50, 3))
    assert out.shape == (2, 1024, 50)
    assert repr(net) == "PointNetFeatures(channels=(64, 64, 128, 1024))"
    with pytest.raises(ValueError, match="points"):
        net(torch.randn(2, 50, 2))


def test_attention_unit_shape_weights_and_mask():
    unit = SelfAttentionUnit(32)
    x = torch.randn(3, 32, 10)
    mask = torch.arange(10)[None] < torch.tensor([10, 4, 7])[:, None]
    assert unit(x, mask).shape == (3, 32, 10)
    w = unit.attention_weights(x, mask)
    assert w.shape == (3, 10, 10)
    torch.testing.assert_close(w.sum(dim=1), torch.ones(3, 10))  # softmax over the summed index
    assert torch.all(w[1, 4:, :] == 0)  # padded points carry no weight
    assert repr(unit) == "SelfAttentionUnit(channels=32, reduction=8)"
    with pytest.raises(ValueError, match="x"):
        unit(torch.randn(3, 31, 10))


def test_attention_unit_matches_naive_formula():
    torch.manual_seed(0)
    unit = SelfAttentionUnit(16, reduction=4).double()
    x = torch.randn(1, 16, 6, dtype=torch.float64)
    g, h, k = unit.mlp_g(x)[0], unit.mlp_h(x)[0], unit.mlp_k(x)[0]  # C' x N, C' x N, C x N
    s = g.T @ h  # S_ji = g_j . h_i
    w = torch.exp(s) / torch.exp(s).sum(dim=0, keepdim=True)
    expected = x[0] + torch.stack([sum(w[j, i] * k[:, j] for j in range(6)) for i in range(6)], dim=1)
    torch.testing.assert_close(unit(x)[0], expected)


def test_attention_weights_below_min_weight_are_zero_not_denormal():
    """Sharp scores leave no denormal weight (a slow CPU path); the output matches the exact softmax."""
    torch.manual_seed(0)
    unit = SelfAttentionUnit(16, reduction=4)
    with torch.no_grad():
        unit.mlp_g.weight.mul_(30.0)  # scores spread over hundreds: many exp(s - max) underflow
    x = torch.randn(2, 16, 40)
    w = unit.attention_weights(x)
    tiny = torch.finfo(w.dtype).tiny
    assert ((w > 0) & (w < tiny)).sum() == 0
    assert (w == 0).any() and w[w > 0].min() >= MIN_WEIGHT
    g, h, k = unit.mlp_g(x), unit.mlp_h(x), unit.mlp_k(x)
    exact = torch.softmax(torch.bmm(g.transpose(1, 2).double(), h.double()), dim=1)
    assert ((exact > 0) & (exact < MIN_WEIGHT)).any()  # the case above is one the threshold changes
    torch.testing.assert_close(unit(x), x + torch.bmm(k.double(), exact).float(), rtol=1e-5, atol=1e-5)


def test_encoder_and_decoder_shapes():
    enc = ActorEncoder()
    z = enc(torch.randn(3, 40, 3), torch.tensor([40, 20, 33]))
    assert z.shape == (3, 1024)
    assert ActorEncoder(attention=False).attention is None
    dec = ActorDecoder()
    assert dec(z).shape == (3, 2048, 3)
    assert dec.num_points == 2048
    with pytest.raises(ValueError, match="lengths"):
        enc(torch.randn(2, 10, 3), torch.tensor([11, 3]))
    with pytest.raises(ValueError, match="strides"):
        ActorDecoder(deconv_channels=(4,), strides=(2,))


def test_masked_batchnorm_matches_batchnorm_on_valid_points():
    torch.manual_seed(0)
    mbn, bn = MaskedBatchNorm1d(4), torch.nn.BatchNorm1d(4)
    x = torch.randn(2, 4, 9)
    mask = torch.arange(9)[None] < torch.tensor([9, 5])[:, None]
    y = mbn(x, mask)
    valid = torch.cat([x[0], x[1, :, :5]], dim=1)[None]  # 1 x 4 x 14
    ref = bn(valid)[0]
    torch.testing.assert_close(torch.cat([y[0], y[1, :, :5]], dim=1), ref)
    torch.testing.assert_close(mbn.running_mean, bn.running_mean)
    torch.testing.assert_close(mbn.running_var, bn.running_var)


@pytest.mark.parametrize("train_mode", [False, True])
@pytest.mark.parametrize("attention", [True, False])
def test_padding_invariance(train_mode, attention):
    """The same clouds padded differently (size and fill value) reconstruct identically."""
    torch.manual_seed(0)
    model = (
        ACTOR(attention=attention, **TINY).double().train(train_mode)
    )  # float64: only summation order differs
    a, b = torch.randn(25, 3, dtype=torch.float64), torch.randn(60, 3, dtype=torch.float64)
    lengths = torch.tensor([25, 60])
    batch1 = torch.stack([_pad(a, 60, 0.0), b])
    batch2 = torch.stack([_pad(a, 200, 7.5), _pad(b, 200, -3.0)])
    with torch.no_grad():
        out1, out2 = model(batch1, lengths), model(batch2, lengths)
    torch.testing.assert_close(out1, out2, atol=1e-10, rtol=1e-10)
    if not train_mode:  # in eval mode a cloud's output does not depend on its batch-mates either
        with torch.no_grad():
            alone = model(a[None])
        torch.testing.assert_close(alone[0], out1[0], atol=1e-10, rtol=1e-10)


# ------------------------------------------------------------------ loss (eq. 8.1)
def _naive_chamfer(x: torch.Tensor, y: torch.Tensor) -> torch.Tensor:
    fwd = sum(min(torch.linalg.norm(p - q) for q in y) for p in x) / len(x)
    bwd = sum(min(torch.linalg.norm(q - p) for p in x) for q in y) / len(y)
    return fwd + bwd


def test_actor_loss_matches_naive_reference():
    torch.manual_seed(1)
    pred, target = torch.randn(2, 7, 3, dtype=torch.float64), torch.randn(2, 5, 3, dtype=torch.float64)
    naive = 100.0 * (_naive_chamfer(pred[0], target[0]) + _naive_chamfer(pred[1], target[1])) / 2
    torch.testing.assert_close(actor_loss(pred, target, alpha=100.0), naive)


def test_actor_loss_hand_computed():
    pred = torch.tensor([[[0.0, 0.0, 0.0], [1.0, 0.0, 0.0]]])
    target = torch.tensor([[[0.0, 0.0, 0.0]]])
    # pred->target: (0 + 1) / 2; target->pred: 0; alpha 100 -> 50
    torch.testing.assert_close(actor_loss(pred, target, alpha=100.0), torch.tensor(50.0))


def test_actor_loss_gradcheck():
    torch.manual_seed(2)
    pred = torch.randn(2, 6, 3, dtype=torch.float64, requires_grad=True)
    target = torch.randn(2, 5, 3, dtype=torch.float64)
    assert torch.autograd.gradcheck(lambda p: actor_loss(p, target, alpha=3.0), (pred,))


def test_bn_momentum_schedule():
    assert bn_momentum_at(0) == 0.5
    assert bn_momentum_at(199_999) == 0.5
    assert bn_momentum_at(200_000) == 0.25
    assert bn_momentum_at(10**9) == pytest.approx(0.01)  # TF decay capped at 0.99
    model = ACTOR(**TINY)
    model.on_train_batch_start({"sparse": torch.zeros(8, 5, 3)}, 0)
    assert all(m.momentum == 0.5 for m in model.modules() if isinstance(m, torch.nn.BatchNorm1d))


def test_invalid_hparams():
    with pytest.raises(ValueError, match="deconv_strides"):
        ACTOR(num_points=100)
    with pytest.raises(ValueError, match="input_scale"):
        ACTOR(input_scale=0.0, **TINY)
    with pytest.raises(ValueError, match="lr_schedule"):
        ACTOR(lr_schedule="step", **TINY)


def test_cosine_schedule_decays_to_min_ratio_over_the_run():
    model = ACTOR(lr=1e-3, lr_schedule="cosine", lr_min_ratio=0.1, **TINY)
    trainer = L.Trainer(
        max_epochs=2, accelerator="cpu", enable_progress_bar=False, enable_model_summary=False, logger=False,
        enable_checkpointing=False, limit_val_batches=0,
    )
    trainer.fit(model, datamodule=_dm())
    opt = trainer.optimizers[0]
    # two epochs of two steps: cosine from 1e-3 to 1e-4 at the last step
    assert opt.param_groups[0]["lr"] == pytest.approx(1e-4, rel=1e-6)
    assert trainer.global_step == 4


# ------------------------------------------------------------------ Lightning
def _dm(num_dense: int = 64) -> PrimitiveDataModule:
    return PrimitiveDataModule(batch_size=4, size=8, num_dense=num_dense, min_points=20, max_points=60)


@pytest.mark.parametrize("attention", [True, False])
def test_fast_dev_run(attention):
    model = ACTOR(attention=attention, **TINY)
    trainer = L.Trainer(
        fast_dev_run=True, accelerator="cpu", enable_progress_bar=False, enable_model_summary=False
    )
    trainer.fit(model, datamodule=_dm())
    trainer.test(model, datamodule=_dm())
    preds = trainer.predict(model, datamodule=_dm())
    assert preds[0].shape == (4, 64, 3)


def test_train_logs_metrics_figure_and_checkpoint_round_trip(tmp_path):
    torch.manual_seed(0)
    model = ACTOR(**TINY)
    best_cb = ModelCheckpoint(dirpath=tmp_path / "ckpt", monitor="val/cd_mm", mode="min", filename="best")
    # Lightning refreshes last.ckpt only when its callback saves, so "last" has its own unmonitored callback.
    last_cb = ModelCheckpoint(dirpath=tmp_path / "ckpt", save_last=True, filename="latest")
    logger = CSVLogger(tmp_path, name="actor")
    trainer = L.Trainer(
        max_epochs=2,
        accelerator="cpu",
        logger=logger,
        callbacks=[best_cb, last_cb],
        enable_progress_bar=False,
        enable_model_summary=False,
        log_every_n_steps=1,
    )
    trainer.fit(model, datamodule=_dm())
    metrics = trainer.callback_metrics
    for key in ("val/loss", "val/cd_mm", "val/hd_mm", "val/emd_mm", "train/loss"):
        assert key in metrics and torch.isfinite(metrics[key])
    # CD (symmetric sum of means) is at most twice HD, and EMD >= the one-sided mean
    assert metrics["val/cd_mm"] <= 2 * metrics["val/hd_mm"] + 1e-3
    figs = list((tmp_path / "actor").rglob("val_reconstruction_step*.png"))
    assert len(figs) == 2
    last = tmp_path / "ckpt" / "last.ckpt"
    assert (tmp_path / "ckpt" / "best.ckpt").is_file()
    raw = torch.load(last, map_location="cpu", weights_only=True)
    assert "state_dict" in raw
    loaded = load_actor(last)
    x = torch.randn(2, 30, 3) * 0.05
    model.eval()
    with torch.no_grad():
        torch.testing.assert_close(loaded(x), model(x))
    out = reconstruct(loaded, x[0].numpy())
    assert out.shape == (64, 3) and np.isfinite(out).all()
    np.testing.assert_allclose(out, model(x[:1]).detach().numpy()[0], atol=1e-5)


def test_load_actor_errors(tmp_path):
    with pytest.raises(FileNotFoundError, match="ckpt"):
        load_actor(tmp_path / "missing.ckpt")
    bad = tmp_path / "corrupt.ckpt"
    bad.write_bytes(b"\x00garbage" * 100)
    with pytest.raises(ValueError, match="not a readable PyTorch checkpoint"):
        load_actor(bad)
    plain = tmp_path / "plain.pt"
    torch.save({"weights": torch.zeros(3)}, plain)
    with pytest.raises(ValueError, match="not a Lightning checkpoint"):
        load_actor(plain)
    foreign = tmp_path / "foreign.ckpt"
    torch.save({"state_dict": {"net.weight": torch.zeros(2)}, "hyper_parameters": {"lr": 0.1}}, foreign)
    with pytest.raises(ValueError, match="not an ACTOR checkpoint"):
        load_actor(foreign)


def test_reconstruct_validates_input():
    model = ACTOR(**TINY)
    with pytest.raises(ValueError, match="points"):
        reconstruct(model, np.full((10, 3), np.nan))
    with pytest.raises(ValueError, match="points"):
        reconstruct(model, np.zeros((10, 2)))


def test_reconstruct_refuses_clouds_that_are_not_canonical():
    """A cloud in millimetres spans hundreds of units; ACTOR's frame puts a whole object within 1."""
    import warnings

    model = ACTOR(**TINY)
    rng = np.random.default_rng(0)
    canon = rng.uniform(-0.5, 0.5, (40, 3))
    assert reconstruct(model, canon).shape[-1] == 3
    with pytest.raises(ValueError, match=r"points: spans 1\d\d\.?\d*, but ACTOR takes clouds in its"):
        reconstruct(model, canon * 150.0)
    batch = np.zeros((2, 40, 3), dtype=np.float32)
    batch[0], batch[1, :20] = canon, canon[:20] * 150.0
    with pytest.raises(ValueError, match=r"\(cloud 1\)"):
        reconstruct(model, batch, lengths=[40, 20])
    batch[1, :20] = canon[:20]
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # padded and lengths given: nothing to say
        assert reconstruct(model, batch, lengths=[40, 20]).shape[0] == 2
    with pytest.warns(UserWarning, match="pass lengths for a padded batch") as record:
        reconstruct(model, batch)
    assert record[0].filename == __file__  # the warning points at the caller's line
    with pytest.raises(ValueError, match="^lengths: expected integer point counts"):
        reconstruct(model, batch, lengths=[40.0, 20.5])  # a cast would silently make it 20
    # a model trained in its data's own units (input_scale) takes clouds of that size
    scaled = ACTOR(**{**TINY, "input_scale": 170.0})
    assert reconstruct(scaled, canon * 150.0).shape[-1] == 3
    with pytest.raises(ValueError, match=r"spans 170 \(1, or the model's input_scale"):
        reconstruct(scaled, canon * 1000.0)
    small = ACTOR(**{**TINY, "input_scale": 0.25})  # a divisor below 1: canonical clouds are still taken
    assert reconstruct(small, canon).shape[-1] == 3


def test_actor_loss_equals_foundation_chamfer_with_padding():
    from vtlearn.geometry.metrics import chamfer_distance

    torch.manual_seed(3)
    pred, target = torch.randn(3, 9, 3, dtype=torch.float64), torch.randn(3, 7, 3, dtype=torch.float64)
    lengths = torch.tensor([7, 4, 2])
    expected = 5.0 * chamfer_distance(pred, target, y_lengths=lengths, reduction="mean")
    torch.testing.assert_close(actor_loss(pred, target, alpha=5.0, target_lengths=lengths), expected)
    naive = 5.0 * sum(_naive_chamfer(pred[b], target[b, : lengths[b]]) for b in range(3)) / 3
    torch.testing.assert_close(actor_loss(pred, target, alpha=5.0, target_lengths=lengths), naive)


def test_nearest_indices_kdtree_equals_distance_matrix_with_padding():
    """The CPU k-d tree search finds the neighbours of the dense matrix path, padded targets excluded."""
    from vtlearn.models.actor import _nearest_indices, _nearest_indices_dense

    torch.manual_seed(4)
    x, y = torch.rand(3, 300, 3), torch.rand(3, 250, 3)
    lengths = torch.tensor([250, 40, 1])
    y[1, 40:] = x[1, :210]  # padding on top of predicted points: must not be matched
    got_xy, got_yx = _nearest_indices(x, y, lengths)
    ref_xy, ref_yx = _nearest_indices_dense(x, y, lengths)
    assert torch.equal(got_xy, ref_xy) and torch.equal(got_yx, ref_yx)
    assert (got_xy[1] < 40).all() and (got_xy[2] == 0).all()
    x_bad = x.clone()
    x_bad[0, 0, 0] = float("nan")  # a diverged step still gives indices (and a NaN loss, as before)
    assert _nearest_indices(x_bad, y, lengths)[0].shape == (3, 300)


def test_strided_conv_transpose_matches_pytorch():
    from vtlearn.models.components.actor_decoder import StridedConvTranspose1d

    torch.manual_seed(4)
    layer = StridedConvTranspose1d(5, 3, 4, bias=True)
    x = torch.randn(2, 5, 6)
    ref = torch.nn.functional.conv_transpose1d(x, layer.weight, layer.bias, stride=4)
    torch.testing.assert_close(layer(x), ref)
    assert layer(x).shape == (2, 3, 24)


def test_chamfer_hausdorff_equals_foundation_metrics():
    from vtlearn.geometry.metrics import chamfer_distance, hausdorff_distance
    from vtlearn.models.actor import chamfer_hausdorff

    torch.manual_seed(5)
    x, y = torch.randn(3, 11, 3, dtype=torch.float64), torch.randn(3, 8, 3, dtype=torch.float64)
    cd, hd = chamfer_hausdorff(x, y)
    torch.testing.assert_close(cd, chamfer_distance(x, y, reduction="none"))
    torch.testing.assert_close(hd, hausdorff_distance(x, y, reduction="none"))
