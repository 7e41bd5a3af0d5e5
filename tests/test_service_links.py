"""The service's link behaviour: ACKs matched to their requests, streams asked for again when the link
reopens, and a slow link's input rate said once."""

from __future__ import annotations

import logging
import time

import numpy as np
import pytest
from pymavlink.dialects.v20 import ardupilotmega as mavlink2

from mavattitude import service as service_module
from mavattitude.config import from_dict
from mavattitude.estimation.conventions import (
    angle_between,
    quat_conjugate,
    quat_from_euler,
    quat_multiply,
    rotate_ned_to_body,
)
from mavattitude.link.memory import MemoryLink
from mavattitude.link.source import Heartbeat
from mavattitude.pipeline import AttitudePipeline
from mavattitude.reports import REFUSAL_HINTS
from mavattitude.sensors import units
from mavattitude.service import AttitudeService
from mavattitude.sim import scenarios
from mavattitude.sim.daemon import config_for
from mavattitude.sim.vehicle import FakeVehicle, VehicleConfig
from mavattitude.systemd_notify import SystemdNotifier
from tests.test_dispatch import Peer, sent
from tests.test_service import G_NED_MPS2, Q_TRUE, Running, make_config

STEP_S = 0.06  # longer than the service's TICK_S: every step runs its periodic work
EVENT_TIMEOUT_S = 10.0


def _service(**overrides: object) -> tuple[AttitudeService, MemoryLink]:
    # no repeats within a test; the cross-check (its ATTITUDE request) has its own tests
    config = make_config(**{"link.request_repeat_s": 60.0, "crosscheck.enabled": False, **overrides})
    link = MemoryLink()
    return AttitudeService(config, link, AttitudePipeline(config), SystemdNotifier(environ={})), link


def _step_until(service: AttitudeService, done, timeout_s: float = EVENT_TIMEOUT_S) -> None:
    deadline = time.monotonic() + timeout_s
    while not done():
        assert time.monotonic() < deadline, "condition not met in time"
        service.step(STEP_S)


def _ack(peer: Peer, target: tuple[int, int] = (1, 191), result: int = mavlink2.MAV_RESULT_ACCEPTED) -> bytes:
    return peer.pack(mavlink2.MAVLink_command_ack_message(mavlink2.MAV_CMD_SET_MESSAGE_INTERVAL, result, 0, 0, *target))


def test_each_ack_is_matched_to_the_request_it_answers(caplog):
    caplog.set_level(logging.INFO, logger="mavattitude.link.session")
    service, link = _service(**{"reference.magnetic": "auto"})  # asks for RAW_IMU, the position and the time
    vehicle = Peer()
    link.deliver(vehicle.heartbeat())
    _step_until(service, lambda: len(sent(link, "COMMAND_LONG")) == 3)
    assert [c.param1 for c in sent(link, "COMMAND_LONG")] == [
        mavlink2.MAVLINK_MSG_ID_RAW_IMU,
        mavlink2.MAVLINK_MSG_ID_GLOBAL_POSITION_INT,
        mavlink2.MAVLINK_MSG_ID_SYSTEM_TIME,
    ]
    # A ground station's ACK (forwarded by a router) is not ours; the three for us answer our three
    # requests in order; a fifth has no request of ours waiting.
    denied = _ack(vehicle, result=mavlink2.MAV_RESULT_DENIED)
    link.deliver(_ack(vehicle, (255, 190)), _ack(vehicle), _ack(vehicle), denied, _ack(vehicle))
    service.step(0.0)
    c = service.counters
    assert c.interval_requests == 3 and c.acks == {"ACCEPTED": 2, "DENIED": 1} and c.acks_unmatched == 1
    said = [r for r in caplog.records if r.getMessage().startswith("autopilot ")]
    assert [r.getMessage() for r in said] == [
        "autopilot accepted RAW_IMU at 200 Hz",
        "autopilot accepted GLOBAL_POSITION_INT at 1 Hz",
        "autopilot answered SET_MESSAGE_INTERVAL(SYSTEM_TIME at 0.2 Hz) with DENIED: going without",
    ]
    assert all(r.levelno == logging.INFO for r in said)  # SYSTEM_TIME is optional: no warning


def test_streams_are_asked_for_again_as_soon_as_the_link_reopens(monkeypatch):
    service, link = _service()
    vehicle = Peer()
    link.deliver(vehicle.heartbeat())
    _step_until(service, lambda: len(sent(link, "COMMAND_LONG")) == 1)
    connection = link._conn

    def reset(*args: object) -> None:
        raise ConnectionResetError("peer gone")

    monkeypatch.setattr(connection, "recv_msg", reset)  # the next read fails: the link drops and reopens
    link.deliver(vehicle.heartbeat())
    _step_until(service, lambda: link.counters.reconnects == 1)
    reopened = time.monotonic()
    _step_until(service, lambda: len(sent(link, "COMMAND_LONG")) == 2)
    # within a loop tick or two, not at the next request_repeat_s (60 s here)
    assert time.monotonic() - reopened < 5 * STEP_S


