"""Compass consistency: the dip and |B| figures, the thresholds, the verdict and its hysteresis."""

from __future__ import annotations

import itertools
import math
import re

import numpy as np
import pytest

from mavattitude.estimation.compass import (
    HEADING_UNKNOWN_STD_RAD,
    NOISE_SIGMAS,
    PERSIST_S,
    CompassMonitor,
    CompassSettings,
    heading_uncertain,
    measured_dip_deg,
    measured_dip_deg_rows,
    reference_dip_deg,
    thresholds,
)
from mavattitude.estimation.conventions import (
    quat_conjugate,
    quat_from_euler,
    quat_multiply,
    rotate_ned_to_body,
    rotvec_from_quat,
)
from mavattitude.replay import JudgedCompass
from mavattitude.sensors.magref import field_from_angles

G = 9.80665
FIELD_NED = np.array(field_from_angles(12.8, 58.0, 50.0))
STILL = (0.0, 0.0, 0.0)  # rad/s
SIGMAS = ((0.05, 0.05, 0.05), (0.5, 0.5, 0.5))  # the config's default noise model


def _body(q: np.ndarray, flip_z: bool = False) -> tuple[tuple, tuple]:
    acc = rotate_ned_to_body(q, [0.0, 0.0, -G])
    mag = rotate_ned_to_body(q, FIELD_NED) * (np.array([1.0, 1.0, -1.0]) if flip_z else 1.0)
    return tuple(acc.tolist()), tuple(mag.tolist())


def _feed(monitor: CompassMonitor, n: int, flip_z: bool = False, t0_s: float = 0.0, seed: int = 3) -> list:
    rng = np.random.default_rng(seed)
    events = []
    for i in range(n):
        q = quat_from_euler(*np.radians(rng.uniform([-20, -20, -180], [20, 20, 180])))
        acc, mag = _body(q, flip_z)
        event = monitor.update(t0_s + 0.02 * i, acc, mag, STILL)  # 50 Hz ticks
        events += [event] if event is not None else []
    return events


def _monitor() -> CompassMonitor:
    m = CompassMonitor(CompassSettings(), *SIGMAS)
    m.set_reference(tuple(FIELD_NED), 50.0)
    return m


def test_the_dip_does_not_depend_on_the_attitude():
    rng = np.random.default_rng(7)
    for _ in range(50):
        q = quat_from_euler(*rng.uniform(-math.pi, math.pi, 3) * np.array([1, 0.49, 1]))
        acc, mag = _body(q)
        assert measured_dip_deg(acc, mag) == pytest.approx(58.0, abs=1e-9)
    assert reference_dip_deg(tuple(FIELD_NED)) == pytest.approx(58.0, abs=1e-12)


def test_thresholds_are_the_allowance_plus_k_sigma_of_the_noise_model():
    t = thresholds(CompassSettings(), *SIGMAS, 50.0)
    sigma_dip_deg = math.degrees(math.hypot(0.5 / 50.0, 0.05 / G))  # 0.65°
    assert t.dip_deg == pytest.approx(10.0 + NOISE_SIGMAS * sigma_dip_deg)
    assert t.dip_noise_deg == pytest.approx(NOISE_SIGMAS * sigma_dip_deg)
    assert t.field == pytest.approx(0.15 + NOISE_SIGMAS * 0.01)


def test_a_good_compass_is_never_judged_inconsistent():
    m = _monitor()
    assert _feed(m, 3000) == []  # 60 s of random tilts and headings
    f = m.figures()
    assert f.dip_deg == pytest.approx(58.0, abs=1e-6) and f.field_ratio == pytest.approx(1.0, abs=1e-9)
    assert f.first_dip_deg == pytest.approx(58.0, abs=1e-6) and not f.inconsistent and f.warnings == 0


def test_an_upside_down_compass_is_reported_once_as_soon_as_it_can_be_judged():
    m = _monitor()
    events = _feed(m, 500, flip_z=True)
    assert len(events) == 1 and events[0].inconsistent
    assert events[0].time_s == pytest.approx(0.02 * (CompassSettings().min_samples - 1))
    f = events[0].figures
    assert f.dip_deg < 0.0  # flipped z: the field points up out of the ground at these tilts
    assert f.describe() == f"compass dip {f.dip_deg:+.0f}° vs expected +58°, |B| 100 % of the expected"
    assert m.figures().warnings == 1


