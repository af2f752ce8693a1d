"""LightningCLI entry point: ``python train.py fit --config configs/<model>.yaml``.

Any vtlearn LightningModule / LightningDataModule is selected by ``class_path`` in the config, so
``validate``, ``test`` and ``predict`` work the same way. ``--ckpt_path last`` resumes from ``last.ckpt``.

A config that cannot be parsed or built (a misspelt key, a value of the wrong type, a dataset directory
without a manifest, an argument out of range) ends with ``train.py: error: <argument>: <reason>`` and exit
code 2, not a usage dump or a traceback through jsonargparse. So does a ``--ckpt_path`` that is not a
readable Lightning checkpoint (missing, corrupted, NaN weights, another model's), and ``validate``, ``test``
or ``predict`` with ``--ckpt_path last`` when the config's checkpoint folder holds no ``last.ckpt`` (they
would otherwise score untrained weights). ``fit --ckpt_path last`` without one starts from scratch, as in
Lightning. Errors raised while training keep their traceback, except the model's and the datamodule's
disagreeing (a :class:`~vtlearn.validation.ConfigMismatchError` from ``setup``), reported the same way.

Checkpoints and the config: a checkpoint file's hyper-parameters replace the config's model arguments (as in
Lightning), and each one replaced is said in a ``train.py: note:`` line; a checkpoint of another model class
is refused. ``--ckpt_path last`` loads into the model the config builds: a ``last.ckpt`` whose weights do not
fit it (the config changed the architecture) is refused in one line naming the settings that differ.
``validate``/``test``/``predict`` without ``--ckpt_path`` run freshly initialised weights, and say so.
``predict`` writes its outputs to ``predictions.npz`` in the run's log folder
(:class:`~vtlearn.prediction_writer.NpzPredictionWriter`) unless the config has a prediction writer.

Logs: ``fit --ckpt_path last``, or ``--ckpt_path`` a checkpoint file of the same run (``epoch=3.ckpt``), logs
on into the version folder of the run it resumes (CSV and TensorBoard loggers; each checkpoint records their
versions, :class:`LogVersions`), ``metrics.csv``'s rows from before the checkpoint kept (those after it are
logged again by the epochs retrained; the file as it was stays beside it, ``metrics.before-step<N>.csv``;
TensorBoard hides the earlier run's events from the checkpoint's step on, by the writer's ``purge_step``);
a checkpoint that records no version in the logger's folder (written with another log folder) starts a new
version, and says so; a wandb logger starts a new run. A refused run leaves nothing on disk but an online
wandb run: the ``last`` checks come before the Trainer is built (and before its device banner),
``config.yaml`` is written once the model's ``setup`` has accepted the data, and a refusal there removes what
the loggers had started.
"""

from __future__ import annotations

import contextlib
import csv
import io
import os
import shutil
import sys
import warnings
from argparse import ArgumentError
from pathlib import Path

from lightning.pytorch.callbacks import Callback
from lightning.pytorch.cli import LightningCLI, SaveConfigCallback
from lightning.pytorch.loggers import CSVLogger, TensorBoardLogger, WandbLogger

from vtlearn.interrupts import import_trimesh, lightning_interrupt_as_keyboard_interrupt
from vtlearn.validation import ConfigMismatchError


class ConfigError(Exception):
    """A config whose model, data or trainer could not be instantiated; the message names the argument."""


def _reason(exc: BaseException) -> str:
    """The useful part of a parse or instantiation error, on one line. jsonargparse reports a subclass-mode
    argument that failed as "Does not validate against any of the Union subtypes", with one ``  - `` block
    per alternative; keep the blocks of the alternatives other than None (the vtlearn ``ValueError`` that
    names the argument, or the key and the type that did not parse), each joined into one line."""
    text = str(exc).strip()
    if "Errors:" not in text:
        return " ".join(ln.strip() for ln in text.splitlines() if ln.strip())
    first = text.splitlines()[0].strip()
    key = first[len('Parser key "'):].split('"', 1)[0] if first.startswith('Parser key "') else None
    blocks: list[list[str]] = []
    given = None
    for ln in text.split("Errors:", 1)[1].splitlines():
        s = ln.strip()
        if s.startswith("Given value:"):
            given = s[len("Given value:"):].strip()
        elif s.startswith("Given value"):
            continue
        elif s.startswith("- "):
            blocks.append([s[2:]])
        elif s and blocks:
            blocks[-1].append(s)
    kept = "; ".join(" ".join(b) for b in blocks if "NoneType" not in b[0]) or text
    if key and given is not None and len(given) < 80 and "Got value" not in kept and "NestedArg" not in given:
        kept += f" (got {given})"
    return f"{key}: {kept}" if key else kept


