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
