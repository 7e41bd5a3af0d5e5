"""PX4 ULog (.ulg) topic fields → SI: the only ULog unit conversions.

The fields replay reads, with the units PX4 logs them in (its uORB message definitions, ``msg/*.msg``):

=========================  ===================================  ==============  =====================
topic                      field                                logged unit     SI / here
=========================  ===================================  ==============  =====================
every topic                timestamp                            µs since boot   s
sensor_combined            accelerometer_m_s2[0..2]             m/s²            m/s² (body FRD)
                           gyro_rad[0..2]                       rad/s           rad/s
sensor_combined (old)      magnetometer_ga[0..2]                gauss           µT (× 100)
                           magnetometer_timestamp_relative      µs              s, added to timestamp
vehicle_magnetometer       magnetometer_ga[0..2]                gauss           µT (× 100)
vehicle_attitude           q[0..3]                              [w, x, y, z]    body FRD → NED
vehicle_gps_position       lat, lon | latitude_deg, ...         1e-7 ° | °      °
                           alt | altitude_msl_m                 mm | m          m AMSL
                           fix_type, time_utc_usec              -, µs (1970)    3D fix; the date
                           vel_n_m_s, vel_e_m_s, vel_d_m_s      m/s             m/s NED (vel_ned_valid)
                           satellites_used                      -               satellites
vehicle_global_position    lat, lon, alt                        °, °, m         °, °, m AMSL
=========================  ===================================  ==============  =====================

Functions take a topic's data: field name → array, as pyulog gives it, and return SI arrays.
"""

from __future__ import annotations

import datetime as dt

import numpy as np
from numpy.typing import NDArray

from mavattitude.estimation.conventions import Array
from mavattitude.sensors.units import GAUSS_UT, GpsVelocity, is_position, unix_date

Topic = dict[str, NDArray]

TIMESTAMP_S = 1e-6  # µs → s
GPS_FIX_3D = 3
MAG_FIELD = "magnetometer_ga"
#: The position fields of vehicle_gps_position by generation: (lat, lon, alt, scale of lat/lon, scale of alt → m).
GPS_FIELDS = (("latitude_deg", "longitude_deg", "altitude_msl_m", 1.0, 1.0), ("lat", "lon", "alt", 1e-7, 1e-3))


def vectors(topic: Topic, field: str, scale: float = 1.0, n: int = 3) -> Array:
    """``field[0]`` … ``field[n-1]`` as rows, times ``scale``."""
    return np.column_stack([np.asarray(topic[f"{field}[{i}]"], dtype=float) for i in range(n)]) * scale


def times_s(topic: Topic) -> Array:
    return np.asarray(topic["timestamp"], dtype=float) * TIMESTAMP_S


def imu(sensor_combined: Topic) -> tuple[Array, Array, Array]:
    """sensor_combined → times (s), specific force (m/s²), angular rate (rad/s)."""
    topic = sensor_combined
    return times_s(topic), vectors(topic, "accelerometer_m_s2"), vectors(topic, "gyro_rad")


def mag(topic: Topic) -> tuple[Array, Array]:
    """vehicle_magnetometer → times (s) and field (µT)."""
    return times_s(topic), vectors(topic, MAG_FIELD, GAUSS_UT)


def combined_mag(sensor_combined: Topic) -> tuple[Array, Array]:
    """The old layout's magnetometer inside sensor_combined: each reading once, at its own time (s), µT.

    Every row repeats the newest reading, its relative timestamp re-based on the row's: a reading is new
    where the value changes (as in ../shared's CSV of the same log, ``mag_new``).
    """
    topic = sensor_combined
    t = times_s(topic) + np.asarray(topic["magnetometer_timestamp_relative"], dtype=float) * TIMESTAMP_S
    field = vectors(topic, MAG_FIELD, GAUSS_UT)
    new = np.ones(len(t), dtype=bool)
    new[1:] = np.any(np.diff(field, axis=0) != 0.0, axis=1)
    keep = new & (t > 0.0)
    return t[keep], field[keep]


def attitude(vehicle_attitude: Topic) -> tuple[Array, Array]:
    """vehicle_attitude → times (s) and q [w, x, y, z] body FRD → NED."""
    return times_s(vehicle_attitude), vectors(vehicle_attitude, "q", n=4)


def gps_position(topic: Topic) -> tuple[Array, Array]:
    """vehicle_gps_position rows with a 3D fix and a place (:func:`~mavattitude.sensors.units.is_position`) →
    times (s) and (latitude °, longitude °, altitude m) rows."""
    for lat, lon, alt, deg, metres in GPS_FIELDS:
        if lat in topic:
            rows = np.column_stack(
                [np.asarray(topic[lat]) * deg, np.asarray(topic[lon]) * deg, np.asarray(topic[alt]) * metres]
            ).astype(float)
            fixed = (np.asarray(topic["fix_type"]) >= GPS_FIX_3D) & is_position(rows)
            return times_s(topic)[fixed], rows[fixed]
    raise KeyError("lat/latitude_deg")


def global_position(topic: Topic) -> tuple[Array, Array]:
    """vehicle_global_position rows that are a place → times (s) and (latitude °, longitude °, altitude m) rows."""
    rows = np.column_stack([np.asarray(topic[f], dtype=float) for f in ("lat", "lon", "alt")])
    place = is_position(rows)
    return times_s(topic)[place], rows[place]


def utc_date(time_utc_usec: int) -> dt.date | None:
    """The UTC date of a GPS receiver's µs since 1970 (``None`` when it is no date: :func:`units.unix_date`)."""
    return unix_date(int(time_utc_usec) * TIMESTAMP_S)


def gps_velocity(topic: Topic) -> tuple[Array, list[GpsVelocity]]:
    """vehicle_gps_position rows with a valid NED velocity → times (s) and the receiver's velocities (their fix
    time the row's timestamp, on the vehicle clock), fix type and satellites."""
    valid = np.asarray(topic["vel_ned_valid"]) != 0
    t = times_s(topic)[valid]
    vel = np.column_stack([np.asarray(topic[f], dtype=float)[valid] for f in ("vel_n_m_s", "vel_e_m_s", "vel_d_m_s")])
    fix = np.asarray(topic["fix_type"])[valid].tolist()
    sats = np.asarray(topic["satellites_used"])[valid].tolist()
    rows = [
        GpsVelocity(t_s, (n, e, d), True, int(k), int(m))
        for t_s, (n, e, d), k, m in zip(t.tolist(), vel.tolist(), fix, sats, strict=True)
    ]
    return t, rows
