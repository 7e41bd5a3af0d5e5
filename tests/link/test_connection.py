"""MavlinkLink over real sockets on 127.0.0.1: MAVLink 2 on the wire, the messages it sends, bad input,
TCP reconnection, and connection-string checking."""

from __future__ import annotations

import contextlib
import logging
import math
import os
import select
import socket
import struct
import subprocess
import sys
import time

import pytest
from pymavlink.dialects.v20 import ardupilotmega as mavlink2

from mavattitude.errors import LinkError
from mavattitude.link import MavlinkLink, parse_connect
from mavattitude.link.connection import SO_TIMESTAMPNS, Endpoint, arrival_on_monotonic
from tests.link.peer import UdpPeer

MAVLINK2_MAGIC = 0xFD
WAIT_S = 3.0  # bound on every wait for a loopback packet (normally well under a millisecond)


def recv_n(link: MavlinkLink, msg_type: str, count: int, timeout_s: float = WAIT_S) -> list[tuple[float, object]]:
    """The first ``count`` messages of a type the link receives, with their arrival stamps."""
    got: list[tuple[float, object]] = []
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline and len(got) < count:
        got += [(t_rx, msg) for t_rx, msg in link.recv(0.05) if msg.get_type() == msg_type]
    assert len(got) >= count, f"link received {len(got)} of {count} {msg_type} within {timeout_s} s"
    return got[:count]


def recv_until(link: MavlinkLink, msg_type: str) -> tuple[float, object]:
    return recv_n(link, msg_type, 1)[0]


@pytest.fixture
def udp_pair():
    link = MavlinkLink("udpin:127.0.0.1:0", source_system=7, source_component=191)
    peer = UdpPeer(system=7, component=1)
    peer.target = link.local_address
    yield link, peer
    link.close()
    peer.close()


def test_udpin_receives_and_answers_in_mavlink2(udp_pair):
    link, peer = udp_pair
    peer.send(peer.heartbeat())
    before = time.monotonic()
    t_rx, msg = recv_until(link, "HEARTBEAT")
    assert msg.get_srcSystem() == 7 and msg.get_srcComponent() == 1
    assert before - 1.0 < t_rx <= time.monotonic()  # a time.monotonic() arrival stamp

    before = time.monotonic()
    assert link.send_heartbeat()
    assert before <= link.last_send_s <= time.monotonic()  # the hand-over to the OS, for the latency figure
    hb = peer.wait_for("HEARTBEAT")
    assert peer.raw[-1][0] == MAVLINK2_MAGIC
    assert (hb.get_srcSystem(), hb.get_srcComponent()) == (7, 191)
    assert hb.type == mavlink2.MAV_TYPE_ONBOARD_CONTROLLER
    assert hb.autopilot == mavlink2.MAV_AUTOPILOT_INVALID


def test_attitude_quaternion_fields(udp_pair):
    link, peer = udp_pair
    peer.send(peer.heartbeat())
    recv_until(link, "HEARTBEAT")
    half = math.sqrt(0.5)
    link.send_attitude_quaternion(123_456, [half, 0.0, 0.0, half], [0.01, -0.02, 0.03])
    aq = peer.wait_for("ATTITUDE_QUATERNION")
    assert peer.raw[-1][0] == MAVLINK2_MAGIC
    assert aq.time_boot_ms == 123_456
    # float32 on the wire: 6e-8 relative rounding
    assert [aq.q1, aq.q2, aq.q3, aq.q4] == pytest.approx([half, 0.0, 0.0, half], abs=1e-7)
    assert [aq.rollspeed, aq.pitchspeed, aq.yawspeed] == pytest.approx([0.01, -0.02, 0.03], abs=1e-7)
    assert list(aq.repr_offset_q) == [0.0, 0.0, 0.0, 0.0]


