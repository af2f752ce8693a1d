"""Tests for the xAVTNet LightningModule and its PointNet components (thesis ch.7)."""

import contextlib
import math
import os
from pathlib import Path

import lightning as L
import pytest
import torch
from lightning.pytorch.utilities import CombinedLoader
from torch.utils.data import DataLoader, Dataset

from vtlearn.models.components.pointnet_tnet import (
    MaskedPointMLP,
    TNet,
    feature_transform_regularizer,
    lengths_to_mask,
    masked_max_pool,
    packed_max_pool,
)
from vtlearn.models.xavtnet import XAVTNet, normalize_padded, subsample_padded

os.environ.setdefault("WANDB_MODE", "disabled")
TINY = dict(num_classes=3, global_dim=32, fc_dims=[16, 8])


@contextlib.contextmanager
def running_statistics_kept(module):
    """Asserts that the block leaves every batch-norm running statistic of ``module`` as it found it; yields
    the snapshot (state-dict key -> a copy of the statistic taken on entry)."""
    running = {k: v.clone() for k, v in module.state_dict().items() if "running" in k}
    assert running, "the module has no running statistics to watch"
    yield running
    for k, v in module.state_dict().items():
        if k in running:
            assert torch.equal(v, running[k]), k


class _Clouds(Dataset):
    """Tiny labelled clouds of varying size: class c is a blob around (c, 0, 0)."""

    def __init__(self, n, n_min, n_max, seed, scale=1.0):
        g = torch.Generator().manual_seed(seed)
        self.items = []
        for i in range(n):
            m = int(torch.randint(n_min, n_max + 1, (1,), generator=g))
            c = i % 3
            pts = torch.randn(m, 3, generator=g) * 0.1 * scale + torch.tensor([float(c), 0.0, 0.0])
            self.items.append((pts, c))

    def __len__(self):
        return len(self.items)

    def __getitem__(self, i):
        return self.items[i]


def _collate(items, with_label=True):
    n = max(p.shape[0] for p, _ in items)
    pts = torch.zeros(len(items), n, 3)
    for i, (p, _) in enumerate(items):
        pts[i, : p.shape[0]] = p
    out = {"points": pts, "lengths": torch.tensor([p.shape[0] for p, _ in items])}
    if with_label:
        out["label"] = torch.tensor([c for _, c in items])
    return out


class TinyCrossModalDM(L.LightningDataModule):
    """Same batch structure as vtlearn.datamodules.CrossModalDataModule, on 3 toy classes."""

    num_classes = 3

    def train_dataloader(self):
        src = DataLoader(_Clouds(12, 40, 40, 0), batch_size=4, collate_fn=_collate, drop_last=True)
        tgt = DataLoader(
            _Clouds(8, 5, 12, 1, scale=2.0), batch_size=4, drop_last=True,
            collate_fn=lambda b: _collate(b, with_label=False),
        )
        return CombinedLoader({"source": src, "target": tgt}, mode="max_size_cycle")

    def val_dataloader(self):
        return DataLoader(_Clouds(6, 5, 12, 2), batch_size=3, collate_fn=_collate)

    test_dataloader = val_dataloader


def test_masked_max_pool_and_mlp_ignore_padding():
    torch.manual_seed(0)
    x = torch.randn(3, 6, 4)
    lengths = torch.tensor([6, 2, 4])
    mask = lengths_to_mask(lengths, 6)
    pooled = masked_max_pool(x, mask)
    for b in range(3):
        assert torch.equal(pooled[b], x[b, : lengths[b]].amax(0))
    mlp = MaskedPointMLP((4, 5)).train()
    y = mlp(x, mask)
    assert y.shape == (3, 6, 5) and torch.all(y[~mask] == 0)
    x_garbage = x.clone()
    x_garbage[~mask] = 1e3
    assert torch.allclose(mlp(x_garbage, mask), y)


def test_packed_max_pool_equals_padded_pool_with_its_gradient():
    """The encoders' pool of packed points is the padded masked max, value and gradient, ties included."""
    torch.manual_seed(0)
    lengths = torch.tensor([5, 1, 3, 5])
    mask = lengths_to_mask(lengths, 5)
    packed = torch.randn(int(mask.sum()), 4)
    packed[0] = packed[1] = packed[:5].amax(0) + 1.0  # a tie for the max of cloud 0: half the gradient each
    packed[6:9, 2] = 0.0  # cloud 2 all zero in one channel (post-ReLU features)
    a = packed.clone().requires_grad_()
    b = packed.clone().requires_grad_()
    padded = a.new_zeros(4, 5, 4).index_put((mask,), a)
    ref = masked_max_pool(padded, mask)
    out = packed_max_pool(b, mask)
    assert torch.equal(out, ref)
    g = torch.randn(4, 4)
    ref.backward(g)
    out.backward(g)
    assert torch.equal(a.grad, b.grad)
    assert torch.equal(b.grad[0], b.grad[1]) and torch.equal(2 * b.grad[0], g[0])
    with pytest.raises(ValueError, match="packed"):
        packed_max_pool(packed[:-1], mask)
    mlp = MaskedPointMLP((4, 6)).train()
    x = torch.randn(4, 5, 4)
    assert torch.allclose(mlp.pooled(x, mask), masked_max_pool(mlp(x, mask), mask))


@pytest.mark.parametrize("train_mode", [True, False])
def test_xavtnet_padding_does_not_change_outputs(train_mode):
    torch.manual_seed(0)
    model = XAVTNet(**TINY, dropout=0.0).train(train_mode)
    if not train_mode:
        model.train()
        model(torch.randn(8, 10, 3))  # move running stats off their init
        model.eval()
    points = torch.randn(4, 9, 3)
    lengths = torch.tensor([9, 3, 5, 1])
    padded = torch.cat([points, 50 * torch.randn(4, 7, 3)], dim=1)
    mask = lengths_to_mask(lengths, 9)
    points = points * mask[..., None]
    out_a = model(points, lengths)
    out_b = model(padded, lengths)
    assert torch.allclose(out_a.logits, out_b.logits, atol=1e-5)
    for name in ("global", "fc1", "fc2"):
        assert torch.allclose(out_a.features[name], out_b.features[name], atol=1e-5)


def test_xavtnet_shapes_and_input_checks():
    model = XAVTNet(**TINY).eval()
    out = model(torch.randn(2, 7, 3), torch.tensor([7, 4]))
    assert out.logits.shape == (2, 3)
    assert out.features["fc1"].shape == (2, 16) and out.features["fc2"].shape == (2, 8)
    # "global" is the max-pooled PointNet feature, the input of fc1 (the layer da_layers may name)
    assert out.features["global"].shape == (2, TINY["global_dim"])
    assert torch.allclose(model.head.fc1(out.features["global"]), out.features["fc1"], atol=1e-6)
    assert out.trans_input.shape == (2, 3, 3) and out.trans_feat.shape == (2, 64, 64)
    with pytest.raises(ValueError, match="points"):
        model(torch.randn(2, 7))
    with pytest.raises(ValueError, match="lengths"):
        model(torch.randn(2, 7, 3), torch.tensor([0, 3]))
    with pytest.raises(ValueError, match="points"):
        model(torch.full((2, 7, 3), float("nan")))
    with pytest.raises(ValueError, match="da_method"):
        XAVTNet(da_method="mmd")
    with pytest.raises(ValueError, match="da_layers"):
        XAVTNet(da_layers=["fc4"])
    with pytest.raises(ValueError, match="mmd_conditional"):
        XAVTNet(mmd_conditional=True, da_memory=8)


def test_untrained_tnet_is_identity_and_regulariser():
    tnet = TNet(3, 16).eval()
    x = torch.randn(2, 5, 3)
    trans = tnet(x, torch.ones(2, 5, dtype=torch.bool))
    assert torch.allclose(trans, torch.eye(3).expand(2, 3, 3))
    q, _ = torch.linalg.qr(torch.randn(4, 64, 64, dtype=torch.float64))
    assert feature_transform_regularizer(q).item() == pytest.approx(0.0, abs=1e-20 + 1e-10)
    # hand case: A = 2I (k = 2): I - 4I = -3I, squared Frobenius = 9 * 2
    assert feature_transform_regularizer(2 * torch.eye(2)[None]).item() == pytest.approx(18.0)
    a = torch.randn(2, 3, 3, dtype=torch.float64, requires_grad=True)
    assert torch.autograd.gradcheck(feature_transform_regularizer, (a,))
    with pytest.raises(ValueError, match="trans"):
        feature_transform_regularizer(torch.randn(2, 3, 4))


def test_subsample_and_normalize_padded():
    points = torch.arange(2 * 10 * 3, dtype=torch.float32).view(2, 10, 3)
    lengths = torch.tensor([10, 4])
    sub, sub_len = subsample_padded(points, lengths, 5, random=False)
    assert sub.shape == (2, 5, 3) and sub_len.tolist() == [5, 4]
    assert torch.equal(sub[0], points[0, ::2])  # strided: every second point of a 10-point cloud
    assert set(map(tuple, sub[1, :4].tolist())) == set(map(tuple, points[1, :4].tolist()))
    assert torch.all(sub[1, 4] == 0)
    rnd, _ = subsample_padded(points, lengths, 5, random=True)
    assert set(map(tuple, rnd[1, :4].tolist())) == set(map(tuple, points[1, :4].tolist()))
    norm = normalize_padded(points, lengths)
    assert torch.allclose(norm[1, :4].mean(0), torch.zeros(3), atol=1e-6)
    assert norm[0].norm(dim=-1).max().item() == pytest.approx(1.0)
    assert torch.all(norm[1, 4:] == 0)


