"""Faults and bad input against one running service: it never dies, never sends a NaN or a non-unit
quaternion, counts what it refused, and is back to a correct attitude right after each fault.

One daemon per estimator serves the whole module, IGN (the snapshot methods' path) and the gyro-aided
filter, which keeps time and state of its own (a fresh one per case would cost ~1.5 s each for nothing: every
case ends by checking the service is healthy again, so the next starts from a clean state). The link is PX4
HIGHRES_IMU, whose float fields can carry NaN and inf.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Iterator

import numpy as np
import pytest

from mavattitude.link.mavlink2 import force_mavlink2, mavlink2, mavutil
from mavattitude.sensors.units import ImuSample
from mavattitude.sim import scenarios
from mavattitude.sim.trajectory import Hold, Script
from mavattitude.sim.vehicle import FakeVehicle, VehicleConfig

from .conftest import (
    EVENT_TIMEOUT_S,
    Flight,
    assert_all_outputs_valid,
    assert_healthy,
    counter,
    flight,
    udp_drops,
    wait_counter,
    wait_outputs,
)

pytestmark = pytest.mark.e2e

MESSAGE = "HIGHRES_IMU"
RATE_HZ = 200.0
INPUT_TIMEOUT_S = 0.3
# Paper noise, static: the error is ≈ 0.3° RMS; 2° is far outside it and far inside any real failure.
HEALTHY_DEG = 2.0
UPTIME_BEFORE_REBOOT_S = 30.0
SETTLE_OUTPUTS = 250  # 5 s: the fused filter's start-up covariance shrunk and its gyro bias taken at rest


@pytest.fixture(scope="module", params=["ign", "fused"])
def method(request: pytest.FixtureRequest) -> str:
    return str(request.param)


@pytest.fixture(scope="module")
def link(method: str) -> Iterator[Flight]:
    service = {"input": {"input_timeout_s": INPUT_TIMEOUT_S}, "estimator": {"method": method}}
    with flight(
        scenarios.static(3600.0), scenarios.paper_sensors(RATE_HZ), service, profile="px4", message=MESSAGE
    ) as f:
        if method == "fused":  # the filter settled first: started, its P is wide, and a fault then bends it for long
            wait_outputs(f[0], SETTLE_OUTPUTS)
        yield f
        vehicle, svc = f
        assert svc.running, "the service died:\n" + svc.log_tail()
        assert svc.stop() == 0
        assert_all_outputs_valid(vehicle)


def _packet(v: FakeVehicle) -> bytes:
    """A valid HIGHRES_IMU packet of the vehicle's truth now (packed, not sent)."""
    t = v.script_time()
    truth = v.script.sample([t])
    sample = ImuSample(
        v.vehicle_time(t),
        tuple(truth.specific_force_mps2[0]),
        tuple(truth.gyr_radps[0]),
        tuple(truth.mag_uT[0]),
    )
    return bytes(v.encode(sample, MESSAGE).pack(v.conn.mav))


def _replace(**values: tuple[float, float, float] | None):  # type: ignore[no-untyped-def]
    """A fault that replaces the named fields of every row."""
    return lambda rows: [dataclasses.replace(r, **values) for r in rows]


def _replace_where(pick, **values):  # type: ignore[no-untyped-def]
    """A fault that replaces the named fields of the rows ``pick`` selects."""
    return lambda rows: [dataclasses.replace(r, **values) if pick(r) else r for r in rows]


def _inject(v: FakeVehicle, fault, duration_s: float) -> None:  # type: ignore[no-untyped-def]
    done = v.inject(fault, duration_s)
    assert done.wait(EVENT_TIMEOUT_S), "the fault window never closed"


def test_garbage_bytes(link: Flight) -> None:
    v, svc = link
    rng = np.random.default_rng(5)
    before = counter(svc, "bad_data")
    for _ in range(20):
        # Random bytes with MAVLink 2 magics sprinkled in, so the parser starts (and fails) frames.
        junk = bytearray(rng.integers(0, 256, 200, dtype=np.uint8).tobytes())
        junk[::25] = b"\xfd" * len(junk[::25])
        v.send_bytes(bytes(junk))
    wait_counter(svc, "bad_data", before + 1)
    assert_healthy(v, HEALTHY_DEG)


