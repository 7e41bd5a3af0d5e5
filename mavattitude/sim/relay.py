"""A serial device for the fake vehicle: a pseudo-terminal joined both ways to its UDP port.

A companion computer wired straight to the autopilot's UART reads a tty through pyserial; this gives the
service (and the benchmarks' bare pymavlink loop) such a device, ``/dev/pts/N``, on loopback. A thread of the
calling process carries the bytes; what arrives while nobody reads the device is dropped once the terminal's
buffer is full, as a UART overruns.
"""

from __future__ import annotations

import os
import select
import socket
import threading
from collections.abc import Iterator
from contextlib import contextmanager, suppress

POLL_S = 0.1  # how soon the carrying thread sees the stop


@contextmanager
def serial_relay(port: int) -> Iterator[str]:
    """``with serial_relay(vehicle.port) as device:`` — the path of a tty whose bytes are the UDP port's on
    127.0.0.1 (``port``), and whose writes go to it."""
    master, slave = os.openpty()
    os.set_blocking(master, False)
    stop = threading.Event()

    def carry() -> None:
        with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as sock:
            sock.connect(("127.0.0.1", port))
            while not stop.is_set():
                ready, _, _ = select.select([master, sock], [], [], POLL_S)
                # what nobody reads is dropped, as what the vehicle's port refuses (it has gone: ICMP)
                with suppress(BlockingIOError, ConnectionRefusedError):
                    if sock in ready:
                        os.write(master, sock.recv(65535))
                    if master in ready:
                        sock.send(os.read(master, 65535))

    thread = threading.Thread(target=carry, name="serial relay", daemon=True)
    thread.start()
    try:
        yield os.ttyname(slave)
    finally:
        stop.set()
        thread.join()
        os.close(master)
        os.close(slave)
