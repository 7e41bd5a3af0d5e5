"""Synthetic flight logs written the way autopilots write them: DataFlash (.bin) records, for tests and benchmarks.

:func:`write_dataflash` lays out FMT records and then the records of each message type in time order,
byte for byte as ArduPilot does (``A3 95 <type>`` then the packed fields, little-endian), in the layout of
an ArduPilot era (:data:`LAYOUTS`: today's, 3.3's, 3.2's and 3.0's FMT records, as the firmware wrote
them). Values are given in SI and stored in the logged units of
:mod:`mavattitude.sensors.dataflash_units` (MAG in milligauss, ATT in degrees, positions in 1e-7 °),
encoded with the multipliers of pymavlink's DFReader.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from numpy.typing import NDArray
from pymavlink import DFReader

from mavattitude.estimation.conventions import (
    Array,
    quat_conjugate,
    quat_from_euler,
    quat_multiply,
    rotate_ned_to_body,
    rotvec_from_quat,
)
from mavattitude.sensors import dataflash_units as du
from mavattitude.sensors.units import STANDARD_GRAVITY_MPS2

HEADER = b"\xa3\x95"
FMT_TYPE = 0x80
_NUMPY = {"Q": "<u8", "I": "<u4", "i": "<i4", "B": "u1", "H": "<u2", "h": "<i2", "f": "<f4", "16s": "S16"}

#: Every layout written, as the ArduPilot of its era logged the records replay reads: (type, name, format
#: characters, columns) of each, from ArduPilot's LogStructure.h of that release. ``4.1``: today's (TimeUS; IMU,
#: MAG and GPS with an instance column ``I``; POS; ATT written as floats). ``3.3``: TimeUS, IMU2, MAG2 and GPS2
#: as messages of their own, GPS with GMS/GWk; no POS. ``3.2``: TimeMS (ms since boot); GPS's TimeMS is the ms
#: of the GPS week and its time since boot ``T``. ``3.0``: as 3.2, and the GPS record has no time since boot.
LAYOUTS: dict[str, tuple[tuple[int, str, str, str], ...]] = {
    "4.1": (
        (129, "IMU", "QBffffff", "TimeUS,I,GyrX,GyrY,GyrZ,AccX,AccY,AccZ"),
        (130, "MAG", "QBhhh", "TimeUS,I,MagX,MagY,MagZ"),
        (131, "ATT", "Qffffff", "TimeUS,DesRoll,Roll,DesPitch,Pitch,DesYaw,Yaw"),
        (132, "POS", "QLLf", "TimeUS,Lat,Lng,Alt"),
        (135, "GPS", "QBBIHBcLLeffffB", "TimeUS,I,Status,GMS,GWk,NSats,HDop,Lat,Lng,Alt,Spd,GCrs,VZ,Yaw,U"),
    ),
    "3.3": (
        (129, "IMU", "QffffffIIfBB", "TimeUS,GyrX,GyrY,GyrZ,AccX,AccY,AccZ,ErrG,ErrA,Temp,GyHlt,AcHlt"),
        (133, "IMU2", "QffffffIIfBB", "TimeUS,GyrX,GyrY,GyrZ,AccX,AccY,AccZ,ErrG,ErrA,Temp,GyHlt,AcHlt"),
        (130, "MAG", "QhhhhhhhhhB", "TimeUS,MagX,MagY,MagZ,OfsX,OfsY,OfsZ,MOfsX,MOfsY,MOfsZ,Health"),
        (134, "MAG2", "QhhhhhhhhhB", "TimeUS,MagX,MagY,MagZ,OfsX,OfsY,OfsZ,MOfsX,MOfsY,MOfsZ,Health"),
        (131, "ATT", "QccccCCCC", "TimeUS,DesRoll,Roll,DesPitch,Pitch,DesYaw,Yaw,ErrRP,ErrYaw"),
        (135, "GPS", "QBIHBcLLeeEefB", "TimeUS,Status,GMS,GWk,NSats,HDop,Lat,Lng,RAlt,Alt,Spd,GCrs,VZ,U"),
        (136, "GPS2", "QBIHBcLLeeEefB", "TimeUS,Status,GMS,GWk,NSats,HDop,Lat,Lng,RAlt,Alt,Spd,GCrs,VZ,U"),
    ),
    "3.2": (
        (131, "IMU", "IffffffIIf", "TimeMS,GyrX,GyrY,GyrZ,AccX,AccY,AccZ,ErrG,ErrA,Temp"),
        (135, "IMU2", "IffffffIIf", "TimeMS,GyrX,GyrY,GyrZ,AccX,AccY,AccZ,ErrG,ErrA,Temp"),
        (141, "MAG", "Ihhhhhhhhh", "TimeMS,MagX,MagY,MagZ,OfsX,OfsY,OfsZ,MOfsX,MOfsY,MOfsZ"),
        (142, "MAG2", "Ihhhhhhhhh", "TimeMS,MagX,MagY,MagZ,OfsX,OfsY,OfsZ,MOfsX,MOfsY,MOfsZ"),
        (136, "ATT", "IccccCCCC", "TimeMS,DesRoll,Roll,DesPitch,Pitch,DesYaw,Yaw,ErrRP,ErrYaw"),
        (130, "GPS", "BIHBcLLeeEefI", "Status,TimeMS,Week,NSats,HDop,Lat,Lng,RelAlt,Alt,Spd,GCrs,VZ,T"),
        (132, "GPS2", "BIHBcLLeEefIBI", "Status,TimeMS,Week,NSats,HDop,Lat,Lng,Alt,Spd,GCrs,VZ,T,DSc,DAg"),
    ),
    "3.0": (
        (131, "IMU", "Iffffff", "TimeMS,GyrX,GyrY,GyrZ,AccX,AccY,AccZ"),
        (135, "IMU2", "Iffffff", "TimeMS,GyrX,GyrY,GyrZ,AccX,AccY,AccZ"),
        (141, "MAG", "Ihhhhhhhhh", "TimeMS,MagX,MagY,MagZ,OfsX,OfsY,OfsZ,MOfsX,MOfsY,MOfsZ"),
        (142, "MAG2", "Ihhhhhhhhh", "TimeMS,MagX,MagY,MagZ,OfsX,OfsY,OfsZ,MOfsX,MOfsY,MOfsZ"),
        (136, "ATT", "IccccCC", "TimeMS,RollIn,Roll,PitchIn,Pitch,YawIn,Yaw"),
        (130, "GPS", "BIHBcLLeeEe", "Status,TimeMS,Week,NSats,HDop,Lat,Lng,RelAlt,Alt,Spd,GCrs"),
    ),
}


@dataclass(frozen=True)
class _Format:
    type: int
    name: str
    format: str
    columns: tuple[str, ...]

    @property
    def dtype(self) -> np.dtype:
        codes = (DFReader.FORMAT_TO_STRUCT[c][0] for c in self.format)  # c, e, L, ...: their struct type
        return np.dtype([(name, _NUMPY[code]) for name, code in zip(self.columns, codes, strict=True)])

    def stored(self, column: str, values: Array) -> Array:
        """SI-ish ``values`` (DFReader's units, after its multipliers) as this column's logged integers or floats."""
        code = self.format[self.columns.index(column)]
        if code == "N":  # a name: its bytes
            return np.array([str(v).encode() for v in values], dtype="S16")
        mult = DFReader.FORMAT_TO_STRUCT[code][1]
        scaled = np.asarray(values, dtype=float) / (mult or 1.0)
        return scaled if code == "f" else np.round(scaled)

    def fmt_record(self) -> bytes:
        body = np.zeros(1, dtype=[("t", "u1"), ("len", "u1"), ("name", "S4"), ("fmt", "S16"), ("cols", "S64")])
        body[0] = (
            self.type,
            3 + self.dtype.itemsize,
            self.name.encode(),
            self.format.encode(),
            ",".join(self.columns).encode(),
        )
        return HEADER + bytes([FMT_TYPE]) + body.tobytes()


@dataclass
class SensorLog:
    """What to write, SI, vehicle clock: IMU rows, magnetometer rows, optional ATT and position rows (POS, or
    GPS records with a 3D fix where the layout has no POS), and the GPS time at vehicle time 0 (s since the GPS
    epoch; None: no GPS time, week 0)."""

    imu_t_s: Array
    acc_mps2: Array
    gyr_radps: Array
    mag_t_s: Array
    mag_uT: Array
    attitude_t_s: Array | None = None
    attitude_rpy_rad: Array | None = None
    position_t_s: Array | None = None
    position: Array | None = None  # latitude °, longitude °, altitude m
    gps_time_s: float | None = None


def _formats(layout: str) -> dict[str, _Format]:
    try:
        rows = LAYOUTS[layout]
    except KeyError:
        raise ValueError(f"layout {layout!r}: expected one of {', '.join(LAYOUTS)}") from None
    return {name: _Format(t, name, fmt, tuple(cols.split(","))) for t, name, fmt, cols in rows}


def _records(fmt: _Format, t_s: Array, columns: dict[str, Array], instance: int = 0) -> tuple[Array, NDArray]:
    """Records of ``fmt`` at vehicle times ``t_s``: its time since boot (TimeUS, TimeMS, or an old GPS's T),
    its instance, and ``columns`` (DFReader's units); the others zero."""
    rows = np.zeros(len(t_s), dtype=fmt.dtype)
    boot = "T" if "Week" in fmt.columns else fmt.columns[0]  # an old GPS record's TimeMS is GPS time
    if boot in fmt.columns and boot in du.TIME_FIELDS:
        rows[boot] = np.round(t_s / du.TIME_FIELDS[boot][0])
    if "I" in fmt.columns:
        rows["I"] = instance
    for name, values in columns.items():
        rows[name] = fmt.stored(name, values)
    raw = np.empty((len(t_s), 3 + fmt.dtype.itemsize), dtype=np.uint8)
    raw[:, :2] = np.frombuffer(HEADER, dtype=np.uint8)
    raw[:, 2] = fmt.type
    raw[:, 3:] = rows.view(np.uint8).reshape(len(t_s), fmt.dtype.itemsize)
    return t_s, raw


def write_dataflash(
    path: str | Path,
    log: SensorLog,
    layout: str = "4.1",
    instances: int = 1,
    mags: Sequence[Array] = (),
    parameters: Mapping[str, float] | None = None,
    parameter_changes: Sequence[tuple[float, str, float]] = (),
) -> Path:
    """Write ``log`` as a DataFlash file in ``layout`` (:data:`LAYOUTS`); with ``instances`` > 1 every IMU and
    MAG row is logged again for instance 1, … (the copies scaled by 1 + instance/100, so a reader that takes
    the wrong one is seen), and the positions by a second GPS receiver where the layout has one. ``mags``:
    instance k's magnetometer readings (µT, at ``log.mag_t_s``) instead of ``log.mag_uT``, for k below its
    length; ``parameters``: PARM records (name → value) at the log's start, as the autopilot logs them, and
    ``parameter_changes`` more at their times, ``(t_s, name, value)`` (a parameter set in flight)."""
    formats = _formats(layout)
    records = [(float(log.imu_t_s[0]), k, v) for k, v in (parameters or {}).items()] + list(parameter_changes)
    parts: list[tuple[Array, NDArray]] = []
    if records:
        imu = formats["IMU"]
        formats["PARM"] = _Format(150, "PARM", imu.format[0] + "Nf", (imu.columns[0], "Name", "Value"))
        t, names, values = zip(*records, strict=True)
        parts.append(_records(formats["PARM"], np.array(t), {"Name": list(names), "Value": list(values)}))
    for k in range(instances):
        gain = 1.0 + k / 100.0
        imu_cols = {**_split(du.GYR_FIELDS, log.gyr_radps * gain), **_split(du.ACC_FIELDS, log.acc_mps2 * gain)}
        parts.append(_records(_instance(formats, "IMU", k), log.imu_t_s, imu_cols, k))
        mag_cols = _split(du.MAG_FIELDS, (mags[k] if k < len(mags) else log.mag_uT) * gain / du.MAG_SI)
        parts.append(_records(_instance(formats, "MAG", k), log.mag_t_s, mag_cols, k))
    if log.attitude_t_s is not None and log.attitude_rpy_rad is not None:
        deg = np.degrees(log.attitude_rpy_rad)
        deg[:, 2] %= 360.0  # the old layouts' Yaw is unsigned (C): 0–360°, as ArduPilot logs it
        parts.append(_records(formats["ATT"], log.attitude_t_s, _split(du.ATT_FIELDS, deg)))
    if log.position_t_s is not None and log.position is not None:
        parts += _positions(formats, log, instances)
    path = Path(path)
    with path.open("wb") as f:
        for fmt in formats.values():
            f.write(fmt.fmt_record())
        f.write(_interleave(parts))
    return path


def _instance(formats: dict[str, _Format], base: str, k: int) -> _Format:
    """The message of instance ``k``: the one with an ``I`` column, or ``IMU2`` … in the old layouts."""
    return formats[base] if k == 0 or "I" in formats[base].columns else formats[f"{base}{k + 1}"]


def _positions(formats: dict[str, _Format], log: SensorLog, instances: int) -> list[tuple[Array, NDArray]]:
    """POS records where the layout has them, and GPS records (3D fix) from each receiver."""
    assert log.position_t_s is not None and log.position is not None
    t, pos = log.position_t_s, log.position
    where = {"Lat": pos[:, 0], "Lng": pos[:, 1], "Alt": pos[:, 2]}
    parts = [_records(formats["POS"], t, where)] if "POS" in formats else []
    gps_s = t + (log.gps_time_s if log.gps_time_s is not None else math.nan)
    week = np.where(np.isfinite(gps_s), np.floor(gps_s / du.GPS_WEEK_S), 0.0)
    ms = np.where(np.isfinite(gps_s), (gps_s - week * du.GPS_WEEK_S) * 1e3, 0.0)
    for k in range(min(instances, 2) if "GPS2" in formats or "I" in formats["GPS"].columns else 1):
        gps = _instance(formats, "GPS", k)
        weeks = {"GWk": week, "GMS": ms} if "GWk" in gps.columns else {"Week": week, "TimeMS": ms}
        parts.append(_records(gps, t, {"Status": np.full(len(t), 3.0), **where, **weeks}, k))
    return parts


def _split(names: tuple[str, ...], values: Array) -> dict[str, Array]:
    return {name: values[:, i] for i, name in enumerate(names)}


def _interleave(parts: list[tuple[Array, NDArray]]) -> bytes:
    """All records in time order (stable: at equal times in the order given), as one byte string."""
    times = np.concatenate([t for t, _ in parts])
    lengths = np.concatenate([np.full(len(t), raw.shape[1]) for t, raw in parts])
    order = np.argsort(times, kind="stable")
    start = np.empty(len(order), dtype=np.int64)
    start[order] = np.concatenate([[0], np.cumsum(lengths[order])[:-1]])
    out = np.empty(int(lengths.sum()), dtype=np.uint8)
    first = 0
    for _, raw in parts:
        n, width = raw.shape
        out[start[first : first + n, None] + np.arange(width)] = raw
        first += n
    return out.tobytes()


def static_log(
    seconds: float, imu_rate_hz: float = 400.0, mag_rate_hz: float = 10.0, yaw_rate_dps: float = 0.0
) -> SensorLog:
    """A vehicle level on the ground turning slowly in yaw at 47.4° N, 8.5° E (Zurich): noise-free specific
    force, field (48.0 µT at 63.5° inclination, the WMM's there to a few tenths), ATT at 10 Hz, POS at 5 Hz."""
    t = np.arange(round(seconds * imu_rate_hz)) / imu_rate_hz + 1.0
    inc = math.radians(63.5)
    field_ned = 48.0 * np.array([math.cos(inc), 0.0, math.sin(inc)])
    acc = np.tile([0.0, 0.0, -STANDARD_GRAVITY_MPS2], (len(t), 1))
    gyr = np.tile([0.0, 0.0, math.radians(yaw_rate_dps)], (len(t), 1))
    mag_t = np.arange(round(seconds * mag_rate_hz)) / mag_rate_hz + 1.0
    mag_yaw = np.radians(yaw_rate_dps) * (mag_t - 1.0)
    c, s = np.cos(mag_yaw), np.sin(mag_yaw)
    mag = np.column_stack([c * field_ned[0], -s * field_ned[0], np.full(len(mag_t), field_ned[2])])
    att_t = np.arange(round(seconds * 10)) / 10.0 + 1.0
    att_rpy = np.column_stack([np.zeros(len(att_t)), np.zeros(len(att_t)), np.radians(yaw_rate_dps) * (att_t - 1.0)])
    pos_t = np.arange(round(seconds * 5)) / 5.0 + 1.0
    pos = np.tile([47.4, 8.5, 450.0], (len(pos_t), 1))
    return SensorLog(t, acc, gyr, mag_t, mag, att_t, att_rpy, pos_t, pos)


def manoeuvring_log(
    seconds: float,
    imu_rate_hz: float = 25.0,
    mag_rate_hz: float = 10.0,
    peak_rate_dps: float = 200.0,
    mag_turn: Array | None = None,
    seed: int = 0,
) -> SensorLog:
    """A hovering copter swinging hard in roll, pitch and yaw (tilts to 30°, body rates to ``peak_rate_dps``),
    logged as ArduPilot logs by default: IMU snapshots at 25 Hz, a 10 Hz compass whose reading is the mean of
    the field over its interval (its driver accumulates samples), stamped at the interval's end; at CMAC
    (WMM there: 58.0 µT, inclination −65.8°, declination +12.8°), ATT 10 Hz, POS 5 Hz. The field is the Earth's
    only and the specific force gravity's only; ``mag_turn`` (3×3) turns the compass's axes against the body's.
    The frequencies are drawn from ``seed`` (0.2–0.8 Hz per axis); the yaw swing sets the peak rate."""
    rng = np.random.default_rng(seed)
    fine_hz = 1000.0  # the truth's grid: rates and the compass's mean from it
    t = np.arange(round(seconds * fine_hz) + 1) / fine_hz + 1.0
    freq, phase = rng.uniform(0.2, 0.8, 3), rng.uniform(0.0, 2.0 * np.pi, 3)
    amplitude = np.radians([30.0, 30.0, 0.0])
    amplitude[2] = np.radians(peak_rate_dps) / (2.0 * np.pi * freq[2])
    angles = amplitude[:, None] * np.sin(2.0 * np.pi * freq[:, None] * (t - 1.0) + phase[:, None])
    q = quat_from_euler(*angles)
    rates = rotvec_from_quat(quat_multiply(quat_conjugate(q[:-1]), q[1:])) * fine_hz  # over each fine step
    inc, dec = math.radians(-65.77), math.radians(12.8)
    field_ned = 58.0 * np.array([math.cos(inc) * math.cos(dec), math.cos(inc) * math.sin(dec), math.sin(inc)])
    body_field = rotate_ned_to_body(q, field_ned) @ (np.eye(3) if mag_turn is None else np.asarray(mag_turn)).T
    imu = np.arange(1, round(seconds * imu_rate_hz)) * round(fine_hz / imu_rate_hz)
    per_mag = round(fine_hz / mag_rate_hz)
    mag_end = np.arange(1, round(seconds * mag_rate_hz)) * per_mag
    mag = np.stack([body_field[e - per_mag + 1 : e + 1].mean(axis=0) for e in mag_end])
    acc = rotate_ned_to_body(q[imu], [0.0, 0.0, -STANDARD_GRAVITY_MPS2])
    att = np.arange(round(seconds * 10.0)) * round(fine_hz / 10.0)
    pos_t = np.arange(round(seconds * 5.0)) / 5.0 + 1.0
    pos = np.tile([-35.363261, 149.165230, 584.0], (len(pos_t), 1))
    return SensorLog(t[imu], acc, rates[imu - 1], t[mag_end], mag, t[att], angles[:, att].T, pos_t, pos)


def write_tlog(
    path: str | Path,
    log: SensorLog,
    system: int = 1,
    message: str = "RAW_IMU",
    others: Sequence[tuple[SensorLog, int, str]] = (),
) -> Path:
    """Write ``log`` as a ground station's telemetry log: a HEARTBEAT a second, ``message`` per IMU row with
    the newest magnetometer reading (ArduPilot units), ATTITUDE and GLOBAL_POSITION_INT; each packet after
    its 8-byte big-endian receive time (µs since 1970, the log's clock starting on 2026-03-01).

    ``others``: more vehicles the ground station heard, ``(log, system, message)`` each; all packets in time
    order, at equal times in the order the vehicles are given (``log`` first)."""
    records = [r for vehicle in [(log, system, message), *others] for r in _tlog_records(*vehicle)]
    records.sort(key=lambda r: r[0])
    start_us = 1_772_323_200_000_000  # 2026-03-01 00:00 UTC
    path = Path(path)
    with path.open("wb") as f:
        for t, buf in records:
            f.write(round(start_us + t * 1e6).to_bytes(8, "big") + buf)
    return path


def _tlog_records(log: SensorLog, system: int, message: str) -> list[tuple[float, bytes]]:
    """One vehicle's packets, each with its vehicle time (see :func:`write_tlog`)."""
    from mavattitude.link.mavlink2 import mavlink2
    from mavattitude.sensors.units import PROFILES, ImuSample, Position, encode, encode_position

    mav = mavlink2.MAVLink(None, srcSystem=system, srcComponent=1)
    profile = PROFILES["ardupilot"]
    imu_message = getattr(mavlink2, f"MAVLink_{message.lower()}_message")
    newest = np.searchsorted(log.mag_t_s, log.imu_t_s, side="right") - 1
    records: list[tuple[float, bytes]] = []
    for t in np.arange(0.0, log.imu_t_s[-1] + 1.0, 1.0):
        hb = mavlink2.MAVLink_heartbeat_message(2, mavlink2.MAV_AUTOPILOT_ARDUPILOTMEGA, 0, 0, 4, 3)
        records.append((float(t), hb.pack(mav)))
    acc, gyr, mag = log.acc_mps2.tolist(), log.gyr_radps.tolist(), log.mag_uT.tolist()
    for i, t in enumerate(log.imu_t_s.tolist()):
        sample = ImuSample(t, tuple(acc[i]), tuple(gyr[i]), tuple(mag[newest[i]]) if newest[i] >= 0 else None)
        records.append((t, imu_message(**encode(sample, profile, message)).pack(mav)))
    if log.attitude_t_s is not None and log.attitude_rpy_rad is not None:
        for t, (r, p, y) in zip(log.attitude_t_s.tolist(), log.attitude_rpy_rad.tolist(), strict=True):
            records.append((t, mavlink2.MAVLink_attitude_message(round(t * 1e3), r, p, y, 0.0, 0.0, 0.0).pack(mav)))
    if log.position_t_s is not None and log.position is not None:
        for t, (lat, lon, alt) in zip(log.position_t_s.tolist(), log.position.tolist(), strict=True):
            fields = (round(t * 1e3), *encode_position(Position(lat, lon, alt)), 0, 0, 0, 0, 0)
            records.append((t, mavlink2.MAVLink_global_position_int_message(*fields).pack(mav)))
    return records
