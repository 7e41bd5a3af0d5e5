"""The fake vehicle as a MAVLink peer: real pymavlink over real UDP on 127.0.0.1."""

from __future__ import annotations

from collections.abc import Iterator

import numpy as np
import pytest

from mavattitude.errors import InputError
from mavattitude.estimation.conventions import quat_multiply
from mavattitude.link.mavlink2 import force_mavlink2, mavlink2, mavutil
from mavattitude.sensors.units import decode, get_profile
from mavattitude.sim import scenarios
from mavattitude.sim.vehicle import OTHER_TELEMETRY_HZ, FakeVehicle, VehicleConfig, _next_deadline

TIMEOUT_S = 5.0


@pytest.fixture
def vehicle() -> Iterator[FakeVehicle]:
    config = VehicleConfig("udpin:127.0.0.1:0", seed=3)
    with FakeVehicle(scenarios.paper_static(600.0), scenarios.paper_sensors(100.0), config) as v:
        yield v


@pytest.fixture
def gcs(vehicle: FakeVehicle) -> Iterator[object]:
    conn = mavutil.mavlink_connection(f"udpout:127.0.0.1:{vehicle.port}", source_system=1, source_component=191)
    force_mavlink2(conn)
    conn.mav.heartbeat_send(mavlink2.MAV_TYPE_ONBOARD_CONTROLLER, mavlink2.MAV_AUTOPILOT_INVALID, 0, 0, 0)
    yield conn
    conn.close()


def _recv(conn: object, kind: str) -> object:
    msg = conn.recv_match(type=kind, blocking=True, timeout=TIMEOUT_S)  # type: ignore[attr-defined]
    assert msg is not None, f"no {kind} within {TIMEOUT_S} s"
    return msg


def _set_interval(conn: object, msg_id: int, interval_us: float, param3: float = 0.0) -> int:
    conn.mav.command_long_send(1, 1, mavlink2.MAV_CMD_SET_MESSAGE_INTERVAL, 0, msg_id, interval_us, param3, 0, 0, 0, 0)  # type: ignore[attr-defined]
    ack = _recv(conn, "COMMAND_ACK")
    assert ack.command == mavlink2.MAV_CMD_SET_MESSAGE_INTERVAL
    return int(ack.result)


def test_silent_until_asked_then_streams_the_truth(vehicle: FakeVehicle, gcs: object) -> None:
    heartbeat = _recv(gcs, "HEARTBEAT")
    assert heartbeat.autopilot == mavlink2.MAV_AUTOPILOT_ARDUPILOTMEGA and heartbeat.get_srcComponent() == 1
    # Between two heartbeats (≥ 1 s) a silent ArduPilot sends positions but no IMU.
    seen = set()
    while True:
        msg = _recv(gcs, None)  # type: ignore[arg-type]
        if msg.get_type() == "HEARTBEAT":
            break
        seen.add(msg.get_type())
    assert "RAW_IMU" not in seen and "GLOBAL_POSITION_INT" in seen
    # ArduPilot denies param3 ≠ 0; then accepts and streams at the asked rate.
    assert _set_interval(gcs, mavlink2.MAVLINK_MSG_ID_RAW_IMU, 10_000, param3=1) == mavlink2.MAV_RESULT_DENIED
    assert _set_interval(gcs, mavlink2.MAVLINK_MSG_ID_RAW_IMU, 10_000) == mavlink2.MAV_RESULT_ACCEPTED
    assert vehicle.stream_rate("RAW_IMU") == pytest.approx(100.0)
    profile = get_profile("ardupilot")
    samples = [decode(_recv(gcs, "RAW_IMU"), profile) for _ in range(200)]
    acc = np.array([s.acc_mps2 for s in samples])
    mag = np.array([s.mag_uT for s in samples])
    truth = vehicle.script.sample([1.0])
    # Mean of 200 samples: noise σ/√200 plus quantisation (1 mG = 0.0098 m/s², 1 mgauss = 0.1 µT).
    np.testing.assert_allclose(acc.mean(0), truth.specific_force_mps2[0], atol=0.01)
    np.testing.assert_allclose(mag.mean(0), truth.mag_uT[0], atol=0.1)
    t = np.array([s.time_s for s in samples])
    assert np.all(np.diff(t) > 0) and np.median(np.diff(t)) == pytest.approx(0.01, abs=1e-3)
    # −1 stops the stream; an unknown message is denied.
    assert _set_interval(gcs, mavlink2.MAVLINK_MSG_ID_RAW_IMU, -1) == mavlink2.MAV_RESULT_ACCEPTED
    assert vehicle.stream_rate("RAW_IMU") is None
    assert _set_interval(gcs, mavlink2.MAVLINK_MSG_ID_PARAM_VALUE, 1000) == mavlink2.MAV_RESULT_DENIED


