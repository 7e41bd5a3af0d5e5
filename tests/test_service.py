"""The service loop against a scripted autopilot over real UDP on 127.0.0.1 (pymavlink on both sides).

The service runs in a thread with a stop event; the test plays the autopilot with :class:`UdpPeer`.
Input is noise-free RAW_IMU encoded by the project's own unit conversion, so the only attitude error
is the message's integer quantisation (1 mG, 1 mgauss).
"""

from __future__ import annotations

import contextlib
import functools
import hashlib
import logging
import math
import signal
import socket
import subprocess
import sys
import threading
import time
from collections.abc import Iterator

import numpy as np
import pytest
from pymavlink.dialects.v20 import ardupilotmega as mavlink2

from mavattitude import alive
from mavattitude.alive import AliveFile
from mavattitude.config import Config, load_config
from mavattitude.estimation.conventions import angle_between, quat_from_euler, rotate_ned_to_body
from mavattitude.link import LinkCounters
from mavattitude.pipeline import AttitudePipeline
from mavattitude.reports import ServiceCounters, counters_line
from mavattitude.sensors import units
from mavattitude.service import AttitudeService, Waiting, open_link
from mavattitude.systemd_notify import SystemdNotifier
from tests.link.peer import UdpPeer

WAIT_S = 3.0  # bound on every wait (loopback replies take milliseconds)
G_NED_MPS2 = np.array([0.0, 0.0, -9.80665])  # specific force at rest: −g along down
DECLINATION_DEG, INCLINATION_DEG, FIELD_UT = 3.0, 60.0, 50.0
Q_TRUE = quat_from_euler(math.radians(10.0), math.radians(-20.0), math.radians(135.0))
GYRO_RADPS = (0.01, -0.02, 0.03)
SAMPLE_PERIOD_S = 0.005  # 200 Hz on the vehicle clock
# RAW_IMU quantisation: 1 mG of ~1000 mG and 1 mgauss of ~500 mgauss -> ~2e-3 rad; 0.5° leaves margin
ANGLE_TOLERANCE_RAD = math.radians(0.5)


def mag_ned_uT() -> np.ndarray:
    dec, inc = math.radians(DECLINATION_DEG), math.radians(INCLINATION_DEG)
    return FIELD_UT * np.array([math.cos(inc) * math.cos(dec), math.cos(inc) * math.sin(dec), math.sin(inc)])


def make_config(**overrides: object) -> Config:
    base = {
        "link.connect": "udpin:127.0.0.1:0",
        "link.request_repeat_s": 0.5,
        "input.input_timeout_s": 0.3,
        "output.stats_interval_s": 0.2,
        "output.statustext_interval_s": 60.0,
        "reference.magnetic": {"declination_deg": DECLINATION_DEG, "inclination_deg": INCLINATION_DEG},
    }
    return load_config(None, {**base, **overrides}, env={})


class Autopilot(UdpPeer):
    """The test's vehicle: heartbeats, RAW_IMU at a static attitude, COMMAND_ACK."""

    profile = units.get_profile("ardupilot")

    def __init__(self, system: int = 1, component: int = 1) -> None:
        super().__init__(system=system, component=component)
        self.time_s = 100.0

    def raw_imu(self, acc_mps2=None, mag_uT=None) -> object:
        acc = rotate_ned_to_body(Q_TRUE, G_NED_MPS2) if acc_mps2 is None else acc_mps2
        mag = rotate_ned_to_body(Q_TRUE, mag_ned_uT()) if mag_uT is None else mag_uT
        sample = units.ImuSample(self.time_s, tuple(acc), GYRO_RADPS, tuple(mag))
        self.time_s += SAMPLE_PERIOD_S
        return mavlink2.MAVLink_raw_imu_message(**units.encode(sample, self.profile, "RAW_IMU"))

    def stream(self, count: int, **kwargs) -> None:
        for _ in range(count):
            self.send(self.raw_imu(**kwargs))


