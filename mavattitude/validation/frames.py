"""Frames of the real-data recordings, and the references estimated from their opening rest phase.

- BROAD's ground truth rotates the IMU's sensor frame into **ENU**; its accelerometer reads +9.81 m/s² on
  z when the sensor lies flat (sensor z up, a right-handed frame, *not* FRD). The estimators need no
  FRD body: they take any right-handed body frame, and the specific-force reference in NED is
  ``acc_ref = (0, 0, −1)`` whatever the body axes are. So the sensor frame is used as the body frame as
  it is, the estimate is sensor → NED, and it is compared in ENU through
  ``q_ENU = Q_ENU_FROM_NED ⊗ q_NED`` with ``Q_ENU_FROM_NED = [0, 1/√2, 1/√2, 0]`` (the 180° turn about
  the north-east bisector that swaps x/y and flips z).
- The PX4 log is body FRD → NED, as the project's conventions are.

Magnetic reference: both recordings' north is *magnetic* north (BROAD's lab frame, PX4 with declination
0), so the reference has no east component; its dip angle is measured, not taken from the truth, as the
mean angle between the field and "down" (−specific force) over the recording's opening rest phase.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from mavattitude.errors import DataFileError
from mavattitude.estimation.conventions import Array, quat_conjugate, quat_multiply

_H = np.sqrt(0.5)
Q_ENU_FROM_NED: Array = np.array([0.0, _H, _H, 0.0])

# Opening rest phase: before the first sample turning faster than this (gyro not bias-corrected:
# BROAD's rest reads ≈ 0.009 rad/s) ...
REST_RATE_RADPS = 0.1
# ... minus a margin so the hand's first movement is left out, and no longer than this (trial 28
# meets its magnet ≈ 34 s in, while still nominally at rest).
REST_MARGIN_S = 0.5
REST_MAX_S = 10.0
REST_MIN_S = 0.5


def enu_from_ned(q_ned: Array) -> Array:
    """Sensor → ENU quaternion of a sensor → NED one."""
    return quat_multiply(Q_ENU_FROM_NED, q_ned)


def ned_from_enu(q_enu: Array) -> Array:
    """Sensor → NED quaternion of a sensor → ENU one."""
    return quat_multiply(quat_conjugate(Q_ENU_FROM_NED), q_enu)


@dataclass(frozen=True)
class RestReference:
    """What the opening rest phase says: the NED magnetic reference and the per-axis sensor noise."""

    field_ned_uT: Array  # (3,), µT, declination 0 (north is magnetic north)
    acc_std_mps2: Array  # (3,)
    mag_std_uT: Array  # (3,)
    window_s: tuple[float, float]  # the rest window used, file time


def opening_rest_window(time_s: Array, gyr_radps: Array) -> slice:
    """Samples of the opening rest phase (see the module docstring for the rule)."""
    moving = np.linalg.norm(gyr_radps, axis=1) > REST_RATE_RADPS
    end_s = time_s[np.argmax(moving)] - REST_MARGIN_S if moving.any() else time_s[-1]
    end_s = min(end_s, time_s[0] + REST_MAX_S)
    if end_s - time_s[0] < REST_MIN_S:
        raise DataFileError(
            f"the recording does not open with {REST_MIN_S} s at rest (|ω| < {REST_RATE_RADPS} rad/s): "
            "cannot measure the magnetic dip and the sensor noise"
        )
    return slice(0, int(np.searchsorted(time_s, end_s, side="right")))


def rest_reference(time_s: Array, acc_mps2: Array, gyr_radps: Array, mag_uT: Array) -> RestReference:
    """Magnetic reference (dip from the data, declination 0) and sensor noise from the opening rest."""
    window = opening_rest_window(time_s, gyr_radps)
    acc, mag = acc_mps2[window], mag_uT[window]
    down = -acc.mean(axis=0)
    field = mag.mean(axis=0)
    strength = float(np.linalg.norm(field))
    sin_dip = float(field @ down) / (strength * float(np.linalg.norm(down)))
    dip = np.arcsin(np.clip(sin_dip, -1.0, 1.0))
    return RestReference(
        field_ned_uT=strength * np.array([np.cos(dip), 0.0, np.sin(dip)]),
        acc_std_mps2=acc.std(axis=0),
        mag_std_uT=mag.std(axis=0),
        window_s=(float(time_s[0]), float(time_s[window.stop - 1])),
    )


#: Compass mounting errors (body-frame matrices turning a good magnetometer's readings): each axis inverted,
#: and a 90° turn about each axis. The misoriented-compass checks (tools/compass_table.py, the tests) use them.
MISORIENTATIONS: dict[str, Array] = {
    "x-flip": np.diag([-1.0, 1.0, 1.0]),
    "y-flip": np.diag([1.0, -1.0, 1.0]),
    "z-flip": np.diag([1.0, 1.0, -1.0]),
    "roll-90": np.array([[1.0, 0.0, 0.0], [0.0, 0.0, -1.0], [0.0, 1.0, 0.0]]),
    "pitch-90": np.array([[0.0, 0.0, 1.0], [0.0, 1.0, 0.0], [-1.0, 0.0, 0.0]]),
    "yaw-90": np.array([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]]),
}