def test_a_slow_link_is_said_once_with_the_measured_rate(monkeypatch, caplog):
    caplog.set_level(logging.INFO, logger="mavattitude.service")
    monkeypatch.setattr(service_module, "RATE_WINDOW_S", 0.5)  # judged over 0.5 s windows, not 5 s
    vehicle_config = VehicleConfig("udpin:127.0.0.1:0", fly_when_asked=True, link_max_imu_hz=100.0)
    with FakeVehicle(scenarios.static(600.0), scenarios.paper_sensors(200.0), vehicle_config) as v:
        config = from_dict(config_for(v, output={"stats_interval_s": 60.0}))
        assert config.link.request_rate_hz == 200.0
        running = Running(config)
        try:
            counters = running.service.counters
            assert v.wait_until(lambda: counters.rate_warnings == 1, EVENT_TIMEOUT_S)
            # six more low windows (three times what it took to say it): said once all the same
            assert not v.wait_until(lambda: counters.rate_warnings > 1, 6 * 0.5)
        finally:
            running.finish()
    warnings = [r.getMessage() for r in caplog.records if "below the 200 Hz asked for" in r.getMessage()]
    assert len(warnings) == 1 and "lower link.request_rate_hz" in warnings[0]
    measured_hz = float(warnings[0].split(" arrives at ")[1].split(" Hz")[0])
    assert 90.0 <= measured_hz <= 105.0  # the link's 100 Hz (the window counts intervals, ±1 sample)
    assert any("RAW_IMU" in t and "< 200 asked" in t for t in v.statustexts)


def test_a_fast_enough_link_is_not_warned_about(monkeypatch):
    rate_hz = 200.0
    monkeypatch.setattr(service_module, "RATE_WINDOW_S", 0.5)
    vehicle_config = VehicleConfig("udpin:127.0.0.1:0", fly_when_asked=True)
    with FakeVehicle(scenarios.static(600.0), scenarios.paper_sensors(rate_hz), vehicle_config) as v:
        running = Running(from_dict(config_for(v, output={"stats_interval_s": 60.0})))
        try:
            counters = running.service.counters
            assert v.wait_until(lambda: counters.input_rate_hz == counters.input_rate_hz, EVENT_TIMEOUT_S)
            assert not v.wait_until(lambda: counters.rate_warnings > 0, 6 * 0.5)
        finally:
            running.finish()
    assert counters.rate_warnings == 0 and counters.input_rate_hz > 0.9 * rate_hz


def _param_value(peer: Peer, name: str, value: float) -> bytes:
    return peer.pack(mavlink2.MAVLink_param_value_message(name.encode(), value, mavlink2.MAV_PARAM_TYPE_REAL32, 900, 0))


def test_the_autopilots_level_trim_is_asked_for_and_turns_the_attitude_into_the_vehicles_frame():
    """The vehicle's readings are its board's; its AHRS_TRIM_Y says the board is pitched 6° down in the frame."""
    service, link = _service()
    vehicle = Peer()
    link.deliver(vehicle.heartbeat())
    _step_until(service, lambda: len(sent(link, "PARAM_REQUEST_READ")) == 5)
    asked = sent(link, "PARAM_REQUEST_READ")
    assert [(r.param_id, r.param_index, r.target_system, r.target_component) for r in asked] == [
        ("AHRS_TRIM_X", -1, 1, 1),
        ("AHRS_TRIM_Y", -1, 1, 1),
        *((f"COMPASS_USE{n}", -1, 1, 1) for n in ("2", "3", "")),  # whether it uses each compass (tests below)
    ]
    link.deliver(*vehicle.stream(100))
    _step_until(service, lambda: not link.inbox)
    untrimmed = sent(link, "ATTITUDE_QUATERNION")[-1]
    link.deliver(_param_value(vehicle, "AHRS_TRIM_X", 0.0), _param_value(vehicle, "AHRS_TRIM_Y", np.radians(-6.0)))
    link.deliver(*vehicle.stream(200))
    _step_until(service, lambda: not link.inbox)
    trimmed = sent(link, "ATTITUDE_QUATERNION")[-1]
    # the frame's attitude: the board's (Q_TRUE) turned back by the trim, R_frame = R_board · T(trim)ᵀ
    frame = quat_multiply(Q_TRUE, quat_conjugate(quat_from_euler(0.0, np.radians(-6.0), 0.0)))
    q = [np.array([m.q1, m.q2, m.q3, m.q4]) for m in (untrimmed, trimmed)]
    # RAW_IMU quantisation moves ours by < 0.2° (test_service's tolerance is 0.5°)
    assert np.degrees(angle_between(q[0], Q_TRUE)) < 0.5 and np.degrees(angle_between(q[1], frame)) < 0.5
    assert service.counters.parameter_requests == 5  # each asked once (the repeat is a minute away)


def test_a_level_trim_never_answered_is_asked_for_three_times_then_gone_without(caplog):
    caplog.set_level(logging.INFO, logger="mavattitude.link.session")
    service, link = _service(**{"link.request_repeat_s": 0.5})
    link.deliver(Peer().heartbeat())
    _step_until(service, lambda: any("did not answer" in r.getMessage() for r in caplog.records))
    names = ("AHRS_TRIM_X", "AHRS_TRIM_Y", "COMPASS_USE2", "COMPASS_USE3", "COMPASS_USE")
    assert [r.param_id for r in sent(link, "PARAM_REQUEST_READ")] == list(names) * 3
    said = [r.getMessage() for r in caplog.records if "did not answer" in r.getMessage()]
    assert said == [f"the autopilot did not answer for {', '.join(names)} in 3 requests: going without"]
    service.step(1.0)
    assert len(sent(link, "PARAM_REQUEST_READ")) == 15


def test_the_level_trim_is_not_asked_for_when_configured_off():
    service, link = _service(**{"mounting.autopilot_trim": False, "link.request_repeat_s": 0.5})
    link.deliver(Peer().heartbeat())
    _step_until(service, lambda: service.counters.interval_requests >= 2)  # two rounds of stream requests
    compasses = ["COMPASS_USE2", "COMPASS_USE3", "COMPASS_USE"]  # the compasses' only
    assert [r.param_id for r in sent(link, "PARAM_REQUEST_READ")] == compasses * 2


