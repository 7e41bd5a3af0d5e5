"""Telemetry logs (.tlog) read with pymavlink: a message source, and plain message iteration.

A .tlog is what MAVProxy and ground stations record: each MAVLink packet preceded by its receive time
(64-bit big-endian µs since 1970). :class:`TlogSource` hands its messages out decoded, as the live link
does (:mod:`mavattitude.link.source`), with the log's receive time as ``t_rx``.
"""

from __future__ import annotations

import datetime as dt
from collections.abc import Iterable, Iterator
from pathlib import Path
from typing import Any

from mavattitude.errors import DataFileError
from mavattitude.link.source import MavlinkDecoder, Received, Sender

CHUNK_MESSAGES = 4096  # messages per recv(): large enough to amortise the call, small enough for progress


def _open(path: Path, dialect: str) -> Any:
    from pymavlink import mavutil

    if not path.is_file():
        raise DataFileError(f"{path}: no such telemetry log")
    try:
        return mavutil.mavlink_connection(str(path), dialect=dialect, robust_parsing=True, notimestamps=False)
    except Exception as exc:  # pymavlink indexes the file on open, and fails on a damaged one with anything
        raise DataFileError(f"{path}: not a readable telemetry log ({type(exc).__name__}: {exc})") from exc


def read_messages(
    path: str | Path, types: Iterable[str], *, system_id: int | None = None, dialect: str = "ardupilotmega"
) -> Iterator[Any]:
    """Yield the messages of ``types`` (e.g. ``{"RAW_IMU"}``) in log order, optionally from one system.

    Raises :class:`DataFileError` when the file cannot be opened; bad packets are skipped by pymavlink.
    """
    log = _open(Path(path), dialect)
    wanted = sorted(set(types))
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


def _log_date(msg: Any) -> dt.date:
    return dt.datetime.fromtimestamp(msg._timestamp, dt.timezone.utc).date()


class TlogSource:
    """A telemetry log as a message source: the messages the decoder reads, decoded, in log order."""

    vehicle: Sender | None = None  # a ground station's log holds every system it heard: lock on as live

    def __init__(self, path: str | Path, decoder: MavlinkDecoder, dialect: str = "ardupilotmega") -> None:
        self.path = Path(path)
        self.name = str(path)
        self.decoder = MavlinkDecoder(decoder.message, decoder.profile, _log_date)
        self.finished = False
        self.size_bytes = self.path.stat().st_size if self.path.is_file() else 0
        self._log = _open(self.path, dialect)
        self._types = sorted(self.decoder.types)

    @property
    def position_bytes(self) -> int:
        """How far into the file the reader is (for progress)."""
        return int(self._log.f.tell())

    def recv(self, timeout_s: float = 0.0) -> list[Received]:
        out: list[Received] = []
        if self.finished:
            return out
        recv_match, decode, types = self._log.recv_match, self.decoder, self._types
        for _ in range(CHUNK_MESSAGES):
            msg = recv_match(type=types)
            if msg is None:
                self.finished = True
                self._log.close()
                break
            out.append((msg._timestamp, (msg.get_srcSystem(), msg.get_srcComponent()), decode(msg)))
        return out