@pytest.mark.parametrize(
    "kwargs,logged,absent",
    [
        (dict(da_method="none"), {"train/ce"}, {"train/mmd", "train/coral"}),
        (dict(use_coral=False), {"train/mmd_fc1", "train/mmd_fc2"}, {"train/coral"}),
        (dict(use_mmd=False), {"train/coral_fc1", "train/coral_fc2"}, {"train/mmd"}),
        (dict(da_layers=["fc1"]), {"train/mmd_fc1", "train/coral_fc1"}, {"train/mmd_fc2"}),
        (dict(da_layers=["fc2"]), {"train/mmd_fc2", "train/coral_fc2"}, {"train/mmd_fc1"}),
        (dict(), {"train/mmd", "train/coral", "train/ce"}, set()),
        (dict(da_method="dann"), {"train/domain", "train/grl_lambda"}, {"train/mmd"}),
        (dict(da_method="cdan"), {"train/domain", "train/grl_lambda"}, {"train/mmd"}),
        (dict(da_ramp_gamma=10.0), {"train/mmd", "train/da_scale"}, {"train/domain"}),
        (dict(da_memory=6), {"train/mmd", "train/coral"}, {"train/domain"}),
        (dict(im_weight=1.0), {"train/mmd", "train/im", "train/cond_entropy"}, {"train/domain"}),
        (dict(da_layers=["fc1", "fc2", "fc3"]), {"train/mmd_fc3", "train/coral_fc3"}, {"train/domain"}),
        (dict(da_layers=["global", "fc1"]), {"train/mmd_global", "train/coral_global"}, {"train/mmd_fc2"}),
        (dict(mmd_conditional=True, da_ramp_gamma=10.0), {"train/mmd_fc1", "train/da_scale"},
         {"train/domain"}),
        (dict(da_method="none", im_weight=1.0), {"train/im", "train/marginal_entropy"}, {"train/mmd"}),
        (dict(mcc_weight=1.0), {"train/mmd", "train/mcc", "train/mcc_diagonal"}, {"train/im"}),
        (dict(da_method="none", mcc_weight=1.0), {"train/mcc"}, {"train/mmd", "train/im"}),
        (dict(consistency_weight=1.0), {"train/consistency", "train/consistency_w", "train/mmd"},
         {"train/domain"}),
        (dict(da_method="none", consistency_weight=1.0), {"train/consistency"}, {"train/mmd"}),
        (dict(defrec_weight=1.0), {"train/mmd", "train/defrec"}, {"train/domain"}),
        (dict(da_method="none", defrec_weight=1.0), {"train/defrec"}, {"train/mmd"}),
        (dict(mcd_weight=1.0), {"train/mmd", "train/mcd", "train/ce_f2"}, {"train/domain"}),
        (dict(da_method="none", mcd_weight=1.0), {"train/mcd", "train/ce_f2"}, {"train/mmd"}),
        (dict(afn_weight=1.0), {"train/mmd", "train/afn_norm_source", "train/afn_norm_target"},
         {"train/domain"}),
        (dict(da_method="none", afn_weight=1.0), {"train/afn_norm_target"}, {"train/mmd"}),
    ],
)
def test_fast_dev_run_every_table_7_2_row(tmp_path, kwargs, logged, absent):
    torch.manual_seed(0)
    model = XAVTNet(**TINY, **kwargs)
    trainer = L.Trainer(
        fast_dev_run=1, accelerator="cpu", logger=False, enable_checkpointing=False,
        enable_progress_bar=False, enable_model_summary=False, default_root_dir=tmp_path,
    )
    trainer.fit(model, datamodule=TinyCrossModalDM())
    keys = set(trainer.logged_metrics) | set(trainer.callback_metrics)
    assert logged <= keys, keys
    assert not (absent & keys), keys
    assert torch.isfinite(trainer.callback_metrics["train/loss"])
    trainer.test(model, datamodule=TinyCrossModalDM(), verbose=False)
    assert model.last_test_confusion.shape == (3, 3)
    assert int(model.last_test_confusion.sum()) == 3  # fast_dev_run=1: one test batch of 3


def test_single_stream_labelled_batch_trains(tmp_path):
    model = XAVTNet(**TINY)
    loader = DataLoader(_Clouds(8, 5, 20, 3), batch_size=4, collate_fn=_collate)
    trainer = L.Trainer(fast_dev_run=1, accelerator="cpu", logger=False, enable_progress_bar=False,
                        enable_model_summary=False, default_root_dir=tmp_path)
    trainer.fit(model, train_dataloaders=loader, val_dataloaders=loader)
    assert "val/acc" in trainer.callback_metrics


def test_cosine_schedule_decays_the_learning_rate_to_zero(tmp_path):
    loader = DataLoader(_Clouds(8, 5, 20, 3), batch_size=4, collate_fn=_collate)
    lrs = []

    class Record(L.Callback):
        def on_train_batch_start(self, trainer, pl_module, batch, batch_idx):
            lrs.append(trainer.optimizers[0].param_groups[0]["lr"])

    model = XAVTNet(**TINY, lr=1e-2, lr_schedule="cosine")
    trainer = L.Trainer(max_epochs=3, accelerator="cpu", logger=False, enable_progress_bar=False,
                        enable_model_summary=False, enable_checkpointing=False, limit_val_batches=0,
                        default_root_dir=tmp_path, callbacks=[Record()])
    trainer.fit(model, train_dataloaders=loader)
    steps = len(lrs)  # 3 epochs x 2 batches
    assert steps == 6
    expected = [1e-2 * 0.5 * (1 + math.cos(math.pi * i / steps)) for i in range(steps)]
    assert lrs == pytest.approx(expected, rel=1e-6)
    assert trainer.optimizers[0].param_groups[0]["lr"] == pytest.approx(0.0, abs=1e-12)
    # the thesis default keeps Adam's rate constant
    assert XAVTNet(**TINY).configure_optimizers().param_groups[0]["lr"] == 1e-3
    with pytest.raises(ValueError, match="lr_schedule"):
        XAVTNet(**TINY, lr_schedule="step")


def test_da_ramp_scales_the_alignment_terms_from_zero(tmp_path):
    """With ``da_ramp_gamma`` the scale passed to VTLoss follows Ganin's ramp: 0 at the first step, rising."""
    from vtlearn.losses.dann import dann_lambda

    scales = []
    model = XAVTNet(**TINY, da_ramp_gamma=10.0)
    forward = model.vtloss.forward

    def record(*args, da_scale=1.0, **kwargs):
        scales.append(da_scale)
        return forward(*args, da_scale=da_scale, **kwargs)

    model.vtloss.forward = record
    trainer = L.Trainer(max_epochs=2, accelerator="cpu", logger=False, enable_progress_bar=False,
                        enable_model_summary=False, enable_checkpointing=False, limit_val_batches=0,
                        default_root_dir=tmp_path)
    trainer.fit(model, datamodule=TinyCrossModalDM())
    total = trainer.estimated_stepping_batches
    assert scales == pytest.approx([dann_lambda(i / total, 10.0) for i in range(len(scales))])
    assert scales[0] == 0.0 and scales[-1] > scales[0]
    with pytest.raises(ValueError, match="da_ramp_gamma"):
        XAVTNet(**TINY, da_ramp_gamma=0.0)


def test_vtloss_training_lowers_domain_discrepancy_vs_no_da():
    """After the same number of steps, VTLoss training leaves a smaller fc1 MK-MMD than no-DA.

    Measured like the loss sees it: one joint source+target forward in training mode.
    """
    from vtlearn.losses import mk_mmd

    batch = next(iter(TinyCrossModalDM().train_dataloader()))[0]
    results = {}
    for method in ("none", "vtloss"):
        out_s, out_t = _trained_joint_outputs(batch, da_method=method)
        results[method] = mk_mmd(out_s.features["fc1"], out_t.features["fc1"]).item()
    assert results["vtloss"] < results["none"], results


def _trained_joint_outputs(batch, steps=10, seed=0, **kwargs):
    """Train a tiny XAVTNet (``seed``, no dropout) for ``steps`` steps on one two-stream batch; return the
    joint forward's (source, target) outputs on that batch, without gradient."""
    torch.manual_seed(seed)
    model = XAVTNet(**TINY, dropout=0.0, **kwargs).train()
    model._log_train = lambda *a, **k: None  # no trainer attached: skip self.log
    opt = model.configure_optimizers()
    for _ in range(steps):
        loss = model.training_step(batch, 0)
        opt.zero_grad()
        loss.backward()
        opt.step()
    with torch.no_grad():
        return model._joint_forward(batch["source"], batch["target"])


def _one_step(batch, **kwargs):
    """One training step of a tiny model (no-DA and no dropout unless ``kwargs`` say otherwise): the step's
    loss, the model, α·CE(source) + the regulariser, and the joint forward's (source, target) outputs on the
    step's subsampling of the clouds. No trainer is attached, so the training progress reads 1."""
    torch.manual_seed(0)
    model = XAVTNet(**{**TINY, "da_method": "none", "dropout": 0.0, **kwargs}).train()
    model._log_train = lambda *a, **k: None  # no trainer attached: skip self.log
    torch.manual_seed(1)
    loss = model.training_step(batch, 0)
    torch.manual_seed(1)  # the same subsampling of the clouds
    out_s, out_t = model._joint_forward(batch["source"], batch["target"])
    ce = torch.nn.functional.cross_entropy(out_s.logits, batch["source"]["label"])
    return loss.item(), model, model.hparams.alpha * ce + model._regulariser(out_s), out_s, out_t