def test_a_px4_denies_an_imu_message_it_has_no_stream_of_and_goes_on() -> None:
    """PX4 has no RAW_IMU stream: asked for it, the px4 vehicle denies it (its send loop once took the request
    and died encoding RAW_IMU, with no heartbeat after) and streams what it has when asked."""
    config = VehicleConfig("udpin:127.0.0.1:0", profile="px4", message="HIGHRES_IMU")
    with FakeVehicle(scenarios.paper_static(60.0), scenarios.paper_sensors(100.0), config) as vehicle:
        gcs = mavutil.mavlink_connection(f"udpout:127.0.0.1:{vehicle.port}", source_system=1, source_component=191)
        force_mavlink2(gcs)
        gcs.mav.heartbeat_send(mavlink2.MAV_TYPE_ONBOARD_CONTROLLER, mavlink2.MAV_AUTOPILOT_INVALID, 0, 0, 0)
        assert _recv(gcs, "HEARTBEAT").autopilot == mavlink2.MAV_AUTOPILOT_PX4
        assert _set_interval(gcs, mavlink2.MAVLINK_MSG_ID_RAW_IMU, 10_000) == mavlink2.MAV_RESULT_DENIED
        assert vehicle.stream_rate("RAW_IMU") is None
        assert _set_interval(gcs, mavlink2.MAVLINK_MSG_ID_HIGHRES_IMU, 10_000) == mavlink2.MAV_RESULT_ACCEPTED
        _recv(gcs, "HIGHRES_IMU")
        _recv(gcs, "HEARTBEAT")
        gcs.close()
        assert vehicle.thread_errors == []


def _stamps(gcs: object, kind: str, count: int) -> np.ndarray:
    """The vehicle times (µs) of the next ``count`` messages of ``kind``."""
    msgs = [_recv(gcs, kind) for _ in range(count)]
    return np.array([m.time_usec if kind == "RAW_IMU" else 1000 * m.time_boot_ms for m in msgs])  # type: ignore[attr-defined]


def test_the_imu_stream_sends_every_tick_of_the_asked_rate() -> None:
    # At 200 Hz the stream restarted each loop from the time of its next sample, k / 200 · 200, which is
    # above k for one k in 22: ceil skipped that sample (and the next loop's start), 187 a second were sent.
    # Noise-free sensors without jitter or drops: every 5 ms tick goes out, stamped k · 5000 µs exactly.
    config = VehicleConfig("udpin:127.0.0.1:0", stream_on_start=True)
    with FakeVehicle(scenarios.static(600.0), scenarios.ideal_sensors(200.0), config) as vehicle:
        conn = mavutil.mavlink_connection(f"udpout:127.0.0.1:{vehicle.port}", source_system=1, source_component=191)
        try:
            conn.mav.heartbeat_send(mavlink2.MAV_TYPE_ONBOARD_CONTROLLER, mavlink2.MAV_AUTOPILOT_INVALID, 0, 0, 0)
            at_200 = _stamps(conn, "RAW_IMU", 400)
            vehicle.set_rate("RAW_IMU", 300.0)  # a grid 200 Hz meets every 10 ms
            after = _stamps(conn, "RAW_IMU", 800)
        finally:
            conn.close()
    np.testing.assert_array_equal(np.diff(at_200), 5000)
    assert np.all(at_200 % 5000 == 0)
    # The switch: the stream goes on at the first 300 Hz tick at or after the 200 Hz one that was next, the same
    # (the grids meet every 10 ms: 3333 µs after it) or 1667 µs later (6667 µs after the 200 Hz tick before).
    switch = np.flatnonzero(np.diff(after) != 5000)[0]
    assert np.diff(after)[switch] in (3333, 6667)
    at_300 = after[switch + 1 :][:600]  # every stamp from the first on the 300 Hz grid alone
    # 300 Hz: 1e6/300 µs rounded to whole µs, so 3333 or 3334; 600 ticks span 599 periods, to the two
    # end stamps' rounding (half a µs each).
    assert set(np.diff(at_300)) <= {3333, 3334} and abs(at_300[-1] - at_300[0] - 599 * 1e6 / 300) <= 1.0


