"""The streaming pipeline: front end → estimator, warm starts, rejected samples, checked outputs."""

from __future__ import annotations

import dataclasses
import datetime as dt

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from mavattitude import pipeline as pipeline_module
from mavattitude.config import from_dict
from mavattitude.errors import ConfigError
from mavattitude.estimation import solve as real_solve
from mavattitude.estimation.compass import measured_dip_deg
from mavattitude.estimation.conventions import angle_between, quat_from_euler, rotate_ned_to_body
from mavattitude.estimation.velocity import GpsVelocity
from mavattitude.pipeline import AttitudeOutput, AttitudePipeline, CrossCheckGate
from mavattitude.reports import heading_lost
from mavattitude.sensors.frontend import SampleFlag
from mavattitude.sensors.magref import field_from_angles, wmm_field_ned_uT
from mavattitude.sensors.units import STANDARD_GRAVITY_MPS2, ImuSample

G = STANDARD_GRAVITY_MPS2
FIELD_NED_UT = np.array(field_from_angles(2.0, 60.0, 50.0))
Q_TRUE = quat_from_euler(np.radians(10.0), np.radians(-20.0), np.radians(135.0))
ACC_STD, MAG_STD = 0.05, 0.5  # the config's default σ, used to draw the noise below
MAX_ERR_DEG = 1.7  # 4σ of the filtered heading error (test_static_attitude_at_the_output_rate)
ANGLES = {"reference": {"magnetic": {"declination_deg": 2.0, "inclination_deg": 60.0, "intensity_uT": 50.0}}}


def static_samples(
    n: int = 400,
    rate_hz: float = 200.0,
    q: np.ndarray = Q_TRUE,
    field_ned_uT: np.ndarray = FIELD_NED_UT,
    board_from_body: np.ndarray | None = None,
    seed: int = 1,
    t0_s: float = 10.0,
) -> list[ImuSample]:
    """A vehicle at rest at attitude ``q``: specific force −g (up), the field, seeded white noise."""
    rng = np.random.default_rng(seed)
    acc = rotate_ned_to_body(q, [0.0, 0.0, -G]) + rng.normal(0.0, ACC_STD, (n, 3))
    mag = rotate_ned_to_body(q, field_ned_uT) + rng.normal(0.0, MAG_STD, (n, 3))
    gyr = rng.normal(0.0, 1e-3, (n, 3))
    if board_from_body is not None:
        acc, mag, gyr = acc @ board_from_body.T, mag @ board_from_body.T, gyr @ board_from_body.T
    return [ImuSample(t0_s + i / rate_hz, tuple(acc[i]), tuple(gyr[i]), tuple(mag[i])) for i in range(n)]


def pushes(p: AttitudePipeline, samples: list[ImuSample]) -> list:
    return [p.push(s) for s in samples]


def run(p: AttitudePipeline, samples: list[ImuSample]) -> list:
    return [o for pushed in pushes(p, samples) for o in pushed.outputs]


def test_static_attitude_at_the_output_rate():
    p = AttitudePipeline(from_dict(ANGLES))
    out = run(p, static_samples())
    # 2 s of input at 200 Hz → the 50 Hz ticks from 10.00 s to 11.98 s.
    assert len(out) == 100
    assert np.allclose(np.diff([o.time_s for o in out]), 0.02)
    settled_deg = np.degrees(angle_between(np.array([o.q for o in out[10:]]), Q_TRUE))
    # Per raw sample the heading σ is σ_m/(B cos I) = 0.5/25 rad = 1.15°, plus the tilt error (σ_a/g = 0.29°)
    # × tan I = 0.50°: 1.25° together. The 10 Hz Butterworth passes 11.1 Hz of the 100 Hz input band:
    # σ × 0.33 ≈ 0.42°. The first ticks still carry the first raw sample (the filter starts at its steady
    # state), hence out[10:].
    assert np.sqrt(np.mean(settled_deg**2)) < 0.5
    assert settled_deg.max() < MAX_ERR_DEG
    assert all(o.converged for o in out)
    assert all(np.allclose(o.rates_radps, 0.0, atol=3e-3) for o in out)  # gyro noise σ 1e-3 rad/s
    assert p.counters.emitted == 100 and not p.counters.rejected
    assert SampleFlag.RESET in out[0].flags and SampleFlag.RESET not in out[1].flags


def test_covariance_is_the_solvers_3x3_prediction():
    out = run(AttitudePipeline(from_dict(ANGLES)), static_samples(n=40))
    cov = out[-1].covariance
    assert cov.shape == (3, 3)
    assert np.allclose(cov, cov.T)
    assert np.all(np.linalg.eigvalsh(cov) > 0)
    # Its size follows the noise model: the tilt σ is of order σ_a/g (unfiltered per-sample σ).
    assert 0.1 * ACC_STD / G < np.sqrt(cov[0, 0]) < 10 * ACC_STD / G


def test_each_tick_is_solved_from_triad_whatever_came_before(monkeypatch):
    """No tick's answer depends on the ticks before it: every solve starts from TRIAD, its answer and corrections
    those of the same solve made alone, across a gap as before one."""
    calls = []

    def recording_solve(*args, **kwargs):
        calls.append((args, kwargs))
        return real_solve(*args, **kwargs)

    monkeypatch.setattr(pipeline_module, "solve", recording_solve)
    p = AttitudePipeline(from_dict(ANGLES))
    out = run(p, static_samples(n=60, t0_s=10.0)) + run(p, static_samples(n=60, t0_s=11.2))  # 0.8 s gap: a reset
    assert p.frontend.counters.gap_resets == 1
    assert len(calls) == len(out) >= 20  # ticks of both runs (the resampler outputs once per 0.02 s)
    for (args, kwargs), o in zip(calls, out, strict=True):
        alone = real_solve(*args, **{k: v for k, v in kwargs.items() if k != "q0"})
        assert kwargs.get("q0") is None
        assert np.array_equal(o.q, alone.q) and o.iterations == alone.iterations


