"""PX4 ULog files (.ulg) read with pyulog, into :class:`~mavattitude.link.logstreams.LogStreams`.

Both topic layouts are read: the current one (``sensor_combined`` for the IMU, ``vehicle_magnetometer``
for the magnetometer) and the old one (the magnetometer inside ``sensor_combined``, ``magnetometer_ga``).
Units by :mod:`mavattitude.sensors.ulog_units`. pyulog reads a damaged or cut-off file as far as it can; it
says so of a damaged one (``file_corruption``) but stops at a cut-off one's incomplete last message without a
word, so the messages' own sizes are walked to find it (:func:`cut_at`). Either becomes
:attr:`LogStreams.damage`.
"""

from __future__ import annotations

import contextlib
import datetime as dt
import io
import logging
import struct
from pathlib import Path
from typing import Any

import numpy as np

from mavattitude.errors import DataFileError
from mavattitude.link.logstreams import Compasses, LogStreams, no_such_instance
from mavattitude.sensors import ulog_units as uu
from mavattitude.sensors.units import GAUSS_UT

TOPICS = [
    "sensor_combined",
    "sensor_mag",
    "sensor_selection",
    "vehicle_magnetometer",
    "vehicle_attitude",
    "vehicle_gps_position",
    "vehicle_global_position",
]
log = logging.getLogger(__name__)

FILE_HEADER_BYTES = 16  # "ULog", its version and its start time; then every message: size (u16), type (u8), payload
_MESSAGE_HEADER = struct.Struct("<HB")
_DEFINITIONS = b"IMFPQB"  # info, multiple info, format, parameter, parameter default, flag bits
_DATA_STARTS = b"ALC"  # a subscription, a logged string, a tagged logged string
_CORRUPT_SIZE = 10_000  # pyulog takes a larger message for corruption


def _open(path: Path, data: bytes) -> Any:
    """pyulog's reading of the file (``data``, its bytes); what it prints of a damaged one (on stdout, where a
    command's table goes) is logged at debug level, the damage itself said by :attr:`LogStreams.damage`. A file
    whose definitions run to its end holds no data, and pyulog may never return from it: refused first."""
    from pyulog import ULog

    if data_section_at(data) is None:
        raise DataFileError(f"{path}: not a readable ULog file: it ends inside its definitions, before any data")
    said = io.StringIO()
    try:
        with contextlib.redirect_stdout(said):
            return ULog(str(path), TOPICS)
    except Exception as exc:  # pyulog raises plain Exception (and struct, index, decode errors) on bad input
        raise DataFileError(f"{path}: not a readable ULog file: {exc}") from exc
    finally:
        for line in said.getvalue().splitlines():
            log.debug("pyulog: %s", line)


def _topic(ulog: Any, name: str, instance: int = 0) -> dict[str, np.ndarray] | None:
    for data in ulog.data_list:
        if data.name == name and data.multi_id == instance and len(data.data["timestamp"]):
            return data.data
    return None


def read_ulog(path: str | Path, imu_instance: int = 0, mag_instance: int | None = None) -> LogStreams:
    """The IMU, magnetometer (instance ``mag_instance``), attitude, position and GPS velocity streams of a ULog
    file, SI."""
    path = Path(path)
    data = path.read_bytes()
    ulog = _open(path, data)
    asked, mag_instance = mag_instance, mag_instance or 0
    empty3 = np.empty((0, 3))
    combined = _topic(ulog, "sensor_combined", imu_instance)
    vehicle_mag = _topic(ulog, "vehicle_magnetometer", mag_instance)
    imus = [d.multi_id for d in ulog.data_list if d.name == "sensor_combined" and len(d.data["timestamp"])]
    if combined is None and imus:
        raise no_such_instance(path, f"sensor_combined[{imu_instance}]", "sensor_combined", "--imu", imus)
    # the instances there are: vehicle_magnetometer's, or an old log's one in sensor_combined
    present = [d.multi_id for d in ulog.data_list if d.name == "vehicle_magnetometer" and len(d.data["timestamp"])]
    present = present or ([0] if combined is not None and f"{uu.MAG_FIELD}[0]" in combined else [])
    if asked is not None and asked not in present and present:
        raise no_such_instance(path, f"vehicle_magnetometer[{asked}]", "magnetometer", "--mag", present)
    try:
        t, acc, gyr = uu.imu(combined) if combined is not None else (np.empty(0), empty3, empty3)
        if vehicle_mag is not None:
            mag_name, (mag_t, mag) = f"vehicle_magnetometer[{mag_instance}]", uu.mag(vehicle_mag)
        elif combined is not None and f"{uu.MAG_FIELD}[0]" in combined:
            mag_name, (mag_t, mag) = f"sensor_combined.{uu.MAG_FIELD}", uu.combined_mag(combined)
        else:
            mag_name, mag_t, mag = "vehicle_magnetometer", np.empty(0), empty3
        vehicle_attitude = _topic(ulog, "vehicle_attitude")
        att_t, att_q = (
            uu.attitude(vehicle_attitude) if vehicle_attitude is not None else (np.empty(0), np.empty((0, 4)))
        )
        pos_t, positions, date = _positions(ulog)
        gps = _topic(ulog, "vehicle_gps_position")
        gps_t, gps_velocity = uu.gps_velocity(gps) if gps is not None else (np.empty(0), [])
    except KeyError as exc:
        raise DataFileError(f"{path}: a topic lacks a field replay reads: {exc}") from exc
    damage = "damaged: pyulog skipped what it could not read" if ulog.file_corruption else None
    if damage is None and not ulog.has_data_appended:  # appended data is placed by offsets, not walked to
        damage = cut_at(data)
    streams = LogStreams(t, acc, gyr, mag_t, mag, att_t, att_q, pos_t, positions, date, None, damage)
    streams.check(str(path), f"sensor_combined[{imu_instance}]", mag_name)
    streams.gps_t_s, streams.gps_velocity = gps_t, gps_velocity
    streams.compasses = _compasses(ulog)
    streams.set_parameters(*_parameters(ulog, float(t[0]) if len(t) else 0.0))
    return streams


