"""Tests for AaD's attract-and-disperse loss and the neighbour bank of XAVTNet (beyond the thesis)."""

import lightning as L
import pytest
import torch
import torch.nn.functional as F

from vtlearn.losses.neighbourhood import attract_disperse, neighbour_probs
from vtlearn.models.xavtnet import XAVTNet


def test_neighbour_probs_are_the_nearest_rows_by_cosine_leaving_out_self_and_empty_rows():
    bank_f = torch.tensor([[1.0, 0.0], [10.0, 1.0], [0.0, 1.0], [1.0, 1.0], [-1.0, 0.0]])
    bank_p = torch.eye(5)  # row j's "probabilities" name j, so the result reads as indices
    query = torch.tensor([[3.0, 0.2], [0.1, 3.0]])
    # cosines of query 0: row 1 (0.9994) > 0 (0.9978) > 3 > 2 > 4, of query 1: 2 > 3 > 1 > 0 > 4
    near = neighbour_probs(query, bank_f, bank_p, k=2)
    assert near.argmax(-1).tolist() == [[1, 0], [2, 3]]
    near = neighbour_probs(query, bank_f, bank_p, k=2, self_index=torch.tensor([1, 2]))
    assert near.argmax(-1).tolist() == [[0, 3], [3, 1]]
    valid = torch.tensor([True, False, True, True, True])
    near = neighbour_probs(query, bank_f, bank_p, k=2, self_index=torch.tensor([0, 2]), valid=valid)
    assert near.argmax(-1).tolist() == [[3, 2], [3, 0]]
    with pytest.raises(ValueError, match="k: need 1 <= k <= 3"):
        neighbour_probs(query, bank_f, bank_p, k=4, self_index=torch.tensor([0, 2]), valid=valid)
    for args, match in [((query[:, :1], bank_f, bank_p), "same feature size"),
                        ((query, bank_f, bank_p[:4]), "bank_probs has 4 rows"),
                        ((query * float("nan"), bank_f, bank_p), "features contains NaN"),
                        ((query, bank_f[:0], bank_p[:0]), "bank_features needs at least 1 rows")]:
        with pytest.raises(ValueError, match=match):
            neighbour_probs(*args, k=1)
    with pytest.raises(ValueError, match="self_index"):
        neighbour_probs(query, bank_f, bank_p, k=1, self_index=torch.tensor([0, 5]))
    with pytest.raises(ValueError, match="valid must be a bool"):
        neighbour_probs(query, bank_f, bank_p, k=1, valid=torch.ones(5))


def test_attract_disperse_matches_a_double_loop_and_its_gradient_reaches_the_batch_only():
    torch.manual_seed(0)
    logits = torch.randn(5, 4, requires_grad=True)
    near = torch.randn(5, 3, 4).softmax(-1).requires_grad_(True)
    p = logits.softmax(-1)
    loss = attract_disperse(p, near, dispersion=0.7)
    expected = 0.0
    for i in range(5):
        expected -= sum(float(p[i].detach() @ near[i, j].detach()) for j in range(3))
        expected += 0.7 * sum(float(p[i].detach() @ p[m].detach()) for m in range(5) if m != i)
    assert loss.item() == pytest.approx(expected / 5, rel=1e-6)
    loss.backward()
    assert logits.grad.abs().sum() > 0 and near.grad is None
    # bounds: one-hot neighbours that agree with a one-hot batch of distinct classes give −K
    onehot = torch.eye(4)
    assert attract_disperse(onehot, onehot[:, None, :].expand(4, 3, 4)).item() == pytest.approx(-3.0)
    same = onehot[[0, 0, 0]]
    assert attract_disperse(same, same[:, None, :], dispersion=2.0).item() == pytest.approx(2.0 * 2 - 1)


def test_attract_disperse_moves_a_cloud_to_its_neighbours_class_and_apart_from_the_batch():
    logits = torch.zeros(3, 3, requires_grad=True)
    near = F.one_hot(torch.tensor([[2, 2], [2, 2], [2, 2]]), 3).float()
    attract_disperse(logits.softmax(-1), near, dispersion=0.0).backward()
    assert (logits.grad[:, 2] < 0).all()  # gradient descent raises class 2
    logits = torch.tensor([[3.0, 0.0], [3.0, 0.0]], requires_grad=True)
    uniform = torch.full((2, 1, 2), 0.5)  # no pull from the neighbours: only the dispersion acts
    attract_disperse(logits.softmax(-1), uniform, dispersion=1.0).backward()
    assert (logits.grad[:, 0] > 0).all()  # the two agreeing clouds are pushed off their shared class