def test_degenerate_samples_are_counted_not_emitted():
    p = AttitudePipeline(from_dict(ANGLES))
    # Field along gravity (inclination 90°) while the reference is at 60°: the measured vectors are collinear.
    vertical = np.array([0.0, 0.0, 50.0])
    bad = run(p, static_samples(n=40, field_ned_uT=vertical))
    assert bad == []
    assert p.counters.rejected["DegenerateGeometryError"] == p.counters.ticks > 0
    assert "from collinear" in str(p.last_error)
    good = run(p, static_samples(n=40, t0_s=10.2))
    assert len(good) > 0
    assert np.degrees(angle_between(good[-1].q, Q_TRUE)) < MAX_ERR_DEG


class _Broken:
    def __init__(self, q):
        self.q, self.iterations, self.converged, self.covariance = np.asarray(q), 1, True, np.eye(3)


@pytest.mark.parametrize("bad_q", [[np.nan, 0, 0, 0], [1.0, 0.01, 0, 0], [np.inf, 0, 0, 0]])
def test_a_non_finite_or_non_unit_quaternion_is_never_output(monkeypatch, bad_q):
    def broken_solve(*args, **kwargs):
        return _Broken(bad_q)

    monkeypatch.setattr(pipeline_module, "solve", broken_solve)
    p = AttitudePipeline(from_dict(ANGLES))
    assert run(p, static_samples(n=40)) == []
    assert p.counters.rejected["invalid_quaternion"] == p.counters.ticks > 0


class _NonFiniteRates:
    wants_filtered = True

    def __init__(self):
        self.resets = 0

    def estimate(self, sample, mag_ref_ned_uT):
        return [AttitudeOutput(sample.time_s, np.array([1.0, 0, 0, 0]), np.array([0.0, np.inf, -np.inf]), 1, True)]

    def reset(self):
        self.resets += 1


def test_non_finite_rates_are_never_output():
    p = AttitudePipeline(from_dict(ANGLES))
    p.estimator = estimator = _NonFiniteRates()
    assert run(p, static_samples(n=40)) == []
    assert p.counters.rejected["invalid_rates"] == p.counters.ticks == estimator.resets > 0


def test_the_fused_filter_awaiting_the_reference_tracks_the_tilt_and_counts_no_compass_finding():
    """reference.magnetic auto, no position for 71 s (position_wait_s 600: no field measured either): the fused
    filter runs on roll and pitch alone, its outputs dropped, and its counters leave that out, so the heading-lost
    finding (a compass without a heading for 60 s) is not said of a compass nobody asked yet. When the position
    comes, the outputs start at once on the tracked tilt, with the field's heading."""
    p = AttitudePipeline(from_dict({"estimator": {"method": "fused"}, "reference": {"position_wait_s": 600.0}}))
    when, (lat, lon, alt) = dt.date(2026, 6, 1), (48.14, 11.58, 520.0)
    samples = static_samples(n=3600, rate_hz=50.0, field_ned_uT=np.array(wmm_field_ned_uT(lat, lon, alt, when)))
    assert run(p, samples[:3550]) == []
    own = p.counters.estimator()
    assert own["updates"] == own["tilt_only_updates"] == own["heading_gap_s"] == 0
    assert heading_lost(own) is None
    assert p.set_position(lat, lon, alt, when)
    out = run(p, samples[3550:])
    # one sample's noise on the tilt the filter kept (σ_a / g = 0.29° per axis, averaged over a minute) and on
    # the heading it takes from one reading (1.25°, test_static_attitude_at_the_output_rate): 4σ of the latter
    assert np.degrees(angle_between(out[0].q, Q_TRUE)) < 5.0
    assert np.degrees(angle_between(out[-1].q, Q_TRUE)) < MAX_ERR_DEG
    own = p.counters.estimator()
    assert own["updates"] > 0 and own["tilt_only_updates"] == 0 and heading_lost(own) is None


def test_auto_reference_waits_for_a_position_then_uses_the_world_magnetic_model():
    p = AttitudePipeline(from_dict({}))  # reference.magnetic: auto
    assert p.waiting_for_reference
    when = dt.date(2026, 6, 1)
    lat, lon, alt = 48.14, 11.58, 520.0
    wmm = np.array(wmm_field_ned_uT(lat, lon, alt, when))
    samples = static_samples(n=200, field_ned_uT=wmm)
    assert run(p, samples[:100]) == []
    assert p.counters.waiting == p.counters.ticks > 0 and not p.counters.rejected  # waited, not refused
    assert p.set_position(lat, lon, alt, when)
    assert not p.waiting_for_reference
    out = run(p, samples[100:])
    assert len(out) > 0
    assert np.degrees(angle_between(out[-1].q, Q_TRUE)) < MAX_ERR_DEG
    assert np.isclose(p.frontend.expected_field_uT, np.linalg.norm(wmm))  # |B| screening on
    assert not p.set_position(lat + 0.001, lon, alt, when)  # ~100 m: not recomputed


