"""The MAVLink link the service talks to: one pymavlink connection, MAVLink 2, signing, reconnection.

:class:`MavlinkLink` is deliberately thin: ``recv(timeout_s)`` returns the messages that arrived (each
with its ``time.monotonic()`` arrival stamp), the ``send_*`` methods encode and send one message each,
and everything protocol-shaped the service needs to ask (is this an autopilot heartbeat? an ACK of our
interval request?) is a method here, so pymavlink stays behind this module.

Connection strings (pymavlink's): ``udpin:HOST:PORT`` (listen; we send to every peer that sent a valid
message in the last ``UDP_PEER_TIMEOUT_S``),
``udpout:HOST:PORT``, ``tcp:HOST:PORT`` (client), ``tcpin:HOST:PORT`` (server, one client at a time),
or a serial device ``/dev/ttyACM0`` (baud from the argument, or ``/dev/ttyACM0,921600``). Port 0 on
``udpin``/``tcpin`` binds an ephemeral port (see :attr:`MavlinkLink.local_address`).

A connection that fails while running (a TCP peer closing, a USB serial adapter unplugged) is closed
and reopened with exponential back-off; the first open of a ``tcp:`` client is retried the same way,
since the router it connects to may start after us. A local address that cannot be bound is a
:class:`LinkError` at once: that is a configuration mistake, not a transient.
"""

from __future__ import annotations

import errno
import functools
import logging
import math
import socket
import struct
import sys
import time
from collections import deque
from collections.abc import Callable, Iterator, Sequence
from contextlib import contextmanager
from dataclasses import dataclass
from typing import Any

from fastcrc import crc16

from mavattitude.endpoints import Endpoint, parse_connect
from mavattitude.errors import InputError, LinkError, SensorError, SigningError
from mavattitude.link.mavlink2 import force_mavlink2, mavlink2, mavutil
from mavattitude.link.signing import signing_timestamp_now, verify_signature
from mavattitude.sensors import units

log = logging.getLogger(__name__)

Message = Any  # a pymavlink MAVLink_message: field attributes, get_type(), get_srcSystem(), ...
Sender = tuple[int, int]  # MAVLink (system id, component id)

MAX_MESSAGES_PER_RECV = 64  # bound one recv() so a burst cannot starve heartbeats and the watchdog
#: What a connection's ``recv_msg`` gives for a frame of a message the caller does not read (``reads``)
SKIPPED = object()
STREAM_READ_BYTES = 4096  # one read of a byte stream: what waits, up to 44 ms of a 921 600 baud serial line
MIN_SLEEP_S = 0.001  # a shorter quiet spell is waited for on the socket: a sleep's wake-up would cost as much
UDP_RECEIVE_BUFFER_BYTES = 1 << 20
#: Linux's SO_TIMESTAMPNS, which Python's socket module does not name (the generic value, x86's and ARM's): the
#: kernel stamps each datagram with its arrival (CLOCK_REALTIME, a ``struct timespec`` of two C longs).
SO_TIMESTAMPNS = getattr(socket, "SO_TIMESTAMPNS", 35)
_TIMESPEC = struct.Struct("@ll")
_TIMESPEC_SPACE = socket.CMSG_SPACE(_TIMESPEC.size)
CLOCK_STEP_S = 0.001  # the wall clock moved this much against the monotonic one between reads: it was set
CLOCK_READ_S = 50e-6  # the two clocks read further apart than this (preempted between): read again
# our HEARTBEATs (1 Hz) whose echo is known as ours: another program's own sequence numbers collide with these 3 in
# 256 of its beats, so it is heard within a beat or two all the same
ECHO_HEARTBEATS = 3
UDP_PEER_TIMEOUT_S = 5.0  # a udpin peer silent this long is no longer sent to (unless it is the only one)
CONNECT_TIMEOUT_S = 0.5  # a TCP connect attempt; short, so a stop request is never held up for long
SIGNING_CLOCK_UPDATE_S = 1.0
STATUSTEXT_LEN = 50
NAMED_VALUE_LEN = 10
NOT_AUTOPILOT_TYPES = frozenset(
    {
        mavlink2.MAV_TYPE_GCS,
        mavlink2.MAV_TYPE_ONBOARD_CONTROLLER,
        mavlink2.MAV_TYPE_GIMBAL,
        mavlink2.MAV_TYPE_ADSB,
        mavlink2.MAV_TYPE_CAMERA,
    }
)
SEVERITY = {
    "emergency": mavlink2.MAV_SEVERITY_EMERGENCY,
    "error": mavlink2.MAV_SEVERITY_ERROR,
    "warning": mavlink2.MAV_SEVERITY_WARNING,
    "notice": mavlink2.MAV_SEVERITY_NOTICE,
    "info": mavlink2.MAV_SEVERITY_INFO,
}


@dataclass
class LinkCounters:
    """What the link saw and did, cumulative."""

    received: int = 0  # well-formed messages handed to the caller
    skipped: int = 0  # frames of a message the caller does not read, left undecoded (:meth:`MavlinkLink.recv_items`)
    bad_data: int = 0  # garbage bytes, bad CRC, truncated or malformed frames
    signature_rejected: int = 0  # unsigned or badly signed while signing is required
    sent: int = 0
    send_failed: int = 0  # the link was down or the write failed
    disconnects: int = 0
    reconnects: int = 0
    same_id: int = 0  # HEARTBEATs under our own system and component id that are not ours echoed: another program


class _Disconnected(ConnectionError):
    """The peer of a stream connection went away (EOF or reset)."""