def _step_with_target_term(batch, term, **kwargs) -> tuple[float, float]:
    """One training step of a tiny no-DA model whose ``kwargs`` add a loss on the target logits, and the loss
    it should give, α·CE(source) + ``term(target logits)`` + the regulariser, on the same subsampling."""
    loss, _, base, _, out_t = _one_step(batch, **kwargs)
    return loss, (base + term(out_t.logits)).item()


def test_im_weight_adds_the_target_information_maximisation():
    """``im_weight`` adds w·L_IM of the target logits to the loss, and training with it makes the target
    predictions more confident than no-DA's after the same steps while they keep using several classes."""
    from vtlearn.losses import information_maximization

    batch = next(iter(TinyCrossModalDM().train_dataloader()))[0]
    loss, expected = _step_with_target_term(batch, lambda z: 2.5 * information_maximization(z)[0],
                                            im_weight=2.5)
    assert loss == pytest.approx(expected, rel=1e-5)

    entropy = {}
    for weight in (0.0, 10.0):
        _, out_t = _trained_joint_outputs(batch, da_method="none", im_weight=weight)
        entropy[weight] = information_maximization(out_t.logits)[1]
    assert entropy[10.0]["cond_entropy"] < entropy[0.0]["cond_entropy"], entropy
    assert entropy[10.0]["marginal_entropy"] > 0.5, entropy  # not collapsed onto one of the 3 classes
    with pytest.raises(ValueError, match="im_weight"):
        XAVTNet(**TINY, im_weight=-1.0)


def test_mcc_weight_adds_the_target_class_confusion():
    """``mcc_weight`` adds w·L_MCC of the target logits to the loss, and training with it leaves the target
    predictions less confused than no-DA's after the same steps."""
    from vtlearn.losses import minimum_class_confusion

    batch = next(iter(TinyCrossModalDM().train_dataloader()))[0]
    loss, expected = _step_with_target_term(batch, lambda z: 2.5 * minimum_class_confusion(z, 1.5)[0],
                                            mcc_weight=2.5, mcc_temperature=1.5)
    assert loss == pytest.approx(expected, rel=1e-5)

    confusion = {}
    for weight in (0.0, 10.0):
        _, out_t = _trained_joint_outputs(batch, da_method="none", mcc_weight=weight)
        confusion[weight] = minimum_class_confusion(out_t.logits)[0].item()
    assert confusion[10.0] < confusion[0.0], confusion
    for bad in (dict(mcc_weight=-1.0), dict(mcc_temperature=0.0)):
        with pytest.raises(ValueError, match=next(iter(bad))):
            XAVTNet(**TINY, **bad)


def test_mcd_weight_adds_the_second_classifier_and_the_reversed_discrepancy():
    """``mcd_weight``: the step's loss is no-DA's plus α·CE of the second classifier on the source fc2 and
    −w·d(fc3, F₂) on the target fc2; the discrepancy's gradient raises d in both classifiers and, through the
    reversal, lowers it in the fc2 feature; the predictions stay fc3's; without the weight there is no F₂."""
    from vtlearn.losses import classifier_discrepancy

    batch = next(iter(TinyCrossModalDM().train_dataloader()))[0]
    assert XAVTNet(**TINY).mcd_head is None
    loss, model, base, out_s, out_t = _one_step(batch, mcd_weight=0.7)
    y = batch["source"]["label"]
    ce_2 = torch.nn.functional.cross_entropy(model.mcd_head(out_s.features["fc2"]), y)
    f_t = out_t.features["fc2"].detach().requires_grad_()
    d = classifier_discrepancy(model.head.fc3(f_t), model.mcd_head(f_t))
    assert loss == pytest.approx((base + model.hparams.alpha * ce_2 - 0.7 * d).item(), rel=1e-5)
    # the adversarial term's gradients: −w·∂d in the classifiers (they ascend d), +w·∂d in the feature
    from vtlearn.models.components.xavtnet_backbone import XAVTNetOutput

    f_s = out_s.features["fc2"].detach()
    outs = [XAVTNetOutput(o.logits.detach(), {"fc2": f}, None, None) for o, f in ((out_s, f_s), (out_t, f_t))]
    terms = model._mcd_loss(*outs, y)[0]
    weights = [model.head.fc3.weight, model.mcd_head.weight]
    got = torch.autograd.grad(terms, [f_t, *weights])
    plain = torch.autograd.grad(d, [f_t, *weights])
    ce_grad = torch.autograd.grad(model.hparams.alpha * torch.nn.functional.cross_entropy(
        model.mcd_head(f_s), y), model.mcd_head.weight)[0]
    assert d.item() > 0 and all(g.abs().sum() > 0 for g in plain)
    torch.testing.assert_close(got[0], 0.7 * plain[0])  # the feature descends d
    torch.testing.assert_close(got[1], -0.7 * plain[1])  # fc3 ascends it
    torch.testing.assert_close(got[2], ce_grad - 0.7 * plain[2])  # F₂ ascends it and fits the source
    with torch.no_grad():
        model.eval()
        out = model(batch["target"]["points"], batch["target"]["lengths"])
        assert torch.equal(out.logits, model.head.fc3(out.features["fc2"]))
    with pytest.raises(ValueError, match="mcd_weight"):
        XAVTNet(**TINY, mcd_weight=-1.0)


def test_afn_weight_adds_the_feature_norm_of_both_domains_and_lengthens_the_target_features():
    """``afn_weight``: the step's loss is no-DA's plus w·(L_SAFN(source fc2) + L_SAFN(target fc2)) = no-DA's +
    2·w·Δr², and training with it leaves the target fc2 features with larger norms than no-DA's after the
    same steps: by 22 % on average over seeds 0-3 (on 1 and 2 threads alike), where one seed's ratio runs
    from 1.04 to 1.42 (ten steps of a tiny model follow the float rounding of the thread count)."""
    from vtlearn.losses import adaptive_feature_norm

    batch = next(iter(TinyCrossModalDM().train_dataloader()))[0]
    loss, model, base, out_s, out_t = _one_step(batch, afn_weight=0.7, afn_step=0.5)
    terms = sum(adaptive_feature_norm(o.features["fc2"], 0.5)[0] for o in (out_s, out_t))
    assert loss == pytest.approx((base + 0.7 * terms).item(), rel=1e-5)
    assert terms.item() == pytest.approx(2 * 0.5**2)
    ratios = []
    for seed in range(4):
        norms = [_trained_joint_outputs(batch, seed=seed, da_method="none", afn_weight=weight)[1]
                 .features["fc2"].norm(dim=1).mean().item() for weight in (0.0, 10.0)]
        ratios.append(norms[1] / norms[0])
    assert sum(ratios) / 4 > 1.1, ratios
    for bad in (dict(afn_weight=-1.0), dict(afn_step=0.0)):
        with pytest.raises(ValueError, match=next(iter(bad))):
            XAVTNet(**TINY, **bad)


def test_l2_preserved_dropout_keeps_the_squared_norm_and_is_what_fc3_and_the_feature_norm_read(monkeypatch):
    """Xu et al.'s L2-preserved dropout: while the dropout is on, fc3 reads m ⊙ fc2 / √(1 − p), whose mean
    squared norm over masks is fc2's (plain dropout's is 1/(1 − p) times it, 1.67 at p = 0.4); with it off the
    head is the plain one; a training step's adaptive feature norm reads the dropped feature."""
    import vtlearn.models.xavtnet as xavtnet_module
    from vtlearn.models.components.xavtnet_backbone import XAVTNetHead

    torch.manual_seed(0)
    p = 0.4
    plain = XAVTNetHead(16, 3, (12, 10), p).eval()
    l2 = XAVTNetHead(16, 3, (12, 10), p, l2_preserved_dropout=True).eval()
    l2.load_state_dict(plain.state_dict())
    g = torch.randn(5, 16)
    (logits_p, feats_p), (logits_l2, feats) = plain(g), l2(g)
    assert torch.equal(logits_p, logits_l2) and torch.equal(feats["fc2_dropout"], feats["fc2"])
    assert set(feats_p) == {"fc1", "fc2"}
    draws = g.repeat(2000, 1)  # 2000 masks of each cloud in one pass (batch norm in eval mode)
    squares = {}
    for name, head in (("plain", plain), ("l2", l2)):
        head.dropout.train()  # as MC-dropout runs it: batch norm in eval mode, dropout on
        logits, f = head(draws)
        fc2 = f["fc2"][:5]
        # what fc3 reads: the head's own output under l2, plain dropout's otherwise
        dropped = f["fc2_dropout"] if name == "l2" else head.dropout(f["fc2"])
        squares[name] = dropped.pow(2).sum(1).view(2000, 5).mean(0)
        if name == "l2":
            kept = dropped != 0
            torch.testing.assert_close(dropped[kept] * math.sqrt(1 - p), f["fc2"][kept])
            torch.testing.assert_close(logits, head.fc3(dropped))
    ref = fc2.pow(2).sum(1)
    assert torch.allclose(squares["l2"] / ref, torch.ones(5), rtol=0.05), squares["l2"] / ref
    assert torch.allclose(squares["plain"] / ref, torch.full((5,), 1 / (1 - p)), rtol=0.05)

    seen = []
    real = xavtnet_module.adaptive_feature_norm
    monkeypatch.setattr(xavtnet_module, "adaptive_feature_norm",
                        lambda f, step: seen.append(f.detach()) or real(f, step))
    batch = next(iter(TinyCrossModalDM().train_dataloader()))[0]
    _, model, _, out_s, out_t = _one_step(batch, afn_weight=0.7, dropout=p, l2_preserved_dropout=True)
    assert model.hparams.l2_preserved_dropout and len(seen) == 2
    for got, out in zip(seen, (out_s, out_t), strict=True):
        torch.testing.assert_close(got, out.features["fc2_dropout"])
        assert not torch.allclose(got, out.features["fc2"])
    with pytest.raises(ValueError, match="l2_preserved_dropout"):
        XAVTNet(**TINY, l2_preserved_dropout="yes")


