"""The front end: the low-pass against scipy, resampling on the vehicle clock, gaps, screening, the
magnetometer on its own times, and the batch path against the streaming one."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest
import scipy.signal
from hypothesis import given, settings
from hypothesis import strategies as st

from mavattitude.lowpass import butter2, filter_batch
from mavattitude.sensors.frontend import (
    STICKY_INTERVALS,
    FrontEnd,
    FrontEndSettings,
    ProcessedSample,
    SampleFlag,
    batch_inputs,
    process_batch,
    repeat_hold_s,
)
from mavattitude.sensors.units import ImuSample

G = 9.80665
MATCH = 1e-9  # the project's bound for matching scipy; float64 rounding of a biquad is ~1e-13 here


def _scipy_lowpass(x: np.ndarray, cutoff_hz: float, fs_hz: float) -> np.ndarray:
    sos = scipy.signal.butter(2, cutoff_hz, fs=fs_hz, output="sos")
    zi = scipy.signal.sosfilt_zi(sos)
    return np.stack([scipy.signal.sosfilt(sos, x[:, c], zi=zi * x[0, c])[0] for c in range(x.shape[1])], axis=1)


def _samples(t, acc, gyr, mag=None, mag_every=1) -> list[ImuSample]:
    out = []
    for i in range(len(t)):
        m = None if mag is None or i % mag_every else tuple(float(v) for v in mag[i])
        out.append(ImuSample(float(t[i]), tuple(map(float, acc[i])), tuple(map(float, gyr[i])), m))
    return out


def _stream(settings: FrontEndSettings, samples: list[ImuSample]) -> tuple[list[ProcessedSample], FrontEnd]:
    fe = FrontEnd(settings)
    out: list[ProcessedSample] = []
    for s in samples:
        out += fe.push(s)
    return out, fe


@pytest.mark.parametrize("fs_hz", [50.0, 200.0, 285.714, 1000.0])
def test_design_and_batch_filter_match_scipy(fs_hz: float) -> None:
    rng = np.random.default_rng(3)
    x = rng.normal(0.0, 5.0, (5000, 3))
    bq = butter2(10.0, fs_hz)
    sos = scipy.signal.butter(2, 10.0, fs=fs_hz, output="sos")[0]
    assert [bq.b0, bq.b1, bq.b2, 1.0, bq.a1, bq.a2] == pytest.approx(sos.tolist(), abs=1e-15)
    steady = np.stack([x[0], x[0]])
    got = filter_batch(bq, x.T, steady, steady).T  # channels first
    assert np.max(np.abs(got - _scipy_lowpass(x, 10.0, fs_hz))) < MATCH


def test_streaming_filter_matches_scipy_on_grid_aligned_input() -> None:
    # 50 Hz input on the 20 ms grid: every output tick is an input sample, so the output is the filter itself
    rng = np.random.default_rng(4)
    n = 2000
    t = np.arange(n) * 0.02 + 1.0
    acc = rng.normal([0, 0, -G], 2.0, (n, 3))
    gyr = rng.normal(0, 1.0, (n, 3))
    out, fe = _stream(FrontEndSettings(expected_field_uT=None), _samples(t, acc, gyr))
    assert len(out) == n and fe.counters.redesigns == 0
    assert [o.time_s for o in out] == pytest.approx(t.tolist(), abs=1e-12)
    ref = _scipy_lowpass(np.hstack([acc, gyr]), 10.0, 50.0)
    got = np.array([o.acc_mps2 + o.gyr_radps for o in out])
    assert np.max(np.abs(got - ref)) < MATCH


def test_steady_state_start_has_no_transient() -> None:
    t = np.arange(300) * 0.005
    acc = np.tile([0.3, -0.2, -G], (300, 1))
    out, _ = _stream(FrontEndSettings(), _samples(t, acc, np.zeros((300, 3)), np.tile([20.0, 1.0, 45.0], (300, 1))))
    got = np.array([o.acc_mps2 for o in out])
    assert np.max(np.abs(got - acc[0])) < 1e-12  # a constant stays exactly constant from the first sample
    assert out[0].flags & SampleFlag.RESET and not any(o.flags & SampleFlag.RESET for o in out[1:])


def test_resampling_is_on_the_vehicle_clock_grid_and_attenuates_above_cutoff() -> None:
    rng = np.random.default_rng(5)
    fs = 200.0
    t = 3.0 + np.arange(4000) / fs + rng.uniform(-0.4e-3, 0.4e-3, 4000)  # jitter ±0.4 ms
    t = np.delete(t, rng.choice(4000, 200, replace=False))  # 5 % of the messages lost
    slow = np.sin(2 * np.pi * 0.5 * t)  # 0.5 Hz: passes
    acc = np.column_stack([slow, np.zeros_like(t), np.full_like(t, -G)])
    out, fe = _stream(FrontEndSettings(), _samples(t, acc, np.zeros_like(acc)))
    times = np.array([o.time_s for o in out])
    ticks = times * 50.0
    assert np.max(np.abs(ticks - np.round(ticks))) < 1e-9  # every output on a 20 ms tick
    assert np.all(np.diff(np.round(ticks)) == 1)  # and none skipped: no gap was longer than the time-out
    assert times[0] >= t[0] and times[-1] <= t[-1]
    got = np.array([o.acc_mps2 for o in out])
    settle = times > t[0] + 0.5
    # the filter delays the 0.5 Hz wave by ~22 ms (group delay at low frequency, √2 / (2π fc)); a dropped
    # message inside the filter's memory (~5 samples) shifts that delay by one 5 ms interval: with up to
    # three there, 15 ms × the wave's slope π /s ≈ 0.05
    delay = math.sqrt(2) / (2 * np.pi * 10.0)
    assert np.max(np.abs(got[settle, 0] - np.sin(2 * np.pi * 0.5 * (times[settle] - delay)))) < 0.05
    assert fe.counters.gap_resets == 0
    # on clean 200 Hz input the 40 Hz wave keeps its 6 % (interpolating between samples never adds)
    clean_t = np.arange(4000) / fs
    # 40 Hz: a 2nd-order 10 Hz Butterworth passes 1/sqrt(1+4^4) = 6 %
    clean = np.column_stack([np.sin(2 * np.pi * 40.0 * clean_t), np.zeros(4000), np.full(4000, -G)])
    out, _ = _stream(FrontEndSettings(), _samples(clean_t, clean, np.zeros_like(clean)))
    assert max(abs(o.acc_mps2[0]) for o in out if o.time_s > 0.5) < 0.062


def test_a_gap_longer_than_the_timeout_restarts_and_is_never_bridged() -> None:
    t = np.concatenate([np.arange(0, 2, 0.01), np.arange(2.8, 4, 0.01)])  # 0.8 s silence > 0.5 s
    acc = np.column_stack([np.where(t < 2.4, 1.0, -1.0), np.zeros_like(t), np.full_like(t, -G)])
    out, fe = _stream(FrontEndSettings(input_timeout_s=0.5), _samples(t, acc, np.zeros_like(acc)))
    times = np.array([o.time_s for o in out])
    assert not np.any((times > 1.99 + 1e-9) & (times < 2.8 - 1e-9))  # nothing inside the gap
    resumed = [o for o in out if o.time_s >= 2.8 - 1e-9]
    assert resumed[0].flags & SampleFlag.RESET and resumed[0].time_s == pytest.approx(2.8)
    assert resumed[0].acc_mps2[0] == pytest.approx(-1.0, abs=1e-12)  # restarted at the new level, not smoothed
    assert fe.counters.gap_resets == 1


def test_rate_change_redesigns_the_filter() -> None:
    t = np.concatenate([np.arange(0, 2, 1 / 100), 2 + np.arange(0, 2, 1 / 400)])
    acc = np.tile([0.0, 0.0, -G], (len(t), 1))
    _, fe = _stream(FrontEndSettings(), _samples(t, acc, np.zeros_like(acc)))
    assert fe.counters.redesigns >= 1
    assert fe._imu.fs_hz == pytest.approx(400.0, rel=FrontEndSettings().rate_tolerance)


def test_screening_drops_bad_samples_and_flags_suspect_vectors() -> None:
    n = 400
    t = np.arange(n) * 0.005
    acc = np.tile([0.0, 0.0, -G], (n, 1))
    mag = np.tile([20.0, 0.0, 40.0], (n, 1))
    acc[50] = [np.nan, 0, -G]
    acc[60] = [0, 0, -200.0]  # beyond the 16 g full scale
    samples = _samples(t, acc, np.zeros((n, 3)), mag)
    samples[70] = ImuSample(samples[70].time_s, samples[70].acc_mps2, samples[70].gyr_radps, (np.inf, 0, 0))
    samples[80] = ImuSample(
        samples[80].time_s,
        samples[80].acc_mps2,
        samples[80].gyr_radps,
        samples[80].mag_uT,
        None,
        frozenset({"gyr"}),
    )
    settings = FrontEndSettings(expected_field_uT=60.0)  # |B| = 44.7: 25 % off, beyond the 15 % tolerance
    out, fe = _stream(settings, samples)
    c = fe.counters
    assert c.rejected == {"nonfinite": 1, "saturated_acc": 1, "saturated_gyr": 1}
    assert c.mag_rejected == {"nonfinite": 1}
    assert c.accepted == n - 3
    assert all(o.flags & SampleFlag.MAG_NORM and o.mag_std_scale == settings.suspect_std_scale for o in out)
    assert not any(o.flags & SampleFlag.ACC_NORM for o in out) and c.flagged["MAG_NORM"] == len(out)
    fe.set_expected_field_uT(math.hypot(20.0, 40.0))
    more = []
    for i in range(100):  # half a g of free fall for 0.5 s
        more += fe.push(ImuSample(2.0 + i * 0.005, (0.0, 0.0, -5.0), (0, 0, 0), (20.0, 0.0, 40.0)))
    assert more and not more[-1].flags & SampleFlag.MAG_NORM
    assert more[-1].flags & SampleFlag.ACC_NORM and more[-1].acc_std_scale == settings.suspect_std_scale


@pytest.mark.parametrize(
    ("rate_dps", "vertical_dps", "acc_g", "moving"),
    [
        (0.0, 0.0, 1.0, False),
        (9.0, 0.0, 1.0, False),  # about a horizontal axis: below the 10°/s that marks a turn
        (11.0, 0.0, 1.0, True),
        (0.0, 1.5, 1.0, False),  # about the vertical: below the 2°/s of a sustained turn's lean
        (0.0, 2.5, 1.0, True),
        (0.0, 0.0, 1.025, False),  # a steady acceleration at 12.7° of tilt: below the 3 % of g that marks one
        (0.0, 0.0, 1.035, True),  # at 15°
        (0.0, 0.0, 0.96, True),  # a descent's 4 % of g
    ],
)
@pytest.mark.parametrize("filtered", [True, False])
def test_a_turn_or_an_acceleration_flags_the_tick_moving(
    rate_dps: float, vertical_dps: float, acc_g: float, moving: bool, filtered
) -> None:
    """Constant inputs (the low-pass passes them unchanged), so each tick's |ω|, rate about the vertical (level:
    the z axis) and |a| are the input's."""
    n = 200
    t = np.arange(n) * 0.005
    gyr = np.tile(np.radians([rate_dps, 0.0, vertical_dps]), (n, 1))
    samples = _samples(t, np.tile([0.0, 0.0, -acc_g * G], (n, 1)), gyr, np.tile(FIELD_UT, (n, 1)))
    settings = FrontEndSettings(filter_enabled=filtered)
    stream, _ = _stream(settings, samples)
    assert len(stream) > 40 and {bool(o.flags & SampleFlag.MOVING) for o in stream} == {moving}
    assert process_batch(settings, **batch_inputs(samples)).flags.tolist() == [int(o.flags) for o in stream]


