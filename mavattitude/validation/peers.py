"""Peer filters run on the same recordings: VQF (causal) and the Fusion AHRS (``imufusion``).

They are test/benchmark dependencies from PyPI, never run-time ones, so they are imported here on use.
Both take the raw samples at the input rate, in the recording's own body frame, and report sensor →
ENU-type quaternions (z up, y magnetic north): converted to body → NED like every other estimate.

- VQF (Laidig & Seel 2023, the BROAD authors' filter): ``vqf.VQF`` with its default parameters, run
  causally sample by sample (``updateBatch`` is the same causal loop in C++); ``quat9D``.
- Fusion: ``imufusion.Ahrs`` with the library's default settings (gain 0.5, rejection off) in its ENU
  convention. Its README's suggested rejection thresholds (10°/10°, 5 s recovery) lose the attitude on
  BROAD's fast trial 08 (42° RMS) and are not used; say so where the figures are quoted.
"""

from __future__ import annotations

import time

import numpy as np

from mavattitude.sensors.units import STANDARD_GRAVITY_MPS2
from mavattitude.validation.frames import ned_from_enu
from mavattitude.validation.loaders import Recording
from mavattitude.validation.runner import Estimate

PEERS = ("vqf", "imufusion")


def _vqf(recording: Recording, dt_s: float) -> np.ndarray:
    from vqf import VQF

    filt = VQF(dt_s)
    out = filt.updateBatch(
        np.ascontiguousarray(recording.gyr_radps),
        np.ascontiguousarray(recording.acc_mps2),
        np.ascontiguousarray(recording.mag_uT),
    )
    return out["quat9D"]


def _imufusion(recording: Recording, dt_s: float) -> np.ndarray:
    import imufusion

    ahrs = imufusion.Ahrs()
    settings = imufusion.AhrsSettings()
    settings.convention = imufusion.CONVENTION_ENU
    settings.sample_rate = 1.0 / dt_s
    ahrs.set_settings(settings)
    gyr_dps = np.degrees(recording.gyr_radps)
    acc_g = recording.acc_mps2 / STANDARD_GRAVITY_MPS2
    q = np.empty((len(recording), 4))
    for i in range(len(recording)):
        ahrs.update(gyr_dps[i], acc_g[i], recording.mag_uT[i])
        q[i] = ahrs.get_quaternion()
    return q


def estimate_peer(recording: Recording, name: str) -> Estimate:
    """Run peer ``name`` (one of :data:`PEERS`) over the raw samples."""
    run = {"vqf": _vqf, "imufusion": _imufusion}[name]
    dt_s = float(np.median(np.diff(recording.time_s)))
    start = time.monotonic()
    q_enu = run(recording, dt_s)
    return Estimate(
        path="peer",
        method=name,
        time_s=recording.time_s,
        q=ned_from_enu(q_enu),
        expected=len(recording),
        elapsed_s=time.monotonic() - start,
    )