class Running:
    """The service on its own thread, stopped and joined at the end."""

    def __init__(self, config: Config, notifier: SystemdNotifier | None = None) -> None:
        self.config = config
        self.link = open_link(config)
        notifier = notifier if notifier is not None else SystemdNotifier(environ={})
        self.service = AttitudeService(config, self.link, AttitudePipeline(config), notifier)
        self.stop = threading.Event()
        self.result: ServiceCounters | None = None
        self.thread = threading.Thread(target=self._run, name="service", daemon=True)
        self.thread.start()

    def _run(self) -> None:
        self.result = self.service.run(self.stop)

    def finish(self) -> ServiceCounters:
        self.stop.set()
        self.thread.join(timeout=1.0)  # the promise: out within a second of the stop request
        assert not self.thread.is_alive(), "the service did not stop within 1 s"
        self.link.close()
        assert self.result is not None
        return self.result


@pytest.fixture
def served() -> Iterator[tuple[Running, Autopilot]]:
    running = Running(make_config())
    vehicle = Autopilot()
    vehicle.target = running.link.local_address
    yield running, vehicle
    if running.thread.is_alive():
        running.finish()
    vehicle.close()


def wait_until(vehicle: UdpPeer, predicate, timeout_s: float = WAIT_S) -> None:
    """Wait for the service's state to meet ``predicate``, blocking on the vehicle's socket meanwhile
    (the service's heartbeats and outputs wake it; what it receives is kept in ``vehicle.received``)."""
    deadline = time.monotonic() + timeout_s
    while not predicate():
        assert time.monotonic() < deadline, "condition not met in time"
        vehicle.poll(0.02)


def lock_on(vehicle: Autopilot) -> None:
    vehicle.send(vehicle.heartbeat())
    vehicle.wait_for("HEARTBEAT", condition=lambda m: m.get_srcComponent() == 191)


def first_output(vehicle: Autopilot, samples: int = 100) -> None:
    """Lock the service on, stream ``samples`` IMU messages and wait for its first attitude."""
    lock_on(vehicle)
    vehicle.stream(samples)
    vehicle.wait_for("ATTITUDE_QUATERNION")


def own_lines(caplog: pytest.LogCaptureFixture, running: Running) -> list[str]:
    """The log lines of this service's thread (another test's service, left running, logs into caplog too)."""
    return [r.getMessage() for r in caplog.records if r.thread == running.thread.ident]


def imu_requests(received: list) -> Iterator[bool]:
    """For each message received, whether it is a SET_MESSAGE_INTERVAL for RAW_IMU."""
    for m in received:
        yield m.get_type() == "COMMAND_LONG" and m.param1 == mavlink2.MAVLINK_MSG_ID_RAW_IMU


def test_locks_on_requests_the_input_and_reads_the_ack(served):
    running, vehicle = served
    vehicle.send(vehicle.heartbeat())
    hb = vehicle.wait_for("HEARTBEAT")
    assert (hb.get_srcSystem(), hb.get_srcComponent()) == (1, 191)
    assert hb.type == mavlink2.MAV_TYPE_ONBOARD_CONTROLLER and hb.autopilot == mavlink2.MAV_AUTOPILOT_INVALID
    # the requests leave in the tick that sends the heartbeat: they may have arrived in the same read
    cmd = vehicle.find_or_wait("COMMAND_LONG")
    assert cmd.command == mavlink2.MAV_CMD_SET_MESSAGE_INTERVAL
    assert (cmd.target_system, cmd.target_component) == (1, 1)
    assert (cmd.param1, cmd.param2, cmd.param3) == (mavlink2.MAVLINK_MSG_ID_RAW_IMU, 1e6 / 200.0, 0.0)
    vehicle.send(mavlink2.MAVLink_command_ack_message(cmd.command, mavlink2.MAV_RESULT_ACCEPTED))
    start = vehicle.find_or_wait("STATUSTEXT", condition=lambda m: "mavattitude" in m.text)
    assert start.severity == mavlink2.MAV_SEVERITY_INFO
    # re-asserted every request_repeat_s (0.5 s here)
    wait_until(vehicle, lambda: sum(imu_requests(vehicle.received)) >= 2, timeout_s=2.0)
    wait_until(vehicle, lambda: running.service.counters.acks.get("ACCEPTED") == 1)
    counters = running.finish()
    assert counters.interval_requests >= 2


