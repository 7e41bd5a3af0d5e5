"""The autopilot cross-check: pairing by vehicle time, the difference, and the verdict's hysteresis."""

from __future__ import annotations

import numpy as np
import pytest

from mavattitude.estimation.conventions import quat_from_euler, rotate_ned_to_body
from mavattitude.estimation.crosscheck import (
    CLEAR_FRACTION,
    DRIFT_LIMIT_DPS,
    KEEP_S,
    MAX_WAITING,
    CrossCheck,
    CrossCheckSettings,
    GyroDrift,
    cross_check_log,
    difference,
)

YAW_RATE_RADPS = np.radians(30.0)


def truth(t_s: np.ndarray, roll_offset_deg: float = 0.0) -> np.ndarray:
    """A vehicle turning at 30°/s with 5° of pitch; ``roll_offset_deg`` added to the roll."""
    n = len(t_s)
    return quat_from_euler(np.full(n, np.radians(roll_offset_deg)), np.full(n, np.radians(5.0)), YAW_RATE_RADPS * t_s)


def test_each_autopilot_attitude_is_paired_with_ours_at_its_time():
    ours_t = np.arange(0.0, 10.0, 0.02)  # 50 Hz
    theirs_t = np.arange(0.005, 10.0, 0.1)  # 10 Hz, between our ticks
    check, diffs, events = cross_check_log(ours_t, truth(ours_t), theirs_t, truth(theirs_t, -2.0), CrossCheckSettings())
    assert check.pairs == len(diffs) == len(theirs_t)  # 9.905 s: before our last output, 9.98 s
    # interpolating a 30°/s turn over 20 ms: the chord's error is (0.6°)²/8 ~ 1e-4°
    assert all(abs(d.roll_deg - 2.0) < 1e-3 and abs(d.pitch_deg) < 1e-3 and abs(d.yaw_deg) < 1e-3 for d in diffs)
    assert all(abs(d.total_deg - 2.0) < 1e-3 for d in diffs) and events == []


def test_a_log_across_a_reboot_pairs_each_boot_with_its_own():
    """A log of two flights, the autopilot rebooted between (both clocks start again at 1 s): each autopilot
    attitude is paired with ours of the same boot, as live, not left waiting for ours of the first boot."""
    ours_t, theirs_t = np.arange(1.0, 10.0, 0.02), np.arange(1.005, 9.9, 0.1)
    ours_q, theirs_q = truth(ours_t), truth(theirs_t, -2.0)
    check, diffs, _ = cross_check_log(
        np.concatenate([ours_t, ours_t]),
        np.concatenate([ours_q, ours_q]),
        np.concatenate([theirs_t, theirs_t]),
        np.concatenate([theirs_q, theirs_q]),
        CrossCheckSettings(),
    )
    assert check.pairs == len(diffs) == 2 * len(theirs_t) and not check.unpaired
    assert all(abs(d.total_deg - 2.0) < 1e-3 for d in diffs)


def test_an_autopilot_attitude_ahead_of_our_outputs_waits_for_them():
    check = CrossCheck(CrossCheckSettings())
    q = truth(np.array([0.0, 0.02, 0.04]))
    check.add_ours(0.0, q[0])
    check.add_autopilot(0.03, q[1])
    assert check.update() == ([], [])  # ours do not reach 0.03 s yet
    check.add_ours(0.04, q[2])
    (d,), _ = check.update()
    assert d.time_s == 0.03


def test_ours_too_far_apart_are_not_interpolated_and_the_miss_is_counted_as_a_gap():
    assert CrossCheckSettings.max_gap_s < 1.0  # the hole below is 1 s
    ours_t = np.concatenate([np.arange(0.0, 2.0, 0.02), np.arange(3.0, 5.0, 0.02)])  # 50 Hz, a 1 s hole
    theirs_t = np.arange(0.05, 5.0, 0.1)
    check, diffs, _ = cross_check_log(ours_t, truth(ours_t), theirs_t, truth(theirs_t), CrossCheckSettings())
    in_hole = int(np.count_nonzero((theirs_t > 1.98) & (theirs_t < 3.0)))
    assert check.unpaired == {"gap": in_hole} and check.pairs == len(diffs) == len(theirs_t) - in_hole  # 4.95 < 4.98
    assert check.missed == in_hole and check.share == pytest.approx(check.pairs / len(theirs_t))