def test_cdan_discriminates_fc2_conditioned_on_the_prediction():
    """CDAN+E's step: α·CE + w·L_dom with the discriminator on fc2 ⊗ softmax and entropy weights normalised
    per domain (``cdan_entropy=False``: every cloud alike); behind the gradient reversal the encoder's
    features get the negated gradient of the discriminator's own loss (times λ)."""
    from vtlearn.losses import domain_adversarial_loss, entropy_weights, multilinear_map
    from vtlearn.models.components.xavtnet_backbone import XAVTNetOutput

    batch = next(iter(TinyCrossModalDM().train_dataloader()))[0]
    for entropy in (True, False):
        loss, model, base, out_s, out_t = _one_step(batch, da_method="cdan", dann_weight=0.7,
                                                     cdan_entropy=entropy)  # progress 1: λ = ramp(1)
        assert model.discriminator.net[0].in_features == 8 * 3  # fc2 (8) ⊗ the 3 class probabilities
        terms = []
        for out, label in ((out_s, 1.0), (out_t, 0.0)):
            g = out.logits.softmax(-1)
            d = model.discriminator(multilinear_map(out.features["fc2"], g))
            bce = torch.nn.functional.binary_cross_entropy_with_logits(d, torch.full_like(d, label),
                                                                       reduction="none")
            w = entropy_weights(g) if entropy else torch.ones_like(d)
            terms.append((w * bce).sum() / w.sum())
        expected = base + 0.7 * 0.5 * (terms[0] + terms[1])
        assert loss == pytest.approx(expected.item(), rel=1e-5)
    # the reversal: d(adversarial loss)/d(fc2) = −λ · d(discriminator loss)/d(fc2)
    f_s = out_s.features["fc2"].detach().requires_grad_()
    f_t = out_t.features["fc2"].detach().requires_grad_()
    outs = [XAVTNetOutput(o.logits.detach(), {"fc2": f}, None, None) for o, f in ((out_s, f_s), (out_t, f_t))]
    (grad_rev,) = torch.autograd.grad(model._adversarial_loss(*outs, 0.4), f_s)
    plain = domain_adversarial_loss(*(model.discriminator(multilinear_map(f, o.logits.softmax(-1)))
                                      for o, f in zip(outs, (f_s, f_t), strict=True)))  # no entropy weights
    (grad_disc,) = torch.autograd.grad(plain, f_s)
    assert torch.allclose(grad_rev, -0.4 * grad_disc, atol=1e-7)


def test_da_memory_aligns_the_batch_followed_by_the_last_clouds():
    """With ``da_memory`` VTLoss sees each domain's current features followed by those of the previous
    batches (at most ``da_memory`` rows, without gradient); the alignment gradient of the current rows is
    scaled by (rows in all) / (rows now)."""
    loader = TinyCrossModalDM().train_dataloader()
    b1, b2 = (b[0] for b in list(iter(loader))[:2])
    torch.manual_seed(0)
    model = XAVTNet(**TINY, dropout=0.0, da_memory=6).train()
    model._log_train = lambda *a, **k: None  # no trainer attached: skip self.log
    seen = []
    forward = model.vtloss.forward
    model.vtloss.forward = lambda *a, **k: seen.append(a) or forward(*a, **k)
    model.training_step(b1, 0)
    loss2 = model.training_step(b2, 1)
    with torch.no_grad():  # train mode normalises by batch statistics: the same features again
        s1, t1 = model._joint_forward(b1["source"], b1["target"])
        s2, t2 = model._joint_forward(b2["source"], b2["target"])
    assert seen[0][2]["fc1"].shape[0] == 4  # first step: the batch alone
    for layer in ("fc1", "fc2"):  # second: the 4 current rows, then the previous 4
        assert torch.allclose(seen[1][2][layer], torch.cat([s2.features[layer], s1.features[layer]]),
                              atol=1e-5)
        assert torch.allclose(seen[1][3][layer], torch.cat([t2.features[layer], t1.features[layer]]),
                              atol=1e-5)
    assert len(model._memory["source"]) == len(model._memory["target"]) == 6  # capacity: 2 of b1 dropped
    # The same value as VTLoss on those rows; only the current rows' gradient differs (scaled 8/4).
    expected, _ = model.vtloss(s2.logits, b2["source"]["label"], seen[1][2], seen[1][3])
    assert loss2.item() == pytest.approx((expected + model._regulariser(s2)).item(), rel=1e-5)
    leaf = {k: v.detach().requires_grad_() for k, v in s2.features.items()}
    ext_s, _ = model._with_memory(leaf, t2.features)  # 4 rows now, 6 queued: gradient x 10/4
    ext_s["fc1"].sum().backward()
    assert torch.allclose(leaf["fc1"].grad, torch.full_like(leaf["fc1"], 2.5))
    plain = XAVTNet(**TINY, da_memory=6, da_memory_rescale=False)
    plain._with_memory(s1.features, t1.features)
    leaf = {k: v.detach().requires_grad_() for k, v in s2.features.items()}
    ext_s, _ = plain._with_memory(leaf, t2.features)
    ext_s["fc1"].sum().backward()
    assert torch.allclose(leaf["fc1"].grad, torch.ones_like(leaf["fc1"]))  # unscaled
    assert XAVTNet(**TINY, da_method="none", da_memory=6)._memory is None  # no alignment terms, no queue
    with pytest.raises(ValueError, match="da_memory"):
        XAVTNet(**TINY, da_memory=-1)


def test_single_cloud_training_batch_is_skipped():
    model = XAVTNet(**TINY).train()
    batch = {"points": torch.randn(1, 5, 3), "lengths": torch.tensor([5]), "label": torch.tensor([0])}
    assert model.training_step(batch, 0) is None


def test_checkpoint_round_trip_weights_only(tmp_path):
    torch.manual_seed(0)
    model = XAVTNet(**TINY, da_method="dann", da_layers=["fc1"], max_points=30)
    trainer = L.Trainer(fast_dev_run=1, accelerator="cpu", logger=False, enable_progress_bar=False,
                        enable_model_summary=False, default_root_dir=tmp_path)
    trainer.fit(model, datamodule=TinyCrossModalDM())
    path = tmp_path / "xavtnet.ckpt"
    trainer.save_checkpoint(path)
    ckpt = torch.load(path, weights_only=True, map_location="cpu")
    assert ckpt["hyper_parameters"]["da_method"] == "dann"
    restored = XAVTNet(**ckpt["hyper_parameters"])
    restored.load_state_dict(ckpt["state_dict"])
    model.eval()
    restored.eval()
    x = torch.randn(2, 12, 3)
    assert torch.equal(model(x).logits, restored(x).logits)
    again = XAVTNet.load_from_checkpoint(path, map_location="cpu", weights_only=True).eval()
    assert torch.equal(again(x).logits, model(x).logits)


def test_checkpoint_keeps_the_optimal_kernel_weights_running_means(tmp_path):
    # a resumed or reloaded run must weigh MK-MMD's kernels as the saved one did
    torch.manual_seed(0)
    model = XAVTNet(**TINY, mmd_kernel_weights="optimal", max_points=30)
    trainer = L.Trainer(fast_dev_run=2, accelerator="cpu", logger=False, enable_progress_bar=False,
                        enable_model_summary=False, default_root_dir=tmp_path)
    trainer.fit(model, datamodule=TinyCrossModalDM())
    assert model.vtloss.kernel_updates.tolist() == [2.0, 2.0] and model.vtloss.kernel_eta.abs().sum() > 0
    path = tmp_path / "xavtnet.ckpt"
    trainer.save_checkpoint(path)
    again = XAVTNet.load_from_checkpoint(path, map_location="cpu", weights_only=True)
    for name in ("kernel_eta", "kernel_q", "kernel_updates"):
        assert torch.equal(getattr(again.vtloss, name), getattr(model.vtloss, name)), name
    assert again.vtloss.kernel_eta.dtype == torch.float64


class _Indexed(Dataset):
    """Unlabelled clouds that carry their position, as CrossModalDataModule's target stream does."""

    def __init__(self, clouds):
        self.clouds = clouds

    def __len__(self):
        return len(self.clouds)

    def __getitem__(self, i):
        return self.clouds[i], i


def _indexed_collate(items):
    out = _collate([(p, 0) for p, _ in items], with_label=False)
    out["index"] = torch.tensor([i for _, i in items])
    return out


class IndexedCrossModalDM(TinyCrossModalDM):
    def train_dataloader(self):
        loaders = super().train_dataloader().iterables
        target = _Indexed([p for p, _ in _Clouds(8, 5, 12, 1, scale=2.0).items])
        loaders["target"] = DataLoader(target, batch_size=4, shuffle=True, collate_fn=_indexed_collate)
        return CombinedLoader(loaders, mode="max_size_cycle")


