"""Telemetry logs (.tlog) read as arrays: a message source.

A .tlog is what MAVProxy and ground stations record: each MAVLink packet (1 or 2, signed or not) preceded
by its receive time (64-bit big-endian µs since 1970). :class:`TlogSource` frames the records once, keeps
the message types its :class:`~mavattitude.link.source.MavlinkDecoder` reads, checks every frame's CRC
(X.25 with pymavlink's ``crc_extra`` per message) and unpacks each type's payloads into columns with numpy,
by pymavlink's own message definitions (field order and struct layout; a MAVLink 2 payload shortened by
its trailing zeros is zero-padded, as pymavlink does). Units are converted by :mod:`mavattitude.sensors.units`.

The source hands its records out two ways, both through the one :class:`~mavattitude.dispatch.Dispatcher`:

- :meth:`TlogSource.recv`: every record as the live link's item, with its sender and the log's receive
  time, for the dispatcher to lock onto the autopilot and route one by one;
- :meth:`TlogSource.streams_for`: the autopilot's IMU, attitude and position rows as
  :class:`~mavattitude.link.logstreams.LogStreams`, the records chosen by :meth:`Dispatcher.follow` (the same
  lock-on and sender rule); what replay feeds :meth:`AttitudePipeline.push_batch`.

A record whose CRC fails is skipped and counted (:attr:`TlogSource.bad_records`); bytes where no record
starts are skipped up to the next record in step with the log (a MAVLink magic after a receive time with the
log's top bytes: :func:`_frame_by_record`), so bytes inserted inside a record cost that record alone; a last
record cut short ends the log. Each is :attr:`TlogSource.damage`.
"""

from __future__ import annotations

import datetime as dt
import functools
import logging
from collections.abc import Iterable, Iterator, Sequence
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np
from numpy.lib.stride_tricks import sliding_window_view
from numpy.typing import NDArray

from mavattitude.errors import DataFileError, SensorError
from mavattitude.link.connection import frame_end
from mavattitude.link.logstreams import (
    Compasses,
    Follower,
    LogStreams,
    autopilot_compass,
    no_such_instance,
    struct_dtype,
)
from mavattitude.link.mavlink2 import mavlink2
from mavattitude.link.source import (
    ATTITUDE_MESSAGES,
    FIRMWARE_PROFILES,
    AutopilotAttitude,
    Heartbeat,
    MavlinkDecoder,
    PositionFix,
    Received,
    Sender,
    Undecodable,
    euler_attitude,
    locks_on,
)
from mavattitude.sensors import units

log = logging.getLogger(__name__)

#: read beside the decoder's messages: every compass, and the parameters saying which one the autopilot uses
COMPASS_TYPES = frozenset({*units.COMPASS_INSTANCES, "PARAM_VALUE"})
CHUNK_MESSAGES = 4096  # messages per recv(): large enough to amortise the call, small enough for progress
TIME_LEN = 8  # the record's receive time before each frame
MAGIC_V1, MAGIC_V2 = 0xFE, 0xFD
HEADER_LEN = {MAGIC_V1: 6, MAGIC_V2: 10}  # magic to message id inclusive
SIGNATURE_LEN = 13
IFLAG_SIGNED = 0x01
MIN_RECORD = TIME_LEN + 3  # enough to read a frame's length and flags
SCAN_BYTES = 1 << 18  # bytes looked through for magics at a time
SNIFF_BYTES = 4096  # what looks_like_tlog reads: a dozen records at least (the longest is 8 + 280 bytes)
PAD = 300  # zero bytes after the data: more than the longest frame, so reading any frame's bytes stays inside


def _crc_table() -> NDArray[np.uint16]:
    """The byte table of MAVLink's X.25 CRC (pymavlink ``x25crc.accumulate``): crc' = crc>>8 ^ T[(crc ^ b) & 0xFF]."""
    b = np.arange(256, dtype=np.int64)
    tmp = (b ^ (b << 4)) & 0xFF
    return ((tmp << 8) ^ (tmp << 3) ^ (tmp >> 4)).astype(np.uint16)


CRC_TABLE = _crc_table()


