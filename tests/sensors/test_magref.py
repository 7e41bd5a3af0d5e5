"""The magnetic reference: angles, a vector, and WMM2025 at the vehicle's position (waiting until one)."""

from __future__ import annotations

import datetime as dt
import logging
import math

import pytest

from mavattitude.errors import ConfigError
from mavattitude.sensors.magref import (
    MagneticReference,
    ReferenceTracker,
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


def test_a_date_outside_the_model_is_clamped_to_its_edge_with_one_warning(caplog):
    from mavattitude.sensors.magref import WMM_FIRST_DAY, WMM_LAST_DAY, wmm_field_ned_uT

    caplog.set_level(logging.WARNING, logger="mavattitude.sensors.magref")
    ref = ReferenceTracker(MagneticReference("auto"))
    assert ref.update_position(47.0, 8.0, 500.0, dt.date(2023, 5, 1))  # a 2023 log: no exit, the 2025 field
    assert ref.reference.field_ned_uT == pytest.approx(wmm_field_ned_uT(47.0, 8.0, 500.0, WMM_FIRST_DAY))
    assert ref.update_position(48.0, 8.0, 500.0, dt.date(2041, 1, 1))  # a board clock far ahead: the last day
    assert ref.reference.field_ned_uT == pytest.approx(wmm_field_ned_uT(48.0, 8.0, 500.0, WMM_LAST_DAY))
    warnings = [r.getMessage() for r in caplog.records]
    assert len(warnings) == 1 and "2023-05-01 is outside WMM2025's span" in warnings[0]
    assert "--declination DEG --inclination DEG" in warnings[0]


def test_the_vehicles_date_arriving_after_the_first_position_replaces_the_clocks() -> None:
    # live, GLOBAL_POSITION_INT may come before SYSTEM_TIME: the first field is then the companion clock's
    ref = ReferenceTracker(MagneticReference("auto"))
    assert ref.update_position(47.0, 8.0, 500.0) is True
    later = dt.date(2029, 6, 1)
    assert ref.update_position(47.0, 8.0, 500.0, later) is True  # same place, the vehicle's date now
    assert ref.reference.field_ned_uT == pytest.approx(wmm_field_ned_uT(47.0, 8.0, 500.0, later))
    assert ref.update_position(47.0, 8.0, 500.0, later) is False  # nothing new: no new reference
    assert ref.update_position(47.0, 8.0, 500.0) is False  # a fix without a date keeps the vehicle's
