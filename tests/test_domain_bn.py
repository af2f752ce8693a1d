"""Tests for batch norm with statistics per domain (AdaBN / DSBN) and its use in xAVTNet."""

import os

import lightning as L
import pytest
import torch
from torch import nn

from vtlearn.models.components.domain_bn import DomainBatchNorm, convert_batchnorm, set_bn_domain
from vtlearn.models.xavtnet import XAVTNet

os.environ.setdefault("WANDB_MODE", "disabled")
TINY = dict(num_classes=3, global_dim=32, fc_dims=[16, 8], dropout=0.0)


@pytest.mark.parametrize("shape", [(6, 4), (5, 4, 7)])
def test_domain_bn_matches_batchnorm_in_each_domain(shape):
    """Each domain alone behaves exactly like a BatchNorm1d (train and eval), and leaves the other alone."""
    torch.manual_seed(0)
    ref = nn.BatchNorm1d(4)
    with torch.no_grad():
        ref.weight.uniform_(0.5, 2.0)
        ref.bias.uniform_(-1.0, 1.0)
    dbn = DomainBatchNorm.from_batchnorm(ref)
    x_s, x_t = torch.randn(*shape), 3.0 + 0.5 * torch.randn(*shape)
    ref_t = nn.BatchNorm1d(4)
    ref_t.load_state_dict(ref.state_dict())
    for _ in range(3):
        dbn.domain = "source"
        assert torch.allclose(dbn(x_s), ref(x_s), atol=1e-6)
        dbn.domain = "target"
        assert torch.allclose(dbn(x_t), ref_t(x_t), atol=1e-6)
    assert torch.allclose(dbn.running_mean_source, ref.running_mean)
    assert torch.allclose(dbn.running_var_target, ref_t.running_var)
    assert not torch.allclose(dbn.running_mean_source, dbn.running_mean_target)
    dbn.eval(), ref.eval(), ref_t.eval()
    y = torch.randn(*shape)
    dbn.domain = "source"
    assert torch.allclose(dbn(y), ref(y), atol=1e-6)
    dbn.domain = "target"
    assert torch.allclose(dbn(y), ref_t(y), atol=1e-6)


def test_convert_and_set_domain_and_bad_input():
    net = nn.Sequential(nn.Linear(3, 4), nn.BatchNorm1d(4), nn.Sequential(nn.BatchNorm1d(4)))
    convert_batchnorm(net)
    assert not any(isinstance(m, nn.BatchNorm1d) for m in net.modules())
    assert set_bn_domain(net, "target") == 2
    assert all(m.domain == "target" for m in net.modules() if isinstance(m, DomainBatchNorm))
    with pytest.raises(ValueError, match="domain"):
        set_bn_domain(net, "visual")
    with pytest.raises(ValueError, match="x: need shape"):
        DomainBatchNorm(4)(torch.randn(2, 5))
    with pytest.raises(ValueError, match="num_features"):
        DomainBatchNorm(0)


def _two_stream(seed=0):
    g = torch.Generator().manual_seed(seed)
    src = {"points": torch.randn(6, 40, 3, generator=g), "lengths": torch.full((6,), 40),
           "label": torch.tensor([0, 1, 2, 0, 1, 2])}
    tgt = {"points": 0.3 * torch.randn(6, 12, 3, generator=g) + 1.0, "lengths": torch.full((6,), 12)}
    return {"source": src, "target": tgt}


def _bn_state(model):
    return {k: v.clone() for k, v in model.state_dict().items() if "running_" in k}


