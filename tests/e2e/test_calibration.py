"""Calibration end to end: a vehicle with hard/soft-iron and accelerometer scale/bias errors, and the
service configured with the matching calibration, flies as well as an undistorted one."""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numpy as np
import pytest

from mavattitude.estimation import NoiseModel, solve_batch
from mavattitude.estimation.conventions import angle_between
from mavattitude.sim import scenarios
from mavattitude.sim.sensors import AxisModel, SensorModel

from .conftest import assert_all_outputs_valid

pytestmark = pytest.mark.e2e

SOFT_IRON = np.array([[1.15, 0.06, -0.03], [0.06, 0.88, 0.04], [-0.03, 0.04, 1.02]])
HARD_IRON_UT = np.array([12.0, -7.0, 5.0])
ACC_MATRIX = np.array([[1.02, 0.0, 0.0], [0.01, 0.98, 0.0], [-0.005, 0.008, 1.01]])
ACC_BIAS_MPS2 = np.array([0.15, -0.1, 0.2])


def _distorted(rate_hz: float) -> SensorModel:
    paper = scenarios.paper_sensors(rate_hz)
    return SensorModel(
        accel=AxisModel(
            noise_std=paper.accel.noise_std, bias=tuple(ACC_BIAS_MPS2), matrix=tuple(map(tuple, ACC_MATRIX))
        ),
        gyro=paper.gyro,
        mag=AxisModel(noise_std=paper.mag.noise_std, bias=tuple(HARD_IRON_UT), matrix=tuple(map(tuple, SOFT_IRON))),
        rate_hz=rate_hz,
    )


def _rows(m: np.ndarray) -> list[list[float]]:
    return [[float(x) for x in row] for row in m]


def test_calibration_undoes_hard_soft_iron_and_accelerometer_errors(fly: Callable[..., Any]) -> None:
    script = scenarios.slow_rotation(120.0)
    calibration = {
        "calibration": {
            "accel": {"bias_mps2": ACC_BIAS_MPS2.tolist(), "matrix": _rows(np.linalg.inv(ACC_MATRIX))},
            "mag": {"hard_iron_uT": HARD_IRON_UT.tolist(), "soft_iron": _rows(np.linalg.inv(SOFT_IRON))},
        }
    }
    with fly(script, _distorted(200.0), calibration, profile="px4", message="HIGHRES_IMU", speed=2.0) as (v, _svc):
        assert v.wait_for_script_time(8.0, 20.0)
    assert_all_outputs_valid(v)
    score = v.score(since_script_s=0.5)
    # Calibrated: as good as the undistorted paper-noise case (≈ 0.3° RMS, see test_profiles).
    assert score.angle_rms_deg < 1.0 and score.angle_max_deg < 3.0, score
    # Control: the same distortion uncalibrated is far off. The project's own solver on the noise-free
    # raw vectors along the flight (what the service would see without the calibration block).
    truth = script.sample(np.linspace(1.0, 8.0, 50))
    raw_mag = truth.mag_uT @ SOFT_IRON.T + HARD_IRON_UT
    raw_acc = truth.specific_force_mps2 @ ACC_MATRIX.T + ACC_BIAS_MPS2
    noise = NoiseModel(accel_std=scenarios.PAPER_ACCEL_STD_MPS2, mag_std=scenarios.PAPER_MAG_STD_UT)
    q_raw = solve_batch(raw_acc, raw_mag, scenarios.DEFAULT_MAG_NED_UT, noise, method="ign", acc_ref=(0, 0, -1))
    uncalibrated_rms = np.degrees(np.sqrt(np.mean(angle_between(q_raw, truth.q) ** 2)))
    assert uncalibrated_rms > 5.0 * score.angle_rms_deg, (uncalibrated_rms, score.angle_rms_deg)