def test_without_the_filter_every_input_sample_is_solved():
    p = AttitudePipeline(from_dict({**ANGLES, "filter": {"enabled": False}}))
    samples = static_samples(n=30, rate_hz=100.0)
    out = run(p, samples)
    assert [o.time_s for o in out] == [s.time_s for s in samples]
    # Unfiltered: per-sample heading σ ≈ 1.1° (static test), so 5° is > 4σ.
    assert np.degrees(angle_between(np.array([o.q for o in out]), Q_TRUE)).max() < 5.0


def test_mounting_from_the_config_reaches_the_front_end():
    yaw_90 = np.array([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])  # body = Rz(90°) board
    samples = static_samples(n=100, board_from_body=yaw_90.T)
    mounted = run(AttitudePipeline(from_dict({**ANGLES, "mounting": {"rotation": "YAW_90"}})), samples)
    unmounted = run(AttitudePipeline(from_dict(ANGLES)), samples)
    assert np.degrees(angle_between(mounted[-1].q, Q_TRUE)) < MAX_ERR_DEG
    assert np.degrees(angle_between(unmounted[-1].q, Q_TRUE)) > 45.0


@pytest.mark.parametrize("follow", [True, False])
def test_the_autopilots_level_trim_turns_the_attitude_into_the_vehicles_frame(follow, caplog):
    """The autopilot's board sits rolled 3° and pitched down 6° in a frame at Q_TRUE; its readings (RAW_IMU)
    are the board's. ArduPilot's level calibration stores that as AHRS_TRIM_X/Y, and its attitude is the
    frame's; so is ours once the trim is known (``mounting.autopilot_trim``, on by default)."""
    board_in_frame = quat_from_euler(np.radians(3.0), np.radians(-6.0), 0.0)
    samples = static_samples(n=100)
    turned = [
        ImuSample(
            s.time_s, *(tuple(rotate_ned_to_body(board_in_frame, v)) for v in (s.acc_mps2, s.gyr_radps, s.mag_uT))
        )
        for s in samples
    ]
    p = AttitudePipeline(from_dict({**ANGLES, "mounting": {"autopilot_trim": follow}}))
    assert p.set_autopilot_parameter("AHRS_TRIM_X", np.radians(3.0)) is follow
    assert p.set_autopilot_parameter("AHRS_TRIM_Y", np.radians(-6.0)) is follow
    assert not p.set_autopilot_parameter("AHRS_TRIM_Y", np.radians(-6.0))  # said again: nothing changes
    assert not p.set_autopilot_parameter("COMPASS_USE", 1.0)
    off_deg = np.degrees(angle_between(run(p, turned)[-1].q, Q_TRUE))
    assert off_deg < MAX_ERR_DEG if follow else off_deg > 6.7 - MAX_ERR_DEG  # the board's 6.7° off the frame
    # beyond the ±10° the autopilot keeps it to: no trim, said
    assert not p.set_autopilot_parameter("AHRS_TRIM_X", 0.2) and not p.set_autopilot_parameter("AHRS_TRIM_Y", np.nan)
    if follow:
        assert sum("no level trim" in r.getMessage() for r in caplog.records) == 2


def test_an_unknown_mounting_name_is_a_config_error():
    with pytest.raises(ConfigError, match="unknown mounting rotation 'YAW_91'"):
        AttitudePipeline(from_dict({"mounting": {"rotation": "YAW_91"}}))


@pytest.mark.parametrize("method", ["cgn", "ml", "triad"])
def test_every_snapshot_method_runs(method):
    out = run(AttitudePipeline(from_dict({**ANGLES, "estimator": {"method": method}})), static_samples(n=100))
    assert len(out) == 25
    assert np.degrees(angle_between(out[-1].q, Q_TRUE)) < MAX_ERR_DEG
    if method == "triad":
        assert all(o.iterations == 0 for o in out)


def test_the_fused_filter_plugs_in():
    p = AttitudePipeline(from_dict({**ANGLES, "estimator": {"method": "fused"}}))
    out = run(p, static_samples(n=400))
    assert len(out) > 50
    assert np.allclose(np.diff([o.time_s for o in out]), 0.02)  # the filter's own 50 Hz ticks
    assert out[0].time_s == 10.0 and not any(SampleFlag.RESET in o.flags for o in out)  # the filter's own business
    q = np.array([o.q for o in out])
    assert np.allclose(np.linalg.norm(q, axis=1), 1.0)
    # At rest the filter is no worse than the snapshot bound.
    assert np.degrees(angle_between(q[-1], Q_TRUE)) < MAX_ERR_DEG
    assert out[-1].covariance.shape == (3, 3)


def test_the_fused_filter_takes_a_changed_reference_without_a_restart(monkeypatch):
    p = AttitudePipeline(from_dict({**ANGLES, "estimator": {"method": "fused"}}))
    samples = static_samples(n=400)
    run(p, samples[:200])
    fused = p.estimator._filter
    calls: list[np.ndarray] = []
    set_mag_ref = fused.set_mag_ref
    monkeypatch.setattr(fused, "set_mag_ref", lambda ref: (calls.append(np.array(ref)), set_mag_ref(ref))[1])
    p.set_magnetic_reference(p.mag_ref_ned_uT.copy())  # a new array holding the same field: not a change
    run(p, samples[200:300])
    assert calls == []
    moved = np.array(field_from_angles(3.0, 60.0, 50.0))
    p.set_magnetic_reference(moved)
    assert run(p, samples[300:])
    assert p.estimator._filter is fused  # the state kept: no re-initialisation from IGN
    assert len(calls) == 1 and np.array_equal(calls[0], moved)


