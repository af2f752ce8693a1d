"""Deep active visual object learning with a simulated oracle, thesis ch.7, section 7.2.2 and the
visual-learning part of Algorithm 5 (eq. 7.3-7.4 for the query).

Loop (Algorithm 5, "active visual learning"):

1. start from ``n₀`` randomly labelled clouds (``ActivePoolDataModule(initial_labels=n₀, seed=...)``);
2. train the classifier on the labelled set with a Lightning ``Trainer``;
3. score the unlabelled pool (MC-dropout entropy, BALD, or random) and query the top κ;
   the oracle is simulated: ``datamodule.query(indices)`` reveals the dataset's labels;
4. retrain and repeat until the budget of rounds is spent.

Retraining (step 4) is **from scratch by default**: each round builds a fresh model from
``model_factory`` with a round-specific seed, as in Gal et al. (2017), so the accuracy at ``n`` labels
does not depend on the order the labels arrived in and strategies are compared fairly. With
``warm_start=True`` the previous round's weights are kept and fine-tuned (a fresh optimiser each
round); it is cheaper but the curve then mixes label count with total training time.

A loop given a ``state_dir`` keeps its state there after every round (:meth:`ActiveLearningLoop.restore`):
a loop stopped part-way (Ctrl-C, a crash) and built again with the same settings goes on from its last
finished round instead of training every round again, and gives the history an unstopped run gives.

Evaluation after each round is ``trainer.test`` on ``datamodule.test_dataloader()``. The Table 7.1
analogue (:func:`labels_to_reach`) gives, per strategy, the number of labels at which the relative
error ``(acc_full − acc) / acc_full`` against a model trained on the whole pool first falls to 10 %,
5 %, 3 % and 2 %.
"""

from __future__ import annotations

import json
import logging
import math
from collections.abc import Callable, Sequence
from dataclasses import asdict, dataclass, field
from pathlib import Path

import lightning as L
import numpy as np
import torch
from tqdm.auto import tqdm

from vtlearn.active.mc_dropout import QUERY_STRATEGIES, score_pool, select_power, select_top_k, split_strategy
from vtlearn.bench_utils import wilcoxon_p
from vtlearn.validation import as_int, as_real

__all__ = ["RoundResult", "ActiveLearningLoop", "epochs_for", "train_and_test", "labels_to_reach",
           "bootstrap_label_ratio", "history_of_fewer_rounds", "LOOP_STATE_FILE"]

log = logging.getLogger(__name__)

#: the file, in an :class:`ActiveLearningLoop`'s ``state_dir``, that holds its state after its last round
LOOP_STATE_FILE = "loop_state.npz"
#: the prefix of the model's weights in that file
_WEIGHTS = "model/"


@dataclass
class RoundResult:
    round: int
    n_labels: int
    accuracy: float
    queried: list[int] = field(default_factory=list)


def _trainer(max_epochs: int, **overrides) -> L.Trainer:
    kwargs = dict(
        max_epochs=max_epochs, accelerator="cpu", devices=1, logger=False, enable_checkpointing=False,
        enable_progress_bar=False, enable_model_summary=False, num_sanity_val_steps=0,
    )
    kwargs.update(overrides)
    return L.Trainer(**kwargs)


def epochs_for(max_epochs: int, min_steps: int, steps_per_epoch: int) -> int:
    """``max_epochs``, raised so that training lasts at least ``min_steps`` optimiser steps."""
    return max(max_epochs, math.ceil(min_steps / max(1, steps_per_epoch)))