def _dead_bursts(n: int, zero_acc: list[range], zero_mag: list[range]) -> list[ImuSample]:
    """200 Hz at rest (level, a mid-latitude field) with the accelerometer or magnetometer reading exactly
    zero over the given sample ranges (a dead sensor on a glitching bus)."""
    rng = np.random.default_rng(11)
    acc = rng.normal([0.0, 0.0, -G], 0.01, (n, 3))
    mag = rng.normal(FIELD_UT, 0.25, (n, 3))
    for r in zero_acc:
        acc[r] = 0.0
    for r in zero_mag:
        mag[r] = 0.0
    return _samples(10.0 + np.arange(n) * 0.005, acc, np.zeros((n, 3)), mag)


FIELD_UT = np.array([21.9, 0.0, 44.9])


@pytest.mark.parametrize("filtered", [True, False])
def test_a_dead_sensor_is_refused_before_the_filter_not_turned_into_a_flipped_vector(filtered: bool) -> None:
    # 0.4 s of zeros (longer than the 0.3 s time-out: the filter restarts) and 0.1 s (shorter: bridged),
    # on each sensor. Without the refusal the low-pass undershoots through zero and the vector flips.
    n = 1400
    zero_acc, zero_mag = [range(200, 280), range(500, 520)], [range(800, 880), range(1100, 1120)]
    samples = _dead_bursts(n, zero_acc, zero_mag)
    settings = FrontEndSettings(
        input_timeout_s=0.3, expected_field_uT=float(np.linalg.norm(FIELD_UT)), filter_enabled=filtered
    )
    out, fe = _stream(settings, samples)
    c = fe.counters
    assert c.rejected == {"dead_acc": 100} and c.mag_rejected == {"dead": 100} and c.gap_resets == 1
    acc = np.array([o.acc_mps2 for o in out])
    mag = np.array([o.mag_uT for o in out if o.mag_uT is not None])
    # Every tick is the live vector: 0.1 m/s² and 1.5 µT are 10σ and 6σ of the unfiltered noise.
    assert np.max(np.abs(acc - [0.0, 0.0, -G])) < 0.1 and np.max(np.abs(mag - FIELD_UT)) < 1.5
    assert not any(o.flags & (SampleFlag.ACC_NORM | SampleFlag.MAG_NORM) for o in out)
    # The magnetometer's long silence is held for the 0.3 s time-out, then reported absent; its stream
    # restarts after each long burst (a dead accelerometer drops its sample's magnetometer reading too).
    assert any(o.flags & SampleFlag.NO_MAG for o in out) and c.mag_gap_resets == 2
    batch = process_batch(settings, **batch_inputs(samples))
    assert batch.counters.rejected == c.rejected and batch.counters.mag_rejected == c.mag_rejected
    assert batch.time_s.tolist() == [o.time_s for o in out]
    assert [o.flags for o in batch.samples()] == [o.flags for o in out]


