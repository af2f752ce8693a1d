"""Classical (non-learned) estimators: TIQF/S-TIQF registration and active touch (ch.4-5), ArtReg (ch.6), and
the Geodesic Flow Kernel baseline of cross-modal recognition (ch.7, Table 7.4).

The public names below are imported on first use (PEP 562), so that importing a submodule such as
``vtlearn.classical.tracking_cli`` (which ``vtlearn --help`` does) does not load torch and Open3D.
"""

from __future__ import annotations

import importlib
from typing import Any

#: public name -> submodule that defines it
_EXPORTS = {
    # registration: TIQF, S-TIQF, baselines, active touch (issue 6; thesis ch.4-5)
    "register": "registration",
    "RegistrationResult": "registration",
    "METHODS": "registration",
    "available_methods": "registration",
    "TIQF": "tiqf",
    "TIQFResult": "tiqf",
    "SequentialTIQF": "tiqf",
    "gaussian_kl": "tiqf",
    "STIQF": "stiqf",
    "STIQFResult": "stiqf",
    # tracking: manifold UKF, ArtReg, part segmentation, tracking baselines (issue 7; thesis ch.6)
    "ManifoldUKF": "ukf",
    "ArtRegTracker": "artreg",
    "segment_parts": "segmentation",
    "SegmentationResult": "segmentation",
    "ParticleFilterTracker": "tracking_baselines",
    "FrameToFrameICPTracker": "tracking_baselines",
    "FilterRegTracker": "tracking_baselines",
    # the classical cross-modal baseline of Table 7.4 (issue 5; thesis ch.7): GFK on ESF descriptors
    "GeodesicFlowKernel": "gfk",
    "gfk_kernel": "gfk",
    "classical_runs": "crossmodal_baseline",
}

__all__ = list(_EXPORTS)


def __getattr__(name: str) -> Any:
    if name not in _EXPORTS:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    value = getattr(importlib.import_module(f"{__name__}.{_EXPORTS[name]}"), name)
    globals()[name] = value
    return value


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(__all__))