def _crc_table_16() -> NDArray[np.uint16]:
    """Two bytes at once: ``crc' = T16[crc ^ (b0 | b1 << 8)]``. The byte step is linear and ``b`` enters it as
    ``crc ^ b``, so the two steps depend only on ``crc ^ word``: ``T16[x]`` is ``x`` through two steps of a zero."""
    x = np.arange(1 << 16, dtype=np.uint32)
    for _ in range(2):
        x = (x >> 8) ^ CRC_TABLE[x & 0xFF]
    return x.astype(np.uint16)


CRC_TABLE_16 = _crc_table_16()


def x25_crc(strings: NDArray[np.uint8], extra: NDArray[np.uint8]) -> NDArray[np.uint16]:
    """The CRC of many equally long byte strings at once: ``strings`` (n, length), then each string's ``extra``
    byte (the message's ``crc_extra``). Two bytes a step (little-endian words, one table look-up each)."""
    n, length = strings.shape
    even = length - length % 2
    words = np.ascontiguousarray(np.ascontiguousarray(strings[:, :even]).view("<u2").T)  # (length // 2, n)
    crc = np.full(n, 0xFFFF, dtype=np.uint16)
    for word in words:
        crc = CRC_TABLE_16[crc ^ word]
    for byte in (*strings[:, even:].T, extra):
        crc = (crc >> 8) ^ CRC_TABLE[(crc ^ byte) & 0xFF]
    return crc


def _frame(data: bytes) -> tuple[NDArray[np.int64], int, int, int]:
    """Where each record starts; the bytes skipped (no MAVLink magic where a record should start), the first
    of them (-1: none); and where framing stopped (``len(data)``: at the end)."""
    whole = _frame_whole(data)
    if whole is not None:
        return whole[0], 0, -1, whole[1]
    starts, skipped, first_skip, stop = _frame_by_record(data)
    return np.asarray(starts, dtype=np.int64), skipped, first_skip, stop


def _frame_whole(data: bytes) -> tuple[NDArray[np.int64], int] | None:
    """:func:`_frame` of a log without skipped bytes, at once: the records' starts and where framing stopped.

    The places where a MAVLink magic follows a receive time whose top three bytes are the first record's (they
    change once in 2⁴⁰ µs, 12.7 days; inside a payload the two coincide about once in 2³¹ bytes) are the records
    exactly when the first is at 0 and each one's frame ends where the next begins: framing from 0 goes from
    each to the next. Otherwise (damage, a log across such a change, a coincidence) ``None``: record by record.
    """
    buf = np.frombuffer(data, dtype=np.uint8)
    last = len(buf) - MIN_RECORD  # the last place a record's header can start
    if last < 0:
        return None
    found = []
    for lo in range(0, last + 1, SCAN_BYTES):  # a cache-sized piece at a time: no log-sized temporary arrays
        magic = buf[lo + TIME_LEN : min(lo + SCAN_BYTES, last + 1) + TIME_LEN]
        found.append(lo + np.flatnonzero((magic - np.uint8(MAGIC_V2)) <= MAGIC_V1 - MAGIC_V2))  # FD or FE, wrapping
    start = np.concatenate(found)
    for k in range(3):
        start = start[buf[start + k] == buf[k]]
    if len(start) == 0 or start[0] != 0:
        return None
    v2 = buf[start + TIME_LEN] == MAGIC_V2
    signed = (buf[start + TIME_LEN + 2] & IFLAG_SIGNED).astype(np.int64) * SIGNATURE_LEN
    end = start + buf[start + TIME_LEN + 1] + np.where(v2, 20 + signed, 16)
    if not np.array_equal(end[:-1], start[1:]):
        return None
    if end[-1] > len(buf):  # the last record cut short: framing stops at it
        return start[:-1], int(start[-1])
    return (start, int(end[-1])) if end[-1] > last else None