def test_truncated_frames_and_bad_crc(link: Flight) -> None:
    v, svc = link
    before = counter(svc, "bad_data")
    for _ in range(5):
        v.send_bytes(_packet(v)[:30])  # a datagram that ends mid-frame
    for _ in range(5):
        bad = bytearray(_packet(v))
        bad[-1] ^= 0xFF  # CRC high byte
        v.send_bytes(bytes(bad))
    # Each truncated datagram and each bad checksum is one bad frame.
    wait_counter(svc, "bad_data", before + 10)
    assert_healthy(v, HEALTHY_DEG)


@pytest.mark.parametrize("value", [np.nan, np.inf, -np.inf])
def test_non_finite_values_are_dropped(link: Flight, value: float) -> None:
    v, svc = link
    before = counter(svc, "rejected.nonfinite")
    index = len(v.attitude_log)
    _inject(v, _replace(acc_mps2=(value, 0.0, -9.8)), 0.1)
    # 0.1 s at 200 Hz: about 20 samples, each dropped before the filter.
    assert wait_counter(svc, "rejected.nonfinite", before + 15) <= before + 25
    assert_healthy(v, HEALTHY_DEG)
    # Dropping 0.1 s is bridged by interpolation (< input_timeout_s): no output was lost or bent.
    assert v.score(index).angle_max_deg < HEALTHY_DEG


def test_saturated_accelerometer_is_dropped(link: Flight) -> None:
    v, svc = link
    before = counter(svc, "rejected.saturated_acc")
    _inject(v, _replace(acc_mps2=(400.0, 0.0, -9.8)), 0.1)  # beyond the 16 g full scale
    wait_counter(svc, "rejected.saturated_acc", before + 15)
    assert_healthy(v, HEALTHY_DEG)


def test_isolated_zero_frames_do_not_bend_the_attitude(link: Flight) -> None:
    v, svc = link
    index = len(v.attitude_log)
    received = counter(svc, "received")
    # Every 10th sample of 0.5 s reads exactly zero on both sensors (a glitching bus). The fault sees the
    # samples in small chunks, so it picks them by sample time, not by position.
    zero = (0.0, 0.0, 0.0)
    tenth = _replace_where(lambda r: round(r.script_s * RATE_HZ) % 10 == 0, acc_mps2=zero, mag_uT=zero)
    _inject(v, tenth, 0.5)
    assert_healthy(v, HEALTHY_DEG)
    assert counter(svc, "received") > received
    # A zero frame dips the filtered vectors by ≤ 1/4 for a tick; their directions, hence the attitude,
    # do not move beyond the noise.
    s = v.score(index)
    assert s.broken == 0 and s.angle_max_deg < HEALTHY_DEG, s


# A dead sensor (reads exactly zero) is refused, counted under the front end's reason for it.
@pytest.mark.parametrize(("sensor", "key"), [("acc_mps2", "rejected.dead_acc"), ("mag_uT", "mag_rejected.dead")])
def test_sustained_zero_vector_is_refused_not_turned_into_an_attitude(link: Flight, sensor: str, key: str) -> None:
    v, svc = link
    before = counter(svc, key)
    index = len(v.attitude_log)
    for _ in range(3):  # 3 × 0.4 s of a dead sensor, with good data between
        _inject(v, _replace(**{sensor: (0.0, 0.0, 0.0)}), 0.4)
        wait_outputs(v, 25, timeout_s=3.0)  # 0.5 s of outputs when alive; a dead service fails fast
    assert svc.running, "the service died:\n" + svc.log_tail()
    # 3 × 0.4 s × 200 Hz = 240 dead samples; a few at the window edges may fall either side.
    wait_counter(svc, key, before + 200)
    s = v.score(index)
    # Any output sent around the dead time must be right (10° leaves room for the low-pass transition at
    # each edge: the filtered vector shrinks towards zero before the sample is refused).
    assert s.broken == 0
    assert s.angle_max_deg < 10.0, s


