"""``reference.magnetic: auto``: the service takes the field from the World Magnetic Model at the
vehicle's GLOBAL_POSITION_INT, and flies right when the truth is that field; without a fix, the field
measured from the compass after the bounded wait."""

from __future__ import annotations

import datetime as dt
from collections.abc import Callable
from typing import Any

import numpy as np
import pytest

from mavattitude.estimation.conventions import euler_from_quat
from mavattitude.sensors.magref import field_from_angles, wmm_field_ned_uT
from mavattitude.sim import scenarios
from mavattitude.sim.trajectory import Hold, Rotate, Script
from mavattitude.sim.vehicle import VehicleConfig

from .conftest import assert_all_outputs_valid, counter, wait_outputs

pytestmark = pytest.mark.e2e


def test_auto_reference_from_the_vehicle_position(fly: Callable[..., Any]) -> None:
    home = VehicleConfig("unused")  # the fake vehicle's default home (Zürich)
    field = wmm_field_ned_uT(home.home_lat_deg, home.home_lon_deg, home.home_alt_m, dt.date.today())
    script = Script([Hold(1.0), Rotate(119.0, (0.03, -0.05, 0.08))], tuple(field))
    service = {"reference": {"magnetic": "auto"}}
    with fly(script, scenarios.paper_sensors(200.0), service) as (v, svc):
        wait_outputs(v, 75)
        assert counter(svc, "positions") >= 1
    score = v.score()
    # The same accuracy as with the field given in the config (test_profiles): WMM at the position the
    # vehicle reported is the field it flies in.
    assert score.broken == 0 and score.angle_rms_deg < 1.0, score
    assert_all_outputs_valid(v)


@pytest.mark.parametrize(
    ("vehicle_day", "model_day"),
    [(dt.date(2027, 7, 1), dt.date(2027, 7, 1)), (dt.date(2031, 3, 1), dt.date(2029, 12, 31))],
    ids=["in_the_model_span", "after_it_clamped"],
)
def test_the_model_is_taken_on_the_vehicles_gps_date(
    fly: Callable[..., Any], vehicle_day: dt.date, model_day: dt.date
) -> None:
    """The vehicle's SYSTEM_TIME, not the machine's clock, dates the World Magnetic Model; a date after
    the model's span is clamped to its last day with one warning, and the service flies on."""
    # Both days differ from the machine's (2026 when written); the log line names the date's source too, so
    # the test holds whatever the machine's clock says.
    home = VehicleConfig("unused")
    field = wmm_field_ned_uT(home.home_lat_deg, home.home_lon_deg, home.home_alt_m, model_day)
    script = Script([Hold(1.0), Rotate(119.0, (0.03, -0.05, 0.08))], tuple(field))
    gps_unix_s = dt.datetime(vehicle_day.year, vehicle_day.month, vehicle_day.day, 12, tzinfo=dt.timezone.utc)
    service = {"reference": {"magnetic": "auto"}}
    with fly(script, scenarios.paper_sensors(200.0), service, gps_unix_s=gps_unix_s.timestamp()) as (v, svc):
        line = svc.wait_for_line(rf"magnetic reference from WMM2025 .* on {model_day} \(the vehicle's GPS date\)", 10.0)
        assert line is not None, svc.log_tail()
        wait_outputs(v, 75)
        clamped = [ln for ln in svc.lines if "is outside the World Magnetic Model's span" in ln]
    assert len(clamped) == (vehicle_day != model_day)  # said once, only when clamped
    if clamped:
        assert f"the date {vehicle_day} is outside" in clamped[0]
        assert "--declination DEG --inclination DEG" in clamped[0]
    # The field of that day is the one the script flies in: the outputs agree with the truth.
    score = v.score()
    assert score.broken == 0 and score.angle_rms_deg < 1.0, score


