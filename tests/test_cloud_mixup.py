"""Cross-domain mixup of point clouds (models/components/cloud_mixup.py) and XAVTNet's mix_weight."""

import os

import pytest
import torch
import torch.nn.functional as F
from test_xavtnet import running_statistics_kept

from vtlearn.models.components.cloud_mixup import mix_clouds, soft_cross_entropy
from vtlearn.models.xavtnet import XAVTNet

os.environ.setdefault("WANDB_MODE", "disabled")
TINY = dict(num_classes=3, global_dim=32, fc_dims=[16, 8])


def _padded(clouds):
    n = max(len(c) for c in clouds)
    out = torch.zeros(len(clouds), n, 3)
    for i, c in enumerate(clouds):
        out[i, : len(c)] = c
    return out, torch.tensor([len(c) for c in clouds])


def _rows(points):
    return {tuple(p.tolist()) for p in points}


def test_mix_clouds_takes_the_share_of_points_from_each_cloud():
    """Cloud i of the mix has lengths_b[i] points, round(lam·m) of them distinct points of a[i] and the rest
    distinct points of b[i]; the padding is zero, and the returned share is the count from a over m."""
    g = torch.Generator().manual_seed(0)
    a = [torch.randn(n, 3, generator=g) + 5.0 for n in (40, 40, 6, 30)]  # a's points sit far from b's
    b = [torch.randn(n, 3, generator=g) for n in (10, 7, 12, 1)]
    pa, la = _padded(a)
    pb, lb = _padded(b)
    lam = torch.tensor([0.3, 1.0, 1.0, 0.0])
    mixed, lengths, share = mix_clouds(pa, la, pb, lb, lam, generator=g)
    assert mixed.shape == pb.shape and torch.equal(lengths, lb)
    expected_k = [3, 7, 6, 0]  # round(0.3·10); all 7; only 6 points in a[2]; none
    for i, k in enumerate(expected_k):
        m = int(lb[i])
        rows = mixed[i, :m]
        from_a = rows[:, 0] > 2.5
        assert int(from_a.sum()) == k
        assert share[i].item() == pytest.approx(k / m)
        assert _rows(rows[from_a]) <= _rows(a[i]) and _rows(rows[~from_a]) <= _rows(b[i])
        assert len(_rows(rows)) == m  # no point is taken twice
        assert torch.all(mixed[i, m:] == 0)
    # lam = 0 gives b's own cloud, reordered
    same, _, share0 = mix_clouds(pa, la, pb, lb, torch.zeros(4), generator=g)
    for i in range(4):
        assert _rows(same[i, : int(lb[i])]) == _rows(b[i])
    assert torch.all(share0 == 0)


def test_mix_clouds_rejects_bad_input():
    pa, la = _padded([torch.randn(5, 3), torch.randn(4, 3)])
    pb, lb = _padded([torch.randn(3, 3), torch.randn(2, 3)])
    lam = torch.tensor([0.5, 0.5])
    for args, match in [
        ((pa[..., :2], la, pb, lb, lam), "points_a"),
        ((pa, la[:1], pb, lb, lam), "lengths of points_a"),
        ((pa, la, pb, torch.tensor([0, 2]), lam), "lengths of points_b"),
        ((pa, la, pb, torch.tensor([3, 9]), lam), "lengths of points_b"),
        ((pa[:1], la[:1], pb, lb, lam), "same number of clouds"),
        ((pa, la, pb, lb, torch.tensor([0.5, 1.5])), "lam"),
        ((pa, la, pb, lb, torch.tensor([0.5])), "lam"),
    ]:
        with pytest.raises(ValueError, match=match):
            mix_clouds(*args)


def test_soft_cross_entropy_is_the_cross_entropy_on_one_hot_labels_and_mixes_linearly():
    g = torch.Generator().manual_seed(1)
    logits = torch.randn(5, 4, generator=g)
    y = torch.tensor([0, 3, 1, 1, 2])
    onehot = F.one_hot(y, 4).float()
    assert soft_cross_entropy(logits, onehot).item() == pytest.approx(F.cross_entropy(logits, y).item())
    q = torch.softmax(torch.randn(5, 4, generator=g), -1)
    mixed = soft_cross_entropy(logits, 0.25 * onehot + 0.75 * q)
    expected = 0.25 * soft_cross_entropy(logits, onehot) + 0.75 * soft_cross_entropy(logits, q)
    assert mixed.item() == pytest.approx(expected.item(), rel=1e-6)
    with pytest.raises(ValueError, match="logits, target"):
        soft_cross_entropy(logits, q[:, :3])


