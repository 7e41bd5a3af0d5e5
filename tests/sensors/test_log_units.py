"""The DataFlash and ULog unit tables against reference values: milligauss, gauss, degrees, GPS dates."""

from __future__ import annotations

import datetime as dt
import math

import numpy as np
import pytest

from mavattitude.estimation.conventions import quat_from_euler
from mavattitude.sensors import dataflash_units as du
from mavattitude.sensors import ulog_units as uu


def test_dataflash_mag_is_milligauss_and_imu_is_si() -> None:
    table = {"TimeUS": np.array([1_500_000]), "MagX": np.array([1000]), "MagY": np.array([-250]), "MagZ": np.array([0])}
    t, mag = du.mag(table)
    assert t.tolist() == [1.5]
    assert mag.tolist() == [[100.0, -25.0, 0.0]]  # 1000 mG = 1 gauss = 100 µT
    imu = {"TimeUS": np.array([2]), **{f: np.array([k + 1.0]) for k, f in enumerate((*du.GYR_FIELDS, *du.ACC_FIELDS))}}
    _, acc, gyr, wrap = du.imu(imu)
    assert gyr.tolist() == [[1.0, 2.0, 3.0]] and acc.tolist() == [[4.0, 5.0, 6.0]] and wrap is None


def test_old_dataflash_time_is_a_wrapping_uint32_of_milliseconds() -> None:
    t, wrap = du.time_s({"TimeMS": np.array([1234])})
    assert t.tolist() == [1.234] and wrap == 2**32 / 1000


def test_dataflash_attitude_degrees_become_the_body_to_ned_quaternion() -> None:
    table = {"TimeUS": np.array([0]), "Roll": np.array([10.0]), "Pitch": np.array([-20.0]), "Yaw": np.array([350.0])}
    _, q = du.attitude(table)
    assert q[0] == pytest.approx(quat_from_euler(math.radians(10), math.radians(-20), math.radians(350)), abs=1e-12)


@pytest.mark.parametrize(
    ("week", "ms", "date"),
    [
        (2048, 86_400_000 * 3 + 5, dt.date(2019, 4, 10)),  # the second rollover (2019-04-07), three days on
        (2347, 0, dt.date(2024, 12, 29)),
        (1024, 0, None),  # 1999-08-22: before the oldest magnetic model (2010), a receiver without time
        (65535, 0, None),  # a garbled week: the year 3236
    ],
)
def test_gps_weeks_give_their_known_dates_and_a_garbled_one_none(week: int, ms: int, date: dt.date | None) -> None:
    table = {"GWk": np.array([0, week]), "GMS": np.array([0, ms]), "Status": np.array([3, 3])}
    assert du.first_gps_date(table) == date  # week 0 (1980), the first record: a receiver without time yet


def test_dataflash_instance_message_names() -> None:
    assert du.message_name("IMU", 0, False) == "IMU"
    assert du.message_name("IMU", 2, False) == "IMU3"  # old logs: IMU, IMU2, IMU3
    assert du.message_name("MAG", 1, True) == "MAG"  # new logs: one message, an instance column


def test_ulog_magnetometer_is_gauss_and_the_old_layout_keeps_each_reading_once() -> None:
    topic = {"timestamp": np.array([1_000_000, 1_004_000, 1_008_000, 1_012_000])}
    topic |= {
        "magnetometer_ga[0]": np.array([0.2, 0.2, 0.3, 0.3]),
        "magnetometer_ga[1]": np.zeros(4),
        "magnetometer_ga[2]": np.full(4, 0.4),
    }
    topic["magnetometer_timestamp_relative"] = np.array([-1000, -5000, -500, -4400])  # re-based on each row
    t, mag = uu.mag(topic)
    assert t.tolist() == pytest.approx([1.0, 1.004, 1.008, 1.012])  # µs since boot
    assert mag[0].tolist() == pytest.approx([20.0, 0.0, 40.0])  # 1 gauss = 100 µT
    t_new, mag_new = uu.combined_mag(topic)
    assert t_new.tolist() == pytest.approx([0.999, 1.0075])  # two readings, each at its own time
    assert mag_new[:, 0].tolist() == pytest.approx([20.0, 30.0])


@pytest.mark.parametrize(
    "fields",
    [
        {"lat": np.array([474000000]), "lon": np.array([85000000]), "alt": np.array([450_000])},  # 1e-7 °, mm
        {"latitude_deg": np.array([47.4]), "longitude_deg": np.array([8.5]), "altitude_msl_m": np.array([450.0])},
    ],
)
def test_ulog_gps_position_both_generations(fields: dict) -> None:
    topic = {"timestamp": np.array([5_000_000]), "fix_type": np.array([3]), **fields}
    t, rows = uu.gps_position(topic)
    assert t.tolist() == [5.0] and rows[0].tolist() == pytest.approx([47.4, 8.5, 450.0])
    assert uu.gps_position({**topic, "fix_type": np.array([2])})[0].size == 0  # no 3D fix: no position


# one place; then off the globe, at 0°, 0°, off the globe, 2147 km down (outside the magnetic model)
PLACES = {
    "lat": np.array([47.4, 214.7, 0.0, 47.4, 47.4]),
    "lon": np.array([8.5, 8.5, 0.0, 190.0, 8.5]),
    "alt": np.array([1.0, 1.0, 1.0, 1.0, -2.147e6]),
}
DF_PLACES = {"Lat": PLACES["lat"], "Lng": PLACES["lon"], "Alt": PLACES["alt"]}
PX4_GPS = {"latitude_deg": PLACES["lat"], "longitude_deg": PLACES["lon"], "altitude_msl_m": PLACES["alt"]}


@pytest.mark.parametrize(
    ("reader", "table"),
    [
        (du.position, {"TimeUS": np.arange(5) * 1e6, **DF_PLACES}),
        (du.gps_fixes, {"TimeUS": np.arange(5) * 1e6, "Status": np.full(5, 3), **DF_PLACES}),
        (uu.global_position, {"timestamp": np.arange(5) * 1e6, **PLACES}),
        (
            uu.gps_position,
            {"timestamp": np.arange(5) * 1e6, "fix_type": np.full(5, 3), **PX4_GPS},
        ),
    ],
)
def test_log_positions_off_the_globe_or_at_zero_zero_are_none(reader, table: dict) -> None:
    t, rows = reader(table)
    assert t.tolist() == [0.0] and rows.tolist() == [[47.4, 8.5, 1.0]]


def test_ulog_utc_date() -> None:
    assert uu.utc_date(1_618_963_200_000_000) == dt.date(2021, 4, 21)
    assert uu.utc_date(2**63) is None  # a garbled receiver time: past any date Python holds