def train_and_test(
    model: L.LightningModule, train_loader, test_loader, max_epochs: int, min_steps: int = 0,
    train_steps: int = 0, **trainer_kwargs,
) -> float:
    """Fit ``model`` on ``train_loader`` (no validation) and return ``test/acc`` on ``test_loader``.

    The run lasts ``max_epochs`` epochs, or more if that would be fewer than ``min_steps`` optimiser
    steps: small labelled sets otherwise get only a handful of updates and stay near chance. With
    ``train_steps > 0`` it lasts exactly ``train_steps`` optimiser steps whatever the set's size (the
    equal-budget protocol: every round, and the full-pool reference, train equally long), and
    ``max_epochs``/``min_steps`` are ignored.
    """
    train_steps = as_int(train_steps, "train_steps", minimum=0)
    if train_steps:
        epochs = math.ceil(train_steps / max(1, len(train_loader)))
        trainer_kwargs = {**trainer_kwargs, "max_steps": int(train_steps)}
    else:
        epochs = epochs_for(max_epochs, min_steps, len(train_loader))
    trainer = _trainer(epochs, limit_val_batches=0, **trainer_kwargs)
    trainer.fit(model, train_dataloaders=train_loader)
    metrics = trainer.test(model, dataloaders=test_loader, verbose=False)
    if not metrics or "test/acc" not in metrics[0]:
        logged = sorted(metrics[0]) if metrics else []
        raise ValueError(f"model: its test_step must log 'test/acc' (the accuracy the loop records, e.g. "
                         f"self.log('test/acc', acc)); it logged {logged}")
    return float(metrics[0]["test/acc"])