def test_missing_acks_counted_and_said_once(served, caplog):
    running, vehicle = served
    caplog.set_level(logging.WARNING, logger="mavattitude.service")
    lock_on(vehicle)  # and never answer: each unanswered request times out after 2 s
    beat_s = time.monotonic()

    def alive_without_acks() -> bool:
        """An autopilot still there (its 1 Hz HEARTBEAT: a silent one's requests are not timeouts) that answers
        no request."""
        nonlocal beat_s
        if time.monotonic() >= beat_s:
            vehicle.send(vehicle.heartbeat())
            beat_s += 1.0
        return running.service.counters.ack_timeouts >= 2

    wait_until(vehicle, alive_without_acks, timeout_s=8.0)
    counters = running.finish()
    assert counters.interval_requests >= 2 and not counters.acks and counters.requests_unheard == 0
    assert sum("no COMMAND_ACK" in r.getMessage() for r in caplog.records) == 1


def test_emits_attitude_quaternion_for_the_vehicle_time(served):
    running, vehicle = served
    lock_on(vehicle)
    first_sample_s = vehicle.time_s
    vehicle.stream(200)  # 1 s of vehicle time at 200 Hz
    outputs = []
    deadline = time.monotonic() + WAIT_S
    while len(outputs) < 40 and time.monotonic() < deadline:
        outputs += [m for m in vehicle.poll(0.1) if m.get_type() == "ATTITUDE_QUATERNION"]
    # 1 s resampled at 50 Hz, less the filter's start-up: at least 40 outputs
    assert len(outputs) >= 40
    for aq in outputs:
        assert aq.get_srcSystem() == 1 and aq.get_srcComponent() == 191
        q = np.array([aq.q1, aq.q2, aq.q3, aq.q4])
        assert abs(np.linalg.norm(q) - 1.0) < 1e-6  # float32 rounding of a unit quaternion
        assert angle_between(q, Q_TRUE) < ANGLE_TOLERANCE_RAD
        assert [aq.rollspeed, aq.pitchspeed, aq.yawspeed] == pytest.approx(GYRO_RADPS, abs=2e-3)  # 1 mrad/s LSB
        assert list(aq.repr_offset_q) == [0.0, 0.0, 0.0, 0.0]
        assert first_sample_s * 1e3 <= aq.time_boot_ms <= vehicle.time_s * 1e3
    times = [aq.time_boot_ms for aq in outputs]
    assert times == sorted(times) and set(np.diff(times)) == {20}  # 50 Hz on the vehicle clock
    wait_until(vehicle, lambda: running.service.counters.received == 200)
    counters = running.finish()
    assert counters.received == 200 and counters.emitted >= 40
    # Measured and ordered; how small is tools/bench.py's to say (a loaded machine stretches it).
    assert 0.0 < counters.latency_p50_ms <= counters.latency_p99_ms < math.inf
    assert 1 <= counters.mean_iterations <= running.config.estimator.max_iterations


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="the kernel's arrival stamps are Linux's")
def test_output_wait_lets_the_completing_sample_wait_and_counts_its_latency_from_arrival():
    """With ``output.wait_ms`` the service sleeps that much past the earliest arrival of each tick's completing
    sample (one wake-up for the samples between) and counts latency from each datagram's arrival (the kernel's
    stamp): on a steady 200 Hz stream the completing sample waits most of the 15 ms; without the wait, or were
    latency counted from the wake-up, its median would be well under 5 ms."""
    running = Running(make_config(**{"output.wait_ms": 15.0, "output.stats_interval_s": 60.0}))
    vehicle = Autopilot()
    vehicle.target = running.link.local_address
    try:
        lock_on(vehicle)
        start = time.monotonic()
        for i in range(400):  # 2 s, paced on the clock as a vehicle sends: what the forecast learns from
            time.sleep(max(0.0, start + i * SAMPLE_PERIOD_S - time.monotonic()))
            vehicle.send(vehicle.raw_imu())
        wait_until(vehicle, lambda: running.service.counters.received == 400)
        counters = running.finish()
    finally:
        vehicle.close()
    assert counters.emitted >= 90  # 2 s at 50 Hz, less the filter's start-up: none held back
    assert counters.latency_p50_ms >= 5.0