def test_a_compass_upside_down_sets_heading_only_and_the_tilt_is_the_accelerometers():
    flipped = [dataclasses.replace(s, mag_uT=(s.mag_uT[0], s.mag_uT[1], -s.mag_uT[2])) for s in static_samples(n=400)]
    p = AttitudePipeline(from_dict(ANGLES))
    results = pushes(p, flipped)
    out = [o for r in results for o in r.outputs]
    assert out and all(SampleFlag.MAG_HEADING_ONLY in o.flags for o in out)  # from the first tick: its own dip is off
    for o, tick_acc in zip(out, _filtered_acc(flipped), strict=False):
        down = -tick_acc / np.linalg.norm(tick_acc)
        # sin of the angle between the output's vertical and the accelerometer's: zero to rounding
        assert np.linalg.norm(np.cross(rotate_ned_to_body(o.q, [0.0, 0.0, 1.0]), down)) < 1e-12
        assert down @ o.covariance @ down > 1.0  # rad²: the heading is unknown
    said = [i for i, r in enumerate(results) if r.compass]  # the push that changed the verdict returns it, once
    assert len(said) == 1 and [e.inconsistent for e in results[said[0]].compass] == [True]
    assert results[said[0]].outputs  # with the tick it judged
    mag_flipped = rotate_ned_to_body(Q_TRUE, FIELD_NED_UT) * [1.0, 1.0, -1.0]
    expected_dip_deg = measured_dip_deg(tuple(rotate_ned_to_body(Q_TRUE, [0.0, 0.0, -G])), tuple(mag_flipped))
    assert p.compass.figures().dip_deg == pytest.approx(expected_dip_deg, abs=0.5)  # noise: σ_dip 0.65°/√n


def _ticks(samples: list[ImuSample]) -> list:
    """The front end's ticks for these samples."""
    frontend = AttitudePipeline(from_dict(ANGLES)).frontend
    return [t for s in samples for t in frontend.push(s)]


def _filtered_acc(samples: list[ImuSample]) -> list[np.ndarray]:
    """The ticks' specific force (what the heading-only solution keeps exactly)."""
    return [np.array(t.acc_mps2) for t in _ticks(samples)]


def test_a_good_compass_leaves_ign_the_papers_ign():
    p = AttitudePipeline(from_dict(ANGLES))
    ticks = _ticks(static_samples(n=400))
    results = pushes(p, static_samples(n=400))
    out = [o for r in results for o in r.outputs]
    assert not any(o.flags & (SampleFlag.MAG_HEADING_ONLY | SampleFlag.MAG_INCONSISTENT) for o in out)
    assert p.compass.figures().warnings == 0 and not any(r.compass for r in results)
    noise = pipeline_module._noise_model(p.config)
    plain = [real_solve(t.acc_mps2, t.mag_uT, FIELD_NED_UT, noise, "ign").q for t in ticks]
    assert np.degrees(angle_between(np.array([o.q for o in out]), np.array(plain))).max() < 1e-6


@pytest.mark.parametrize("method", ["ign", "cgn", "ml", "triad", "fused"])
def test_output_covariances_at_once_are_each_outputs_bit_for_bit(method):
    """The CSV's covariances are computed for all outputs at once: the same values as one by one, exactly (the
    kernel's arithmetic is elementwise); heading-only outputs (an upside-down compass) and the fused filter's
    go one by one."""
    samples = static_samples(n=200)
    flipped = [dataclasses.replace(s, mag_uT=(s.mag_uT[0], s.mag_uT[1], -s.mag_uT[2])) for s in static_samples(n=200)]
    p = AttitudePipeline(from_dict({**ANGLES, "estimator": {"method": method}}))
    out = run(p, samples) + run(AttitudePipeline(from_dict({**ANGLES, "estimator": {"method": method}})), flipped)
    assert method == "fused" or any(SampleFlag.MAG_HEADING_ONLY in o.flags for o in out)
    one_by_one = np.array([o.covariance_or_nan() for o in out])
    assert np.array_equal(pipeline_module.output_covariances(out), one_by_one)


@pytest.mark.parametrize("method", ["ign", "fused"])
def test_without_a_position_one_by_one_and_at_once_measure_the_same_field(method):
    """reference.magnetic: auto and no position: after reference.position_wait_s the field the ticks measure,
    by the same rule whether the samples come one by one (live) or as arrays (replay): the same outputs."""
    config = from_dict({"estimator": {"method": method}, "reference": {"position_wait_s": 3.0}})
    samples = static_samples(n=1000)  # 5 s at 200 Hz from 10 s
    one = AttitudePipeline(config)
    by_one = run(one, samples)
    rows = {k: np.array([getattr(s, k) for s in samples]) for k in ("time_s", "acc_mps2", "gyr_radps", "mag_uT")}
    batch = AttitudePipeline(config)
    at_once = batch.push_batch(
        rows["time_s"], rows["acc_mps2"], rows["gyr_radps"], rows["mag_uT"], np.ones(len(samples), dtype=bool)
    ).outputs
    assert one.magref.measured and batch.magref.measured
    # the batch front end's ticks equal the one-by-one ticks to rounding (process_batch)
    assert one.magref.reference.field_ned_uT == pytest.approx(batch.magref.reference.field_ned_uT, abs=1e-9)
    assert [o.time_s for o in by_one] == pytest.approx([o.time_s for o in at_once], abs=1e-9)
    assert 13.0 <= by_one[0].time_s < 13.03  # the wait, vehicle time from the first tick (10 s)
    assert np.allclose([o.q for o in by_one], [o.q for o in at_once], atol=1e-9)
    # heading is magnetic: the truth turned back by the field's 2° declination
    magnetic = quat_from_euler(np.radians(10.0), np.radians(-20.0), np.radians(133.0))
    assert np.degrees(angle_between(by_one[-1].q, magnetic)) < MAX_ERR_DEG
    # the measured dip: 60° with the noise of hundreds of quiet ticks (σ per raw sample ~0.6°)
    dip = np.degrees(np.arcsin(one.mag_ref_ned_uT[2] / np.linalg.norm(one.mag_ref_ned_uT)))
    assert dip == pytest.approx(60.0, abs=0.3) and one.frontend.expected_field_uT == pytest.approx(50.0, abs=0.3)