def test_adabn_target_stream_updates_only_target_statistics():
    """No-DA with domain_bn: the tactile batch moves the target statistics and contributes no gradient."""
    torch.manual_seed(0)
    model = XAVTNet(**TINY, da_method="none", domain_bn=True).train()
    model._log_train = lambda *a, **k: None
    batch = _two_stream()
    before = _bn_state(model)
    loss = model.training_step(batch, 0)
    after = _bn_state(model)
    moved = {k for k in before if not torch.equal(before[k], after[k])}
    assert any(k.endswith("_target") for k in moved) and any(k.endswith("_source") for k in moved)
    # the same loss as a forward of the source batch alone: the target stream adds nothing to it
    torch.manual_seed(0)
    plain = XAVTNet(**TINY, da_method="none", domain_bn=True).train()
    plain._log_train = lambda *a, **k: None
    with plain.bn_domain("source"):
        out = plain(batch["source"]["points"], batch["source"]["lengths"])
    ce = torch.nn.functional.cross_entropy(out.logits, batch["source"]["label"])
    assert loss.item() == pytest.approx(10.0 * ce.item() + plain._regulariser(out).item(), rel=1e-5)
    # eval defaults to the target statistics; bn_domain("source") switches and restores
    model.eval()
    x = batch["target"]["points"]
    with model.bn_domain("source"):
        s = model(x).logits
    assert model._bn_domain == "target"
    assert not torch.allclose(model(x).logits, s)


def test_vtloss_domain_bn_normalises_each_domain_with_its_own_batch():
    """In training mode the target features do not depend on the source batch (split forward)."""
    torch.manual_seed(0)
    model = XAVTNet(**TINY, domain_bn=True).train()
    b1, b2 = _two_stream(0), _two_stream(1)
    b2["target"] = b1["target"]
    _, t1 = model._split_forward(b1["source"], b1["target"])
    _, t2 = model._split_forward(b2["source"], b2["target"])
    assert torch.allclose(t1.features["fc1"], t2.features["fc1"], atol=1e-6)
    # pooled statistics (domain_bn off) do mix them
    plain = XAVTNet(**TINY).train()
    _, p1 = plain._joint_forward(b1["source"], b1["target"])
    _, p2 = plain._joint_forward(b2["source"], b2["target"])
    assert not torch.allclose(p1.features["fc1"], p2.features["fc1"], atol=1e-4)


def test_domain_bn_refuses_single_stream_and_round_trips(tmp_path):
    from tests.test_xavtnet import TinyCrossModalDM

    model = XAVTNet(**TINY, domain_bn=True)
    single = {"points": torch.randn(4, 10, 3), "lengths": torch.full((4,), 10),
              "label": torch.zeros(4).long()}
    with pytest.raises(ValueError, match="domain_bn needs two-stream batches"):
        model.training_step(single, 0)
    trainer = L.Trainer(fast_dev_run=1, accelerator="cpu", logger=False, enable_progress_bar=False,
                        enable_model_summary=False, default_root_dir=tmp_path)
    trainer.fit(model, datamodule=TinyCrossModalDM())
    path = tmp_path / "dbn.ckpt"
    trainer.save_checkpoint(path)
    again = XAVTNet.load_from_checkpoint(path, map_location="cpu", weights_only=True).eval()
    model.eval()
    x = torch.randn(2, 12, 3)
    assert torch.equal(again(x).logits, model(x).logits)
    with model.bn_domain("source"), again.bn_domain("source"):
        assert torch.equal(again(x).logits, model(x).logits)