def test_input_loss_is_reported_once_and_output_resumes(served):
    running, vehicle = served
    first_output(vehicle)
    lost = vehicle.wait_for("STATUSTEXT", condition=lambda m: "output stopped" in m.text)
    assert lost.severity == mavlink2.MAV_SEVERITY_WARNING
    # two more heartbeats (1 Hz) of silence: still said only once
    for _ in range(2):
        vehicle.wait_for("HEARTBEAT")
    assert running.service.counters.input_lost == 1
    vehicle.time_s += 5.0
    vehicle.stream(100)
    vehicle.wait_for("ATTITUDE_QUATERNION", condition=lambda m: m.time_boot_ms >= (vehicle.time_s - 0.5) * 1e3)
    counters = running.finish()
    assert counters.input_lost == 1
    assert sum(1 for m in vehicle.received if m.get_type() == "STATUSTEXT" and "output stopped" in m.text) == 1


SLOW_INTERVAL_S = 0.45  # a 2.2 Hz telemetry stream: each interval longer than the test config's input_timeout_s


def test_a_slow_streams_first_interval_is_no_loss(served):
    """Before its second sample the service knows no rhythm of the stream: a telemetry stream's first interval,
    longer than input_timeout_s, is not said to be its loss ("output stopped"), nor are those after (2.5 of its
    own intervals would be)."""
    running, vehicle = served
    lock_on(vehicle)
    for _ in range(4):
        vehicle.stream(1)
        vehicle.time_s += SLOW_INTERVAL_S - SAMPLE_PERIOD_S
        deadline = time.monotonic() + SLOW_INTERVAL_S  # the service's clock must see the silence pass
        while (left_s := deadline - time.monotonic()) > 0.0:
            vehicle.poll(left_s)
    counters = running.finish()
    assert counters.received == 4 and counters.input_lost == 0


def test_automatic_magnetic_reference_waits_for_the_vehicle_position(caplog):
    caplog.set_level(logging.INFO)
    config = make_config(**{"reference.magnetic": "auto"})
    running = Running(config)
    vehicle = Autopilot()
    vehicle.target = running.link.local_address
    assert running.service.waiting is Waiting.AUTOPILOT
    lock_on(vehicle)
    assert running.service.waiting is Waiting.IMU_STREAM
    # The input and the position among what it asks for (the date and the autopilot's attitude too; a set
    # equal to these two held only while those two requests had arrived and the next not yet).
    wanted = {mavlink2.MAVLINK_MSG_ID_RAW_IMU, mavlink2.MAVLINK_MSG_ID_GLOBAL_POSITION_INT}
    wait_until(vehicle, lambda: {m.param1 for m in vehicle.received if m.get_type() == "COMMAND_LONG"} >= wanted)
    vehicle.stream(100)
    wait_until(vehicle, lambda: running.service.pipeline.counters.waiting > 0)
    assert running.service.waiting is Waiting.POSITION  # a state, not a reject
    assert running.service.counters.emitted == 0 and not running.service.pipeline.counters.rejected
    assert running.service.waiting_text() == (
        "waiting for a GPS position (reference: auto): GLOBAL_POSITION_INT, or GPS_RAW_INT with a 3D fix; without "
        "one, after 5 s of the IMU stream, the field is measured from the compass while the vehicle is still"
    )
    # Zurich, 500 m: the WMM field there becomes the reference
    vehicle.send(mavlink2.MAVLink_global_position_int_message(0, 473_769_000, 85_417_000, 500_000, 0, 0, 0, 0, 0))
    wait_until(vehicle, lambda: running.service.counters.positions == 1)
    vehicle.stream(100)
    vehicle.wait_for("ATTITUDE_QUATERNION")
    wait_until(vehicle, lambda: running.service.waiting is Waiting.RUNNING)
    counters = running.finish()
    assert sum("magnetic reference" in r.getMessage() for r in caplog.records) == 1  # one line per change
    reference = running.service.pipeline.mag_ref_ned_uT
    # Central Europe: |B| ≈ 48 µT, inclination ≈ 63° (WMM); 5 µT and 3° are loose bounds on "the right place"
    assert abs(np.linalg.norm(reference) - 48.0) < 5.0
    assert abs(math.degrees(math.atan2(reference[2], math.hypot(reference[0], reference[1]))) - 63.5) < 3.0
    assert counters.emitted > 0
    vehicle.close()


