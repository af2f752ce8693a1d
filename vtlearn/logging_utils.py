"""The default Lightning logger: wandb in offline mode, or a CSV logger when wandb is disabled/unavailable."""

from __future__ import annotations

import logging
import os

__all__ = ["default_logger", "get_logger"]


def get_logger(name: str) -> logging.Logger:
    """A module logger under the ``vtlearn`` namespace."""
    return logging.getLogger(name if name.startswith("vtlearn") else f"vtlearn.{name}")


def default_logger(save_dir: str = "runs", name: str = "vtlearn", project: str = "vtlearn"):
    """Build the default experiment logger.

    * ``WANDB_MODE=disabled`` (tests) or wandb not importable -> ``CSVLogger(save_dir, name)``.
    * otherwise ``WandbLogger`` in **offline** mode unless ``WANDB_MODE=online``; nothing is uploaded without
      that (an API key alone does not switch it on, as in ``train.py``, which sets ``WANDB_MODE=offline``
      when it is unset).
    """
    from lightning.pytorch.loggers import CSVLogger

    mode = os.environ.get("WANDB_MODE", "").lower()
    if mode == "disabled":
        return CSVLogger(save_dir=save_dir, name=name)
    try:
        import wandb  # noqa: F401
        from lightning.pytorch.loggers import WandbLogger
    except Exception:  # noqa: BLE001 - any import problem means: fall back to CSV
        return CSVLogger(save_dir=save_dir, name=name)
    os.makedirs(save_dir, exist_ok=True)
    return WandbLogger(project=project, name=name, save_dir=save_dir, offline=mode != "online")
