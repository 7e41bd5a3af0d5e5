"""One design, proven: a telemetry log replayed offline and the same log played into the running daemon over
loopback UDP, at its recorded pace, give the same attitude on every output the live run produced.

The daemon is a real subprocess (``mavattitude run``, udpout to the test's socket); the test plays each
packet of the .tlog at its recorded time. Both read the packets through the same source decoding,
dispatcher and pipeline, so the attitudes agree to the ATTITUDE_QUATERNION's float32 rounding.
"""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np
import pytest
from pymavlink import mavutil

from mavattitude.config import load_config
from mavattitude.estimation.conventions import angle_between
from mavattitude.link.source import MavlinkDecoder
from mavattitude.link.tlog import TlogSource
from mavattitude.replay import replay
from mavattitude.sensors.frontend import SampleFlag
from mavattitude.sim.daemon import START_TIMEOUT_S, ServiceProcess
from tests.commands.test_replay import DECL, INCL, write_tlog
from tests.link.peer import UdpPeer

pytestmark = pytest.mark.e2e

# float32 quaternion components (ATTITUDE_QUATERNION): ~6e-8 each, ~1.2e-7 rad of angle; 1e-6 rad bounds it
SAME_RAD = 1e-6


def tlog_packets(path: Path) -> list[tuple[float, bytes]]:
    """Every packet of a telemetry log with its recorded receive time (s)."""
    log = mavutil.mavlink_connection(str(path), robust_parsing=True)
    out = []
    while (msg := log.recv_msg()) is not None:
        if msg.get_type() != "BAD_DATA":
            out.append((msg._timestamp, bytes(msg.get_msgbuf())))
    log.close()
    return out


@pytest.mark.parametrize("method", ["ign", "fused"])
def test_replayed_and_live_attitudes_are_the_same(tmp_path, method):
    # a 10 Hz compass repeated in every RAW_IMU, as ArduPilot sends it: both hold the repeats the same way
    path = write_tlog(tmp_path / "flight.tlog", seconds=4.0, second_vehicle=True, mag_every=10)
    settings = {
        "reference": {"magnetic": {"declination_deg": DECL, "inclination_deg": INCL}},
        "estimator": {"method": method},
    }
    config = load_config(
        None, {"reference.magnetic": settings["reference"]["magnetic"], "estimator.method": method}, env={}
    )
    offline = replay(TlogSource(path, MavlinkDecoder.from_config(config)), config)
    expected = {round(o.time_s * 1e3): o.q for o in offline.outputs}
    assert len(expected) > 150
    held = sum(SampleFlag.MAG_HELD in o.flags for o in offline.outputs)
    assert held > 0.7 * len(offline.outputs)  # 4 ticks in 5 between the compass's readings: the repeats held

    peer = UdpPeer()
    service = {**settings, "link": {"connect": f"udpout:127.0.0.1:{peer.address[1]}", "request_messages": False}}
    with ServiceProcess(service, workdir=tmp_path) as svc:
        deadline = time.monotonic() + START_TIMEOUT_S
        while peer.target is None:  # the daemon's first heartbeat tells where it listens
            assert time.monotonic() < deadline, "no heartbeat from the daemon; its log:\n" + svc.log_tail()
            peer.sock.settimeout(0.5)
            try:
                _, peer.target = peer.sock.recvfrom(65535)
            except TimeoutError:
                continue
        packets = tlog_packets(path)
        start_wall, start_log = time.monotonic(), packets[0][0]
        for t_log, data in packets:  # at the recorded pace
            delay = (t_log - start_log) - (time.monotonic() - start_wall)
            if delay > 0:
                peer.poll(delay)  # waiting on the socket keeps what the daemon sent
            peer.send_raw(data)
        last_ms = max(expected)
        peer.find_or_wait("ATTITUDE_QUATERNION", timeout_s=10.0, condition=lambda m: m.time_boot_ms >= last_ms)
    live = [m for m in peer.received if m.get_type() == "ATTITUDE_QUATERNION"]
    assert len(live) > 0.9 * len(expected)  # a loaded machine may drop a few datagrams, not the run
    differences = [
        float(angle_between(np.array([m.q1, m.q2, m.q3, m.q4]), expected[m.time_boot_ms])) for m in live
    ]  # every live output has its offline twin (a KeyError otherwise)
    assert max(differences) < SAME_RAD
    peer.close()