def test_a_compass_the_autopilot_does_not_use_is_said_once_and_its_use_again_too(caplog):
    """RAW_IMU carries ArduPilot's first compass whether or not it heads by it: one it set aside (COMPASS_USE 0:
    interference, a bad mount) gives our heading, unless the pilot is told and moves input.message to another."""
    caplog.set_level(logging.INFO, logger="mavattitude.service")
    service, link = _service(**{"output.statustext_interval_s": 0.0})
    vehicle = Peer()
    link.deliver(vehicle.heartbeat())
    _step_until(service, lambda: len(sent(link, "PARAM_REQUEST_READ")) == 5)
    # answered twice (a ground station asking too): said once; the others' use not answered (lost)
    link.deliver(_param_value(vehicle, "COMPASS_USE", 0.0), _param_value(vehicle, "COMPASS_USE", 0.0))
    _step_until(service, lambda: not link.inbox)
    link.deliver(_param_value(vehicle, "COMPASS_USE", 1.0))  # the pilot set it back in use
    _step_until(service, lambda: not link.inbox)
    said = [r.getMessage() for r in caplog.records if "compass 1" in r.getMessage()]
    assert len(said) == 2 and said[0].startswith("the autopilot does not use compass 1 (COMPASS_USE 0)")
    assert said[0].endswith("input.message SCALED_IMU2 carries compass 2 or SCALED_IMU3 carries compass 3")
    assert said[1] == "the autopilot uses compass 1 again (COMPASS_USE 1)"
    texts = [m.text for m in sent(link, "STATUSTEXT") if "compass" in m.text]
    assert texts == ["mavattitude: compass 1 unused by autopilot"]


@pytest.mark.parametrize(
    ("others", "instead"),
    [
        ((1.0, 1.0), "it uses compass 2: input.message SCALED_IMU2 carries it"),
        ((0.0, 1.0), "it uses compass 3: input.message SCALED_IMU3 carries it"),
        ((0.0, 0.0), "it uses none of its compasses (its heading comes from elsewhere: a GPS, or nowhere)"),
    ],
)
def test_the_compass_the_autopilot_uses_instead_is_named(others, instead, caplog):
    """Its other compasses' use is asked first: answered (as ArduPilot answers, in the order asked) before the one
    RAW_IMU carries, they say which it heads by, and the input message that carries that one."""
    caplog.set_level(logging.WARNING, logger="mavattitude.service")
    service, link = _service()
    vehicle = Peer()
    link.deliver(vehicle.heartbeat())
    _step_until(service, lambda: len(sent(link, "PARAM_REQUEST_READ")) == 5)
    answers = zip(("COMPASS_USE2", "COMPASS_USE3", "COMPASS_USE"), (*others, 0.0), strict=True)
    link.deliver(*(_param_value(vehicle, name, value) for name, value in answers))
    _step_until(service, lambda: not link.inbox)
    (said,) = [r.getMessage() for r in caplog.records if "does not use compass 1" in r.getMessage()]
    assert said.endswith(instead)


@pytest.mark.parametrize(
    ("message", "asked"), [("SCALED_IMU2", ["COMPASS_USE", "COMPASS_USE3", "COMPASS_USE2"]), ("HIGHRES_IMU", [])]
)
def test_the_compass_asked_about_is_the_one_the_input_message_carries(message, asked):
    service, link = _service(**{"input.message": message, "mounting.autopilot_trim": False})
    link.deliver(Peer().heartbeat())
    _step_until(service, lambda: service.counters.interval_requests >= 1)
    assert [r.param_id for r in sent(link, "PARAM_REQUEST_READ")] == asked  # HIGHRES_IMU (PX4's) carries no number


def test_an_imu_time_that_stops_advancing_is_said_once_with_why_and_the_output_coming_back_too(caplog):
    """The autopilot's RAW_IMU keeps coming, stamped with one time (a stuck clock): every sample is a duplicate,
    no attitude goes out, and without a word the service would look merely idle."""
    caplog.set_level(logging.INFO, logger="mavattitude.service")
    service, link = _service()
    vehicle = Peer()
    link.deliver(vehicle.heartbeat(), *vehicle.stream(200))
    _step_until(service, lambda: not link.inbox)
    assert service.waiting is service_module.Waiting.RUNNING
    stuck_s = vehicle.time_s

    def stuck(count: int) -> list[bytes]:
        out = []
        for _ in range(count):
            vehicle.time_s = stuck_s
            out.append(vehicle.raw_imu())
        return out

    def frozen_until(done) -> None:
        while not done():
            link.deliver(*stuck(10))
            _step_until(service, lambda: not link.inbox)

    frozen_until(lambda: service.waiting is service_module.Waiting.ATTITUDES)
    said = [r for r in caplog.records if "no attitude has gone out" in r.getMessage()]
    assert len(said) == 1 and said[0].levelno == logging.WARNING
    assert "refused: duplicate" in said[0].getMessage() and "its IMU time does not advance" in said[0].getMessage()
    assert "arrives but no attitude goes out (refused: duplicate" in service.waiting_text()
    frozen_until(lambda: len(sent(link, "HEARTBEAT")) >= 3)  # a while longer frozen: said once only
    texts = [m.text for m in sent(link, "STATUSTEXT") if "no attitude" in m.text]
    assert texts == ["mavattitude: RAW_IMU duplicate: no attitude"]
    vehicle.time_s = stuck_s + 0.005
    link.deliver(*vehicle.stream(100))
    _step_until(service, lambda: not link.inbox)
    assert service.waiting is service_module.Waiting.RUNNING
    assert sum("attitudes go out again" in r.getMessage() for r in caplog.records) == 1
    assert sum("no attitude has gone out" in r.getMessage() for r in caplog.records) == 1