def test_attract_disperse_rejects_bad_input():
    p = torch.full((2, 3), 1 / 3)
    for near, dispersion, match in [(torch.full((2, 3), 1 / 3), 1.0, "neighbour_probs must have shape"),
                                    (torch.full((2, 1, 4), 0.25), 1.0, "neighbour_probs must have shape"),
                                    (torch.full((2, 1, 3), float("nan")), 1.0, "neighbour_probs contains"),
                                    (torch.full((2, 1, 3), 1 / 3), -1.0, "dispersion"),
                                    (torch.full((2, 1, 3), 1 / 3), float("nan"), "dispersion")]:
        with pytest.raises(ValueError, match=match):
            attract_disperse(p, near, dispersion)
    with pytest.raises(ValueError, match="probs"):
        attract_disperse(p[:, :1], torch.ones(2, 1, 1))


def test_xavtnet_fills_the_bank_at_the_start_epoch_and_adds_the_aad_loss_of_its_neighbours(tmp_path):
    """From epoch ⌈start·max_epochs⌉ the bank holds the eval-mode fc2 features and softmax of the whole
    target stream; each step overwrites the batch's rows and adds w·L_AaD against the K nearest others."""
    from tests.test_xavtnet import (
        TINY,
        IndexedCrossModalDM,
        TinyCrossModalDM,
        _Clouds,
        _Indexed,
        _indexed_collate,
    )

    seen = []

    class Record(L.Callback):
        def on_train_batch_start(self, trainer, pl_module, batch, batch_idx):
            bank = pl_module._neighbour_bank
            seen.append((trainer.current_epoch, None if bank is None else int(bank["valid"].sum())))

    torch.manual_seed(0)
    model = XAVTNet(**TINY, neighbour_weight=2.0, neighbour_k=2, neighbour_dispersion=0.5,
                    neighbour_start=0.5)
    trainer = L.Trainer(max_epochs=2, accelerator="cpu", logger=False, enable_progress_bar=False,
                        enable_model_summary=False, enable_checkpointing=False, limit_val_batches=0,
                        default_root_dir=tmp_path, callbacks=[Record()])
    trainer.fit(model, datamodule=IndexedCrossModalDM())
    assert seen == [(0, None)] * 3 + [(1, 8)] * 3  # 8 target clouds, filled once at epoch 1 of 2
    assert "train/aad" in trainer.callback_metrics and model._neighbour_bank is None  # reset after fit

    clouds = [p for p, _ in _Clouds(8, 5, 12, 1, scale=2.0).items]
    loader = torch.utils.data.DataLoader(_Indexed(clouds), batch_size=3, collate_fn=_indexed_collate)
    bank = model.fill_neighbour_bank(loader)
    everything = _indexed_collate([loader.dataset[i] for i in range(8)])
    out = model.extract_features(everything["points"], everything["lengths"])
    assert torch.allclose(bank["features"], F.normalize(out["fc2"], dim=1), atol=1e-6)
    assert torch.allclose(bank["probs"], out["logits"].softmax(-1), atol=1e-6) and bank["valid"].all()

    # the step's loss: VTLoss's plus 2·L_AaD(batch softmax, its 2 nearest bank rows other than itself)
    batch = _indexed_collate([loader.dataset[i] for i in (5, 1, 6, 2)])
    two = {"source": next(iter(TinyCrossModalDM().train_dataloader()))[0]["source"], "target": batch}
    model._log_train = lambda *a, **k: None
    model.train()
    model._neighbour_bank = {k: v.clone() for k, v in bank.items()}
    torch.manual_seed(1)
    loss = model.training_step(two, 0)
    updated = model._neighbour_bank
    model._neighbour_bank = None
    torch.manual_seed(1)
    plain = model.training_step(two, 0)
    torch.manual_seed(1)
    _, out_t = model._joint_forward(two["source"], two["target"])
    rows = batch["index"]
    assert torch.allclose(updated["features"][rows], F.normalize(out_t.features["fc2"], dim=1), atol=1e-6)
    others = torch.ones(8, dtype=torch.bool)
    others[rows] = False
    assert torch.equal(updated["features"][others], bank["features"][others])
    p = out_t.logits.softmax(-1)
    near = []
    for i, row in enumerate(rows.tolist()):  # by hand: cosine to every other row, the two largest
        sims = updated["features"] @ F.normalize(out_t.features["fc2"][i], dim=0)
        sims[row] = -2.0
        near.append(updated["probs"][sims.topk(2).indices])
    aad = attract_disperse(p, torch.stack(near), 0.5)
    assert aad.item() != 0 and loss.item() == pytest.approx(plain.item() + 2.0 * aad.item(), rel=1e-5)
    # and it trains: the step's gradient is the plain step's plus that of 2·L_AaD of the same forward
    params = list(model.head.parameters())
    grad_step = torch.autograd.grad(loss, params)
    grad_plain = torch.autograd.grad(plain, params)
    grad_aad = torch.autograd.grad(2.0 * aad, params)
    assert sum(float(g.abs().sum()) for g in grad_aad) > 0
    for gs, gp, ga in zip(grad_step, grad_plain, grad_aad, strict=True):
        assert torch.allclose(gs - gp, ga, atol=1e-5)