def test_the_verdict_clears_with_hysteresis_and_is_said_again_only_after_clearing():
    m = _monitor()
    _feed(m, 100, flip_z=True)
    assert m.inconsistent
    events = _feed(m, 1000, t0_s=2.0)  # the compass fixed: the window (10 s) fills with good samples
    assert [e.inconsistent for e in events] == [False]
    assert events[0].time_s < 2.0 + CompassSettings().window_s
    assert [e.inconsistent for e in _feed(m, 200, flip_z=True, t0_s=30.0)] == [True]
    assert m.warnings == 2


def test_high_acceleration_samples_are_not_judged():
    m = _monitor()
    acc, mag = _body(quat_from_euler(0.0, 0.0, 0.0), flip_z=True)
    strong = tuple(1.5 * a for a in acc)  # 1.5 g: the specific force is not gravity
    assert all(m.update(0.02 * i, strong, mag, STILL) is None for i in range(200))
    assert m.samples == 0 and not m.judged and not m.suspect(strong, mag, STILL)


def test_a_single_sample_far_off_is_suspect_before_the_compass_is_judged():
    m = _monitor()
    acc, mag = _body(quat_from_euler(0.1, -0.2, 1.0))
    _, flipped = _body(quat_from_euler(0.1, -0.2, 1.0), flip_z=True)
    assert not m.suspect(acc, mag, STILL) and m.suspect(acc, flipped, STILL)


def test_the_heading_uncertain_covariance_adds_variance_about_the_vertical_only():
    acc, _ = _body(quat_from_euler(0.3, -0.2, 1.0))
    base = np.diag([1e-6, 2e-6, 3e-6])
    cov = heading_uncertain(base, acc)
    down = -np.asarray(acc) / G
    assert down @ cov @ down == pytest.approx(down @ base @ down + HEADING_UNKNOWN_STD_RAD**2)
    across = np.cross(down, [1.0, 0.0, 0.0])
    across /= np.linalg.norm(across)
    assert across @ cov @ across == pytest.approx(across @ base @ across)


def test_fast_rotation_is_not_quiet():
    m = _monitor()
    acc, mag = _body(quat_from_euler(0.0, 0.0, 0.0), flip_z=True)
    spinning = (0.0, 0.0, np.radians(CompassSettings().max_rate_dps + 1.0))
    for i in range(200):
        m.update(0.02 * i, acc, mag, spinning)
    assert m.samples == 0 and not m.judged and not m.suspect(acc, mag, spinning)


def test_a_turn_about_the_vertical_is_not_quiet_one_about_a_horizontal_axis_is():
    """``max_turn_rate_dps`` gates the rate about the specific force's direction (a sustained turn's lean), not the
    body's rate: level and upside-down compass, turning about the vertical just faster is not judged; rolling at
    the same rate is."""
    rate = np.radians(CompassSettings().max_turn_rate_dps + 1.0)
    acc, mag = _body(quat_from_euler(0.0, 0.0, 0.0), flip_z=True)
    for gyr, judged in (((0.0, 0.0, rate), False), ((rate, 0.0, 0.0), True)):
        m = _monitor()
        for i in range(200):
            m.update(0.02 * i, acc, mag, gyr)
        assert (m.samples > 0, m.judged) == (judged, judged)


def _turning(
    flip: np.ndarray,
    seconds: float = 20.0,
    seed: int = 5,
    amplitudes_deg=(20.0, 20.0, 90.0),
    mag_std_uT=0.5,
    noise_uT: float = 0.0,
) -> list:
    """A level vehicle rolling, pitching and yawing (±20°, ±20°, ±90° by default; 0.2–0.5 Hz); its compass
    turned by ``flip``, its readings with white noise of ``noise_uT`` per axis (seeded)."""
    rng = np.random.default_rng(seed)
    freq, phase = rng.uniform(0.2, 0.5, 3), rng.uniform(0, 2 * np.pi, 3)
    t = np.arange(0.0, seconds, 0.02)
    angles = np.radians(amplitudes_deg)[:, None] * np.sin(2 * np.pi * freq[:, None] * t + phase[:, None])
    q = quat_from_euler(*angles)
    events = []
    m = CompassMonitor(CompassSettings(), SIGMAS[0], (mag_std_uT,) * 3)
    m.set_reference(tuple(FIELD_NED), 50.0)
    for k in range(1, len(t)):
        # body rate from consecutive attitudes: the rotation vector of q_{k-1}* ⊗ q_k over dt
        w = rotvec_from_quat(quat_multiply(quat_conjugate(q[k - 1]), q[k])) / 0.02
        acc, mag = _body(q[k])
        reading = flip @ np.array(mag) + rng.normal(0.0, noise_uT, 3)
        event = m.update(t[k], acc, tuple(reading.tolist()), tuple(w.tolist()))
        events += [event] if event is not None else []
    return events, m


