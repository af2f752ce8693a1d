"""Tiny primitive-shape reconstruction data (sphere / box / cylinder) for ACTOR tests and smoke runs.

Not a thesis dataset: the real training data come from ``vtlearn.datamodules.ReconstructionDataModule``.
This produces batches in the same format, so the ACTOR modules can be exercised without generated data.

Shapes:
    a sample is {"sparse": (n, 3), "dense": (num_dense, 3), "label": ()}; ``collate_padded`` pads to
    {"sparse": (B, N_max, 3), "lengths": (B,), "dense": (B, num_dense, 3), "label": (B,)}.
"""

from __future__ import annotations

import lightning as L
import numpy as np
import torch
from torch.utils.data import DataLoader, Dataset

__all__ = ["PrimitiveClouds", "PrimitiveDataModule", "collate_padded", "primitive_surface"]

CLASS_NAMES = ("sphere", "box", "cylinder")


def primitive_surface(kind: str, n: int, rng: np.random.Generator, size: float = 0.05) -> np.ndarray:
    """``n`` random surface points of a sphere / box / cylinder of half-size ``size``. Shapes: (n, 3)."""
    if kind == "sphere":
        v = rng.normal(size=(n, 3))
        return size * v / np.linalg.norm(v, axis=1, keepdims=True)
    if kind == "box":
        p = rng.uniform(-size, size, size=(n, 3))
        axis = rng.integers(0, 3, size=n)
        p[np.arange(n), axis] = size * rng.choice([-1.0, 1.0], size=n)
        return p
    if kind == "cylinder":
        theta = rng.uniform(0, 2 * np.pi, size=n)
        z = rng.uniform(-size, size, size=n)
        p = np.stack([size * np.cos(theta), size * np.sin(theta), z], axis=1)
        cap = rng.random(n) < 0.25
        r = size * np.sqrt(rng.random(cap.sum()))
        p[cap, 0], p[cap, 1] = r * np.cos(theta[cap]), r * np.sin(theta[cap])
        p[cap, 2] = size * rng.choice([-1.0, 1.0], size=cap.sum())
        return p
    raise ValueError(f"kind: expected one of {CLASS_NAMES}, got {kind!r}")


class PrimitiveClouds(Dataset):
    """Randomly scaled primitives; sparse clouds of ``min_points..max_points`` points of the dense one."""

    def __init__(
        self,
        size: int = 16,
        num_dense: int = 2048,
        min_points: int = 20,
        max_points: int = 120,
        seed: int = 0,
    ) -> None:
        self.size, self.num_dense, self.min_points, self.max_points, self.seed = (
            size,
            num_dense,
            min_points,
            max_points,
            seed,
        )

    def __len__(self) -> int:
        return self.size

    def __getitem__(self, i: int) -> dict[str, torch.Tensor]:
        rng = np.random.default_rng(self.seed * 100_003 + i)
        label = i % len(CLASS_NAMES)
        dense = primitive_surface(CLASS_NAMES[label], self.num_dense, rng, size=rng.uniform(0.03, 0.06))
        n = int(rng.integers(self.min_points, self.max_points + 1))
        sparse = dense[rng.choice(self.num_dense, size=n, replace=False)]
        return {
            "sparse": torch.as_tensor(sparse, dtype=torch.float32),
            "dense": torch.as_tensor(dense, dtype=torch.float32),
            "label": torch.tensor(label, dtype=torch.long),
        }


def collate_padded(samples: list[dict[str, torch.Tensor]]) -> dict[str, torch.Tensor]:
    """Pad variable-size sparse clouds with zeros (the ReconstructionDataModule batch format).

    Shapes:
        samples[b]["sparse"] (N_b, 3), ["dense"] (M, 3) -> "sparse" (B, max N_b, 3), "lengths" (B,),
        "dense" (B, M, 3), "label" (B,).
    """
    lengths = torch.tensor([len(s["sparse"]) for s in samples], dtype=torch.long)
    sparse = torch.zeros(len(samples), int(lengths.max()), 3)
    for b, s in enumerate(samples):
        sparse[b, : len(s["sparse"])] = s["sparse"]
    return {
        "sparse": sparse,
        "lengths": lengths,
        "dense": torch.stack([s["dense"] for s in samples]),
        "label": torch.stack([s["label"] for s in samples]),
    }


class PrimitiveDataModule(L.LightningDataModule):
    """Train / val / test / predict loaders of :class:`PrimitiveClouds` (different seeds per split)."""

    def __init__(
        self,
        batch_size: int = 4,
        size: int = 16,
        num_dense: int = 2048,
        min_points: int = 20,
        max_points: int = 120,
    ) -> None:
        super().__init__()
        self.batch_size, self.size, self.num_dense = batch_size, size, num_dense
        self.min_points, self.max_points = min_points, max_points
        self.num_classes = len(CLASS_NAMES)
        self.class_names = list(CLASS_NAMES)

    def _loader(self, seed: int, shuffle: bool) -> DataLoader:
        ds = PrimitiveClouds(self.size, self.num_dense, self.min_points, self.max_points, seed)
        return DataLoader(
            ds, batch_size=self.batch_size, shuffle=shuffle, collate_fn=collate_padded, drop_last=shuffle
        )

    def train_dataloader(self) -> DataLoader:
        return self._loader(0, True)

    def val_dataloader(self) -> DataLoader:
        return self._loader(1, False)

    def test_dataloader(self) -> DataLoader:
        return self._loader(2, False)

    def predict_dataloader(self) -> DataLoader:
        return self._loader(3, False)
