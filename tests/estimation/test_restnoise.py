"""The noise measured at rest: the σ of still ticks, motion left out, and IGN weighing with them in the pipeline."""

from __future__ import annotations

import importlib.util
import logging
from pathlib import Path

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


def test_a_reboot_starts_a_block_and_the_rest_after_it_counts() -> None:
    """6 s still, the autopilot reboots (its clock from 100 s back to 2 s), 6 s still again: the block the reboot
    cut is dropped and a new one starts, so the blocks after it close as before (else none would until the new
    clock passed 100 s) and the σ come from 10 still seconds."""
    rest = RestNoise(rest_s=10.0)
    _still(rest, 100.0, 6.0, np.random.default_rng(SEED))
    _still(rest, 2.0, 6.0, np.random.default_rng(SEED + 1))
    assert rest.still_s == pytest.approx(10.0)  # 5 closed blocks each side: the last of each is still open or cut
    # 500 ticks: each σ's relative sampling error 1/√(2n) ≈ 3 %; 15 % is 5 of it
    assert rest.measured is not None and rest.measured.accel_std == pytest.approx(ACC_STD, rel=0.15)


def test_a_stream_without_noise_is_no_sigma_measured_and_ign_keeps_solving() -> None:
    """Every axis constant but for arithmetic rounding (a noise-free simulator's stream through the low-pass): σ of
    1e-12 on all axes alike (a few hundred ulps of 45 µT) passes the axes' ratio, but is no sensor's noise. Taken as
    R, IGN's weights would be ~1e24 and its solves refused; the config's prior stays and every tick is solved."""
    rest = RestNoise(rest_s=10.0)
    rng = np.random.default_rng(SEED)
    for k in range(round(12.0 * RATE_HZ)):
        acc = tuple(np.array([0.01, -0.02, -9.8]) + rng.normal(0.0, 1e-12, 3))
        mag = tuple(np.array([20.0, 1.0, 45.0]) + rng.normal(0.0, 1e-12, 3))
        rest.add(k / RATE_HZ, acc, mag, (0.001, -0.002, 0.003))
    assert rest.still_s >= 10.0 and rest.measured is None
    config = from_dict({"reference": {"magnetic": {"field_ned_uT": [20.0, 1.0, 45.0]}}})
    p = pipeline.AttitudePipeline(config)
    still = ((0.01, -0.02, -9.8), (0.001, -0.002, 0.003), (20.0, 1.0, 45.0))
    outputs = [o for k in range(4000) for o in p.push(ImuSample(k / 200.0, *still)).outputs]
    assert len(outputs) == p.counters.ticks == 1000 and not p.counters.rejected  # 20 s at 50 Hz, none refused


def _fused_at_rest(rest_s: float, seconds: float = 20.0) -> tuple[pipeline.AttitudePipeline, np.ndarray]:
    """The fake vehicle still for ``seconds`` (consumer sensors at 100 Hz, gyro bias (2, −1, 1.5) mrad/s, σ 3 mrad/s)
    through the pipeline with ``method: fused``; the pipeline and the sensor model's true gyro bias."""
    script, sensors = scenarios.static(seconds), scenarios.consumer_sensors(100.0)
    rng = np.random.default_rng(SEED)
    t = sensors.sample_times(0.0, script.duration_s, rng)
    acc, gyr, mag = sensors.measure(script, t, rng)
    config = from_dict(
        {
            "estimator": {"method": "fused"},
            "noise": {"rest_s": rest_s},
            "reference": {"magnetic": {"field_ned_uT": list(scenarios.DEFAULT_MAG_NED_UT)}},
        }
    )
    p = pipeline.AttitudePipeline(config)
    for i in range(len(t)):
        p.push(ImuSample(t[i], tuple(acc[i]), tuple(gyr[i]), tuple(mag[i])))
    return p, np.array(sensors.gyro.bias)


