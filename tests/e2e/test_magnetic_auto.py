"""``reference.magnetic: auto``: the service takes the field from the World Magnetic Model at the
vehicle's GLOBAL_POSITION_INT, and flies right when the truth is that field."""

from __future__ import annotations

import datetime as dt
from collections.abc import Callable
from typing import Any

import pytest

from mavattitude.sensors.magref import wmm_field_ned_uT
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