@dataclass(frozen=True)
class DirectFrame:
    """A message the link decodes from its frame itself, without pymavlink's message object: ``decode`` takes the
    payload's fields as the frame carries them (wire order, pymavlink's ``unpacker`` of the message) and returns
    the item to hand on (:meth:`MavlinkLink.recv_items`), or raises :class:`SensorError`, handed on as
    ``refused(error)``; anything else it raises (a bug met on odd fields) is handed on as ``broken(error)``, so
    that one message is lost and not the link."""

    message_id: int
    decode: Callable[[tuple[Any, ...]], Any]
    refused: Callable[[SensorError], Any]  # the item for fields ``decode`` refuses (raising SensorError)
    broken: Callable[[Exception], Any]  # the item for a bug met in ``decode``


class _FrameReader:
    """:class:`DirectFrame` on a datagram: one unsigned MAVLink 2 frame of its message, CRC checked (CRC-16/MCRF4XX
    over the frame after the magic, then the message's CRC extra byte, as pymavlink checks it); anything else is
    left to pymavlink, which parses it as before."""

    def __init__(self, frame: DirectFrame) -> None:
        cls = mavlink2.mavlink_map[frame.message_id]
        self._id = frame.message_id.to_bytes(3, "little")
        self._crc_extra = bytes([cls.crc_extra])
        self._unpack = cls.unpacker.unpack
        self._size = cls.unpacker.size
        self._decode = frame.decode
        self._refused = frame.refused
        self._broken = frame.broken

    def read(self, data: bytes) -> tuple[Sender, Any] | None:
        """The sender and item of ``data``, or None when it is not such a frame (or its CRC is wrong)."""
        end = len(data) - 2
        if end < mavlink2.HEADER_LEN_V2 or data[0] != mavlink2.PROTOCOL_MARKER_V2 or data[2] != 0:
            return None
        if data[7:10] != self._id or end != mavlink2.HEADER_LEN_V2 + data[1]:
            return None
        if crc16.mcrf4xx(self._crc_extra, crc16.mcrf4xx(memoryview(data)[1:end])) != data[end] | data[end + 1] << 8:
            return None
        payload = data[mavlink2.HEADER_LEN_V2 : end]
        if len(payload) != self._size:  # MAVLink 2 drops trailing zero bytes; pymavlink pads, or cuts a long one
            payload = (payload + bytes(self._size))[: self._size]
        try:
            return (data[5], data[6]), self._decode(self._unpack(payload))
        except SensorError as exc:
            return (data[5], data[6]), self._refused(exc)
        except Exception as exc:  # a bug met on one odd message: that message is lost, not the link
            return (data[5], data[6]), self._broken(exc)


class FrameConnection:
    """A connection read a frame at a time by :class:`MavlinkLink`, the input message (when the link gives it its
    :class:`DirectFrame`) decoded straight from its frame: :class:`DatagramConnection`, :class:`StreamConnection`."""

    mav: Any
    on_truncated: Any = None  # called once per dropped incomplete frame
    direct: _FrameReader | None = None
    reads: frozenset[int] | None = None  # the message ids the caller reads (None: all); others are SKIPPED
    stamps_arrivals = False  # the OS stamps each datagram's arrival: :attr:`arrival_s`
    arrival_s: float | None = None  # the last datagram's arrival (``time.monotonic()``) when known

    def drop_unfinished(self) -> None:
        """Forget the start of a frame whose rest will not come (a truncated datagram, a stream's sender gone):
        counted, so that it does not take the next bytes as its rest."""
        mav = self.mav
        if len(mav.buf) > mav.buf_index:
            mav.buf = bytearray()
            mav.buf_index = 0
            mav.expected_length = mavlink2.HEADER_LEN_V1 + 2
            if self.on_truncated is not None:
                self.on_truncated()


class StreamConnection(FrameConnection):
    """Reading a byte stream (serial, TCP): every byte waiting in one read, then its frames one at a time, a whole
    unsigned frame of the direct message decoded by it, any other framed and decoded by pymavlink's parser.

    pymavlink's own loop reads a stream a frame's header and then its rest at a time (two reads per message,
    and with pyserial a ``select`` before each) and builds every message's object: on a tty here, three times
    the CPU per message of this (110 against 35 µs).
    """

    def select(self, timeout: float) -> bool:
        """Whether a frame can be read: one already whole in the buffer at once, else the OS's word within
        ``timeout``."""
        mav = self.mav
        end = frame_end(mav.buf, mav.buf_index)
        return (end is not None and end <= len(mav.buf)) or super().select(timeout)

    def recv_msg(self) -> Message | tuple[Sender, Any] | None:
        """The next message (pymavlink's), or ``(sender, item)`` of one decoded directly; None when nothing waits."""
        msg = self._next_frame()
        if msg is None:
            data = self.recv(STREAM_READ_BYTES)
            if not data:
                return None
            mav = self.mav
            del mav.buf[: mav.buf_index]  # what is parsed goes: the buffer holds one read and a frame's start
            mav.buf_index = 0
            mav.buf.extend(data)
            mav.total_bytes_received += len(data)
            msg = self._next_frame()
        return msg

    def _next_frame(self) -> Message | tuple[Sender, Any] | None:
        """The frame at the head of the buffer when it is whole (or bytes that start none, which pymavlink reports
        as BAD_DATA at once); None while it is incomplete."""
        mav = self.mav
        buf, start = mav.buf, mav.buf_index
        end = frame_end(buf, start)
        if end is None or end > len(buf):
            return None
        direct, reads = self.direct, self.reads
        if direct is not None or reads is not None:
            frame = bytes(buf[start:end])
            got = direct.read(frame) if direct is not None else None
            if got is None and reads is not None and _unread(frame, reads):
                got = SKIPPED
            if got is not None:
                mav.buf_index = end
                return got
        return mav.parse_char(b"")


