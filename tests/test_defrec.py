"""DefRec's deformation reconstruction (models/components/deformation_task.py) and XAVTNet(defrec_weight)."""

import os

import lightning as L
import pytest
import torch
from test_xavtnet import TINY, TinyCrossModalDM, running_statistics_kept

from vtlearn.models.components.deformation_task import RegionDecoder, deform_region, region_chamfer
from vtlearn.models.components.xavtnet_backbone import PointNetEncoder
from vtlearn.models.xavtnet import XAVTNet

os.environ.setdefault("WANDB_MODE", "disabled")


def _cloud_with_one_full_voxel():
    """A cloud whose bounding box is [0, 3]³ (corners at both ends), with 6 points in the voxel (1, 2, 0)
    of the 3 × 3 × 3 grid and one point in each of 6 other voxels: only (1, 2, 0) holds the 2 points that
    a 12-point cloud needs (⌈12·40/1024⌉ = 1, at least 2). Padded to 15 rows with a far-off value."""
    pts = [[0.0, 0.0, 0.0], [3.0, 3.0, 3.0], [0.5, 0.5, 2.5], [2.5, 0.5, 0.5], [0.5, 1.5, 1.5],
           [2.5, 1.5, 2.5]]
    pts += [[1.2 + 0.1 * i, 2.3 + 0.1 * i, 0.2 + 0.1 * i] for i in range(6)]
    padded = torch.full((1, 15, 3), 9.0)
    padded[0, :12] = torch.tensor(pts)
    return padded, torch.tensor([12])


def test_deform_region_replaces_one_full_voxel_by_its_centre():
    """Noiseless (variance 0): the one voxel with enough points is picked, its points land on the voxel's
    centre, every other point and the padding stay as they were, and the scale is half the box's longest
    side. Moved and scaled, the cloud deforms the same way; the noise's spread is √variance · scale."""
    points, lengths = _cloud_with_one_full_voxel()
    out, region, scale = deform_region(points, lengths, variance=0.0)
    assert region[0].tolist() == [False] * 6 + [True] * 6 + [False] * 3
    assert torch.equal(out[0, 6:12], torch.tensor([[1.5, 2.5, 0.5]]).expand(6, 3))
    assert torch.equal(out[0, :6], points[0, :6]) and torch.equal(out[0, 12:], points[0, 12:])
    assert scale.tolist() == [1.5]
    moved, region2, scale2 = deform_region(points * 0.02 + torch.tensor([1.0, -2.0, 0.5]), lengths,
                                           variance=0.0)
    assert torch.equal(region2, region)
    assert torch.allclose(moved[0, :12], out[0, :12] * 0.02 + torch.tensor([1.0, -2.0, 0.5]), atol=1e-6)
    assert scale2.item() == pytest.approx(0.03)
    g = torch.Generator().manual_seed(0)
    many = torch.rand(1, 4000, 3, generator=g) * 2.0  # scale 1, ~148 points per voxel
    noisy, region, scale = deform_region(many, torch.tensor([4000]), variance=0.01, generator=g)
    spread = noisy[0][region[0]].std(0)
    assert torch.allclose(spread, torch.full((3,), 0.1), rtol=0.25)


def test_deform_region_picks_at_random_among_full_voxels_and_falls_back_to_the_fullest():
    """Different draws pick different voxels, always one holding at least ⌈n·40/1024⌉ (≥ 2) points; a cloud
    whose voxels each hold one point deforms one of them; a one-point cloud deforms that point."""
    g = torch.Generator().manual_seed(1)
    points = torch.rand(64, 200, 3, generator=g)
    lengths = torch.full((64,), 200)
    _, region, _ = deform_region(points, lengths, generator=g)
    counts = region.sum(1)
    assert (counts >= 8).all()  # ⌈200·40/1024⌉ = 8
    first = region.float().argmax(1)
    assert len({tuple(points[i, first[i]].mul(3).floor().clamp(max=2).tolist()) for i in range(64)}) > 5
    spread = torch.tensor([[[0.0, 0.0, 0.0], [1.0, 1.0, 1.0], [0.5, 0.5, 0.5]], [[0.3, 0.4, 0.5]] * 3])
    _, region, scale = deform_region(spread, torch.tensor([3, 1]), generator=g)
    assert region.sum(1).tolist() == [1, 1] and scale[1].item() == 1.0


def test_deform_region_refuses_bad_input_by_name():
    with pytest.raises(ValueError, match="points"):
        deform_region(torch.zeros(2, 5), torch.tensor([5, 5]))
    with pytest.raises(ValueError, match="lengths"):
        deform_region(torch.zeros(2, 5, 3), torch.tensor([5]))
    with pytest.raises(ValueError, match="regions"):
        deform_region(torch.zeros(2, 5, 3), torch.tensor([5, 5]), regions=0)
    with pytest.raises(ValueError, match="variance"):
        deform_region(torch.zeros(2, 5, 3), torch.tensor([5, 5]), variance=-1.0)
    with pytest.raises(ValueError, match="min_share"):
        deform_region(torch.zeros(2, 5, 3), torch.tensor([5, 5]), min_share=1.5)


