"""LightningCLI entry point: ``python train.py fit --config configs/<model>.yaml``.

Any vtlearn LightningModule / LightningDataModule is selected by ``class_path`` in the config, so
``validate``, ``test`` and ``predict`` work the same way. ``--ckpt_path last`` resumes from ``last.ckpt``.

A config that cannot be built (a dataset directory without a manifest, an argument out of range) ends with
``train.py: error: <argument>: <reason>`` and exit code 2, not a traceback through jsonargparse; errors
raised while training keep their traceback, except the model's and the datamodule's disagreeing (a
:class:`~vtlearn.validation.ConfigMismatchError` from ``setup``), which is reported the same way.
"""

from __future__ import annotations

import os
import sys

from lightning.pytorch.cli import LightningCLI

from vtlearn.validation import ConfigMismatchError


class ConfigError(Exception):
    """A config whose model, data or trainer could not be instantiated; the message names the argument."""


def _reason(exc: BaseException) -> str:
    """The useful lines of an instantiation error. jsonargparse reports a subclass-mode argument that failed
    as "Does not validate against any of the Union subtypes", with one ``  - `` line per alternative; keep
    the lines of the alternatives other than None (the vtlearn ``ValueError`` that names the argument)."""
    text = str(exc)
    if "Errors:" not in text:
        return text
    lines = [ln.strip()[2:] for ln in text.split("Errors:", 1)[1].splitlines()
             if ln.strip().startswith("- ") and "NoneType" not in ln]
    return "; ".join(lines) or text


class VtlearnCLI(LightningCLI):
    """LightningCLI that turns a failure to build the config's classes into a :class:`ConfigError`."""

    def instantiate_classes(self) -> None:
        try:
            super().instantiate_classes()
        except (ValueError, TypeError, FileNotFoundError) as exc:
            raise ConfigError(_reason(exc)) from exc


def cli_main(args=None) -> LightningCLI:
    os.environ.setdefault("WANDB_MODE", "offline")
    return VtlearnCLI(
        subclass_mode_model=True,
        subclass_mode_data=True,
        save_config_kwargs={"overwrite": True},
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
