"""Tests for MC-dropout active learning (thesis eq. 7.3-7.4, Algorithm 5 visual-learning loop)."""

import json
import math
import os

import lightning as L
import numpy as np
import pytest
import torch
from _interrupt import CountedCalls
from torch import nn
from torch.utils.data import DataLoader

from vtlearn.active.learning_loop import (
    ActiveLearningLoop,
    bootstrap_label_ratio,
    epochs_for,
    labels_to_reach,
    paired_advantage,
)
from vtlearn.active.mc_dropout import (
    acquisition_scores,
    bald_score,
    mc_dropout_mode,
    mc_dropout_probs,
    predictive_entropy,
    random_query,
    score_pool,
    select_power,
    select_top_k,
    split_strategy,
)
from vtlearn.models.xavtnet import XAVTNet

os.environ.setdefault("WANDB_MODE", "disabled")
TINY = dict(num_classes=3, global_dim=32, fc_dims=[16, 8], feature_transform=False)


def _collate(items):
    n = max(p.shape[0] for p, _, _ in items)
    pts = torch.zeros(len(items), n, 3)
    for i, (p, _, _) in enumerate(items):
        pts[i, : p.shape[0]] = p
    return {
        "points": pts,
        "lengths": torch.tensor([p.shape[0] for p, _, _ in items]),
        "label": torch.tensor([c for _, c, _ in items]),
        "index": torch.tensor([i for _, _, i in items]),
    }


class TinyPoolDM:
    """The ActivePoolDataModule interface on 3 toy classes (blobs around (c, 0, 0))."""

    def __init__(self, n_pool=24, initial_labels=6, seed=0):
        g = torch.Generator().manual_seed(seed)
        self.items = []
        for i in range(n_pool + 9):
            m = int(torch.randint(6, 15, (1,), generator=g))
            c = i % 3
            self.items.append((torch.randn(m, 3, generator=g) * 0.2 + torch.tensor([float(c), 0, 0]), c, i))
        self.test_items = self.items[n_pool:]
        self.pool = self.items[:n_pool]
        perm = torch.randperm(n_pool, generator=g).tolist()
        self.labelled_indices = sorted(perm[:initial_labels])
        self.unlabelled_indices = sorted(perm[initial_labels:])

    def train_dataloader(self):
        return DataLoader([self.pool[i] for i in self.labelled_indices], batch_size=4, shuffle=True,
                          collate_fn=_collate, drop_last=len(self.labelled_indices) % 4 == 1)

    def unlabelled_dataloader(self):
        def strip(items):
            batch = _collate(items)
            del batch["label"]
            return batch

        return DataLoader([self.pool[i] for i in self.unlabelled_indices], batch_size=5, collate_fn=strip)

    def test_dataloader(self):
        return DataLoader(self.test_items, batch_size=5, collate_fn=_collate)

    def query(self, indices):
        indices = [int(i) for i in indices]
        assert all(i in self.unlabelled_indices for i in indices)
        self.unlabelled_indices = [i for i in self.unlabelled_indices if i not in indices]
        self.labelled_indices = sorted(self.labelled_indices + indices)
        return torch.tensor([self.pool[i][1] for i in indices])


def test_mc_dropout_passes_differ_with_dropout_and_match_without():
    torch.manual_seed(0)
    model = XAVTNet(**TINY, dropout=0.5)
    model.train()
    model(torch.randn(6, 10, 3))  # non-trivial BN running stats
    points = torch.randn(4, 10, 3)
    on = mc_dropout_probs(model, points, num_passes=5, dropout=True)
    off = mc_dropout_probs(model, points, num_passes=5, dropout=False)
    assert on.shape == (5, 4, 3)
    assert not torch.allclose(on[0], on[1])
    assert torch.allclose(off[0], off[1]) and torch.allclose(off[0], off[4])
    assert torch.allclose(on.sum(-1), torch.ones(5, 4))
    assert model.training  # flags restored


def test_mc_dropout_mode_keeps_batch_norm_in_eval():
    model = XAVTNet(**TINY, dropout=0.5).train()
    bn = model.head.fc1[1]
    stats = bn.running_mean.clone()
    with mc_dropout_mode(model):
        assert not bn.training and model.head.dropout.training
        model(torch.randn(3, 8, 3))
    assert torch.equal(bn.running_mean, stats)  # eval-mode BN does not update running stats
    with pytest.raises(ValueError, match="dropout"):
        with mc_dropout_mode(nn.Linear(2, 2)):
            pass


