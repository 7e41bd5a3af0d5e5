"""ArduPilot DataFlash logs read into :class:`~.logstreams.LogStreams`: binary (.bin) with pymavlink's DFReader,
and written as text (.log, :class:`_TextReader`).

In a binary log, DFReader parses the formats (FMT, FMTU) and indexes every record by type; the records replay
needs are then unpacked all at once with numpy, with DFReader's own struct layout and multipliers; both kinds
are converted by :mod:`mavattitude.sensors.dataflash_units`. Where the index leaves bytes out (damaged bytes skipped,
a record of an undeclared type where DFReader stops, a last record cut short) is
:attr:`LogStreams.damage`; DFReader's own report of it, printed on the process's stdout/stderr (its fast
indexer is C), is kept off the terminal, so the user sees one line.
"""

from __future__ import annotations

import contextlib
import os
import sys
import tempfile
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np
from numpy.lib.stride_tricks import sliding_window_view
from pymavlink import DFReader

from mavattitude.errors import DataFileError
from mavattitude.link.logstreams import Compasses, LogStreams, autopilot_compass, no_such_instance, struct_dtype
from mavattitude.sensors import dataflash_units as du

OFFSET = "_offset"  # the column of a table holding each record's byte offset: no DataFlash field is named so
TEXT_HEAD_BYTES = 4096  # a text log's FMT lines begin within these (its first line is FMT's own)


class _Index(DFReader.DFReader_binary):
    """DFReader's format parsing and record index, without its clock: the times here are the records' own
    TimeUS/TimeMS, and DFReader's clock set-up parses every record of a log without GPS (9 s for 30 min)."""

    def init_clock(self) -> None:
        self.clock = None


class _Reader:
    """The records of one type of a DataFlash log as columns (:meth:`_columns`, per format), and what is damaged."""

    def __init__(self, path: Path) -> None:
        self.path = path
        self.damage: str | None = None
        self._tables: dict[str, dict[str, np.ndarray]] = {}  # each type read once (MAG is asked for per instance)

    def _columns(self, name: str) -> dict[str, np.ndarray]:
        """Every complete record of ``name`` as columns, scaled (empty if none), and each one's place in the
        file (``OFFSET``: anything increasing in file order)."""
        raise NotImplementedError

    def _note(self, damage: str) -> None:
        """``damage`` said in :attr:`damage`, once."""
        if damage not in (self.damage or ""):
            self.damage = f"{self.damage}; {damage}" if self.damage else damage

    def table(self, name: str) -> dict[str, np.ndarray]:
        """Every complete record of ``name`` as columns (:meth:`_columns`); records with no time since boot of their
        own (a GPS record before ArduPilot 3.1, the oldest MAG and ATT) are given the time of the last IMU record
        before them in the file, as ``TimeUS``."""
        if name not in self._tables:
            columns = self._columns(name)
            if columns and name != "IMU" and not _has_time(columns):
                columns["TimeUS"] = self._file_order_time_s(columns[OFFSET]) * 1e6
            self._tables[name] = columns
        return self._tables[name]

    def _file_order_time_s(self, offsets: np.ndarray) -> np.ndarray:
        """The time of the last IMU record (any instance) before each offset; the first IMU's before them all."""
        imu = self.table("IMU")
        if not imu:
            raise KeyError("no time field, and no IMU record to take one from")
        clock_s = du.time_s(imu)[0]
        before = np.searchsorted(imu[OFFSET], offsets) - 1
        return clock_s[np.maximum(before, 0)]

    def instance(self, base: str, instance: int) -> tuple[str, dict[str, np.ndarray]]:
        """The records of one instance of a sensor (``IMU`` with an ``I`` column, or ``IMU2`` … in old logs)."""
        table = self.table(base)
        name = du.message_name(base, instance, "I" in table)
        if "I" in table:
            keep = table["I"] == instance
            return f"{base}[I={instance}]", {k: v[keep] for k, v in table.items()}
        return name, self.table(name) if name != base else table


