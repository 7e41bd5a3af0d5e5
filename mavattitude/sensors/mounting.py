"""Board → body mounting rotations: ArduPilot's names (``AP_Math/rotations.h``) or a 3×3 matrix.

ArduPilot names a rotation by the Euler angles that take the board's axes to the vehicle's, applied roll,
then pitch, then yaw: ``v_body = Rz(yaw) Ry(pitch) Rx(roll) v_board`` (e.g. ``ROLL_180_YAW_90`` maps
``(x, y, z)`` to ``(y, x, −z)`` as ``Vector3::rotate`` does). The odd one, ``ROLL_90_PITCH_68_YAW_293``,
is ArduPilot's Euler (90°, 68.8°, 293.3°). Names are accepted with or without the ``ROTATION_`` prefix.

ArduPilot's *level trim* (``AHRS_TRIM_X``, ``AHRS_TRIM_Y``, radians, set by its "calibrate level") turns once more:
its IMU readings (RAW_IMU, DataFlash IMU/MAG) are in the autopilot's body frame, the board orientation applied,
while its attitude (ATTITUDE, DataFlash ATT) is of the vehicle's, which ``AP_AHRS`` takes from the autopilot's
as ``R_vehicle→NED = R_autopilot→NED · from_euler(x, y, 0)ᵀ``. A reading turns into the vehicle's frame as
``v_vehicle = from_euler(x, y, 0) · v_autopilot`` (:func:`trim_matrix`), after the mounting.
"""

from __future__ import annotations

import math
import re
from typing import Any

import numpy as np

from mavattitude.errors import ConfigError
from mavattitude.estimation.conventions import Array

#: ArduPilot's Rotation enum (value → name without the ROTATION_ prefix), 0–43.
ARDUPILOT_ROTATIONS: dict[int, str] = dict(
    enumerate(
        [
            "NONE",
            "YAW_45",
            "YAW_90",
            "YAW_135",
            "YAW_180",
            "YAW_225",
            "YAW_270",
            "YAW_315",
            "ROLL_180",
            "ROLL_180_YAW_45",
            "ROLL_180_YAW_90",
            "ROLL_180_YAW_135",
            "PITCH_180",
            "ROLL_180_YAW_225",
            "ROLL_180_YAW_270",
            "ROLL_180_YAW_315",
            "ROLL_90",
            "ROLL_90_YAW_45",
            "ROLL_90_YAW_90",
            "ROLL_90_YAW_135",
            "ROLL_270",
            "ROLL_270_YAW_45",
            "ROLL_270_YAW_90",
            "ROLL_270_YAW_135",
            "PITCH_90",
            "PITCH_270",
            "PITCH_180_YAW_90",
            "PITCH_180_YAW_270",
            "ROLL_90_PITCH_90",
            "ROLL_180_PITCH_90",
            "ROLL_270_PITCH_90",
            "ROLL_90_PITCH_180",
            "ROLL_270_PITCH_180",
            "ROLL_90_PITCH_270",
            "ROLL_180_PITCH_270",
            "ROLL_270_PITCH_270",
            "ROLL_90_PITCH_180_YAW_90",
            "ROLL_90_YAW_270",
            "ROLL_90_PITCH_68_YAW_293",
            "PITCH_315",
            "ROLL_90_PITCH_315",
            "PITCH_7",
            "ROLL_45",
            "ROLL_315",
        ]
    )
)
_EXACT_ANGLES_DEG = {"ROLL_90_PITCH_68_YAW_293": (90.0, 68.8, 293.3)}
_PART = re.compile(r"(ROLL|PITCH|YAW)_(\d+)")


def euler_matrix(roll_deg: float, pitch_deg: float, yaw_deg: float) -> Array:
    """``Rz(yaw) Ry(pitch) Rx(roll)``: ArduPilot's ``Matrix3::from_euler``."""
    r, p, y = (math.radians(a) for a in (roll_deg, pitch_deg, yaw_deg))
    cr, sr, cp, sp, cy, sy = math.cos(r), math.sin(r), math.cos(p), math.sin(p), math.cos(y), math.sin(y)
    m = np.array(
        [
            [cp * cy, sr * sp * cy - cr * sy, cr * sp * cy + sr * sy],
            [cp * sy, sr * sp * sy + cr * cy, cr * sp * sy - sr * cy],
            [-sp, sr * cp, cr * cp],
        ]
    )
    # the named rotations are mostly multiples of 90°: make their zeros and ones exact
    return np.where(np.abs(m) < 1e-15, 0.0, m)


def rotation_angles_deg(name: str) -> tuple[float, float, float]:
    """(roll, pitch, yaw) in degrees of an ArduPilot rotation name."""
    key = name.upper().removeprefix("ROTATION_")
    if key not in ARDUPILOT_ROTATIONS.values():
        raise ConfigError(f"unknown mounting rotation {name!r}; ArduPilot names such as NONE, ROLL_180, YAW_90")
    if key in _EXACT_ANGLES_DEG:
        return _EXACT_ANGLES_DEG[key]
    angles = {"ROLL": 0.0, "PITCH": 0.0, "YAW": 0.0}
    for axis, degrees in _PART.findall(key):
        angles[axis] = float(degrees)
    return angles["ROLL"], angles["PITCH"], angles["YAW"]


#: ArduPilot's level trim parameters, roll and pitch (radians; the autopilot limits each to ±10°).
TRIM_PARAMETERS = ("AHRS_TRIM_X", "AHRS_TRIM_Y")
TRIM_LIMIT_RAD = math.radians(10.0)


def trim_matrix(roll_rad: float, pitch_rad: float) -> Array:
    """The autopilot body → vehicle body matrix of a level trim (the module docstring)."""
    return euler_matrix(math.degrees(roll_rad), math.degrees(pitch_rad), 0.0)


def mounting_matrix(rotation: Any) -> Array:
    """Board → body matrix from an ArduPilot name or a 3×3 rotation matrix (checked orthonormal, det +1)."""
    if isinstance(rotation, str):
        return euler_matrix(*rotation_angles_deg(rotation))
    m = np.asarray(rotation, dtype=float)
    if m.shape != (3, 3) or not np.all(np.isfinite(m)):
        raise ConfigError(f"a mounting matrix must be 3×3 and finite, got {rotation!r}")
    if np.max(np.abs(m @ m.T - np.eye(3))) > 1e-6 or np.linalg.det(m) < 0:
        raise ConfigError("a mounting matrix must be a rotation (orthonormal, determinant +1)")
    return m