def test_pseudo_labels_add_a_target_cross_entropy_from_the_start_epoch(tmp_path):
    """From epoch ⌈start·max_epochs⌉ each epoch relabels the whole target stream by its centroids, and
    the loss gains w·CE of the target logits against the kept labels."""
    from vtlearn.losses.pseudo_labels import centroid_pseudo_labels

    seen = []

    class Record(L.Callback):
        def on_train_batch_start(self, trainer, pl_module, batch, batch_idx):
            labels = pl_module._pseudo_labels
            seen.append((trainer.current_epoch, None if labels is None else labels.clone()))

    torch.manual_seed(0)
    model = XAVTNet(**TINY, pseudo_label_weight=2.0, pseudo_label_start=0.5, pseudo_label_fraction=0.5)
    trainer = L.Trainer(max_epochs=2, accelerator="cpu", logger=False, enable_progress_bar=False,
                        enable_model_summary=False, enable_checkpointing=False, limit_val_batches=0,
                        default_root_dir=tmp_path, callbacks=[Record()])
    trainer.fit(model, datamodule=IndexedCrossModalDM())
    assert [e for e, lab in seen if lab is None] == [0, 0, 0]  # epoch 0 of 2 trains before the start
    labels = [lab for e, lab in seen if e == 1]
    assert len(labels) == 3 and labels[0].shape == (8,)
    assert 4 <= int((labels[0] >= 0).sum()) <= 6  # half of each pseudo-class, rounded up
    assert {"train/pseudo_ce", "train/pseudo_kept"} <= set(trainer.callback_metrics)

    # the labels are those of the centroid rule on the eval-mode features of the stream, in index order
    loader = DataLoader(_Indexed([p for p, _ in _Clouds(8, 5, 12, 1, scale=2.0).items]), batch_size=3,
                        collate_fn=_indexed_collate)
    batch = _indexed_collate([loader.dataset[i] for i in range(8)])
    out = model.extract_features(batch["points"], batch["lengths"])
    expected = centroid_pseudo_labels(out["fc1"], out["logits"].softmax(-1), 0.5)
    assert torch.equal(model.label_target(loader), expected)

    # the step's loss: VTLoss's plus 2·CE(target logits, kept labels)
    two = {"source": next(iter(TinyCrossModalDM().train_dataloader()))[0]["source"], "target": batch}
    model._pseudo_labels = expected
    model._log_train = lambda *a, **k: None
    model.train()
    torch.manual_seed(1)
    loss = model.training_step(two, 0)
    model._pseudo_labels = None
    torch.manual_seed(1)
    plain = model.training_step(two, 0)
    torch.manual_seed(1)
    _, out_t = model._joint_forward(two["source"], two["target"])
    target = expected[two["target"]["index"]]
    keep = target >= 0
    assert keep.any() and not keep.all()
    pce = torch.nn.functional.cross_entropy(out_t.logits[keep], target[keep]).item()
    assert pce > 0 and loss.item() == pytest.approx(plain.item() + 2.0 * pce, rel=1e-5)


def test_pseudo_labels_reject_bad_settings_and_streams(tmp_path):
    for kwargs, match in [(dict(pseudo_label_weight=-1.0), "pseudo_label_weight"),
                          (dict(pseudo_label_start=1.0), "pseudo_label_start"),
                          (dict(pseudo_label_fraction=0.0), "pseudo_label_fraction"),
                          (dict(pseudo_label_layer="fc3"), "pseudo_label_layer")]:
        with pytest.raises(ValueError, match=match):
            XAVTNet(**TINY, **kwargs)
    trainer_kwargs = dict(max_epochs=1, accelerator="cpu", logger=False, enable_progress_bar=False,
                          enable_model_summary=False, enable_checkpointing=False, limit_val_batches=0,
                          default_root_dir=tmp_path)
    single = DataLoader(_Clouds(8, 5, 20, 3), batch_size=4, collate_fn=_collate)
    with pytest.raises(ValueError, match="two-stream"):
        L.Trainer(**trainer_kwargs).fit(XAVTNet(**TINY, pseudo_label_weight=1.0, pseudo_label_start=0.0),
                                        train_dataloaders=single)
    with pytest.raises(ValueError, match="index"):  # TinyCrossModalDM's target items have no index
        L.Trainer(**trainer_kwargs).fit(XAVTNet(**TINY, pseudo_label_weight=1.0, pseudo_label_start=0.0),
                                        datamodule=TinyCrossModalDM())


def _grouped_collate(items):
    """Indexed target items, two clouds per object: the group is ``index // 2``."""
    out = _indexed_collate(items)
    out["group"] = out["index"] // 2
    return out


class GroupedCrossModalDM(TinyCrossModalDM):
    def train_dataloader(self):
        loaders = super().train_dataloader().iterables
        target = _Indexed([p for p, _ in _Clouds(8, 5, 12, 1, scale=2.0).items])
        loaders["target"] = DataLoader(target, batch_size=4, shuffle=True, collate_fn=_grouped_collate)
        return CombinedLoader(loaders, mode="max_size_cycle")


def test_pseudo_label_groups_vote_the_labels_over_each_object(tmp_path):
    """``pseudo_label_groups``: the target stream is labelled by the vote of each group's eval-mode
    softmax, so the two clouds of an object share their label, and training takes the kept labels; a
    stream without groups, or the switch without self-training, is refused by name."""
    from vtlearn.losses.pseudo_labels import group_vote_pseudo_labels

    torch.manual_seed(0)
    model = XAVTNet(**TINY, pseudo_label_weight=2.0, pseudo_label_start=0.5, pseudo_label_groups=True)
    trainer = L.Trainer(max_epochs=2, accelerator="cpu", logger=False, enable_progress_bar=False,
                        enable_model_summary=False, enable_checkpointing=False, limit_val_batches=0,
                        default_root_dir=tmp_path)
    trainer.fit(model, datamodule=GroupedCrossModalDM())
    assert {"train/pseudo_ce", "train/pseudo_kept"} <= set(trainer.callback_metrics)
    loader = DataLoader(_Indexed([p for p, _ in _Clouds(8, 5, 12, 1, scale=2.0).items]), batch_size=3,
                        collate_fn=_grouped_collate)
    batch = _grouped_collate([loader.dataset[i] for i in range(8)])
    model.eval()
    probs = model(batch["points"], batch["lengths"]).logits.softmax(-1)
    labels = model.label_target(loader)
    assert torch.equal(labels, group_vote_pseudo_labels(probs, batch["group"], 0.5))
    assert torch.equal(labels[0::2], labels[1::2])  # one label (or none) per object
    assert (labels >= 0).any()
    with pytest.raises(ValueError, match="group"):
        model.label_target(DataLoader(loader.dataset, batch_size=3, collate_fn=_indexed_collate))
    with pytest.raises(ValueError, match="pseudo_label_groups"):
        XAVTNet(**TINY, pseudo_label_groups=True)


def test_pseudo_labels_start_by_the_share_of_steps_without_max_epochs(tmp_path):
    """A run bounded by max_steps alone starts self-training after that share of its optimiser steps."""
    starts = []

    class Record(L.Callback):
        def on_train_batch_start(self, trainer, pl_module, batch, batch_idx):
            if batch_idx == 0:  # after the module's on_train_epoch_start
                starts.append((trainer.global_step, pl_module._pseudo_labels is not None))

    model = XAVTNet(**TINY, pseudo_label_weight=1.0, pseudo_label_start=0.5)
    trainer = L.Trainer(max_steps=12, max_epochs=-1, accelerator="cpu", logger=False,
                        enable_progress_bar=False, enable_model_summary=False, enable_checkpointing=False,
                        limit_val_batches=0, default_root_dir=tmp_path, callbacks=[Record()])
    trainer.fit(model, datamodule=IndexedCrossModalDM())
    assert starts == [(0, False), (3, False), (6, True), (9, True)]  # 3 steps per epoch


def test_mean_teacher_averages_the_trained_weights_and_is_not_optimised(tmp_path):
    """The teacher starts at the network's weights and follows θ' ← d·θ' + (1 − d)·θ after every optimiser
    step; the optimiser never holds its parameters, and checkpoints keep it (weights_only)."""
    student_after = []

    class Record(L.Callback):  # callbacks run before the module's on_train_batch_end
        def on_train_batch_end(self, trainer, pl_module, outputs, batch, batch_idx):
            student_after.append({k: v.detach().clone() for k, v in pl_module.encoder.state_dict().items()})

    torch.manual_seed(0)
    model = XAVTNet(**TINY, consistency_weight=2.0, ema_decay=0.5)
    model.encoder.load_state_dict(XAVTNet(**TINY).encoder.state_dict())  # weights changed after __init__
    start = {k: v.clone() for k, v in model.encoder.state_dict().items()}
    trainer = L.Trainer(max_steps=3, accelerator="cpu", logger=False, enable_progress_bar=False,
                        enable_model_summary=False, limit_val_batches=0, default_root_dir=tmp_path,
                        callbacks=[Record()])
    trainer.fit(model, datamodule=TinyCrossModalDM())
    held = {id(p) for group in trainer.optimizers[0].param_groups for p in group["params"]}
    assert not held & {id(p) for p in model.teacher.parameters()}
    assert {id(p) for p in model.encoder.parameters()} <= held
    assert len(student_after) == 3
    for k, v in model.teacher["encoder"].state_dict().items():
        if not v.is_floating_point():
            continue
        expected = start[k]
        for step in student_after:
            expected = 0.5 * expected + 0.5 * step[k]
        assert torch.allclose(v, expected, atol=1e-6), k
    # the average lags the trained weights
    assert not torch.equal(next(model.teacher["encoder"].parameters()), next(model.encoder.parameters()))

    path = tmp_path / "mt.ckpt"
    trainer.save_checkpoint(path)
    again = XAVTNet.load_from_checkpoint(path, map_location="cpu", weights_only=True)
    for (k, v), (_, w) in zip(again.teacher.state_dict().items(), model.teacher.state_dict().items(),
                              strict=True):
        assert torch.equal(v, w), k
    assert XAVTNet(**TINY).teacher is None  # no teacher, no extra weights, without the consistency term


