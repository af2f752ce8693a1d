"""LightningDataModules over `vtlearn gen-data` datasets (padded (B, N, 3) clouds + lengths)."""

from vtlearn.datamodules.active import ActivePoolDataModule
from vtlearn.datamodules.crossmodal import CrossModalDataModule
from vtlearn.datamodules.reconstruction import ReconstructionDataModule

__all__ = ["ReconstructionDataModule", "CrossModalDataModule", "ActivePoolDataModule"]