def test_xavtnet_neighbour_settings_and_streams_are_checked(tmp_path):
    from tests.test_xavtnet import TINY, TinyCrossModalDM

    for kwargs, match in [(dict(neighbour_weight=-1.0), "neighbour_weight"),
                          (dict(neighbour_k=0), "neighbour_k"), (dict(neighbour_k=1.5), "neighbour_k"),
                          (dict(neighbour_dispersion=float("inf")), "neighbour_dispersion"),
                          (dict(neighbour_start=1.0), "neighbour_start"),
                          (dict(neighbour_layer="fc3"), "neighbour_layer"),
                          (dict(neighbour_bank="queue"), "neighbour_bank"),
                          (dict(neighbour_bank="teacher"), "needs consistency_weight")]:
        with pytest.raises(ValueError, match=match):
            XAVTNet(**TINY, **kwargs)
    with pytest.raises(ValueError, match="index"):  # TinyCrossModalDM's target items have no index
        L.Trainer(max_epochs=1, accelerator="cpu", logger=False, enable_progress_bar=False,
                  enable_model_summary=False, enable_checkpointing=False, limit_val_batches=0,
                  default_root_dir=tmp_path).fit(
            XAVTNet(**TINY, neighbour_weight=1.0, neighbour_start=0.0), datamodule=TinyCrossModalDM())


def test_a_teacher_bank_takes_the_teachers_rows_and_neighbours_of_its_own_copy():
    """neighbour_bank="teacher": a step writes the teacher's unit fc2 feature and softmax of its perturbed
    copy into the batch's rows, finds the neighbours from that feature, and pulls the network's softmax."""
    from tests.test_xavtnet import TINY, TinyCrossModalDM, _Clouds, _Indexed, _indexed_collate

    torch.manual_seed(0)
    model = XAVTNet(**TINY, consistency_weight=1.0, consistency_rampup=0.0, neighbour_weight=2.0,
                    neighbour_k=2, neighbour_bank="teacher")
    model.train()
    with torch.no_grad():  # a teacher unlike the network, so that whose rows they are shows
        for p in model.teacher.parameters():
            p.add_(0.3 * torch.randn_like(p))
    clouds = _Indexed([p for p, _ in _Clouds(8, 5, 12, 1, scale=2.0).items])
    batch = _indexed_collate([clouds[i] for i in (5, 1, 6, 2)])
    bank = model.fill_neighbour_bank([_indexed_collate([clouds[i] for i in range(8)])])
    src = next(iter(TinyCrossModalDM().train_dataloader()))[0]["source"]
    model._log_train = lambda *a, **k: None
    model._progress = lambda: 1.0
    model._neighbour_bank = {k: v.clone() for k, v in bank.items()}
    torch.manual_seed(1)
    loss = model.training_step({"source": src, "target": batch}, 0)
    updated, model._neighbour_bank = model._neighbour_bank, None
    torch.manual_seed(1)
    plain = model.training_step({"source": src, "target": batch}, 0)
    torch.manual_seed(1)
    logits_t, feats_t = model._teacher_forward(src, batch)
    out_t = model._joint_forward(src, model._perturb(batch))[1]
    rows = batch["index"]
    unit = F.normalize(feats_t["fc2"], dim=1)
    assert torch.allclose(updated["features"][rows], unit, atol=1e-6)
    assert torch.allclose(updated["probs"][rows], logits_t.softmax(-1), atol=1e-6)
    assert not torch.allclose(unit, F.normalize(out_t.features["fc2"], dim=1), atol=1e-2)
    near = neighbour_probs(feats_t["fc2"], updated["features"], updated["probs"], 2, rows)
    aad = attract_disperse(out_t.logits.softmax(-1), near, 1.0).item()
    assert loss.item() == pytest.approx(plain.item() + 2.0 * aad, rel=1e-5)