def test_slow_outputs_are_bridged_at_their_own_rhythm():
    """One output per sample of a 2 Hz stream (0.5 s apart, jittered): each autopilot attitude between two
    of them is compared, none taken for a gap."""
    rng = np.random.default_rng(3)
    ours_t = np.arange(0.0, 20.0, 0.5) + rng.uniform(0.0, 0.05, 40)
    theirs_t = np.arange(0.1, 19.5, 0.25)  # 4 Hz
    check, _, _ = cross_check_log(ours_t, truth(ours_t), theirs_t, truth(theirs_t), CrossCheckSettings())
    assert check.pairs == len(theirs_t) and not check.unpaired


def test_ours_starting_late_pair_every_autopilot_attitude_after_our_first():
    """The autopilot's attitudes from long before our first output (waiting for a GPS position) are outside our
    span; every one after it is paired, however many came before."""
    ours_t = np.arange(30.0, 60.0, 0.02)
    theirs_t = np.arange(0.0, 60.0, 0.02) + 0.007  # 50 Hz from 0 s
    check, diffs, _ = cross_check_log(ours_t, truth(ours_t), theirs_t, truth(theirs_t), CrossCheckSettings())
    inside = int(np.count_nonzero((theirs_t >= 30.0) & (theirs_t <= ours_t[-1])))
    assert check.pairs == len(diffs) == inside and check.missed == 0
    assert check.unpaired["outside"] == len(theirs_t) - inside


def test_an_attitude_before_our_restart_is_counted_as_a_reset():
    check = CrossCheck(CrossCheckSettings())
    q = truth(np.array([0.0]))[0]
    for t in (10.0, 10.02, 10.04):
        check.add_ours(t, q)
    for t in (1.0, 1.02):  # the vehicle rebooted: our clock went back
        check.add_ours(t, q)
    check.add_autopilot(0.5, q)
    check.add_autopilot(1.01, q)
    check.update()
    assert check.unpaired == {"reset": 1} and check.pairs == 1


def test_after_both_clocks_start_again_the_pairing_goes_on_at_once():
    """A reboot: the autopilot's attitude that was waiting ahead of our outputs (10.05 s) would wait for ours to
    reach 10.05 s again on the new clock, and every attitude after it with it; it is counted a reset instead."""
    check = CrossCheck(CrossCheckSettings())
    q = truth(np.array([0.0]))[0]
    for t in (10.0, 10.02, 10.04):
        check.add_ours(t, q)
    check.add_autopilot(10.05, q)
    for t in (1.0, 1.02, 1.04):
        check.add_ours(t, q)
        check.add_autopilot(t + 0.01, q)
    check.update()
    assert check.pairs == 2 and check.unpaired == {"reset": 1}  # 1.05 waits for our next output
    check.add_autopilot(0.6, q)  # 0.45 s behind the waiting 1.05 s: reordered, not a reboot
    assert check.unpaired == {"reset": 1}


def test_differences_are_wrapped_to_180_degrees():
    """Upside down: ours at roll −179°, the autopilot's at +179°: 2° apart, in roll as in total."""
    ours = tuple(quat_from_euler(np.radians(-179.0), np.radians(10.0), np.radians(-178.0)).tolist())
    theirs = tuple(quat_from_euler(np.radians(179.0), np.radians(10.0), np.radians(178.0)).tolist())
    d = difference(0.0, ours, theirs)
    assert d.roll_deg == pytest.approx(2.0, abs=1e-9) and d.yaw_deg == pytest.approx(4.0, abs=1e-9)
    assert -180.0 <= d.roll_deg < 180.0 and d.total_deg < 5.0


def _run(offsets_deg: list[tuple[float, float]], settings: CrossCheckSettings) -> list:
    """Ours at 50 Hz, the autopilot's at 10 Hz with a roll offset per (until_s, offset) span."""
    ours_t = np.arange(0.0, offsets_deg[-1][0], 0.02)
    theirs_t = np.arange(0.0, offsets_deg[-1][0], 0.1)
    offset = np.zeros(len(theirs_t))
    start = 0.0
    for until_s, deg in offsets_deg:
        offset[(theirs_t >= start) & (theirs_t < until_s)] = deg
        start = until_s
    theirs = np.array([truth(np.array([t]), -o)[0] for t, o in zip(theirs_t, offset, strict=True)])
    return cross_check_log(ours_t, truth(ours_t), theirs_t, theirs, settings)[2]