def test_every_attitude_goes_out_with_its_covariance():
    service, link = _service()
    vehicle = Peer()
    link.deliver(vehicle.heartbeat(), *vehicle.stream(200))
    _step_until(service, lambda: not link.inbox)
    plain, with_cov = sent(link, "ATTITUDE_QUATERNION"), sent(link, "ATTITUDE_QUATERNION_COV")
    assert len(plain) == len(with_cov) > 40
    for a, b in zip(plain, with_cov, strict=True):
        assert b.time_usec == a.time_boot_ms * 1000 and b.q == pytest.approx([a.q1, a.q2, a.q3, a.q4], abs=1e-7)
        cov = np.array(b.covariance).reshape(3, 3)
        assert np.allclose(cov, cov.T, rtol=1e-6) and np.all(np.linalg.eigvalsh(cov) > 0.0)
        # σ_mag/(|B| cos I) = 0.5/25 rad = 1.15° about the vertical, σ_acc/g = 0.3° for the tilt
        assert np.radians(0.2) < np.sqrt(np.diag(cov)).max() < np.radians(1.5)


def test_the_covariance_message_is_off_when_configured():
    service, link = _service(**{"output.covariance": False})
    vehicle = Peer()
    link.deliver(vehicle.heartbeat(), *vehicle.stream(200))
    _step_until(service, lambda: not link.inbox)
    assert sent(link, "ATTITUDE_QUATERNION") and not sent(link, "ATTITUDE_QUATERNION_COV")


def _autopilot_8_deg_off(
    vehicle: Peer, clock_offset_s: float = 0.0, gps: bool = False, axis: int = 0, **raw_imu: object
) -> list[bytes]:
    """6 s of RAW_IMU at 200 Hz with the autopilot's ATTITUDE at 10 Hz, its roll (``axis`` 0; 2: its yaw) 8° off
    Q_TRUE's (stamped ``clock_offset_s`` from the IMU's clock); with ``gps``, GPS_RAW_INT at 5 Hz: a 3D fix,
    10 satellites, 0 m/s."""
    roll_deg, pitch_deg, yaw_deg = (a + (8.0 if k == axis else 0.0) for k, a in enumerate((10.0, -20.0, 135.0)))
    datagrams = [vehicle.heartbeat()]
    for i in range(60):  # 0.1 s of RAW_IMU, then the autopilot's ATTITUDE for its middle
        datagrams += vehicle.stream(20, **raw_imu)
        stamp_ms = round((vehicle.time_s - 0.05 + clock_offset_s) * 1000)
        attitude = mavlink2.MAVLink_attitude_message(
            stamp_ms, np.radians(roll_deg), np.radians(pitch_deg), np.radians(yaw_deg), 0.0, 0.0, 0.0
        )
        datagrams.append(vehicle.pack(attitude))
        if gps and i % 2:  # sent 0.1 s after its fix (ArduPilot: µs since boot)
            fix_us = round((vehicle.time_s - 0.1) * 1e6)
            datagrams.append(vehicle.pack(mavlink2.MAVLink_gps_raw_int_message(fix_us, 3, 0, 0, 0, 80, 90, 0, 0, 10)))
    return datagrams


def test_the_cross_check_publishes_the_difference_and_warns_once(caplog):
    caplog.set_level(logging.WARNING, logger="mavattitude.service")
    service, link = _service(**{"crosscheck.enabled": True})
    vehicle = Peer()
    link.deliver(*_autopilot_8_deg_off(vehicle))
    _step_until(service, lambda: not link.inbox)
    _step_until(service, lambda: len(sent(link, "NAMED_VALUE_FLOAT")) >= 4)  # published at 2 Hz
    request = [c for c in sent(link, "COMMAND_LONG") if c.param1 == mavlink2.MAVLINK_MSG_ID_ATTITUDE]
    assert len(request) == 1 and request[0].param2 == 1e6 / 10.0  # 10 Hz
    values = {m.name: m.value for m in sent(link, "NAMED_VALUE_FLOAT")[-4:]}
    assert set(values) == {"xc_roll", "xc_pitch", "xc_yaw", "xc_total"}
    # RAW_IMU quantisation moves ours by < 0.2° (test_service's tolerance is 0.5°)
    assert values["xc_roll"] == pytest.approx(-8.0, abs=0.5) and values["xc_total"] == pytest.approx(8.0, abs=0.5)
    texts = [m.text for m in sent(link, "STATUSTEXT") if "autopilot" in m.text]
    assert texts == ["mavattitude: 8 deg off the autopilot's attitude"]
    assert sum("differ by" in r.getMessage() for r in caplog.records) == 1
    assert not any("none can be paired" in r.getMessage() for r in caplog.records)  # one clock: paired
    caplog.set_level(logging.INFO, logger="mavattitude.service")
    service._log_counters(final=True)
    line = [r.getMessage() for r in caplog.records if r.getMessage().startswith("counters (final):")][-1]
    pairs = dict(item.split("=") for item in line.removeprefix("counters (final): ").split())
    assert pairs["xc_warnings"] == "1" and int(pairs["xc_pairs"]) >= 55  # 60 less the first, before ours
    assert float(pairs["xc_total_deg"]) == pytest.approx(8.0, abs=0.5) and pairs["xc_unjudged"] == "0"


@pytest.mark.parametrize(("mag_std_uT", "warned"), [(0.5, True), (30.0, False)])
def test_a_yaw_difference_is_not_judged_where_our_heading_is_too_uncertain(mag_std_uT, warned):
    """The autopilot's yaw 8° off ours. With the compass's σ at 30 µT (on a 50 µT field) our heading's σ is over
    30°: the difference is published, yaw and all, and the verdict goes on the tilt alone (no warning); at 0.5 µT
    it warns."""
    service, link = _service(**{"crosscheck.enabled": True, "noise.mag_std_uT": mag_std_uT})
    link.deliver(*_autopilot_8_deg_off(Peer(), axis=2))
    _step_until(service, lambda: not link.inbox)
    _step_until(service, lambda: len(sent(link, "NAMED_VALUE_FLOAT")) >= 4)  # published at 2 Hz
    values = {m.name: m.value for m in sent(link, "NAMED_VALUE_FLOAT")[-4:]}
    assert values["xc_yaw"] == pytest.approx(-8.0, abs=0.5)
    assert bool([m for m in sent(link, "STATUSTEXT") if "off the autopilot" in m.text]) is warned