@pytest.mark.parametrize("covariance", [None, [1e-4, 0.0, 0.0, 0.0, 1e-4, 0.0, 0.0, 0.0, 4e-4]])
def test_an_attitude_goes_out_in_one_datagram(udp_pair, covariance):
    """ATTITUDE_QUATERNION and its COV in one datagram: one send, where two cost the CPU twice."""
    link, peer = udp_pair
    peer.send(peer.heartbeat())
    recv_until(link, "HEARTBEAT")
    sent = link.counters.sent
    assert link.send_attitude(12.5, [1.0, 0.0, 0.0, 0.0], [0.0, 0.0, 0.1], covariance)
    aq = peer.wait_for("ATTITUDE_QUATERNION")
    datagram = peer.raw[-1]
    frames = mavlink2.MAVLink(None).parse_buffer(datagram)
    expected = ["ATTITUDE_QUATERNION"] + ([] if covariance is None else ["ATTITUDE_QUATERNION_COV"])
    assert [m.get_type() for m in frames] == expected and link.counters.sent == sent + len(expected)
    assert aq.time_boot_ms == 12_500
    if covariance is not None:
        assert frames[1].time_usec == 12_500_000
        assert list(frames[1].covariance) == pytest.approx(covariance, rel=1e-6)  # float32 on the wire


def test_set_message_interval_and_statustext(udp_pair):
    link, peer = udp_pair
    peer.send(peer.heartbeat())
    recv_until(link, "HEARTBEAT")
    link.request_message_interval((7, 1), mavlink2.MAVLINK_MSG_ID_RAW_IMU, 200.0)
    cmd = peer.wait_for("COMMAND_LONG")
    assert (cmd.target_system, cmd.target_component) == (7, 1)
    assert cmd.command == mavlink2.MAV_CMD_SET_MESSAGE_INTERVAL
    assert (cmd.param1, cmd.param2, cmd.param3) == (27.0, 5000.0, 0.0)
    link.send_statustext("mavattitude: " + "x" * 80, "warning")
    st = peer.wait_for("STATUSTEXT")
    assert st.severity == mavlink2.MAV_SEVERITY_WARNING
    assert st.text == ("mavattitude: " + "x" * 80)[:50]

    ack = mavlink2.MAVLink_command_ack_message(mavlink2.MAV_CMD_SET_MESSAGE_INTERVAL, mavlink2.MAV_RESULT_DENIED)
    peer.send(ack)
    _, got = recv_until(link, "COMMAND_ACK")
    assert link.interval_ack_result(got) == "DENIED"


def test_autopilot_heartbeat_recognised(udp_pair):
    link, peer = udp_pair
    peer.send(peer.heartbeat(autopilot=mavlink2.MAV_AUTOPILOT_INVALID))
    peer.send(peer.heartbeat())
    (_, first), (_, second) = recv_n(link, "HEARTBEAT", 2)
    assert not link.is_autopilot_heartbeat(first)
    assert link.is_autopilot_heartbeat(second)