class ActiveLearningLoop:
    """Pool-based active learning driver around Lightning.

    Args:
        datamodule: an ``ActivePoolDataModule`` (``train_dataloader`` over the labelled set,
            ``unlabelled_dataloader`` yielding ``{"points", "lengths", "index"}``, ``query(indices)``,
            ``labelled_indices``, ``unlabelled_indices``, ``test_dataloader``). It is mutated.
        model_factory: ``seed -> LightningModule`` with dropout layers (e.g. an ``XAVTNet``). A model of
            your own needs three things: ``forward(points, lengths)`` returning class logits ``(B, K)`` (or
            an object with a ``.logits`` attribute), dropout modules that MC-dropout switches on
            (:func:`vtlearn.active.mc_dropout.mc_dropout_probs`), and a ``test_step`` that logs
            ``"test/acc"``, the accuracy each round records.
        strategy: "entropy" (thesis), "bald", "random", or "power_entropy" / "power_bald" (draw κ
            samples ∝ score^``power_beta`` instead of the top κ; see ``vtlearn.active.mc_dropout``).
        kappa: κ, clouds queried per round.
        rounds: number of query rounds (the loop trains ``rounds + 1`` times).
        mc_passes: T of eq. 7.3.
        max_epochs: epochs per (re)training.
        min_steps: at least this many optimiser steps per (re)training (more epochs on small sets).
        train_steps: if > 0, every (re)training runs exactly this many optimiser steps instead
            (``max_epochs`` and ``min_steps`` are then unused), so that the accuracy at ``n`` labels
            is not confounded with training length.
        warm_start: keep the weights between rounds instead of retraining from scratch.
        power_beta: β of the power strategies.
        seed: base seed; round r trains with ``seed + r``.
        trainer_kwargs: extra ``Trainer`` arguments (e.g. ``limit_train_batches``).
        state_dir: a folder in which the loop keeps its state after every round (:meth:`restore`), so
            that a stopped loop built again with the same arguments goes on from its last finished round,
            and a finished one built with more ``rounds`` goes on to them; ``None`` keeps nothing.
    """

    def __init__(
        self,
        datamodule,
        model_factory: Callable[[int], L.LightningModule],
        strategy: str = "entropy",
        kappa: int = 10,
        rounds: int = 5,
        mc_passes: int = 20,
        max_epochs: int = 10,
        min_steps: int = 0,
        train_steps: int = 0,
        warm_start: bool = False,
        power_beta: float = 1.0,
        seed: int = 0,
        trainer_kwargs: dict | None = None,
        show_progress: bool = True,
        state_dir: str | Path | None = None,
    ) -> None:
        if strategy not in QUERY_STRATEGIES:
            raise ValueError(f"strategy must be one of {QUERY_STRATEGIES}, got {strategy!r}")
        power_beta = as_real(power_beta, "power_beta", low=0.0)
        self.dm = datamodule
        if isinstance(model_factory, torch.nn.Module) or not callable(model_factory):
            raise ValueError(f"model_factory: need a callable seed -> LightningModule (e.g. lambda seed: "
                             f"XAVTNet(...)), got {type(model_factory).__name__}")
        self.model_factory = model_factory
        self.strategy = strategy
        self.kappa, self.rounds = as_int(kappa, "kappa"), as_int(rounds, "rounds", minimum=0)
        self.train_steps = as_int(train_steps, "train_steps", minimum=0)
        self.mc_passes, self.max_epochs = as_int(mc_passes, "mc_passes"), as_int(max_epochs, "max_epochs")
        self.min_steps = as_int(min_steps, "min_steps", minimum=0)
        self.warm_start, self.seed = bool(warm_start), int(seed)
        self.power_beta = float(power_beta)
        self.trainer_kwargs = dict(trainer_kwargs or {})
        self.show_progress = show_progress
        self.state_dir = None if state_dir is None else Path(state_dir)
        if self.state_dir is not None and self.state_dir.exists() and not self.state_dir.is_dir():
            raise ValueError(f"state_dir: {self.state_dir} is a file; the loop keeps its state in a folder")
        self.history: list[RoundResult] = []
        self.model: L.LightningModule | None = None
        self._restored = False
        self._rng_before_query: torch.Tensor | None = None  # set by each training (run) or by restore

    def _query(self, round_idx: int) -> list[int]:
        unlabelled = list(self.dm.unlabelled_indices)
        k = min(self.kappa, len(unlabelled))
        gen = torch.Generator().manual_seed(self.seed * 7919 + round_idx)
        score, selection = split_strategy(self.strategy)
        idx, scores = score_pool(self.model, self.dm.unlabelled_dataloader(), score,
                                 self.mc_passes, generator=gen)
        pick = (select_power(scores, k, self.power_beta, generator=gen) if selection == "power"
                else select_top_k(scores, k))
        chosen = idx[pick].tolist()
        self.dm.query(chosen)
        return [int(i) for i in chosen]

    def run(self) -> list[RoundResult]:
        """Train, test and query round after round (Algorithm 5) and return the history. With a
        ``state_dir`` the loop first goes on from the state kept there (:meth:`restore`), and keeps its state
        after every round; a loop whose rounds are all kept trains nothing."""
        start = self.restore()
        bar = tqdm(total=self.rounds + 1, initial=start, desc=f"active learning [{self.strategy}]",
                   disable=not self.show_progress)
        for r in range(start, self.rounds + 1):
            if self._finished():
                break
            L.seed_everything(self.seed + r, verbose=False)
            if self.model is None or not self.warm_start:
                self.model = self.model_factory(self.seed + r)
            acc = train_and_test(self.model, self.dm.train_dataloader(), self.dm.test_dataloader(),
                                 self.max_epochs, self.min_steps, self.train_steps, **self.trainer_kwargs)
            # the query's MC-dropout masks come from the global generator as training left it; kept with
            # the state, so that a loop given more rounds later queries this round as an unstopped run does
            self._rng_before_query = torch.get_rng_state()
            result = RoundResult(r, len(self.dm.labelled_indices), acc)
            self.history.append(result)
            bar.update()
            bar.set_postfix(labels=result.n_labels, acc=f"{acc:.3f}")
            if r < self.rounds and len(self.dm.unlabelled_indices) > 0:
                result.queried = self._query(r)
            elif r < self.rounds:
                log.info("pool exhausted after %d rounds", r)
            self._save_state()
        bar.close()
        return self.history

    def _finished(self) -> bool:
        """Whether the rounds are spent, or the last round found the pool empty (nothing queried)."""
        return bool(self.history) and (self.history[-1].round >= self.rounds or not self.history[-1].queried)

    def _settings(self) -> dict:
        """What a kept state must have been made with to be gone on from."""
        return {"strategy": self.strategy, "kappa": self.kappa, "rounds": self.rounds,
                "mc_passes": self.mc_passes, "max_epochs": self.max_epochs, "min_steps": self.min_steps,
                "train_steps": self.train_steps, "warm_start": self.warm_start, "power_beta": self.power_beta,
                "seed": self.seed}

    def _save_state(self) -> None:
        """Keep the history, the labelled set and the last model's weights in ``state_dir`` (one ``.npz``
        written atomically, loaded with ``allow_pickle=False``), so a kill leaves the previous round's."""
        if self.state_dir is None:
            return
        from vtlearn.io import atomic_write_npz

        h = self.history
        weights = {_WEIGHTS + k: v.detach().cpu().numpy() for k, v in self.model.state_dict().items()}
        settings = json.dumps(self._settings(), sort_keys=True)
        atomic_write_npz(
            self.state_dir / LOOP_STATE_FILE, settings=np.array([settings]),
            labelled=np.asarray(self.dm.labelled_indices, dtype=np.int64),
            round=np.array([x.round for x in h], dtype=np.int64),
            n_labels=np.array([x.n_labels for x in h], dtype=np.int64),
            accuracy=np.array([x.accuracy for x in h], dtype=np.float64),
            queried=np.array([q for x in h for q in x.queried], dtype=np.int64),
            queried_count=np.array([len(x.queried) for x in h], dtype=np.int64),
            rng_before_query=self._rng_before_query.numpy(), **weights)

    def restore(self) -> int:
        """Go on from the state kept in ``state_dir`` by an earlier run of this loop, and return the number
        of rounds it holds (0 when there is none, or without a ``state_dir``). Only the first call reads the
        state; a later one changes nothing and returns the number of rounds the loop holds by then.

        The history comes back as it was; the labelled set by querying the datamodule for the clouds the
        kept rounds queried (its first labels must be those the kept run started from); the model is built
        by ``model_factory`` and given the last round's weights. Every round seeds the random number
        generators anew (``seed + r``), so the rounds still to run give what they give in an unstopped run.

        A loop built with more ``rounds`` than the state was kept with goes on to them: if the kept loop
        spent its rounds (rather than its pool), its last round queries now, with the restored weights and
        the state of torch's generator that its training left (kept for this, since the MC-dropout masks
        are drawn from it), as a run with these rounds would have, and the state is kept with the new
        ``rounds``.

        Raises:
            ValueError: the state was kept with other settings (more ``rounds`` included), from another
                starting set of labels, or for a model with other weights (naming what differs), or the
                file cannot be read.
        """
        path = None if self.state_dir is None else self.state_dir / LOOP_STATE_FILE
        if not self._restored and path is not None:
            from vtlearn.io import remove_stale_temporaries

            for tmp in remove_stale_temporaries(path):  # left by a loop killed while writing its state
                log.info("active learning: removed %s, a partial state of a stopped process", tmp)
        if self._restored or path is None or not path.is_file():
            self._restored = True
            return len(self.history)
        state, kept, history = _read_state(path)
        now = self._settings()
        kept_rounds = kept.get("rounds")
        more_rounds = isinstance(kept_rounds, int) and kept_rounds < self.rounds
        differ = sorted(k for k in now.keys() | kept.keys()
                        if now.get(k) != kept.get(k) and not (k == "rounds" and more_rounds))
        if differ:
            fewer = ("; a loop goes on to more rounds than it kept, not to fewer" if "rounds" in differ
                     and isinstance(kept_rounds, int) else "")
            raise ValueError(f"state_dir: {path} was kept by a loop with other settings ("
                             + ", ".join(f"{k} {kept.get(k)!r} there, {now.get(k)!r} here" for k in differ)
                             + f"{fewer}); remove it or choose another state_dir")
        first = sorted(set(state["labelled"].tolist()) - set(state["queried"].tolist()))
        if sorted(int(i) for i in self.dm.labelled_indices) != first:
            raise ValueError(f"state_dir: {path} was kept by a loop that started from other labels; the "
                             "datamodule must start from the same initial labels (initial_labels, seed)")
        last = int(state["round"][-1])
        model = self.model_factory(self.seed + last)
        weights = {k[len(_WEIGHTS):]: torch.from_numpy(v) for k, v in state.items() if k.startswith(_WEIGHTS)}
        try:
            model.load_state_dict(weights)
        except RuntimeError as exc:
            raise ValueError(f"state_dir: {path} holds the weights of another model ({exc})") from None
        if len(state["queried"]):
            self.dm.query([int(i) for i in state["queried"]])
        self.model = model
        self.history = history
        self._restored = True
        log.info("active learning [%s]: %d rounds restored from %s", self.strategy, len(self.history), path)
        self._rng_before_query = torch.from_numpy(state["rng_before_query"])
        last_round = self.history[-1]
        if more_rounds and last_round.round == kept_rounds and not last_round.queried:
            # the kept loop spent its rounds (it did not run out of pool): its last round queries now, as
            # it would have with these rounds, and the state is kept with them
            if len(self.dm.unlabelled_indices) > 0:
                with torch.random.fork_rng(devices=[]):
                    torch.set_rng_state(self._rng_before_query)
                    last_round.queried = self._query(last_round.round)
            self._save_state()
        return len(self.history)

    def history_dicts(self) -> list[dict]:
        return [asdict(h) for h in self.history]