def test_the_warning_needs_hold_s_above_the_threshold_and_clears_after_hold_s_below():
    s = CrossCheckSettings(threshold_deg=5.0, hold_s=3.0)
    assert _run([(10.0, 0.0), (12.8, 6.0), (20.0, 0.0)], s) == []  # 2.8 s above: not said
    events = _run([(10.0, 0.0), (15.0, 6.0), (25.0, 0.0)], s)
    assert [(e.disagree, round(e.time_s, 1)) for e in events] == [(True, 13.0), (False, 18.0)]
    assert events[0].total_deg == pytest.approx(6.0, abs=1e-3)


def _moving_run(moving_spans: list[tuple[float, float]], settings: CrossCheckSettings, end_s: float = 20.0):
    """The autopilot's roll 8° off ours throughout (beyond the 5° threshold); ours a snapshot solve while the
    vehicle moved in the given (start, end) spans."""
    ours_t, theirs_t = np.arange(0.0, end_s, 0.02), np.arange(0.0, end_s, 0.1)
    moving = np.zeros(len(ours_t), dtype=bool)
    for start, end in moving_spans:
        moving[(ours_t >= start) & (ours_t < end)] = True
    return cross_check_log(ours_t, truth(ours_t), theirs_t, truth(theirs_t, -8.0), settings, None, moving)


def test_a_snapshot_solve_while_the_vehicle_moves_is_compared_but_not_judged():
    s = CrossCheckSettings(threshold_deg=5.0, hold_s=3.0, settle_s=1.0)
    # moving 0–2.5 s: judged from 3.5 s on (settle_s after), warned 3 s of judged pairs later
    check, diffs, events = _moving_run([(0.0, 2.5)], s)
    assert [(e.disagree, round(e.time_s, 1)) for e in events] == [(True, 6.5)]
    assert len(diffs) == check.pairs == 200 and check.unjudged == 35  # 0.0 … 3.4 s at 10 Hz
    # a short move every 3 s (ours moving at 3k … 3k + 0.08 s) restarts the hold each time: the pairs at 3k …
    # 3k + 1.0 s are not judged, the 1.9 s left are less than the 3 s held
    moves = [(k * 3.0, k * 3.0 + 0.1) for k in range(7)]
    check, _, events = _moving_run(moves, s)
    assert events == [] and check.pairs == 200 and check.unjudged == 7 * 11
    # settle_s 0: only the pair at a moving output is not judged; 2.8 s are left, still short of 3 s
    check, _, events = _moving_run(moves, CrossCheckSettings(settle_s=0.0))
    assert events == [] and check.unjudged == 7
    # without moving outputs every pair is judged, as before
    check, _, events = _moving_run([], s)
    assert [round(e.time_s, 1) for e in events] == [3.0] and check.unjudged == 0


def test_no_flip_flop_around_the_threshold():
    s = CrossCheckSettings(threshold_deg=5.0, hold_s=3.0)
    between = (CLEAR_FRACTION * 5.0 + 5.0) / 2  # below the threshold, above where it clears
    spans = [(5.0, 6.0)] + [(5.0 + 2 * k, between if k % 2 else 6.0) for k in range(1, 10)]
    events = _run(spans, s)
    assert [e.disagree for e in events] == [True]


def test_ours_without_a_heading_is_compared_on_the_tilt_alone():
    """No magnetometer: ours holds yaw 0; the yaw difference is unknown (NaN) and the total is the tilt's."""
    ours = tuple(quat_from_euler(np.radians(12.0), np.radians(-3.0), 0.0).tolist())
    theirs = tuple(quat_from_euler(np.radians(10.0), np.radians(-3.0), np.radians(140.0)).tolist())
    d = difference(0.0, ours, theirs, heading=False)
    assert np.isnan(d.yaw_deg) and d.roll_deg == pytest.approx(2.0, abs=1e-9)
    assert d.total_deg == pytest.approx(2.0, abs=1e-6)  # not the 140° of yaw
    check = CrossCheck(CrossCheckSettings())
    check.add_ours(0.0, ours, heading=False)
    check.add_ours(0.02, ours)
    check.add_autopilot(0.01, theirs)
    (between,), _ = check.update()
    assert np.isnan(between.yaw_deg)  # interpolated from one without a heading: none


