"""Sensor models and the scorer: the fake vehicle's noise and its error measures."""

from __future__ import annotations

import numpy as np
import pytest

from mavattitude.errors import InputError
from mavattitude.estimation.conventions import angle_between, quat_from_euler, quat_from_rotvec, quat_multiply
from mavattitude.sim import scenarios
from mavattitude.sim.scoring import compare, heading_error, score, tilt_error
from mavattitude.sim.sensors import AxisModel, SensorModel


def test_noise_bias_and_distortion_are_what_was_asked() -> None:
    rng = np.random.default_rng(1)
    std = np.array([0.01, 0.02, 0.03])
    bias = np.array([0.1, -0.2, 0.3])
    soft = np.array([[1.1, 0.05, 0.0], [0.05, 0.9, 0.02], [0.0, 0.02, 1.05]])
    model = AxisModel(noise_std=tuple(std), bias=tuple(bias), matrix=tuple(map(tuple, soft)))
    truth = np.tile([20.0, -5.0, 40.0], (20000, 1))
    out = model.apply(truth, rng)
    # Sample mean within 4σ/√N of soft·truth + bias; sample σ within 4·σ/√(2N).
    np.testing.assert_allclose(out.mean(0), soft @ truth[0] + bias, atol=4 * std.max() / np.sqrt(20000))
    np.testing.assert_allclose(out.std(0), std, rtol=4 / np.sqrt(2 * 20000))
    # The calibration S (raw − h) with S = soft⁻¹, h = bias undoes the distortion.
    undone = (out - bias) @ np.linalg.inv(soft).T
    np.testing.assert_allclose(undone.mean(0), truth[0], atol=1e-3)


def test_scale_misalignment_and_saturation() -> None:
    model = AxisModel.scaled((1.01, 0.99, 1.02), (0.0, 0.0, 0.01), full_scale=50.0)
    out = model.apply(np.array([[10.0, 0.0, 0.0], [0.0, 0.0, 100.0]]), np.random.default_rng(0))
    # y leans towards x by 0.01 rad: x input leaks 1% into y; z saturates at the full scale.
    np.testing.assert_allclose(out[0], [10.1, 0.101, 0.0], atol=1e-12)
    assert out[1, 2] == 50.0


def test_sample_times_rate_jitter_and_drops() -> None:
    rng = np.random.default_rng(2)
    model = SensorModel(rate_hz=200.0, jitter_std_s=0.0005, drop_probability=0.1)
    t = model.sample_times(0.0, 100.0, rng)
    assert np.all(np.diff(t) > 0)
    # 20 000 nominal samples, 10% dropped: binomial σ = 42, so ±300 is > 7σ.
    assert abs(len(t) - 18000) < 300
    residual = t * 200.0 - np.round(t * 200.0)
    assert np.std(residual) / 200.0 == pytest.approx(0.0005, rel=0.05)
    # Chunks join without gaps or repeats.
    plain = SensorModel(rate_hz=200.0)
    joined = np.concatenate([plain.sample_times(0.0, 0.5, rng), plain.sample_times(0.5, 1.0, rng)])
    np.testing.assert_allclose(joined, np.arange(200) / 200.0)
    with pytest.raises(InputError, match="rate_hz"):
        SensorModel(rate_hz=0.0)


def test_a_higher_rate_caps_the_jitter_instead_of_failing() -> None:
    # 1 ms of jitter is legal at 200 Hz (a fifth of the period) but not at 2 kHz (two periods): a ground
    # station raising the rate must get the largest jitter the model keeps ordered, a quarter period.
    slow = SensorModel(rate_hz=200.0, jitter_std_s=1e-3)
    with pytest.raises(InputError, match="quarter of the sample period"):
        SensorModel(rate_hz=2000.0, jitter_std_s=1e-3)
    fast = slow.at_rate(2000.0)
    assert fast.rate_hz == 2000.0 and fast.jitter_std_s == pytest.approx(0.25 / 2000.0)
    assert slow.at_rate(100.0).jitter_std_s == slow.jitter_std_s  # within the bound: kept as it is
    t = fast.sample_times(0.0, 1.0, np.random.default_rng(7))
    assert np.all(np.diff(t) > 0)


def test_tilt_and_heading_errors_separate() -> None:
    q_true = quat_from_euler(0.3, -0.4, 2.0)
    yaw_err = quat_multiply(quat_from_rotvec([0.0, 0.0, 0.05]), q_true)  # NED-frame yaw error 0.05 rad
    assert tilt_error(yaw_err, q_true) == pytest.approx(0.0, abs=1e-12)
    assert heading_error(yaw_err, q_true) == pytest.approx(0.05, abs=1e-12)
    roll_err = quat_multiply(quat_from_rotvec([0.02, 0.0, 0.0]), q_true)  # a horizontal-axis error
    assert tilt_error(roll_err, q_true) == pytest.approx(0.02, abs=1e-9)
    assert heading_error(roll_err, q_true) == pytest.approx(0.0, abs=1e-4)


def test_score_counts_broken_quaternions_and_measures_rate_and_latency() -> None:
    t = np.arange(100) / 50.0
    q_true = np.tile(scenarios.PAPER_Q, (100, 1))
    q_est = q_true.copy()
    q_est[10] = np.nan
    q_est[20] *= 1.01  # not unit
    # IMU samples 4 ms after each tick (the first at or after it enables that tick's output), one more
    # sample much later; outputs arrive 6 ms after their tick: latency 2 ms.
    sent_t = np.append(t + 0.004, 9.0)
    sent_mono = 1000.0 + sent_t
    recv_mono = 1000.0 + t + 0.006
    s = score(compare(t, q_est, recv_mono, q_true, sent_t, sent_mono))
    assert s.count == 100 and s.broken == 2
    assert s.angle_max_deg == pytest.approx(0.0, abs=1e-6)
    assert s.output_rate_hz == pytest.approx(50.0)
    assert s.latency_p50_ms == pytest.approx(2.0, abs=1e-6)
    err = quat_multiply(q_true, quat_from_rotvec([0.0, np.radians(1.0), 0.0]))
    s2 = score(compare(t, err, recv_mono, q_true, sent_t, sent_mono))
    assert s2.angle_rms_deg == pytest.approx(1.0, rel=1e-6)
    assert np.degrees(angle_between(err[0], q_true[0])) == pytest.approx(1.0)