class _BinaryReader(_Reader):
    """DFReader's index of one binary log (.bin), each type's records unpacked at once with numpy."""

    def __init__(self, path: Path) -> None:
        super().__init__(path)
        try:
            with _silenced():
                self.df = _Index(str(path), zero_time_base=False)
        except Exception as exc:  # DFReader raises plain Exception (a format char it does not know) on bad input too
            raise DataFileError(f"{path}: not a readable DataFlash log: {exc}") from exc
        self.size = int(self.df.data_len)
        self.damage = _unindexed(self.df, self.size)
        self._bytes = np.frombuffer(self.df.data_map, dtype=np.uint8)

    def _columns(self, name: str) -> dict[str, np.ndarray]:
        if name not in self.df.name_to_id:
            return {}
        fmt = self.df.formats[self.df.name_to_id[name]]
        offsets = np.asarray(self.df.offsets[fmt.type], dtype=np.int64)
        offsets = offsets[offsets + fmt.len <= self.size]  # a record the file's end cuts (said: _unindexed)
        dtype = self._dtype(name, fmt)
        if dtype is None:
            return {}
        body = sliding_window_view(self._bytes, fmt.len - 3)[offsets + 3]  # no (n, len) index array
        records = body.view(dtype).ravel()
        return {
            column: records[column] * mult if mult is not None else records[column]
            for column, mult in zip(fmt.columns, fmt.msg_mults, strict=True)
        } | {OFFSET: offsets}

    def _dtype(self, name: str, fmt: Any) -> np.dtype | None:
        """The record type of ``fmt``; None, said in :attr:`damage`, when its FMT record is damaged (column names
        and layout that do not match, a name empty or given twice, a layout longer or shorter than the record):
        those records are not read."""
        try:
            dtype = struct_dtype(fmt.columns, fmt.msg_struct)
        except (ValueError, KeyError):
            dtype = None
        if dtype is not None and dtype.itemsize == fmt.len - 3 and dtype.names == tuple(fmt.columns):
            return dtype
        self._note(f"the format (FMT) of {name} is damaged: its records are not read")
        return None


class _TextReader(_Reader):
    """A DataFlash log as text (.log): each record a line of comma-separated values, ``IMU, 1234, 0.01, …``, as
    Mission Planner writes a .bin out and early ArduPilot logs were downloaded; pymavlink reads it as
    ``DFReader_text``. The values are written scaled (a ``c`` field as 12.34, not 1234), so no multiplier is
    applied; a record's place in the file (``OFFSET``) is its line number. A line of a type read here whose
    values do not fit its FMT (a count or number that is wrong: damaged, or a last line cut short) is not
    read, and said in :attr:`damage`."""

    def __init__(self, path: Path) -> None:
        super().__init__(path)
        try:
            with path.open("rb") as f:
                head = f.read(TEXT_HEAD_BYTES)
                if not looks_like_dataflash_text(head):  # not read whole: a .log may be any program's, any size
                    raise DataFileError(
                        f"{path}: not a DataFlash log: no format (FMT) line in its first {TEXT_HEAD_BYTES} bytes"
                    )
                self._lines = (head + f.read()).decode("latin-1").splitlines()
        except OSError as exc:
            raise DataFileError(f"{path}: cannot read: {exc.strerror or exc}") from exc
        self._formats: dict[str, tuple[str, list[str]]] = {}  # name: the format's characters, its columns
        self._numbers: dict[str, list[int]] = {}  # name: the lines of its records
        for number, line in enumerate(self._lines):
            name = line.partition(",")[0].strip()
            self._numbers.setdefault(name, []).append(number)
            if name == "FMT":
                self._format(line)
        if not self._formats:
            raise DataFileError(f"{path}: not a DataFlash log: no format (FMT) line in it")

    def _format(self, line: str) -> None:
        """An FMT line, ``FMT, 129, 32, IMU, Qfff, TimeUS,GyrX,GyrY,GyrZ``: the columns are its last field."""
        fields = [f.strip() for f in line.split(",")]
        if len(fields) >= 6 and fields[3]:
            self._formats[fields[3]] = (fields[4], fields[5:])

    def _columns(self, name: str) -> dict[str, np.ndarray]:
        if name not in self._formats or name not in self._numbers:
            return {}
        chars, columns = self._formats[name]
        if len(chars) != len(columns) or len(set(columns)) != len(columns) or "" in columns:
            self._note(f"the format (FMT) of {name} is damaged: its records are not read")
            return {}
        numbers = np.asarray(self._numbers[name], dtype=np.int64)
        lines = [self._lines[k] for k in numbers.tolist()]
        kept = np.flatnonzero([line.count(",") == len(chars) for line in lines])
        try:
            table = _text_table([lines[k] for k in kept], chars, columns)
        except ValueError:  # a value that is not one: which lines, one at a time (a damaged log only)
            kept = kept[[_text_readable(lines[k], chars, columns) for k in kept]]
            table = _text_table([lines[k] for k in kept], chars, columns)
        if len(kept) < len(lines):
            self._note(f"{len(lines) - len(kept)} {name} line(s) damaged: not read")
        return table | {OFFSET: numbers[kept]}


