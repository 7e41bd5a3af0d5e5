"""The dispatcher and the service over the in-memory link: lock-on, routing and rejects without sockets.

The service is stepped by hand (``AttitudeService.step``): what it received is handled before ``step``
returns, so the tests need neither threads nor waits. Input is noise-free RAW_IMU encoded by the
project's own unit conversion, packed by pymavlink as the autopilot would send it.
"""

from __future__ import annotations

import logging

import numpy as np
import pytest
from pymavlink.dialects.v20 import ardupilotmega as mavlink2

from mavattitude.dispatch import Dispatcher
from mavattitude.estimation.conventions import angle_between, quat_from_euler, rotate_ned_to_body
from mavattitude.link.memory import MemoryLink
from mavattitude.link.source import Heartbeat, MavlinkDecoder, MavlinkSource, PositionFix
from mavattitude.pipeline import AttitudePipeline
from mavattitude.sensors import units
from mavattitude.service import AttitudeService
from mavattitude.systemd_notify import SystemdNotifier
from tests.test_service import ANGLE_TOLERANCE_RAD, G_NED_MPS2, GYRO_RADPS, Q_TRUE, mag_ned_uT, make_config

SAMPLE_PERIOD_S = 0.005  # 200 Hz on the vehicle clock


class Peer:
    """One MAVLink system packing messages for the in-memory link."""

    def __init__(self, system: int = 1, component: int = 1) -> None:
        self.mav = mavlink2.MAVLink(None, srcSystem=system, srcComponent=component)
        self.time_s = 100.0

    def pack(self, msg: object) -> bytes:
        return bytes(msg.pack(self.mav))  # type: ignore[attr-defined]

    def heartbeat(
        self, mav_type: int = mavlink2.MAV_TYPE_QUADROTOR, autopilot: int = mavlink2.MAV_AUTOPILOT_ARDUPILOTMEGA
    ) -> bytes:
        return self.pack(mavlink2.MAVLink_heartbeat_message(mav_type, autopilot, 0, 0, mavlink2.MAV_STATE_ACTIVE, 3))

    def raw_imu(self, mag_uT: object = None, acc_mps2: object = None) -> bytes:
        acc = rotate_ned_to_body(Q_TRUE, G_NED_MPS2) if acc_mps2 is None else acc_mps2
        mag = rotate_ned_to_body(Q_TRUE, mag_ned_uT()) if mag_uT is None else mag_uT
        sample = units.ImuSample(self.time_s, tuple(acc), GYRO_RADPS, tuple(mag))
        self.time_s += SAMPLE_PERIOD_S
        return self.pack(
            mavlink2.MAVLink_raw_imu_message(**units.encode(sample, units.PROFILES["ardupilot"], "RAW_IMU"))
        )

    def stream(self, count: int, **kwargs: object) -> list[bytes]:
        return [self.raw_imu(**kwargs) for _ in range(count)]


@pytest.fixture
def memory_service() -> tuple[AttitudeService, MemoryLink]:
    config = make_config()
    link = MemoryLink()
    service = AttitudeService(config, link, AttitudePipeline(config), SystemdNotifier(environ={}))
    return service, link


def serve(service: AttitudeService, link: MemoryLink) -> None:
    """Step the service until it has handled everything delivered (one recv takes at most 64 messages)."""
    while True:
        service.step(0.0)
        if not link.inbox:
            return


def sent(link: MemoryLink, kind: str) -> list:
    return [m for m in link.sent() if m.get_type() == kind]


def test_locks_on_and_emits_the_attitude_at_the_vehicle_time(memory_service):
    service, link = memory_service
    vehicle = Peer()
    link.deliver(vehicle.heartbeat(), *vehicle.stream(200))  # 1 s at 200 Hz
    serve(service, link)
    assert service.vehicle == (1, 1)
    outputs = sent(link, "ATTITUDE_QUATERNION")
    assert len(outputs) >= 45  # 1 s at 50 Hz less the low-pass's first ticks
    for aq in outputs:
        assert (aq.get_srcSystem(), aq.get_srcComponent()) == (1, 191)
        assert angle_between(np.array([aq.q1, aq.q2, aq.q3, aq.q4]), Q_TRUE) < ANGLE_TOLERANCE_RAD
        assert 100_000 <= aq.time_boot_ms <= 101_000
    assert set(np.diff([aq.time_boot_ms for aq in outputs])) == {20}
    assert service.counters.received == 200 and service.counters.emitted == len(outputs)


