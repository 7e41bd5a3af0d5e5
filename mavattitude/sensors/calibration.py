"""Sensor calibration models, pure: accelerometer ``M_a (raw − b_a)``, magnetometer ``S (raw − h)``
(hard-iron offset ``h``, soft-iron matrix ``S``), gyroscope ``raw − b_g``.

:class:`Calibration` is the config's ``calibration`` section itself (:mod:`mavattitude.config` reads and
checks it from YAML, by the field types and descriptions written here)::

    calibration:
      accel: {bias_mps2: [0, 0, 0], matrix: [[1,0,0],[0,1,0],[0,0,1]]}
      mag:   {hard_iron_uT: [0, 0, 0], soft_iron: [[1,0,0],[0,1,0],[0,0,1]]}
      gyro:  {bias_radps: [0, 0, 0]}

Calibration acts on the sensor's own axes, before the board → body mounting rotation ``R``, so the whole
chain per sensor is one affine map ``body = R M (raw − b) = A raw − A b`` (:func:`affine`).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import ArrayLike

from mavattitude.errors import CalibrationError
from mavattitude.estimation.conventions import Array, Mat3, Vec3

IDENTITY: Mat3 = ((1.0, 0.0, 0.0), (0.0, 1.0, 0.0), (0.0, 0.0, 1.0))
ZERO: Vec3 = (0.0, 0.0, 0.0)


def _doc(text: str) -> dict[str, str]:
    """A field's one-line description, shown by ``check-config`` and the config reference."""
    return {"doc": text}


@dataclass(frozen=True)
class AccelCalibration:
    bias_mps2: Vec3 = field(default=ZERO, metadata=_doc("accelerometer bias b_a, m/s²"))
    matrix: Mat3 = field(default=IDENTITY, metadata=_doc("accelerometer scale/misalignment M_a: acc = M_a (raw − b_a)"))


@dataclass(frozen=True)
class MagCalibration:
    hard_iron_uT: Vec3 = field(default=ZERO, metadata=_doc("hard-iron offset h, µT"))
    soft_iron: Mat3 = field(default=IDENTITY, metadata=_doc("soft-iron matrix S: mag = S (raw − h)"))


@dataclass(frozen=True)
class GyroCalibration:
    bias_radps: Vec3 = field(default=ZERO, metadata=_doc("gyroscope bias, rad/s"))


@dataclass(frozen=True)
class Calibration:
    """All three models: the config's ``calibration`` section."""

    accel: AccelCalibration = field(default_factory=AccelCalibration)
    mag: MagCalibration = field(default_factory=MagCalibration)
    gyro: GyroCalibration = field(default_factory=GyroCalibration)


def mag_block(hard_iron_uT: ArrayLike, soft_iron: ArrayLike) -> dict[str, Any]:
    """The ``calibration: mag:`` mapping for a YAML file, plain floats."""
    mag = {"hard_iron_uT": np.asarray(hard_iron_uT, float).tolist(), "soft_iron": np.asarray(soft_iron, float).tolist()}
    return {"calibration": {"mag": mag}}


def hard_iron_with_body_offset(mag: MagCalibration, mounting: ArrayLike, offset_body_uT: ArrayLike) -> Array:
    """The hard iron that also removes an offset ``o`` found in the calibrated body-frame field (e.g. the
    fused filter's learnt offset): ``R S (raw − h) − o = R S (raw − h − S⁻¹ Rᵀ o)``, so ``h' = h + S⁻¹ Rᵀ o``."""
    r, soft = np.asarray(mounting, dtype=float), np.asarray(mag.soft_iron, dtype=float)
    return np.asarray(mag.hard_iron_uT, dtype=float) + np.linalg.solve(soft, r.T @ np.asarray(offset_body_uT, float))


def affine(matrix: ArrayLike, bias: ArrayLike, mounting: ArrayLike) -> tuple[Array, Array]:
    """``(A, c)`` with ``body = A raw − c``: ``A = R M``, ``c = A b``."""
    a = np.asarray(mounting, dtype=float) @ np.asarray(matrix, dtype=float)
    c = a @ np.asarray(bias, dtype=float)
    if not (np.all(np.isfinite(a)) and np.all(np.isfinite(c))):
        raise CalibrationError("calibration or mounting is not finite")
    return a, c


def sensor_affines(calibration: Calibration, mounting: ArrayLike) -> dict[str, tuple[Array, Array]]:
    """The affine map of each sensor (``"acc"``, ``"gyr"``, ``"mag"``) for a calibration and mounting."""
    return {
        "acc": affine(calibration.accel.matrix, calibration.accel.bias_mps2, mounting),
        "gyr": affine(np.eye(3), calibration.gyro.bias_radps, mounting),
        "mag": affine(calibration.mag.soft_iron, calibration.mag.hard_iron_uT, mounting),
    }