def test_counters_line_logged_periodically_and_at_the_end(served, caplog):
    running, vehicle = served
    caplog.set_level(logging.INFO, logger="mavattitude.service")
    first_output(vehicle)
    wait_until(vehicle, lambda: any(m.startswith("counters: ") for m in own_lines(caplog, running)))
    wait_until(vehicle, lambda: running.service.counters.received == 100)
    running.finish()
    final = [m for m in own_lines(caplog, running) if m.startswith("counters (final): ")]
    assert len(final) == 1
    pairs = dict(item.split("=") for item in final[0].split(": ", 1)[1].split())
    assert int(pairs["received"]) == 100
    assert int(pairs["emitted"]) == running.result.emitted > 0
    assert float(pairs["latency_p99_ms"]) >= float(pairs["latency_p50_ms"]) > 0.0
    assert {"rejected.decode", "ignored", "mean_iterations", "bad_data", "signature_rejected"} <= pairs.keys()


def test_periodic_counters_lines_say_what_changed_the_whole_line_at_debug(served, caplog):
    running, vehicle = served
    caplog.set_level(logging.DEBUG, logger="mavattitude.service")
    first_output(vehicle)
    ours = functools.partial(own_lines, caplog, running)
    wait_until(vehicle, lambda: any(m.startswith("counters: received=100 ") for m in ours()))
    mark = len(ours())
    # Three more periods (0.2 s each) with no more input: the DEBUG line is whole, the INFO line holds only
    # what moved (our heartbeats' "sent", nothing at all in most periods), never "received=100" again.
    wait_until(vehicle, lambda: sum(m.startswith("counters (all): ") for m in ours()[mark:]) >= 3)
    later = ours()[mark:]
    whole = [m for m in later if m.startswith("counters (all): ")]
    short = [m for m in later if m.startswith("counters: ")]
    assert all("received=100 " in m and "rejected.decode=0" in m for m in whole)
    assert len(short) < len(whole) and not any("received=" in m or "ignored=" in m for m in short)
    running.finish()
    final = [m for m in ours() if m.startswith("counters (final): ")]
    assert len(final) == 1 and "received=100 " in final[0]  # the end says everything


def test_counters_line_is_numbers_only():
    pipeline_counters = AttitudePipeline(make_config()).counters
    pipeline_counters.rejected["DegenerateGeometryError"] = 4
    pipeline_counters.frontend.rejected["nan"] = 5
    service_counters = ServiceCounters(acks={"DENIED": 2})
    service_counters.rejected["decode"] = 1
    line = counters_line(service_counters, LinkCounters(bad_data=3), pipeline_counters)
    pairs = dict(item.split("=") for item in line.split())
    assert pairs["acks.denied"] == "2" and pairs["bad_data"] == "3" and pairs["rejected.decode"] == "1"
    assert pairs["rejected.DegenerateGeometryError"] == "4" and pairs["rejected.nan"] == "5"
    assert pairs["mean_iterations"] == "nan"  # nothing emitted yet
    assert all(math.isnan(float(v)) or float(v) >= 0 for v in pairs.values())