def test_other_senders_and_everything_before_the_lock_are_ignored(memory_service):
    service, link = memory_service
    vehicle, stranger, camera = Peer(), Peer(system=2), Peer(system=1, component=100)
    gimbal = Peer(system=3)
    link.deliver(*vehicle.stream(5), gimbal.heartbeat(mavlink2.MAV_TYPE_GIMBAL), vehicle.heartbeat())
    link.deliver(stranger.heartbeat(), *stranger.stream(10), *camera.stream(10), *vehicle.stream(3))
    serve(service, link)
    assert service.vehicle == (1, 1)  # not the gimbal's, which came first
    assert service.counters.ignored == 5 + 1 + 1 + 10 + 10
    assert service.counters.received == 3


def test_undecodable_input_is_a_counted_decode_reject(memory_service, caplog):
    service, link = memory_service
    caplog.set_level(logging.WARNING, logger="mavattitude.service")
    vehicle = Peer()
    link.deliver(vehicle.heartbeat(), *vehicle.stream(5, mag_uT=(3000.0, 0.0, 0.0)))
    serve(service, link)
    assert service.counters.rejected["decode"] == 5 and service.counters.received == 5
    assert service.counters.emitted == 0
    assert sum("rejected (decode)" in r.getMessage() for r in caplog.records) == 1  # rate-limited


def test_a_bug_in_the_pipeline_is_counted_logged_once_and_served_around(memory_service, caplog):
    service, link = memory_service
    caplog.set_level(logging.ERROR, logger="mavattitude.service")
    estimator = service.pipeline.estimator
    working = estimator.estimate

    def broken(*args: object, **kwargs: object) -> list:
        raise ZeroDivisionError("injected")

    estimator.estimate = broken  # fault injection into the real pipeline
    vehicle = Peer()
    link.deliver(vehicle.heartbeat(), *vehicle.stream(100))
    serve(service, link)
    assert service.counters.rejected["internal_error"] >= 20  # 0.5 s of input: ~25 ticks
    estimator.estimate = working
    link.deliver(*vehicle.stream(100))
    serve(service, link)
    assert service.counters.emitted > 0
    tracebacks = [r for r in caplog.records if r.exc_info and r.exc_info[0] is ZeroDivisionError]
    assert len(tracebacks) == 1  # rate-limited: statustext_interval_s is 60 s here


class _Recorder:
    def __init__(self) -> None:
        self.locks: list = []
        self.outputs: list = []
        self.attitudes: list = []
        self.messages: list = []

    def on_lock(self, vehicle):
        self.locks.append(vehicle)

    def on_input(self, sample, t_rx):
        pass

    def on_outputs(self, pushed, t_rx):
        self.outputs += pushed.outputs

    def on_autopilot_attitude(self, attitude, t_rx):
        self.attitudes.append(attitude)

    def on_message(self, msg, t_rx):
        self.messages.append(msg.get_type())

    def on_reject(self, reason, exc):
        raise AssertionError(f"unexpected reject {reason}: {exc}")


def test_the_dispatcher_routes_attitude_position_and_other_messages():
    config = make_config(**{"reference.magnetic": "auto"})
    pipeline = AttitudePipeline(config)
    recorder = _Recorder()
    dispatcher = Dispatcher(pipeline, recorder, wants_position=True)
    link = MemoryLink()
    source = MavlinkSource(link, MavlinkDecoder.from_config(config))
    vehicle = Peer()
    link.deliver(
        vehicle.heartbeat(),
        vehicle.pack(mavlink2.MAVLink_attitude_message(1500, 0.1, -0.2, 0.3, 0, 0, 0)),
        vehicle.pack(mavlink2.MAVLink_global_position_int_message(0, 473_769_000, 85_417_000, 500_000, 0, 0, 0, 0, 0)),
        vehicle.pack(mavlink2.MAVLink_command_ack_message(511, 0, 0, 0, 1, 191)),
    )
    received = source.recv(0.0)
    assert [type(item) for _, _, item in received[:1]] == [Heartbeat]
    assert isinstance(received[2][2], PositionFix) and received[2][2].date is None  # live: today's field
    for item in received:
        dispatcher.handle(item)
    assert recorder.locks == [(1, 1)] and recorder.messages == ["COMMAND_ACK"]
    (attitude,) = recorder.attitudes
    assert attitude.time_s == 1.5
    assert angle_between(np.array(attitude.q), quat_from_euler(0.1, -0.2, 0.3)) < 1e-6  # float32 fields
    assert dispatcher.counters.positions == 1 and not pipeline.waiting_for_reference


