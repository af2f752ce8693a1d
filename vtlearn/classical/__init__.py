"""Classical (non-learned) estimators: TIQF/S-TIQF registration and active touch (ch.4-5), ArtReg (ch.6)."""

# --- registration: TIQF, S-TIQF, baselines, active touch (issue 6; thesis ch.4-5) ---------------------------
from vtlearn.classical.registration import METHODS, RegistrationResult, available_methods, register
from vtlearn.classical.stiqf import STIQF, STIQFResult
from vtlearn.classical.tiqf import TIQF, SequentialTIQF, TIQFResult, gaussian_kl

__all__ = [
    "register",
    "RegistrationResult",
    "METHODS",
    "available_methods",
    "TIQF",
    "TIQFResult",
    "SequentialTIQF",
    "STIQF",
    "STIQFResult",
    "gaussian_kl",
]
# --- end registration block ---------------------------------------------------------------------------------

# --- tracking: manifold UKF, ArtReg, part segmentation, tracking baselines (issue 7; thesis ch.6) ----------
from vtlearn.classical.artreg import ArtRegTracker
from vtlearn.classical.segmentation import SegmentationResult, segment_parts
from vtlearn.classical.tracking_baselines import FilterRegTracker, FrameToFrameICPTracker, ParticleFilterTracker
from vtlearn.classical.ukf import ManifoldUKF

__all__ += [
    "ManifoldUKF",
    "ArtRegTracker",
    "segment_parts",
    "SegmentationResult",
    "ParticleFilterTracker",
    "FrameToFrameICPTracker",
    "FilterRegTracker",
]
# --- end tracking block -------------------------------------------------------------------------------------