def _read_state(path: Path) -> tuple[dict[str, np.ndarray], dict, list[RoundResult]]:
    """The arrays of the loop state kept in ``path``, its settings and its rounds; a ValueError naming the
    file when it cannot be read (not a zip, a key missing, settings that are not a JSON object, a
    generator state of another shape) or its rounds do not add up."""
    try:
        with np.load(path, allow_pickle=False) as z:
            state = {k: z[k] for k in z.files}
        kept = json.loads(str(state["settings"][0]))
        if not isinstance(kept, dict):
            raise ValueError(f"settings are {type(kept).__name__}, not a JSON object")
        rng = state["rng_before_query"]
        want = tuple(torch.get_rng_state().shape)
        if rng.dtype != np.uint8 or rng.shape != want:
            raise ValueError(f"rng_before_query is not a state of torch's generator: {rng.dtype} "
                             f"{rng.shape}, need uint8 {want}")
        counts = state["queried_count"]
        queried = np.split(state["queried"], np.cumsum(counts)[:-1]) if len(counts) else []
        history = [RoundResult(int(r), int(n), float(a), [int(i) for i in q]) for r, n, a, q in
                   zip(state["round"], state["n_labels"], state["accuracy"], queried, strict=True)]
    except (OSError, ValueError, KeyError, IndexError) as exc:  # JSONDecodeError is a ValueError
        raise ValueError(f"state_dir: cannot read {path} ({exc}); remove it to start the loop again") \
            from None
    return state, kept, history


