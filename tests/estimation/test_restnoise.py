"""The noise measured at rest: the σ of still ticks, motion left out, and IGN weighing with them in the pipeline."""

from __future__ import annotations

import logging

import numpy as np
import pytest

from mavattitude import pipeline
from mavattitude.config import from_dict
from mavattitude.estimation.restnoise import RestNoise
from mavattitude.sensors.units import ImuSample
from mavattitude.sim import scenarios

SEED = 20261128
ACC_STD = (0.02, 0.03, 0.04)
MAG_STD = (0.3, 0.4, 0.5)
GYRO_STD, GYRO_BIAS = 0.002, (0.01, -0.02, 0.005)
RATE_HZ = 50.0


def _still(rest: RestNoise, start_s: float, duration_s: float, rng: np.random.Generator, turning: float = 0.0) -> None:
    """Still ticks (or turning at ``turning`` rad/s about z) with the module's σ."""
    for k in range(round(duration_s * RATE_HZ)):
        t = start_s + k / RATE_HZ
        acc = np.array([0.0, 0.0, -9.81]) + rng.normal(0.0, ACC_STD)
        mag = np.array([20.0, 0.0, 45.0]) + rng.normal(0.0, MAG_STD)
        gyr = np.add(GYRO_BIAS, (0.0, 0.0, turning)) + rng.normal(0.0, GYRO_STD, 3)
        rest.add(t, tuple(acc), tuple(mag), tuple(gyr))


def test_the_sigma_of_still_ticks_and_the_gyro_bias() -> None:
    """20 s still at 50 Hz: 1 000 ticks, so each σ within 10 % (its relative sampling error is 1/√(2n) ≈ 2 %,
    the block means removed cost 2 % of the degrees of freedom) and the bias within 4σ/√n = 0.25 mrad/s."""
    rest = RestNoise(rest_s=10.0)
    _still(rest, 0.0, 9.0, np.random.default_rng(SEED))
    assert rest.measured is None  # 8 closed blocks: not yet still long enough
    _still(rest, 9.0, 11.5, np.random.default_rng(SEED + 1))
    assert rest.measured is not None and rest.still_s == pytest.approx(20.0)
    assert rest.measured.accel_std == pytest.approx(ACC_STD, rel=0.1)
    assert rest.measured.mag_std == pytest.approx(MAG_STD, rel=0.1)
    assert rest.gyro_bias_radps == pytest.approx(GYRO_BIAS, abs=4 * GYRO_STD / np.sqrt(1000))
    assert rest.since_s == pytest.approx(10.0)  # the tick that closed the tenth still block


def test_turning_blocks_are_not_rest() -> None:
    """A turn at 10°/s is no rest (its rate is above 3°/s): a minute of it measures nothing."""
    rest = RestNoise(rest_s=10.0)
    _still(rest, 0.0, 60.0, np.random.default_rng(SEED), turning=np.radians(10.0))
    assert rest.still_s == 0.0 and rest.measured is None


def test_ign_weighs_with_the_measured_sigma_and_says_so(caplog: pytest.LogCaptureFixture) -> None:
    """The fake vehicle at rest for 30 s through the pipeline: from 10 s of rest on IGN's σ are the measured
    ones (the log says so once, the counters too), and its covariance shrinks from the config's 0.05 m/s² and
    0.5 µT to the ticks' own (measured 0.010–0.013 m/s², 0.13–0.17 µT: the 10 Hz low-pass's share of the
    consumer sensors' 0.03–0.04 m/s² and 0.4–0.5 µT)."""
    caplog.set_level(logging.INFO, logger="mavattitude.pipeline")
    script, sensors = scenarios.static(30.0), scenarios.consumer_sensors(200.0)
    rng = np.random.default_rng(SEED)
    t = sensors.sample_times(0.0, script.duration_s, rng)
    acc, gyr, mag = sensors.measure(script, t, rng)
    config = from_dict({"reference": {"magnetic": {"field_ned_uT": list(scenarios.DEFAULT_MAG_NED_UT)}}})
    p = pipeline.AttitudePipeline(config)
    out = [
        o for i in range(len(t)) for o in p.push(ImuSample(t[i], tuple(acc[i]), tuple(gyr[i]), tuple(mag[i]))).outputs
    ]
    said = [r.getMessage() for r in caplog.records if "noise measured at rest" in r.getMessage()]
    assert len(said) == 1 and "in use instead of the config's" in said[0]
    counters = p.counters.estimator()
    assert counters["noise_measured"] == 1 and counters["noise_rest_s"] >= 28.0
    measured = p.estimator.noise
    assert max(measured.accel_std) < 0.02 and max(measured.mag_std) < 0.25
    early, late = out[10].covariance, out[-1].covariance
    assert np.trace(late) < np.trace(early) / 4.0


def test_rest_s_zero_keeps_the_config_noise() -> None:
    config = from_dict({"noise": {"rest_s": 0}, "reference": {"magnetic": {"field_ned_uT": [20.0, 0.0, 45.0]}}})
    p = pipeline.AttitudePipeline(config)
    assert p.estimator.rest_noise is None and p.counters.estimator() == {}


def test_an_axis_without_noise_is_no_sigma_measured() -> None:
    """A simulator's noise-free axis (SITL's x and y accelerometer: 2e-14 m/s² of rounding beside 3e-3 on z) is
    not measured noise: IGN would take that axis as exact and refuse every tick (σ/|a| 1e-14); the prior stays."""
    rest = RestNoise(rest_s=10.0)
    rng = np.random.default_rng(SEED)
    for k in range(round(12.0 * RATE_HZ)):
        acc = (1e-14 * rng.normal(), 1e-14 * rng.normal(), -9.81 + rng.normal(0.0, 0.003))
        mag = tuple(np.array([20.0, 0.0, 45.0]) + rng.normal(0.0, MAG_STD))
        rest.add(k / RATE_HZ, acc, mag, tuple(np.add(GYRO_BIAS, rng.normal(0.0, GYRO_STD, 3))))
    assert rest.still_s >= 10.0 and rest.measured is None