def _step_with_a_nudged_teacher(model, batch):
    """One training step of ``model`` (no trainer attached, so logging is skipped) after its teacher has been
    moved away from the network, with torch's random state seeded 1 just before the step."""
    model._log_train = lambda *a, **k: None
    with torch.no_grad():  # a teacher that differs from the network
        for p in model.teacher.parameters():
            p.add_(0.1 * torch.randn_like(p))
    torch.manual_seed(1)
    return model.training_step(batch, 0)


def test_mean_teacher_adds_the_ramped_consistency_of_two_perturbed_copies():
    """The step's loss is VTLoss on the perturbed target copy plus w·r(p)·L_cons between the network's
    logits of that copy and the teacher's logits of another one."""
    from vtlearn.losses.consistency import softmax_consistency

    batch = next(iter(TinyCrossModalDM().train_dataloader()))[0]
    torch.manual_seed(0)
    model = XAVTNet(**TINY, consistency_weight=3.0, consistency_rampup=0.0, consistency_keep=0.5,
                    consistency_jitter=0.05).train()
    loss = _step_with_a_nudged_teacher(model, batch)
    torch.manual_seed(1)  # the same draws, in the step's order
    teacher_logits = model._teacher_logits(batch["source"], batch["target"])
    target = model._perturb(batch["target"])
    out_s, out_t = model._joint_forward(batch["source"], target)
    vt = model.vtloss(out_s.logits, batch["source"]["label"], out_s.features, out_t.features)[0]
    cons = softmax_consistency(out_t.logits, teacher_logits)
    assert cons.item() > 1e-4
    assert target["lengths"].sum() < batch["target"]["lengths"].sum()  # points were dropped
    assert model.teacher.training is False  # the teacher's dropout was off, and it is left in eval mode
    expected = vt + 3.0 * cons + model._regulariser(out_s)
    assert loss.item() == pytest.approx(expected.item(), rel=1e-5)


def test_fixmatch_consistency_labels_a_weak_copy_and_trains_on_a_strong_one():
    """consistency_loss="cross_entropy" with student_*: the step adds w·L_hard between the network's
    logits of its strong copy (fewer points, its own jitter and stretch) and the teacher's argmax of a weak
    copy (consistency_keep, consistency_jitter); the other target terms see the strong copy."""
    from vtlearn.losses.consistency import confident_cross_entropy

    batch = next(iter(TinyCrossModalDM().train_dataloader()))[0]
    src, tgt = batch["source"], batch["target"]
    torch.manual_seed(0)
    model = XAVTNet(**TINY, consistency_weight=3.0, consistency_rampup=0.0, consistency_keep=1.0,
                    consistency_jitter=0.0, consistency_loss="cross_entropy", student_keep=0.3,
                    student_jitter=0.05, student_scale=1.5).train()
    loss = _step_with_a_nudged_teacher(model, batch)
    torch.manual_seed(1)  # the same draws, in the step's order
    teacher_logits = model._teacher_logits(src, tgt)
    strong = model._perturb(tgt, student=True)
    out_s, out_t = model._joint_forward(src, strong)
    vt = model.vtloss(out_s.logits, src["label"], out_s.features, out_t.features)[0]
    hard = confident_cross_entropy(out_t.logits, teacher_logits.softmax(-1))
    assert hard.item() > 1e-3
    assert loss.item() == pytest.approx((vt + 3.0 * hard + model._regulariser(out_s)).item(), rel=1e-5)
    assert strong["lengths"].sum() < tgt["lengths"].sum()
    # the weak copy keeps every point unmoved; the strong copy stretches each axis within [2/3, 3/2]
    weak = model._perturb(tgt)
    assert torch.equal(weak["lengths"], tgt["lengths"])
    stretch = XAVTNet(**TINY, consistency_weight=1.0, student_keep=1.0, student_jitter=0.0, student_scale=1.5)
    copy = stretch._perturb(tgt, student=True)

    def extent(p):
        return p.amax(0) - p.amin(0)

    for b, n in enumerate(tgt["lengths"].tolist()):
        assert torch.allclose(extent(weak["points"][b, :n]), extent(tgt["points"][b, :n]))
        ratio = extent(copy["points"][b, :n]) / extent(tgt["points"][b, :n])
        assert torch.all(ratio >= 1 / 1.5 - 1e-5) and torch.all(ratio <= 1.5 + 1e-5)
        assert not torch.allclose(ratio, torch.ones(3), atol=1e-3)


def test_distribution_alignment_targets_the_aligned_teacher_and_tracks_both_priors(tmp_path):
    """consistency_align: each step moves ρ_s towards the source batch's label frequencies and ρ_t towards
    the teacher's mean target probabilities (momentum ALIGN_MOMENTUM), and the consistency compares the
    network with the teacher's probabilities aligned by them; checkpoints keep both running means."""
    from vtlearn.losses.consistency import probability_consistency
    from vtlearn.models.components.class_balance import align_distribution
    from vtlearn.models.xavtnet import ALIGN_MOMENTUM

    batch = next(iter(TinyCrossModalDM().train_dataloader()))[0]
    torch.manual_seed(0)
    model = XAVTNet(**TINY, consistency_weight=3.0, consistency_rampup=0.0, consistency_align=True).train()
    assert torch.equal(model.align_source_prior, torch.full((3,), 1 / 3))
    loss = _step_with_a_nudged_teacher(model, batch)
    torch.manual_seed(1)  # the same draws, in the step's order
    teacher_probs = model._teacher_logits(batch["source"], batch["target"]).softmax(-1)
    target = model._perturb(batch["target"])
    out_s, out_t = model._joint_forward(batch["source"], target)
    y = batch["source"]["label"]
    m = ALIGN_MOMENTUM
    rho_s = m / 3 + (1 - m) * torch.bincount(y, minlength=3).float() / len(y)
    rho_t = m / 3 + (1 - m) * teacher_probs.mean(0)
    assert torch.allclose(model.align_source_prior, rho_s, atol=1e-6)
    assert torch.allclose(model.align_target_mean, rho_t, atol=1e-6)
    cons = probability_consistency(out_t.logits, align_distribution(teacher_probs, rho_s, rho_t))
    vt = model.vtloss(out_s.logits, y, out_s.features, out_t.features)[0]
    assert loss.item() == pytest.approx((vt + 3.0 * cons + model._regulariser(out_s)).item(), rel=1e-5)

    trainer = L.Trainer(max_steps=2, accelerator="cpu", logger=False, enable_progress_bar=False,
                        enable_model_summary=False, limit_val_batches=0, default_root_dir=tmp_path)
    trainer.fit(model, datamodule=TinyCrossModalDM())
    path = tmp_path / "align.ckpt"
    trainer.save_checkpoint(path)
    again = XAVTNet.load_from_checkpoint(path, map_location="cpu", weights_only=True)
    assert torch.equal(again.align_target_mean, model.align_target_mean)
    assert not hasattr(XAVTNet(**TINY, consistency_weight=1.0), "align_target_mean")


def teacher_against(model, src, tgt, forward):
    """The teacher's logits of a perturbed copy of ``tgt`` (training mode), and ``forward(copy)`` of the
    same copy without gradient: the two draws start from one seed. The teacher's running statistics must
    come out as they went in."""
    torch.manual_seed(3)
    with running_statistics_kept(model.teacher):
        teacher = model.train()._teacher_logits(src, tgt)
    torch.manual_seed(3)
    copy = model._perturb(tgt)
    with torch.no_grad():
        return teacher, forward(copy)


def test_mean_teacher_normalises_as_the_network_trains_and_keeps_its_running_statistics():
    """teacher_norm="batch": a teacher equal to the network gives the target logits of the network's
    training forward on the joint batch (dropout off), depends on the source batch, and leaves its running
    statistics alone; "running" is the eval-mode network on the target copy alone."""
    batch = next(iter(TinyCrossModalDM().train_dataloader()))[0]
    src, tgt = batch["source"], batch["target"]
    model = XAVTNet(**TINY, consistency_weight=1.0, dropout=0.0)
    model._update_teacher(0.0)  # the teacher equals the network
    teacher, expected = teacher_against(model, src, tgt, lambda c: model._joint_forward(src, c)[1].logits)
    assert torch.allclose(teacher, expected, atol=1e-5)
    other = {**src, "points": src["points"] + 0.5}  # other source clouds, other batch statistics
    torch.manual_seed(3)
    assert not torch.allclose(model._teacher_logits(other, tgt), teacher, atol=1e-3)

    model = XAVTNet(**TINY, consistency_weight=1.0, teacher_norm="running")
    model._update_teacher(0.0)
    teacher, expected = teacher_against(model, src, tgt,
                                        lambda c: model.eval()(c["points"], c["lengths"]).logits)
    assert torch.allclose(teacher, expected, atol=1e-5)