@pytest.mark.parametrize(
    "flip",
    [np.diag([-1.0, 1.0, 1.0]), np.array([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])],
    ids=["mirrored_x", "turned_90_about_z"],
)
def test_a_compass_turned_about_the_vertical_is_found_by_its_turn(flip):
    events, m = _turning(flip)
    assert events and events[0].inconsistent and events[0].time_s < 5.0
    f = m.figures()
    assert f.turn_off and f.turn_mismatch > 0.4 and "turns unlike the gyroscope" in f.describe()


def test_a_good_compass_turns_with_the_gyroscope():
    # yaw ±10° (up to 31°/s): the default ±90° turns about the vertical faster than max_turn_rate_dps nearly all the
    # time, and the dip, never quiet, is never judged; a vouching needs it
    events, m = _turning(np.eye(3), amplitudes_deg=(20.0, 20.0, 10.0))
    assert events == [] and m.figures().turn_mismatch < 0.01  # exact data: only the rate's discretisation
    assert m.confirmed  # vouched for by a turn about three axes: every sample of it is trusted from now on
    acc, mag = _body(quat_from_euler(0.3, -0.2, 1.0))
    assert not m.suspect(tuple(1.3 * a for a in acc), mag, STILL)  # even an accelerated one (IGN is the paper's)


MIRROR_X = np.diag([-1.0, 1.0, 1.0])


def test_a_turn_about_one_axis_does_not_vouch_for_a_compass():
    # Mirrored in x, a compass turns like a good one while the body only rolls (the mirror commutes with a
    # rotation about x): the turn check cannot tell, and the compass stays unconfirmed.
    events, m = _turning(MIRROR_X, amplitudes_deg=(30.0, 0.0, 0.0))
    assert events == [] and m.figures().turn_mismatch < 0.01
    assert m.judged and m.turn_judged and not m.confirmed


TURNED_90_Z = np.array([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])


def test_a_turn_the_noise_model_cannot_judge_by_its_mismatch_is_judged_by_the_mounting_it_fits():
    # With a noise model this poor (σ 8 µT per axis, four times the readings' 2 µT) the mismatch threshold is
    # widened past what a compass turned by 90° about z shows; but the turned mounting explains the turns far
    # beyond what 8 µT of noise lets one mounting gain on another (4 k² σ² = 2304 µT²): warned, not vouched.
    events, m = _turning(TURNED_90_Z, mag_std_uT=8.0, noise_uT=2.0)
    f = m.figures()
    assert f.turn_mismatch > 0.4 and f.threshold_turn > f.turn_mismatch
    assert events and events[0].inconsistent and f.mounting_off and f.mounting_share > 0.5
    assert "explained by a compass mounted otherwise" in f.describe() and not m.confirmed


MOSTLY_ROLL, MOSTLY_YAW = (40.0, 4.0, 4.0), (4.0, 4.0, 60.0)  # amplitudes, deg: roll, pitch, yaw


@pytest.mark.parametrize(
    ("flip", "amplitudes_deg"), [(MIRROR_X, MOSTLY_ROLL), (TURNED_90_Z, MOSTLY_YAW)], ids=["mirrored_x", "turned_90_z"]
)
def test_a_turn_mostly_about_the_misorientations_own_axis_shows_it_by_the_mounting_it_fits(flip, amplitudes_deg):
    # Turning mostly about the misorientation's own axis (with 0.5 µT of noise, seeded): the mirror in x or the
    # turn about z shows only in the small rest of the turn, too small a share of the field's change for the
    # mismatch (threshold turn_allowance 0.2 plus the noise's share); the mirrored or turned mounting still
    # explains that rest better than the configured one, by far more than noise lets it (4 k² σ² = 9 µT²).
    events, m = _turning(flip, amplitudes_deg=amplitudes_deg, noise_uT=0.5, seed=11)
    f = m.figures()
    assert f.turn_mismatch < f.threshold_turn  # the mismatch alone cannot tell
    # warned once judged off for PERSIST_S: 25 turning steps of 20 ms (0.5 s) after the first 0.2 s step, then that
    assert events and events[0].inconsistent and events[0].time_s < 1.0 + PERSIST_S and f.mounting_off
    assert "explained by a compass mounted otherwise" in f.describe()


