"""End-to-end harness: the daemon as a real subprocess, the fake vehicle in the test, real UDP on 127.0.0.1.

The vehicle binds an ephemeral port (``udpin:127.0.0.1:0``); the service is started with
``udpout:127.0.0.1:PORT`` to it, so nothing races for a port. Every wait is on an event (an output, a
counters line, a STATUSTEXT) with a bounded time-out; the only sleeps are the vehicle's own pacing.
"""

from __future__ import annotations

import select
import socket
import subprocess
import sys
import threading
from collections.abc import Callable, Iterator, Mapping, Sequence
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from mavattitude.config import merge
from mavattitude.sim.daemon import START_TIMEOUT_S, ServiceProcess, config_for
from mavattitude.sim.scoring import UNIT_NORM_TOLERANCE
from mavattitude.sim.sensors import SensorModel
from mavattitude.sim.trajectory import Script
from mavattitude.sim.vehicle import FakeVehicle, VehicleConfig

EVENT_TIMEOUT_S = 10.0
# Fast counters and re-requests keep the waits short; short input time-out keeps the silence case short.
FAST_SERVICE: dict[str, Any] = {
    "output": {"stats_interval_s": 0.2, "statustext_interval_s": 0.0},
    "link": {"request_repeat_s": 1.0},
}

Flight = tuple[FakeVehicle, ServiceProcess]


def merged(*layers: Mapping[str, Any]) -> dict[str, Any]:
    out: dict[str, Any] = {}
    for layer in layers:
        out = merge(out, layer)
    return out


@contextmanager
def flight(
    script: Script,
    sensors: SensorModel,
    service: Mapping[str, Any] | None = None,
    **vehicle: Any,
) -> Iterator[Flight]:
    """The vehicle flying ``script`` and the service connected to it, both stopped on exit."""
    vehicle.setdefault("fly_when_asked", True)  # the script starts when the service asks for the IMU
    with FakeVehicle(script, sensors, VehicleConfig("udpin:127.0.0.1:0", **vehicle)) as v:
        config = config_for(v, **merged(FAST_SERVICE, service or {}))
        with ServiceProcess(config) as svc:
            if not v.wait_for_outputs(1, START_TIMEOUT_S):
                pytest.fail("the service sent no ATTITUDE_QUATERNION; its log:\n" + svc.log_tail())
            yield v, svc


@pytest.fixture
def fly() -> Callable[..., Any]:
    return flight


def counter(svc: ServiceProcess, key: str) -> float:
    """The latest value of a counter (0 when the counters line does not mention it yet)."""
    return svc.latest_counters().get(key, 0.0)


def wait_counter(svc: ServiceProcess, key: str, at_least: float, timeout_s: float = EVENT_TIMEOUT_S) -> float:
    """Wait for a counters line with ``key ≥ at_least``; fail with the log tail if none comes."""
    ok = svc.wait_until(lambda: bool(svc.counters) and svc.counters[-1].get(key, 0.0) >= at_least, timeout_s)
    if not ok:
        pytest.fail(f"counter {key} never reached {at_least} (now {counter(svc, key)}); log:\n{svc.log_tail()}")
    return counter(svc, key)


def wait_outputs(v: FakeVehicle, more: int, timeout_s: float = EVENT_TIMEOUT_S) -> None:
    target = len(v.attitude_log) + more
    assert v.wait_for_outputs(target, timeout_s), (
        f"fewer than {more} new outputs within {timeout_s} s; vehicle thread errors: {v.thread_errors}"
    )


def udp_drops(port: int) -> int:
    """Datagrams the kernel dropped for the UDP socket on local ``port`` because its receive buffer was full
    (its process starved of CPU on a loaded machine): the ``drops`` column of /proc/net/udp."""
    for line in Path("/proc/net/udp").read_text().splitlines()[1:]:
        fields = line.split()
        if int(fields[1].rsplit(":", 1)[1], 16) == port:
            return int(fields[-1])
    raise AssertionError(f"no UDP socket on port {port} in /proc/net/udp")


def drain(v: FakeVehicle, svc: ServiceProcess) -> tuple[int, int]:
    """Pause the vehicle's IMU and wait until the service has taken in everything it was sent.

    Returns (IMU messages sent, of them dropped by the kernel before the service read them): what the
    service's ``received`` must then equal ``sent − dropped`` exactly, whatever the machine's load.
    """
    v.pause_imu(True)
    sent, port = v.imu_sent, v.peers()[0][1]  # the first peer of the vehicle is the service

    def taken_in() -> bool:
        return bool(svc.counters) and svc.counters[-1].get("received", 0.0) + udp_drops(port) >= sent

    if not svc.wait_until(taken_in, EVENT_TIMEOUT_S):
        pytest.fail(f"the service never took in the {sent} IMU messages sent; log:\n{svc.log_tail()}")
    return sent, udp_drops(port)


