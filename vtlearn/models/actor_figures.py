"""Matplotlib figures for ACTOR (reconstruction triplets, confusion matrices) and logging them.

Figures are sent to whichever Lightning logger is active: W&B gets an image, TensorBoard a figure,
and any other logger (CSVLogger) a PNG under ``<log_dir>/figures/``.
"""

from __future__ import annotations

import os
from collections.abc import Sequence

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

__all__ = ["reconstruction_figure", "confusion_figure", "log_figure"]


def _scatter3d(ax, points: np.ndarray, color: str, size: float, title: str, lims) -> None:
    ax.scatter(points[:, 0], points[:, 1], points[:, 2], s=size, c=color, depthshade=False)
    ax.set_title(title, fontsize=9)
    for setter, (lo, hi) in zip((ax.set_xlim, ax.set_ylim, ax.set_zlim), lims, strict=True):
        setter(lo, hi)
    ax.set_xticks([])
    ax.set_yticks([])
    ax.set_zticks([])


def reconstruction_figure(
    rows: Sequence[Sequence[np.ndarray | None]],
    titles: Sequence[str] = ("input (sparse)", "reconstruction", "ground truth"),
    row_labels: Sequence[str] | None = None,
):
    """A grid of 3D scatter plots, one row per object, one column per cloud (None leaves a blank).

    Shapes:
        every cloud is (N_i, 3); all panels of a row share the same axis limits.
    """
    n_rows, n_cols = len(rows), len(titles)
    fig = plt.figure(figsize=(3.0 * n_cols, 3.0 * n_rows))
    for r, clouds in enumerate(rows):
        valid = [np.asarray(c) for c in clouds if c is not None and len(c)]
        allp = np.concatenate(valid, axis=0)
        centre = 0.5 * (allp.min(0) + allp.max(0))
        half = 0.5 * float((allp.max(0) - allp.min(0)).max()) + 1e-9
        lims = [(centre[i] - half, centre[i] + half) for i in range(3)]
        for c, cloud in enumerate(clouds):
            ax = fig.add_subplot(n_rows, n_cols, r * n_cols + c + 1, projection="3d")
            if cloud is None:
                ax.set_axis_off()
                continue
            cloud = np.asarray(cloud)
            size = 6.0 if len(cloud) < 300 else 0.8
            color = ("tab:red", "tab:blue", "tab:green", "tab:orange", "tab:purple")[c % 5]
            title = titles[c] if r == 0 else ""
            if row_labels is not None and c == 0:
                title = f"{row_labels[r]}\n{title}" if title else row_labels[r]
            _scatter3d(ax, cloud, color, size, title, lims)
    fig.tight_layout()
    return fig


def confusion_figure(
    matrix: np.ndarray, class_names: Sequence[str], title: str = "confusion (row-normalised)"
):
    """Row-normalised confusion matrix like thesis Table 8.1 (rows: true, columns: predicted).

    Shapes:
        matrix: (k, k) counts.
    """
    matrix = np.asarray(matrix, dtype=np.float64)
    norm = matrix / np.clip(matrix.sum(axis=1, keepdims=True), 1, None)
    k = len(class_names)
    fig, ax = plt.subplots(figsize=(1.0 + 0.6 * k, 1.0 + 0.55 * k))
    ax.imshow(norm, vmin=0, vmax=1, cmap="Blues")
    ax.set_xticks(range(k), class_names, rotation=60, ha="right", fontsize=8)
    ax.set_yticks(range(k), class_names, fontsize=8)
    ax.set_xlabel("predicted")
    ax.set_ylabel("true")
    for i in range(k):
        for j in range(k):
            ax.text(
                j,
                i,
                f"{norm[i, j]:.2f}",
                ha="center",
                va="center",
                fontsize=7,
                color="white" if norm[i, j] > 0.5 else "black",
            )
    ax.set_title(title, fontsize=9)
    fig.tight_layout()
    return fig


def log_figure(logger, key: str, fig, step: int) -> str | None:
    """Send ``fig`` to a Lightning logger and close it. Returns the PNG path when one was written."""
    path = None
    try:
        if logger is None:
            return None
        name = type(logger).__name__
        if name == "WandbLogger":
            import wandb

            logger.experiment.log({key: wandb.Image(fig), "trainer/global_step": step})
        elif name == "TensorBoardLogger":
            logger.experiment.add_figure(key, fig, global_step=step)
        else:
            log_dir = getattr(logger, "log_dir", None) or getattr(logger, "save_dir", None)
            if not log_dir:  # e.g. the DummyLogger of fast_dev_run: logging is off, write nothing
                return None
            folder = os.path.join(str(log_dir), "figures")
            os.makedirs(folder, exist_ok=True)
            path = os.path.join(folder, f"{key.replace('/', '_')}_step{step:07d}.png")
            fig.savefig(path, dpi=80)
    finally:
        plt.close(fig)
    return path