def history_of_fewer_rounds(state_dir, rounds: int) -> list[RoundResult] | None:
    """The history a loop of ``rounds`` rounds gives, read off the state of a longer loop kept in
    ``state_dir`` without training: every round seeds itself (``seed + r``) and queries from what the rounds
    before it left, so the first ``rounds + 1`` rounds of a longer run are those of the shorter run, except
    that the shorter run's last round queries nothing.

    None when ``state_dir`` holds no state, one of ``rounds`` rounds or fewer, one that cannot be read (the
    loop's :meth:`ActiveLearningLoop.restore` then says why) or one stopped before its round ``rounds`` with
    its pool not spent. The other settings are not compared: the caller keys the folder by them.
    """
    rounds = as_int(rounds, "rounds", minimum=0)
    path = Path(state_dir) / LOOP_STATE_FILE
    if not path.is_file():
        return None
    try:
        _, kept, history = _read_state(path)
    except ValueError:
        return None
    kept_rounds = kept.get("rounds")
    if not (isinstance(kept_rounds, int) and kept_rounds > rounds and history):
        return None
    shorter = [h for h in history if h.round <= rounds]
    if shorter[-1].round < rounds and shorter[-1].queried:  # neither at round `rounds` nor out of pool
        return None
    if shorter[-1].round == rounds:
        shorter[-1].queried = []
    return shorter