class DatagramConnection(FrameConnection):
    """Reading whole datagrams (UDP, and the in-memory link): each parsed on its own.

    MAVLink over UDP puts whole frames in each datagram. pymavlink keeps the bytes of a truncated frame and
    reads the next datagram as its continuation, so one truncated datagram also destroys the good frame after
    it; here the incomplete rest of a datagram is dropped (and counted) when the next one arrives.
    """

    def recv(self, n: int | None = None) -> bytes:
        raise NotImplementedError

    def heard(self) -> None:
        """The last datagram held a well-formed message (for a peer list)."""

    def recv_msg(self) -> Message | tuple[Sender, Any] | None:
        """The next message (pymavlink's), or ``(sender, item)`` of one decoded directly; None when nothing waits."""
        # Complete frames still buffered from the last datagram. The parser is called only when bytes are
        # left (one frame per datagram is usual): a call on nothing is a third of its calls per message, and
        # with robust parsing it changes no state.
        mav = self.mav
        msg = mav.parse_char(b"") if len(mav.buf) > mav.buf_index else None  # pymavlink's buf_len(), inline
        if msg is None:
            data = self.recv()
            if not data:
                return None
            self.drop_unfinished()
            direct = self.direct
            got = direct.read(data) if direct is not None else None
            if got is not None:
                self.heard()
                return got
            if not _whole_frame(data):
                msg = self.mav.parse_char(data)
            elif self.reads is not None and _unread(data, self.reads):
                return SKIPPED  # (not heard: its CRC is unchecked, so it buys its sender nothing)
            else:
                msg = self._decode(data)
        if msg is not None and msg.get_type() != "BAD_DATA":
            self.heard()
        # no mavutil.post_message: its per-system bookkeeping (two message copies per instance-keyed
        # message such as RAW_IMU) is a third of the receive cost and nothing here reads it
        return msg

    def _decode(self, frame: bytes) -> Message:
        """One whole frame decoded as pymavlink's robust parser does once it has framed it: CRC, signature and
        payload checked by ``decode``, an error made BAD_DATA. Its byte-by-byte framing (a third of the cost
        of a message) has nothing to find in a datagram that is exactly one frame."""
        mbuf = bytearray(frame)
        try:
            return self.mav.decode(mbuf)
        except mavlink2.MAVError as reason:
            self.mav.total_receive_errors += 1
            return mavlink2.MAVLink_bad_data(mbuf, reason.message)


def wall_minus_monotonic() -> tuple[float, float]:
    """The wall clock's offset from the monotonic one, and the monotonic time it was read at: the wall clock read
    between two monotonic reads no more than ``CLOCK_READ_S`` apart (a read preempted between the two would be off
    by the preemption; three tries, then the last)."""
    for _ in range(3):
        before = time.monotonic()
        wall = time.time()
        after = time.monotonic()
        if after - before <= CLOCK_READ_S:
            break
    return wall - 0.5 * (before + after), after


def arrival_on_monotonic(
    ancillary: list[tuple[int, int, bytes]], wall_minus_monotonic_s: float, before_s: float, now_s: float
) -> float | None:
    """A datagram's arrival on ``time.monotonic()`` from the kernel's wall-clock stamp in its ``ancillary`` data
    (``recvmsg``), given the wall clock's offset from the monotonic one now and at the previous read
    (``before_s``); None without a stamp, or when the offset moved by ``CLOCK_STEP_S`` or more (the wall clock
    was set: the stamp may be on either side). Never later than ``now_s``."""
    if abs(wall_minus_monotonic_s - before_s) >= CLOCK_STEP_S:
        return None
    for level, kind, data in ancillary:
        if level == socket.SOL_SOCKET and kind == SO_TIMESTAMPNS:
            seconds, nanoseconds = _TIMESPEC.unpack(data)
            return min(seconds - wall_minus_monotonic_s + 1e-9 * nanoseconds, now_s)
    return None


class _Udp(DatagramConnection, mavutil.mavudp):
    """pymavlink's UDP socket, read as :class:`DatagramConnection`, answering only real peers.

    A ``udpin`` socket sends to every address it has heard from. pymavlink adds any sender, forever; here only
    senders of a well-formed (and, with signing required, well-signed) message count, and one silent for
    ``UDP_PEER_TIMEOUT_S`` is dropped (pymavlink keeps the last one), so garbage from a spoofed address buys
    neither our traffic nor our memory.
    """

    def __init__(self, address: str, *, input: bool, **kwargs: Any) -> None:
        if input:
            _check_port_free(address)
        super().__init__(address, input=input, timeout=UDP_PEER_TIMEOUT_S, **kwargs)
        # room for a burst while the loop is busy (the kernel caps this at net.core.rmem_max)
        self.port.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, UDP_RECEIVE_BUFFER_BYTES)
        self._sender: tuple[str, int] | None = None
        self.stamps_arrivals = self._stamp_arrivals()

    def recv(self, n: int | None = None) -> bytes:
        try:
            if not self.stamps_arrivals:
                data, self._sender = self.port.recvfrom(mavutil.UDP_MAX_PACKET_LEN)
                return data
            data, ancillary, _, self._sender = self.port.recvmsg(mavutil.UDP_MAX_PACKET_LEN, _TIMESPEC_SPACE)
        except (BlockingIOError, ConnectionRefusedError):  # nothing waiting; an ICMP error from a udpout peer
            return b""
        self.arrival_s = self._arrival(ancillary)
        return data

    def _stamp_arrivals(self) -> bool:
        """Ask the kernel to stamp each datagram's arrival (Linux); whether it will."""
        if not sys.platform.startswith("linux"):
            return False
        try:
            self.port.setsockopt(socket.SOL_SOCKET, SO_TIMESTAMPNS, 1)
        except OSError:
            return False
        self._wall_minus_monotonic = wall_minus_monotonic()[0]
        return True

    def _arrival(self, ancillary: list[tuple[int, int, bytes]]) -> float | None:
        offset, now = wall_minus_monotonic()
        previous, self._wall_minus_monotonic = self._wall_minus_monotonic, offset
        return arrival_on_monotonic(ancillary, offset, previous, now)

    def heard(self) -> None:
        if self.udp_server:
            self.clients.add(self._sender)
            self.clients_last_alive[self._sender] = time.time()  # pymavlink's write() ages them by time.time()