def test_isolated_zero_frames_are_refused_and_bridged() -> None:
    n = 400
    tenth = [range(i, i + 1) for i in range(5, n, 10)]
    out, fe = _stream(FrontEndSettings(expected_field_uT=49.95), _dead_bursts(n, tenth, tenth))
    assert fe.counters.rejected == {"dead_acc": 40} and fe.counters.gap_resets == 0
    assert len(out) == 100 and all(o.mag_uT is not None for o in out)  # no tick lost: each hole is 10 ms
    acc = np.array([o.acc_mps2 for o in out])
    assert np.max(np.abs(acc - [0.0, 0.0, -G])) < 0.1  # 10σ of the unfiltered noise: untouched


def test_the_dead_floor_is_a_fraction_of_g_and_of_the_known_field_else_of_the_weakest_field() -> None:
    s = FrontEndSettings()
    weak = (0.0, 0.0, 2.0)  # 2 µT: 4 % of a 50 µT reference, 9 % of the weakest field on Earth (22 µT)
    for expected, dead in ((50.0, True), (None, False)):
        fe = FrontEnd(FrontEndSettings(expected_field_uT=expected))
        fe.push(ImuSample(1.0, (0.0, 0.0, -G), (0.0, 0.0, 0.0), weak))
        assert (fe.counters.mag_rejected == {"dead": 1}) is dead
    fe = FrontEnd(s)
    fe.set_expected_field_uT(50.0)  # the reference becoming known moves the floor
    fe.push(ImuSample(1.0, (0.0, 0.0, -G), (0.0, 0.0, 0.0), weak))
    assert fe.counters.mag_rejected == {"dead": 1}
    # 0.04 g is dead, 0.06 g is a (suspect) live reading: the floor is 5 % of g.
    for i, (z, dead) in enumerate(((-0.04 * G, True), (-0.06 * G, False))):
        fe.push(ImuSample(2.0 + i, (0.0, 0.0, z), (0.0, 0.0, 0.0), None))
        assert (fe.counters.rejected["dead_acc"] == 1) is True
        assert fe.counters.accepted == 1 + (not dead)