def test_a_reboot_after_the_measured_field_keeps_it_one_by_one_and_at_once(caplog):
    """The clock going back (an autopilot reboot) after the field was measured: the ticks after it are solved with
    that field, live and in replay alike; the reboot is said once."""
    config = from_dict({"reference": {"position_wait_s": 1.0}})
    first, second = static_samples(n=600, t0_s=10.0), static_samples(n=600, t0_s=2.0, seed=2)  # 3 s, then 3 s from 2 s
    samples = first + second
    by_one = run(AttitudePipeline(config), samples)
    rows = {k: np.array([getattr(s, k) for s in samples]) for k in ("time_s", "acc_mps2", "gyr_radps", "mag_uT")}
    caplog.clear()
    at_once = (
        AttitudePipeline(config)
        .push_batch(rows["time_s"], rows["acc_mps2"], rows["gyr_radps"], rows["mag_uT"], np.ones(1200, dtype=bool))
        .outputs
    )
    # 2 s after the 1 s wait, then the 3 s after the reboot (its first tick at the first sample: 2.0 s)
    assert sum(o.time_s < 5.0 for o in by_one) == 150 and len(by_one) == 250
    assert [o.time_s for o in at_once] == pytest.approx([o.time_s for o in by_one], abs=1e-9)
    assert np.allclose([o.q for o in by_one], [o.q for o in at_once], atol=1e-9)
    assert sum("vehicle clock went back" in r.getMessage() for r in caplog.records) == 1


def test_an_input_in_the_wrong_units_is_said_once_one_by_one_and_at_once():
    """An accelerometer read 3.33× too large (an ADIS16405 profile on ArduPilot's mg): the pipeline's push and
    push_batch return the finding once, at the same sample; a judge of another compass (``attitudes=False``)
    shares the IMU and says nothing of it. The attitude itself is solved from directions: unchanged."""
    samples = [dataclasses.replace(s, acc_mps2=tuple(3.33 * a for a in s.acc_mps2)) for s in static_samples(n=1400)]
    one = AttitudePipeline(from_dict(ANGLES))
    found = [f for pushed in pushes(one, samples) for f in pushed.units]
    rows = {k: np.array([getattr(s, k) for s in samples]) for k in ("time_s", "acc_mps2", "gyr_radps", "mag_uT")}
    batch = AttitudePipeline(from_dict(ANGLES)).push_batch(*rows.values(), np.ones(len(samples), dtype=bool))
    assert [f.sensor for f in found] == ["accelerometer"] and batch.units == found
    assert found[0].time_s == pytest.approx(15.0)  # the first sample 5 s on (10 s at 200 Hz)
    judge = AttitudePipeline(from_dict(ANGLES))
    assert not any(judge.push(s, attitudes=False).units for s in samples) and judge.units.open
    assert np.degrees(angle_between(batch.outputs[-1].q, Q_TRUE)) < MAX_ERR_DEG


DAMAGE = ("reboot", "gap", "nan", "duplicate", "back", "no_mag", "saturated", "dead", "slow", "no_time")


def _damaged_stream(seed: int) -> tuple[np.ndarray, ...]:
    """A turning vehicle at a random rate, its compass every 1–10 samples, with up to three faults of
    :data:`DAMAGE` at random places: times, mag_new, acc, gyr, mag (NaN rows where no reading)."""
    rng = np.random.default_rng(seed)
    rate_hz, n = float(rng.choice([8.0, 25.0, 50.0, 200.0, 400.0])), int(rng.integers(100, 1500))
    t = np.sort(10.0 + np.arange(n) / rate_hz + rng.normal(0.0, 0.05 / rate_hz, n))
    yaw = np.radians(20.0) + np.cumsum(np.full(n, rng.normal(0.0, 0.5) / rate_hz))
    tilt = np.radians(rng.normal(0.0, 10.0, 2))
    q = quat_from_euler(np.full(n, tilt[0]), np.full(n, tilt[1]), yaw)
    acc = rotate_ned_to_body(q, [0.0, 0.0, -G]) + rng.normal(0.0, ACC_STD, (n, 3))
    mag = rotate_ned_to_body(q, FIELD_NED_UT) + rng.normal(0.0, MAG_STD, (n, 3))
    gyr = rng.normal(0.0, 0.01, (n, 3)) + np.outer(np.gradient(yaw) * rate_hz, [0.0, 0.0, 1.0])
    mag_new = np.arange(n) % int(rng.choice([1, 2, 4, 10])) == 0
    for fault in rng.choice(DAMAGE, int(rng.integers(0, 4))):
        i = int(rng.integers(1, n - 1))
        j = min(n, i + int(rng.integers(5, 300)))
        if fault == "reboot":
            t[i:] += rng.uniform(0.5, 8.0) - t[i]
        elif fault == "gap":
            t[i:] += rng.uniform(0.2, 3.0)
        elif fault == "nan":
            acc[i, 0] = np.nan
        elif fault == "duplicate":
            t[i] = t[i - 1]
        elif fault == "back":
            t[i] = t[i - 1] - 0.3 / rate_hz
        elif fault == "no_mag":
            mag_new[i:j] = False
        elif fault == "saturated":
            acc[i, 0] = 1000.0
        elif fault == "dead":
            acc[i:j] = 0.0
        elif fault == "no_time":  # a CSV's nan or inf, anywhere (the last row too: the batch's fast path)
            t[rng.choice([i, n - 1])] = rng.choice([np.nan, np.inf])
        else:  # a slow spell: the samples 0.2 s apart for a while
            t[i:] += np.minimum(np.arange(n - i), j - i) * 0.2
    return t, mag_new, acc, gyr, np.where(mag_new[:, None], mag, np.nan)


