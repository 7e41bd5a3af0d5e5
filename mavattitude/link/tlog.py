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
MAGIC_V2 = 0xFD
SIGNATURE_LEN = 13


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
    """A telemetry log as a message source: the messages the decoder reads, decoded, in log order.

    pymavlink's memory-mapped reader indexes the log by message type; only the records of the types the
    decoder reads are then decoded (CRC checked) by pymavlink's MAVLink 2 parser, one by one, without the
    per-message bookkeeping of its connection objects (a copy of every message per type and system).
    A record whose CRC fails is skipped and counted; a last record cut short is :attr:`damage`.
    """

    vehicle: Sender | None = None  # a ground station's log holds every system it heard: lock on as live

    def __init__(self, path: str | Path, decoder: MavlinkDecoder, dialect: str = "ardupilotmega") -> None:
        self.path = Path(path)
        self.name = str(path)
        self.decoder = MavlinkDecoder(decoder.message, decoder.profile, _log_date)
        self.finished = False
        self.damage: str | None = None
        self.bad_records = 0
        log = _open(self.path, dialect)
        self._data = log.data_map if getattr(log, "data_map", None) is not None else b""
        self.size_bytes = len(self._data)
        offsets = getattr(log, "offsets", {})
        wanted = [log.name_to_id[name] for name in self.decoder.types if name in getattr(log, "name_to_id", {})]
        self._offsets = sorted(o for msg_id in wanted for o in offsets[msg_id])
        self._mav = log.mav
        self._log = log
        self._next = 0

    @property
    def total(self) -> int:
        """Records the source hands out in all (progress: :attr:`done` of them)."""
        return len(self._offsets)

    @property
    def done(self) -> int:
        return self._next

    def recv(self, timeout_s: float = 0.0) -> list[Received]:
        out: list[Received] = []
        data, decode_frame, decode = self._data, self._mav.decode, self.decoder
        stop = min(self._next + CHUNK_MESSAGES, len(self._offsets))
        for ofs in self._offsets[self._next : stop]:
            end = ofs + _frame_end(data, ofs)
            if end > len(data):
                self.damage = f"truncated: the record at byte {ofs} is incomplete"
                continue
            try:
                msg = decode_frame(bytearray(data[ofs + 8 : end]))
            except Exception as exc:  # pymavlink raises MAVError (and struct errors) on a damaged frame
                self._bad(ofs, exc)
                continue
            t = int.from_bytes(data[ofs : ofs + 8], "big") * 1e-6
            msg._timestamp = t
            out.append((t, (msg.get_srcSystem(), msg.get_srcComponent()), decode(msg)))
        self._next = stop
        if stop >= len(self._offsets) and not self.finished:
            self.finished = True
            self._log.close()
        return out

    def _bad(self, ofs: int, exc: Exception) -> None:
        self.bad_records += 1
        if self.damage is None:
            self.damage = f"damaged: the record at byte {ofs} does not decode ({exc})"


def _frame_end(data: Any, ofs: int) -> int:
    """The length of the record at ``ofs``: the 8-byte time, then a MAVLink 2 (0xFD) or 1 (0xFE) frame."""
    if data[ofs + 8] == MAGIC_V2:
        return 8 + 12 + data[ofs + 9] + (SIGNATURE_LEN if data[ofs + 10] & 1 else 0)
    return 8 + 8 + data[ofs + 9]