def test_a_heading_too_uncertain_to_judge_by_keeps_its_yaw_and_the_verdict_takes_the_tilt():
    """Ours 20° of yaw off the autopilot's throughout (a compass judged off), the tilt 1° off: with the heading not
    judged the difference still says the 20° (the figures and plot are the same), the verdict goes on the 1° and
    says nothing; the same heading judged warns after hold_s."""
    ours_t, theirs_t = np.arange(0.0, 10.0, 0.02), np.arange(0.0, 10.0, 0.1)
    ours = quat_from_euler(np.full(len(ours_t), np.radians(1.0)), np.zeros(len(ours_t)), np.full(len(ours_t), 0.35))
    theirs = quat_from_euler(np.zeros(len(theirs_t)), np.zeros(len(theirs_t)), np.zeros(len(theirs_t)))
    settings = CrossCheckSettings(threshold_deg=5.0, hold_s=3.0)
    for judged, warned in ((False, []), (True, [3.0])):
        flags = np.full(len(ours_t), judged)
        _, diffs, events = cross_check_log(ours_t, ours, theirs_t, theirs, settings, None, None, flags)
        assert [round(e.time_s, 1) for e in events] == warned
        assert all(d.yaw_deg == pytest.approx(np.degrees(0.35), abs=1e-6) for d in diffs)


def test_an_attitude_that_waited_past_our_kept_outputs_is_late_and_too_many_waiting_overflow():
    q = tuple(truth(np.array([0.0]))[0].tolist())
    late = CrossCheck(CrossCheckSettings())
    late.add_ours(0.0, q)
    late.add_ours(0.02, q)
    late.add_autopilot(0.01, q)
    late.add_ours(KEEP_S + 1.0, q)  # ours ran on past KEEP_S before the autopilot's attitude was paired
    late.update()
    assert late.unpaired == {"late": 1} and late.missed == 1
    full = CrossCheck(CrossCheckSettings())
    full.add_ours(0.0, q)
    for k in range(MAX_WAITING + 3):  # ahead of ours, more than can wait
        full.add_autopilot(1.0 + 0.01 * k, q)
    assert full.unpaired == {"overflow": 3}


def test_a_hole_in_our_outputs_longer_than_kept_is_a_gap_not_late():
    """Ours stop for 10 s (the solver refused those ticks): the autopilot's attitudes in the hole are gaps, though
    ours before it were forgotten (KEEP_S) by the time ours after it came."""
    ours_t = np.concatenate([np.arange(0.0, 10.0, 0.02), np.arange(20.0, 30.0, 0.02)])
    theirs_t = np.arange(0.05, 29.9, 0.1)
    check, _, _ = cross_check_log(ours_t, truth(ours_t), theirs_t, truth(theirs_t), CrossCheckSettings())
    in_hole = int(np.count_nonzero((theirs_t > ours_t[499]) & (theirs_t < 20.0)))
    assert check.unpaired == {"gap": in_hole} and check.pairs == len(theirs_t) - in_hole


def test_an_autopilot_quaternion_that_is_no_rotation_is_counted_invalid_and_one_off_unit_length_normalised():
    check = CrossCheck(CrossCheckSettings())
    ours_t = np.arange(0.0, 1.0, 0.02)
    for t, q in zip(ours_t, truth(ours_t), strict=True):
        check.add_ours(t, q)
    nan, zero, infinite = np.full(4, np.nan), np.zeros(4), np.array([np.inf, 0.0, 0.0, 0.0])
    for t, q in ((0.1, nan), (0.2, zero), (0.3, infinite), (0.5, 0.9 * truth(np.array([0.5]))[0])):
        check.add_autopilot(t, q)
    (d,), _ = check.update()
    assert check.unpaired == {"invalid": 3} and check.pairs == 1
    assert d.total_deg < 1e-3  # 0.9 × ours, normalised: the same attitude


