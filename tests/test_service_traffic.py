"""Whatever the link carries, the service goes on.

Random MAVLink traffic (every message the service reads, with any value its fields can hold: NaN and infinite
floats, times past any date, positions off the globe, IMU readings at full scale, random interval ACKs) from the
vehicle and from other systems, some datagrams cut short, between stretches of the vehicle's steady RAW_IMU
stream whose clock now and then jumps, through the in-memory link. Nothing escapes a step, nothing is counted
as an internal error, every attitude sent is a unit quaternion, and once the traffic ends the steady stream's
attitudes go out again.
"""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from pymavlink.dialects.v20 import ardupilotmega as mavlink2

from mavattitude.link.memory import MemoryLink
from mavattitude.pipeline import AttitudePipeline
from mavattitude.sensors import units
from mavattitude.service import AttitudeService
from mavattitude.systemd_notify import SystemdNotifier
from tests.test_dispatch import Peer, sent
from tests.test_service import make_config


def _u(bits: int) -> st.SearchStrategy[int]:
    return st.integers(0, 2**bits - 1)


def _s(bits: int) -> st.SearchStrategy[int]:
    return st.integers(-(2 ** (bits - 1)), 2 ** (bits - 1) - 1)


_F = st.floats(width=32)  # any float32: NaN and ±inf included
_AUTOPILOT = st.sampled_from([mavlink2.MAV_AUTOPILOT_ARDUPILOTMEGA, mavlink2.MAV_AUTOPILOT_PX4, 0])
MESSAGES = st.one_of(
    st.builds(mavlink2.MAVLink_heartbeat_message, st.sampled_from([2, 6, 13]), _AUTOPILOT, _u(8), _u(32), _u(8), _u(8)),
    st.builds(mavlink2.MAVLink_raw_imu_message, _u(64), *[_s(16)] * 9, st.integers(0, 2), _s(16)),
    st.builds(mavlink2.MAVLink_scaled_imu2_message, _u(32), *[_s(16)] * 9, _s(16)),
    st.builds(mavlink2.MAVLink_attitude_message, _u(32), *[_F] * 6),
    st.builds(mavlink2.MAVLink_attitude_quaternion_message, _u(32), *[_F] * 7),
    st.builds(mavlink2.MAVLink_gps_raw_int_message, _u(64), st.integers(0, 8), *[_s(32)] * 3, *[_u(16)] * 4, _u(8)),
    st.builds(mavlink2.MAVLink_global_position_int_message, _u(32), *[_s(32)] * 4, *[_s(16)] * 3, _u(16)),
    st.builds(mavlink2.MAVLink_system_time_message, _u(64), _u(32)),
    st.builds(
        mavlink2.MAVLink_command_ack_message,
        st.sampled_from([mavlink2.MAV_CMD_SET_MESSAGE_INTERVAL, mavlink2.MAV_CMD_REQUEST_MESSAGE]),
        *[_u(8)] * 2,
        _s(32),
        *[_u(8)] * 2,
    ),
)
# who sends it: the vehicle, the vehicle cut short mid-frame, or another system
SENDERS = st.sampled_from(["vehicle", "cut", "other"])
# the vehicle's clock after it, when it jumps (a reboot, a time since 1970): up to 1.8e13 s, near a uint64 of µs
JUMPS = st.none() | st.floats(0.0, 1.8e13)
CONFIGS = [
    {},
    {"estimator.method": "fused", "crosscheck.enabled": True},
    {"reference.magnetic": "auto", "crosscheck.enabled": True},
    {"estimator.method": "fused", "reference.magnetic": "auto", "output.covariance": False},
]
STEADY = 200  # RAW_IMU samples (1 s) before each random message, and after the last


def _serve(service: AttitudeService, link: MemoryLink) -> None:
    while link.inbox:
        service.step(0.0)


@settings(max_examples=40, deadline=None)
@given(config=st.sampled_from(CONFIGS), traffic=st.lists(st.tuples(MESSAGES, SENDERS, JUMPS), max_size=12))
def test_any_traffic_leaves_the_service_running_and_its_attitudes_sound(config, traffic):
    cfg = make_config(**{"output.stats_interval_s": 60.0, "crosscheck.enabled": False, **config})
    link = MemoryLink()
    service = AttitudeService(cfg, link, AttitudePipeline(cfg), SystemdNotifier(environ={}))
    vehicle, other = Peer(), Peer(system=7)
    link.deliver(vehicle.heartbeat())
    for msg, sender, jump_s in traffic:
        link.deliver(*vehicle.stream(STEADY // 10))
        data = (other if sender == "other" else vehicle).pack(msg)
        link.deliver(data[: len(data) // 2] if sender == "cut" else data)
        vehicle.time_s = vehicle.time_s if jump_s is None else jump_s
    _serve(service, link)
    before = len(sent(link, "ATTITUDE_QUATERNION"))
    link.deliver(*vehicle.stream(STEADY))
    _serve(service, link)
    assert service.counters.rejected["internal_error"] == 0
    attitudes = sent(link, "ATTITUDE_QUATERNION")
    q = np.array([[m.q1, m.q2, m.q3, m.q4] for m in attitudes]).reshape(-1, 4)
    assert np.allclose(np.linalg.norm(q, axis=1), 1.0, atol=1e-6)  # float32 fields: ~1e-7 of rounding
    if cfg.reference.magnetic.mode != "auto":  # with auto it waits for a valid position, which may never come
        assert len(attitudes) > before


ODD_TIME_US = 123  # the time of the one RAW_IMU the IMU decoder's bug is met on


def _odd_messages(decoder: str) -> list[object]:
    """One message that meets the bug put in ``decoder``."""
    if decoder == "decode_utc_date":
        return [mavlink2.MAVLink_system_time_message(1_800_000_000_000_000, 0)]
    return [mavlink2.MAVLink_raw_imu_message(ODD_TIME_US, *[0] * 9, 0, 0)]


@pytest.mark.parametrize("decoder", ["decode_utc_date", "decode_fields"])
def test_a_decoding_bug_on_one_message_is_reported_and_the_service_goes_on(decoder, monkeypatch, caplog):
    """A bug met on one odd message (the date decoder, or the IMU decoder the link calls on the frame's fields,
    raising as a library's might): that message is dropped and counted an internal error with its traceback in
    the log, from the vehicle or from another system, and the attitudes go on; before, it ended the daemon."""
    real = getattr(units, decoder)

    def bug(*args: object) -> object:
        if decoder == "decode_utc_date" or args[1] == ODD_TIME_US:
            raise RuntimeError("a decoder's bug")
        return real(*args)

    monkeypatch.setattr(units, decoder, bug)
    cfg = make_config(**{"output.stats_interval_s": 60.0, "crosscheck.enabled": False})
    link = MemoryLink()
    service = AttitudeService(cfg, link, AttitudePipeline(cfg), SystemdNotifier(environ={}))
    vehicle, other = Peer(), Peer(system=7)
    odd = [peer.pack(msg) for msg in _odd_messages(decoder) for peer in (vehicle, other)]
    link.deliver(vehicle.heartbeat(), *vehicle.stream(100), *odd)
    link.deliver(*vehicle.stream(100))
    _serve(service, link)
    assert service.counters.rejected["internal_error"] == 2 and service.counters.received == 200
    assert len(sent(link, "ATTITUDE_QUATERNION")) >= 45  # 1 s at 50 Hz, less the filter's start
    assert any(r.exc_info and "internal error" in r.getMessage() for r in caplog.records)