def test_entropy_and_bald_hand_cases_and_naive_reference():
    uniform = torch.full((1, 4), 0.25)
    onehot = torch.tensor([[0.0, 1.0, 0.0]])
    assert predictive_entropy(uniform).item() == pytest.approx(math.log(4))
    assert predictive_entropy(onehot).item() == pytest.approx(0.0)
    # Two confident passes that disagree: H[mean] = log 2, mean H = 0 -> BALD = log 2.
    disagree = torch.tensor([[[1.0, 0.0]], [[0.0, 1.0]]])
    assert bald_score(disagree).item() == pytest.approx(math.log(2))
    # Two identical uncertain passes: high entropy, zero mutual information.
    agree = torch.full((2, 1, 2), 0.5)
    assert bald_score(agree).item() == pytest.approx(0.0, abs=1e-7)
    assert acquisition_scores(agree, "entropy").item() == pytest.approx(math.log(2))
    probs = torch.softmax(torch.randn(3, 5, 4, dtype=torch.float64), -1)
    mean = probs.mean(0)
    naive = [-sum(float(p) * math.log(float(p)) for p in mean[b]) for b in range(5)]
    assert predictive_entropy(mean).tolist() == pytest.approx(naive)
    with pytest.raises(ValueError, match="strategy"):
        acquisition_scores(probs, "margin")
    with pytest.raises(ValueError, match="mean_probs"):
        predictive_entropy(torch.ones(4))


def test_select_top_k_and_random_query():
    scores = torch.tensor([0.1, 0.9, 0.5, 0.9])
    assert select_top_k(scores, 3).tolist() == [1, 3, 2]
    with pytest.raises(ValueError, match="k"):
        select_top_k(scores, 5)
    pool = torch.tensor([10, 11, 12, 13, 14])
    picked = random_query(pool, 3, torch.Generator().manual_seed(0))
    assert len(set(picked.tolist())) == 3 and set(picked.tolist()) <= set(pool.tolist())


def test_select_power_draws_in_proportion_to_the_scores():
    scores = torch.tensor([1.0, 2.0, 3.0, 4.0])
    g = torch.Generator().manual_seed(0)
    n = 20000
    counts = torch.bincount(torch.stack([select_power(scores, 1, 1.0, g) for _ in range(n)]).reshape(-1),
                            minlength=4)
    # Binomial std of each frequency is at most 0.0035; 0.015 is over 4 sigma.
    assert torch.allclose(counts / n, scores / scores.sum(), atol=0.015)
    # beta = 0 is uniform
    counts0 = torch.bincount(torch.stack([select_power(scores, 1, 0.0, g) for _ in range(n)]).reshape(-1))
    assert torch.allclose(counts0 / n, torch.full((4,), 0.25), atol=0.015)


def test_select_power_large_beta_is_top_k_and_zero_scores_come_last():
    scores = torch.tensor([0.1, 0.9, 0.5, 0.7, 0.0])
    g = torch.Generator().manual_seed(1)
    for _ in range(20):
        assert select_power(scores, 3, 1e4, g).tolist() == [1, 3, 2]
        picked = select_power(scores, 4, 1.0, g).tolist()
        assert len(set(picked)) == 4 and 4 not in picked  # without replacement, zero score last
    with pytest.raises(ValueError, match="k"):
        select_power(scores, 6)
    with pytest.raises(ValueError, match="beta"):
        select_power(scores, 2, -1.0)
    with pytest.raises(ValueError, match="scores"):
        select_power(torch.tensor([0.5, -0.1]), 1)
    with pytest.raises(ValueError, match="scores"):
        select_power(torch.tensor([0.5, float("nan")]), 1)


def test_split_strategy():
    assert split_strategy("power_bald") == ("bald", "power")
    assert split_strategy("entropy") == ("entropy", "top_k")
    with pytest.raises(ValueError, match="strategy"):
        split_strategy("power_random")


class _Stub(nn.Module):
    """Logits read from the first point; the dropout only makes the module MC-dropout capable."""

    def __init__(self):
        super().__init__()
        self.drop = nn.Dropout(0.5)
        self.w = nn.Parameter(torch.zeros(()))

    def forward(self, points, lengths=None):
        return points[:, 0, :2] + 0 * self.drop(torch.ones(points.shape[0], 2)) + self.w