def _frame_by_record(data: bytes) -> tuple[list[int], int, int, int]:
    """:func:`_frame` one record after the other, skipping damage to the next record.

    A record is where a MAVLink magic follows a receive time whose top three bytes are the last record's (or one
    more: they change once in 2⁴⁰ µs, 12.7 days); the first is one whose next record has its top bytes too.
    Elsewhere (bytes inserted, a record cut short or its length byte hit) the bytes up to the next such place are
    skipped. A magic alone would take the first 0xFD of a payload for a record and frame on from there out of
    step, losing the records after it until one fell in step by chance (half a second of a log, measured)."""
    starts: list[int] = []
    append = starts.append
    n = len(data)
    last = n - MIN_RECORD  # the last place a record's header can start
    ofs = skipped = 0
    first_skip = -1
    marks: tuple[bytes, bytes] | None = None  # the last record's top time bytes, and those one more
    while ofs <= last:  # the hot loop: one pass of it per record
        end = _record_end(data, ofs)
        if end is not None and not (marks and data.startswith(marks[0], ofs)):  # the first record, or none
            in_step = data.startswith(marks[1], ofs) if marks else _starts_run(data, ofs, end)
            end, marks = (end, _marks(data, ofs)) if in_step else (None, marks)
        if end is not None:
            if end > n:
                break
            append(ofs)
            ofs = end
            continue
        resume = _next_record(data, ofs + 1, marks)
        first_skip = ofs if first_skip < 0 else first_skip
        skipped += resume - ofs
        ofs = resume
    return starts, skipped, first_skip, ofs


def _record_end(data: bytes, ofs: int) -> int | None:
    """Where the record at ``ofs`` ends by its frame's header, framed as the live link frames it
    (:func:`~mavattitude.link.connection.frame_end`); None when no MAVLink magic follows its time."""
    start = ofs + TIME_LEN
    return frame_end(data, start) if data[start] in (MAGIC_V1, MAGIC_V2) else None


def _marks(data: bytes, ofs: int) -> tuple[bytes, bytes]:
    """The top three bytes of the receive time at ``ofs``, and those of the next 2⁴⁰ µs."""
    top = int.from_bytes(data[ofs : ofs + 3], "big")
    return data[ofs : ofs + 3], ((top + 1) & 0xFFFFFF).to_bytes(3, "big")


def _starts_run(data: bytes, ofs: int, end: int) -> bool:
    """Whether the record at ``ofs`` (ending at ``end``) is followed in step by another, or ends the log."""
    if end > len(data) - MIN_RECORD:
        return True
    return _record_end(data, end) is not None and data[end : end + 3] in _marks(data, ofs)


def _next_record(data: bytes, start: int, marks: tuple[bytes, bytes] | None) -> int:
    """The next place from ``start`` a record can begin: a MAVLink magic after a receive time in step with
    ``marks`` (any magic before the first record); the log's length when there is none."""
    n = len(data)
    if marks is None:
        found = [p - TIME_LEN for p in (data.find(b"\xfd", start + TIME_LEN), data.find(b"\xfe", start + TIME_LEN))]
        return min([p for p in found if p >= start], default=n)
    p = start
    while p <= n - MIN_RECORD:
        # a window at a time: the next record is usually bytes away, and a mark absent (the next 2⁴⁰ µs's, nearly
        # always) would be looked for through the rest of the log at every damage
        stop = min(p + SCAN_BYTES, n)
        found = [q for q in (data.find(marks[0], p, stop), data.find(marks[1], p, stop)) if q >= 0]
        if not found:
            p = stop - 2  # (a mark across the window's end)
            continue
        p = min(found)
        if p <= n - MIN_RECORD and _record_end(data, p) is not None:
            return p
        p += 1
    return n


def looks_like_tlog(head: bytes) -> bool:
    """Whether ``head``, a file's first bytes (:data:`SNIFF_BYTES`), is a telemetry log's: records framed from
    byte 0 on, at least two of known messages, every one's CRC right. A .tlog has no magic, so this is how one
    saved under another name is known; random bytes pass both tests about once in 10⁸."""
    starts, skipped, _, _ = _frame_by_record(head)
    if skipped or not starts:
        return False
    frames = _Frames(head, np.asarray(starts, dtype=np.int64))
    frames.keep(np.isin(frames.msgid, list(mavlink2.mavlink_map)))
    return len(frames.start) >= 2 and bool(frames.crc_ok().all())


@dataclass
class _Table:
    """The records of one message type that passed their CRC: their place in the log and their columns."""

    name: str
    index: NDArray[np.int64]  # position among the kept records (log order)
    sender: NDArray[np.int64]  # system << 8 | component
    t_rx: NDArray[np.float64]  # the log's receive time, s since 1970
    fields: dict[str, NDArray[Any]]


def _sender(code: int) -> Sender:
    return (code >> 8, code & 0xFF)