def _last_checkpoints(callbacks) -> tuple[list[Path], list[Path]]:
    """(folders searched, ``last*.ckpt`` files found) of the checkpoint callbacks among ``callbacks`` that
    name a ``dirpath``; a callback without one writes into the logger's version folder, which Lightning
    names only when training starts."""
    dirs = list(dict.fromkeys(Path(cb.dirpath) for cb in callbacks
                              if getattr(cb, "dirpath", None)))  # two callbacks may share one folder
    return dirs, [f for d in dirs if d.is_dir() for f in d.glob("last*.ckpt")]


def _version_key(logger) -> str:
    """A logger's entry in :class:`LogVersions`: its class and absolute root folder (a CSV and a TensorBoard
    logger may share one root and still have versions of their own; a relative root names another folder
    when train.py runs from another working directory)."""
    return f"{type(logger).__name__}:{os.path.abspath(logger.root_dir)}"


class LogVersions(Callback):
    """Records in each checkpoint the version folder of each CSV and TensorBoard logger, by the logger's class
    and root folder, so that ``fit --ckpt_path`` logs on into the folder of the run it resumes. The record is
    a key of the checkpoint (``checkpoint[LogVersions.key]``), not callback state: a plain Lightning Trainer
    resuming the checkpoint without this callback has no state of it to miss (it warned "callbacks used to
    create the checkpoint need to be provided")."""

    key = "train.py:log_versions"
    # checkpoints of 2026-12-04 kept the record as this callback's state under this name; with the name,
    # train.py resuming one has the callback its state belongs to (no "please add the callbacks" warning).
    # The state itself is empty now, and Lightning saves no empty state.
    state_key = "train.py:log_versions"

    def on_save_checkpoint(self, trainer, pl_module, checkpoint: dict) -> None:
        checkpoint[self.key] = {_version_key(lg): lg.version for lg in trainer.loggers
                                if isinstance(lg, (CSVLogger, TensorBoardLogger))}


class SayLastCheckpointOnInterrupt(Callback):
    """On a Ctrl-C during ``fit``, says on stderr where the last checkpoint is and that ``fit --ckpt_path
    last`` goes on from it (Lightning's own line only says it shuts down). Nothing is saved here: the epoch
    under way is lost, as ``last.ckpt`` is written at the end of each epoch."""

    def on_exception(self, trainer, pl_module, exception: BaseException) -> None:
        if not isinstance(exception, KeyboardInterrupt) or not trainer.is_global_zero:
            return
        last = next((cb.last_model_path for cb in trainer.checkpoint_callbacks
                     if getattr(cb, "last_model_path", "")), "")
        where = (f"the last checkpoint is {last}; fit --ckpt_path last goes on from it" if last else
                 "no checkpoint was written yet")
        print(f"train.py: stopped in epoch {trainer.current_epoch}; {where}", file=sys.stderr)


def _recorded_versions(checkpoint: dict) -> dict:
    """The logger versions ``checkpoint`` records (:class:`LogVersions`), by :func:`_version_key`; also from
    the callback state of the first checkpoints that recorded them, whose keys held the root folder as
    given (relative to the working directory)."""
    if isinstance(checkpoint.get(LogVersions.key), dict):
        return checkpoint[LogVersions.key]
    old = ((checkpoint.get("callbacks") or {}).get(LogVersions.state_key) or {}).get("versions") or {}
    return {f"{k.partition(':')[0]}:{os.path.abspath(k.partition(':')[2])}": v for k, v in old.items()}


def _rows_before(text: str, step: int) -> str:
    """The rows of a ``metrics.csv`` (its header kept) logged before global step ``step``: those after it
    were logged by epochs that the resumed run trains, and logs, again."""
    rows = list(csv.reader(text.splitlines()))
    if not rows or "step" not in rows[0]:
        return text
    k = rows[0].index("step")
    out = io.StringIO()
    csv.writer(out, lineterminator="\n").writerows(
        [rows[0]] + [r for r in rows[1:] if not (len(r) > k and r[k].isdigit() and int(r[k]) >= step)])
    return out.getvalue()


