"""A minimal scripted MAVLink 2 peer for the link and service tests: pymavlink's v2 dialect over a raw UDP
socket on 127.0.0.1, so the tests see the exact bytes on the wire.

It is independent of the code under test (it does not use :mod:`mavattitude.link`): it packs and parses
with pymavlink's MAVLink 2 protocol object itself, and can sign with a key of its own.
"""

from __future__ import annotations

import socket
import time
from collections.abc import Callable
from typing import Any

from pymavlink.dialects.v20 import ardupilotmega as mavlink2

SIGNING_EPOCH_UNIX_S = 1_420_070_400


class UdpPeer:
    """One MAVLink system on a UDP socket bound to an ephemeral loopback port."""

    def __init__(self, system: int = 1, component: int = 1, key: bytes | None = None, link_id: int = 0) -> None:
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sock.bind(("127.0.0.1", 0))
        self.address: tuple[str, int] = self.sock.getsockname()
        self.mav = mavlink2.MAVLink(None, srcSystem=system, srcComponent=component)
        self.mav.robust_parsing = True
        self.target: tuple[str, int] | None = None
        self.received: list[Any] = []
        self.raw: list[bytes] = []
        if key is not None:
            self.set_key(key, link_id)

    def set_key(self, key: bytes, link_id: int = 0, timestamp: int | None = None) -> None:
        self.mav.signing.secret_key = key
        self.mav.signing.sign_outgoing = True
        self.mav.signing.link_id = link_id
        now = int((time.time() - SIGNING_EPOCH_UNIX_S) * 100_000)
        self.mav.signing.timestamp = now if timestamp is None else timestamp

    def pack(self, msg: Any) -> bytes:
        buf = bytes(msg.pack(self.mav))
        self.mav.seq = (self.mav.seq + 1) % 256
        return buf

    def send(self, msg: Any) -> bytes:
        assert self.target is not None, "set peer.target first"
        buf = self.pack(msg)
        self.sock.sendto(buf, self.target)
        return buf

    def send_raw(self, data: bytes) -> None:
        assert self.target is not None
        self.sock.sendto(data, self.target)

    def heartbeat(self, autopilot: int = mavlink2.MAV_AUTOPILOT_ARDUPILOTMEGA) -> Any:
        mav_type = mavlink2.MAV_TYPE_QUADROTOR if autopilot != mavlink2.MAV_AUTOPILOT_INVALID else 18
        return mavlink2.MAVLink_heartbeat_message(mav_type, autopilot, 0, 0, mavlink2.MAV_STATE_ACTIVE, 3)

    def poll(self, timeout_s: float) -> list[Any]:
        """Datagrams that arrive within ``timeout_s`` (at least one wait), parsed; also kept in ``received``."""
        self.sock.settimeout(timeout_s)
        out: list[Any] = []
        try:
            data, _ = self.sock.recvfrom(65535)
        except TimeoutError:
            return out
        self.sock.setblocking(False)
        while True:
            self.raw.append(data)
            out += self.mav.parse_buffer(data) or []
            try:
                data, _ = self.sock.recvfrom(65535)
            except BlockingIOError:
                break
        self.received += out
        return out

    def wait_for(self, msg_type: str, timeout_s: float = 3.0, condition: Callable[[Any], bool] = lambda m: True) -> Any:
        """The first message of a type (received from now on) meeting ``condition``; fails after ``timeout_s``."""
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline:
            for msg in self.poll(max(deadline - time.monotonic(), 0.001)):
                if msg.get_type() == msg_type and condition(msg):
                    return msg
        raise AssertionError(f"no {msg_type} within {timeout_s} s")

    def find_or_wait(
        self, msg_type: str, timeout_s: float = 3.0, condition: Callable[[Any], bool] = lambda m: True
    ) -> Any:
        """Like :meth:`wait_for`, but a matching message already received counts too."""
        for msg in self.received:
            if msg.get_type() == msg_type and condition(msg):
                return msg
        return self.wait_for(msg_type, timeout_s, condition)

    def close(self) -> None:
        self.sock.close()