def _bn_batch_means(model, batches):
    """Each batch norm's per-channel input mean for each joint batch, from forward hooks."""
    bns = [m for m in (*model.encoder.modules(), *model.head.modules())
           if isinstance(m, torch.nn.modules.batchnorm._BatchNorm)]
    seen = {i: [] for i in range(len(bns))}
    hooks = [m.register_forward_hook(lambda mod, inp, out, i=i: seen[i].append(
        inp[0].transpose(0, 1).reshape(inp[0].shape[1], -1).mean(1).detach())) for i, m in enumerate(bns)]
    with torch.no_grad():
        for points, lengths in batches:
            model.train()(points, lengths)
    for h in hooks:
        h.remove()
    return bns, seen


def test_reestimated_bn_statistics_average_the_joint_batches():
    """The running means become the exact mean of the batch means over the loader's joint source + target
    batches, with no weight changed and the model's mode kept; one-stream loaders are refused with a
    ValueError (domain_bn models: tests/test_domain_bn.py)."""
    from vtlearn.models.xavtnet import _concat_streams

    torch.manual_seed(0)
    model = XAVTNet(**TINY, consistency_weight=1.0)
    loader = TinyCrossModalDM().train_dataloader()
    joint = [_concat_streams(b["source"], b["target"])[:2] for b, _, _ in loader]
    assert len(joint) == 3 and joint[0][0].shape[0] == 8  # 4 source + 4 target clouds per batch
    weights = {k: v.clone() for k, v in model.state_dict().items() if "running" not in k and "num_" not in k}
    reference = XAVTNet(**TINY, consistency_weight=1.0)
    reference.load_state_dict(model.state_dict())
    bns, means = _bn_batch_means(reference, joint)
    model.eval()
    assert model.reestimate_bn_statistics(loader) == 24
    assert not model.training
    model_bns = [m for m in (*model.encoder.modules(), *model.head.modules())
                 if isinstance(m, torch.nn.modules.batchnorm._BatchNorm)]
    assert len(model_bns) == len(bns) >= 5
    for i, m in enumerate(model_bns):
        assert torch.allclose(m.running_mean, torch.stack(means[i]).mean(0), atol=1e-5), i
        assert m.momentum == 0.1  # restored
    for k, v in model.state_dict().items():
        if k in weights:
            assert torch.equal(v, weights[k]), k
    # two passes average the same batches twice: the same statistics
    before = model_bns[-1].running_mean.clone()
    assert model.reestimate_bn_statistics(loader, passes=2) == 48
    assert torch.allclose(model_bns[-1].running_mean, before, atol=1e-5)

    one_stream = DataLoader(_Clouds(6, 5, 12, 2), batch_size=3, collate_fn=_collate)
    with pytest.raises(ValueError, match="two-stream"):
        model.reestimate_bn_statistics(one_stream)
    with pytest.raises(ValueError, match="passes"):
        model.reestimate_bn_statistics(loader, passes=0)


def test_adopt_teacher_puts_the_averaged_weights_in_the_network(tmp_path):
    """After a training, adopt_teacher gives the network the teacher's weights (the teacher keeps them) and
    the batch-norm statistics those weights have on the joint batches; without a teacher it is a
    ValueError."""
    torch.manual_seed(0)
    model = XAVTNet(**TINY, consistency_weight=2.0, ema_decay=0.5)
    trainer = L.Trainer(max_steps=3, accelerator="cpu", logger=False, enable_progress_bar=False,
                        enable_model_summary=False, limit_val_batches=0, default_root_dir=tmp_path)
    trainer.fit(model, datamodule=TinyCrossModalDM())
    teacher = {k: v.clone() for k, v in model.teacher.state_dict().items()}
    # the average lags the network
    assert not torch.equal(next(model.teacher["encoder"].parameters()), next(model.encoder.parameters()))
    reference = XAVTNet(**TINY, consistency_weight=2.0)
    reference.encoder.load_state_dict(model.teacher["encoder"].state_dict())
    reference.head.load_state_dict(model.teacher["head"].state_dict())
    reference.reestimate_bn_statistics(TinyCrossModalDM().train_dataloader())
    assert model.adopt_teacher(TinyCrossModalDM().train_dataloader()) == 24
    for part in ("encoder", "head"):
        for (k, v), (_, w) in zip(getattr(model, part).state_dict().items(),
                                  getattr(reference, part).state_dict().items(), strict=True):
            assert torch.allclose(v, w, atol=1e-6), (part, k)
    for k, v in model.teacher.state_dict().items():
        assert torch.equal(v, teacher[k]), k
    with pytest.raises(ValueError, match="no teacher"):
        XAVTNet(**TINY).adopt_teacher(TinyCrossModalDM().train_dataloader())



def test_quarter_turns_about_x_are_exact_rotations():
    """One turn takes +y to +z and +z to −y, four turns are the identity, two flip y and z; padding stays
    zero, and bad turns or shapes are refused by name."""
    from vtlearn.models.components.rotation_task import random_quarter_turns, turn_about_x

    pts = torch.tensor([[[1.0, 2.0, 3.0], [0.0, 1.0, 0.0], [0.0, 0.0, 0.0]]]).repeat(5, 1, 1)
    out = turn_about_x(pts, torch.tensor([0, 1, 2, 3, 0]))
    assert torch.equal(out[0], pts[0]) and torch.equal(out[4], pts[4])
    assert torch.allclose(out[1, 0], torch.tensor([1.0, -3.0, 2.0]))
    assert torch.allclose(out[1, 1], torch.tensor([0.0, 0.0, 1.0]))
    assert torch.allclose(out[2, 0], torch.tensor([1.0, -2.0, -3.0]))
    assert torch.allclose(out[3, 0], torch.tensor([1.0, 3.0, -2.0]))
    assert torch.equal(out[:, 2], torch.zeros(5, 3))
    x = torch.randn(4, 7, 3)
    again = x
    for _ in range(4):
        again = turn_about_x(again, torch.ones(4, dtype=torch.long))
    assert torch.allclose(again, x, atol=1e-6)
    turned, turns = random_quarter_turns(x, torch.Generator().manual_seed(0))
    assert torch.allclose(turned, turn_about_x(x, turns)) and turns.dtype == torch.long
    assert torch.allclose(turned.norm(dim=-1), x.norm(dim=-1), atol=1e-6)
    with pytest.raises(ValueError, match="turns"):
        turn_about_x(x, torch.tensor([0, 1, 4, 0]))
    with pytest.raises(ValueError, match="turns"):
        turn_about_x(x, torch.zeros(3, dtype=torch.long))
    with pytest.raises(ValueError, match="points"):
        turn_about_x(torch.randn(4, 7), torch.zeros(4, dtype=torch.long))


def test_rotation_task_trains_the_encoder_on_both_domains_and_keeps_running_statistics(tmp_path):
    """rotation_weight > 0: the rotation head's cross-entropy on the turned source and target clouds
    reaches the encoder, its forward leaves the running statistics alone, and the step logs it; without
    the weight there is no head. A bad weight, or one with domain_bn, is refused."""
    batch = next(iter(TinyCrossModalDM().train_dataloader()))[0]
    model = XAVTNet(**TINY, rotation_weight=10.0).train()
    assert XAVTNet(**TINY).rotation_head is None
    with running_statistics_kept(model.encoder):
        rot, acc = model._rotation_loss(batch["source"], batch["target"])
    assert torch.isfinite(rot) and 0 <= float(acc) <= 1
    rot.backward()
    assert model.rotation_head.net[0].weight.grad.abs().sum() > 0
    assert any(p.grad is not None and p.grad.abs().sum() > 0 for p in model.encoder.parameters())
    # the head learns the turns of upright sticks (a turn about x shows: the stick then lies along ∓y or
    # hangs down), in both domains; the toy blobs above sit on the x axis, where turns about x cannot show
    class Sticks(Dataset):
        def __init__(self, n, n_points, seed):
            g = torch.Generator().manual_seed(seed)
            self.items = [(torch.cat([0.05 * torch.randn(n_points, 2, generator=g),
                                      torch.rand(n_points, 1, generator=g)], 1), i % 3) for i in range(n)]

        def __len__(self):
            return len(self.items)

        def __getitem__(self, i):
            return self.items[i]

    class SticksDM(L.LightningDataModule):
        def train_dataloader(self):
            src = DataLoader(Sticks(16, 30, 0), batch_size=8, collate_fn=_collate, drop_last=True)
            tgt = DataLoader(Sticks(16, 8, 1), batch_size=8,
                             collate_fn=lambda b: _collate(b, with_label=False))
            return CombinedLoader({"source": src, "target": tgt}, mode="max_size_cycle")

    torch.manual_seed(0)
    model = XAVTNet(**TINY, da_method="none", rotation_weight=10.0, lr=3e-3)
    trainer = L.Trainer(max_epochs=12, accelerator="cpu", logger=False, enable_progress_bar=False,
                        enable_model_summary=False, limit_val_batches=0, default_root_dir=tmp_path,
                        enable_checkpointing=False)
    trainer.fit(model, datamodule=SticksDM())
    assert trainer.callback_metrics["train/rotation_acc"] > 0.9  # chance: 0.25
    for kwargs, match in [(dict(rotation_weight=-1.0), "rotation_weight"),
                          (dict(rotation_weight=float("nan")), "rotation_weight"),
                          (dict(rotation_weight=1.0, domain_bn=True), "domain_bn")]:
        with pytest.raises(ValueError, match=match):
            XAVTNet(**TINY, **kwargs)