def test_an_autopilot_attitude_on_another_clock_than_the_imu_is_said_to_leave_no_cross_check(caplog):
    """RAW_IMU stamped an hour from the autopilot's ATTITUDE (a bridge filling time_usec with Unix time, say): no
    attitude of the autopilot's can ever be paired with ours, and the cross-check, on, would check nothing."""
    caplog.set_level(logging.WARNING, logger="mavattitude.service")
    service, link = _service(**{"crosscheck.enabled": True})
    link.deliver(*_autopilot_8_deg_off(Peer(), clock_offset_s=3600.0))
    _step_until(service, lambda: any("none can be paired" in r.getMessage() for r in caplog.records))
    (said,) = [r.getMessage() for r in caplog.records if "none can be paired" in r.getMessage()]
    assert said.startswith("the autopilot's ATTITUDE is stamped +3600 s from our RAW_IMU time")
    assert [m.text for m in sent(link, "STATUSTEXT") if "cross-check" in m.text] == [
        "mavattitude: no cross-check: clocks apart"
    ]
    assert not any("differ by" in r.getMessage() for r in caplog.records)


@pytest.mark.parametrize(
    ("method", "gps", "judged"), [("ign", True, False), ("fused", False, False), ("fused", True, True)]
)
def test_an_attitude_that_may_read_acceleration_as_tilt_is_published_not_judged(caplog, method, gps, judged):
    """The specific force 5 % above g throughout (a climb; beyond the 3 % that marks the vehicle moving, within
    the 10 % that down-weights it): the 8° is published as before, but ign's attitudes are not judged, nor the
    fused filter's without the GPS receiver's velocity (it leans in a sustained acceleration). With it, the fused
    filter takes the vehicle's acceleration out: judged, and the 8° warned about."""
    caplog.set_level(logging.INFO, logger="mavattitude.service")
    service, link = _service(**{"crosscheck.enabled": True, "estimator.method": method})
    vehicle = Peer()
    acc = rotate_ned_to_body(Q_TRUE, 1.05 * G_NED_MPS2)
    link.deliver(*_autopilot_8_deg_off(vehicle, gps=gps, acc_mps2=acc))
    _step_until(service, lambda: not link.inbox)
    _step_until(service, lambda: len(sent(link, "NAMED_VALUE_FLOAT")) >= 4)
    values = {m.name: m.value for m in sent(link, "NAMED_VALUE_FLOAT")[-4:]}
    assert values["xc_total"] == pytest.approx(8.0, abs=0.5)  # RAW_IMU quantisation, as above
    service._log_counters(final=True)
    line = [r.getMessage() for r in caplog.records if r.getMessage().startswith("counters (final):")][-1]
    pairs = dict(item.split("=") for item in line.removeprefix("counters (final): ").split())
    assert int(pairs["xc_pairs"]) >= 55 and pairs["xc_warnings"] == str(int(judged))
    # judged: all but those before the GPS acceleration is in use (from the second fix, 0.4 s) and settle_s after
    unjudged = int(pairs["xc_unjudged"])
    assert unjudged < 20 if judged else unjudged == int(pairs["xc_pairs"])


@pytest.mark.parametrize(("magnetic", "asked"), [("auto", True), ({"field_ned_uT": [20.0, 0.0, 45.0]}, False)])
def test_the_declination_is_asked_for_only_where_the_field_may_be_measured(magnetic, asked):
    """With reference.magnetic auto and no position the field is the compass's own, its north magnetic: the
    autopilot's COMPASS_DEC makes it true (docs/frames.md); a field given in the config has its own north."""
    service, link = _service(**{"reference.magnetic": magnetic, "mounting.autopilot_trim": False})
    link.deliver(Peer().heartbeat())
    _step_until(service, lambda: service.counters.interval_requests >= 1)
    assert ("COMPASS_DEC" in [r.param_id for r in sent(link, "PARAM_REQUEST_READ")]) is asked


def test_a_px4_is_asked_for_its_own_declination():
    """PX4's EKF2 heads by EKF2_MAG_DECL without a GPS position (saved from its last fix's lookup): input.profile px4
    asks for it, not ArduPilot's COMPASS_DEC."""
    service, link = _service(
        **{
            "input.profile": "px4",
            "input.message": "HIGHRES_IMU",
            "mounting.autopilot_trim": False,
            "reference.magnetic": "auto",
        }
    )
    link.deliver(Peer().heartbeat())
    _step_until(service, lambda: service.counters.interval_requests >= 1)
    assert [r.param_id for r in sent(link, "PARAM_REQUEST_READ")] == ["EKF2_MAG_DECL"]


def test_waiting_for_the_imu_stream_names_the_imu_message_the_vehicle_sends_instead():
    """A PX4 sends HIGHRES_IMU, never the default RAW_IMU: the wait says so, with what to set."""
    service, link = _service()
    vehicle = Peer()
    sample = units.ImuSample(100.0, (0.0, 0.0, -9.8), (0.0, 0.0, 0.0), (20.0, 0.0, 45.0))
    highres = mavlink2.MAVLink_highres_imu_message(**units.encode(sample, units.PROFILES["px4"], "HIGHRES_IMU"))
    link.deliver(vehicle.heartbeat(), vehicle.pack(highres))
    _step_until(service, lambda: not link.inbox)
    assert service.waiting_text() == (
        "waiting for the IMU stream: RAW_IMU from system 1, component 1, asked for at 200 Hz; it sends HIGHRES_IMU: "
        "set input.message (and input.profile) to read one"
    )