def test_collinear_acc_and_mag_is_refused_and_reported(link: Flight, method: str) -> None:
    """IGN refuses the ticks and says so. The fused filter, settled, takes an accelerometer turned 64° with no
    rotation on the gyro for the acceleration it would be, and the gyro carries the attitude through."""
    v, svc = link
    before, texts, index = counter(svc, "rejected.DegenerateGeometryError"), len(v.statustexts), len(v.attitude_log)
    mag = np.asarray(scenarios.DEFAULT_MAG_NED_UT)  # level: body = NED
    along = tuple(-9.80665 * mag / np.linalg.norm(mag))
    _inject(v, _replace(acc_mps2=along), 0.4)
    if method == "fused":
        wait_outputs(v, 25)
        assert v.score(index).angle_max_deg < HEALTHY_DEG  # during the fault and after it
        return
    wait_counter(svc, "rejected.DegenerateGeometryError", before + 5)
    assert v.wait_until(lambda: any("collinear" in t for t in v.statustexts[texts:]), EVENT_TIMEOUT_S)
    # The low-pass blends the last collinear samples with good ones for ~0.1 s (its settling time at
    # 10 Hz): those few ticks are neither refused nor right. 10 outputs (0.2 s) later all is well.
    assert_healthy(v, HEALTHY_DEG, settle=10)


def test_repeated_timestamps_are_dropped_as_duplicates(link: Flight) -> None:
    v, svc = link
    before = counter(svc, "rejected.duplicate")
    _inject(v, lambda rows: [r for row in rows for r in (row, row)], 0.2)  # every sample twice
    wait_counter(svc, "rejected.duplicate", before + 30)
    assert_healthy(v, HEALTHY_DEG)


def test_time_going_back_a_little_is_dropped_as_out_of_order(link: Flight) -> None:
    v, svc = link
    before = counter(svc, "rejected.out_of_order")
    index = len(v.attitude_log)
    v.jump_clock(-0.2)  # within the clock's reorder window: 0.2 s of samples look stale
    wait_counter(svc, "rejected.out_of_order", before + 30)
    assert_healthy(v, HEALTHY_DEG)
    assert v.score(index).broken == 0


def test_time_jumping_forward_restarts_the_filter(link: Flight) -> None:
    v, svc = link
    before = counter(svc, "gap_resets")
    v.jump_clock(5.0)  # a 5 s hole in vehicle time: never bridged
    wait_counter(svc, "gap_resets", before + 1)
    assert_healthy(v, HEALTHY_DEG)


def test_vehicle_reboot(link: Flight) -> None:
    v, svc = link
    # A reboot is the clock going back by more than the service's reorder window (FrontEndSettings:
    # 1 s; less is reordered datagrams, dropped) once the stream resumes, which the service re-requests
    # within request_repeat_s (1 s). So first the vehicle has been up for far longer than both, whatever
    # ran before this case (alone, it would reboot under a second after its start): a jump forward.
    gaps = counter(svc, "gap_resets")
    v.jump_clock(UPTIME_BEFORE_REBOOT_S)
    wait_counter(svc, "gap_resets", gaps + 1)
    assert_healthy(v, HEALTHY_DEG)
    before = counter(svc, "reboots")
    requests = counter(svc, "interval_requests")
    v.reboot()  # boot time restarts at 0 and the IMU stream is off again, as on a real autopilot
    # The service's periodic re-request turns the stream back on; the clock going back is a reboot.
    wait_counter(svc, "interval_requests", requests + 1)
    wait_counter(svc, "reboots", before + 1)
    assert_healthy(v, HEALTHY_DEG)


def test_5khz_burst(link: Flight) -> None:
    v, svc = link
    port = v.peers()[0][1]  # the service's socket
    received, dropped = counter(svc, "received"), udp_drops(port)
    sent = v.imu_sent
    index = len(v.attitude_log)
    # 0.5 s at 5 kHz: every 200 Hz sample becomes 25, 0.2 ms apart. (Changing the stream rate instead
    # would last only until the service re-asserts its own, a random fraction of request_repeat_s.)
    step_s = 1.0 / 5000.0
    burst = lambda rows: [  # noqa: E731
        dataclasses.replace(r, vehicle_s=r.vehicle_s + k * step_s) for r in rows for k in range(25)
    ]
    _inject(v, burst, 0.5)
    burst_sent = v.imu_sent - sent
    assert burst_sent > 2000  # 2 500 expected
    assert_healthy(v, HEALTHY_DEG)

    # Every burst message reached the service or was dropped by the kernel (its receive buffer full:
    # counted there), whatever the load; the 200 Hz stream after the burst only adds to "received".
    def taken_in() -> bool:
        return counter(svc, "received") + udp_drops(port) - dropped >= received + burst_sent

    assert svc.wait_until(taken_in, EVENT_TIMEOUT_S), (burst_sent, counter(svc, "received"), svc.log_tail())
    s = v.score(index)
    # The output stays on its 50 Hz ticks of the vehicle clock whatever the input rate.
    assert s.output_rate_hz == pytest.approx(50.0, abs=0.5)
    assert s.broken == 0