def test_score_pool_ranks_the_most_uncertain_first():
    points = torch.tensor([[[5.0, 0.0, 0.0]], [[0.0, 0.0, 0.0]], [[0.0, 3.0, 0.0]], [[1.0, 0.0, 0.0]]])
    batches = [{"points": points[:2], "index": torch.tensor([7, 8])},
               {"points": points[2:], "index": torch.tensor([9, 10])}]
    idx, scores = score_pool(_Stub(), batches, "entropy", num_passes=2)
    assert idx.tolist() == [7, 8, 9, 10]
    assert idx[select_top_k(scores, 2)].tolist() == [8, 10]  # equal logits, then the closest pair


def test_epochs_for_min_steps():
    assert epochs_for(10, 0, 3) == 10
    assert epochs_for(10, 150, 1) == 150  # 32 labels, batch 32: one step per epoch
    assert epochs_for(10, 150, 18) == 10  # the full pool already gets 180 steps
    assert epochs_for(2, 7, 3) == 3


def test_labels_to_reach_hand_case():
    n = [10, 20, 30, 40]
    acc = [0.5, 0.85, 0.9, 0.97]
    got = labels_to_reach(n, acc, full_accuracy=0.95)
    # rel. errors: 0.47, 0.105, 0.053, -0.02
    assert got == {0.10: 30, 0.05: 40, 0.03: 40, 0.02: 40}
    got = labels_to_reach(n, acc, 0.95, thresholds=(0.2, 0.06))
    assert got == {0.2: 20, 0.06: 30}
    # A lucky round that later falls back out counts only without sustained.
    noisy = [0.5, 0.94, 0.85, 0.94]  # rel. errors 0.47, 0.011, 0.105, 0.011
    assert labels_to_reach(n, noisy, 0.95, thresholds=(0.02, 0.2)) == {0.02: 20, 0.2: 20}
    assert labels_to_reach(n, noisy, 0.95, thresholds=(0.02, 0.2), sustained=True) == {0.02: 40, 0.2: 20}
    falls = [0.5, 0.94, 0.94, 0.8]
    assert labels_to_reach(n, falls, 0.95, thresholds=(0.02,), sustained=True) == {0.02: None}
    assert labels_to_reach([5], [0.1], 1.0) == {0.10: None, 0.05: None, 0.03: None, 0.02: None}
    with pytest.raises(ValueError, match="full_accuracy"):
        labels_to_reach(n, acc, 0.0)


def test_paired_advantage_hand_case():
    base = np.array([[0.5, 0.80, 0.85, 0.90], [0.6, 0.82, 0.84, 0.88]])
    ahead = base + np.array([[0.0, 0.02, 0.03, -0.01], [0.0, 0.04, 0.01, 0.02]])
    got = paired_advantage(ahead, base)
    # round 0 skipped (same n0 labels): differences 2, 3, -1, 4, 1, 2 points
    assert got["pairs"] == 6 and got["ahead"] == 5
    assert got["mean_diff"] == pytest.approx(11 / 6)
    assert 0 < got["wilcoxon_p"] < 0.2
    same = paired_advantage(base, base)
    assert same["mean_diff"] == 0 and same["ahead"] == 0 and same["wilcoxon_p"] is None
    # a strategy ahead by 3 points in every one of 30 pairs is significant
    rng = np.random.default_rng(0)
    b = rng.uniform(0.6, 0.9, size=(3, 11))
    strong = paired_advantage(b + 0.03, b)
    assert strong["ahead"] == 30 and strong["wilcoxon_p"] < 1e-4
    with pytest.raises(ValueError, match="same shape"):
        paired_advantage(base, base[:, :3])
    with pytest.raises(ValueError, match="at least one round"):
        paired_advantage(base[:, :1], base[:, :1])