class TlogSource:
    """A telemetry log as a message source (see the module docstring).

    With ``first_of``, the decoder reads the first of those IMU messages that the followed autopilot sent
    (the one a dispatcher locks onto: the first autopilot HEARTBEAT, from ``system_id`` if given) after the
    HEARTBEAT it is locked on by, instead of its own: :attr:`decoder` then names the one found. Another
    vehicle's or a ground station's messages in the log do not choose it.
    """

    vehicle: Sender | None = None  # a ground station's log holds every system it heard: lock on as live

    def __init__(
        self,
        path: str | Path,
        decoder: MavlinkDecoder,
        first_of: Sequence[str] = (),
        system_id: int | None = None,
        mag_instance: int | None = None,
    ) -> None:
        self.path = Path(path)
        self.mag_instance = mag_instance  # the compass to replay (None: the autopilot's, else the message's own)
        self.name = str(path)
        self.decoder = decoder
        self.finished = False
        self.damage: str | None = None
        self.bad_records = 0
        self._next = 0
        if not self.path.is_file():
            raise DataFileError(f"{path}: no such telemetry log")
        try:
            data = self.path.read_bytes()
        except OSError as exc:
            raise DataFileError(f"{path}: cannot read: {exc.strerror or exc}") from exc
        self.tables, self.count = self._read(data, first_of, system_id)

    def _read(self, data: bytes, first_of: Sequence[str], system_id: int | None) -> tuple[dict[str, _Table], int]:
        starts, skipped, first_skip, stop = _frame(data)
        if stop < len(data):
            self.damage = f"truncated: the record at byte {stop} is incomplete ({len(data) - stop} bytes)"
        if skipped:
            self.damage = f"damaged: {skipped} byte(s) skipped, the first at byte {first_skip}"
        frames = _Frames(data, starts)
        ids = {
            mavlink2.mavlink_map[i].msgname: i
            for i in frames.ids_of(self.decoder.types | set(first_of) | COMPASS_TYPES)
        }
        frames.keep(np.isin(frames.msgid, list(ids.values())))
        good = frames.crc_ok()
        if first_of:
            self.decoder = self._first_imu(frames, good, [ids[n] for n in first_of if n in ids], system_id)
            ids = {name: i for name, i in ids.items() if name in self.decoder.types | COMPASS_TYPES}
            wanted = np.isin(frames.msgid, list(ids.values()))
            frames.keep(wanted)
            good = good[wanted]
        if not good.all():
            self.bad_records = int(np.count_nonzero(~good))
            first = int(frames.start[~good][0])
            self.damage = self.damage or f"damaged: the record at byte {first} does not decode (CRC)"
        frames.keep(good)
        tables = {name: frames.table(name, msg_id) for name, msg_id in ids.items()}
        return {name: t for name, t in tables.items() if len(t.index)}, len(frames.start)

    def _first_imu(
        self, frames: _Frames, good: NDArray[np.bool_], imu_ids: list[int], system_id: int | None
    ) -> MavlinkDecoder:
        """The decoder for the first good record of ``imu_ids`` that the followed autopilot sent after its
        locking HEARTBEAT (:func:`locks_on`, as the dispatcher locks); its own if none."""
        heartbeat = mavlink2.MAVLINK_MSG_ID_HEARTBEAT
        lock = _lock(_rows(frames.table("HEARTBEAT", heartbeat), good[frames.msgid == heartbeat]), system_id or 0)
        if lock is None:
            return self.decoder
        locked_at, (system, component) = lock
        found = good & np.isin(frames.msgid, imu_ids) & (frames.system == system) & (frames.component == component)
        found[: locked_at + 1] = False
        if not found.any():
            return self.decoder
        return replace(self.decoder, message=mavlink2.mavlink_map[int(frames.msgid[np.argmax(found)])].msgname)

    # --- one by one, as the live link --------------------------------------------------------------

    @functools.cached_property
    def _items(self) -> list[tuple[float, Sender, Any]]:
        """Every record as the live link's item, in log order; built at the first recv."""
        out: list[Any] = [None] * self.count
        for table in self.tables.values():
            senders = [_sender(c) for c in table.sender.tolist()]
            items = self._decode_items(table)
            for i, t_rx, sender, item in zip(table.index.tolist(), table.t_rx.tolist(), senders, items, strict=True):
                out[i] = (t_rx, sender, item)
        return out

    def _decode_items(self, table: _Table) -> list[Any]:
        name, f = table.name, table.fields
        if name == "HEARTBEAT":
            return _heartbeats(table)
        if name in ATTITUDE_MESSAGES:
            return _attitudes(name, f)
        if name in units.POSITION_MESSAGES:
            valid, position = units.decode_position_columns(name, f)
            dates = self._dates(table)
            moving, velocities = (
                units.decode_gps_velocity_columns(f) if name == "GPS_RAW_INT" else (valid & False, [None] * len(valid))
            )
            return [
                PositionFix(units.Position(*p), d, v if m else None) if ok else (v if m else None)
                for ok, p, d, m, v in zip(
                    valid.tolist(), position.tolist(), dates, moving.tolist(), velocities, strict=True
                )
            ]
        if name == self.decoder.message:
            try:
                imu = units.decode_columns(name, f, self.decoder.profile)
            except SensorError as exc:
                return [Undecodable(exc)] * len(table.index)
            return [Undecodable(imu.error(i)) if s is None else s for i, s in enumerate(imu.samples())]
        return [None] * len(table.index)  # SYSTEM_TIME: its date goes with the positions

    @property
    def total(self) -> int:
        """Records the source hands out in all (progress: :attr:`done` of them)."""
        return self.count

    @property
    def done(self) -> int:
        return self._next

    def recv(self, timeout_s: float = 0.0) -> list[Received]:
        items = self._items
        start, stop = self._next, min(self._next + CHUNK_MESSAGES, len(items))
        self._next = stop
        self.finished = stop >= len(items)
        return items[start:stop]

    # --- all at once, for replay ---------------------------------------------------------------------

    def streams_for(self, follower: Follower) -> LogStreams:
        """The rows of the autopilot ``follower`` follows (:meth:`Dispatcher.follow`) as arrays, in SI;
        what it would count (ignored senders, undecodable input) is counted on it."""
        code = np.full(self.count, -1, dtype=np.int64)
        for table in self.tables.values():
            code[table.index] = table.sender
        heartbeats = self.tables.get("HEARTBEAT")
        taken = follower.follow(code, _heartbeat_items(heartbeats) if heartbeats is not None else iter(()))
        return self._streams({name: _rows(t, taken[t.index]) for name, t in self.tables.items()}, follower)

    def _streams(self, tables: dict[str, _Table], follower: Follower) -> LogStreams:
        empty1, empty3 = np.empty(0), np.empty((0, 3))
        t, acc, gyr, mag_t, mag, carried, wrap, repeats = empty1, empty3, empty3, empty1, empty3, None, None, False
        imu_index = np.empty(0, dtype=np.int64)
        imu_table = tables.get(self.decoder.message)
        imu = self._imu_columns(imu_table, follower) if imu_table is not None else None
        if imu is not None:
            ok = ~imu.refused if imu.refused.any() else np.s_[:]  # every row decoded, usually: views, no copies
            imu_index = imu_table.index[ok]  # type: ignore[union-attr]
            t, acc, gyr, wrap = imu.time_s[ok], imu.acc_mps2[ok], imu.gyr_radps[ok], imu.time_wrap_s
            repeats = imu.mag_repeats
            has_mag = imu.has_mag[ok]
            mag_t, mag = t[has_mag], imu.mag_uT[ok][has_mag]
            carried = np.where(has_mag, np.cumsum(has_mag) - 1, -1)  # each message carries its own reading
        att_t, att_q = self._attitudes(tables)
        pos_t, pos, date = self._positions(tables, imu_index, t)
        streams = LogStreams(
            t, acc, gyr, mag_t, mag, att_t, att_q, pos_t, pos, date, wrap, self.damage, carried, repeats
        )
        if "GPS_RAW_INT" in tables:
            streams.gps_t_s, streams.gps_velocity = _velocities(tables["GPS_RAW_INT"], imu_index, t)
        if "PARAM_VALUE" in tables:
            streams.set_parameters(*_parameters(tables["PARAM_VALUE"], imu_index, t))
        streams.mag_instance = units.COMPASS_INSTANCES.get(self.decoder.message)
        return self._with_compasses(streams, tables)

    def _with_compasses(self, streams: LogStreams, tables: dict[str, _Table]) -> LogStreams:
        """``streams`` with every compass the vehicle sent (:data:`~mavattitude.sensors.units.COMPASS_INSTANCES`)
        in its ``compasses``, and the one replayed: ``mag_instance``, else the autopilot's (PARAM_VALUE), else the
        IMU message's own."""
        own = units.COMPASS_INSTANCES.get(self.decoder.message)
        readings = {own: (streams.mag_t_s, streams.mag_uT)} if own is not None and len(streams.mag_t_s) else {}
        for name, instance in units.COMPASS_INSTANCES.items():
            if name in tables and instance not in readings:
                try:
                    imu = units.decode_columns(name, tables[name].fields, self.decoder.profile)
                except SensorError:
                    continue  # a profile that does not read it: that compass is not judged
                keep = imu.has_mag & ~imu.refused
                if keep.any():
                    readings[instance] = (imu.time_s[keep], imu.mag_uT[keep])
        if self.mag_instance is not None and self.mag_instance not in readings and readings:
            raise no_such_instance(self.path, f"compass {self.mag_instance}", "compass", "--mag", readings)
        if own is None or own not in readings or len(readings) < 2:
            return streams
        streams.compasses = Compasses(readings, own)
        if self.mag_instance is not None and self.mag_instance in readings:
            return streams.with_compass(self.mag_instance, f"--mag {self.mag_instance}")
        chosen = autopilot_compass(streams.parameters, list(readings))
        return streams if chosen is None else streams.with_compass(*chosen)

    def _imu_columns(self, table: _Table, follower: Follower) -> units.ImuColumns | None:
        """The vehicle's IMU messages decoded; what cannot be is counted on ``follower``, as the dispatcher counts
        it."""
        try:
            imu = units.decode_columns(table.name, table.fields, self.decoder.profile)
        except SensorError as exc:
            follower.undecodable(exc, len(table.index))
            return None
        refused = int(np.count_nonzero(imu.refused))
        if refused:
            follower.undecodable(imu.error(int(np.flatnonzero(imu.refused)[0])), refused)
        return imu

    def _attitudes(self, tables: dict[str, _Table]) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        found = [(t.index, _attitudes(name, t.fields)) for name, t in tables.items() if name in ATTITUDE_MESSAGES]
        if not found:
            return np.empty(0), np.empty((0, 4))
        order = np.argsort(np.concatenate([index for index, _ in found]), kind="stable")
        attitudes = [a for _, items in found for a in items]
        return (
            np.array([attitudes[i].time_s for i in order], dtype=float),
            np.array([attitudes[i].q for i in order], dtype=float).reshape(-1, 4),
        )

    def _positions(
        self, tables: dict[str, _Table], imu_index: NDArray[np.int64], imu_t: NDArray[np.float64]
    ) -> tuple[NDArray[np.float64], NDArray[np.float64], dt.date | None]:
        """The vehicle's positions, each at the time of the first IMU sample after it; the date of the first."""
        parts = []
        for name in units.POSITION_MESSAGES:
            if name in tables:
                valid, position = units.decode_position_columns(name, tables[name].fields)
                parts.append((tables[name], valid, position))
        if not parts:
            return np.empty(0), np.empty((0, 3)), None
        index = np.concatenate([t.index[v] for t, v, _ in parts])
        order = np.argsort(index, kind="stable")
        index = index[order]
        position = np.concatenate([p[v] for _, v, p in parts])[order]
        pos_t = _at_next_sample(index, imu_index, imu_t)
        t_rx = np.concatenate([t.t_rx[v] for t, v, _ in parts])[order]
        date = self._date_at(int(index[0]), float(t_rx[0])) if len(index) else None
        return pos_t, position, date

    @functools.cached_property
    def _vehicle_times(self) -> tuple[NDArray[np.int64], NDArray[np.float64]]:
        """The records that carry the vehicle's GPS time (any sender, as the decoder takes them), in log order."""
        parts = [
            (t.index, units.utc_time_columns(name, t.fields))
            for name, t in self.tables.items()
            if name in units.UTC_TIME_FIELDS
        ]
        if not parts:
            return np.empty(0, dtype=np.int64), np.empty(0)
        index = np.concatenate([i for i, _ in parts])
        unix_s = np.concatenate([u for _, u in parts])
        keep = ~np.isnan(unix_s)
        order = np.argsort(index[keep], kind="stable")
        return index[keep][order], unix_s[keep][order]

    def _date_at(self, record: int, t_rx: float) -> dt.date | None:
        """The date a position at ``record`` (received at ``t_rx``) is given, as :class:`MavlinkDecoder`
        gives it: the vehicle's latest GPS date at or before it, else the day the log recorded it (``None``
        when the log's own clock is no date either)."""
        index, unix_s = self._vehicle_times
        before = int(np.searchsorted(index, record, side="right")) - 1
        return units.unix_date(float(unix_s[before]) if before >= 0 else t_rx)

    def _dates(self, table: _Table) -> list[dt.date | None]:
        return [self._date_at(i, t) for i, t in zip(table.index.tolist(), table.t_rx.tolist(), strict=True)]