def autopilot_heartbeat(autopilot: Any, mav_type: Any, system: Any) -> Any:
    """Whether HEARTBEAT fields say a flight controller (not a GCS, companion, gimbal, camera or ADS-B unit, and
    not system 255, the ground stations' id): on one message's ints, or a log's columns (``&`` and ``!=`` only)."""
    verdict = (autopilot != mavlink2.MAV_AUTOPILOT_INVALID) & (system != 255)
    for kind in NOT_AUTOPILOT_TYPES:
        verdict = verdict & (mav_type != kind)
    return verdict


def _as_is(msg: Message) -> Message:
    return msg


def frame_end(buf: bytes | bytearray, start: int) -> int | None:
    """Where the frame at ``buf[start]`` ends as pymavlink's parser frames it: by its header's payload length and,
    in MAVLink 2, its signature; ``start + 1`` for a byte that starts no frame (the parser reports it at once);
    None before there is a byte, or a frame's first three."""
    n = len(buf) - start
    if n < 1:
        return None
    marker = buf[start]
    if marker != mavlink2.PROTOCOL_MARKER_V2 and marker != mavlink2.PROTOCOL_MARKER_V1:
        return start + 1
    if n < 3:
        return None
    if marker == mavlink2.PROTOCOL_MARKER_V1:
        return start + mavlink2.HEADER_LEN_V1 + buf[start + 1] + 2
    signed = buf[start + 2] & mavlink2.MAVLINK_IFLAG_SIGNED
    return start + mavlink2.HEADER_LEN_V2 + buf[start + 1] + 2 + (mavlink2.MAVLINK_SIGNATURE_BLOCK_LEN if signed else 0)


def _unread(frame: bytes, reads: frozenset[int]) -> bool:
    """Whether ``frame`` (one whole frame, as :func:`frame_end` frames it) is a MAVLink 2 message whose id is not
    in ``reads``. MAVLink 1 frames are left to pymavlink: no vehicle streams them to a companion any more."""
    return frame[0] == mavlink2.PROTOCOL_MARKER_V2 and (frame[7] | frame[8] << 8 | frame[9] << 16) not in reads


def _whole_frame(data: bytes) -> bool:
    """Whether a datagram is exactly one MAVLink 2 frame by its header (length, signature; no other
    incompatibility flag, which the parser's framing rejects): what :meth:`_Udp._decode` takes."""
    if len(data) < mavlink2.HEADER_LEN_V2 or data[0] != mavlink2.PROTOCOL_MARKER_V2:
        return False
    return not data[2] & ~mavlink2.MAVLINK_IFLAG_SIGNED and frame_end(data, 0) == len(data)


class _FramePacker:
    """One message's frames as pymavlink's MAVLink 2 ``pack`` makes them, unsigned, byte for byte: the payload by
    the message's own struct (wire order), its trailing zero bytes cut (one kept), the header with the sender's
    sequence number (then advanced, as ``MAVLink.send`` does), the CRC with the message's CRC extra. A fifth of
    the Python of building pymavlink's message object and packing it."""

    def __init__(self, cls: Any) -> None:
        self._pack = cls.unpacker.pack
        self._id = int(cls.id).to_bytes(3, "little")
        self._crc_extra = bytes([cls.crc_extra])

    def frame(self, mav: Any, *wire: Any) -> bytes:
        payload = self._pack(*wire).rstrip(b"\0") or b"\0"
        seq = mav.seq
        mav.seq = (seq + 1) % 256
        head = bytes((mavlink2.PROTOCOL_MARKER_V2, len(payload), 0, 0, seq, mav.srcSystem, mav.srcComponent))
        frame = head + self._id + payload
        crc = crc16.mcrf4xx(self._crc_extra, crc16.mcrf4xx(memoryview(frame)[1:]))
        return frame + crc.to_bytes(2, "little")


_QUATERNION = _FramePacker(mavlink2.MAVLink_attitude_quaternion_message)
_QUATERNION_COV = _FramePacker(mavlink2.MAVLink_attitude_quaternion_cov_message)
_NO_OFFSET = (0.0, 0.0, 0.0, 0.0)  # ATTITUDE_QUATERNION's repr_offset_q: none


def _check_port_free(address: str) -> None:
    """Raise ``EADDRINUSE`` when another socket already holds this UDP address.

    pymavlink binds ``udpin`` with SO_REUSEADDR, which on Linux lets a second socket bind the same port
    when both set it: a second instance (a CLI run beside the systemd service) would bind silently and
    the two would share the datagrams, the first going deaf. A probe bound *without* the option fails
    while any other socket holds the address, and is closed before pymavlink binds.
    """
    host, _, port = address.rpartition(":")
    if int(port) == 0:
        return  # an ephemeral port is free by definition
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as probe:
        probe.bind((host, int(port)))


class _StampedWriter:
    """What pymavlink's ``MAVLink.send`` writes its packed bytes to: the connection's ``write``, with
    the moment of the hand-over to the OS noted on the link (:attr:`MavlinkLink.last_send_s`).

    Stamped before the write, because on a loaded machine the process woken by our datagram can
    preempt us inside it: that time delays neither the packet nor our next one.
    """

    def __init__(self, write: Callable[[bytes], Any], link: MavlinkLink) -> None:
        self._write = write
        self._link = link
        self._held: list[bytes] | None = None

    def write(self, buf: bytes) -> Any:
        if self._held is not None:
            self._held.append(bytes(buf))
            return len(buf)
        self._link.last_send_s = time.monotonic()
        return self._write(buf)

    @contextmanager
    def one_write(self) -> Iterator[None]:
        """What is written inside goes out in one write when the block ends (also when it raised)."""
        self._held = []
        try:
            yield
        finally:
            held, self._held = self._held, None
            if held:
                self.write(b"".join(held))