def test_counters_line_carries_the_fused_filters_counters_and_learnt_offset():
    pipeline = AttitudePipeline(make_config(**{"estimator.method": "fused"}))
    field = 50.0 * pipeline.mag_ref_ned_uT / np.linalg.norm(pipeline.mag_ref_ned_uT)  # angles only: a direction
    mag = rotate_ned_to_body((1.0, 0.0, 0.0, 0.0), field)
    for i in range(100):  # 2 s at rest, level, heading north: an update per sample after the first
        pipeline.push(units.ImuSample(0.02 * i, (0.0, 0.0, -9.80665), (0.0, 0.0, 0.0), tuple(mag)))
    line = counters_line(ServiceCounters(), LinkCounters(), pipeline.counters)
    pairs = dict(item.split("=") for item in line.split())
    assert int(pairs["fused.updates"]) >= 95 and int(pairs["fused.tilt_only_updates"]) == 0
    assert int(pairs["fused.rest_updates"]) > 0 and pairs["fused.mag_offset_learned"] == "0"
    assert float(pairs["fused.mag_offset_z_uT"]) == 0.0
    assert "fused.updates" not in counters_line(
        ServiceCounters(), LinkCounters(), AttitudePipeline(make_config()).counters
    )


@pytest.mark.parametrize(("stop_signal", "code"), [(signal.SIGTERM, 0), (signal.SIGINT, 130)])
def test_run_command_stops_on_a_signal_with_final_counters(stop_signal, code):
    # SIGTERM is how systemd and Docker stop it (a clean stop); SIGINT is Ctrl-C (interrupted: 130).
    vehicle = Autopilot()
    cmd = [sys.executable, "-m", "mavattitude", "run", "--connect", f"udpout:127.0.0.1:{vehicle.address[1]}"]
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        vehicle.wait_for("HEARTBEAT", timeout_s=15.0)  # start-up imports numpy and pymavlink: allow for it
        stopped_at = time.monotonic()
        proc.send_signal(stop_signal)
        _, err = proc.communicate(timeout=5.0)
        elapsed_s = time.monotonic() - stopped_at
    finally:
        if proc.poll() is None:
            proc.kill()
        vehicle.close()
    assert proc.returncode == code, err
    assert elapsed_s < 1.0
    assert "counters (final): received=0" in err


def test_world_readable_key_refused_with_one_line(tmp_path):
    key = tmp_path / "key"
    key.write_bytes(bytes(32))
    key.chmod(0o644)
    cmd = [sys.executable, "-m", "mavattitude", "run", "--connect", "udpin:127.0.0.1:0", "--signing-key", str(key)]
    proc = subprocess.run(cmd, capture_output=True, text=True, timeout=30)
    assert proc.returncode == 2
    assert "world-readable" in proc.stderr and "Traceback" not in proc.stderr


def test_signed_link_required_forger_ignored(tmp_path):
    key_file = tmp_path / "signing.key"
    key_file.write_text("vehicle passphrase\n")
    key_file.chmod(0o600)
    key = hashlib.sha256(b"vehicle passphrase").digest()  # MAVProxy's passphrase -> key
    running = Running(make_config(**{"link.signing.key_file": str(key_file), "link.signing.require_signing": True}))
    vehicle = Autopilot()
    vehicle.set_key(key)
    forger = Autopilot()  # same system and component, no key
    for peer in (vehicle, forger):
        peer.target = running.link.local_address
    lock_on(vehicle)
    forger.stream(20, acc_mps2=(9.8, 0.0, 0.0))
    vehicle.stream(100)
    vehicle.wait_for("ATTITUDE_QUATERNION")
    wait_until(vehicle, lambda: running.link.counters.signature_rejected == 20)
    wait_until(vehicle, lambda: running.service.counters.received == 100)
    counters = running.finish()
    assert running.link.counters.signature_rejected == 20
    assert counters.received == 100  # the forged samples never reached the pipeline
    assert vehicle.mav.signing.goodsig_count > 0 and vehicle.mav.signing.badsig_count == 0
    vehicle.close()
    forger.close()