def test_bootstrap_label_ratio_hand_case():
    n = [10, 20, 30, 40]
    full = [1.0, 1.0]  # the 2 % line is 0.98
    rand = np.array([[0.5, 0.9, 0.95, 0.99], [0.5, 0.9, 0.95, 0.99]])  # reaches at 40 labels
    # Identical seeds: every draw is the same, so the interval collapses onto the point ratio 20 / 40.
    same = np.array([[0.5, 0.99, 0.99, 0.99]] * 2)
    got = bootstrap_label_ratio(n, same, rand, full, n_boot=200)
    assert got["ratio"] == got["median"] == 0.5 and got["ci90"] == [0.5, 0.5]
    assert got["p_target"] == 1.0 and got["never"] == 0 and got["undefined"] == 0
    # Seed 0 reaches the line at 20 labels, seed 1 at 30, their mean at 30: ratio 0.75 on all seeds,
    # and 0.5 only in the draws that take seed 0 twice (probability 1/4).
    mixed = np.array([[0.5, 0.99, 0.99, 0.99], [0.5, 0.90, 0.99, 0.99]])
    got = bootstrap_label_ratio(n, mixed, rand, full, n_boot=4000, seed=1)
    assert got["ratio"] == 0.75 and got["ci90"] == [0.5, 0.75]
    assert got["p_target"] == pytest.approx(0.25, abs=0.03)
    # It agrees with the table's reading on the mean curves.
    a = labels_to_reach(n, mixed.mean(0), 1.0, thresholds=(0.02,))[0.02]
    assert got["ratio"] == a / labels_to_reach(n, rand.mean(0), 1.0, thresholds=(0.02,))[0.02]
    # A lucky round that falls back out: 0.5 first reached, 0.75 sustained.
    dips = np.array([[0.5, 0.99, 0.9, 0.99]] * 2)
    assert bootstrap_label_ratio(n, dips, rand, full, n_boot=50)["ratio"] == 0.5
    assert bootstrap_label_ratio(n, dips, rand, full, n_boot=50, sustained=True)["ratio"] == 1.0
    # Never reached: an infinite ratio (None), never meeting the target; a baseline that never
    # reaches the line leaves the ratio undefined.
    low = np.full((2, 4), 0.5)
    got = bootstrap_label_ratio(n, low, rand, full, n_boot=50)
    assert got["ratio"] is None and got["never"] == 1.0 and got["p_target"] == 0.0
    got = bootstrap_label_ratio(n, same, low, full, n_boot=50)
    assert got["ratio"] is None and got["undefined"] == 1.0 and got["median"] is None
    with pytest.raises(ValueError, match="rounds = len"):
        bootstrap_label_ratio(n[:3], same, rand, full)
    with pytest.raises(ValueError, match="one value per seed"):
        bootstrap_label_ratio(n, same, rand, [1.0])
    with pytest.raises(ValueError, match="finite"):
        bootstrap_label_ratio(n, same * np.nan, rand, full)
    with pytest.raises(ValueError, match="n_boot"):
        bootstrap_label_ratio(n, same, rand, full, n_boot=0)


@pytest.mark.parametrize("strategy,warm", [("entropy", False), ("bald", True), ("random", False),
                                           ("power_entropy", False)])
def test_active_learning_loop_queries_kappa_per_round(strategy, warm):
    dm = TinyPoolDM()
    before = set(dm.unlabelled_indices)
    made = []

    def factory(seed):
        made.append(seed)
        return XAVTNet(**TINY)

    loop = ActiveLearningLoop(dm, factory, strategy=strategy, kappa=4, rounds=1, mc_passes=3,
                              max_epochs=1, warm_start=warm, seed=5, show_progress=False)
    history = loop.run()
    assert [h.n_labels for h in history] == [6, 10]
    assert all(0.0 <= h.accuracy <= 1.0 for h in history)
    queried = history[0].queried
    assert len(set(queried)) == 4 and set(queried) <= before
    assert set(dm.labelled_indices) == set(range(24)) - set(dm.unlabelled_indices)
    assert history[1].queried == []
    assert made == ([5] if warm else [5, 6])
    with pytest.raises(ValueError, match="strategy"):
        ActiveLearningLoop(dm, factory, strategy="margin")
    with pytest.raises(ValueError, match="power_beta"):
        ActiveLearningLoop(dm, factory, strategy="power_bald", power_beta=float("inf"))


def test_active_learning_loop_fast_dev_run_module():
    dm = TinyPoolDM()
    model = XAVTNet(**TINY)
    trainer = L.Trainer(fast_dev_run=1, accelerator="cpu", logger=False, enable_progress_bar=False,
                        enable_model_summary=False)
    trainer.fit(model, train_dataloaders=dm.train_dataloader(), val_dataloaders=dm.test_dataloader())
    assert "val/acc" in trainer.callback_metrics