def test_region_chamfer_matches_a_hand_computation():
    """Cloud 0's region holds (0,0,0) and (1,0,0), decoded as (0,0,0) and (0,2,0): each way the mean
    squared nearest distance, (0 + 1)/2 from the targets and (0 + 4)/2 from the decoded points, in units
    of its scale 2, so (0.5 + 2)/4; cloud 1 is decoded exactly. Points outside the regions do not count,
    the loss is scale-free, and an empty region is left out (all empty: 0, with a gradient)."""
    target = torch.tensor([[[0.0, 0, 0], [1, 0, 0], [5, 5, 5]], [[1.0, 1, 1], [2, 2, 2], [7, 7, 7]]])
    pred = torch.tensor([[[0.0, 0, 0], [0, 2, 0], [0, 0, 0]], [[1.0, 1, 1], [2, 2, 2], [0, 0, 0]]])
    region = torch.tensor([[True, True, False], [True, True, False]])
    scale = torch.tensor([2.0, 1.0])
    assert region_chamfer(pred, target, region, scale).item() == pytest.approx((2.5 / 4 + 0.0) / 2)
    assert region_chamfer(pred * 10, target * 10, region, scale * 10).item() == pytest.approx(2.5 / 8)
    only_first = torch.tensor([[True, True, False], [False, False, False]])
    assert region_chamfer(pred, target, only_first, scale).item() == pytest.approx(2.5 / 4)
    p = pred.clone().requires_grad_(True)
    zero = region_chamfer(p, target, torch.zeros(2, 3, dtype=torch.bool), scale)
    zero.backward()
    assert zero.item() == 0.0 and torch.equal(p.grad, torch.zeros_like(p))
    with pytest.raises(ValueError, match="region"):
        region_chamfer(pred, target, region[:, :2], scale)


def test_point_features_pool_to_the_encoders_global_feature():
    """The per-point features are 64 + 128 wide with zero padding, and their pooled feature is the one the
    classifier reads (the same computation); the decoder answers on the region's points only."""
    torch.manual_seed(0)
    encoder = PointNetEncoder(32).eval()
    points, lengths = torch.randn(3, 20, 3), torch.tensor([20, 12, 5])
    per_point, g = encoder.point_features(points, lengths)
    assert per_point.shape == (3, 20, 192)
    assert torch.equal(g, encoder(points, lengths)[0])
    assert torch.equal(per_point[1, 12:], torch.zeros(8, 192)) and per_point[1, :12].abs().sum() > 0
    region = torch.zeros(3, 20, dtype=torch.bool)
    region[0, :4] = region[2, 1:3] = True
    decoder = RegionDecoder(192, 32).eval()
    out = decoder(per_point, g, region)
    assert out.shape == (3, 20, 3) and torch.equal(out[~region], torch.zeros(int((~region).sum()), 3))
    # the region's rows are the MLP of each point's features beside its own cloud's pooled feature
    full = decoder.net(torch.cat([per_point, g[:, None].expand(-1, 20, -1)], -1).reshape(60, -1))
    torch.testing.assert_close(out[region], full.reshape(3, 20, 3)[region])
    with pytest.raises(ValueError, match="pooled"):
        decoder(per_point, g[:2], region)
    with pytest.raises(ValueError, match="point_features"):
        decoder(per_point[..., :100], g, region)
    with pytest.raises(ValueError, match="region"):
        decoder(per_point, g, region.float())


def test_defrec_step_adds_its_weighted_loss_and_trains_the_encoder():
    """defrec_weight > 0: the step's loss is the same step's loss without the task plus the weight times
    the task's loss; the task's loss reaches the decoder and the encoder and leaves the running statistics
    alone; without the weight there is no decoder. A bad weight or grid, or one with domain_bn, is refused."""
    batch = next(iter(TinyCrossModalDM().train_dataloader()))[0]
    assert XAVTNet(**TINY).defrec_head is None
    torch.manual_seed(0)
    model = XAVTNet(**TINY, da_method="none", dropout=0.0, defrec_weight=2.0).train()
    model._log_train = lambda *a, **k: None
    with running_statistics_kept(model.encoder):
        rec = model._defrec_loss(batch["source"], batch["target"])
    assert rec.item() > 0
    rec.backward()
    assert model.defrec_head.net[0].weight.grad.abs().sum() > 0
    assert model.encoder.mlp1.net[0].weight.grad.abs().sum() > 0
    model.zero_grad()
    model._defrec_loss = lambda src, tgt: torch.tensor(0.75)
    torch.manual_seed(1)
    with_task = model.training_step(batch, 0).item()
    model.hparams.defrec_weight = 0.0
    torch.manual_seed(1)
    without = model.training_step(batch, 0).item()
    assert with_task == pytest.approx(without + 2.0 * 0.75, rel=1e-6)
    for kwargs, match in [(dict(defrec_weight=-1.0), "defrec_weight"),
                          (dict(defrec_weight=float("nan")), "defrec_weight"),
                          (dict(defrec_weight=1.0, defrec_regions=0), "defrec_regions"),
                          (dict(defrec_weight=1.0, domain_bn=True), "domain_bn")]:
        with pytest.raises(ValueError, match=match):
            XAVTNet(**TINY, **kwargs)


def test_defrec_decoder_learns_to_put_the_region_back(tmp_path):
    """Trained on the toy clouds with the task alone (α = 0), the region's Chamfer distance falls to under
    a tenth of the untrained model's, measured on the same deformations."""
    batch = next(iter(TinyCrossModalDM().train_dataloader()))[0]

    def task_loss(model):
        torch.manual_seed(5)
        with torch.no_grad():
            return model._defrec_loss(batch["source"], batch["target"]).item()

    torch.manual_seed(0)
    model = XAVTNet(**TINY, da_method="none", alpha=0.0, defrec_weight=1.0, lr=3e-3)
    before = task_loss(model.train())
    trainer = L.Trainer(max_epochs=40, accelerator="cpu", logger=False, enable_progress_bar=False,
                        enable_model_summary=False, limit_val_batches=0, default_root_dir=tmp_path,
                        enable_checkpointing=False)
    trainer.fit(model, datamodule=TinyCrossModalDM())
    assert task_loss(model.train()) < 0.1 * before  # 0.01-0.02 of it on three seeds