_TEXT_INTEGERS = frozenset("bBhHiIMqQ")  # DataFlash format characters of integers
_TEXT_STRINGS = frozenset("nNZa")  # ... of strings (and a, an array, read as its text)


def _text_table(lines: list[str], chars: str, columns: list[str]) -> dict[str, np.ndarray]:
    """The columns of a text log's records (``lines`` of one type, each with its fields) as the binary reader
    gives them: numbers parsed by numpy's C reader (8 bytes a value), integer fields as integers, strings as
    bytes; ValueError if a value is not one."""
    numeric = [k for k, char in enumerate(chars) if char not in _TEXT_STRINGS]
    values = np.empty((len(lines), len(numeric)))
    if lines and numeric:
        values = np.loadtxt(lines, delimiter=",", usecols=[k + 1 for k in numeric], ndmin=2, comments=None)
    table = {
        columns[k]: _integers(v) if chars[k] in _TEXT_INTEGERS else v for k, v in zip(numeric, values.T, strict=True)
    }
    for k in (k for k, char in enumerate(chars) if char in _TEXT_STRINGS):
        strings = np.array([line.split(",")[k + 1].strip() for line in lines], dtype=str)
        table[columns[k]] = np.char.encode(strings, "latin-1")
    return {c: table[c] for c in columns}


def _integers(values: np.ndarray) -> np.ndarray:
    if not np.all((np.abs(values) < 2.0**63) & (values == np.round(values))):  # also false for NaN
        raise ValueError("an integer field that is not an integer")
    return values.astype(np.int64)


def _text_readable(line: str, chars: str, columns: list[str]) -> bool:
    try:
        _text_table([line], chars, columns)
    except ValueError:
        return False
    return True


def _has_time(columns: dict[str, np.ndarray]) -> bool:
    try:
        du.time_s(columns)
    except KeyError:
        return False
    return True


@contextlib.contextmanager
def _silenced() -> Iterator[None]:
    """File descriptors 1 and 2 to a scratch file while DFReader indexes (its C indexer prints there)."""
    sys.stdout.flush()
    sys.stderr.flush()
    saved = [os.dup(1), os.dup(2)]
    try:
        with tempfile.TemporaryFile() as scratch:
            os.dup2(scratch.fileno(), 1)
            os.dup2(scratch.fileno(), 2)
            yield
    finally:
        os.dup2(saved[0], 1)
        os.dup2(saved[1], 2)
        for fd in saved:
            os.close(fd)