class _TcpClient(StreamConnection, mavutil.mavtcp):
    """pymavlink's TCP client with a bounded connect time and disconnects raised instead of printed."""

    def do_connect(self) -> None:
        self.port = socket.create_connection(self.destination_addr, timeout=CONNECT_TIMEOUT_S)
        self.port.setblocking(False)
        self.port.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        mavutil.set_close_on_exec(self.port.fileno())

    def handle_eof(self) -> None:
        raise _Disconnected("TCP peer closed the connection")

    def handle_disconnect(self) -> None:
        raise _Disconnected("TCP connection reset by peer")


class _TcpServer(StreamConnection, mavutil.mavtcpin):
    """pymavlink's TCP server, which also notices a client's EOF (pymavlink spins on it)."""

    def recv(self, n: int | None = None) -> bytes:
        if self.port is None:
            try:
                self.port, _ = self.listen.accept()
            except OSError:
                return b""
            self.port.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
            self.port.setblocking(False)
            mavutil.set_close_on_exec(self.port.fileno())
            self.fd = self.port.fileno()
        try:
            data = self.port.recv(self.mav.bytes_needed() if n is None else n)
        except OSError as exc:
            if exc.errno in (errno.EAGAIN, errno.EWOULDBLOCK):
                return b""
            data = b""
        if not data:  # EOF or error: wait for the next client (a frame the last one left unfinished goes)
            self.drop_unfinished()
            self.port.close()
            self.port = None
            self.fd = self.listen.fileno()
            log.info("TCP client disconnected; listening again")
        return data


class _Serial(StreamConnection, mavutil.mavserial):
    """pymavlink's serial device (pyserial, non-blocking), read as a :class:`StreamConnection`."""


def _open_connection(endpoint: Endpoint, source_system: int, source_component: int) -> Any:
    ids = {"source_system": source_system, "source_component": source_component}
    if endpoint.kind == "tcp":
        return _TcpClient(endpoint.address, retries=0, **ids)
    if endpoint.kind == "tcpin":
        return _TcpServer(endpoint.address, **ids)
    if endpoint.kind == "serial":
        return _Serial(endpoint.address, baud=endpoint.baud, **ids)
    return _Udp(endpoint.address, input=endpoint.kind == "udpin", **ids)


