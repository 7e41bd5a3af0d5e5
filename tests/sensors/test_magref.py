"""The magnetic reference: angles, a vector, the WMM of the date at the vehicle's position, the field measured
from the compass without one."""

from __future__ import annotations

import datetime as dt
import logging
import math

import numpy as np
import pytest

from mavattitude.errors import ConfigError
from mavattitude.sensors.magref import (
    MIN_MEASURED_TICKS,
    WMM_FIRST_DAY,
    WMM_LAST_DAY,
    MagneticReference,
    ReferenceTracker,
    decimal_year,
    distance_km,
    field_from_angles,
    wmm_field_ned_uT,
)

DATE = dt.date(2026, 6, 1)


def test_angles_give_the_ned_field() -> None:
    n, e, d = field_from_angles(10.0, 60.0, 50.0)
    assert math.hypot(n, e, d) == pytest.approx(50.0)
    assert math.degrees(math.atan2(e, n)) == pytest.approx(10.0)  # declination east of north
    assert math.degrees(math.atan2(d, math.hypot(n, e))) == pytest.approx(60.0)  # inclination, down positive
    ref = ReferenceTracker(MagneticReference("angles", declination_deg=10.0, inclination_deg=60.0))
    assert ref.reference.intensity_uT is None and math.hypot(*ref.reference.field_ned_uT) == pytest.approx(1.0)


def test_vector_mode_and_checks() -> None:
    ref = ReferenceTracker(MagneticReference("vector", field_ned_uT=(20.0, 1.0, 44.0)))
    assert ref.reference.field_ned_uT == (20.0, 1.0, 44.0) and not ref.waiting
    assert ref.reference.intensity_uT == pytest.approx(math.hypot(20.0, 1.0, 44.0))
    assert ref.update_position(47.0, 8.0, 400.0) is False  # a fixed reference ignores positions
    with pytest.raises(ConfigError, match="field_ned_uT: the field vector is zero"):
        MagneticReference("vector", field_ned_uT=(0.0, 0.0, 0.0))
    with pytest.raises(ConfigError, match="inclination_deg: missing"):
        MagneticReference("angles", declination_deg=3.0)
    with pytest.raises(ConfigError, match="mode: 'wmm': expected auto, angles, vector"):
        MagneticReference("wmm")


def test_auto_waits_for_a_position_then_uses_wmm() -> None:
    ref = ReferenceTracker(MagneticReference("auto"))
    assert ref.waiting and ref.reference.source == "waiting" and ref.reference.field_ned_uT is None
    assert ref.update_position(48.137, 11.575, 520.0, DATE) is True  # Munich
    n, e, d = ref.reference.field_ned_uT
    # published figures for Munich, 2025–2026: declination ≈ +4.4°, inclination ≈ 64.3°, ≈ 48.6 µT
    assert math.degrees(math.atan2(e, n)) == pytest.approx(4.4, abs=0.6)
    assert math.degrees(math.atan2(d, math.hypot(n, e))) == pytest.approx(64.3, abs=0.5)
    assert math.hypot(n, e, d) == pytest.approx(48.6, abs=0.8)
    assert ref.reference.source == "wmm" and not ref.waiting


def test_auto_recomputes_only_after_moving_a_few_km() -> None:
    ref = ReferenceTracker(MagneticReference("auto"), recompute_distance_km=5.0)
    ref.update_position(-33.86, 151.21, 0.0, DATE)  # Sydney: the field points up (negative down component)
    assert ref.reference.field_ned_uT[2] < 0.0
    first = ref.reference
    assert ref.update_position(-33.87, 151.21, 0.0, DATE) is False  # 1.1 km
    assert ref.reference is first
    assert ref.update_position(-33.95, 151.21, 0.0, DATE) is True  # 10 km
    assert ref.reference.field_ned_uT != first.field_ned_uT


def test_altitude_is_metres_and_weakens_the_field() -> None:
    low = math.hypot(*wmm_field_ned_uT(0.0, 0.0, 0.0, DATE))
    high = math.hypot(*wmm_field_ned_uT(0.0, 0.0, 100_000.0, DATE))
    # a dipole field falls as r⁻³: 100 km up is (6371 / 6471)³ = 0.954 of the ground value; the model's
    # higher-degree terms fall faster (r⁻⁴ and beyond), so a little lower. Metres read as km would give ~0.
    assert high / low == pytest.approx((6371.0 / 6471.0) ** 3, abs=0.02)


def test_haversine_distance() -> None:
    assert distance_km(0.0, 0.0, 0.0, 1.0) == pytest.approx(111.19, abs=0.01)


