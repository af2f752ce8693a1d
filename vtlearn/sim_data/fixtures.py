"""Tiny generated datasets for tests of vtlearn and of code built on its datamodules.

``make_tiny_dataset("reconstruction" | "crossmodal", out_dir)`` runs the real generator on three
categories with three instances each (train / val / test get one instance per category) at small
sizes; it takes a few CPU seconds and is cached by directory (a finished dataset is reused).
"""

from __future__ import annotations

from pathlib import Path

from vtlearn.sim_data.writer import GenConfig, generate_dataset

TINY_CATEGORIES = ["mug", "bottle", "box"]


def tiny_config(kind: str, seed: int = 0) -> GenConfig:
    return GenConfig(
        kind=kind,
        categories=list(TINY_CATEGORIES),
        per_category=3,
        seed=seed,
        shard_size=2,
        sections=24,
        touches=16,
        pinches=4,
        views=2,
        image_width=160,
        image_height=120,
        tactile_clouds=2,
    )


def make_tiny_dataset(kind: str, out_dir: str | Path, seed: int = 0) -> Path:
    """Generate (or reuse) a tiny ``kind`` dataset in ``out_dir``; returns the directory."""
    out = Path(out_dir)
    if not (out / "manifest.json").exists():
        generate_dataset(tiny_config(kind, seed), out, workers=1, progress=False)
    return out
