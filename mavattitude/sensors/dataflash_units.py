"""ArduPilot DataFlash (.bin) log fields → SI: the only DataFlash unit conversions.

The fields replay reads, with the units ArduPilot logs them in (its ``LogStructure.h`` and the log
messages documentation; DataFlash's own FMTU units agree), after pymavlink's DFReader has applied the
format's multiplier (``L``: 1e-7 °, ``e``: 0.01 m, ``c``/``C``: 0.01 °):

===================  =====================  ==============  ==============================================
message              field                  logged unit     SI / here
===================  =====================  ==============  ==============================================
IMU (IMU2, IMU3)     TimeUS | TimeMS        µs | ms         s (TimeMS: uint32, wraps)
                     AccX, AccY, AccZ       m/s²            m/s² (board frame, FRD)
                     GyrX, GyrY, GyrZ       rad/s           rad/s
MAG (MAG2, MAG3)     MagX, MagY, MagZ       milligauss      µT (× 0.1)
ATT                  Roll, Pitch, Yaw       degrees         rad → quaternion body → NED
POS                  Lat, Lng, Alt          °, °, m AMSL    °, °, m
GPS (GPS2)           TimeUS | T             µs | ms         s, since boot
                     Status, NSats          fix type, -     a position when ≥ 3 (3D fix); satellites
                     Lat, Lng, Alt          °, °, m AMSL    °, °, m
                     GWk, GMS | Week,       week, ms        the date (GPS epoch 1980-01-06); the fix time, s
                     TimeMS
                     Spd, GCrs, VZ          m/s, °, m/s     NED velocity, m/s (VZ positive down)
===================  =====================  ==============  ==============================================

The layouts of every era pymavlink's DFReader reads: TimeUS (ArduPilot 3.3 on) or TimeMS (before: uint32
ms since boot); new logs put every instance in one message with an ``I`` column, old ones have IMU2, MAG2,
GPS2 as messages of their own. The GPS record's own fields changed too: 3.3 on, ``TimeUS``, ``GMS``
(ms of the GPS week), ``GWk``; before, ``TimeMS`` *is* the ms of the GPS week, beside ``Week``, and the
time since boot is ``T`` (3.1, 3.2) or not logged at all (earlier: such records take their time from
the log's order, :func:`time_s`). Functions take a table: column name → array (one message type's
records), and return SI arrays.
"""

from __future__ import annotations

import datetime as dt
import math

import numpy as np
from numpy.typing import NDArray

from mavattitude.estimation.conventions import Array, quat_from_euler
from mavattitude.estimation.velocity import GPS_FIX_3D
from mavattitude.sensors.units import BOOT_MS_WRAP_S, MILLIGAUSS_UT, GpsVelocity, is_date, is_position, unix_date

Table = dict[str, NDArray]

#: SI per logged unit of each time-since-boot field, in the order taken, and its wrap period (s; None: a
#: uint64 of µs never wraps). ``T``: an old GPS record's time since boot (its ``TimeMS`` is GPS time).
TIME_FIELDS: dict[str, tuple[float, float | None]] = {
    "TimeUS": (1e-6, None),
    "T": (1e-3, BOOT_MS_WRAP_S),
    "TimeMS": (1e-3, BOOT_MS_WRAP_S),
}
GPS_WEEK_FIELDS = (("GWk", "GMS"), ("Week", "TimeMS"))  # (week, ms of week): 3.3 on, and before
ACC_FIELDS, ACC_SI = ("AccX", "AccY", "AccZ"), 1.0  # m/s²
GYR_FIELDS, GYR_SI = ("GyrX", "GyrY", "GyrZ"), 1.0  # rad/s
MAG_FIELDS, MAG_SI = ("MagX", "MagY", "MagZ"), MILLIGAUSS_UT  # milligauss → µT
ATT_FIELDS, ATT_SI = ("Roll", "Pitch", "Yaw"), math.radians(1.0)  # degrees → rad
POS_FIELDS = ("Lat", "Lng", "Alt")  # °, °, m once DFReader's multipliers are applied
GPS_EPOCH_UNIX_S = 315_964_800.0  # 1980-01-06, the GPS epoch
GPS_WEEK_S = 7 * 86_400.0


def message_name(base: str, instance: int, table_has_instances: bool) -> str:
    """The message holding ``instance`` of a sensor: ``IMU`` (with an ``I`` column), or ``IMU2`` … in old logs."""
    return base if table_has_instances or instance == 0 else f"{base}{instance + 1}"