def _unindexed(df: Any, size: int) -> str | None:
    """Where DFReader's index leaves bytes out: skipped (damaged) bytes, the rest of the file unread, or a last
    record the file's end cuts, whatever its type (:meth:`_Reader.table` leaves it out)."""
    spans = []
    for mtype, offsets in enumerate(df.offsets):
        if len(offsets) and mtype in df.formats:
            start = np.asarray(offsets, dtype=np.int64)
            spans.append(np.column_stack([start, start + df.formats[mtype].len, np.full(len(start), mtype)]))
    if not spans:
        return None
    span = np.concatenate(spans)
    span = span[np.argsort(span[:, 0], kind="stable")]
    gaps = np.flatnonzero(span[1:, 0] > span[:-1, 1])
    start, end, mtype = (int(v) for v in span[-1])
    if len(gaps):
        skipped = int(np.sum(span[1:, 0][gaps] - span[:-1, 1][gaps]))
        return f"damaged: {skipped} byte(s) skipped, the first at byte {int(span[gaps[0], 1])}"
    if end > size:
        return f"truncated: the {df.formats[mtype].name} record at byte {start} is incomplete"
    if end < size:
        return f"unreadable from byte {end} ({size - end} bytes are not records DFReader could read)"
    return None


def read_dataflash(path: str | Path, imu_instance: int = 0, mag_instance: int | None = None) -> LogStreams:
    """The IMU (instance ``imu_instance``), magnetometer, ATT, POS and GPS velocity streams of a DataFlash log
    (.bin), SI; the magnetometer ``mag_instance``, by default the one the autopilot used (its PARM records),
    else instance 0, every instance in :attr:`LogStreams.compasses`."""
    return _streams(_BinaryReader(Path(path)), imu_instance, mag_instance)


def read_dataflash_text(path: str | Path, imu_instance: int = 0, mag_instance: int | None = None) -> LogStreams:
    """:func:`read_dataflash` of a DataFlash log written as text (.log)."""
    return _streams(_TextReader(Path(path)), imu_instance, mag_instance)


def looks_like_dataflash_text(head: bytes) -> bool:
    """Whether ``head``, a file's first bytes, is a DataFlash text log's: a line that begins ``FMT,``."""
    return head.startswith(b"FMT,") or b"\nFMT," in head


def _streams(reader: _Reader, imu_instance: int, mag_instance: int | None) -> LogStreams:
    path = reader.path
    empty3 = np.empty((0, 3))
    try:  # a record without a field read here: a log of another layout, or its FMT damaged in the column names
        imu_name, imu_table = reader.instance("IMU", imu_instance)
        readings = _magnetometers(reader)
        parameter_t, names, values = _parameters(reader)
        parameters = dict(zip(names, values, strict=True))  # each at its last value
        chosen = autopilot_compass(parameters, list(readings)) if mag_instance is None else None
        used, why = (mag_instance, f"--mag {mag_instance}") if mag_instance is not None else chosen or (0, None)
        mag_name, mag_table = reader.instance("MAG", used)
        if mag_instance is not None and mag_instance not in readings and readings:
            raise no_such_instance(path, mag_name, "MAG", "--mag", readings)
        if imu_table and len(imu_table["AccX"]):
            t, acc, gyr, wrap = du.imu(imu_table)
        else:
            _refuse_for_others(reader, imu_name)
            t, acc, gyr, wrap = np.empty(0), empty3, empty3, None
        mag_t, mag = du.mag(mag_table) if mag_table and len(mag_table["MagX"]) else (np.empty(0), empty3)
        att = reader.table("ATT")
        att_t, att_q = du.attitude(att) if att else (np.empty(0), np.empty((0, 4)))
        pos_t, positions = _positions(reader)
        gps_t, gps_velocity = _gps_velocity(reader)
        date = _date(reader)
    except KeyError as exc:
        raise DataFileError(f"{path}: a record lacks a field replay reads: {exc}") from exc
    streams = LogStreams(t, acc, gyr, mag_t, mag, att_t, att_q, pos_t, positions, date, wrap, reader.damage)
    streams.check(str(path), imu_name, mag_name)
    streams.gps_t_s, streams.gps_velocity = gps_t, gps_velocity
    streams.set_parameters(parameter_t, names, values)
    streams.mag_instance = used
    if len(readings) > 1 and used in readings:
        streams.compasses = Compasses(readings, used, why)
    return streams