def test_slow_magnetometer_is_interpolated_on_its_own_times_and_held_then_dropped() -> None:
    # a PX4-like IMU at 250 Hz with the magnetometer new every third message (~83 Hz)
    n = 1000
    t = np.arange(n) / 250.0
    acc = np.tile([0.0, 0.0, -G], (n, 1))
    mag = np.column_stack([20 + 5 * np.sin(2 * np.pi * 0.5 * t), np.zeros(n), np.full(n, 40.0)])
    out, _ = _stream(FrontEndSettings(), _samples(t, acc, np.zeros((n, 3)), mag, mag_every=3))
    steady = [o for o in out if o.time_s > 0.5]
    assert all(o.mag_uT is not None for o in steady)
    delay = math.sqrt(2) / (2 * np.pi * 10)  # the filter's group delay, compensated in the reference
    err = {
        held: max(
            abs(o.mag_uT[0] - (20 + 5 * np.sin(2 * np.pi * 0.5 * (o.time_s - delay))))
            for o in steady
            if bool(o.flags & SampleFlag.MAG_HELD) == held
        )
        for held in (False, True)
    }
    slope = 5 * 2 * np.pi * 0.5  # µT/s, the wave's steepest
    assert err[False] < 0.03  # interpolated between magnetometer samples: the filter's residual, < 1 %
    assert err[True] < slope * 3 / 250  # held: at most one magnetometer interval (3 IMU samples) old
    assert all(o.mag_age_s == 0.0 for o in steady if not o.flags & SampleFlag.MAG_HELD)  # interpolated to the tick
    assert all(0.0 <= o.mag_age_s <= 3 / 250 for o in steady if o.flags & SampleFlag.MAG_HELD)
    # then the magnetometer stops: held for input_timeout_s, then absent
    fe = FrontEnd(FrontEndSettings(input_timeout_s=0.5))
    for s in _samples(t, acc, np.zeros((n, 3)), mag, mag_every=1)[:100]:
        fe.push(s)
    later = []
    for s in _samples(t[100:500], acc[100:500], np.zeros((400, 3))):
        later += fe.push(s)
    t_last_mag = t[99]
    held = [o for o in later if o.time_s - t_last_mag <= 0.5]
    gone = [o for o in later if o.time_s - t_last_mag > 0.5]
    assert held and all(o.flags & SampleFlag.MAG_HELD and o.mag_uT is not None for o in held)
    assert [o.mag_age_s for o in held] == pytest.approx([o.time_s - t_last_mag for o in held], abs=1e-12)
    assert gone and all(o.flags & SampleFlag.NO_MAG and o.mag_uT is None for o in gone)


