"""LightningCLI entry point: ``python train.py fit --config configs/<model>.yaml``.

Any vtlearn LightningModule / LightningDataModule is selected by ``class_path`` in the config, so
``validate``, ``test`` and ``predict`` work the same way. ``--ckpt_path last`` resumes from ``last.ckpt``.
"""

from __future__ import annotations

import os

from lightning.pytorch.cli import LightningCLI


def cli_main(args=None) -> LightningCLI:
    os.environ.setdefault("WANDB_MODE", "offline")
    return LightningCLI(
        subclass_mode_model=True,
        subclass_mode_data=True,
        save_config_kwargs={"overwrite": True},
        args=args,
    )


if __name__ == "__main__":
    cli_main()
