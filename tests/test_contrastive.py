"""Tests for SimCLR's NT-Xent (vtlearn.losses.contrastive) and the xAVTNet contrastive task."""

import math

import lightning as L
import pytest
import torch
from lightning.pytorch.utilities import CombinedLoader
from test_xavtnet import TINY, TinyCrossModalDM, _Clouds, _collate, running_statistics_kept
from torch.utils.data import DataLoader

from vtlearn.losses.contrastive import nt_xent
from vtlearn.models.xavtnet import XAVTNet


def _naive_nt_xent(z1, z2, tau):
    """Chen et al.'s eq. 1, one anchor at a time."""
    z = torch.nn.functional.normalize(torch.cat([z1, z2]), dim=1).tolist()
    n, total = len(z1), 0.0
    for i in range(2 * n):
        j = (i + n) % (2 * n)
        s = [sum(a * b for a, b in zip(z[i], z[m], strict=True)) / tau for m in range(2 * n)]
        total -= s[j] - math.log(sum(math.exp(s[m]) for m in range(2 * n) if m != i))
    return total / (2 * n)


def test_nt_xent_matches_a_naive_loop_and_its_bounds():
    g = torch.Generator().manual_seed(0)
    z1, z2 = torch.randn(5, 4, generator=g), torch.randn(5, 4, generator=g)
    for tau in (0.1, 0.5, 1.0):
        assert nt_xent(z1, z2, tau).item() == pytest.approx(_naive_nt_xent(z1, z2, tau), rel=1e-5)
    same = torch.ones(6, 3)
    assert nt_xent(same, same).item() == pytest.approx(math.log(11), rel=1e-6)  # every pair alike
    # orthogonal clouds, each copy equal to its partner: the loss falls towards 0 as τ does
    eye = torch.eye(4)
    assert nt_xent(eye, eye, 0.05).item() < 1e-6 < nt_xent(eye, eye, 0.5).item() < math.log(7)
    # scale does not matter (the projections are normalised); swapping the views does not either
    assert nt_xent(3 * z1, z2).item() == pytest.approx(nt_xent(z1, z2).item(), rel=1e-6)
    assert nt_xent(z2, z1).item() == pytest.approx(nt_xent(z1, z2).item(), rel=1e-6)


def test_nt_xent_rejects_bad_input():
    for args, match in [((torch.randn(4, 3), torch.randn(4, 2)), "z1, z2"),
                        ((torch.randn(4), torch.randn(4)), "z1, z2"),
                        ((torch.randn(1, 3), torch.randn(1, 3)), "n >= 2"),
                        ((torch.randn(4, 3), torch.randn(4, 3), 0.0), "temperature"),
                        ((torch.randn(4, 3), torch.randn(4, 3), float("nan")), "temperature")]:
        with pytest.raises(ValueError, match=match):
            nt_xent(*args)


def test_contrast_task_trains_encoder_and_head_on_target_and_keeps_running_statistics():
    """contrast_weight > 0: the NT-Xent of two copies of the target batch reaches the projection head and
    the encoder, and its forward leaves the running statistics alone; without the weight there is no head.
    Bad settings are refused."""
    batch = next(iter(TinyCrossModalDM().train_dataloader()))[0]
    assert XAVTNet(**TINY).projection_head is None
    model = XAVTNet(**TINY, contrast_weight=10.0).train()
    with running_statistics_kept(model.encoder):
        con = model._contrast_loss(batch["target"])
    n = batch["target"]["points"].shape[0]
    assert torch.isfinite(con) and 0 < con.item() < math.log(2 * n - 1) + 1
    con.backward()
    assert model.projection_head.net[0].weight.grad.abs().sum() > 0
    assert any(p.grad is not None and p.grad.abs().sum() > 0 for p in model.encoder.parameters())
    for kwargs, match in [(dict(contrast_weight=-1.0), "contrast_weight"),
                          (dict(contrast_weight=float("inf")), "contrast_weight"),
                          (dict(contrast_temperature=0.0), "contrast_temperature"),
                          (dict(contrast_weight=1.0, domain_bn=True), "domain_bn")]:
        with pytest.raises(ValueError, match=match):
            XAVTNet(**TINY, **kwargs)


def test_contrast_task_learns_to_pair_copies_of_target_clouds(tmp_path):
    """Trained with the contrastive task alone on the target stream (no-DA otherwise), the loss falls well
    below its value at every-pair-alike, log(2n − 1): the encoder learns to tell the tactile clouds apart."""

    class DM(L.LightningDataModule):
        def train_dataloader(self):
            src = DataLoader(_Clouds(16, 20, 30, 0), batch_size=8, collate_fn=_collate, drop_last=True)
            tgt = DataLoader(_Clouds(16, 6, 12, 1, scale=3.0), batch_size=8, drop_last=True,
                             collate_fn=lambda b: _collate(b, with_label=False))
            return CombinedLoader({"source": src, "target": tgt}, mode="max_size_cycle")

    torch.manual_seed(0)
    model = XAVTNet(**TINY, da_method="none", contrast_weight=10.0, consistency_keep=0.8, lr=3e-3)
    trainer = L.Trainer(max_epochs=15, accelerator="cpu", logger=False, enable_progress_bar=False,
                        enable_model_summary=False, limit_val_batches=0, default_root_dir=tmp_path,
                        enable_checkpointing=False)
    trainer.fit(model, datamodule=DM())
    assert trainer.callback_metrics["train/contrast"] < 0.6 * math.log(15)