def _at_next_sample(index: NDArray[np.int64], imu_index: NDArray[np.int64], imu_t: NDArray[np.float64]) -> Any:
    """The time of the first IMU sample after each record at ``index``: what it is handed in before."""
    return np.append(imu_t, np.inf)[np.searchsorted(imu_index, index)]


def _velocities(
    table: _Table, imu_index: NDArray[np.int64], imu_t: NDArray[np.float64]
) -> tuple[NDArray[np.float64], list[units.GpsVelocity]]:
    """The receiver's velocities of the GPS_RAW_INT rows that carry one, each at the next IMU sample's time."""
    valid, velocities = units.decode_gps_velocity_columns(table.fields)
    return _at_next_sample(table.index[valid], imu_index, imu_t), [
        v for v, ok in zip(velocities, valid.tolist(), strict=True) if ok
    ]


def _parameters(
    table: _Table, imu_index: NDArray[np.int64], imu_t: NDArray[np.float64]
) -> tuple[NDArray[np.float64], list[str], list[float]]:
    """The PARAM_VALUE messages' parameters, each at the next IMU sample's time."""
    names = [n.split(b"\0")[0].decode("ascii", "replace") for n in table.fields["param_id"].tolist()]
    values = np.asarray(table.fields["param_value"], dtype=float).tolist()
    return _at_next_sample(table.index, imu_index, imu_t), names, values