def test_a_fused_filter_started_after_the_rest_starts_from_its_gyro_bias(caplog: pytest.LogCaptureFixture) -> None:
    """20 s still: the measurement is in after 10 s (said once, counted); the running filter keeps its own bias
    (its zero-rate updates saw the same stillness). A filter started after it (here: the estimator reset, as the
    pipeline does after an invalid output; or the input fast again after a too-slow stretch) starts from the
    measured bias, within 4σ/√n of the true one (σ 3 mrad/s, n ≈ 19 s × 50 samples a second taken), its ``P_bb``
    the standard error and the bias walk since: below (0.5 mrad/s)², not the prior's (20 mrad/s)²."""
    caplog.set_level(logging.INFO, logger="mavattitude.pipeline")
    p, bias = _fused_at_rest(10.0)
    said = [r.getMessage() for r in caplog.records if "noise measured at rest" in r.getMessage()]
    assert len(said) == 1 and "the fused filter's start" in said[0]
    counters = p.counters.estimator()
    assert counters["noise_measured"] == 1 and counters["noise_rest_s"] >= 18.0 and counters["bias_from_rest"] == 0
    p.estimator.reset()
    p.push(ImuSample(20.0, (0.0, 0.0, -9.81), tuple(bias), tuple(scenarios.DEFAULT_MAG_NED_UT)))
    started = p.estimator._filter
    assert started.bias_radps == pytest.approx(bias, abs=4 * 0.003 / np.sqrt(19 * 50))
    assert np.all(np.diag(started.covariance)[3:] < 0.0005**2)
    assert p.counters.estimator()["bias_from_rest"] == 1


def test_without_the_rest_measurement_a_fused_filter_starts_from_no_bias() -> None:
    """``noise.rest_s: 0``: no measurement, no counters for it; a new filter starts from zero bias and the prior."""
    p, _ = _fused_at_rest(0.0, seconds=3.0)
    assert p.estimator.rest_noise is None and "noise_measured" not in p.counters.estimator()
    p.estimator.reset()
    p.push(ImuSample(3.0, (0.0, 0.0, -9.81), (0.0, 0.0, 0.0), tuple(scenarios.DEFAULT_MAG_NED_UT)))
    started = p.estimator._filter
    assert started.bias_radps.tolist() == [0.0, 0.0, 0.0]
    assert np.diag(started.covariance)[3:] == pytest.approx([0.02**2] * 3)  # gyro_bias_init_radps


def test_the_magnetometer_sigma_at_rest_floors_the_fused_sigma_m() -> None:
    """The fused σ_m (3.75 µT) is an effective value, sensor noise included: a magnetometer measured noisier at rest
    (6 µT on its worst axis) raises it to that; a quieter one (BROAD's 0.7 µT) leaves it."""
    from mavattitude.estimation.fused import FusedFilter, FusedSettings

    f = FusedFilter(FusedSettings(), scenarios.DEFAULT_MAG_NED_UT)
    f.set_rest_noise(0.7, (0.0, 0.0, 0.0), (1e-4,) * 3)
    assert f._mag_var == pytest.approx(3.75**2)
    f.set_rest_noise(6.0, (0.0, 0.0, 0.0), (1e-4,) * 3)
    assert f._mag_var == pytest.approx(36.0)


def _noise_at_rest_tool():
    path = Path(__file__).resolve().parents[2] / "tools" / "noise_at_rest.py"
    spec = importlib.util.spec_from_file_location("noise_at_rest_tool", path)
    assert spec is not None and spec.loader is not None
    tool = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(tool)
    return tool


def test_ign_at_rest_with_the_noise_it_measured_claims_the_scatter_it_has() -> None:
    """The issue's target on the fake vehicle at rest (60 s, consumer sensors at 200 Hz, seeded), scored as
    ``tools/noise_at_rest.py`` scores it, on the ~2 500 ticks after the switch to the measured σ:

    - the σ the covariance claims is within 10 % of the error's scatter on every axis. The scatter is an RMS over
      ~50 s of ticks low-passed at 10 Hz (about 2 × 11 Hz × 50 s ≈ 1 100 independent values: ±2 % at 1σ) and the
      claim comes from σ measured over 10–59 s of rest (±2–5 %): 10 % is two to three of their combined σ;
    - its rest RMS is no worse than IGN's with the sensors' true σ handed in (the same samples, only the weights
      differ), to 1 %: below the ±2 % the RMS itself is known to, so the weighting costs nothing measurable.
    The config's default σ claims 4–5 times the scatter: the check can fail."""
    tool = _noise_at_rest_tool()
    runs, rest = tool.scores(*tool.sim_recording(seed=0))
    rms_measured, ratio_measured = runs["measured"]
    rms_true, _ = runs["true"]
    assert rest.still_s >= 55.0
    assert np.all(np.abs(ratio_measured - 1.0) <= 0.10), ratio_measured
    assert rms_measured <= 1.01 * rms_true
    assert np.all(runs["config"][1] > 3.0)