def test_reboot_restarts_the_front_end() -> None:
    t = np.concatenate([100 + np.arange(200) * 0.01, 0.5 + np.arange(200) * 0.01])
    acc = np.tile([0.0, 0.0, -G], (400, 1))
    out, fe = _stream(FrontEndSettings(), _samples(t, acc, np.zeros((400, 3))))
    assert fe.counters.reboots == 1 and fe.counters.gap_resets == 0
    after = [o for o in out if o.time_s < 50]
    assert after[0].flags & SampleFlag.RESET and after[0].time_s == pytest.approx(0.5)


def test_filter_disabled_passes_every_sample_calibrated_and_mounted() -> None:
    t = np.arange(10) * 0.013
    acc = np.tile([1.0, 2.0, -G], (10, 1))
    settings = FrontEndSettings(filter_enabled=False, mounting="ROLL_180")
    out, _ = _stream(settings, _samples(t, acc, np.zeros((10, 3)), np.tile([10.0, 20.0, 30.0], (10, 1))))
    assert [o.time_s for o in out] == pytest.approx(t.tolist())
    assert out[3].acc_mps2 == pytest.approx((1.0, -2.0, G)) and out[3].mag_uT == pytest.approx((10.0, -20.0, -30.0))


def _messy_input(seed: int, n: int = 6000):
    """200 Hz with jitter, drops, a gap, a rate change, a slower magnetometer, NaN, zero and out-of-order rows."""
    rng = np.random.default_rng(seed)
    t = np.cumsum(rng.uniform(0.004, 0.006, n))
    t[n // 3 :] += 0.9  # a gap
    t[2 * n // 3 :] = t[2 * n // 3] + np.cumsum(np.full(n - 2 * n // 3, 0.0025))  # 400 Hz from here
    acc = rng.normal([0, 0, -G], 1.5, (n, 3))
    gyr = rng.normal(0, 0.5, (n, 3))
    mag = rng.normal([20, 2, 40], 3.0, (n, 3))
    acc[100] = np.nan
    acc[150:153] = 0.0  # a dead accelerometer
    mag[162:175] = 0.0  # a dead magnetometer (new readings on every third row)
    samples = _samples(t, acc, gyr, mag, mag_every=3)
    samples[200], samples[201] = samples[201], samples[200]  # reordered datagrams
    samples.insert(300, samples[299])  # a duplicate
    return samples


def _assert_same_ticks(got: list[ProcessedSample], stream: list[ProcessedSample]) -> None:
    """Batch ticks ``got`` are the streaming ones: times and flags bit for bit, the same absent
    magnetometers, values equal to rounding (the two filter forms round differently, by ~1e-13 of the signal)."""
    assert [o.time_s for o in got] == [o.time_s for o in stream]
    assert [o.flags for o in got] == [o.flags for o in stream]
    assert [o.mag_age_s for o in got] == [o.mag_age_s for o in stream]
    got_v, stream_v = (
        np.array([o.acc_mps2 + o.gyr_radps + (o.mag_uT or (np.nan,) * 3) for o in os]) for os in (got, stream)
    )
    assert np.array_equal(np.isnan(got_v), np.isnan(stream_v))
    assert np.nanmax(np.abs(got_v - stream_v), initial=0.0) < 1e-9


@pytest.mark.parametrize("filtered", [True, False])
def test_batch_path_gives_the_streaming_output(filtered: bool) -> None:
    samples = _messy_input(7)
    settings = FrontEndSettings(mounting="YAW_90", expected_field_uT=44.0, filter_enabled=filtered)
    stream, fe = _stream(settings, samples)
    batch = process_batch(settings, **batch_inputs(samples))
    assert len(batch) == len(stream) > 100
    got = batch.samples()
    _assert_same_ticks(got, stream)
    assert [o.acc_std_scale for o in got] == [o.acc_std_scale for o in stream]
    assert [o.mag_std_scale for o in got] == [o.mag_std_scale for o in stream]
    c, cb = fe.counters, batch.counters
    assert (c.received, c.accepted, c.emitted, c.gap_resets, c.redesigns) == (
        cb.received, cb.accepted, cb.emitted, cb.gap_resets, cb.redesigns
    )  # fmt: skip
    assert c.rejected == cb.rejected and c.flagged == cb.flagged and c.rejected["duplicate"] == 1
    assert c.mag_rejected == cb.mag_rejected and c.rejected["dead_acc"] == 3 and c.mag_rejected["dead"] == 5


def test_batch_edge_cases_empty_all_rejected_and_a_reboot() -> None:
    settings = FrontEndSettings()
    empty = process_batch(settings, np.empty(0), np.empty((0, 3)), np.empty((0, 3)))
    assert len(empty) == 0 and empty.counters.received == 0
    nan = np.full((5, 3), np.nan)
    rejected = process_batch(settings, np.arange(5) * 0.01, nan, nan)
    assert len(rejected) == 0 and rejected.counters.rejected == {"nonfinite": 5}
    t = np.concatenate([100 + np.arange(100) * 0.01, 0.5 + np.arange(100) * 0.01])
    acc = np.tile([0.0, 0.0, -G], (200, 1))
    batch = process_batch(settings, t, acc, np.zeros((200, 3)))
    stream, fe = _stream(settings, _samples(t, acc, np.zeros((200, 3))))
    assert batch.counters.reboots == fe.counters.reboots == 1
    assert batch.time_s.tolist() == [o.time_s for o in stream]
    # a duplicate last row after the reboot: still two epochs of ticks
    t, acc = np.append(t, t[-1]), np.vstack([acc, acc[-1]])
    batch = process_batch(settings, t, acc, np.zeros((201, 3)))
    assert batch.counters.rejected == {"duplicate": 1} and batch.time_s.tolist() == [o.time_s for o in stream]


@settings(max_examples=25, deadline=None)
@given(
    seed=st.integers(0, 2**31),
    rate_hz=st.sampled_from([50.0, 87.0, 250.0, 1000.0]),
    mag_every=st.integers(1, 4),
    filtered=st.booleans(),
)
def test_batch_equals_streaming_on_random_timing(seed: int, rate_hz: float, mag_every: int, filtered: bool) -> None:
    rng = np.random.default_rng(seed)
    n = 400
    dt = rng.choice([1.0, 1.0, 1.0, 2.0, 0.5, 0.0, 80.0], n, p=[0.6, 0.1, 0.1, 0.1, 0.05, 0.03, 0.02]) / rate_hz
    t = 5.0 + np.cumsum(dt * rng.uniform(0.9, 1.1, n))  # jitter, drops, bursts, duplicates and gaps
    acc = rng.normal([0, 0, -G], 2.0, (n, 3))
    mag = rng.normal([20, 0, 40], 5.0, (n, 3))
    acc[rng.random(n) < 0.05] = 0.0  # dead readings
    mag[rng.random(n) < 0.05] = 0.0
    samples = _samples(t, acc, rng.normal(0, 1, (n, 3)), mag, mag_every=mag_every)
    settings_ = FrontEndSettings(expected_field_uT=44.7, filter_enabled=filtered)
    stream, fe = _stream(settings_, samples)
    batch = process_batch(settings_, **batch_inputs(samples))
    assert batch.counters.rejected == fe.counters.rejected and batch.counters.mag_rejected == fe.counters.mag_rejected
    _assert_same_ticks(batch.samples(), stream)


def _repeating(t, acc, mag_t, mag, repeats: bool = True) -> list[ImuSample]:
    """An integer IMU message's stream: every sample carries the newest magnetometer reading of ``mag_t``
    (none before the first)."""
    newest = np.searchsorted(mag_t, t, side="right") - 1
    rows = [None if k < 0 else tuple(map(float, mag[k])) for k in newest]
    return [
        ImuSample(float(ti), tuple(map(float, a)), (0.0, 0.0, 0.0), m, mag_repeats=repeats)
        for ti, a, m in zip(t, acc, rows, strict=True)
    ]


def _once(samples: list[ImuSample], t, mag_t) -> list[ImuSample]:
    """The same samples with each magnetometer reading once, on the first sample after it (a log's MAG)."""
    first = np.searchsorted(t, mag_t, side="left")
    return [
        dataclasses.replace(s, mag_uT=s.mag_uT if i in first else None, mag_repeats=False)
        for i, s in enumerate(samples)
    ]


def test_a_repeated_magnetometer_reading_is_held_as_a_separate_magnetometer_stream_is() -> None:
    # RAW_IMU at 50 Hz repeating a 10 Hz compass: the ticks of a log that has each reading once (DataFlash MAG)
    n = 500
    t = np.arange(n) / 50.0
    mag_t = np.arange(100) / 10.0
    mag = np.column_stack([20 + 5 * np.sin(2 * np.pi * 0.5 * mag_t), np.zeros(100), np.full(100, 40.0)])
    acc = np.tile([0.0, 0.0, -G], (n, 1))
    repeated, once = _repeating(t, acc, mag_t, mag), _once(_repeating(t, acc, mag_t, mag), t, mag_t)
    got, _ = _stream(FrontEndSettings(), repeated)
    expected, _ = _stream(FrontEndSettings(), once)
    _assert_same_ticks(got, expected)
    assert max(o.mag_age_s for o in got) == pytest.approx(0.1 - 1 / 50, abs=1e-9)  # held up to one compass interval
    # the same values from a message that says each is new (HIGHRES_IMU's fields_updated) are new readings
    fresh, _ = _stream(FrontEndSettings(), _repeating(t, acc, mag_t, mag, repeats=False))
    assert all(o.mag_age_s == 0.0 for o in fresh)


def test_a_constant_field_at_rest_is_taken_again_never_lost() -> None:
    # the same integers for 5 s (a quiet compass at rest): held up to repeat_hold_s, then taken again
    n = 250
    t = np.arange(n) / 50.0
    acc = np.tile([0.0, 0.0, -G], (n, 1))
    settings_ = FrontEndSettings(input_timeout_s=0.5)
    out, fe = _stream(settings_, _repeating(t, acc, np.array([0.0]), np.array([[20.0, 1.0, 40.0]])))
    assert all(o.mag_uT == pytest.approx((20.0, 1.0, 40.0)) for o in out)
    assert not any(o.flags & SampleFlag.NO_MAG for o in out) and fe.counters.mag_gap_resets == 0
    hold_s = repeat_hold_s(settings_)
    assert hold_s < settings_.input_timeout_s
    assert hold_s - 1 / 50 <= max(o.mag_age_s for o in out) <= hold_s  # taken again at the first sample after


@settings(max_examples=25, deadline=None)
@given(seed=st.integers(0, 2**31), run=st.integers(1, 60), filtered=st.booleans())
def test_batch_holds_the_repeated_readings_the_stream_holds(seed: int, run: int, filtered: bool) -> None:
    rng = np.random.default_rng(seed)
    n = 600
    dt = rng.choice([1.0, 1.0, 2.0, 0.0, 40.0], n, p=[0.8, 0.1, 0.05, 0.03, 0.02]) / 50.0
    t = 5.0 + np.cumsum(dt * rng.uniform(0.9, 1.1, n))  # drops, duplicates and gaps
    t[n // 2 :] -= 4.0  # a reboot
    mag_t = np.sort(rng.uniform(t.min(), t.max(), n // run))  # readings repeated over ~run messages
    mag = np.round(rng.normal([20, 0, 40], 5.0, (len(mag_t), 3)), 1)
    mag[rng.random(len(mag_t)) < 0.05] = 0.0  # dead readings
    mag[len(mag_t) // 3 : len(mag_t) // 3 + 10] = mag[len(mag_t) // 3]  # a constant field longer than the hold
    samples = _repeating(
        np.sort(t[: n // 2]).tolist() + np.sort(t[n // 2 :]).tolist(), np.tile([0, 0, -G], (n, 1)), mag_t, mag
    )
    settings_ = FrontEndSettings(expected_field_uT=44.7, filter_enabled=filtered)
    stream, fe = _stream(settings_, samples)
    batch = process_batch(settings_, **batch_inputs(samples))
    assert batch.counters.mag_rejected == fe.counters.mag_rejected and batch.counters.reboots == fe.counters.reboots
    assert batch.counters.redesigns == fe.counters.redesigns
    _assert_same_ticks(batch.samples(), stream)


def _slow_then_fast(seed: int, slow_s: float = 30.0, fast_s: float = 3.0) -> list[ImuSample]:
    """2 Hz with ±0.06 s of jitter (intervals of 0.44-0.56 s: many longer than input_timeout_s), then 100 Hz."""
    rng = np.random.default_rng(seed)
    slow_t = 1.013 + np.arange(0.0, slow_s, 0.5) + rng.uniform(-0.03, 0.03, round(slow_s / 0.5))
    fast_t = slow_t[-1] + 0.5 + np.arange(0.0, fast_s, 0.01)
    t = np.concatenate([slow_t, fast_t])
    n = len(t)
    acc = rng.normal([0, 0, -G], 1.0, (n, 3))
    return _samples(t, acc, rng.normal(0, 0.5, (n, 3)), rng.normal([20, 2, 40], 2.0, (n, 3)))


def test_a_slow_stream_gives_one_unfiltered_attitude_per_sample_and_no_gap_at_its_own_pace() -> None:
    samples = _slow_then_fast(5, fast_s=0.0)
    out, fe = _stream(FrontEndSettings(), samples)
    # the first sample, its pace not known yet, is a filtered stream's start (off the 50 Hz grid: no tick)
    assert [o.time_s for o in out] == [s.time_s for s in samples[1:]]
    assert all(o.flags & SampleFlag.PER_SAMPLE for o in out) and fe.per_sample
    assert [o.flags & SampleFlag.RESET for o in out].count(SampleFlag.RESET) == 1  # the switch, not a gap
    assert fe.counters.gap_resets == 0 and fe.counters.per_sample == len(out)
    got = np.array([o.acc_mps2 + o.gyr_radps + o.mag_uT for o in out])
    sent = np.array([s.acc_mps2 + s.gyr_radps + s.mag_uT for s in samples[1:]])
    assert np.max(np.abs(got - sent)) < 1e-12  # unfiltered: the input through the identity calibration, rounded
    assert fe.rate_hz == pytest.approx(2.0, rel=0.05) and fe.gap_limit_s == pytest.approx(1.25, rel=0.1)


def test_a_slow_stream_still_has_gaps_when_messages_are_lost() -> None:
    samples = _slow_then_fast(6, fast_s=0.0)
    del samples[30:34]  # 2.5 s without a message: more than 2.5 of its 0.5 s intervals
    out, fe = _stream(FrontEndSettings(), samples)
    assert fe.counters.gap_resets == 1 and len(out) == len(samples) - 1


@pytest.mark.parametrize("filtered", [True, False])
def test_a_stream_that_speeds_up_is_filtered_again_on_the_grid_and_the_batch_path_agrees(filtered: bool) -> None:
    samples = _slow_then_fast(7)
    settings = FrontEndSettings(expected_field_uT=44.7, filter_enabled=filtered)
    stream, fe = _stream(settings, samples)
    fast = [o for o in stream if not o.flags & SampleFlag.PER_SAMPLE and o.time_s > samples[1].time_s]
    # the pace turns when most of the last 32 intervals are short: the 17th fast sample
    assert fast[0].flags & SampleFlag.RESET and not fe.per_sample
    assert fast[0].time_s == pytest.approx(samples[-300 + 16].time_s, abs=0.02)
    if filtered:
        assert np.allclose(np.diff([o.time_s for o in fast]), 0.02)  # the 50 Hz ticks
    batch = process_batch(settings, **batch_inputs(samples))
    _assert_same_ticks(batch.samples(), stream)
    assert batch.counters.per_sample == fe.counters.per_sample == 59 + 16


@pytest.mark.parametrize(("rate_hz", "slow"), [(20.0, True), (23.0, False)])
def test_a_stream_at_the_boundary_keeps_one_pace(rate_hz: float, slow: bool) -> None:
    """20 Hz with ±3 ms of jitter (intervals on both sides of 50 ms) is slow throughout, 23 Hz (between the slow
    and the fast pace) filtered throughout: neither flips between the two, and the batch path agrees."""
    rng = np.random.default_rng(8)
    n = 400
    t = 1.0 + np.arange(n) / rate_hz + rng.uniform(-0.003, 0.003, n)
    samples = _samples(t, rng.normal([0, 0, -G], 0.5, (n, 3)), rng.normal(0, 0.1, (n, 3)), np.full((n, 3), 30.0))
    stream, fe = _stream(FrontEndSettings(), samples)
    per_sample = [bool(o.flags & SampleFlag.PER_SAMPLE) for o in stream]
    resets = sum(bool(o.flags & SampleFlag.RESET) for o in stream)
    if slow:  # from the second sample (the first, its pace unknown, starts a filtered stream off the grid)
        assert all(per_sample) and fe.counters.per_sample == len(stream) == n - 1 and resets == 1
    else:  # the first few intervals, by chance longer than 45 ms, may make a sample slow; never once 8 are in
        late = [p for p, o in zip(per_sample, stream, strict=True) if o.time_s > t[STICKY_INTERVALS]]
        assert not any(late) and len(late) > 0.9 * len(stream)
    _assert_same_ticks(process_batch(FrontEndSettings(), **batch_inputs(samples)).samples(), stream)