def labels_to_reach(
    n_labels: Sequence[int],
    accuracy: Sequence[float],
    full_accuracy: float,
    thresholds: Sequence[float] = (0.10, 0.05, 0.03, 0.02),
    sustained: bool = False,
) -> dict[float, int | None]:
    """Table 7.1 analogue: the first label count whose relative error ``(full − acc)/full`` ≤ each
    threshold, or ``None`` if the curve never gets there.

    With ``sustained=True`` it is the first label count from which the curve *stays* within the
    threshold up to its last point: a stricter reading for noisy curves, where a single lucky round
    would otherwise count.

    Shapes:
        n_labels (R,) increasing, accuracy (R,) -> {threshold: labels or None}
    """
    if len(n_labels) != len(accuracy) or len(n_labels) == 0:
        raise ValueError(f"n_labels and accuracy must be non-empty and equal length, got "
                         f"{len(n_labels)} and {len(accuracy)}")
    full_accuracy = as_real(full_accuracy, "full_accuracy", low=0.0, open_low=True)
    out: dict[float, int | None] = {}
    within = [[(full_accuracy - a) / full_accuracy <= t for a in accuracy] for t in thresholds]
    for t, ok in zip(thresholds, within, strict=True):
        if sustained:
            out[t] = next((int(n) for i, n in enumerate(n_labels) if all(ok[i:])), None)
        else:
            out[t] = next((int(n) for n, w in zip(n_labels, ok, strict=True) if w), None)
    return out


def _first_within(within: np.ndarray, sustained: bool) -> np.ndarray:
    """Index of the first True per row (the first from which every later one is True when
    ``sustained``), or -1 where there is none. Shapes: within (B, R) bool -> (B,) int."""
    if sustained:
        within = np.flip(np.logical_and.accumulate(np.flip(within, 1), axis=1), 1)
    first = within.argmax(axis=1)
    return np.where(within.any(axis=1), first, -1)