def _continue_versions(trainer, checkpoint: dict, kept: dict | None = None) -> list:
    """Points the trainer's CSV and TensorBoard loggers that the config gives no ``version`` at the version
    folders ``checkpoint`` records for them (:class:`LogVersions`); returns those it records none for (they
    start a new version). Lightning's CSV writer deletes the ``metrics.csv`` it finds there: its rows logged
    before the checkpoint's global step are put back (by the main process) and its columns kept, so the
    resumed epochs' rows follow them, each epoch once (also from an earlier epoch's checkpoint). The rows it
    drops are not lost: the whole file from before is kept beside it as ``metrics.before-step<N>.csv``.
    ``kept`` receives each ``metrics.csv`` path with its text from before and that copy, so that a refused
    run can put them back. A TensorBoard logger's writer gets the checkpoint's global step as its
    ``purge_step``: TensorBoard then hides the earlier run's events from that step on, so each step shows
    once, and their event files stay on disk (the resumed run's file ends in ``.resumed-step<N>``)."""
    versions = _recorded_versions(checkpoint)
    unrecorded = []
    for lg in trainer.loggers:
        if not isinstance(lg, (CSVLogger, TensorBoardLogger)) or lg._version is not None:
            continue
        if _version_key(lg) not in versions:
            unrecorded.append(lg)
            continue
        lg._version = versions[_version_key(lg)]  # the loggers take one only at construction
        step = int(checkpoint.get("global_step", 0))
        if isinstance(lg, TensorBoardLogger):
            # the SummaryWriter's purge_step: TensorBoard hides the events of the earlier run from this step
            # on (the epochs trained again), as metrics.csv drops their rows; a purge_step the config gives
            # is kept (LightningCLI passes the writer's unset arguments as None). The file name's suffix
            # keeps tensorboardX, which names an event file by the second and the host alone, from
            # overwriting the earlier run's file when both start within one second.
            if lg._experiment is None:
                if lg._kwargs.get("purge_step") is None:
                    lg._kwargs["purge_step"] = step
                if not lg._kwargs.get("filename_suffix"):
                    lg._kwargs["filename_suffix"] = f".resumed-step{step}"
            continue
        if not trainer.is_global_zero:
            continue
        path = Path(lg.log_dir) / "metrics.csv"
        text = path.read_text() if path.is_file() else ""
        rows = _rows_before(text, step) if text else ""
        copy = None
        if rows.count("\n") < text.count("\n"):  # rows of the epochs trained again: keep the file as it was
            copy = path.with_name(f"metrics.before-step{step}.csv")
            n = 1
            while copy.exists():
                n += 1
                copy = path.with_name(f"metrics.before-step{step}-{n}.csv")
            copy.write_text(text)
            print(f"train.py: note: {path}'s rows from step {step} on are logged again by the resumed run; "
                  f"the file as it was is kept in {copy.name}", file=sys.stderr)
        if text and kept is not None:
            kept[path] = (text, copy)
        with warnings.catch_warnings():  # "Previous log files ... will be deleted": they are put back below
            warnings.filterwarnings("ignore", message="Experiment logs directory")
            writer = lg.experiment
        if rows:
            path.write_text(rows)
            writer.metrics_keys = next(csv.reader(rows.splitlines()), [])
    return unrecorded


def _new_dirs(paths) -> list[Path]:
    """The folders among ``paths`` and their parents that do not exist yet, deepest first."""
    new = set()
    for p in paths:
        p = Path(p).absolute()
        while not p.exists():
            new.add(p)
            p = p.parent
    return sorted(new, key=lambda p: len(p.parts), reverse=True)


def _discard_offline_wandb_runs(loggers) -> None:
    """Ends the offline wandb runs of ``loggers`` and removes their folders, with the ``latest-run`` and
    debug-log links into them (wandb starts its run before the model's ``setup``; an online run is left to
    wandb)."""
    for lg in loggers:
        run = lg._experiment if isinstance(lg, WandbLogger) else None
        if run is None or getattr(run.settings, "mode", None) != "offline":
            continue
        folder = Path(run.settings.sync_dir)
        with contextlib.redirect_stdout(io.StringIO()), contextlib.redirect_stderr(io.StringIO()):
            run.finish()  # its "wandb sync <folder>" advice would name the folder removed here
        shutil.rmtree(folder, ignore_errors=True)
        for link in folder.parent.iterdir():  # only the links into the removed folder
            if not link.is_symlink():
                continue
            target = os.path.normpath(os.path.join(link.parent.absolute(), os.readlink(link)))
            if Path(target).is_relative_to(os.path.normpath(folder.absolute())):
                link.unlink()


