"""A MAVLink link held in memory: the service without sockets (tests, and anything driving it in-process).

:class:`MemoryLink` is a :class:`~mavattitude.link.connection.MavlinkLink` whose connection is two byte
queues: :meth:`MemoryLink.deliver` puts packed MAVLink bytes in (what a peer would have sent; each call one
datagram), and everything the link sends is kept, packed, in :attr:`MemoryLink.sent_bytes`
(:meth:`MemoryLink.sent` parses it back). Parsing, signing checks, counters and every ``send_*`` encoding
are the real link's; only the socket is missing.
"""

from __future__ import annotations

from collections import deque
from typing import Any

from mavattitude.link.connection import DatagramConnection, Endpoint, MavlinkLink, Message
from mavattitude.link.mavlink2 import mavlink2


class _MemoryConnection(DatagramConnection):
    """The part of a pymavlink connection that :class:`MavlinkLink` drives, over two queues of datagrams."""

    def __init__(self, source_system: int, source_component: int, inbox: deque[bytes], outbox: list[bytes]) -> None:
        self.mav = mavlink2.MAVLink(self, srcSystem=source_system, srcComponent=source_component)
        self.inbox = inbox
        self.outbox = outbox

    def write(self, buf: bytes) -> None:
        self.outbox.append(bytes(buf))

    def select(self, timeout_s: float) -> bool:
        return bool(self.inbox) or self.mav.buf_len() > 0

    def recv(self, n: int | None = None) -> bytes:
        return self.inbox.popleft() if self.inbox else b""

    def close(self) -> None:
        """Nothing to release."""


class MemoryLink(MavlinkLink):
    """A link whose peer is the caller: :meth:`deliver` bytes in, :attr:`sent_bytes` out."""

    def __init__(
        self, *, source_system: int = 1, source_component: int = mavlink2.MAV_COMP_ID_ONBOARD_COMPUTER
    ) -> None:
        self.inbox: deque[bytes] = deque()
        self.sent_bytes: list[bytes] = []
        super().__init__(
            Endpoint("memory", "memory", 0), source_system=source_system, source_component=source_component
        )

    def _connect(self) -> Any:
        return _MemoryConnection(*self._source, self.inbox, self.sent_bytes)

    def deliver(self, *datagrams: bytes) -> None:
        """Queue packed MAVLink bytes for :meth:`recv`, as if they had arrived (one datagram each)."""
        self.inbox.extend(datagrams)

    def sent(self) -> list[Message]:
        """Everything sent so far, parsed back with a fresh MAVLink 2 parser."""
        parser = mavlink2.MAVLink(None)
        parser.robust_parsing = True
        out: list[Message] = []
        for buf in self.sent_bytes:
            out += parser.parse_buffer(buf) or []
        return out