def test_an_autopilot_on_another_clock_is_found_unpairable_and_only_then():
    ours_t = np.arange(100.0, 110.0, 0.02)
    apart, paired, near = (
        CrossCheck(CrossCheckSettings()),
        CrossCheck(CrossCheckSettings()),
        CrossCheck(CrossCheckSettings()),
    )
    for check, offset_s in ((apart, 3600.0), (paired, 0.0), (near, -KEEP_S / 2)):
        for t, q in zip(ours_t, truth(ours_t), strict=True):
            check.add_ours(float(t), q)
            if round(t * 50) % 5 == 0:  # 10 Hz
                check.add_autopilot(float(t) + offset_s, q)
                check.update()
    # its newest (10 Hz) less our newest (50 Hz): the offset, less up to one of its intervals
    assert apart.pairs == 0 and apart.unpairable_offset_s() == pytest.approx(3600.0, abs=0.1)
    assert paired.pairs > 0 and paired.unpairable_offset_s() is None
    # half a kept span behind ours: they will pair as ours go on, not said to be apart
    assert near.unpairable_offset_s() is None
    assert CrossCheck(CrossCheckSettings()).unpairable_offset_s() is None  # nothing came yet


def _drifting(t_s: np.ndarray, q: np.ndarray, rates_radps: np.ndarray) -> list[bool]:
    drift = GyroDrift()
    return [drift.update(t, qi, w) for t, qi, w in zip(t_s.tolist(), q, rates_radps, strict=True)]


def test_ours_turning_with_the_gyro_does_not_drift():
    """30°/s of yaw at 5° of pitch, the body rates of that very rotation: no window turns unlike the gyro."""
    t = np.arange(0.0, 3.0, 0.02)
    q = truth(t)
    rates = np.array([rotate_ned_to_body(qi, (0.0, 0.0, YAW_RATE_RADPS)) for qi in q])
    assert not any(_drifting(t, q, rates))


@pytest.mark.parametrize("bias_dps", [0.0, 3.0])
@pytest.mark.parametrize(("pitch_rate_dps", "drifting"), [(2.0 * DRIFT_LIMIT_DPS, True), (DRIFT_LIMIT_DPS / 2, False)])
def test_ours_tilting_while_the_gyro_says_still_drifts_above_the_limit(pitch_rate_dps, drifting, bias_dps):
    """Still for 5 s, then a snapshot coming round to a dash's tilt as the speed settles: its pitch creeps while the
    gyro reads its bias alone (0, or 3°/s about x, a raw gyro's: taken out as the fitted rate's slow mean). From
    the end of the creep's first whole 1 s window (6 s; looked at from 6.5 s, margin for where the windows fall)
    it drifts at twice the limit, and not at half of it; never before it."""
    t = np.arange(0.0, 8.0, 0.02)
    creep_deg = np.where(t > 5.0, pitch_rate_dps * (t - 5.0), 0.0)
    q = quat_from_euler(np.zeros(len(t)), np.radians(-2.0 - creep_deg), np.full(len(t), np.radians(-120.0)))
    rates = np.tile([np.radians(bias_dps), 0.0, 0.0], (len(t), 1))
    flags = np.array(_drifting(t, q, rates))
    assert not flags[t < 5.0].any()
    assert (flags[t > 6.5] == drifting).all()


def test_outputs_too_far_apart_to_integrate_never_drift():
    """One unfiltered snapshot a sample at 2 Hz (a ground station's telemetry): its rates are not integrable."""
    t = np.arange(0.0, 5.0, 0.5)
    q = quat_from_euler(np.zeros(len(t)), np.radians(-2.0 - 10.0 * t), np.zeros(len(t)))
    assert not any(_drifting(t, q, np.zeros((len(t), 3))))


def test_a_still_vehicles_noisy_snapshots_do_not_drift():
    """A minute still, each snapshot 0.6° off at random about each axis (a real board's, PX4's sample.ulg), the
    gyro at 0: a window's fitted rate has σ ≈ 0.34°/s an axis (the mean of 25 outputs each half, half a window
    apart), so 2°/s is 6σ: no window of the 60 drifts."""
    rng = np.random.default_rng(7)
    t = np.arange(0.0, 60.0, 0.02)
    jitter = np.radians(rng.normal(0.0, 0.6, (len(t), 3)))
    q = quat_from_euler(jitter[:, 0], jitter[:, 1], np.radians(40.0) + jitter[:, 2])
    assert not any(_drifting(t, q, np.zeros((len(t), 3))))