@pytest.mark.parametrize(
    ("day", "coefficients"),
    [
        (dt.date(2012, 7, 1), "wmm/WMM_2010.COF"),
        (dt.date(2014, 12, 31), "wmm/WMM_2010.COF"),
        (dt.date(2016, 4, 18), "wmm/WMM_2015v2.COF"),
        (dt.date(2023, 4, 18), "wmm/WMM_2020.COF"),
        (dt.date(2029, 12, 31), "wmm/WMM_2025.COF"),
    ],
)
def test_the_model_of_the_logs_own_epoch_without_a_warning(caplog, day, coefficients):
    from pygeomag import GeoMag

    caplog.set_level(logging.WARNING, logger="mavattitude.sensors.magref")
    ref = ReferenceTracker(MagneticReference("auto"))
    assert ref.update_position(-35.36, 149.17, 584.0, day)
    # pygeomag itself, with that release's coefficients, on the same decimal year
    expected = GeoMag(coefficients_file=coefficients).calculate(-35.36, 149.17, 0.584, decimal_year(day))
    assert ref.reference.field_ned_uT == pytest.approx((expected.x / 1e3, expected.y / 1e3, expected.z / 1e3), abs=1e-9)
    assert ref.reference.label.startswith(f"WMM{coefficients[8:-4].replace('_', '')} at -35.3600°, 149.1700° on {day}")
    assert not caplog.records


def test_a_date_outside_every_model_is_clamped_to_the_nearest_edge_with_one_warning(caplog):
    caplog.set_level(logging.WARNING, logger="mavattitude.sensors.magref")
    ref = ReferenceTracker(MagneticReference("auto"))
    assert ref.update_position(47.0, 8.0, 500.0, dt.date(2009, 5, 1))  # a board clock before 2010: the first day
    assert ref.reference.field_ned_uT == pytest.approx(wmm_field_ned_uT(47.0, 8.0, 500.0, WMM_FIRST_DAY))
    assert (dt.date(2010, 1, 1), dt.date(2029, 12, 31)) == (WMM_FIRST_DAY, WMM_LAST_DAY)
    assert ref.update_position(48.0, 8.0, 500.0, dt.date(2041, 1, 1))  # a board clock far ahead: the last day
    assert ref.reference.field_ned_uT == pytest.approx(wmm_field_ned_uT(48.0, 8.0, 500.0, WMM_LAST_DAY))
    warnings = [r.getMessage() for r in caplog.records]
    assert len(warnings) == 1 and "2009-05-01 is outside the World Magnetic Model's span" in warnings[0]
    assert "--declination DEG --inclination DEG" in warnings[0]


def quiet_ticks(ref: ReferenceTracker, t_s: np.ndarray, dip_deg: float, field_uT: float) -> list[bool]:
    return [ref.observe(float(t), dip_deg, field_uT) for t in t_s]


def test_without_a_position_the_field_is_measured_after_the_wait(caplog):
    caplog.set_level(logging.INFO, logger="mavattitude.sensors.magref")
    ref = ReferenceTracker(MagneticReference("auto"), position_wait_s=2.0)
    moving = quiet_ticks(ref, 100.0 + np.arange(150) / 50.0, math.nan, math.nan)  # 3 s, never quiet: waits on
    assert not any(moving) and ref.waiting
    # quiet ticks at 50 Hz, the dip alternating 57 ± 1° and |B| 48 ± 2 µT: their means are the field
    t = 103.0 + np.arange(MIN_MEASURED_TICKS) / 50.0
    taken = [ref.observe(float(ti), 57.0 + (-1) ** i, 48.0 + 2 * (-1) ** i) for i, ti in enumerate(t)]
    assert taken == [False] * (MIN_MEASURED_TICKS - 1) + [True]  # the wait is over: the 25th quiet tick decides
    assert ref.measured and ref.reference.intensity_uT == pytest.approx(48.0 + 2 / MIN_MEASURED_TICKS)
    n, e, d = ref.reference.field_ned_uT
    assert e == 0.0 and n > 0.0  # declination 0: heading is magnetic north
    assert math.degrees(math.atan2(d, n)) == pytest.approx(57.0 + 1 / MIN_MEASURED_TICKS)  # 13 ticks of 58°, 12 of 56°
    assert "no GPS position: heading is magnetic north, field measured from the compass: dip 57.0°, 48.1 µT" in (
        caplog.records[-1].getMessage()
    )
    assert ref.observe(200.0, 10.0, 10.0) is False  # measured once: kept until a position
    assert ref.update_position(47.0, 8.0, 500.0, DATE) and ref.reference.source == "wmm"  # a later fix: the WMM
    then = f"then WMM2025 at 47.0000°, 8.0000° on {DATE}"
    assert ref.describe() == f"measured: dip 57.0°, 48.1 µT, magnetic north; {then}"