def test_systemd_ready_at_start_status_says_what_it_waits_for_then_counters(tmp_path):
    path = str(tmp_path / "notify.sock")
    listener = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
    listener.bind(path)
    listener.settimeout(WAIT_S)
    notifier = SystemdNotifier(environ={"NOTIFY_SOCKET": path, "WATCHDOG_USEC": "200000"})
    running = Running(make_config(), notifier)
    vehicle = Autopilot()
    vehicle.target = running.link.local_address

    def next_notification() -> str:
        return listener.recv(4096).decode()

    def statuses_until(last: str) -> list[str]:
        seen: list[str] = []
        while not seen or not seen[-1].startswith(last):
            seen.append(next_notification())  # each wait bounded by the socket's time-out
        return [n for n in seen if n.startswith(("READY", "STATUS"))]

    # READY as soon as the loop runs, with no vehicle yet: systemd's start-up must not wait for the autopilot.
    connect = running.service.config.link.connect
    assert next_notification() == (
        f"READY=1\nSTATUS=waiting for a HEARTBEAT on {connect} (is the autopilot sending to this port?)"
    )
    assert next_notification() == "WATCHDOG=1"  # pinged from the loop before any vehicle
    lock_on(vehicle)
    assert statuses_until("STATUS=waiting for the IMU stream") == [
        "STATUS=waiting for the IMU stream: RAW_IMU from system 1, component 1, asked for at 200 Hz"
    ]
    vehicle.stream(100)
    vehicle.wait_for("ATTITUDE_QUATERNION")
    seen = statuses_until("STATUS=received=")
    assert seen[-2:] == ["STATUS=running", seen[-1]]  # the counters once attitudes flow
    assert not [n for n in seen if n.startswith("READY")]  # READY once only
    running.finish()
    rest = []
    listener.setblocking(False)
    with contextlib.suppress(BlockingIOError):
        while True:
            rest.append(next_notification())
    assert "STOPPING=1" in rest
    listener.close()
    notifier.close()
    vehicle.close()


def test_what_it_waits_for_is_said_after_a_few_seconds_then_ever_more_rarely(caplog):
    caplog.set_level(logging.INFO, logger="mavattitude.service")
    running = Running(make_config(**{"link.connect": "udpin:127.0.0.1:0"}))
    running.finish()  # the loop's own reports would interleave: drive the reporting with a clock of our own
    caplog.clear()
    service = running.service
    start = service._wait_reports.since
    for step in range(1, 1000):  # 100 s of 0.1 s ticks with no autopilot
        service._report_waiting(start + 0.1 * step)
    said = [r.getMessage() for r in caplog.records]
    assert (
        said[0] == "waiting for a HEARTBEAT on udpin:127.0.0.1:0 (is the autopilot sending to this port?) (3 s so far)"
    )
    assert [m.rsplit("(", 1)[1] for m in said] == [
        "3 s so far)",
        "6 s so far)",
        "12 s so far)",
        "24 s so far)",
        "48 s so far)",
        "96 s so far)",
    ]


def test_data_that_holds_no_mavlink_is_said_in_the_wait_for_the_autopilot(served):
    """Bytes on the port that are no MAVLink (another program's, or a serial line at another baud rate): the wait
    says data comes but no frame is in it, rather than ask whether anything is sent; a MAVLink frame heard (a
    ground station's heartbeat) is no longer that case."""
    running, vehicle = served
    vehicle.send_raw(bytes(range(256)) * 2)  # no start marker 0xFD or 0xFE followed by a frame that checks
    wait_until(vehicle, lambda: running.service.link.counters.bad_data > 0)
    assert running.service.waiting_text() == (
        "waiting for a HEARTBEAT on udpin:127.0.0.1:0: data, but no MAVLink frame in it (another program sending to "
        "this port)"
    )
    station = UdpPeer(system=255, component=190)
    station.target = vehicle.target
    station.send(station.heartbeat(mavlink2.MAV_AUTOPILOT_INVALID))
    wait_until(vehicle, lambda: running.service.link.counters.received > 0)
    station.close()
    assert running.service.waiting_text().endswith("(is the autopilot sending to this port?)")


def test_each_wait_is_said_in_words_with_what_to_check():
    running = Running(make_config(**{"link.vehicle_system_id": 7, "link.request_rate_hz": 100.0}))
    running.finish()
    service = running.service
    assert service.waiting_text() == (
        "waiting for a HEARTBEAT from system 7 on udpin:127.0.0.1:0 (is the autopilot sending to this port?)"
    )
    service.dispatcher.vehicle = (7, 1)
    assert service.waiting is Waiting.IMU_STREAM
    assert (
        service.waiting_text() == "waiting for the IMU stream: RAW_IMU from system 7, component 1, asked for at 100 Hz"
    )
    assert service.waiting_text(Waiting.FIRST_ATTITUDE) == "waiting for the first attitude (nothing refused)"