def test_a_px4_asked_for_raw_imu_is_told_apart_by_its_heartbeat(caplog):
    """The default config on a PX4, which has no RAW_IMU stream and denies the request: said once on locking on
    (log and STATUSTEXT, with what to set), and the wait names the refusal and the fix; an ArduPilot's HEARTBEAT
    with the same config says nothing of its firmware."""
    caplog.set_level(logging.WARNING, logger="mavattitude.service")
    service, link = _service()
    vehicle = Peer()
    link.deliver(vehicle.heartbeat(autopilot=mavlink2.MAV_AUTOPILOT_PX4))
    _step_until(service, lambda: service.counters.interval_requests >= 1)
    link.deliver(_ack(vehicle, result=mavlink2.MAV_RESULT_DENIED))
    _step_until(service, lambda: not link.inbox)
    fix = (
        "the autopilot is a PX4 (its HEARTBEAT), which has no RAW_IMU stream: set input.message: HIGHRES_IMU and "
        "input.profile: px4"
    )
    assert [r.getMessage() for r in caplog.records if r.name == "mavattitude.service"] == [fix]
    assert [m.text for m in sent(link, "STATUSTEXT") if "PX4" in m.text] == ["mavattitude: a PX4 sends no RAW_IMU"]
    assert service.waiting_text() == (
        f"waiting for the IMU stream: RAW_IMU from system 1, component 1, asked for at 200 Hz (answered DENIED); {fix}"
    )
    ardupilot, _ = _service()
    ardupilot.dispatcher.handle((0.0, (1, 1), Heartbeat(autopilot=True, profile="ardupilot")))
    assert ardupilot.waiting_text().endswith("asked for at 200 Hz")


@pytest.mark.parametrize(("rate_hz", "asked"), [(5.0, ["SCALED_IMU2", "SCALED_IMU3"]), (0.0, [])])
def test_the_other_compasses_messages_are_asked_for_when_configured(rate_hz, asked):
    """compass.others_rate_hz: the other compasses' IMU messages at that rate, each judged beside ours; off by
    default (a judge costs a front end per IMU sample), when only what the vehicle streams is judged."""
    service, link = _service(**{"compass.others_rate_hz": rate_hz})
    link.deliver(Peer().heartbeat())
    _step_until(service, lambda: service.counters.interval_requests >= 1)
    ids = {mavlink2.MAVLINK_MSG_ID_SCALED_IMU2: "SCALED_IMU2", mavlink2.MAVLINK_MSG_ID_SCALED_IMU3: "SCALED_IMU3"}
    requests = [c for c in sent(link, "COMMAND_LONG") if c.param1 in ids]
    assert [ids[int(c.param1)] for c in requests] == asked
    assert all(c.param2 == pytest.approx(1e6 / rate_hz) for c in requests)


@pytest.mark.parametrize("reference", ["auto", {"declination_deg": 0.0, "inclination_deg": 60.0}])
def test_an_imu_message_of_zeros_is_said_with_the_imu_messages_the_vehicle_sends_besides(reference):
    """ArduPilot without a third IMU sends SCALED_IMU3 with a zero accelerometer and gyroscope (its compass may be
    real): every sample is refused as a dead accelerometer, and the wait names what the vehicle sends besides;
    with reference.magnetic auto and no position too (the wait for a position is not what stops it)."""
    service, link = _service(**{"input.message": "SCALED_IMU3", "reference.magnetic": reference})
    vehicle, profile = Peer(), units.PROFILES["ardupilot"]
    dead = units.ImuSample(100.0, (0.0, 0.0, 0.0), (0.0, 0.0, 0.0), (20.0, 0.0, 45.0))
    live = units.ImuSample(100.0, (0.0, 0.0, -9.8), (0.0, 0.0, 0.0), (20.0, 0.0, 45.0))
    third = mavlink2.MAVLink_scaled_imu3_message(**units.encode(dead, profile, "SCALED_IMU3"))
    first = mavlink2.MAVLink_raw_imu_message(**units.encode(live, profile, "RAW_IMU"))
    link.deliver(vehicle.heartbeat(), vehicle.pack(third), vehicle.pack(first))
    _step_until(service, lambda: not link.inbox)
    assert service.waiting_text() == (
        f"waiting for the first attitude (refused: dead_acc 1 ({REFUSAL_HINTS['dead_acc']})); it sends RAW_IMU: "
        "set input.message (and input.profile) to read one"
    )


def test_an_accelerometer_in_the_wrong_units_is_said_with_the_profile_to_check(caplog):
    """input.profile adis16405 on an ArduPilot's RAW_IMU (its 3.33 mg per count for the autopilot's 1 mg): the
    accelerometer reads 3.33 g, so the vehicle never reads as still and, without a position, no field is measured.
    Said once when judged (log and STATUSTEXT, with the profile's scale to check), and in the wait."""
    caplog.set_level(logging.WARNING, logger="mavattitude.service")
    service, link = _service(**{"input.profile": "adis16405", "reference.magnetic": "auto"})
    vehicle = Peer()
    link.deliver(vehicle.heartbeat(), *vehicle.stream(1100))  # 5.5 s at 200 Hz
    _step_until(service, lambda: not link.inbox)
    warned = [r.getMessage() for r in caplog.records if "wrong units" in r.getMessage()]
    assert warned == [
        "accelerometer: its median |f| over the first 5 s is 3.33 g, where a vehicle's is about 1 g: wrong units: "
        "check input.profile adis16405's scale, 0.03266 m/s² per unit of RAW_IMU's accelerometer: the autopilot's? "
        "(profile custom with input.custom gives any other)"
    ]
    assert [s.text for s in sent(link, "STATUSTEXT")][-1] == "accel reads 3.33 g: check units, profile"
    assert service.waiting_text().endswith(
        "the field is measured from the compass while the vehicle is still (accelerometer: its median |f| over "
        "the first 5 s is 3.33 g, where a vehicle's is about 1 g: wrong units)"
    )