def test_silence_stops_output_then_resumes_within_100ms(link: Flight) -> None:
    v, svc = link
    lost = counter(svc, "input_lost")
    texts = len(v.statustexts)
    v.pause_imu(True)
    try:
        paused_at = v.script_time()
        # The service says so (STATUSTEXT, cut to MAVLink's 50 characters, + counter) after input_timeout_s
        assert v.wait_until(lambda: any("mavattitude: no " in t for t in v.statustexts[texts:]), EVENT_TIMEOUT_S)
        wait_counter(svc, "input_lost", lost + 1)
        # ... and sends nothing describing the silent time.
        silent_index = len(v.attitude_log)
        _, t_out, _ = v.outputs_since(0)
        assert np.all(t_out <= paused_at + 0.02), "an output described the silent time"
        sent_before = v.imu_sent
    finally:
        v.pause_imu(False)
    assert v.wait_for_outputs(silent_index + 1, EVENT_TIMEOUT_S)
    # Judged on the vehicle's clock (what the first output describes against the first sample sent after
    # the silence), not on arrival times, which a loaded machine stretches: the restart takes a few samples
    # and one 20 ms output tick; 100 ms would mean samples lost or a filter waiting to settle.
    _, t_out, _ = v.outputs_since(silent_index)
    first_sample = v.sent_log()[0][sent_before]
    assert t_out[0] - first_sample < 0.100, f"resumed {1e3 * (t_out[0] - first_sample):.0f} ms after the first sample"
    assert_healthy(v, HEALTHY_DEG)


def test_second_vehicle_is_ignored(link: Flight) -> None:
    v, svc = link
    ignored = counter(svc, "ignored")
    service_address = v.peers()[0]
    upside_down = Script([Hold(3600.0)], scenarios.DEFAULT_MAG_NED_UT, q0=(0.0, 1.0, 0.0, 0.0))
    other = VehicleConfig(
        f"udpout:{service_address[0]}:{service_address[1]}",
        profile="px4",
        message=MESSAGE,
        system_id=2,
        stream_on_start=True,
    )
    index = len(v.attitude_log)
    with FakeVehicle(upside_down, scenarios.paper_sensors(RATE_HZ), other):
        wait_counter(svc, "ignored", ignored + 100)
        wait_outputs(v, 25)
    # Its heartbeats and upside-down IMU were ignored: our attitude never moved.
    s = v.score(index)
    assert s.broken == 0 and s.angle_max_deg < HEALTHY_DEG


def test_ground_station_changing_the_rate_is_overridden(link: Flight) -> None:
    v, svc = link
    gcs = mavutil.mavlink_connection(f"udpout:127.0.0.1:{v.port}", source_system=255, source_component=190)
    force_mavlink2(gcs)
    try:
        before = len(v.commands)
        msg_id = mavlink2.MAVLINK_MSG_ID_HIGHRES_IMU
        gcs.mav.command_long_send(1, 1, mavlink2.MAV_CMD_SET_MESSAGE_INTERVAL, 0, msg_id, 100_000, 0, 0, 0, 0, 0)
        ack = gcs.recv_match(type="COMMAND_ACK", blocking=True, timeout=EVENT_TIMEOUT_S)
        assert ack is not None and ack.result == mavlink2.MAV_RESULT_ACCEPTED  # the vehicle went to 10 Hz
        # (The 10 Hz state itself may last only an instant: the service's next re-assertion can follow at
        # once, so the test waits on the command log rather than polling the rate.)
        gcs_at = next(i for i, c in enumerate(v.commands) if i >= before and c.get_srcSystem() == 255)
        # The service asserts its rate again within request_repeat_s, after the ground station did.
        assert v.wait_until(
            lambda: any(c.get_srcComponent() == 191 for c in v.commands[gcs_at + 1 :]), EVENT_TIMEOUT_S
        ), svc.log_tail()
        assert v.stream_rate(MESSAGE) == pytest.approx(RATE_HZ)
        assert_healthy(v, HEALTHY_DEG)
    finally:
        gcs.close()