def assert_all_outputs_valid(v: FakeVehicle) -> None:
    """The service's promise: every quaternion it sent was finite and unit."""
    _, _, q = v.outputs_since(0)
    assert len(q) > 0
    assert np.all(np.isfinite(q)), "a non-finite quaternion was sent"
    assert np.max(np.abs(np.linalg.norm(q, axis=1) - 1.0)) < UNIT_NORM_TOLERANCE


def assert_healthy(v: FakeVehicle, max_error_deg: float, outputs: int = 25, settle: int = 0) -> None:
    """``outputs`` more outputs arrive (after ``settle`` outputs) and all are within ``max_error_deg``."""
    if settle:
        wait_outputs(v, settle)
    index = len(v.attitude_log)
    wait_outputs(v, outputs)
    s = v.score(index)
    assert s.broken == 0
    assert s.angle_max_deg < max_error_deg, s


def free_udp_port() -> int:
    """An ephemeral UDP port for a process that must bind it itself (MAVProxy's master, the service)."""
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


ROUTER_POLL_S = 0.05  # how soon the router's thread sees the stop


@contextmanager
def udp_router(upstream_port: int) -> Iterator[int]:
    """A MAVLink router as mavlink-router's UDP server endpoint is one: a port (yielded) whose every client's datagram
    goes to the autopilot at ``upstream_port`` on 127.0.0.1 and to every other client, and the autopilot's to every
    client; none back to its sender. (MAVProxy routes no client's messages to another: it cannot stand in.)"""
    stop = threading.Event()
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as sock:
        sock.bind(("127.0.0.1", 0))
        upstream = ("127.0.0.1", upstream_port)

        def route() -> None:
            clients: list[tuple[str, int]] = []
            while not stop.is_set():
                if not select.select([sock], [], [], ROUTER_POLL_S)[0]:
                    continue
                data, sender = sock.recvfrom(65535)
                if sender != upstream and sender not in clients:
                    clients.append(sender)
                for peer in [upstream, *clients]:
                    if peer != sender:
                        sock.sendto(data, peer)

        thread = threading.Thread(target=route, name="router", daemon=True)
        thread.start()
        try:
            yield int(sock.getsockname()[1])
        finally:
            stop.set()
            thread.join(5.0)


# MAVProxy as a pure router: no heartbeats of its own, no stream-rate requests, no modules (param, wp,
# rally, fence... each fetch from the vehicle at start), no state on disk, no console.
MAVPROXY_QUIET = [
    "--daemon",
    "--non-interactive",
    "--no-state",
    "--streamrate=-1",
    "--heartbeat-rate=0",
    "--default-modules=",
    "--mav20",
    "--nowait",
]


@contextmanager
def mavproxy(master: str, outs: Sequence[str], workdir: Path) -> Iterator[subprocess.Popen[str]]:
    exe = Path(sys.executable).with_name("mavproxy.py")
    proc = subprocess.Popen(
        [str(exe), f"--master={master}", *(f"--out={out}" for out in outs), *MAVPROXY_QUIET],
        stdin=subprocess.DEVNULL,
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
        cwd=workdir,
    )
    try:
        yield proc
    finally:
        proc.terminate()
        try:
            proc.communicate(timeout=5.0)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.communicate()


@contextmanager
def routed_flight(
    script: Script,
    sensors: SensorModel,
    workdir: Path,
    service: Mapping[str, Any] | None = None,
    other_outs: Sequence[str] = (),
    **vehicle: Any,
) -> Iterator[Flight]:
    """Vehicle ⇄ MAVProxy ⇄ service, wired as the README's "Wiring through MAVProxy" says: MAVProxy sends
    to the service's port (``--out=udpout:…``), the service listens (``udpin:``). ``other_outs`` are more
    MAVProxy outputs (a ground station's)."""
    vehicle.setdefault("fly_when_asked", True)
    # The autopilot talks first, as on a serial port: the vehicle sends to MAVProxy's master port.
    master_port, service_port = free_udp_port(), free_udp_port()
    with FakeVehicle(script, sensors, VehicleConfig(f"udpout:127.0.0.1:{master_port}", **vehicle)) as v:
        config = config_for(v, **merged(FAST_SERVICE, service or {}))
        config["link"]["connect"] = f"udpin:127.0.0.1:{service_port}"
        with (
            ServiceProcess(config) as svc,
            mavproxy(f"udpin:127.0.0.1:{master_port}", [f"udpout:127.0.0.1:{service_port}", *other_outs], workdir),
        ):
            if not v.wait_for_outputs(1, START_TIMEOUT_S):
                pytest.fail("no ATTITUDE_QUATERNION through MAVProxy; service log:\n" + svc.log_tail())
            yield v, svc