def test_mean_teacher_rejects_bad_settings():
    for kwargs, match in [(dict(consistency_weight=-1.0), "consistency_weight"),
                          (dict(consistency_weight=float("inf")), "consistency_weight"),
                          (dict(consistency_rampup=1.5), "consistency_rampup"),
                          (dict(ema_decay=1.0), "ema_decay"),
                          (dict(consistency_keep=0.0), "consistency_keep"),
                          (dict(consistency_jitter=-0.1), "consistency_jitter"),
                          (dict(consistency_threshold=1.0), "consistency_threshold"),
                          (dict(teacher_norm="eval"), "teacher_norm"),
                          (dict(consistency_align=True), "consistency_align"),
                          (dict(consistency_weight=1.0, consistency_loss="kl"), "consistency_loss"),
                          (dict(consistency_loss="cross_entropy"), "consistency_loss.*consistency_weight"),
                          (dict(consistency_weight=1.0, student_keep=0.0), "student_keep"),
                          (dict(consistency_weight=1.0, student_jitter=float("nan")), "student_jitter"),
                          (dict(consistency_weight=1.0, student_scale=0.5), "student_scale"),
                          (dict(student_jitter=0.1), "student_jitter.*consistency_weight"),
                          (dict(student_scale=1.5), "student_scale.*consistency_weight")]:
        with pytest.raises(ValueError, match=match):
            XAVTNet(**TINY, **kwargs)


@pytest.mark.parametrize("kwargs,match", [
    (dict(da_layers=[]), "da_layers: .*at least one layer"),
    (dict(da_layers=["fc1", "fc1"]), r"da_layers: \['fc1'\] named more than once"),
    (dict(use_mmd=False, use_coral=False), "use_mmd, use_coral: .*da_method='none'"),
    (dict(fc_dims=[0, 8]), "fc_dims"),
    (dict(fc_dims=[16, 2.5]), "fc_dims"),
    (dict(da_method="dann", dann_weight=-1.0), "dann_weight"),
    (dict(da_method="dann", dann_weight=0.0), "dann_weight"),
    (dict(da_method="dann", dann_gamma=0.0), "dann_gamma"),
    (dict(da_method="cdan", dann_weight=0.0), "dann_weight"),
    (dict(feature_transform_weight=-0.001), "feature_transform_weight"),
    (dict(feature_transform_weight=float("nan")), "feature_transform_weight"),
    (dict(mmd_num_kernels=0), "mmd_num_kernels"),
    (dict(mmd_kernel_mul=0.0), "mmd_kernel_mul"),
    (dict(weight_decay=-1e-4), "weight_decay"),
    (dict(mmd_kernel_weights="best"), "mmd_kernel_weights"),
    (dict(da_method="none", mmd_kernel_weights="Optimal"), "mmd_kernel_weights"),
    (dict(mmd_kernel_weights="optimal", mmd_conditional=True), "mmd_kernel_weights"),
])
def test_bad_loss_and_network_settings_are_refused_by_name(kwargs, match):
    # before: each was accepted, then failed inside the first training step or the optimiser (a kernel
    # count, a weight decay), trained silently as another row (no MMD and no CORAL is no-DA; a zero DANN
    # weight or ramp is no-DA too), or counted a layer's alignment twice
    with pytest.raises(ValueError, match=match):
        XAVTNet(**{**TINY, **kwargs})


def test_optimal_kernel_weights_are_ignored_by_the_rows_without_mk_mmd():
    # one config may set them for every row of the bench, as it sets the MMD kernel family
    for kwargs in (dict(da_method="none"), dict(use_mmd=False), dict(da_method="dann")):
        model = XAVTNet(**TINY, **kwargs, mmd_kernel_weights="optimal")
        assert not model.vtloss.optimal_kernels and "kernel_eta" not in model.vtloss.state_dict()
    assert XAVTNet(**TINY, mmd_kernel_weights="optimal").vtloss.optimal_kernels


def test_the_linear_time_estimator_is_ignored_by_the_rows_without_mk_mmd_and_refused_with_another():
    for kwargs in (dict(da_method="none"), dict(use_mmd=False), dict(da_method="dann")):
        assert not XAVTNet(**TINY, **kwargs, mmd_linear_time=True).vtloss.mmd_kwargs["linear_time"]
    assert XAVTNet(**TINY, mmd_linear_time=True).vtloss.mmd_kwargs["linear_time"]
    with pytest.raises(ValueError, match="mmd_linear_time"):
        XAVTNet(**TINY, mmd_linear_time=True, mmd_unbiased=True)


def test_ddcs_linear_kernel_is_ignored_by_the_rows_without_mmd_and_refused_with_optimal_weights():
    for kwargs in (dict(da_method="none"), dict(use_mmd=False), dict(da_method="dann")):
        assert not XAVTNet(**TINY, **kwargs, mmd_kernel="linear").vtloss.linear_kernel
    assert XAVTNet(**TINY, mmd_kernel="linear").vtloss.linear_kernel
    with pytest.raises(ValueError, match="mmd_kernel"):
        XAVTNet(**TINY, mmd_kernel="linear", mmd_kernel_weights="optimal")
    with pytest.raises(ValueError, match="mmd_kernel: expected one of"):
        XAVTNet(**TINY, mmd_kernel="Linear")


def test_da_layers_as_one_name_is_that_layer():
    # before: the string was read letter by letter ("got ['1', 'c', 'f']")
    model = XAVTNet(**TINY, da_layers="fc1")
    assert model.vtloss.layers == ("fc1",) and model.hparams.da_layers == ["fc1"]


@pytest.mark.parametrize("row,mmd,coral_,layers,dann", [
    ("noda", False, False, (), False),
    ("mmd", True, False, ("fc1", "fc2"), False),
    ("coral", False, True, ("fc1", "fc2"), False),
    ("vtloss_fc1", True, True, ("fc1",), False),
    ("vtloss_fc2", True, True, ("fc2",), False),
    ("vtloss", True, True, ("fc1", "fc2"), False),
    ("dann", False, False, (), True),
    ("cdan", False, False, (), True),
    ("mmd_g12", True, False, ("global", "fc1", "fc2"), False),
    ("mmd_g12_mt_vote", True, False, ("global", "fc1", "fc2"), False),
    ("vtloss_bal", True, True, ("fc1", "fc2"), False),
    ("coral_bal", False, True, ("fc1", "fc2"), False),
    ("vtloss_kopt", True, True, ("fc1", "fc2"), False),
    ("mmd_kopt", True, False, ("fc1", "fc2"), False),
    ("vtloss_lin", True, True, ("fc1", "fc2"), False),
    ("mmd_lin", True, False, ("fc1", "fc2"), False),
    ("vtloss_ddc", True, True, ("fc1", "fc2"), False),
    ("mmd_ddc", True, False, ("fc1", "fc2"), False),
])
def test_each_table_7_2_config_trains_the_terms_its_row_names(tmp_path, row, mmd, coral_, layers, dann):
    """configs/xavtnet_ablation/<row>.yaml over configs/quick/xavtnet.yaml (LightningCLI merges the second
    config's init_args into the first's): the model computes exactly the row's alignment terms."""
    import yaml

    root = Path(__file__).resolve().parents[1] / "configs"
    base = yaml.safe_load((root / "quick" / "xavtnet.yaml").read_text())["model"]["init_args"]
    over = yaml.safe_load((root / "xavtnet_ablation" / f"{row}.yaml").read_text())["model"]["init_args"]
    args = {**base, **over, "num_classes": 3, "global_dim": 32, "fc_dims": [16, 8], "max_points": 40}
    model = XAVTNet(**args)
    assert (model.vtloss.use_mmd, model.vtloss.use_coral) == (mmd, coral_)
    assert (model.discriminator is not None) == dann
    if mmd or coral_:
        assert model.vtloss.layers == layers
    torch.manual_seed(0)
    trainer = L.Trainer(fast_dev_run=1, accelerator="cpu", logger=False, enable_checkpointing=False,
                        enable_progress_bar=False, enable_model_summary=False, default_root_dir=tmp_path)
    trainer.fit(model, datamodule=TinyCrossModalDM())
    logged = {k.removeprefix("train/") for k in trainer.logged_metrics if k.startswith("train/")}
    terms = {k for k in logged if k.startswith(("mmd_", "coral_"))}
    assert terms == {f"{t}_{layer}" for t, on in (("mmd", mmd), ("coral", coral_)) if on for layer in layers}
    assert ("domain" in logged) == dann
    # the balance-rule rows set λ each step (Deep CORAL's rule, online) and log it
    assert (model.vtloss.lam_balance is not None) == row.endswith("_bal") == ("lam" in logged)
    # Gretton's optimal kernel weights: logged per layer and kernel, and the running means were updated
    betas = {k for k in logged if k.startswith("kernel_beta_")}
    assert model.vtloss.optimal_kernels == row.endswith("_kopt") == bool(betas)
    if betas:
        assert betas == {f"kernel_beta_{layer}_{u}" for layer in layers for u in range(5)}
        assert model.vtloss.kernel_updates.tolist() == [1.0] * len(layers)
    # DAN's linear-time MK-MMD estimator: on in exactly the rows that name it
    assert model.vtloss.mmd_kwargs["linear_time"] == row.endswith("_lin")
    # DDC's linear kernel: likewise
    assert model.vtloss.linear_kernel == row.endswith("_ddc")