def _two_stream_batch():
    g = torch.Generator().manual_seed(2)
    src = [torch.randn(20, 3, generator=g) * 0.1 + torch.tensor([float(i % 3), 0.0, 0.0]) for i in range(6)]
    tgt = [torch.randn(n, 3, generator=g) * 0.2 for n in (5, 9, 7, 6)]
    ps, ls = _padded(src)
    pt, lt = _padded(tgt)
    return {"source": {"points": ps, "lengths": ls, "label": torch.tensor([i % 3 for i in range(6)])},
            "target": {"points": pt, "lengths": lt}}


def test_mixup_loss_is_the_soft_cross_entropy_of_the_mixed_clouds_and_keeps_running_statistics():
    """_mixup_loss pairs target cloud i with a permuted source cloud, labels it by the share of points
    each gave, and normalises by the mixed batch's own statistics; its gradient reaches the encoder."""
    batch = _two_stream_batch()
    src, tgt = batch["source"], batch["target"]
    torch.manual_seed(0)
    model = XAVTNet(**TINY, dropout=0.0, mix_weight=10.0).train()
    probs_t = torch.softmax(torch.randn(4, 3), -1)
    torch.manual_seed(3)
    with running_statistics_kept(model) as running:
        loss = model._mixup_loss(src, tgt, probs_t)
    loss.backward()
    assert any(p.grad is not None and p.grad.abs().sum() > 0 for p in model.encoder.parameters())
    torch.manual_seed(3)  # the same draws, in the method's order
    pick = torch.randperm(6)[:4]
    lam = torch.distributions.Beta(1.0, 1.0).sample((4,))
    mixed, lengths, share = mix_clouds(src["points"][pick], src["lengths"][pick], tgt["points"],
                                       tgt["lengths"], lam)
    target = share[:, None] * F.one_hot(src["label"][pick], 3).float() + (1 - share[:, None]) * probs_t
    with torch.no_grad():  # a training forward normalises by the batch; its running update is undone
        logits = model(mixed, lengths).logits
        model.load_state_dict({**model.state_dict(), **running})
    assert loss.item() == pytest.approx(soft_cross_entropy(logits, target).item(), rel=1e-5)


def test_mix_weight_adds_the_ramped_mixup_to_the_step_and_rejects_bad_settings():
    batch = _two_stream_batch()
    logged = {}
    for kwargs in (dict(mix_weight=10.0, consistency_rampup=0.0),
                   dict(mix_weight=10.0, consistency_weight=1.0, consistency_rampup=0.0), {}):
        model = XAVTNet(**TINY, **kwargs).train()
        model._log_train = lambda loss, logits, y, parts: logged.update(parts)
        logged.clear()
        torch.manual_seed(0)
        assert torch.isfinite(model.training_step(batch, 0))
        if kwargs:
            assert logged["mixup"] > 0 and float(logged["mixup_w"]) == pytest.approx(10.0)
        else:
            assert "mixup" not in logged
    for kwargs, match in [(dict(mix_weight=-1.0), "mix_weight"),
                          (dict(mix_weight=float("nan")), "mix_weight"), (dict(mix_alpha=0.0), "mix_alpha"),
                          (dict(mix_alpha=float("inf")), "mix_alpha"),
                          (dict(mix_weight=1.0, domain_bn=True), "domain_bn")]:
        with pytest.raises(ValueError, match=match):
            XAVTNet(**TINY, **kwargs)


def test_random_valid_order_puts_a_permutation_of_the_valid_slots_first():
    """The shared ordering behind mix_clouds and perturb_padded: each row starts with a permutation of its
    valid slots and ends with its padding slots, and a seeded generator repeats it."""
    from vtlearn.models.components.pointnet_tnet import random_valid_order

    lengths = torch.tensor([1, 4, 6])
    order = random_valid_order(lengths, 6, torch.Generator().manual_seed(0))
    for row, n in zip(order, lengths.tolist(), strict=True):
        assert sorted(row[:n].tolist()) == list(range(n))
        assert sorted(row[n:].tolist()) == list(range(n, 6))
    assert torch.equal(order, random_valid_order(lengths, 6, torch.Generator().manual_seed(0)))