def _heartbeat_items(table: _Table) -> Iterator[tuple[int, Received]]:
    """The HEARTBEAT records as the live link's items, with their place in the log."""
    rows = zip(table.index.tolist(), table.t_rx.tolist(), table.sender.tolist(), _heartbeats(table), strict=True)
    for i, t_rx, code, heartbeat in rows:
        yield i, (t_rx, _sender(code), heartbeat)


def _heartbeats(table: _Table) -> list[Heartbeat]:
    """The HEARTBEAT records as the live decoder makes them: a flight controller's or not, its firmware's profile."""
    autopilot = _autopilot_heartbeats(table).tolist()
    firmware = table.fields["autopilot"].tolist()
    return [Heartbeat(a, FIRMWARE_PROFILES.get(f)) for a, f in zip(autopilot, firmware, strict=True)]


def _lock(heartbeats: _Table, system_id: int) -> tuple[int, Sender] | None:
    """The record a dispatcher locks on among these HEARTBEATs (:func:`locks_on`) and its sender; None: none."""
    for i, (_, sender, item) in _heartbeat_items(heartbeats):
        if locks_on(item, sender, system_id):
            return i, sender
    return None


def _autopilot_heartbeats(table: _Table) -> NDArray[np.bool_]:
    """Which HEARTBEATs are a flight controller's: the live link's rule on the columns."""
    from mavattitude.link.connection import autopilot_heartbeat

    return autopilot_heartbeat(table.fields["autopilot"], table.fields["type"], table.sender >> 8)