def test_train_steps_gives_every_round_the_same_number_of_optimiser_steps():
    """Equal-budget protocol: 6 labels (2 batches/epoch) and 14 labels (4 batches/epoch) both train
    exactly 7 optimiser steps, so accuracy at n labels is not confounded with training length."""
    dm = TinyPoolDM()
    steps = []

    class Counting(XAVTNet):
        def on_train_end(self):
            steps.append(self.trainer.global_step)

    loop = ActiveLearningLoop(dm, lambda s: Counting(**TINY), strategy="random", kappa=8, rounds=1,
                              mc_passes=1, max_epochs=50, min_steps=100, train_steps=7, seed=0,
                              show_progress=False)
    history = loop.run()
    assert [h.n_labels for h in history] == [6, 14]
    assert steps == [7, 7]
    # Without it, max_epochs sets the length and the larger set trains longer.
    steps.clear()
    ActiveLearningLoop(TinyPoolDM(), lambda s: Counting(**TINY), strategy="random", kappa=8, rounds=1,
                       mc_passes=1, max_epochs=2, seed=0, show_progress=False).run()
    assert steps == [4, 8]
    with pytest.raises(ValueError, match="train_steps"):
        ActiveLearningLoop(dm, lambda s: Counting(**TINY), train_steps=-1)


def test_loop_names_a_model_that_does_not_log_test_acc():
    """A model of one's own that logs its accuracy under another key gets a ValueError saying which key
    the loop reads, not a KeyError from inside the loop."""

    class OtherKey(XAVTNet):
        def test_step(self, batch, batch_idx):
            out = self(batch["points"], batch["lengths"])
            self.log("test_acc", (out.logits.argmax(-1) == batch["label"]).float().mean())

    loop = ActiveLearningLoop(TinyPoolDM(), lambda s: OtherKey(**TINY), strategy="random", kappa=4,
                              rounds=0, mc_passes=1, max_epochs=1, seed=0, show_progress=False)
    with pytest.raises(ValueError, match=r"model: its test_step must log 'test/acc'.*\['test_acc'\]"):
        loop.run()


@pytest.mark.parametrize("kwargs, name", [
    ({"kappa": 2.5}, "kappa"), ({"rounds": "3"}, "rounds"), ({"mc_passes": 0}, "mc_passes"),
    ({"min_steps": -1}, "min_steps"), ({"max_epochs": None}, "max_epochs"),
])
def test_loop_arguments_are_checked_by_name(kwargs, name):
    with pytest.raises(ValueError, match=f"^{name}: need an integer"):
        ActiveLearningLoop(TinyPoolDM(), lambda s: XAVTNet(**TINY), **kwargs)
    with pytest.raises(ValueError, match="model_factory: need a callable"):
        ActiveLearningLoop(TinyPoolDM(), XAVTNet(**TINY))


@pytest.mark.parametrize("warm", [False, True])
def test_loop_stopped_mid_way_goes_on_from_its_state_to_the_unstopped_history(tmp_path, warm, monkeypatch):
    """A Ctrl-C in the third training: rebuilt with the same settings, the loop restores two rounds (the
    labelled set, the history, the last weights), trains only the rest, and ends where an unstopped run
    does, queries included (warm-started rounds go on from the restored weights)."""
    import vtlearn.active.learning_loop as loop_module

    kw = dict(strategy="entropy", kappa=4, rounds=3, mc_passes=3, max_epochs=2, warm_start=warm, seed=5,
              show_progress=False)
    unstopped = ActiveLearningLoop(TinyPoolDM(), lambda s: XAVTNet(**TINY), **kw)
    unstopped.run()
    real = loop_module.train_and_test
    monkeypatch.setattr(loop_module, "train_and_test", CountedCalls(real, stop_at=3))
    with pytest.raises(KeyboardInterrupt):
        ActiveLearningLoop(TinyPoolDM(), lambda s: XAVTNet(**TINY), state_dir=tmp_path, **kw).run()
    assert (tmp_path / loop_module.LOOP_STATE_FILE).is_file()
    monkeypatch.setattr(loop_module, "train_and_test", real)

    dm = TinyPoolDM()
    loop = ActiveLearningLoop(dm, lambda s: XAVTNet(**TINY), state_dir=tmp_path, **kw)
    assert loop.restore() == 2 and loop.restore() == 2
    assert len(dm.labelled_indices) == 6 + 2 * 4
    assert loop.run() is loop.history and loop.history_dicts() == unstopped.history_dicts()
    assert sorted(dm.labelled_indices) == sorted(unstopped.dm.labelled_indices)
    # a loop whose rounds are all kept trains nothing and gives the last round's model back
    monkeypatch.setattr(loop_module, "train_and_test", CountedCalls(real, stop_at=1))
    again = ActiveLearningLoop(TinyPoolDM(), lambda s: XAVTNet(**TINY), state_dir=tmp_path, **kw)
    assert again.run() and again.history_dicts() == unstopped.history_dicts()
    for a, b in zip(again.model.state_dict().values(), unstopped.model.state_dict().values(), strict=True):
        assert torch.equal(a, b)