def test_the_vehicles_other_telemetry_is_skipped_and_what_the_service_reads_is_not():
    """A real autopilot streams a hundred other messages a second (the ArduSub dive: VFR_HUD, SYS_STATUS, AHRS2,
    …): counted ``skipped``, never decoded. What the service does read still comes: the IMU stream, the ACK to
    its request, the parameter it asked for, another IMU message (the vehicle's other compass)."""
    service, link = _service(**{"compass.others_rate_hz": 5.0})
    vehicle = Peer()
    link.deliver(vehicle.heartbeat())
    _step_until(service, lambda: service.counters.interval_requests >= 1)
    hud = vehicle.pack(mavlink2.MAVLink_vfr_hud_message(1.0, 2.0, 90, 50, 10.0, 0.5))
    status = vehicle.pack(mavlink2.MAVLink_sys_status_message(1, 1, 1, 500, 12000, 30, 80, 0, 0, 0, 0, 0, 0))
    trim = vehicle.pack(mavlink2.MAVLink_param_value_message(b"AHRS_TRIM_X", 0.02, 9, 900, 1))
    sample = units.ImuSample(100.0, (0.0, 0.0, -9.8), (0.0, 0.0, 0.0), (20.0, 0.0, 45.0))
    second = vehicle.pack(
        mavlink2.MAVLink_scaled_imu2_message(**units.encode(sample, units.PROFILES["ardupilot"], "SCALED_IMU2"))
    )
    link.deliver(_ack(vehicle), hud, trim, *vehicle.stream(400), status, second, hud)
    _step_until(service, lambda: not link.inbox)
    assert service.link.counters.skipped == 3
    assert service.counters.acks == {"ACCEPTED": 1} and service.counters.received == 400
    assert service.pipeline.frontend.settings.trim_rad[0] == pytest.approx(0.02)
    assert service.other_imu_messages == {"SCALED_IMU2"}
    assert "skipped=3" in service_module.counters_line(
        service.counters, service.link.counters, service.pipeline.counters
    )


def test_another_autopilot_on_the_link_is_said_once_with_the_setting_that_chooses(caplog):
    """Two vehicles on one radio: locked on in automatic mode to the first autopilot heard, the service says
    once (log and STATUSTEXT) that it hears another, and how to follow that one instead; a ground station's
    HEARTBEAT is no autopilot's."""
    caplog.set_level(logging.WARNING, logger="mavattitude.service")
    service, link = _service()
    first, second, station = Peer(), Peer(system=2), Peer(system=255)
    gcs = station.pack(mavlink2.MAVLink_heartbeat_message(6, mavlink2.MAV_AUTOPILOT_INVALID, 0, 0, 0, 3))
    link.deliver(first.heartbeat(), gcs, second.heartbeat(), *first.stream(20), second.heartbeat())

    def said() -> list[str]:
        return [r.getMessage() for r in caplog.records if "another autopilot" in r.getMessage()]

    _step_until(service, lambda: not link.inbox and said())  # (said by the periodic work)
    for _ in range(3):
        service.step(STEP_S)  # more periodic work: said once, not again
    assert service.vehicle == (1, 1) and service.counters.other_autopilots == {(2, 1)}
    assert said() == [
        "another autopilot on the link: system 2, component 1 (following system 1, component 1, the first heard): "
        "if this companion is on the other vehicle, set link.vehicle_system_id: 2"
    ]
    assert [s.text for s in sent(link, "STATUSTEXT") if "also heard" in s.text] == [
        "mavattitude: autopilot sys 2 also heard"
    ]


def test_waiting_for_the_configured_autopilot_names_the_ones_heard():
    """link.vehicle_system_id set to an id no autopilot on the link has: the wait names the ones heard."""
    service, link = _service(**{"link.vehicle_system_id": 3})
    link.deliver(Peer().heartbeat(), Peer(system=2).heartbeat())
    _step_until(service, lambda: not link.inbox)
    assert service.vehicle is None
    connect = service.config.link.connect
    assert (
        service.waiting_text()
        == f"waiting for a HEARTBEAT from system 3 on {connect}: heard only autopilot systems 1, 2"
    )


def test_an_autopilot_whose_heartbeat_stops_is_said_and_asked_again_when_it_is_back(monkeypatch, caplog):
    """An autopilot restarting (or a link down) stops its HEARTBEAT: said once, and the wait says it rather than
    blame the IMU stream, naming any other autopilot heard meanwhile; nothing is asked meanwhile, and what was asked
    unanswered is not said to time out; its HEARTBEAT back, its streams are asked for at once, as a restarted
    autopilot has forgotten them."""
    monkeypatch.setattr(service_module, "HEARTBEAT_LOST_S", 0.2)  # not 5 s of a test's time
    caplog.set_level(logging.INFO, logger="mavattitude.service")
    service, link = _service(**{"link.request_repeat_s": 0.5})
    vehicle = Peer()
    link.deliver(vehicle.heartbeat())
    _step_until(service, lambda: service.counters.autopilot_silent == 1)
    asked = len(sent(link, "COMMAND_LONG"))
    assert service.waiting is service_module.Waiting.AUTOPILOT_BACK
    assert service.waiting_text().startswith("waiting for the autopilot: no HEARTBEAT from system 1, component 1 for")
    silent_until = time.monotonic() + 2.5  # over two of request_repeat_s, and the ACK time-out of 2 s
    _step_until(service, lambda: time.monotonic() > silent_until)
    assert len(sent(link, "COMMAND_LONG")) == asked
    # the requests sent before it fell silent went unanswered: its silence, not a refusal (no warning)
    assert service.counters.requests_unheard == asked and service.counters.ack_timeouts == 0
    link.deliver(Peer(system=2).heartbeat())  # another vehicle, or this one back under a new system id
    _step_until(service, lambda: service.counters.other_autopilots)
    assert service.waiting_text().endswith("; autopilot system 2 heard: link.vehicle_system_id chooses")
    link.deliver(vehicle.heartbeat())
    _step_until(service, lambda: len(sent(link, "COMMAND_LONG")) > asked)
    assert [c.param1 for c in sent(link, "COMMAND_LONG")[asked:]] == [mavlink2.MAVLINK_MSG_ID_RAW_IMU]
    assert service.waiting is service_module.Waiting.IMU_STREAM
    said = [r.getMessage() for r in caplog.records if "HEARTBEAT" in r.getMessage()]
    assert len(said) == 2
    assert said[0].startswith("no HEARTBEAT from the autopilot (system 1, component 1) for 0 s: the link")
    assert said[1].startswith("the autopilot's HEARTBEAT again after ")