class _SaveConfigWhenAccepted(SaveConfigCallback):
    """Writes ``config.yaml`` when the run starts, after the model's ``setup`` has accepted the data
    (Lightning writes it in the callbacks' ``setup``, before the model's, so a run refused there with a
    :class:`~vtlearn.validation.ConfigMismatchError` left one behind, or replaced an earlier run's)."""

    def setup(self, trainer, pl_module, stage: str) -> None:
        self._stage = stage

    def _save(self, trainer, pl_module) -> None:
        super().setup(trainer, pl_module, self._stage)

    on_fit_start = on_validation_start = on_test_start = on_predict_start = _save


def _read_checkpoint(path, label: str) -> dict:
    """The checkpoint at ``path`` (``weights_only=True``, finite weights), or a :class:`ConfigError` starting
    with ``label`` (``ckpt_path``)."""
    from vtlearn.models.actor import read_lightning_checkpoint

    try:
        return read_lightning_checkpoint(path)
    except ValueError as exc:
        raise ConfigError(f"{label}: {str(exc).removeprefix('ckpt: ')}") from None


class VtlearnCLI(LightningCLI):
    """LightningCLI that turns a config it cannot parse or build, or a checkpoint it cannot use, into a
    :class:`ConfigError`."""

    def parse_arguments(self, parser, args) -> None:
        try:
            super().parse_arguments(parser, args)
        except ArgumentError as exc:
            raise ConfigError(_reason(exc)) from None
        self._check_ckpt_path()

    def _check_ckpt_path(self) -> None:
        """A ``--ckpt_path`` file must be a readable Lightning checkpoint with finite weights (checked with
        ``weights_only=True`` before Lightning reads its hyper-parameters into the config)."""
        sub = self.config.get("subcommand")
        ckpt = self.config[sub].get("ckpt_path") if sub else None
        if ckpt is None or ckpt in ("last", "best", "hpc"):
            return
        if str(ckpt).startswith("registry") or "://" in str(ckpt):
            return  # Lightning's model registry and remote (fsspec) files: left to Lightning
        if not Path(ckpt).is_file():
            raise ConfigError(f"ckpt_path: no checkpoint file at {ckpt}")
        self._ckpt_data = _read_checkpoint(ckpt, "ckpt_path")

    def _model_args(self) -> dict:
        """The config's model arguments (``init_args``) as a plain dict."""
        model = self.config[self.config.subcommand].get("model")
        init = getattr(model, "init_args", None) if model is not None else None
        return dict(init.as_dict()) if init is not None else {}

    def _parse_ckpt_path(self) -> None:
        """Lightning merges a checkpoint file's hyper-parameters into the config here, its model class
        included. A checkpoint of another model class is refused (Lightning would build that model and fail
        deep inside training); hyper-parameters that replace the config's are said, one line each (they
        were replaced silently); another model's that fail to parse are one line, not a usage dump."""
        data = getattr(self, "_ckpt_data", None)
        sub = self.config.get("subcommand")
        ckpt = self.config[sub].get("ckpt_path") if sub else None
        before = {}
        if data is not None:
            theirs = (data.get("hyper_parameters") or {}).get("_class_path")
            model = self.config[sub].get("model")
            ours = getattr(model, "class_path", None)
            if theirs and ours and theirs != ours:
                raise ConfigError(f"ckpt_path: {ckpt} is a checkpoint of {theirs}; the config's model is "
                                  f"{ours} (give the matching config, or a checkpoint of this model)")
            before = self._model_args()
        try:
            super()._parse_ckpt_path()
        except ArgumentError as exc:
            raise ConfigError(
                f"ckpt_path: the hyper-parameters of {ckpt} do not fit the config's model (a checkpoint of "
                f"another model?): {_reason(exc)}"
            ) from None
        if data is not None:
            after = self._model_args()
            for key in after:
                if before.get(key) is not None and before[key] != after[key]:
                    print(f"train.py: note: model.{key}: {after[key]!r} from {ckpt} replaces the config's "
                          f"{before[key]!r} (a checkpoint keeps the hyper-parameters it was trained with)",
                          file=sys.stderr)

    def _check_last(self, subcommand: str, callbacks) -> tuple[Path, dict] | None:
        """``--ckpt_path last``, among the checkpoint folders of the trainer's ``callbacks``; returns the
        checkpoint found, if any, with its path. With no ``last.ckpt`` there, ``validate``, ``test`` and
        ``predict`` are refused (they would score untrained weights; ``fit`` starts from scratch, as in
        Lightning). Lightning
        loads the file into the model the config built, without its hyper-parameters: one of another class,
        or whose weights do not fit (the config changed the architecture), is refused in one line naming the
        settings that differ, instead of a state-dict traceback. Settings that differ without changing the
        weights' shapes apply, and are said."""
        if self.config_init[subcommand].get("ckpt_path") != "last":
            return None
        dirs, found = _last_checkpoints(callbacks)
        if not found:
            if dirs and subcommand != "fit":
                raise ConfigError(
                    f"ckpt_path: 'last' found no last.ckpt in {', '.join(map(str, dirs))}; {subcommand} "
                    "would score untrained weights (train first with fit, or pass a checkpoint file)"
                )
            return None
        path = max(found, key=lambda f: f.stat().st_mtime)
        data = _read_checkpoint(path, "ckpt_path: last")
        hp = dict(data.get("hyper_parameters") or {})
        theirs = hp.pop("_class_path", None)
        hp.pop("_instantiator", None)
        ours = f"{type(self.model).__module__}.{type(self.model).__qualname__}"
        if theirs and theirs != ours:
            raise ConfigError(f"ckpt_path: last ({path}) is a checkpoint of {theirs}; the config's model is "
                              f"{ours}")
        mine = dict(self.model.hparams)
        # a None here is a value the model fills in at setup (class names, the input normalisation)
        differ = {k: (v, mine[k]) for k, v in hp.items() if mine.get(k) is not None and mine[k] != v}
        shapes = {k: tuple(v.shape) for k, v in self.model.state_dict().items()}
        stored = {k: tuple(v.shape) for k, v in data["state_dict"].items()}
        said = ", ".join(f"{k}={a!r} there, {b!r} here" for k, (a, b) in differ.items())
        if shapes != stored:
            raise ConfigError(f"ckpt_path: last ({path}) does not fit the config's model"
                              f"{': ' + said if said else ''}; resume with the settings it was trained with, "
                              "or train from scratch in another checkpoint folder")
        groups = (data.get("optimizer_states") or [{}])[0].get("param_groups") or [{}]
        restored = set(groups[0]) if subcommand == "fit" else set()  # fit restores the optimizer's state
        for k, (a, b) in differ.items():
            if k in restored:
                print(f"train.py: note: model.{k}: {a!r} from the optimizer state resumed from {path} "
                      f"applies, not the config's {b!r} (the checkpoint records the config's)",
                      file=sys.stderr)
            else:
                print(f"train.py: note: model.{k}: the config's {b!r} applies on resuming from {path} "
                      f"(trained with {a!r})", file=sys.stderr)
        return path, data

    def instantiate_classes(self) -> None:
        try:
            super().instantiate_classes()
        except (ValueError, TypeError, FileNotFoundError) as exc:
            raise ConfigError(_reason(exc)) from exc

    def instantiate_trainer(self, **kwargs):
        """The ``--ckpt_path last`` checks, and the note that ``validate``/``test``/``predict`` without
        ``--ckpt_path`` run the config's freshly initialised weights, come before the Trainer is built, so a
        refusal is not printed below its device banner. ``fit`` resuming from a checkpoint (``last`` or a
        file) that records its loggers' versions (:class:`LogVersions`) logs on into those version folders;
        one that records none for a logger (another run's, or another log folder's) starts a new version,
        and says so."""
        sub = self.subcommand
        if sub is None:
            return super().instantiate_trainer(**kwargs)
        callbacks = {**self._get(self.config_init, "trainer", default={}), **kwargs}.get("callbacks") or []
        resumed = self._check_last(sub, callbacks if isinstance(callbacks, list) else [callbacks])
        if resumed is None and getattr(self, "_ckpt_data", None) is not None:
            resumed = self.config_init[sub]["ckpt_path"], self._ckpt_data
        if sub != "fit" and self.config_init[sub].get("ckpt_path") is None:
            print(f"train.py: note: {sub} without --ckpt_path runs the config's freshly initialised weights; "
                  "pass --ckpt_path last (or a checkpoint file) for a trained model", file=sys.stderr)
        trainer = super().instantiate_trainer(**kwargs)
        if sub == "fit":
            self._kept_logs: dict = {}
            unrecorded = [] if resumed is None else _continue_versions(trainer, resumed[1], self._kept_logs)
            if unrecorded:
                logs = ", ".join(f"{type(lg).__name__} in {lg.root_dir}" for lg in unrecorded)
                print(f"train.py: note: {resumed[0]} records no log version for {logs} (it was written with "
                      f"another log folder); logging into a new version folder", file=sys.stderr)
            trainer.callbacks += [LogVersions(), SayLastCheckpointOnInterrupt()]
        return trainer

    def _run_subcommand(self, subcommand: str) -> None:
        """A run refused by the model's ``setup`` (a :class:`~vtlearn.validation.ConfigMismatchError`) leaves
        nothing behind: the loggers start before it; their offline wandb runs and the folders this run made,
        now empty, are removed, and a resumed ``metrics.csv`` gets back the rows it had (those after the
        checkpoint were dropped to be logged again)."""
        loggers = self.trainer.loggers
        logs = [self.trainer.log_dir] + [lg.log_dir for lg in loggers
                                         if isinstance(lg, (CSVLogger, TensorBoardLogger))]
        logs += [Path(lg.save_dir or ".") / "wandb" for lg in loggers if isinstance(lg, WandbLogger)]
        made = _new_dirs(d for d in logs if d)
        try:
            super()._run_subcommand(subcommand)
        except ConfigMismatchError:
            if self.trainer.is_global_zero:  # one process cleans up; the others may still be writing
                _discard_offline_wandb_runs(loggers)
                for path, (text, copy) in getattr(self, "_kept_logs", {}).items():
                    path.write_text(text)
                    if copy is not None:
                        copy.unlink(missing_ok=True)
                for d in made:
                    with contextlib.suppress(OSError):  # not empty, or gone already
                        d.rmdir()
            raise

    def after_fit(self) -> None:
        """Says where the run's checkpoints are: each checkpoint callback's last file and, when it monitors a
        metric, its best one with the value, on stdout, once training has ended."""
        if not self.trainer.is_global_zero:
            return
        for cb in self.trainer.checkpoint_callbacks:
            said = []
            if getattr(cb, "last_model_path", ""):
                said.append(f"last {cb.last_model_path}")
            # without a monitor, Lightning's "best" is only the newest file: the last one says it
            if cb.monitor and getattr(cb, "best_model_path", ""):
                score = cb.best_model_score
                value = f" ({cb.monitor} {float(score):.4g})" if score is not None else ""
                said.append(f"best {cb.best_model_path}{value}")
            if said:
                print(f"train.py: checkpoints: {'; '.join(said)}")

    def before_predict(self) -> None:
        from lightning.pytorch.callbacks import BasePredictionWriter

        from vtlearn.prediction_writer import NpzPredictionWriter

        if not any(isinstance(cb, BasePredictionWriter) for cb in self.trainer.callbacks):
            self.trainer.callbacks.append(NpzPredictionWriter())  # predictions.npz in the run's log folder


def cli_main(args=None) -> LightningCLI:
    os.environ.setdefault("WANDB_MODE", "offline")
    return VtlearnCLI(
        subclass_mode_model=True,
        subclass_mode_data=True,
        save_config_callback=_SaveConfigWhenAccepted,
        save_config_kwargs={"overwrite": True},
        # parse errors raise, and main() prints them on one line; no --trainer.max_epoch for max_epochs
        parser_kwargs={"exit_on_error": False, "allow_abbrev": False},
        args=args,
    )


def main(args=None) -> int:
    try:
        # a config's class_path may name any module, and trimesh swallows a Ctrl-C during its import
        # (vtlearn.interrupts); imported here first, with Ctrl-C held back, it cannot be imported later
        import_trimesh()
    except KeyboardInterrupt:
        print("train.py: interrupted", file=sys.stderr)
        return 130
    try:
        # Lightning answers a Ctrl-C during training with sys.exit(1): it ends here as any other Ctrl-C
        with lightning_interrupt_as_keyboard_interrupt():
            cli_main(args)
    except (ConfigError, ConfigMismatchError) as exc:
        print(f"train.py: error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("train.py: interrupted", file=sys.stderr)
        return 130
    return 0


if __name__ == "__main__":
    sys.exit(main())