@pytest.mark.parametrize("warm", [False, True])
def test_finished_loop_built_with_more_rounds_goes_on_to_the_longer_runs_history(tmp_path, warm, monkeypatch):
    """A loop of 1 round kept in state_dir, built again with 3 rounds: its last round queries with the
    restored weights, only the 2 new rounds train, and history, labels and weights equal a 3-round run's."""
    import vtlearn.active.learning_loop as loop_module

    kw = dict(strategy="entropy", kappa=4, mc_passes=3, max_epochs=2, warm_start=warm, seed=5,
              show_progress=False)
    longer = ActiveLearningLoop(TinyPoolDM(), lambda s: XAVTNet(**TINY), rounds=3, **kw)
    longer.run()
    short = ActiveLearningLoop(TinyPoolDM(), lambda s: XAVTNet(**TINY), rounds=1, state_dir=tmp_path, **kw)
    short.run()
    assert short.history_dicts()[-1]["queried"] == []  # its rounds spent, its last round queried nothing
    trainings = CountedCalls(loop_module.train_and_test)
    monkeypatch.setattr(loop_module, "train_and_test", trainings)
    dm = TinyPoolDM()
    extended = ActiveLearningLoop(dm, lambda s: XAVTNet(**TINY), rounds=3, state_dir=tmp_path, **kw)
    assert extended.restore() == 2 and len(dm.labelled_indices) == 6 + 2 * 4  # round 1 queried on restore
    extended.run()
    assert trainings.calls == 2 and extended.history_dicts() == longer.history_dicts()
    assert sorted(dm.labelled_indices) == sorted(longer.dm.labelled_indices)
    for a, b in zip(extended.model.state_dict().values(), longer.model.state_dict().values(), strict=True):
        assert torch.equal(a, b)
    # the state now holds 3 rounds: going back to fewer is refused, naming the rounds
    with pytest.raises(ValueError, match=r"other settings \(rounds 3 there, 1 here; a loop goes on to more "
                                         r"rounds than it kept, not to fewer\)"):
        ActiveLearningLoop(TinyPoolDM(), lambda s: XAVTNet(**TINY), rounds=1, state_dir=tmp_path, **kw).run()


def test_loop_removes_the_partial_state_a_killed_process_left(tmp_path):
    """A SIGKILL between the write and the rename of the state leaves a temporary file: the next loop on
    that state_dir removes it; a temporary file of a running process (here this one) is kept."""
    from _interrupt import ended_pid

    pid = ended_pid()
    dead = tmp_path / f".loop_state.tmp-{pid}.npz"
    alive = tmp_path / f".loop_state.tmp-{os.getpid()}.npz"
    # another file's temporaries of the same ended writer: another stem, another suffix
    others = [tmp_path / f".other.tmp-{pid}.npz", tmp_path / f".loop_state.tmp-{pid}.json",
              tmp_path / f".loop_state.tmp-{pid}"]
    for f in (dead, alive, *others):
        f.write_bytes(b"partial")
    loop = ActiveLearningLoop(TinyPoolDM(), lambda s: XAVTNet(**TINY), rounds=1, state_dir=tmp_path,
                              show_progress=False)
    assert loop.restore() == 0
    assert not dead.exists() and alive.exists() and all(f.exists() for f in others)


