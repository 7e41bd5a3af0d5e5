"""Stream requests: each COMMAND_ACK matched to the request it answers, and the received rate judged."""

from __future__ import annotations

from mavattitude.link.requests import (
    CLEAR_FRACTION,
    LOW_FRACTION,
    PendingRequests,
    RateMonitor,
    RequestSchedule,
    StreamRequest,
)

IMU = StreamRequest("RAW_IMU", 27, 200.0)
POSITION = StreamRequest("GLOBAL_POSITION_INT", 33, 1.0)


def test_acks_answer_the_oldest_waiting_request_in_order():
    pending = PendingRequests(timeout_s=2.0, forget_s=10.0)
    pending.sent(IMU, 0.0)
    pending.sent(POSITION, 0.0)
    assert pending.answered(0.1) == IMU
    assert pending.answered(0.2) == POSITION
    assert pending.answered(0.3) is None  # an ACK nobody of ours waits for


def test_a_timed_out_request_is_reported_once_and_still_takes_its_late_ack():
    pending = PendingRequests(timeout_s=2.0, forget_s=10.0)
    pending.sent(IMU, 0.0)
    assert pending.timed_out(1.9) == ([], 0)
    assert pending.timed_out(2.0, heard_s=1.0) == ([IMU], 0)  # heard after it was sent: it did not answer
    assert pending.timed_out(4.0) == ([], 0)  # said once
    pending.sent(POSITION, 5.0)
    assert pending.answered(5.5) == IMU  # the late ACK is the IMU request's, not the position's
    assert pending.answered(5.6) == POSITION


def test_a_request_to_a_vehicle_silent_since_is_dropped_not_said_unanswered():
    """Sent at 5 s to a vehicle last heard at 4.5 s (restarting, or the link down): at the time-out it is dropped,
    counted, and no ACK is matched to it; one sent before the vehicle was last heard times out as before."""
    pending = PendingRequests(timeout_s=2.0, forget_s=10.0)
    pending.sent(IMU, 4.0)
    pending.sent(POSITION, 5.0)
    assert pending.timed_out(7.0, heard_s=4.5) == ([IMU], 1)
    assert len(pending) == 1 and pending.answered(7.5) == IMU


def test_requests_unanswered_for_long_are_forgotten():
    pending = PendingRequests(timeout_s=2.0, forget_s=10.0)
    pending.sent(IMU, 0.0)
    pending.timed_out(2.0)
    assert pending.answered(10.0) is None and len(pending) == 0


def _feed(monitor: RateMonitor, rate_hz: float, start_s: float, duration_s: float) -> list:
    events = []
    n = int(rate_hz * duration_s)
    for i in range(n):
        t = start_s + i / rate_hz
        monitor.count(t)
        event = monitor.update(t)
        if event is not None:
            events.append((round(t, 2), event))
    return events


def test_a_stream_below_the_requested_rate_is_said_once_and_its_recovery_once():
    monitor = RateMonitor(requested_hz=200.0, window_s=1.0)
    events = _feed(monitor, 139.0, 0.0, 5.0)  # SITL's RAW_IMU over a 57600-baud link
    assert [e for _, e in events] == [True] and 1.9 < events[0][0] < 2.1  # two low windows in a row
    assert abs(monitor.rate_hz - 139.0) < 2.0 and monitor.warnings == 1
    assert _feed(monitor, 200.0, 5.0, 3.0)[0][1] is False


def test_no_flip_flop_at_the_edge():
    monitor = RateMonitor(requested_hz=200.0, window_s=1.0)
    _feed(monitor, 150.0, 0.0, 3.0)
    assert monitor.low
    # between the two fractions: neither low enough to warn again nor high enough to clear
    middle = 200.0 * (LOW_FRACTION + CLEAR_FRACTION) / 2
    assert _feed(monitor, middle, 3.0, 5.0) == [] and monitor.low and monitor.warnings == 1


def test_a_stopped_stream_is_not_a_slow_one():
    monitor = RateMonitor(requested_hz=200.0, window_s=1.0)
    _feed(monitor, 200.0, 0.0, 1.5)
    monitor.restart()  # input lost
    assert monitor.update(10.0) is None and not monitor.low


def test_the_schedule_asks_at_once_when_told_then_every_repeat():
    imu = StreamRequest("RAW_IMU", 27, 50.0)
    schedule = RequestSchedule([imu], repeat_s=5.0)
    assert schedule.due(100.0) == []  # not before locking on
    schedule.ask_now(100.0)
    assert schedule.due(100.0) == [imu]
    assert schedule.due(104.9) == [] and schedule.due(105.0) == [imu]
    schedule.ask_now(106.0)  # a new connection or a rebooted autopilot: at once again
    assert schedule.due(106.0) == [imu]
    nothing = RequestSchedule([], repeat_s=5.0)
    nothing.ask_now(0.0)
    assert nothing.due(1e9) == []  # link.request_messages off: never asked