def test_adapt_bn_statistics_averages_the_target_batches_exactly(tmp_path):
    """AdaBN after training: target statistics = the mean of the batch statistics; source ones unchanged."""
    from tests.test_xavtnet import TinyCrossModalDM

    torch.manual_seed(0)
    model = XAVTNet(**TINY, da_method="none")
    trainer = L.Trainer(max_epochs=2, accelerator="cpu", logger=False, enable_progress_bar=False,
                        enable_model_summary=False, enable_checkpointing=False, limit_val_batches=0,
                        default_root_dir=tmp_path)
    trainer.fit(model, datamodule=TinyCrossModalDM())
    model.eval()
    x = torch.randn(3, 15, 3)
    before = model(x).logits
    fc1_stats = (model.head.fc1[1].running_mean.clone(), model.head.fc1[1].running_var.clone())
    batches = [next(iter(TinyCrossModalDM().train_dataloader()))[0]["target"] for _ in range(1)]
    batches = batches + [{"points": 2.0 * b["points"], "lengths": b["lengths"]} for b in batches]
    batches.append({"points": torch.randn(1, 5, 3), "lengths": torch.tensor([5])})  # too small: skipped
    seen = []
    # the fc1 Linear's output is what fc1's batch norm normalises
    hook = model.head.fc1[0].register_forward_hook(lambda m, inp, out: seen.append(out.detach().clone()))
    n = model.adapt_bn_statistics(batches)
    hook.remove()
    assert n == sum(int(b["points"].shape[0]) for b in batches[:2])
    assert model.hparams.domain_bn and model.training is False
    fc1 = model.head.fc1[1]
    assert isinstance(fc1, DomainBatchNorm)
    assert len(seen) == 2
    assert torch.allclose(fc1.running_mean_target, torch.stack([s.mean(0) for s in seen]).mean(0), atol=1e-6)
    assert torch.allclose(fc1.running_var_target, torch.stack([s.var(0) for s in seen]).mean(0), atol=1e-5)
    assert torch.equal(fc1.running_mean_source, fc1_stats[0])
    assert torch.equal(fc1.running_var_source, fc1_stats[1])
    with model.bn_domain("source"):  # the trained network, as it was
        assert torch.allclose(model(x).logits, before, atol=1e-6)
    assert not torch.allclose(model(x).logits, before, atol=1e-4)  # tactile clouds: the new statistics
    # reloads from a plain state dict + the updated hyperparameters
    again = XAVTNet(**dict(model.hparams))
    again.load_state_dict(model.state_dict())
    again.eval()
    assert torch.equal(again(x).logits, model(x).logits)
    with pytest.raises(ValueError, match="no batch of >= 2 clouds"):
        model.adapt_bn_statistics([batches[-1]])
    with pytest.raises(ValueError, match="passes"):
        model.adapt_bn_statistics(batches, passes=0)
    with pytest.raises(ValueError, match="domain"):
        model.adapt_bn_statistics(batches, domain="tactile")


def test_mean_teacher_with_domain_bn_normalises_its_target_copy_alone():
    """consistency_weight with domain_bn: a teacher equal to the network gives the target logits of the
    network's own target forward (``_split_forward``, the copy's batch statistics alone), whatever the source
    batch, and leaves both domains' running statistics alone; teacher_norm="running" is the eval-mode
    network with the target statistics."""
    from tests.test_xavtnet import TinyCrossModalDM, teacher_against

    batch = next(iter(TinyCrossModalDM().train_dataloader()))[0]
    src, tgt = batch["source"], batch["target"]

    def teacher_row(**kwargs):
        """A teacher row whose teacher equals the network, with target statistics unlike the source's."""
        model = XAVTNet(**TINY, consistency_weight=1.0, domain_bn=True, **kwargs)
        with torch.no_grad():
            for m in model.modules():
                if isinstance(m, DomainBatchNorm):
                    m.running_mean_target.add_(0.5)
        model._update_teacher(0.0)
        return model

    model = teacher_row()
    assert all(isinstance(m, DomainBatchNorm) for m in model.teacher.modules()
               if isinstance(m, nn.BatchNorm1d | DomainBatchNorm))
    teacher, expected = teacher_against(model, src, tgt, lambda c: model._split_forward(src, c)[1].logits)
    assert torch.allclose(teacher, expected, atol=1e-5)
    other = {**src, "points": src["points"] + 0.5}  # other source clouds: the same target logits
    assert torch.allclose(teacher_against(model, other, tgt, lambda c: None)[0], teacher, atol=1e-6)

    model = teacher_row(teacher_norm="running")
    teacher, (target, source) = teacher_against(model, src, tgt, lambda c: (
        model.eval()(c["points"], c["lengths"]).logits,  # the target statistics, by default
        _source_logits(model, c)))
    assert torch.allclose(teacher, target, atol=1e-5)
    assert not torch.allclose(source, target, atol=1e-3)