class MavlinkLink:
    """A MAVLink 2 connection with optional signing, reopened with back-off when it fails.

    ``signing_key`` (32 bytes) signs every packet sent; with ``require_signing`` unsigned and badly
    signed packets are dropped and counted (:attr:`counters` ``.signature_rejected``).
    """

    def __init__(
        self,
        connect: str | Endpoint,
        *,
        source_system: int,
        source_component: int = mavlink2.MAV_COMP_ID_ONBOARD_COMPUTER,
        baud: int = 115200,
        signing_key: bytes | None = None,
        require_signing: bool = False,
        reconnect_min_s: float = 0.1,
        reconnect_max_s: float = 5.0,
    ) -> None:
        if not 1 <= source_system <= 254:
            raise LinkError(f"source system id {source_system} is outside 1-254 (255 is for ground stations)")
        if signing_key is not None and len(signing_key) != 32:
            raise SigningError(f"a MAVLink 2 signing key is 32 bytes, not {len(signing_key)}")
        if require_signing and signing_key is None:
            raise SigningError("require_signing is on but no signing key is configured")
        self.endpoint = connect if isinstance(connect, Endpoint) else parse_connect(connect, baud)
        self.counters = LinkCounters()
        self._source = (source_system, source_component)
        self._signing_key = signing_key
        self._require_signing = require_signing
        self._signing: Any = None  # pymavlink's MAVLinkSigning, kept across reconnects
        self._seq = 0
        self._reconnect_range_s = (reconnect_min_s, reconnect_max_s)
        self._backoff_s = reconnect_min_s
        self._retry_at = 0.0
        self._signing_clock_at = 0.0
        self._conn: Any = None
        self._direct: tuple[DirectFrame, _FrameReader] | None = None  # the last one asked for, ready
        self._backlog_since: float | None = None  # a sleep's backlog is being read: its stamp
        self.backlog = False  # the last recv_items returned what waited through a sleep, stamped at its start
        self.last_send_s = float("nan")  # time.monotonic() at which the last packet was handed to the OS
        self._heartbeat_seqs: deque[int] = deque(maxlen=ECHO_HEARTBEATS)  # of our latest HEARTBEATs
        self.same_id_heard_s = -math.inf  # when another program's HEARTBEAT under our id last arrived (t_rx)
        try:
            self._open()
        except OSError as exc:
            if self.endpoint.kind != "tcp":
                in_use = " (another program holds it: a second mavattitude, the systemd service, a router?)"
                hint = in_use if exc.errno == errno.EADDRINUSE else ""
                raise LinkError(f"cannot open {connect}: {exc.strerror or exc}{hint}") from exc
            log.info("waiting for the autopilot at %s (%s); retrying with back-off", connect, exc)
            self._schedule_retry()

    # -- connection management ------------------------------------------------------------------------

    def _connect(self) -> Any:
        """The pymavlink connection of :attr:`endpoint`, not yet set up (raises ``OSError`` when it cannot open)."""
        try:
            return _open_connection(self.endpoint, *self._source)
        except ValueError as exc:  # pymavlink's complaint about an address
            raise LinkError(f"cannot open {self.endpoint.kind}:{self.endpoint.address}: {exc}") from exc

    def _open(self) -> None:
        conn = self._connect()
        force_mavlink2(conn)
        conn.mav.file = _StampedWriter(conn.write, self)
        conn.mav.seq = self._seq
        conn.on_truncated = self._count_truncated
        if self._signing_key is not None:
            self._install_signing(conn)
        self._conn = conn

    def _install_signing(self, conn: Any) -> None:
        if self._signing is None:
            conn.setup_signing(
                self._signing_key,
                sign_outgoing=True,
                allow_unsigned_callback=lambda _mav, _msg_id: not self._require_signing,
                initial_timestamp=signing_timestamp_now(),
                link_id=0,
            )
            self._signing = conn.mav.signing
        conn.mav.signing = self._signing
        conn.mav.check_signature = functools.partial(verify_signature, self._signing)

    def _schedule_retry(self) -> None:
        self._retry_at = time.monotonic() + self._backoff_s
        self._backoff_s = min(2.0 * self._backoff_s, self._reconnect_range_s[1])

    def _drop(self, exc: BaseException) -> None:
        """Close a failed connection and schedule its reopening."""
        self.counters.disconnects += 1
        log.warning("link %s:%s lost (%s); reopening in %.1f s", *self._where(), exc, self._backoff_s)
        self._close_conn()
        self._schedule_retry()

    def _reopen(self, timeout_s: float) -> None:
        wait_s = self._retry_at - time.monotonic()
        if wait_s > 0.0:
            time.sleep(min(wait_s, timeout_s))
            return
        was_open = self.counters.disconnects > 0  # else this is the first open of a tcp client, still retried
        try:
            self._open()
        except OSError as exc:
            # never open yet: the service says what it waits for, and each refused try is detail
            what = "reopening failed" if was_open else "no autopilot yet"
            log.log(
                logging.WARNING if was_open else logging.DEBUG,
                "link %s:%s: %s (%s); next try in %.1f s",
                *self._where(),
                what,
                exc,
                self._backoff_s,
            )
            self._schedule_retry()
            return
        if was_open:
            self.counters.reconnects += 1
        log.info("link %s:%s open%s", *self._where(), " again" if was_open else "")

    def _where(self) -> tuple[str, str]:
        return self.endpoint.kind, self.endpoint.address

    def _close_conn(self) -> None:
        conn, self._conn = self._conn, None
        if conn is None:
            return
        self._seq = conn.mav.seq
        try:
            conn.close()
        except OSError as exc:
            log.debug("closing the link: %s", exc)

    @property
    def is_open(self) -> bool:
        return self._conn is not None

    @property
    def local_address(self) -> tuple[str, int] | None:
        """The bound (host, port) of a udpin/tcpin link (useful with port 0), else None."""
        if self._conn is None or self.endpoint.kind not in ("udpin", "tcpin"):
            return None
        sock = self._conn.listen if self.endpoint.kind == "tcpin" else self._conn.port
        return sock.getsockname()[:2]

    def set_source_system(self, system_id: int) -> None:
        """Send as this system from now on (the vehicle's, once the service has locked onto it)."""
        if not 1 <= system_id <= 254:
            raise LinkError(f"source system id {system_id} is outside 1-254 (255 is for ground stations)")
        self._source = (system_id, self._source[1])
        if self._conn is not None:
            self._conn.mav.srcSystem = system_id

    @property
    def source(self) -> Sender:
        """Our (system id, component id): what we send as."""
        return self._source

    def close(self) -> None:
        self._close_conn()

    def __enter__(self) -> MavlinkLink:
        return self

    def __exit__(self, *exc_info: object) -> None:
        self.close()

    # -- receiving ------------------------------------------------------------------------------------

    def recv(self, timeout_s: float) -> list[tuple[float, Message]]:
        """Wait up to ``timeout_s`` for input; return ``(arrival time.monotonic(), message)`` pairs."""
        return [(t_rx, msg) for t_rx, _, msg in self.recv_items(timeout_s, _as_is)]

    def recv_items(
        self,
        timeout_s: float,
        decode: Callable[[Message], Any],
        direct: DirectFrame | None = None,
        quiet_until: float = -math.inf,
        reads: frozenset[int] | None = None,
    ) -> list[tuple[float, Sender, Any]]:
        """Wait up to ``timeout_s`` for input; return ``(arrival time.monotonic(), sender, decode(message))`` of
        every message waiting (at most ``MAX_MESSAGES_PER_RECV``). A datagram that is exactly one unsigned frame
        of ``direct``'s message is decoded by it instead, without pymavlink (not while signing is required: then
        every frame is pymavlink's to check). ``reads``: the ids of the messages the caller reads; a MAVLink 2
        frame of any other is counted ``skipped`` and not decoded at all (a real autopilot streams a hundred
        messages a second that an attitude service has no use for), its CRC unchecked (not while signing is
        required either).

        ``quiet_until`` (``time.monotonic()``): the caller need not hear of anything before then, so the link
        sleeps until then (within ``timeout_s``) rather than wake for every message, and returns what arrived
        meanwhile at once, stamped with its arrival where the OS stamps datagrams (:attr:`stamps_arrivals`), else
        with the time the sleep began (each may have arrived at any moment of it: latency counted from there is
        never understated; :attr:`backlog` says it was).
        """
        conn = self._conn
        if conn is None:
            self._reopen(timeout_s)
            return []
        self._keep_signing_clock()
        if isinstance(conn, FrameConnection):
            conn.direct = self._reader(direct)
            conn.reads = None if self._require_signing else reads
        asleep_since = self._backlog_since  # a backlog longer than one call is still stamped so
        self.backlog = False
        if asleep_since is None:
            now = time.monotonic()
            quiet_s = min(quiet_until - now, timeout_s)
            if quiet_s >= MIN_SLEEP_S:
                time.sleep(quiet_s)
                asleep_since, timeout_s = now, timeout_s - quiet_s
        if asleep_since is not None:
            received = self._read(conn, decode, asleep_since)
            self._backlog_since = asleep_since if len(received) >= MAX_MESSAGES_PER_RECV else None
            if received or self._conn is None:
                return received
        if not conn.select(max(timeout_s, 0.0)):
            return []
        return self._read(conn, decode, None)

    def _read(
        self, conn: Any, decode: Callable[[Message], Any], slept_since: float | None
    ) -> list[tuple[float, Sender, Any]]:
        """Every message waiting (at most ``MAX_MESSAGES_PER_RECV``), stamped with its datagram's arrival where
        the OS stamps it, else with ``slept_since`` (:attr:`backlog`), else when read."""
        received: list[tuple[float, Sender, Any]] = []
        stamped = self.stamps_arrivals
        try:
            while len(received) < MAX_MESSAGES_PER_RECV:
                # before reading and parsing: our whole handling counts as latency
                t_rx = time.monotonic() if slept_since is None else slept_since
                msg = conn.recv_msg()
                if msg is None:
                    break
                if msg is SKIPPED:
                    self.counters.skipped += 1
                    continue
                if stamped and conn.arrival_s is not None:
                    t_rx = conn.arrival_s
                elif slept_since is not None:
                    self.backlog = True
                if type(msg) is tuple:  # (sender, item), decoded from its frame
                    received.append((t_rx, *msg))
                elif msg.get_type() == "BAD_DATA":
                    self._count_bad(msg)
                else:
                    sender = (msg.get_srcSystem(), msg.get_srcComponent())
                    if sender == self._source:
                        self._heard_as_us(msg, t_rx)
                    received.append((t_rx, sender, decode(msg)))
        except OSError as exc:  # includes _Disconnected and serial.SerialException
            self._drop(exc)
        if received:
            self.counters.received += len(received)
            self._backoff_s = self._reconnect_range_s[0]  # the link works: the next failure retries fast
        return received

    def _heard_as_us(self, msg: Message, t_rx: float) -> None:
        """A message sent under our own id: our HEARTBEAT echoed (a broadcast address, a loop in the routing) has
        the sequence number we sent it with; a HEARTBEAT with another is a second program speaking as us (a second
        mavattitude, the systemd service beside a run by hand, another onboard program on the same component)."""
        if msg.get_type() == "HEARTBEAT" and msg.get_seq() not in self._heartbeat_seqs:
            self.counters.same_id += 1
            self.same_id_heard_s = t_rx

    @property
    def stamps_arrivals(self) -> bool:
        """Whether each datagram is stamped with its arrival by the OS (UDP on Linux): a sleep through arrivals
        then delays them without hiding how long."""
        return getattr(self._conn, "stamps_arrivals", False)

    def _reader(self, direct: DirectFrame | None) -> _FrameReader | None:
        if direct is None or self._require_signing:
            return None
        if self._direct is None or self._direct[0] is not direct:
            self._direct = (direct, _FrameReader(direct))
        return self._direct[1]

    def _count_truncated(self) -> None:
        self.counters.bad_data += 1

    def _count_bad(self, msg: Message) -> None:
        if "signature" in str(getattr(msg, "reason", "")).lower():
            self.counters.signature_rejected += 1
        else:
            self.counters.bad_data += 1

    def _keep_signing_clock(self) -> None:
        """Raise the signing timestamp to the wall clock now and then (MAVProxy does it every 10 s)."""
        if self._signing is None:
            return
        now = time.monotonic()
        if now - self._signing_clock_at >= SIGNING_CLOCK_UPDATE_S:
            self._signing_clock_at = now
            self._signing.timestamp = max(self._signing.timestamp, signing_timestamp_now())

    @staticmethod
    def is_autopilot_heartbeat(msg: Message) -> bool:
        """A HEARTBEAT from a flight controller (:func:`autopilot_heartbeat`)."""
        return msg.get_type() == "HEARTBEAT" and bool(autopilot_heartbeat(msg.autopilot, msg.type, msg.get_srcSystem()))

    @staticmethod
    def interval_ack_result(msg: Message) -> str | None:
        """For a COMMAND_ACK of SET_MESSAGE_INTERVAL, the result's name (``"ACCEPTED"``, ...); else None."""
        if msg.get_type() != "COMMAND_ACK" or msg.command != mavlink2.MAV_CMD_SET_MESSAGE_INTERVAL:
            return None
        entry = mavlink2.enums["MAV_RESULT"].get(msg.result)
        return entry.name.removeprefix("MAV_RESULT_") if entry is not None else str(msg.result)

    def addressed_to_us(self, msg: Message) -> bool:
        """A message with MAVLink 2's ``target_system``/``target_component`` (COMMAND_ACK's extension fields)
        meant for us: each 0 (unset, or a MAVLink 1 sender) or our own id. A ground station's ACK, which a
        router forwards to every peer, is not."""
        system, component = getattr(msg, "target_system", 0), getattr(msg, "target_component", 0)
        return system in (0, self._source[0]) and component in (0, self._source[1])

    # -- sending --------------------------------------------------------------------------------------

    def _send(self, msg: Message) -> bool:
        conn = self._conn
        if conn is None:
            self.counters.send_failed += 1
            return False
        try:
            conn.mav.send(msg)
        except OSError as exc:
            self.counters.send_failed += 1
            self._drop(exc)
            return False
        self.counters.sent += 1
        return True

    def send_heartbeat(self) -> bool:
        """Our HEARTBEAT: an onboard controller, not an autopilot. Its sequence number is kept: an echo of it is
        not another program under our id."""
        msg = mavlink2.MAVLink_heartbeat_message(
            mavlink2.MAV_TYPE_ONBOARD_CONTROLLER, mavlink2.MAV_AUTOPILOT_INVALID, 0, 0, mavlink2.MAV_STATE_ACTIVE, 3
        )
        sent = self._send(msg)
        if sent:
            self._heartbeat_seqs.append(msg.get_seq())
        return sent

    def request_message_interval(self, target: tuple[int, int], message_id: int, rate_hz: float) -> bool:
        """MAV_CMD_SET_MESSAGE_INTERVAL for one message; param3 = 0 (ArduPilot refuses anything else)."""
        interval_us = float(round(1e6 / rate_hz))
        return self._send(
            mavlink2.MAVLink_command_long_message(
                target[0],
                target[1],
                mavlink2.MAV_CMD_SET_MESSAGE_INTERVAL,
                0,
                float(message_id),
                interval_us,
                0.0,
                0.0,
                0.0,
                0.0,
                0.0,
            )
        )

    def request_parameter(self, target: tuple[int, int], name: str) -> bool:
        """PARAM_REQUEST_READ of one parameter by its name (the autopilot answers with PARAM_VALUE)."""
        return self._send(mavlink2.MAVLink_param_request_read_message(target[0], target[1], name.encode("ascii"), -1))

    def send_attitude_quaternion_cov(
        self, time_usec: int, q: Sequence[float], rates_radps: Sequence[float], covariance: Sequence[float]
    ) -> bool:
        """ATTITUDE_QUATERNION_COV: as ATTITUDE_QUATERNION, with the 3×3 attitude error covariance (rad², body
        frame error angles, row-major; a NaN first element means unknown, as MAVLink says)."""
        return self._send(
            mavlink2.MAVLink_attitude_quaternion_cov_message(
                int(time_usec),
                [float(v) for v in q],
                float(rates_radps[0]),
                float(rates_radps[1]),
                float(rates_radps[2]),
                [float(v) for v in covariance],
            )
        )

    def send_named_value_float(self, time_boot_ms: int, name: str, value: float) -> bool:
        """NAMED_VALUE_FLOAT: one named number (``name`` at most 10 ASCII characters, the message's field)."""
        if len(name) > NAMED_VALUE_LEN or not name.isascii():
            raise InputError(f"NAMED_VALUE_FLOAT name {name!r} is not at most {NAMED_VALUE_LEN} ASCII characters")
        return self._send(
            mavlink2.MAVLink_named_value_float_message(int(time_boot_ms) & 0xFFFFFFFF, name.encode(), float(value))
        )

    def send_statustext(self, text: str, severity: str = "info") -> bool:
        """One STATUSTEXT (ASCII, cut to the message's 50 characters; the log keeps the full text)."""
        payload = text.encode("ascii", "replace")[:STATUSTEXT_LEN]
        return self._send(mavlink2.MAVLink_statustext_message(SEVERITY[severity], payload, 0, 0))

    def send_attitude(
        self, time_s: float, q: Sequence[float], rates_radps: Sequence[float], covariance: Sequence[float] | None
    ) -> bool:
        """One attitude: ATTITUDE_QUATERNION and, with a ``covariance``, ATTITUDE_QUATERNION_COV, written together
        (one datagram on UDP, which may carry several MAVLink frames: one system call where two cost twice the
        CPU of sending). False when nothing could be sent."""
        conn = self._conn
        writer = conn.mav.file if conn is not None else None
        if not isinstance(writer, _StampedWriter):
            return self._send_attitude(time_s, q, rates_radps, covariance)
        if self._signing is None:  # else pymavlink packs and signs each
            return self._write_frames(writer, self._attitude_frames(conn.mav, time_s, q, rates_radps, covariance))
        try:
            with writer.one_write():
                return self._send_attitude(time_s, q, rates_radps, covariance)
        except OSError as exc:  # the one write failed: neither message went out
            self.counters.sent -= 1 + (covariance is not None)
            self.counters.send_failed += 1 + (covariance is not None)
            self._drop(exc)
            return False

    def _attitude_frames(
        self,
        mav: Any,
        time_s: float,
        q: Sequence[float],
        rates_radps: Sequence[float],
        covariance: Sequence[float] | None,
    ) -> list[bytes]:
        """The frames :meth:`_send_attitude` sends, packed by :class:`_FramePacker` (unsigned)."""
        frames = [_QUATERNION.frame(mav, units.time_boot_ms(time_s) & 0xFFFFFFFF, *q, *rates_radps, *_NO_OFFSET)]
        if covariance is not None:
            frames.append(_QUATERNION_COV.frame(mav, units.time_usec(time_s), *q, *rates_radps, *covariance))
        return frames

    def _write_frames(self, writer: _StampedWriter, frames: list[bytes]) -> bool:
        """Packed frames in one write, counted sent, or failed and the link dropped."""
        try:
            writer.write(b"".join(frames))
        except OSError as exc:
            self.counters.send_failed += len(frames)
            self._drop(exc)
            return False
        self.counters.sent += len(frames)
        return True

    def _send_attitude(
        self, time_s: float, q: Sequence[float], rates_radps: Sequence[float], covariance: Sequence[float] | None
    ) -> bool:
        if not self.send_attitude_quaternion(units.time_boot_ms(time_s), q, rates_radps):
            return False
        if covariance is not None:
            self.send_attitude_quaternion_cov(units.time_usec(time_s), q, rates_radps, covariance)
        return True

    def send_attitude_quaternion(self, time_boot_ms: int, q: Sequence[float], rates_radps: Sequence[float]) -> bool:
        """ATTITUDE_QUATERNION: ``q`` = [w, x, y, z] body -> NED, body rates in rad/s, no offset.

        What it sends has passed the pipeline's output check (finite, unit: :mod:`mavattitude.pipeline`).
        """
        return self._send(
            mavlink2.MAVLink_attitude_quaternion_message(
                int(time_boot_ms) & 0xFFFFFFFF,
                float(q[0]),
                float(q[1]),
                float(q[2]),
                float(q[3]),
                float(rates_radps[0]),
                float(rates_radps[1]),
                float(rates_radps[2]),
                [0.0, 0.0, 0.0, 0.0],
            )
        )