def test_a_log_that_names_its_vehicle_is_locked_onto_from_the_start():
    config = make_config()
    recorder = _Recorder()
    dispatcher = Dispatcher(AttitudePipeline(config), recorder, vehicle=(1, 1))
    assert dispatcher.vehicle == (1, 1) and recorder.locks == [(1, 1)]


def test_degenerate_geometry_is_rejected_and_said_once(memory_service):
    service, link = memory_service
    vehicle = Peer()
    along_gravity = rotate_ned_to_body(Q_TRUE, [0.0, 0.0, 1.0])
    link.deliver(vehicle.heartbeat(), *vehicle.stream(200, mag_uT=-40.0 * along_gravity))  # mag ∥ acc: no heading
    serve(service, link)
    assert service.pipeline.counters.rejected["DegenerateGeometryError"] > 0
    assert service.counters.emitted == 0
    warnings = [m for m in sent(link, "STATUSTEXT") if "collinear" in m.text]
    assert len(warnings) == 1 and warnings[0].severity == mavlink2.MAV_SEVERITY_WARNING


def test_the_configured_system_id_is_followed_and_nothing_requested():
    config = make_config(**{"link.vehicle_system_id": 5, "link.request_messages": False})
    link = MemoryLink(source_system=5)
    service = AttitudeService(config, link, AttitudePipeline(config), SystemdNotifier(environ={}))
    other, wanted = Peer(system=1), Peer(system=5)
    link.deliver(other.heartbeat(), *other.stream(10), wanted.heartbeat(), *wanted.stream(100))
    serve(service, link)
    assert service.vehicle == (5, 1)
    assert service.counters.ignored == 11 and service.counters.received == 100
    assert sent(link, "ATTITUDE_QUATERNION") and all(m.get_srcSystem() == 5 for m in link.sent())
    assert service.counters.interval_requests == 0 and not sent(link, "COMMAND_LONG")


def test_the_fused_service_asks_for_the_gps_velocity_and_removes_its_acceleration():
    """With ``method: fused`` the service asks for GPS_RAW_INT at 5 Hz, and the receiver's velocity reaches the
    filter whether or not the position is wanted (``reference.magnetic`` is fixed here): still, at 0 m/s."""
    config = make_config(**{"estimator.method": "fused"})
    link = MemoryLink()
    service = AttitudeService(config, link, AttitudePipeline(config), SystemdNotifier(environ={}))
    vehicle = Peer()
    link.deliver(vehicle.heartbeat())
    for _ in range(6):  # 1.2 s at 200 Hz, a fix every 0.2 s, sent 0.1 s after it (ArduPilot: µs since boot)
        link.deliver(*vehicle.stream(40))
        time_usec = round((vehicle.time_s - 0.1) * 1e6)
        link.deliver(vehicle.pack(mavlink2.MAVLink_gps_raw_int_message(time_usec, 3, 0, 0, 0, 80, 90, 0, 0, 10)))
    serve(service, link)
    asked = {(c.param1, c.param2) for c in sent(link, "COMMAND_LONG")}
    assert (mavlink2.MAVLINK_MSG_ID_GPS_RAW_INT, 1e6 / 5.0) in asked
    counters = service.pipeline.estimator.counters()
    # the first fix has nothing to difference: from the second (0.4 s in) to the end (1.2 s) 0.8 s of 50 Hz updates
    assert counters["gps_updates"] == 40 and counters["gps_refused"] == 0