def bootstrap_label_ratio(
    n_labels: Sequence[int],
    accuracy: np.ndarray,
    baseline: np.ndarray,
    full_accuracy: Sequence[float],
    threshold: float = 0.02,
    target: float = 0.65,
    n_boot: int = 2000,
    sustained: bool = False,
    seed: int = 0,
) -> dict:
    """Seed bootstrap of the Table 7.1 ratio: the labels a strategy needs to come within ``threshold``
    relative error of the full-pool model, over the labels the baseline (random) needs.

    The table reads the first point of a mean curve over a few seeds that crosses a line, so one lucky
    seed can move the ratio by a whole κ step. Here the seeds are drawn with replacement ``n_boot``
    times; each draw takes the same seeds for the strategy, the baseline and the full-pool models (a
    seed's runs share their n₀ labels), recomputes the three means and reads
    :func:`labels_to_reach` again. A draw in which the strategy never reaches the line counts as an
    infinite ratio; one in which the baseline never does is undefined and is left out of the quantiles.
    The quantiles are empirical (no interpolation), since the ratios take a few discrete values.

    Shapes:
        n_labels (R,), accuracy (S, R), baseline (S, R), full_accuracy (S,) -> {"ratio" (all seeds),
        "median", "ci90" ([5 %, 95 %] quantiles), "p_target" (share of draws with ratio ≤ ``target``),
        "never" (share of draws where the strategy never reaches the line), "undefined" (share where the
        baseline never does), "n_boot"}. A ratio or quantile that is infinite or undefined is None.
    """
    a, b = np.asarray(accuracy, dtype=float), np.asarray(baseline, dtype=float)
    full = np.asarray(full_accuracy, dtype=float)
    n = np.asarray(n_labels, dtype=float)
    if a.ndim != 2 or a.shape != b.shape or a.shape[1] != n.shape[0] or a.shape[1] == 0:
        raise ValueError(f"accuracy and baseline must both be (seeds, rounds) with rounds = len(n_labels) "
                         f"= {n.shape[0]}, got {a.shape} and {b.shape}")
    if full.shape != (a.shape[0],):
        raise ValueError(f"full_accuracy must have one value per seed ({a.shape[0]}), got shape {full.shape}")
    if not (np.isfinite(a).all() and np.isfinite(b).all() and np.isfinite(full).all()) or (full <= 0).any():
        raise ValueError("accuracy, baseline and full_accuracy must be finite, and full_accuracy > 0")
    threshold = as_real(threshold, "threshold", low=0.0, high=1.0, open_high=True)
    n_boot = as_int(n_boot, "n_boot")

    def ratios(idx: np.ndarray) -> np.ndarray:  # idx (B, S) seed draws -> (B,) ratios (inf, nan)
        f = full[idx].mean(1, keepdims=True)
        ia = _first_within((f - a[idx].mean(1)) / f <= threshold, sustained)
        ib = _first_within((f - b[idx].mean(1)) / f <= threshold, sustained)
        out = np.where(ia >= 0, n[ia] / n[np.maximum(ib, 0)], np.inf)
        return np.where(ib >= 0, out, np.nan)

    point = ratios(np.arange(a.shape[0])[None])[0]
    draws = np.random.default_rng(seed).integers(0, a.shape[0], size=(n_boot, a.shape[0]))
    r = ratios(draws)
    defined = r[~np.isnan(r)]
    lo, med, hi = (np.quantile(defined, [0.05, 0.5, 0.95], method="inverted_cdf") if defined.size
                   else (np.nan,) * 3)

    def as_float(v: float) -> float | None:  # JSON has no inf or nan
        return float(v) if np.isfinite(v) else None

    return {"ratio": as_float(point), "median": as_float(med), "ci90": [as_float(lo), as_float(hi)],
            "p_target": float((r <= target).mean()), "never": float(np.isinf(r).mean()),
            "undefined": float(np.isnan(r).mean()), "n_boot": int(n_boot)}


def paired_advantage(accuracy: np.ndarray, baseline: np.ndarray, skip_first: bool = True) -> dict:
    """How far a query strategy is ahead of a baseline (random) on the same seeds and rounds.

    The Table 7.1 columns read one point of a noisy mean curve; this uses every (seed, round) pair.
    Both runs of a seed start from the same n₀ random labels, so round 0 is identical and is skipped
    by default. The p-value is the two-sided Wilcoxon signed-rank test of the paired differences
    (``None`` when every difference is zero or there is only one pair).

    Shapes:
        accuracy (S, R), baseline (S, R) in [0, 1] -> {"mean_diff", "std_diff" (points),
        "ahead", "pairs", "wilcoxon_p"}
    """
    a, b = np.asarray(accuracy, dtype=float), np.asarray(baseline, dtype=float)
    if a.ndim != 2 or a.shape != b.shape:
        raise ValueError(f"accuracy and baseline must both be (seeds, rounds) of the same shape, got "
                         f"{a.shape} and {b.shape}")
    if skip_first:
        a, b = a[:, 1:], b[:, 1:]
    if a.size == 0:
        raise ValueError("accuracy: need at least one round after the first to compare")
    if not (np.isfinite(a).all() and np.isfinite(b).all()):
        raise ValueError("accuracy and baseline must be finite")
    diff = 100.0 * (a - b).ravel()
    return {"mean_diff": float(diff.mean()), "std_diff": float(diff.std()), "ahead": int((diff > 0).sum()),
            "pairs": int(diff.size), "wilcoxon_p": wilcoxon_p(diff)}