@pytest.mark.parametrize("amplitudes_deg", [MOSTLY_ROLL, MOSTLY_YAW], ids=["mostly_roll", "mostly_yaw"])
def test_no_other_mounting_explains_a_good_compass_better(amplitudes_deg):
    events, m = _turning(np.eye(3), amplitudes_deg=amplitudes_deg, noise_uT=0.5, seed=11)
    gain_uT2, _ = m._turn.better_mounting()
    assert events == [] and not m.figures().mounting_off
    assert gain_uT2 <= 0.0  # the configured mounting fits best: every other one leaves a larger residual


def test_before_it_is_confirmed_a_sample_off_the_dip_sets_heading_only():
    m = _monitor()
    level = quat_from_euler(0.0, 0.0, 0.0)  # heading north: the x axis carries the horizontal field
    acc, mag = _body(level)
    for i in range(100):  # level: a compass mirrored in x keeps its dip, so the dip check passes it
        m.update(0.02 * i, acc, tuple((MIRROR_X @ mag).tolist()), STILL)
    assert m.judged and not m.inconsistent and not m.confirmed
    acc, mag = _body(quat_from_euler(0.0, np.radians(30.0), 0.0))  # pitched 30°: the mirror shows in the dip
    mirrored = tuple((MIRROR_X @ mag).tolist())
    off_deg = abs(measured_dip_deg(acc, mirrored) - measured_dip_deg(acc, mag))
    noise_deg = m._thresholds.dip_noise_deg
    assert off_deg > noise_deg  # far beyond the noise: this sample would drag the tilt
    assert m.suspect(acc, mirrored, STILL) and not m.suspect(acc, mag, STILL)


def test_no_new_evidence_does_not_clear_the_verdict():
    m = _monitor()
    _feed(m, 100, flip_z=True)
    assert m.inconsistent
    acc, mag = _body(quat_from_euler(0.0, 0.0, 0.0), flip_z=True)
    strong = tuple(1.5 * a for a in acc)
    for i in range(1000):  # 20 s of high acceleration: not one quiet sample, the window ages out
        m.update(2.0 + 0.02 * i, strong, mag, STILL)
    m.update(30.0, acc, mag, STILL)  # one quiet sample: too few to judge anew
    assert m.inconsistent and m.warnings == 1


def test_the_dip_of_many_rows_is_each_rows_bit_for_bit():
    rng = np.random.default_rng(17)
    acc = rng.normal(0.0, 9.8, (2000, 3))
    mag = np.concatenate([rng.normal(0.0, 50.0, (1990, 3)), -acc[-10:-5], acc[-5:]])  # ten at asin's clamp
    # a zero vector has no direction: no dip (NaN) either way, where one by one divided by zero
    acc[:3], mag[3:6] = 0.0, 0.0
    rows = measured_dip_deg_rows(acc, mag)
    one_by_one = [measured_dip_deg(tuple(a), tuple(m)) for a, m in zip(acc.tolist(), mag.tolist(), strict=True)]
    np.testing.assert_array_equal(rows, one_by_one)  # bit for bit, NaN where NaN
    assert np.isnan(one_by_one[:6]).all() and not np.isnan(one_by_one[6:]).any()
    assert np.allclose(one_by_one[-10:], [90.0] * 5 + [-90.0] * 5)


@pytest.mark.parametrize("flip", [np.eye(3), TURNED_90_Z, np.diag([1.0, 1.0, -1.0])], ids=["good", "turned", "flipped"])
def test_rows_at_once_are_update_then_suspect_one_by_one(flip):
    """update_rows: the same events, suspect verdicts and figures as update then suspect per row (turning, the
    field noisy, a fifth of the rows accelerated and those turning about the vertical faster than
    ``max_turn_rate_dps`` not quiet; a compass turned or upside down is warned about)."""
    rng = np.random.default_rng(23)
    t = np.arange(0.0, 12.0, 0.02)
    # yaw ±30° at 0.25 Hz (47°/s at most): quiet about a tenth of the time, enough to judge within the window
    angles = np.radians([[25.0], [25.0], [30.0]]) * np.sin(2 * np.pi * np.array([[0.3], [0.4], [0.25]]) * t)
    q = quat_from_euler(*angles)
    acc = np.array([_body(qk)[0] for qk in q]) * rng.choice([1.0, 1.2], (len(t), 1), p=[0.8, 0.2])
    mag = np.array([flip @ np.array(_body(qk)[1]) for qk in q]) + rng.normal(0.0, 0.5, (len(t), 3))
    gyr = np.array([rotvec_from_quat(quat_multiply(quat_conjugate(a), b)) / 0.02 for a, b in itertools.pairwise(q)])
    t, acc, mag = t[1:], acc[1:], mag[1:]
    one, rows = _monitor(), _monitor()
    events, suspect = [], []
    for row in zip(t.tolist(), acc.tolist(), mag.tolist(), gyr.tolist(), strict=True):
        events.append(one.update(*row))
        suspect.append(one.suspect(*row[1:]))
    at_once, suspect_rows, inconsistent = rows.update_rows(t, acc, mag, gyr)
    assert repr(at_once) == repr(events) and suspect_rows == suspect and inconsistent[-1] == one.inconsistent
    assert repr(rows.figures()) == repr(one.figures())  # NaN figures compare equal as text
    good = np.array_equal(flip, np.eye(3))  # both paths: vouched for, never suspect; or warned, then suspect
    assert (one.confirmed, one.warnings, any(suspect)) == ((True, 0, False) if good else (False, 1, True))


