"""mavattitude.sim.daemon: the counters line parser and the config built for a fake vehicle."""

from __future__ import annotations

import pytest

from mavattitude.config import load_config
from mavattitude.sim import scenarios
from mavattitude.sim.daemon import config_for, parse_counters
from mavattitude.sim.vehicle import FakeVehicle, VehicleConfig


def test_parse_counters_reads_the_services_line() -> None:
    line = (
        "2026-01-01 00:00:00,000 INFO mavattitude.service: counters (final): received=36 emitted=10 "
        "rejected.decode=0 rejected.DegenerateGeometryError=3 mean_iterations=2.000 latency_p50_ms=nan acks.accepted=1"
    )
    counters = parse_counters(line)
    assert counters is not None
    assert counters["received"] == 36 and counters["rejected.DegenerateGeometryError"] == 3
    assert counters["acks.accepted"] == 1 and counters["mean_iterations"] == 2.0
    assert counters["latency_p50_ms"] != counters["latency_p50_ms"]  # nan
    assert parse_counters("INFO mavattitude.service: locked onto the autopilot: system 1") is None


@pytest.mark.parametrize(("profile", "message"), [("ardupilot", "RAW_IMU"), ("px4", "HIGHRES_IMU")])
def test_config_for_a_vehicle_is_a_valid_service_config(profile: str, message: str) -> None:
    config = VehicleConfig("udpin:127.0.0.1:0", profile=profile, message=message)
    with FakeVehicle(scenarios.paper_static(10.0), scenarios.ideal_sensors(100.0), config) as vehicle:
        overrides = config_for(vehicle, estimator={"method": "ml"})
        port = vehicle.port
    loaded = load_config(None, overrides=overrides, env={})
    assert loaded.link.connect == f"udpout:127.0.0.1:{port}"
    assert (loaded.input.profile, loaded.input.message) == (profile, message)
    assert loaded.link.request_rate_hz == 100.0 and loaded.estimator.method == "ml"
    assert loaded.reference.magnetic.field_ned_uT == pytest.approx(tuple(scenarios.PAPER_MAG_NED_UT))
    # Ideal sensors have σ = 0; the service gets the encoding's quantisation floor instead.
    assert min(loaded.noise.accel_std_mps2) > 0 and min(loaded.noise.mag_std_uT) > 0