def test_started_before_the_autopilot_it_says_its_banner_then_what_it_waits_for():
    closed = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
    closed.bind(("127.0.0.1", 0))  # bound, not listening: connections are refused, the port stays ours
    connect = f"tcp:127.0.0.1:{closed.getsockname()[1]}"
    proc = subprocess.Popen(
        [sys.executable, "-m", "mavattitude", "run", "--connect", connect], stderr=subprocess.PIPE, text=True
    )
    lines: list[str] = []
    deadline = threading.Timer(20.0, proc.kill)  # the report comes ~3 s after start; this bounds the read
    deadline.start()
    try:
        assert proc.stderr is not None
        for line in proc.stderr:
            lines.append(line.rstrip())
            if "so far" in line:
                break
    finally:
        deadline.cancel()
        proc.send_signal(signal.SIGINT)
        try:
            proc.communicate(timeout=15.0)
        finally:
            if proc.poll() is None:  # never left running
                proc.kill()
                proc.wait()
            closed.close()
    assert "mavattitude" in lines[0] and f"link {connect}" in lines[0]  # the banner first
    assert f"waiting for the autopilot at {connect} (" in lines[1]
    assert lines[2].endswith(
        f"waiting for a HEARTBEAT on {connect} (is the autopilot listening on that port?) (3 s so far)"
    )
    assert not any("reopen" in line or "again" in line for line in lines)


def test_the_loop_refreshes_the_alive_file_once_a_period(tmp_path):
    running = Running(make_config())
    running.finish()  # drive the periodic work with a clock of our own
    service = running.service
    path = tmp_path / "alive"
    service.alive_file = AliveFile({alive.ENV: str(path)})
    start = time.monotonic() + 10.0
    try:
        service._periodic(start)
        assert path.exists()
        path.unlink()
        service._periodic(start + alive.PERIOD_S / 2)
        assert not path.exists()  # not yet due
        service._periodic(start + alive.PERIOD_S)
        assert path.exists()
    finally:
        service.alive_file.close()  # disarm the hang exit: it would end this test process


def test_alive_file_unset_writes_nothing_and_a_failed_touch_is_counted(tmp_path, caplog):
    assert AliveFile({}).touch() is False
    blocked = AliveFile({alive.ENV: str(tmp_path / "missing-dir" / "alive")})
    try:
        assert blocked.touch() is False and blocked.touch() is False
    finally:
        blocked.close()
    assert blocked.errors == 2
    assert "cannot refresh the alive file" in caplog.text


HANG_EXIT_S = 1.0  # ten times the touch interval below: a loaded machine's late wake-up does not trip it


def test_a_loop_that_stops_touching_the_alive_file_exits_with_every_threads_traceback(tmp_path):
    """The container's restart: a hung loop (here: one that sleeps, holding nothing) ends the process
    with exit code 1 after ``hang_exit_s``, its tracebacks in stderr; a touch in time re-arms it."""
    code = (
        "import sys, time\n"
        "from mavattitude.alive import AliveFile\n"
        f"alive = AliveFile({{'{alive.ENV}': sys.argv[1]}}, hang_exit_s={HANG_EXIT_S})\n"
        f"for _ in range(3):\n    alive.touch()\n    time.sleep({HANG_EXIT_S / 10})\n"
        "print('touched', flush=True)\n"
        "time.sleep(60)  # the hang\n"
    )
    result = subprocess.run(
        [sys.executable, "-c", code, str(tmp_path / "alive")], capture_output=True, text=True, timeout=30
    )
    assert result.returncode == 1
    assert result.stdout == "touched\n"  # it survived the touched period
    hang_line = code.splitlines().index("time.sleep(60)  # the hang") + 1
    assert "Timeout (0:00:01)!" in result.stderr, result.stderr
    assert f'File "<string>", line {hang_line} in <module>' in result.stderr, result.stderr  # where it hung
