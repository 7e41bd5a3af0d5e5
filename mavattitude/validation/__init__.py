"""Validation on real recordings: loaders, frames and the BROAD / PX4 metrics (no I/O beyond reading data).

``from mavattitude.validation import load_recording, score_broad, score_px4, broad_errors`` is what the
tuning of other parts (e.g. the fused filter) imports; ``mavattitude validate`` runs everything.
"""

from mavattitude.validation.frames import Q_ENU_FROM_NED, RestReference, enu_from_ned, ned_from_enu
from mavattitude.validation.loaders import Recording, find_recordings, load_recording, rest_mask, truth_at
from mavattitude.validation.metrics import (
    BroadScore,
    ErrorRms,
    Px4Score,
    broad_errors,
    euler_differences,
    score_broad,
    score_px4,
)

__all__ = [
    "Q_ENU_FROM_NED",
    "BroadScore",
    "ErrorRms",
    "Px4Score",
    "Recording",
    "RestReference",
    "broad_errors",
    "enu_from_ned",
    "euler_differences",
    "find_recordings",
    "load_recording",
    "ned_from_enu",
    "rest_mask",
    "score_broad",
    "score_px4",
    "truth_at",
]