@settings(max_examples=30, deadline=None)
@given(
    seed=st.integers(0, 2**31),
    method=st.sampled_from(["ign", "fused", "triad", "ml"]),
    measured=st.booleans(),
    filtered=st.booleans(),
)
def test_one_by_one_and_at_once_agree_on_damaged_streams(seed, method, measured, filtered):
    """Live (push, sample by sample) and replay (push_batch, the arrays) on reboots, gaps, NaN, duplicate, stale
    and non-finite times, compass dropouts, saturated and dead samples and slow spells: the same outputs (to rounding:
    the batch front end's ticks), refusals and compass verdicts; neither raises."""
    reference = {"position_wait_s": 1.0} if measured else ANGLES["reference"]
    config = from_dict({"estimator": {"method": method}, "reference": reference, "filter": {"enabled": filtered}})
    t, mag_new, acc, gyr, mag = _damaged_stream(seed)
    one = AttitudePipeline(config)
    by_one = [
        one.push(ImuSample(t[i], tuple(acc[i]), tuple(gyr[i]), tuple(mag[i]) if mag_new[i] else None))
        for i in range(len(t))
    ]
    outputs = [o for p in by_one for o in p.outputs]
    batch = AttitudePipeline(config)
    at_once = batch.push_batch(t, acc, gyr, mag, mag_new)
    assert [o.time_s for o in at_once.outputs] == pytest.approx([o.time_s for o in outputs], abs=1e-9)
    dots = [np.dot(a.q, b.q) for a, b in zip(outputs, at_once.outputs, strict=True)]
    assert np.allclose(np.abs(dots), 1.0, atol=1e-9)  # the same attitudes: |q_a · q_b| = 1
    assert batch.counters.rejected == one.counters.rejected
    assert [e.time_s for e in at_once.compass] == pytest.approx([e.time_s for p in by_one for e in p.compass])


@pytest.mark.parametrize("method", ["ign", "triad"])
def test_at_once_progress_counts_ticks_already_estimated(monkeypatch, method):
    """push_batch solves the snapshot methods' ticks together, a run at a time: each progress report comes with
    every tick up to it estimated (one output each here), not with ticks still waiting to be solved."""
    monkeypatch.setattr(pipeline_module, "PROGRESS_TICKS", 40)
    samples = static_samples(n=1000)  # 5 s at 200 Hz: 250 ticks
    rows = {k: np.array([getattr(s, k) for s in samples]) for k in ("time_s", "acc_mps2", "gyr_radps", "mag_uT")}
    p = AttitudePipeline(from_dict({**ANGLES, "estimator": {"method": method}}))
    reports = []

    def progress(done: int, total: int) -> None:
        reports.append((done, total, p.counters.emitted))

    mag_new = np.ones(len(samples), dtype=bool)
    out = p.push_batch(rows["time_s"], rows["acc_mps2"], rows["gyr_radps"], rows["mag_uT"], mag_new, progress=progress)
    ticks = p.counters.ticks
    assert [r[0] for r in reports] == [*range(0, ticks, 40), ticks] and len(out.outputs) == ticks >= 249
    assert all(emitted == min(done + 1, ticks) for done, _, emitted in reports)


@pytest.mark.parametrize(
    ("reference", "yaw_deg"),
    [(ANGLES["reference"], 135.0), ({"position_wait_s": 1.0}, 133.0)],  # measured: magnetic, the 2° declination off
)
def test_after_a_reboot_the_fused_filter_goes_on_at_once(reference, yaw_deg):
    """The autopilot rebooted 10 s into its clock (the clock starts again at 2 s): the fused filter restarts there,
    with the field given or while it still waits to measure it, as the snapshot methods go on, and as it does after
    a gap; not one tick refused until the new clock passes the old."""
    config = from_dict({"reference": reference, "estimator": {"method": "fused"}})
    p = AttitudePipeline(config)
    first, second = static_samples(n=1000, t0_s=10.0), static_samples(n=1000, t0_s=2.0, seed=2)  # 5 s each
    for s in first:
        p.push(s)
    after = [o for s in second for o in p.push(s).outputs]
    assert not p.counters.rejected
    assert len(after) == 250 and after[0].time_s == pytest.approx(2.0)  # 5 s at 50 Hz from the first sample
    truth = quat_from_euler(np.radians(10.0), np.radians(-20.0), np.radians(yaw_deg))
    assert np.degrees(angle_between(after[-1].q, truth)) < MAX_ERR_DEG