def test_against_a_field_measured_from_the_compass_a_change_is_judged_not_the_compass_itself():
    """Without a position the reference is the compass's own field at the start (docs/vehicle.md): an upside-down
    compass measured so is taken as it is (its dip is the reference); a field that changes later is found."""
    from mavattitude.reports import compass_statustext

    upside_down = np.array([1.0, -1.0, -1.0])  # turned 180° about x: level, it reads the dip −58°
    m = CompassMonitor(CompassSettings(), *SIGMAS)
    m.set_reference(field_from_angles(0.0, -58.0, 50.0), 50.0, measured=True)  # as measured without a position
    events = []
    for i in range(1000):  # 10 s level and still at headings all round, then |B| 30 % stronger (a magnet)
        acc, mag = _body(quat_from_euler(0.0, 0.0, math.radians(7.0 * i)))
        gain = 1.0 if i < 500 else 1.3
        event = m.update(0.02 * i, acc, tuple(gain * upside_down * mag), STILL)
        events += [] if event is None else [(i, event)]
    assert [(i >= 500, e.inconsistent) for i, e in events] == [(True, True)]  # nothing before the change
    f = events[0][1].figures
    assert re.fullmatch(
        r"compass dip -58° vs measured at the start -58°, \|B\| 1\d\d % of the measured at the start", f.describe()
    )
    assert re.fullmatch(r"compass \|B\| 1\d\d% of start: check calibration", compass_statustext(f))
    assert m.figures().field_ratio == pytest.approx(1.3, abs=1e-9)  # the window now all after the change
    model = _monitor()  # the same compass against the model's field (+58°): found upside down at once
    level = [_body(quat_from_euler(0.0, 0.0, math.radians(7.0 * i))) for i in range(100)]
    verdicts = [model.update(0.02 * i, acc, tuple(upside_down * mag), STILL) for i, (acc, mag) in enumerate(level)]
    assert [e.inconsistent for e in verdicts if e is not None] == [True]


@pytest.mark.parametrize("rate_hz", [2.0, 0.5])
def test_a_stream_at_telemetry_rates_is_judged_over_its_last_25_quiet_samples(rate_hz):
    """At 2 Hz (a ground station's RAW_IMU) the 10 s window holds 20 quiet samples, fewer than the 25 a judgement
    needs: the window spans the 25 instead (12.5 s; 50 s at 0.5 Hz), and an upside-down compass is found at the
    25th, not left unjudged for the whole flight."""
    m, rng = _monitor(), np.random.default_rng(5)
    events = []
    for i in range(40):
        acc, mag = _body(quat_from_euler(*np.radians(rng.uniform([-20, -20, -180], [20, 20, 180]))), flip_z=True)
        event = m.update(i / rate_hz, acc, mag, STILL)
        events += [event] if event is not None else []
    assert m.ever_judged and [e.inconsistent for e in events] == [True]
    assert events[0].time_s == pytest.approx(24 / rate_hz)  # the 25th sample


def test_a_compass_never_judged_is_not_said_to_be_ok():
    """Quiet for 0.4 s every 15 s (20 ticks at 50 Hz), accelerating between: 100 quiet samples in all, never 25
    in one window. The replay's verdict is "not judged", not "ok"."""
    m = _monitor()
    acc, mag = _body(quat_from_euler(0.1, -0.2, 1.0))
    pushing = tuple(1.2 * a for a in acc)  # |f| 20 % over g: not quiet
    t = 0.0
    for _ in range(5):
        for k in range(750):
            m.update(t, acc if k < 20 else pushing, mag, STILL)
            t += 0.02
    assert m.samples == 100 and not m.ever_judged
    assert JudgedCompass(0, [], m).verdict() == "not judged"