def test_without_a_gps_fix_the_field_is_measured_then_a_fix_switches_to_the_model(fly: Callable[..., Any]) -> None:
    """A vehicle with no GPS fix (GLOBAL_POSITION_INT all 0, as ArduPilot sends it): attitudes within the
    bounded wait (reference.position_wait_s, 5 s by default) on the field measured from the compass, heading
    magnetic; a fix later switches to the WMM's field, heading true."""
    field = field_from_angles(0.0, 63.0, 48.0)  # declination 0: magnetic north is the truth's north
    script = Script([Hold(2.0), Rotate(118.0, (0.03, -0.05, 0.08))], field)
    with fly(script, scenarios.paper_sensors(200.0), {"reference": {"magnetic": "auto"}}, gps_fix=False) as (v, svc):
        # the vehicle says its declination, 0 as its field's (COMPASS_DEC, asked on locking): north is the same
        line = svc.wait_for_line(
            r"no GPS position: heading is north as the autopilot's: declination \+0\.0° \(COMPASS_DEC\), field "
            "measured from the compass",
            10.0,
        )
        assert line is not None and "dip 63.0°, 48.0 µT" in line, svc.log_tail()
        wait_outputs(v, 75)
        _, first_s, _ = v.outputs_since(0)
        # the wait is vehicle time from the first IMU tick the service takes: script time 0 (the next 50 Hz tick
        # 0.02 s on), or a little later on a machine so loaded that the first datagrams were dropped (0.5 s)
        assert 5.0 <= first_s[0] < 5.5
        assert counter(svc, "positions") == 0
        measured = v.score()
        v.set_gps_fix(True)
        wmm = svc.wait_for_line(r"magnetic reference from WMM2025 at 47\.3977°, 8\.5456°", 10.0)
        assert wmm is not None, svc.log_tail()
        since = len(v.attitude_log)
        wait_outputs(v, 75)
    assert measured.broken == 0 and measured.angle_rms_deg < 1.0, measured  # as with the field given
    # after the fix the reference is the WMM's, declination D, while the script's field has none: the heading
    # is turned by D, the switch to the model taken (the field measured from the compass would give 0)
    home = VehicleConfig("unused")
    n, e, _ = wmm_field_ned_uT(home.home_lat_deg, home.home_lon_deg, home.home_alt_m, dt.date.today())
    _, t, q = v.outputs_since(since)
    yaw_deg = np.degrees(euler_from_quat(q)[:, 2] - euler_from_quat(script.attitude(t))[:, 2])
    # within the 1° RMS bound of the flight before (the median of 75 outputs is tighter still)
    assert np.median((yaw_deg + 180.0) % 360.0 - 180.0) == pytest.approx(np.degrees(np.arctan2(e, n)), abs=1.0)
    assert_all_outputs_valid(v)


@pytest.mark.parametrize(
    ("profile", "message", "parameter"),
    [("ardupilot", "RAW_IMU", "COMPASS_DEC"), ("px4", "HIGHRES_IMU", "EKF2_MAG_DECL")],
)
def test_without_a_fix_the_autopilots_declination_makes_the_measured_heading_true(
    fly: Callable[..., Any], profile: str, message: str, parameter: str
) -> None:
    """The field has a declination of 12.8° (CMAC's) and the vehicle no fix: a field measured from the compass
    alone would head 12.8° off the truth's north, but the autopilot's declination, asked on locking (ArduPilot's
    COMPASS_DEC in radians, PX4's EKF2_MAG_DECL in degrees), says it."""
    field = field_from_angles(12.8, -65.8, 58.0)
    script = Script([Hold(2.0), Rotate(118.0, (0.03, -0.05, 0.08))], field)
    service = {"reference": {"magnetic": "auto"}}
    vehicle = {"gps_fix": False, "profile": profile, "message": message}
    with fly(script, scenarios.paper_sensors(200.0), service, **vehicle) as (v, svc):
        north = rf"north as the autopilot's: declination \+12\.8° \({parameter}\)"
        line = svc.wait_for_line(rf"no GPS position: heading is {north}", 10.0)
        assert line is not None, svc.log_tail()
        wait_outputs(v, 75)
        assert svc.stop() == 0
    score = v.score()
    # as with the field given (the measured dip and |B| are the compass's own, within its noise)
    assert score.broken == 0 and score.angle_rms_deg < 1.0, score