def time_s(table: Table) -> tuple[Array, float | None]:
    """The records' times on the vehicle clock, s, and the field's wrap period. An old GPS record's ``TimeMS``
    beside ``Week`` is GPS time, not the vehicle's: without a ``T`` there is no time (``KeyError``)."""
    for name, (scale, wrap) in TIME_FIELDS.items():
        if name in table and not (name == "TimeMS" and "Week" in table):
            return np.asarray(table[name], dtype=float) * scale, wrap
    raise KeyError(f"no time field (one of {', '.join(TIME_FIELDS)})")


def _vectors(table: Table, fields: tuple[str, str, str], scale: float) -> Array:
    return np.column_stack([np.asarray(table[f], dtype=float) for f in fields]) * scale


def imu(table: Table) -> tuple[Array, Array, Array, float | None]:
    """IMU records → times (s), specific force (m/s²), angular rate (rad/s), the time field's wrap period."""
    t, wrap = time_s(table)
    return t, _vectors(table, ACC_FIELDS, ACC_SI), _vectors(table, GYR_FIELDS, GYR_SI), wrap


def mag(table: Table) -> tuple[Array, Array]:
    """MAG records → times (s) and field (µT, board frame)."""
    return time_s(table)[0], _vectors(table, MAG_FIELDS, MAG_SI)


def attitude(table: Table) -> tuple[Array, Array]:
    """ATT records → times (s) and the autopilot's attitude quaternion [w, x, y, z] body → NED."""
    rpy = _vectors(table, ATT_FIELDS, ATT_SI)
    return time_s(table)[0], quat_from_euler(rpy[:, 0], rpy[:, 1], rpy[:, 2]).reshape(-1, 4)


def position(table: Table) -> tuple[Array, Array]:
    """POS records → the times (s) and (latitude °, longitude °, altitude m AMSL) rows of those that are a place
    (:func:`~mavattitude.sensors.units.is_position`)."""
    pos = _vectors(table, POS_FIELDS, 1.0)
    place = is_position(pos)
    return time_s(table)[0][place], pos[place]


def gps_fixes(table: Table) -> tuple[Array, Array]:
    """GPS records → the times (s) and (latitude °, longitude °, altitude m AMSL) rows of those with a 3D fix
    and a place."""
    pos = _vectors(table, POS_FIELDS, 1.0)
    fixed = (np.asarray(table["Status"]) >= GPS_FIX_3D) & is_position(pos)
    return time_s(table)[0][fixed], pos[fixed]


def first_gps_date(table: Table) -> dt.date | None:
    """The day of the first GPS record with a 3D fix and a GPS week (``GWk``/``GMS``, or ``Week``/``TimeMS``)
    that can be a GPS date (:func:`~mavattitude.sensors.units.is_date`: a garbled week is none)."""
    names = next(((w, ms) for w, ms in GPS_WEEK_FIELDS if w in table and ms in table), None)
    if names is None:
        return None
    week, ms = (np.asarray(table[n], dtype=float) for n in names)
    unix_s = GPS_EPOCH_UNIX_S + week * GPS_WEEK_S + ms * 1e-3  # leap seconds ignored: a date is enough
    fixed = np.flatnonzero((np.asarray(table["Status"]) >= GPS_FIX_3D) & is_date(unix_s))
    return unix_date(float(unix_s[fixed[0]])) if len(fixed) else None


def gps_velocity(table: Table) -> tuple[Array, list[GpsVelocity]]:
    """GPS records → times (s) and the receiver's velocities (NED m/s from speed, course and VZ), each with its
    fix time (GPS week and ms, or the record's time without them), fix type and satellites."""
    t = time_s(table)[0]
    if "GWk" in table and "GMS" in table:
        fix_t = np.asarray(table["GWk"], dtype=float) * GPS_WEEK_S + np.asarray(table["GMS"], dtype=float) * 1e-3
    else:
        fix_t = t
    speed, course = np.asarray(table["Spd"], dtype=float), np.radians(np.asarray(table["GCrs"], dtype=float))
    north, east = (speed * np.cos(course)).tolist(), (speed * np.sin(course)).tolist()
    down = np.asarray(table["VZ"], dtype=float).tolist()
    fix, sats = np.asarray(table["Status"]).tolist(), np.asarray(table["NSats"]).tolist()
    rows = [
        GpsVelocity(f_s, (n, e, d), True, int(k), int(m))
        for f_s, n, e, d, k, m in zip(fix_t.tolist(), north, east, down, fix, sats, strict=True)
    ]
    return t, rows
