"""Sensor calibration models, pure: accelerometer ``M_a (raw − b_a)``, magnetometer ``S (raw − h)``
(hard-iron offset ``h``, soft-iron matrix ``S``), gyroscope ``raw − b_g``.

The YAML block (the config's ``calibration`` section; other keys may be added)::

    calibration:
      accel: {bias_mps2: [0, 0, 0], matrix: [[1,0,0],[0,1,0],[0,0,1]]}
      mag:   {hard_iron_uT: [0, 0, 0], soft_iron: [[1,0,0],[0,1,0],[0,0,1]]}
      gyro:  {bias_radps: [0, 0, 0]}

Calibration acts on the sensor's own axes, before the board → body mounting rotation ``R``, so the whole
chain per sensor is one affine map ``body = R M (raw − b) = A raw − A b`` (:func:`affine`).
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from mavattitude.errors import CalibrationError

Array = NDArray[np.float64]
Vec3 = tuple[float, float, float]
Mat3 = tuple[Vec3, Vec3, Vec3]
IDENTITY: Mat3 = ((1.0, 0.0, 0.0), (0.0, 1.0, 0.0), (0.0, 0.0, 1.0))
ZERO: Vec3 = (0.0, 0.0, 0.0)


@dataclass(frozen=True)
class AccelCalibration:
    bias_mps2: Vec3 = ZERO
    matrix: Mat3 = IDENTITY


@dataclass(frozen=True)
class MagCalibration:
    hard_iron_uT: Vec3 = ZERO
    soft_iron: Mat3 = IDENTITY


@dataclass(frozen=True)
class GyroCalibration:
    bias_radps: Vec3 = ZERO


@dataclass(frozen=True)
class Calibration:
    """All three models. Any object with the same attribute names (the config's) works where this does."""

    accel: AccelCalibration = field(default_factory=AccelCalibration)
    mag: MagCalibration = field(default_factory=MagCalibration)
    gyro: GyroCalibration = field(default_factory=GyroCalibration)

    @classmethod
    def from_mapping(cls, data: Mapping[str, Any]) -> Calibration:
        """From the ``calibration`` mapping of a YAML file; missing keys keep the identity model."""
        try:
            accel = data.get("accel", {})
            mag = data.get("mag", {})
            gyro = data.get("gyro", {})
            return cls(
                AccelCalibration(_vec(accel.get("bias_mps2", ZERO)), _mat(accel.get("matrix", IDENTITY))),
                MagCalibration(_vec(mag.get("hard_iron_uT", ZERO)), _mat(mag.get("soft_iron", IDENTITY))),
                GyroCalibration(_vec(gyro.get("bias_radps", ZERO))),
            )
        except (AttributeError, TypeError, ValueError) as exc:
            raise CalibrationError(f"calibration block is malformed: {exc}") from exc


def _vec(v: ArrayLike) -> Vec3:
    a = np.asarray(v, dtype=float)
    if a.shape != (3,) or not np.all(np.isfinite(a)):
        raise ValueError(f"expected 3 finite numbers, got {v!r}")
    return (float(a[0]), float(a[1]), float(a[2]))


def _mat(m: ArrayLike) -> Mat3:
    a = np.asarray(m, dtype=float)
    if a.shape != (3, 3) or not np.all(np.isfinite(a)):
        raise ValueError(f"expected a 3×3 finite matrix, got {m!r}")
    return (_vec(a[0]), _vec(a[1]), _vec(a[2]))


def mag_block(hard_iron_uT: ArrayLike, soft_iron: ArrayLike) -> dict[str, Any]:
    """The ``calibration: mag:`` mapping for a YAML file, plain floats."""
    mag = {"hard_iron_uT": list(_vec(hard_iron_uT)), "soft_iron": [list(row) for row in _mat(soft_iron)]}
    return {"calibration": {"mag": mag}}


def affine(matrix: ArrayLike, bias: ArrayLike, mounting: ArrayLike) -> tuple[Array, Array]:
    """``(A, c)`` with ``body = A raw − c``: ``A = R M``, ``c = A b``."""
    a = np.asarray(mounting, dtype=float) @ np.asarray(matrix, dtype=float)
    c = a @ np.asarray(bias, dtype=float)
    if not (np.all(np.isfinite(a)) and np.all(np.isfinite(c))):
        raise CalibrationError("calibration or mounting is not finite")
    return a, c


def sensor_affines(calibration: Any, mounting: ArrayLike) -> dict[str, tuple[Array, Array]]:
    """The affine map of each sensor (``"acc"``, ``"gyr"``, ``"mag"``) for a calibration and mounting."""
    return {
        "acc": affine(calibration.accel.matrix, calibration.accel.bias_mps2, mounting),
        "gyr": affine(np.eye(3), calibration.gyro.bias_radps, mounting),
        "mag": affine(calibration.mag.soft_iron, calibration.mag.hard_iron_uT, mounting),
    }