def test_telemetry_keeps_its_rate_on_absolute_deadlines() -> None:
    # ATTITUDE at 50 Hz was sent a period after the loop woke for it, so each wake-up's lateness (the loop
    # sleeps up to 2 ms) added to every period: 47-48 a second, each stamp ~1 ms further behind the 20 ms grid
    # than the one before, 70-90 ms between the first and the last quarter of 100. On absolute deadlines a stamp
    # is on the grid plus that wake-up's lateness, which does not grow: the quarters' medians (a late wake-up
    # or a stall's skipped ticks move a few stamps, not a median) stay within half a period of each other.
    config = VehicleConfig("udpin:127.0.0.1:0", attitude_rate_hz=50.0)
    with FakeVehicle(scenarios.static(600.0), scenarios.ideal_sensors(200.0), config) as vehicle:
        conn = mavutil.mavlink_connection(f"udpout:127.0.0.1:{vehicle.port}", source_system=1, source_component=191)
        try:
            conn.mav.heartbeat_send(mavlink2.MAV_TYPE_ONBOARD_CONTROLLER, mavlink2.MAV_AUTOPILOT_INVALID, 0, 0, 0)
            stamps_us = _stamps(conn, "ATTITUDE", 100)
        finally:
            conn.close()
    periods = np.cumsum(np.rint(np.diff(stamps_us) / 20_000))  # grid periods since the first stamp, skips counted
    behind_us = stamps_us[1:] - stamps_us[0] - 20_000 * periods
    drift_us = np.median(behind_us[-25:]) - np.median(behind_us[:25])
    assert abs(drift_us) < 10_000, f"ATTITUDE stamps drift {drift_us / 1000:.1f} ms off the 20 ms grid"


def test_other_telemetry_streams_a_real_autopilots_mix_at_its_rates() -> None:
    """``other_telemetry``: the messages of OTHER_TELEMETRY_HZ from boot, each at its rate, counted between two of
    its heartbeats a second apart: one more for where the second falls; fewer only by ticks a stall of the loaded
    machine skipped (never half of them)."""
    config = VehicleConfig("udpin:127.0.0.1:0", other_telemetry=True)
    with FakeVehicle(scenarios.static(600.0), scenarios.ideal_sensors(200.0), config) as vehicle:
        conn = mavutil.mavlink_connection(f"udpout:127.0.0.1:{vehicle.port}", source_system=1, source_component=191)
        try:
            conn.mav.heartbeat_send(mavlink2.MAV_TYPE_ONBOARD_CONTROLLER, mavlink2.MAV_AUTOPILOT_INVALID, 0, 0, 0)
            _recv(conn, "HEARTBEAT")
            counts: dict[str, int] = {}
            while (msg := _recv(conn, None)).get_type() != "HEARTBEAT":  # type: ignore[arg-type]
                counts[msg.get_type()] = counts.get(msg.get_type(), 0) + 1
        finally:
            conn.close()
    for name, rate_hz in OTHER_TELEMETRY_HZ.items():
        assert rate_hz / 2 <= counts.get(name, 0) <= rate_hz + 1, (name, counts.get(name, 0))


def test_a_deadline_stays_on_its_grid_and_a_stall_skips_ticks() -> None:
    assert _next_deadline(1.0, 1.0, 0.25) == 1.25  # on time: one period on
    assert _next_deadline(1.0, 1.2, 0.25) == 1.25  # late within the period: still the grid's next
    assert _next_deadline(1.0, 2.1, 0.25) == 2.25  # a stall of four periods: those ticks are skipped
    assert _next_deadline(1.0, 0.5, 0.25) == 1.25  # called early: the next after the deadline