@pytest.mark.parametrize("method", ["ign", "fused"])
@pytest.mark.parametrize(("parameter", "per_degree"), [("COMPASS_DEC", np.radians(1.0)), ("EKF2_MAG_DECL", 1.0)])
def test_the_autopilots_declination_turns_a_measured_field_to_true_north_at_once(method, parameter, per_degree, caplog):
    """No position: the field measured from the compass points to magnetic north, 12.8° off the true north the
    vehicle's attitude (and the autopilot's) is of. The autopilot's declination says by how much (ArduPilot's
    COMPASS_DEC in radians, PX4's EKF2_MAG_DECL in degrees): from the next output on, ours is of true north too
    (the fused filter's heading turned with it, no restart)."""
    declination_deg = 12.8
    field = np.array(field_from_angles(declination_deg, 60.0, 50.0))
    p = AttitudePipeline(from_dict({"estimator": {"method": method}, "reference": {"position_wait_s": 1.0}}))
    samples = static_samples(n=1000, field_ned_uT=field)
    magnetic = run(p, samples[:600])
    assert p.magref.measured
    turned = quat_from_euler(np.radians(10.0), np.radians(-20.0), np.radians(135.0 - declination_deg))
    assert np.degrees(angle_between(magnetic[-1].q, turned)) < MAX_ERR_DEG
    beyond = 200.0 * per_degree  # past ±180°: no declination
    assert not p.set_autopilot_parameter(parameter, np.nan) and not p.set_autopilot_parameter(parameter, beyond)
    assert [r.getMessage() for r in caplog.records if "no declination" in r.getMessage()] == [
        f"{parameter} nan is no declination (nan°): not applied",
        f"{parameter} {beyond:g} is no declination (200°): not applied",
    ]
    assert p.set_autopilot_parameter(parameter, declination_deg * per_degree)
    true = run(p, samples[600:])
    assert np.degrees(angle_between(np.array([o.q for o in true]), Q_TRUE)).max() < MAX_ERR_DEG
    if method == "fused":
        assert p.estimator.counters()["restarts"] == 0


def test_a_position_after_the_measured_field_turns_the_fused_heading_to_true_north_at_once():
    """Measured field (magnetic north), then a position: the WMM's field, and the fused filter's heading turned by
    the declination with it from the next output on (the state kept, no restart)."""
    when, (lat, lon, alt) = dt.date(2026, 6, 1), (-35.36, 149.17, 584.0)  # CMAC: declination ≈ +12.8°
    wmm = np.array(wmm_field_ned_uT(lat, lon, alt, when))
    declination = np.arctan2(wmm[1], wmm[0])
    p = AttitudePipeline(from_dict({"estimator": {"method": "fused"}, "reference": {"position_wait_s": 1.0}}))
    samples = static_samples(n=1000, field_ned_uT=wmm)  # 5 s from 10 s
    measured = run(p, samples[:600])
    assert p.magref.measured
    magnetic = quat_from_euler(np.radians(10.0), np.radians(-20.0), np.radians(135.0) - declination)
    assert np.degrees(angle_between(measured[-1].q, magnetic)) < MAX_ERR_DEG
    assert p.set_position(lat, lon, alt, when)
    true = run(p, samples[600:])
    assert np.degrees(angle_between(np.array([o.q for o in true]), Q_TRUE)).max() < MAX_ERR_DEG
    assert p.estimator.counters()["restarts"] == 0


def test_fused_outputs_say_whether_the_gps_took_the_acceleration_out():
    """The fused filter's outputs carry GPS_AIDED while its tilt updates take the receiver's acceleration out (from
    the second fix, the first having nothing to difference), and only then: still, 0 m/s, fixes at 5 Hz from 1 s."""
    config = from_dict({**ANGLES, "estimator": {"method": "fused"}})
    p = AttitudePipeline(config)
    samples = static_samples(n=600)  # 3 s at 200 Hz from t = 10 s
    aided = []
    for i, sample in enumerate(samples):
        if i >= 200 and i % 40 == 0:  # a fix every 0.2 s from 1 s in, handed in as it is taken
            p.set_velocity(GpsVelocity(sample.time_s, (0.0, 0.0, 0.0), True, 3, 12))
        aided += [(o.time_s, bool(o.flags & SampleFlag.GPS_AIDED)) for o in p.push(sample).outputs]
    assert aided and not any(a for t, a in aided if t < 11.2)  # before the second fix (1.2 s in)
    assert all(a for t, a in aided if t > 11.3)


@pytest.mark.parametrize(
    ("flags", "reads"),
    [
        (SampleFlag.NONE, False),
        (SampleFlag.MOVING, True),  # a snapshot solve, or the fused filter without the GPS, in a manoeuvre
        (SampleFlag.MOVING | SampleFlag.PER_SAMPLE, True),
        (SampleFlag.MOVING | SampleFlag.GPS_AIDED, False),  # the fused filter took the acceleration out
        (SampleFlag.GPS_AIDED, False),
    ],
)
def test_an_attitude_reads_acceleration_as_tilt_while_moving_unless_the_gps_took_it_out(flags, reads):
    output = AttitudeOutput(1.0, Q_TRUE, np.zeros(3), 0, True, flags)
    assert CrossCheckGate().moving(output) is reads  # a first output: nothing yet to turn unlike the gyro


