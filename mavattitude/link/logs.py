"""Flight logs as message sources: the table of formats a log is recognised by.

:func:`open_log` recognises a log by its first bytes (ULog's magic, DataFlash's FMT header; otherwise a
telemetry log or a DataFlash text log by its name, ``.tlog`` or ``.log``, or by its first records: frames
with their CRCs right, a line that begins ``FMT,``), the rows of :data:`FORMATS`, and returns its reader's
:class:`~mavattitude.link.source.MessageSource`: a DataFlash or ULog reader's
:class:`~mavattitude.link.logstreams.LogStreams` as a :class:`~mavattitude.link.logstreams.StreamSource`, a
telemetry log's :class:`~mavattitude.link.tlog.TlogSource`.

What cannot be used is a :class:`~mavattitude.errors.DataFileError` naming the file and where: unknown
format, no IMU, no magnetometer, a magnetometer reading only zero. A log cut short (the last record
incomplete) or with damaged bytes is read as far as it goes, and the source's ``damage`` says where.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Protocol

from mavattitude.config import Config
from mavattitude.errors import DataFileError
from mavattitude.link.dataflash import looks_like_dataflash_text, read_dataflash, read_dataflash_text
from mavattitude.link.logstreams import Follower, LogStreams, StreamSource
from mavattitude.link.source import MavlinkDecoder, MessageSource
from mavattitude.link.tlog import SNIFF_BYTES, TlogSource, looks_like_tlog
from mavattitude.link.ulog import read_ulog


class LogSource(MessageSource, Protocol):
    """A log file as a message source: its items one by one, or the followed vehicle's rows at once."""

    def streams_for(self, follower: Follower) -> LogStreams: ...


@dataclass(frozen=True)
class LogFormat:
    """One row of :data:`FORMATS`: how a format is recognised, and its reader."""

    name: str
    magic: bytes | None  # the file starts so; None: recognised by ``suffix`` or ``sniff`` (a .tlog has no magic)
    suffix: str  # the usual name's suffix (lower case)
    open: Callable[[Path, Config, int, int | None, Sequence[str], int | None], LogSource]
    sniff: Callable[[bytes], bool] | None = None  # without magic: the file's first bytes are the format's
    #: other programs name their files so too (.log): in a folder, such a file is taken only if ``sniff`` says so
    shared_suffix: bool = False


def _stream_reader(read: Callable[[Path, int, int | None], LogStreams]) -> Callable[..., LogSource]:
    """A reader of arrays (DataFlash, ULog) as the table's ``open``."""
    return lambda path, config, imu_instance, mag_instance, first_of, system_id: StreamSource(
        str(path), read(path, imu_instance, mag_instance)
    )


def _tlog(
    path: Path, config: Config, imu: int, mag: int | None, first_of: Sequence[str], system_id: int | None
) -> LogSource:
    if imu:  # a telemetry log numbers no IMU: each of its IMU messages is one
        raise DataFileError(
            f"{path}: a telemetry log's IMU is its message, not an instance (--imu {imu}): --message SCALED_IMU2 "
            "reads the second IMU, SCALED_IMU3 the third"
        )
    return TlogSource(path, MavlinkDecoder.from_config(config), first_of, system_id, mag)


#: Every log format read, in the order they are tried.
FORMATS = (
    LogFormat("ulog", b"ULog\x01\x12\x35", ".ulg", _stream_reader(read_ulog)),
    # a message header and the FMT message's type: every DataFlash log starts so
    LogFormat("dataflash", b"\xa3\x95\x80", ".bin", _stream_reader(read_dataflash)),
    LogFormat("tlog", None, ".tlog", _tlog, looks_like_tlog),
    LogFormat(
        "dataflash text",
        None,
        ".log",
        _stream_reader(read_dataflash_text),
        looks_like_dataflash_text,
        shared_suffix=True,
    ),
)


#: How the archives and compressed files logs are shared in begin: said, so that the user takes the log out.
PACKED = {
    b"\x1f\x8b": "gzip",
    b"PK\x03\x04": "zip",
    b"\xfd7zXZ\x00": "xz",
    b"BZh": "bzip2",
    b"7z\xbc\xaf\x27\x1c": "7-Zip",
    b"\x28\xb5\x2f\xfd": "zstd",
    b"Rar!\x1a\x07": "RAR",
}


def _head(path: Path) -> bytes:
    try:
        with path.open("rb") as f:
            return f.read(SNIFF_BYTES)
    except OSError as exc:
        raise DataFileError(f"{path}: cannot open: {exc.strerror or exc}") from exc


def detect_format(path: Path) -> LogFormat:
    """The row of :data:`FORMATS` the file's first bytes say it is: its magic; else (a .tlog and a text log have
    none) the format its name says unless its first bytes are another's, else the format they look like."""
    head = _head(path)
    magic = next((f for f in FORMATS if f.magic is not None and head.startswith(f.magic)), None)
    if magic is not None:
        return magic
    sniffed = [f for f in FORMATS if f.sniff is not None and f.sniff(head)]
    named = next((f for f in FORMATS if f.magic is None and path.suffix.lower() == f.suffix), None)
    if named is not None and (named in sniffed or not sniffed):  # a damaged first record is still its format's
        return named
    if sniffed:
        return sniffed[0]
    packed = next((kind for magic, kind in PACKED.items() if head.startswith(magic)), None)
    if path.name.lower().endswith((".csv", ".csv.gz")):
        hint = " (a CSV of samples is for `mavattitude solve`)"
    else:
        hint = f" (a {packed} file: take the log out of it and give that)" if packed else ""
    raise DataFileError(
        f"{path}: not a flight log this reads (byte 0: {head[:4].hex(' ') or 'empty file'}): expected a DataFlash "
        f".bin (starts a3 95 80) or .log (text, lines from 'FMT, '), a ULog .ulg (starts 'ULog') or a telemetry "
        f"log (.tlog: MAVLink frames, each after an 8-byte time){hint}"
    )


def found_in_folder(path: Path) -> bool:
    """Whether a file met in a folder is a log to read: its name's suffix is a format's and, where other programs
    use that suffix too (:attr:`LogFormat.shared_suffix`), its first bytes are the format's."""
    fmt = next((f for f in FORMATS if path.suffix.lower() == f.suffix), None)
    if fmt is None or not path.is_file():
        return False
    if not fmt.shared_suffix or fmt.sniff is None:
        return True
    try:
        return fmt.sniff(_head(path))
    except DataFileError:  # unreadable: not known to be a flight log
        return False


def open_log(
    path: str | Path,
    config: Config,
    imu_instance: int = 0,
    mag_instance: int | None = None,
    *,
    first_of: Sequence[str] = (),
    system_id: int | None = None,
) -> LogSource:
    """The message source of one log file, its format recognised from its content (see the module docstring).

    ``first_of``: a telemetry log's IMU message is the first of these that the autopilot followed (the first
    autopilot HEARTBEAT's, from ``system_id`` if given) sent, rather than the config's
    (:class:`~mavattitude.link.tlog.TlogSource`); other formats name theirs. ``mag_instance``: the compass
    replayed; by default the one the autopilot used where the log says (ArduPilot's COMPASS_USE, _PRIMARY;
    PX4's calibrated selection), every other one in the streams' ``compasses``.
    """
    path = Path(path)
    return detect_format(path).open(path, config, imu_instance, mag_instance, first_of, system_id)
