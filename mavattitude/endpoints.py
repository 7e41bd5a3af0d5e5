"""MAVLink connection strings, checked and split: what ``link.connect`` and the commands' links accept.

Pure string handling (no pymavlink), so that the config can check a connection string when it is read, as it
checks every other value, rather than the service failing on it at start.
"""

from __future__ import annotations

from dataclasses import dataclass

from mavattitude.errors import LinkError


@dataclass(frozen=True)
class Endpoint:
    """A parsed connection string."""

    kind: str  # udpin | udpout | tcp | tcpin | serial
    address: str  # HOST:PORT, or the serial device
    baud: int


def parse_connect(connect: str, baud: int = 115200) -> Endpoint:
    """Check a connection string and split it; a malformed one is a :class:`LinkError` naming the forms."""
    kind, sep, rest = connect.partition(":")
    if sep and kind in ("udpin", "udpout", "udp", "tcp", "tcpin"):
        host, sep, port_text = rest.rpartition(":")
        listening = kind in ("udpin", "udp", "tcpin")
        if not sep or not host or not port_text.isdigit() or not (listening or int(port_text) > 0):
            raise LinkError(f"connection string {connect!r}: expected {kind}:HOST:PORT")
        if int(port_text) > 65535:
            raise LinkError(f"connection string {connect!r}: port {port_text} is out of range 0-65535")
        return Endpoint("udpin" if kind == "udp" else kind, f"{host}:{port_text}", baud)
    if connect.startswith("/") or connect.upper().startswith("COM"):
        device, sep, baud_text = connect.partition(",")
        if sep and not baud_text.isdigit():
            raise LinkError(f"connection string {connect!r}: expected DEVICE or DEVICE,BAUD")
        return Endpoint("serial", device, int(baud_text) if sep else baud)
    raise LinkError(
        f"connection string {connect!r}: expected udpin:HOST:PORT, udpout:HOST:PORT, tcp:HOST:PORT, "
        "tcpin:HOST:PORT or a serial device such as /dev/ttyACM0[,BAUD]"
    )