def _parameters(ulog: Any, start_s: float) -> tuple[np.ndarray, list[str], list[float]]:
    """The parameters: times (s), names and values; the initial ones at ``start_s``, then each change at its time."""
    records = [(start_s, k, v) for k, v in ulog.initial_parameters.items()]
    records += [(stamp * uu.TIMESTAMP_S, k, v) for stamp, k, v in ulog.changed_parameters]
    return np.array([r[0] for r in records]), [r[1] for r in records], [float(r[2]) for r in records]


def data_section_at(data: bytes) -> int | None:
    """Where a ULog file's data section starts (its first subscription or logged string), walking its
    definitions as pyulog does (1.3): message by message, one byte on from a header that cannot be one (type 0,
    size 0 or over 10 000 bytes) unless it is a definition. None when the walk reaches the end first. pyulog
    does not stop there: from such a header running past the end it seeks back before it and walks to it again,
    forever."""
    pos, end = FILE_HEADER_BYTES, len(data)
    while pos + _MESSAGE_HEADER.size <= end:
        size, kind = _MESSAGE_HEADER.unpack_from(data, pos)
        if kind in _DATA_STARTS:
            return pos
        if kind not in _DEFINITIONS and (kind == 0 or size == 0 or size > _CORRUPT_SIZE):
            if pos + _MESSAGE_HEADER.size + size > end:
                return None
            pos += 1
        else:
            pos += _MESSAGE_HEADER.size + size
    return None


def cut_at(data: bytes) -> str | None:
    """Where a ULog file ends inside its last message, from each message's size (None: it ends on a message's
    end). ~0.1 s for 20 MB."""
    unpack, pos, end = _MESSAGE_HEADER.unpack_from, FILE_HEADER_BYTES, len(data)
    while pos + _MESSAGE_HEADER.size <= end:
        after = pos + _MESSAGE_HEADER.size + unpack(data, pos)[0]
        if after > end:
            break
        pos = after
    return None if pos == end else f"truncated: the message at byte {pos} is incomplete ({end - pos} bytes)"


def _compasses(ulog: Any) -> Compasses | None:
    """Every ``sensor_mag`` instance, its CAL_MAGn offsets and scales applied (the rotation not), where there are
    several; the one PX4 selected (``sensor_selection``'s device, else ``CAL_MAG_PRIME``) is the replayed one,
    whose calibrated field ``vehicle_magnetometer`` holds."""
    params = ulog.initial_parameters
    readings, devices, disabled = {}, {}, {}
    for data in ulog.data_list:
        if data.name == "sensor_mag" and len(data.data["timestamp"]):
            device = int(data.data["device_id"][-1])
            devices[device] = data.multi_id
            readings[data.multi_id] = (uu.times_s(data.data), _calibrated(data.data, device, params))
            slot = _calibration_slot(device, params)
            if slot is not None and params.get(f"CAL_MAG{slot}_EN") == 0:
                disabled[data.multi_id] = f"CAL_MAG{slot}_EN"
    if len(readings) < 2:
        return None
    selection = _topic(ulog, "sensor_selection")
    if selection is not None and int(selection["mag_device_id"][-1]) in devices:
        device, said = int(selection["mag_device_id"][-1]), "sensor_selection's mag_device_id"
    else:
        device, said = int(params.get("CAL_MAG_PRIME", -1)), "CAL_MAG_PRIME"
    if device not in devices:
        why = "vehicle_magnetometer (the log does not say which sensor it is)"
        return Compasses(readings, min(readings), why, disabled)
    why = f"the autopilot's: {said} {device} (its field: vehicle_magnetometer)"
    return Compasses(readings, devices[device], why, disabled)


def _calibration_slot(device: int, params: dict[str, Any]) -> int | None:
    """The n of the CAL_MAGn parameters that hold the calibration of the magnetometer ``device`` (CAL_MAGn_ID)."""
    return next((n for n in range(4) if params.get(f"CAL_MAG{n}_ID") == device), None)


def _calibrated(topic: dict[str, np.ndarray], device: int, params: dict[str, Any]) -> np.ndarray:
    """A ``sensor_mag`` instance's readings (µT) with the offsets and scales of the CAL_MAGn matching its device."""
    raw = np.column_stack([topic["x"], topic["y"], topic["z"]]).astype(float)
    slot = _calibration_slot(device, params)
    if slot is not None:
        offset = np.array([params.get(f"CAL_MAG{slot}_{a}OFF", 0.0) for a in "XYZ"])
        scale = np.array([params.get(f"CAL_MAG{slot}_{a}SCALE", 1.0) for a in "XYZ"])
        raw = (raw - offset) * scale
    return raw * GAUSS_UT


def _positions(ulog: Any) -> tuple[np.ndarray, np.ndarray, dt.date | None]:
    gps = _topic(ulog, "vehicle_gps_position")
    if gps is not None:
        t, rows = uu.gps_position(gps)
        utc = np.asarray(gps.get("time_utc_usec", np.zeros(0)))
        return t, rows, next(filter(None, map(uu.utc_date, utc[utc > 0].tolist())), None)
    fused = _topic(ulog, "vehicle_global_position")
    if fused is not None:
        return (*uu.global_position(fused), None)
    return np.empty(0), np.empty((0, 3)), None