def _gps_velocity(reader: _Reader) -> tuple[np.ndarray, list[Any]]:
    """The first GPS receiver's velocities (instance 0), if the log has them."""
    _, gps = reader.instance("GPS", 0)
    if not gps or not all(k in gps for k in ("Spd", "GCrs", "VZ", "Status", "NSats")):
        return np.empty(0), []
    return du.gps_velocity(gps)


def _gps_tables(reader: _Reader) -> list[dict[str, np.ndarray]]:
    """The GPS receivers' records: GPS (every instance, in new logs by its ``I`` column), and GPS2 in old ones;
    a GPS message of another layout (not ArduPilot's: no Status, Lat, Lng, Alt) is no position, not an error."""
    tables = (reader.table("GPS"), reader.table("GPS2"))
    return [t for t in tables if t and {"Status", *du.POS_FIELDS} <= t.keys()]


def _positions(reader: _Reader) -> tuple[np.ndarray, np.ndarray]:
    """The vehicle's positions in time order: the autopilot's POS records that are a place where it logged
    any, else every GPS receiver's records with a 3D fix."""
    pos = reader.table("POS")
    if pos:
        t, rows = du.position(pos)
        if len(t):
            return t, rows
    fixes = [du.gps_fixes(gps) for gps in _gps_tables(reader)]
    if not fixes:
        return np.empty(0), np.empty((0, 3))
    t, rows = np.concatenate([f[0] for f in fixes]), np.concatenate([f[1] for f in fixes])
    order = np.argsort(t, kind="stable")
    return t[order], rows[order]


def _magnetometers(reader: _Reader) -> dict[int, tuple[np.ndarray, np.ndarray]]:
    """Every MAG instance with readings (an ``I`` column, or MAG, MAG2, MAG3 in old logs): times s, field µT."""
    return {k: du.mag(found) for k, found in _instances(reader, "MAG", "MagX")}


def _instances(reader: _Reader, base: str, column: str) -> Iterator[tuple[int, dict[str, np.ndarray]]]:
    """Each instance of a sensor with records (an ``I`` column, or ``base``, ``base2``, ``base3`` in old logs)."""
    table = reader.table(base)
    for k in sorted(set(table["I"].tolist())) if "I" in table else range(3):
        found = reader.instance(base, k)[1]
        if found and len(found[column]):
            yield k, found


def _refuse_for_others(reader: _Reader, name: str) -> None:
    """The chosen IMU instance has no records: a DataFileError naming those the log has (an autopilot whose
    first IMU is disabled), if any; without any, the streams' own check says so."""
    others = [k for k, _ in _instances(reader, "IMU", "AccX")]
    if others:
        raise no_such_instance(reader.path, name, "IMU", "--imu", others)


def _parameters(reader: _Reader) -> tuple[np.ndarray, list[str], list[float]]:
    """The PARM records: their times (s), names and values, in log order."""
    parm = reader.table("PARM")
    if not parm:
        return np.empty(0), [], []
    names = [n.split(b"\0")[0].decode("ascii", "replace") for n in parm["Name"].tolist()]
    return du.time_s(parm)[0], names, np.asarray(parm["Value"], dtype=float).tolist()


def _date(reader: _Reader) -> Any:
    """The day of the first GPS record with a 3D fix and a GPS week, from any receiver."""
    return next((d for d in map(du.first_gps_date, _gps_tables(reader)) if d is not None), None)