def test_a_heading_is_judged_by_the_cross_check_only_when_its_sigma_about_the_vertical_is_small():
    """The σ about the body's vertical, not about body z: a vehicle pitched 60° with 90° of variance about its
    vertical has none to judge by; the same variance about body x (roll) leaves its heading judged. NO_HEADING
    has none whatever the covariance; an unknown covariance (NaN) refuses nothing."""
    q = quat_from_euler(0.0, np.radians(60.0), np.radians(30.0))
    down = rotate_ned_to_body(q, np.array([0.0, 0.0, 1.0]))
    small = np.eye(3) * np.radians(1.0) ** 2
    about_vertical = small + np.radians(90.0) ** 2 * np.outer(down, down)
    about_x = small + np.radians(90.0) ** 2 * np.outer([1.0, 0.0, 0.0], [1.0, 0.0, 0.0])
    # pitched 60°, the body's x axis is 60° above the horizontal: sin(60°)·90° = 78° of its variance about the vertical
    assert bool(pipeline_module.comparable_heading(q, about_x, 0)) is False
    flat = quat_from_euler(0.0, 0.0, np.radians(30.0))
    assert bool(pipeline_module.comparable_heading(flat, about_x, 0)) is True  # level: roll moves no heading
    assert bool(pipeline_module.comparable_heading(q, about_vertical, 0)) is False
    assert bool(pipeline_module.comparable_heading(q, small, 0)) is True
    assert bool(pipeline_module.comparable_heading(q, small, int(SampleFlag.NO_HEADING))) is False
    assert bool(pipeline_module.comparable_heading(q, np.full((3, 3), np.nan), 0)) is True
    many = pipeline_module.comparable_heading(np.stack([q, q]), np.stack([small, about_vertical]), np.zeros(2, int))
    assert many.tolist() == [True, False]


@pytest.mark.parametrize("method", ["ign", "fused"])
def test_a_vehicle_circling_with_a_good_compass_is_not_warned_about(method):
    """The simulator's coordinated turns (circles at 10 m/s and 18°/s: the specific force leans 17.7° for tens of
    seconds, 5 % over g) with a good compass: the centripetal acceleration is not the compass's fault. Without the
    compass monitor's turn gate the dip read off the leaning specific force was judged off twice (+47° and +51°
    against +64°)."""
    from mavattitude.sim import scenarios

    rng = np.random.default_rng(1)
    script, sensors = scenarios.turns(), scenarios.consumer_sensors(100.0)
    t = sensors.sample_times(0.0, script.duration_s, rng)
    acc, gyr, mag = sensors.measure(script, t, rng)
    config = from_dict(
        {
            "reference": {"magnetic": {"field_ned_uT": [float(v) for v in script.mag_ned_uT]}},
            "estimator": {"method": method},
        }
    )
    pipeline = AttitudePipeline(config)
    pushed = pipeline.push_batch(t, acc, gyr, mag, np.ones(len(t), dtype=bool))
    assert pushed.outputs and pipeline.compass.samples > 0  # judged: the holds and straight legs are quiet
    assert pushed.compass == []


def test_a_gentle_circle_is_not_judged_by_the_cross_check():
    """A circle at 10 m/s over 120 s (3°/s on average, up to 6°/s): under the 10°/s and 3 % of g that mark a turn or
    an acceleration, yet its centripetal acceleration leans the specific force up to 3.5°, which IGN takes for tilt
    and the field's dip turns into heading. Against the true attitude as the autopilot's, the cross-check warned
    (6.4°) of what is ours to be wrong about; the outputs turning about the vertical faster than 2°/s are not
    judged, and those at rest before and after are."""
    from mavattitude.estimation.crosscheck import cross_check_log
    from mavattitude.sim import scenarios
    from mavattitude.sim.trajectory import Fly, Hold, Script

    script = Script(
        [
            Hold(5.0),
            Fly(5.0, delta_vel_ned_mps=(10.0, 0.0, 0.0)),
            Fly(120.0, turn_rad=2.0 * np.pi),
            Fly(5.0, delta_vel_ned_mps=(-10.0, 0.0, 0.0)),
            Hold(5.0),
        ],
        scenarios.DEFAULT_MAG_NED_UT,
    )
    rng = np.random.default_rng(2)
    sensors = scenarios.consumer_sensors(100.0)
    t = sensors.sample_times(0.0, script.duration_s, rng)
    acc, gyr, mag = sensors.measure(script, t, rng)
    config = from_dict({"reference": {"magnetic": {"field_ned_uT": [float(v) for v in script.mag_ned_uT]}}})
    outputs = AttitudePipeline(config).push_batch(t, acc, gyr, mag, np.ones(len(t), dtype=bool)).outputs
    gate = CrossCheckGate()
    moving = np.array([gate.moving(o) for o in outputs])
    ours_t, ours_q = np.array([o.time_s for o in outputs]), np.array([o.q for o in outputs])
    theirs_t = np.arange(0.0, script.duration_s, 0.1)  # the autopilot's ATTITUDE at 10 Hz: the truth
    _, pairs, events = cross_check_log(
        ours_t, ours_q, theirs_t, script.attitude(theirs_t), config.crosscheck, None, moving
    )
    assert events == []
    judged = np.array([p.time_s for p in pairs if p.judged])
    assert np.any(judged < 5.0) and np.any(judged > 135.0)  # at rest, before and after
