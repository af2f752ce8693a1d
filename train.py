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
"""

from __future__ import annotations

import os
import sys
from argparse import ArgumentError
from pathlib import Path

from lightning.pytorch.cli import LightningCLI

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


def _last_checkpoints(trainer) -> tuple[list[Path], list[Path]]:
    """(folders searched, ``last*.ckpt`` files found) of the trainer's checkpoint callbacks that name a
    ``dirpath``; a callback without one writes into the logger's new version folder, which cannot hold a
    checkpoint yet."""
    dirs = list(dict.fromkeys(Path(cb.dirpath) for cb in trainer.checkpoint_callbacks
                              if getattr(cb, "dirpath", None)))  # two callbacks may share one folder
    return dirs, [f for d in dirs if d.is_dir() for f in d.glob("last*.ckpt")]


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
        from vtlearn.models.actor import read_lightning_checkpoint

        sub = self.config.get("subcommand")
        ckpt = self.config[sub].get("ckpt_path") if sub else None
        if ckpt is None or ckpt in ("last", "best", "hpc"):
            return
        if str(ckpt).startswith("registry") or "://" in str(ckpt):
            return  # Lightning's model registry and remote (fsspec) files: left to Lightning
        if not Path(ckpt).is_file():
            raise ConfigError(f"ckpt_path: no checkpoint file at {ckpt}")
        try:
            read_lightning_checkpoint(ckpt)
        except ValueError as exc:
            raise ConfigError(f"ckpt_path: {str(exc).removeprefix('ckpt: ')}") from None

    def _parse_ckpt_path(self) -> None:
        # Lightning merges the checkpoint's hyper-parameters into the config here; another model's fail to
        # parse (a usage dump, then "Parsing of ckpt_path hyperparameters failed!")
        try:
            super()._parse_ckpt_path()
        except ArgumentError as exc:
            ckpt = self.config[self.config.subcommand].get("ckpt_path")
            raise ConfigError(
                f"ckpt_path: the hyper-parameters of {ckpt} do not fit the config's model (a checkpoint of "
                f"another model?): {_reason(exc)}"
            ) from None

    def instantiate_classes(self) -> None:
        try:
            super().instantiate_classes()
        except (ValueError, TypeError, FileNotFoundError) as exc:
            raise ConfigError(_reason(exc)) from exc

    def _require_last(self, subcommand: str) -> None:
        if self.config_init[subcommand].get("ckpt_path") != "last":
            return
        dirs, found = _last_checkpoints(self.trainer)
        if dirs and not found:
            raise ConfigError(
                f"ckpt_path: 'last' found no last.ckpt in {', '.join(map(str, dirs))}; {subcommand} would "
                "score untrained weights (train first with fit, or pass a checkpoint file)"
            )

    def before_validate(self) -> None:
        self._require_last("validate")

    def before_test(self) -> None:
        self._require_last("test")

    def before_predict(self) -> None:
        self._require_last("predict")


def cli_main(args=None) -> LightningCLI:
    os.environ.setdefault("WANDB_MODE", "offline")
    return VtlearnCLI(
        subclass_mode_model=True,
        subclass_mode_data=True,
        save_config_kwargs={"overwrite": True},
        parser_kwargs={"exit_on_error": False},  # parse errors raise, and main() prints them on one line
        args=args,
    )


def main(args=None) -> int:
    try:
        cli_main(args)
    except (ConfigError, ConfigMismatchError) as exc:
        print(f"train.py: error: {exc}", file=sys.stderr)
        return 2
    return 0


if __name__ == "__main__":
    sys.exit(main())