def test_garbage_and_bad_crc_are_counted_and_do_not_block_good_frames(udp_pair):
    link, peer = udp_pair
    good = peer.pack(peer.heartbeat())
    bad_crc = bytearray(peer.pack(peer.heartbeat()))
    bad_crc[-1] ^= 0xFF
    peer.send_raw(b"\x00\x01garbage\x02")
    peer.send_raw(bytes(bad_crc))
    peer.send_raw(good[: len(good) // 2])  # truncated frame: its tail never comes
    peer.send_raw(good)
    received = []
    deadline = time.monotonic() + WAIT_S
    while time.monotonic() < deadline and not received:
        received = [m for _, m in link.recv(0.05) if m.get_type() == "HEARTBEAT"]
    assert received, "the good frame after the bad ones was not received"
    assert link.counters.bad_data == 3  # the garbage run, the bad CRC, the truncated frame


def test_udpout_sends_to_its_peer():
    peer = UdpPeer(system=3)
    with MavlinkLink(f"udpout:127.0.0.1:{peer.address[1]}", source_system=3) as link:
        assert link.local_address is None
        link.send_heartbeat()
        hb = peer.wait_for("HEARTBEAT")
        assert hb.get_srcSystem() == 3 and hb.get_srcComponent() == 191
    peer.close()


def _listener() -> socket.socket:
    server = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
    server.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
    server.bind(("127.0.0.1", 0))
    server.listen(1)
    server.settimeout(WAIT_S)
    return server


def test_tcp_client_reconnects_with_backoff_after_the_peer_drops():
    server = _listener()
    port = server.getsockname()[1]
    packer = UdpPeer(system=1)  # used only to pack frames
    link = MavlinkLink(f"tcp:127.0.0.1:{port}", source_system=1, reconnect_min_s=0.05)
    try:
        conn, _ = server.accept()
        conn.sendall(packer.pack(packer.heartbeat()))
        recv_until(link, "HEARTBEAT")
        conn.close()  # the router restarts
        deadline = time.monotonic() + WAIT_S
        while link.counters.disconnects == 0 and time.monotonic() < deadline:
            link.recv(0.05)
        assert link.counters.disconnects == 1 and not link.is_open
        # the link comes back by itself once its back-off has passed
        deadline = time.monotonic() + WAIT_S
        while not link.is_open and time.monotonic() < deadline:
            link.recv(0.05)
        conn, _ = server.accept()
        assert link.counters.reconnects == 1
        conn.sendall(packer.pack(packer.heartbeat()))
        recv_until(link, "HEARTBEAT")
        link.send_heartbeat()
        conn.settimeout(WAIT_S)
        assert conn.recv(1)[0] == MAVLINK2_MAGIC
        conn.close()
    finally:
        link.close()
        server.close()
        packer.close()


def test_tcp_client_waits_for_a_router_that_is_not_up_yet(caplog):
    probe = _listener()
    port = probe.getsockname()[1]
    probe.close()  # nothing listens on the port now
    caplog.set_level(logging.DEBUG, logger="mavattitude.link.connection")
    link = MavlinkLink(f"tcp:127.0.0.1:{port}", source_system=1, reconnect_min_s=0.05, reconnect_max_s=0.2)
    try:
        assert not link.is_open
        assert link.send_heartbeat() is False and link.counters.send_failed == 1
        delays: list[str] = []
        deadline = time.monotonic() + WAIT_S
        while len(delays) < 4 and time.monotonic() < deadline:
            link.recv(0.05)
            messages = [r.getMessage() for r in caplog.records]
            delays = [m.rsplit("next try in ", 1)[1] for m in messages if "next try in" in m]
        assert delays[:4] == ["0.1 s", "0.2 s", "0.2 s", "0.2 s"]  # doubling from 0.05 s, capped at 0.2 s
        server = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
        server.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        server.bind(("127.0.0.1", port))
        server.listen(1)
        deadline = time.monotonic() + WAIT_S
        while not link.is_open and time.monotonic() < deadline:
            link.recv(0.05)
        assert link.is_open
        server.close()
    finally:
        link.close()
    # A link never open is not "reopened": one line says what it waits for, the retries are DEBUG detail.
    said = [(r.levelname, r.getMessage()) for r in caplog.records if r.levelno > logging.DEBUG]
    assert said[0][1].startswith(f"waiting for the autopilot at tcp:127.0.0.1:{port} (")
    assert said[-1] == ("INFO", f"link tcp:127.0.0.1:{port} open")
    assert all(level == "INFO" for level, _ in said) and link.counters.reconnects == 0


def test_tcpin_serves_one_client_after_another():
    packer = UdpPeer(system=1)
    with MavlinkLink("tcpin:127.0.0.1:0", source_system=1) as link:
        for _ in range(2):
            client = socket.create_connection(link.local_address, timeout=WAIT_S)
            client.sendall(packer.pack(packer.heartbeat()))
            recv_until(link, "HEARTBEAT")
            client.close()
            link.recv(0.05)  # sees the EOF and listens again
    packer.close()


def test_tcpin_a_clients_unfinished_frame_does_not_swallow_the_next_clients_first():
    """A client that goes mid-frame: its unfinished frame is counted and forgotten, not completed by the bytes
    of the next client, whose first message comes through."""
    packer = UdpPeer(system=1)
    heartbeat = packer.pack(packer.heartbeat())
    with MavlinkLink("tcpin:127.0.0.1:0", source_system=1) as link:
        client = socket.create_connection(link.local_address, timeout=WAIT_S)
        client.sendall(heartbeat[:15])
        client.close()
        deadline = time.monotonic() + WAIT_S
        while link.counters.bad_data == 0 and time.monotonic() < deadline:
            link.recv(0.05)  # reads the 15 bytes, then sees the EOF
        assert link.counters.bad_data == 1
        client = socket.create_connection(link.local_address, timeout=WAIT_S)
        client.sendall(packer.pack(packer.heartbeat()))
        recv_until(link, "HEARTBEAT")
        assert link.counters.bad_data == 1
        client.close()
    packer.close()


@pytest.mark.parametrize(
    ("connect", "kind", "address", "baud"),
    [
        ("udpin:0.0.0.0:14550", "udpin", "0.0.0.0:14550", 115200),
        ("udp:127.0.0.1:0", "udpin", "127.0.0.1:0", 115200),
        ("udpout:10.0.0.2:14550", "udpout", "10.0.0.2:14550", 115200),
        ("tcp:localhost:5760", "tcp", "localhost:5760", 115200),
        ("tcpin:0.0.0.0:5760", "tcpin", "0.0.0.0:5760", 115200),
        ("/dev/ttyACM0", "serial", "/dev/ttyACM0", 115200),
        ("/dev/serial0,921600", "serial", "/dev/serial0", 921600),
    ],
)
def test_parse_connect_accepts_pymavlink_forms(connect, kind, address, baud):
    assert parse_connect(connect) == Endpoint(kind, address, baud)


@pytest.mark.parametrize(
    ("connect", "match"),
    [
        ("udpin:14550", "expected udpin:HOST:PORT"),
        ("udpout:127.0.0.1:0", "expected udpout:HOST:PORT"),
        ("tcp:host:99999", "out of range"),
        ("ws://vehicle", "expected udpin:HOST:PORT, udpout"),
        ("/dev/ttyS0,fast", "DEVICE,BAUD"),
    ],
)
def test_parse_connect_rejects_malformed_strings(connect, match):
    with pytest.raises(LinkError, match=match):
        parse_connect(connect)


def test_unbindable_address_and_missing_serial_device_are_link_errors():
    with pytest.raises(LinkError, match="cannot open"):
        MavlinkLink("udpin:192.0.2.1:14550", source_system=1)  # TEST-NET address: not ours to bind
    with pytest.raises(LinkError, match="cannot open"):
        MavlinkLink("/dev/nonexistent-mavattitude-tty", source_system=1)


def test_system_id_255_is_refused():
    with pytest.raises(LinkError, match="255 is for ground stations"):
        MavlinkLink("udpin:127.0.0.1:0", source_system=255)


def test_udpin_answers_only_senders_of_valid_messages(udp_pair):
    link, peer = udp_pair
    spoofer = UdpPeer(system=9)
    spoofer.target = peer.target
    spoofer.send_raw(b"\xfd\x09garbage that is no frame")
    peer.send(peer.heartbeat())
    recv_until(link, "HEARTBEAT")
    link.send_heartbeat()
    peer.wait_for("HEARTBEAT")
    assert link.counters.bad_data == 1
    assert spoofer.poll(0.2) == []  # bounded wait: the heartbeat reached the peer already
    spoofer.close()


def test_serial_device_through_a_pseudo_terminal():
    """A real tty (a pty pair) through pyserial: the link on the slave end, the test on the master."""
    master, slave = os.openpty()
    packer = UdpPeer(system=1)  # used only to pack and parse frames
    try:
        with MavlinkLink(f"{os.ttyname(slave)},57600", source_system=1) as link:
            assert link.endpoint.kind == "serial" and link.endpoint.baud == 57600
            os.write(master, packer.pack(packer.heartbeat()))
            recv_until(link, "HEARTBEAT")
            link.send_heartbeat()
            ready, _, _ = select.select([master], [], [], WAIT_S)
            assert ready
            frame = os.read(master, 280)
            assert frame[0] == MAVLINK2_MAGIC
            (hb,) = packer.mav.parse_buffer(frame)
            assert hb.get_type() == "HEARTBEAT" and hb.get_srcComponent() == 191
    finally:
        os.close(master)
        os.close(slave)
        packer.close()


def test_serial_adapter_unplugged_and_plugged_back_in(tmp_path):
    """A USB serial adapter pulled out (its tty hangs up: the pty's master closed) and plugged back in under the
    same stable name (udev's /dev/serial/by-id link, here a symlink to a new pty): counted, closed, reopened."""
    device = tmp_path / "usb-autopilot"
    packer = UdpPeer(system=1)  # used only to pack frames
    master, slave = os.openpty()
    device.symlink_to(os.ttyname(slave))
    link = MavlinkLink(f"{device},921600", source_system=1, reconnect_min_s=0.05)
    try:
        os.write(master, packer.pack(packer.heartbeat()))
        recv_until(link, "HEARTBEAT")
        os.close(master)  # unplugged
        os.close(slave)
        deadline = time.monotonic() + WAIT_S
        while link.counters.disconnects == 0 and time.monotonic() < deadline:
            link.recv(0.05)
        assert link.counters.disconnects == 1 and not link.is_open
        link.recv(0.2)  # retried (and refused: the device is gone) while it is out
        assert not link.is_open and link.counters.reconnects == 0
        master, slave = os.openpty()  # plugged back in
        device.unlink()
        device.symlink_to(os.ttyname(slave))
        deadline = time.monotonic() + WAIT_S
        while not link.is_open and time.monotonic() < deadline:
            link.recv(0.05)
        assert link.counters.reconnects == 1
        os.write(master, packer.pack(packer.heartbeat()))
        recv_until(link, "HEARTBEAT")
        link.send_heartbeat()
        ready, _, _ = select.select([master], [], [], WAIT_S)
        assert ready and os.read(master, 280)[0] == MAVLINK2_MAGIC
    finally:
        link.close()
        for fd in (master, slave):
            with contextlib.suppress(OSError):  # closed already when the test failed while unplugged
                os.close(fd)
        packer.close()


def test_mavlink2_even_when_pymavlink_was_imported_first_for_mavlink1():
    """Another importer got pymavlink's MAVLink 1 default; our link still sends and parses MAVLink 2
    (ADAP_TUNING has id 11010: MAVLink 2 only)."""
    script = """
import os, socket, time
os.environ.pop("MAVLINK20", None)
from pymavlink import mavutil
assert mavutil.mavlink.WIRE_PROTOCOL_VERSION == "1.0", mavutil.mavlink.WIRE_PROTOCOL_VERSION
from pymavlink.dialects.v20 import all as v2
from mavattitude.link import MavlinkLink
link = MavlinkLink("udpin:127.0.0.1:0", source_system=1)
peer = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
peer.settimeout(3.0)
packer = v2.MAVLink(None, srcSystem=1, srcComponent=1)
peer.sendto(v2.MAVLink_adap_tuning_message(1, *[0.0] * 12).pack(packer), link.local_address)
got = []
deadline = time.monotonic() + 3.0
while not got and time.monotonic() < deadline:
    got = link.recv(0.05)
link.send_heartbeat()
print(peer.recv(300)[0], got[0][1].get_type())
"""
    env = {k: v for k, v in os.environ.items() if k != "MAVLINK20"}
    out = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=30, env=env)
    assert out.returncode == 0, out.stderr
    assert out.stdout.split() == [str(MAVLINK2_MAGIC), "ADAP_TUNING"]


def _timespec(wall_s: float) -> list[tuple[int, int, bytes]]:
    """``recvmsg``'s ancillary data for a kernel arrival stamp at ``wall_s`` (Unix time)."""
    seconds = int(wall_s)
    return [(socket.SOL_SOCKET, SO_TIMESTAMPNS, struct.pack("@ll", seconds, round((wall_s - seconds) * 1e9)))]


def test_a_kernel_arrival_stamp_goes_on_the_monotonic_clock_unless_the_wall_clock_was_set():
    offset_s, now_s = 1.7e9, 5000.0  # wall = monotonic + offset
    stamp = _timespec(offset_s + now_s - 0.004)  # arrived 4 ms ago
    # float64 at 1.7e9 s resolves 0.24 µs
    assert arrival_on_monotonic(stamp, offset_s, offset_s, now_s) == pytest.approx(now_s - 0.004, abs=1e-6)
    assert arrival_on_monotonic(stamp, offset_s, offset_s + 2e-4, now_s) == pytest.approx(now_s - 0.004, abs=1e-6)
    # the wall clock was set back an hour since the last read: the stamp may be of either clock
    assert arrival_on_monotonic(stamp, offset_s, offset_s + 3600.0, now_s) is None
    assert arrival_on_monotonic([], offset_s, offset_s, now_s) is None  # no stamp came with the datagram
    future = _timespec(offset_s + now_s + 0.5)  # later than now: never later than its reading
    assert arrival_on_monotonic(future, offset_s, offset_s, now_s) == now_s