def _attitudes(name: str, f: dict[str, NDArray[Any]]) -> list[AutopilotAttitude]:
    """The autopilot's attitudes, each as the live decoder makes it."""
    t = (f["time_boot_ms"] * 1e-3).tolist()
    if name == "ATTITUDE":
        rpy = zip(t, f["roll"].tolist(), f["pitch"].tolist(), f["yaw"].tolist(), strict=True)
        return [euler_attitude(*row) for row in rpy]
    q = np.column_stack([f["q1"], f["q2"], f["q3"], f["q4"]]).astype(float).tolist()
    return [AutopilotAttitude(ti, tuple(qi)) for ti, qi in zip(t, q, strict=True)]  # type: ignore[arg-type]


def _rows(table: _Table, keep: NDArray[np.bool_]) -> _Table:
    if keep.all():  # the usual case: one vehicle's log
        return table
    return _Table(
        table.name,
        table.index[keep],
        table.sender[keep],
        table.t_rx[keep],
        {k: v[keep] for k, v in table.fields.items()},
    )


class _Frames:
    """The framed records of a log as columns: where each frame starts, its header fields, payload and CRC."""

    def __init__(self, data: bytes, start: NDArray[np.int64]) -> None:
        self.buf = np.frombuffer(data + bytes(PAD), dtype=np.uint8)  # reads past a short last frame find zeros
        self.start = start
        self._header()

    def _at(self, offsets: NDArray[np.int64]) -> NDArray[np.int64]:
        return self.buf[offsets].astype(np.int64)

    def _windows(self, offsets: NDArray[np.int64], length: int) -> NDArray[np.uint8]:
        """The ``length`` bytes from each offset, (n, length)."""
        return sliding_window_view(self.buf, length)[offsets]

    def _header(self) -> None:
        f = self.start + TIME_LEN
        v2 = self._at(f) == MAGIC_V2
        self.v2 = v2
        self.length = self._at(f + 1)
        self.system = np.where(v2, self._at(f + 5), self._at(f + 3))
        self.component = np.where(v2, self._at(f + 6), self._at(f + 4))
        self.msgid = np.where(v2, self._at(f + 7) | self._at(f + 8) << 8 | self._at(f + 9) << 16, self._at(f + 5))
        self.payload = f + np.where(v2, HEADER_LEN[MAGIC_V2], HEADER_LEN[MAGIC_V1])

    def keep(self, mask: NDArray[np.bool_]) -> None:
        for name in ("start", "v2", "length", "system", "component", "msgid", "payload"):
            setattr(self, name, getattr(self, name)[mask])

    @staticmethod
    def ids_of(names: Iterable[str]) -> list[int]:
        return [
            int(getattr(mavlink2, f"MAVLINK_MSG_ID_{n}")) for n in names if hasattr(mavlink2, f"MAVLINK_MSG_ID_{n}")
        ]

    def crc_ok(self) -> NDArray[np.bool_]:
        """Whether each frame's CRC (header after the magic, payload, the message's crc_extra) matches."""
        extra = np.zeros(int(self.msgid.max(initial=0)) + 1, dtype=np.uint8)
        for msg_id in np.unique(self.msgid).tolist():
            extra[msg_id] = mavlink2.mavlink_map[msg_id].crc_extra
        first = self.start + TIME_LEN + 1
        span = self.payload + self.length - first
        stored = self._at(self.payload + self.length) | self._at(self.payload + self.length + 1) << 8
        ok = np.zeros(len(self.start), dtype=bool)
        for n in np.unique(span).tolist():
            rows = np.flatnonzero(span == n)
            ok[rows] = x25_crc(self._windows(first[rows], n), extra[self.msgid[rows]]) == stored[rows]
        return ok

    def table(self, name: str, msg_id: int) -> _Table:
        """The frames of one message type, payloads unpacked by pymavlink's definition of it."""
        rows = np.flatnonzero(self.msgid == msg_id)
        cls = mavlink2.mavlink_map[msg_id]
        size = cls.unpacker.size
        body = self._windows(self.payload[rows], size)
        short = self.length[rows] < size
        if short.any():  # MAVLink 2 drops a payload's trailing zeros: put them back
            body[short] = np.where(np.arange(size) < self.length[rows][short, None], body[short], 0)
        records = np.ascontiguousarray(body).view(struct_dtype(cls.ordered_fieldnames, cls.unpacker.format)).ravel()
        t_us = self._windows(self.start[rows], TIME_LEN).view(">u8").ravel()
        return _Table(
            name,
            rows.astype(np.int64),
            (self.system[rows] << 8) | self.component[rows],
            t_us * 1e-6,
            {field: records[field] for field in cls.ordered_fieldnames},
        )