@pytest.mark.parametrize(("copies", "said"), [(2, True), (1, False)])
def test_an_input_arriving_twice_is_said_once(monkeypatch, caplog, copies, said):
    """Every RAW_IMU a second time (two routes to the autopilot: a router beside a direct link): the copies are
    dropped as duplicates and the attitude goes on; said once, log and STATUSTEXT, however long it lasts. Each
    once: nothing said."""
    monkeypatch.setattr(service_module, "RATE_WINDOW_S", 0.2)  # judged over 0.2 s windows, not 5 s
    caplog.set_level(logging.WARNING, logger="mavattitude.service")
    service, link = _service()
    vehicle = Peer()
    link.deliver(vehicle.heartbeat())
    for _ in range(4):  # four windows, each with 0.5 s of the vehicle's 200 Hz stream
        link.deliver(*[m for m in vehicle.stream(100) for _ in range(copies)])
        window_end = time.monotonic() + 0.25
        _step_until(service, lambda end=window_end: not link.inbox and time.monotonic() > end)
    warnings = [r.getMessage() for r in caplog.records if "arrives twice" in r.getMessage()]
    assert len(warnings) == int(said)
    for warning in warnings:  # (a window holds one delivery or two, as the windows fall: each half copies)
        assert warning.startswith("50 % of the last ") and "RAW_IMU repeated the time of the one before" in warning
    texts = [m.text for m in sent(link, "STATUSTEXT") if "twice" in m.text]
    assert texts == (["mavattitude: RAW_IMU arrives twice"] if said else [])
    assert service.counters.emitted >= 4 * 20  # 0.5 s at 50 Hz a window, less the filter's start


def test_an_autopilot_whose_input_flows_is_not_silent_for_want_of_heartbeats(monkeypatch):
    """Its HEARTBEAT filtered out on the way (a router's rule) while its IMU stream flows: it is heard, not said
    silent, and the streams are still asked for on their schedule."""
    monkeypatch.setattr(service_module, "HEARTBEAT_LOST_S", 0.2)
    service, link = _service(**{"link.request_repeat_s": 0.5})
    vehicle = Peer()
    link.deliver(vehicle.heartbeat())
    until = time.monotonic() + 1.2  # six of HEARTBEAT_LOST_S, two of request_repeat_s
    while time.monotonic() < until:
        link.deliver(*vehicle.stream(10))
        _step_until(service, lambda: not link.inbox)
        service.step(STEP_S)
    assert service.counters.autopilot_silent == 0 and service.counters.interval_requests >= 3


def test_another_program_under_our_id_is_said_and_gone_too_and_our_own_echo_is_not_it(monkeypatch, caplog):
    """A second program sending HEARTBEATs as system 1, component 191 (a second mavattitude, the systemd service
    beside a run by hand): said, log and STATUSTEXT, and said gone once unheard for ``SAME_ID_GONE_S``. Our own
    HEARTBEATs echoed back (a broadcast address, a routing loop) carry the sequence numbers we sent: not it."""
    monkeypatch.setattr(service_module, "SAME_ID_GONE_S", 0.3)  # not 10 s of a test's time
    caplog.set_level(logging.INFO, logger="mavattitude.service")
    service, link = _service()
    link.deliver(Peer().heartbeat())
    _step_until(service, lambda: sent(link, "HEARTBEAT"))
    parser = mavlink2.MAVLink(None)
    ours = [buf for buf in link.sent_bytes if parser.parse_buffer(buf)[0].get_type() == "HEARTBEAT"]
    link.deliver(*ours)
    _step_until(service, lambda: not link.inbox)
    other = Peer(system=1, component=191)
    other.mav.seq = (1 + max(m.get_seq() for m in sent(link, "HEARTBEAT"))) % 256  # none of ours
    beat = other.heartbeat(mavlink2.MAV_TYPE_ONBOARD_CONTROLLER, mavlink2.MAV_AUTOPILOT_INVALID)

    def said(words: str) -> list[str]:
        return [r.getMessage() for r in caplog.records if words in r.getMessage()]

    service.step(STEP_S)  # periodic work after the echoes: nothing to say
    assert link.counters.same_id == 0 and not said("another program")
    link.deliver(beat)
    _step_until(service, lambda: said("another program"))
    assert said("another program") == [
        "another program sends HEARTBEATs as system 1, component 191, our id (a second mavattitude, the systemd "
        "service beside a run by hand, another onboard program): a ground station cannot tell its messages from "
        "ours; stop it, or give one of them another link.component_id"
    ]
    assert [m.text for m in sent(link, "STATUSTEXT") if "191" in m.text] == [
        "mavattitude: comp 191 also used by another"
    ]
    _step_until(service, lambda: said("no other program heard"))
    link.deliver(beat)  # back: said again
    _step_until(service, lambda: len(said("another program")) == 2)
    assert link.counters.same_id == 2