def test_records_and_scores_attitude_it_receives(vehicle: FakeVehicle, gcs: object) -> None:
    _recv(gcs, "HEARTBEAT")
    vehicle.set_rate("RAW_IMU", 100.0)
    sample = decode(_recv(gcs, "RAW_IMU"), get_profile("ardupilot"))
    q = scenarios.PAPER_Q
    tilted = np.array([np.cos(0.01), np.sin(0.01), 0.0, 0.0])  # 1.146° about body x
    for k in range(10):
        q_sent = quat_multiply(q, tilted) if k % 2 else q
        gcs.mav.attitude_quaternion_send(round(sample.time_s * 1000) - 200 + 20 * k, *q_sent, 0, 0, 0, [0, 0, 0, 0])  # type: ignore[attr-defined]
    assert vehicle.wait_for_outputs(10, TIMEOUT_S)
    score = vehicle.score()
    assert score.count == 10 and score.broken == 0
    assert score.angle_max_deg == pytest.approx(np.degrees(0.02), rel=1e-4)
    assert score.angle_rms_deg == pytest.approx(np.degrees(0.02) / np.sqrt(2), rel=1e-4)
    assert score.output_rate_hz == pytest.approx(50.0, rel=1e-6)
    # Outputs describe times already sent: the enabling IMU went out before the output arrived.
    assert 0.0 < score.latency_p50_ms < 1000.0


def test_clock_faults_are_checked(vehicle: FakeVehicle) -> None:
    with pytest.raises(InputError, match="below zero"):
        vehicle.jump_clock(-1e6)
    vehicle.jump_clock(2.5)
    assert vehicle.vehicle_time(10.0) == pytest.approx(12.5)
    vehicle.reboot()
    now = vehicle.script_time()
    assert vehicle.vehicle_time(now + 1.0) == pytest.approx(1.0, abs=0.01)  # boot time restarts, offset gone
    assert vehicle.stream_rate("RAW_IMU") is None  # back to silent, like a freshly booted ArduPilot


def test_a_batch_the_send_loop_took_before_a_reboot_sends_no_time_from_before_the_boot() -> None:
    # The send loop takes the time and the stream, then a reboot lands before it encodes the batch: the
    # samples due from before the boot must not be stamped with the new epoch (negative time: the send
    # thread died packing HIGHRES_IMU's unsigned time_usec). At 10⁵x, script time runs 1 s per 10 µs.
    config = VehicleConfig("udpin:127.0.0.1:0", message="HIGHRES_IMU", profile="px4", stream_on_start=True, speed=1e5)
    v = FakeVehicle(scenarios.paper_static(600.0), scenarios.consumer_sensors(200.0), config)  # not started
    try:
        msg_id = mavlink2.MAVLINK_MSG_ID_HIGHRES_IMU
        stream = v._streams[msg_id]
        start_s = stream.next_t_s
        v.reboot()
        boot_s = v.script_time()
        sent: list[object] = []
        v.send = sent.append  # type: ignore[method-assign]
        v._send_imu_until(msg_id, stream, boot_s + 1.0)
        assert boot_s - start_s > 0.05  # samples (200 Hz) were due from before the boot
        times_s = [m.time_usec * 1e-6 for m in sent]  # type: ignore[attr-defined]
        assert times_s and min(times_s) >= 0.0
        for m in sent:
            m.pack(v.conn.mav)  # type: ignore[attr-defined]
    finally:
        v.stop()


def test_an_output_is_timed_to_the_microsecond_by_its_covariance(vehicle: FakeVehicle, gcs: object) -> None:
    """ATTITUDE_QUATERNION's time_boot_ms rounds to the ms, past its sample half the time: an output per sample of a
    4 Hz input was then paired with the next sample, 250 ms on (its latency −249 ms). The covariance sent with it
    carries the time in µs; without one the ms stays."""
    q = (1.0, 0.0, 0.0, 0.0)
    gcs.mav.attitude_quaternion_send(10251, *q, 0.0, 0.0, 0.0)  # type: ignore[attr-defined]
    gcs.mav.attitude_quaternion_cov_send(10250700, q, 0.0, 0.0, 0.0, [0.0] * 9)  # type: ignore[attr-defined]
    gcs.mav.attitude_quaternion_send(12000, *q, 0.0, 0.0, 0.0)  # type: ignore[attr-defined]
    assert vehicle.wait_for_outputs(2, TIMEOUT_S)
    assert vehicle.wait_until(lambda: vehicle.received[(1, 191, "ATTITUDE_QUATERNION_COV")] == 1, TIMEOUT_S)
    assert [row[1] for row in vehicle.attitude_log] == [10.2507, 12.0]