def test_loop_state_dir_of_other_settings_labels_or_model_is_refused(tmp_path):
    kw = dict(strategy="random", kappa=4, rounds=1, mc_passes=1, max_epochs=1, seed=0, show_progress=False)
    ActiveLearningLoop(TinyPoolDM(), lambda s: XAVTNet(**TINY), state_dir=tmp_path, **kw).run()
    other = {**kw, "kappa": 3, "strategy": "entropy"}
    with pytest.raises(ValueError, match=r"^state_dir: .* other settings \(kappa 4 there, 3 here, strategy "
                                         r"'random' there, 'entropy' here\)"):
        ActiveLearningLoop(TinyPoolDM(), lambda s: XAVTNet(**TINY), state_dir=tmp_path, **other).run()
    with pytest.raises(ValueError, match="started from other labels"):
        ActiveLearningLoop(TinyPoolDM(seed=1), lambda s: XAVTNet(**TINY), state_dir=tmp_path, **kw).run()
    wider = {**TINY, "fc_dims": [16, 12]}
    with pytest.raises(ValueError, match="holds the weights of another model"):
        ActiveLearningLoop(TinyPoolDM(), lambda s: XAVTNet(**wider), state_dir=tmp_path, **kw).run()
    with np.load(tmp_path / "loop_state.npz", allow_pickle=False) as z:
        kept = {k: z[k] for k in z.files}
    np.savez(tmp_path / "loop_state.npz", **{**kept, "rng_before_query": np.zeros(3)})
    with pytest.raises(ValueError, match=r"state_dir: cannot read .*rng_before_query is not a state of "
                                         r"torch's generator: float64 \(3,\), need uint8"):
        ActiveLearningLoop(TinyPoolDM(), lambda s: XAVTNet(**TINY), state_dir=tmp_path, **kw).run()
    (tmp_path / "loop_state.npz").write_bytes(b"not a zip")
    with pytest.raises(ValueError, match="state_dir: cannot read .*loop_state.npz"):
        ActiveLearningLoop(TinyPoolDM(), lambda s: XAVTNet(**TINY), state_dir=tmp_path, **kw).run()
    with pytest.raises(ValueError, match="state_dir: .* is a file"):
        ActiveLearningLoop(TinyPoolDM(), lambda s: XAVTNet(**TINY), state_dir=tmp_path / "loop_state.npz")


def test_history_of_fewer_rounds_reads_the_first_rounds_of_a_longer_kept_loop(tmp_path):
    from vtlearn.active.learning_loop import LOOP_STATE_FILE, history_of_fewer_rounds

    def keep(rounds: int, queried: list[list[int]]) -> None:  # a kept state's arrays, as _save_state writes
        n = len(queried)
        np.savez(tmp_path / LOOP_STATE_FILE, settings=np.array([json.dumps({"rounds": rounds})]),
                 labelled=np.arange(3 + sum(map(len, queried))), round=np.arange(n),
                 n_labels=3 + 2 * np.arange(n), accuracy=np.linspace(0.5, 0.8, n),
                 queried=np.array([i for q in queried for i in q], dtype=np.int64),
                 queried_count=np.array([len(q) for q in queried]),
                 rng_before_query=torch.get_rng_state().numpy())

    def read(rounds: int):
        got = history_of_fewer_rounds(tmp_path, rounds)
        return None if got is None else [(h.round, h.n_labels, h.queried) for h in got]

    keep(3, [[5, 6], [7, 8], [9, 1], []])  # a 3-round loop that spent its rounds
    # a 1-round loop: rounds 0 and 1, whose last round queries nothing
    assert read(1) == [(0, 3, [5, 6]), (1, 5, [])]
    assert read(2) == [(0, 3, [5, 6]), (1, 5, [7, 8]), (2, 7, [])]
    assert read(3) is None and read(4) is None  # not fewer rounds: the loop's restore goes on from it
    keep(3, [[5, 6], [7, 8]])  # stopped after round 1, which queried: round 2 is not there
    assert read(2) is None and read(1) == [(0, 3, [5, 6]), (1, 5, [])]
    keep(3, [[5, 6], []])  # the pool ran out at round 1: a 2-round loop ends there too
    assert read(2) == [(0, 3, [5, 6]), (1, 5, [])]
    (tmp_path / LOOP_STATE_FILE).write_bytes(b"not a zip")  # restore says why; here it is no answer
    assert read(1) is None
    (tmp_path / LOOP_STATE_FILE).unlink()
    assert read(1) is None
    for bad in (-1, 1.5, "2"):
        with pytest.raises(ValueError, match="rounds"):
            history_of_fewer_rounds(tmp_path, bad)
