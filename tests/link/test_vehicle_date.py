"""The date for the magnetic model comes from the vehicle's GPS time, a log's clock only as a fallback."""

from __future__ import annotations

import datetime as dt

import numpy as np
import pytest
from pymavlink.dialects.v20 import ardupilotmega as mavlink2

from mavattitude.link.source import MavlinkDecoder, PositionFix
from mavattitude.sensors import units

MAV = mavlink2.MAVLink(None, srcSystem=1, srcComponent=1)
UNIX_2027_03_01_US = int(dt.datetime(2027, 3, 1, 12, tzinfo=dt.timezone.utc).timestamp()) * 1_000_000


def _decoded(msg):
    return MAV.decode(bytearray(msg.pack(MAV)))


def _position() -> object:
    return _decoded(mavlink2.MAVLink_global_position_int_message(0, 473_769_000, 85_417_000, 500_000, 0, 0, 0, 0, 0))


def _gps_raw(time_usec: int) -> object:
    return _decoded(mavlink2.MAVLink_gps_raw_int_message(time_usec, 3, 473_769_000, 85_417_000, 500_000, 0, 0, 0, 0, 9))


def test_system_time_and_a_unix_stamped_gps_raw_int_give_the_date():
    assert units.decode_utc_date(_decoded(mavlink2.MAVLink_system_time_message(UNIX_2027_03_01_US, 0))) == dt.date(
        2027, 3, 1
    )
    assert units.decode_utc_date(_gps_raw(UNIX_2027_03_01_US)) == dt.date(2027, 3, 1)
    # ArduPilot stamps GPS_RAW_INT with the time since boot, and SYSTEM_TIME is 0 until it knows the time
    assert units.decode_utc_date(_gps_raw(62_173_000)) is None
    assert units.decode_utc_date(_decoded(mavlink2.MAVLink_system_time_message(0, 1000))) is None


@pytest.mark.parametrize("time_usec", [units.LATEST_UNIX_S * 1_000_000, 2**63, 2**64 - 1])
def test_a_garbled_gps_time_is_no_date(time_usec):
    """A time past 2100 (the largest a uint64 holds is in the year 586 524, past any date Python can hold) is a
    garbled field: no date, in a message and in a log's columns alike, rather than an exception."""
    assert units.decode_utc_date(_decoded(mavlink2.MAVLink_system_time_message(time_usec, 0))) is None
    assert units.decode_utc_date(_gps_raw(time_usec)) is None
    columns = units.utc_time_columns("SYSTEM_TIME", {"time_unix_usec": np.array([time_usec, UNIX_2027_03_01_US])})
    assert np.isnan(columns[0]) and columns[1] == UNIX_2027_03_01_US * 1e-6


def test_positions_carry_the_vehicles_date_over_the_logs_and_none_before_it_is_known():
    log_day = dt.date(2026, 11, 24)
    decoder = MavlinkDecoder("RAW_IMU", units.get_profile("ardupilot"), lambda msg: log_day)
    live = MavlinkDecoder("RAW_IMU", units.get_profile("ardupilot"))
    assert decoder(_position()) == PositionFix(units.decode_position(_position()), log_day)
    assert live(_position()).date is None  # live, no GPS time yet: the companion's clock decides
    for d in (decoder, live):
        assert d(_decoded(mavlink2.MAVLink_system_time_message(UNIX_2027_03_01_US, 0))) is None
        assert d(_position()).date == dt.date(2027, 3, 1)
    assert "SYSTEM_TIME" in decoder.types  # a log reader reads it