def test_the_wait_is_vehicle_time_and_starts_over_when_the_time_goes_back():
    ref = ReferenceTracker(MagneticReference("auto"), position_wait_s=5.0)
    assert not any(quiet_ticks(ref, 10.0 + np.arange(200) / 50.0, 60.0, 50.0))  # 4 s: quiet, but within the wait
    assert not any(quiet_ticks(ref, np.arange(200) / 50.0, 60.0, 50.0))  # a reboot: 4 s from its own start
    assert quiet_ticks(ref, [5.0], 60.0, 50.0) == [True]
    assert ref.describe() == "measured: dip 60.0°, 50.0 µT, magnetic north"


def test_a_position_within_the_wait_is_used_and_a_fixed_reference_measures_nothing():
    ref = ReferenceTracker(MagneticReference("auto"), position_wait_s=5.0)
    assert not any(quiet_ticks(ref, np.arange(100) / 50.0, 60.0, 50.0))
    assert ref.update_position(47.0, 8.0, 500.0, DATE) and ref.reference.source == "wmm"
    assert not any(quiet_ticks(ref, 2.0 + np.arange(400) / 50.0, 60.0, 50.0)) and ref.reference.source == "wmm"
    given = ReferenceTracker(MagneticReference("angles", declination_deg=3.0, inclination_deg=60.0))
    assert not any(quiet_ticks(given, np.arange(400) / 50.0, 60.0, 50.0))
    assert given.describe() == "given: declination 3°, inclination 60°"
    assert ReferenceTracker(MagneticReference("auto")).describe() == "none"


def test_the_vehicles_date_arriving_after_the_first_position_replaces_the_clocks() -> None:
    # live, GLOBAL_POSITION_INT may come before SYSTEM_TIME: the first field is then the companion clock's
    ref = ReferenceTracker(MagneticReference("auto"))
    assert ref.update_position(47.0, 8.0, 500.0) is True
    later = dt.date(2029, 6, 1)
    assert ref.update_position(47.0, 8.0, 500.0, later) is True  # same place, the vehicle's date now
    assert ref.reference.field_ned_uT == pytest.approx(wmm_field_ned_uT(47.0, 8.0, 500.0, later))
    assert ref.update_position(47.0, 8.0, 500.0, later) is False  # nothing new: no new reference
    assert ref.update_position(47.0, 8.0, 500.0) is False  # a fix without a date keeps the vehicle's


def test_the_summary_names_the_first_and_the_last_reference_and_counts_those_between():
    ref = ReferenceTracker(MagneticReference("auto"), recompute_distance_km=5.0)
    for lat in (47.0, 47.1, 47.2, 47.2, 47.3):  # 11 km steps: a new look-up each, but for the repeated place
        ref.update_position(lat, 8.0, 500.0, DATE)
    first, last = (f"WMM2025 at {lat:.4f}°, 8.0000° on {DATE}" for lat in (47.0, 47.3))
    assert ref.describe() == f"{first}; then {last} (+2 more WMM look-ups)"


def test_the_autopilots_declination_turns_a_measured_field_to_its_north(caplog):
    """A measured field has no declination of its own: the autopilot's (ArduPilot's COMPASS_DEC) makes its heading
    the autopilot's north; a field from the model keeps the model's."""
    caplog.set_level(logging.INFO, logger="mavattitude.sensors.magref")
    ref = ReferenceTracker(MagneticReference("auto"), position_wait_s=2.0)
    assert not ref.set_declination(12.8, "COMPASS_DEC")  # nothing measured yet: kept for the field to come
    assert any(quiet_ticks(ref, 100.0 + np.arange(150) / 50.0, 60.0, 50.0))
    n, e, d = ref.reference.field_ned_uT
    assert math.degrees(math.atan2(e, n)) == pytest.approx(12.8) and math.degrees(math.atan2(d, math.hypot(n, e))) == (
        pytest.approx(60.0)
    )
    said = "no GPS position: heading is north as the autopilot's: declination +12.8° (COMPASS_DEC), field measured"
    assert said in caplog.records[-1].getMessage()
    assert not ref.set_declination(12.8, "COMPASS_DEC")  # said again: nothing changes
    assert ref.set_declination(-3.0, "COMPASS_DEC")  # changed in flight: the measured field turned at once
    n, e, _ = ref.reference.field_ned_uT
    assert math.degrees(math.atan2(e, n)) == pytest.approx(-3.0) and ref.reference.intensity_uT == 50.0
    measured = "measured: dip 60.0°, 50.0 µT, north as the autopilot's: declination {} (COMPASS_DEC)"
    assert ref.describe() == measured.format("+12.8°") + "; then " + measured.format("-3.0°")  # the first and last
    assert ref.update_position(47.0, 8.0, 500.0, DATE)
    wmm = ref.reference.field_ned_uT
    assert not ref.set_declination(20.0, "COMPASS_DEC") and ref.reference.field_ned_uT == wmm  # the model's own