def _source_logits(model, batch):
    with model.bn_domain("source"):
        return model(batch["points"], batch["lengths"]).logits


def test_reestimated_bn_statistics_with_domain_bn_average_each_domain_over_its_own_stream():
    """With domain_bn, reestimate_bn_statistics sets each domain's running means to the exact mean of the
    batch means over that domain's batches of the two-stream loader, and no weight changes."""
    from tests.test_xavtnet import TinyCrossModalDM

    torch.manual_seed(0)
    model = XAVTNet(**TINY, consistency_weight=1.0, domain_bn=True)
    loader = TinyCrossModalDM().train_dataloader()
    batches = [b for b, _, _ in loader]
    reference = XAVTNet(**TINY, consistency_weight=1.0, domain_bn=True)
    reference.load_state_dict(model.state_dict())
    fc1 = reference.head.fc1[0]  # the Linear whose output fc1's batch norm normalises
    expected = {}
    for domain in ("source", "target"):
        seen = []
        hook = fc1.register_forward_hook(lambda m, inp, out, seen=seen: seen.append(out.detach().mean(0)))
        with torch.no_grad(), reference.bn_domain(domain):
            for b in batches:
                reference.train()(b[domain]["points"], b[domain]["lengths"])  # batch statistics, no dropout
        hook.remove()
        expected[domain] = torch.stack(seen).mean(0)
    weights = {k: v.clone() for k, v in model.state_dict().items() if "running" not in k}
    assert model.reestimate_bn_statistics(loader) == 24  # 3 batches of 4 source and 4 target clouds
    bn = model.head.fc1[1]
    assert torch.allclose(bn.running_mean_source, expected["source"], atol=1e-5)
    assert torch.allclose(bn.running_mean_target, expected["target"], atol=1e-5)
    assert not torch.allclose(bn.running_mean_source, bn.running_mean_target, atol=1e-3)
    assert bn.momentum == 0.1  # restored
    for k, v in model.state_dict().items():
        if k in weights:
            assert torch.equal(v, weights[k]), k


def test_mean_teacher_with_domain_bn_trains_adopts_its_teacher_and_round_trips(tmp_path):
    """A short training of the teacher row with domain_bn logs the consistency, keeps the teacher's
    per-domain statistics in a weights_only checkpoint, and adopt_teacher gives the network the teacher's
    weights with both domains' statistics re-estimated."""
    from tests.test_xavtnet import TinyCrossModalDM

    torch.manual_seed(0)
    model = XAVTNet(**TINY, consistency_weight=2.0, consistency_rampup=0.0, ema_decay=0.5, domain_bn=True)
    trainer = L.Trainer(max_steps=3, accelerator="cpu", logger=False, enable_progress_bar=False,
                        enable_model_summary=False, limit_val_batches=0, default_root_dir=tmp_path)
    trainer.fit(model, datamodule=TinyCrossModalDM())
    assert "train/consistency" in trainer.logged_metrics
    t_bn = model.teacher["head"].fc1[1]
    assert not torch.equal(t_bn.running_mean_source, t_bn.running_mean_target)
    path = tmp_path / "mt_dbn.ckpt"
    trainer.save_checkpoint(path)
    again = XAVTNet.load_from_checkpoint(path, map_location="cpu", weights_only=True).eval()
    for (k, v), (_, w) in zip(again.teacher.state_dict().items(), model.teacher.state_dict().items(),
                              strict=True):
        assert torch.equal(v, w), k
    teacher_fc1 = model.teacher["head"].fc1[0].weight.clone()
    assert model.adopt_teacher(TinyCrossModalDM().train_dataloader()) == 24
    assert torch.equal(model.head.fc1[0].weight, teacher_fc1)
    x = torch.randn(2, 12, 3)
    model.eval()
    with model.bn_domain("source"):
        source = model(x).logits
    assert not torch.allclose(model(x).logits, source, atol=1e-4)
