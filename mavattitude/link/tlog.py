"""Read MAVLink messages of given types from a telemetry log (.tlog) with pymavlink.

A .tlog is what MAVProxy and ground stations record: each packet prefixed with a 64-bit timestamp.
Used by ``mavattitude calibrate`` and ``mavattitude replay``.
"""

from __future__ import annotations

from collections.abc import Iterable, Iterator
from pathlib import Path
from typing import Any

from mavattitude.errors import DataFileError


def read_messages(
    path: str | Path, types: Iterable[str], *, system_id: int | None = None, dialect: str = "ardupilotmega"
) -> Iterator[Any]:
    """Yield the messages of ``types`` (e.g. ``{"RAW_IMU"}``) in log order, optionally from one system.

    Raises :class:`DataFileError` when the file cannot be opened; bad packets are skipped by pymavlink.
    """
    from pymavlink import mavutil

    path = Path(path)
    if not path.is_file():
        raise DataFileError(f"{path}: no such telemetry log")
    wanted = sorted(set(types))
    try:
        log = mavutil.mavlink_connection(str(path), dialect=dialect, robust_parsing=True, notimestamps=False)
    except OSError as exc:
        raise DataFileError(f"{path}: cannot open as a telemetry log: {exc}") from exc
    try:
        while True:
            msg = log.recv_match(type=wanted)
            if msg is None:
                return
            if system_id is not None and msg.get_srcSystem() != system_id:
                continue
            yield msg
    finally:
        log.close()
