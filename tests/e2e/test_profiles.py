"""Each unit profile and IMU message, end to end: fake vehicle → UDP → `mavattitude run` → UDP → score."""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import pytest

from mavattitude.sim import scenarios
from mavattitude.sim.daemon import ServiceProcess, config_for
from mavattitude.sim.vehicle import FakeVehicle, VehicleConfig

from .conftest import (
    EVENT_TIMEOUT_S,
    FAST_SERVICE,
    START_TIMEOUT_S,
    assert_all_outputs_valid,
    drain,
    wait_counter,
    wait_outputs,
)

pytestmark = pytest.mark.e2e

CASES = [
    ("ardupilot", "RAW_IMU"),
    ("ardupilot", "SCALED_IMU"),
    ("ardupilot", "SCALED_IMU2"),
    ("ardupilot", "SCALED_IMU3"),
    ("px4", "HIGHRES_IMU"),
    ("px4", "SCALED_IMU"),
    ("adis16405", "RAW_IMU"),
]


@pytest.mark.parametrize(("profile", "message"), CASES)
def test_profile_and_message(fly: Callable[..., Any], profile: str, message: str) -> None:
    script = scenarios.slow_rotation(120.0)
    with fly(script, scenarios.paper_sensors(200.0), profile=profile, message=message) as (vehicle, service):
        wait_outputs(vehicle, 75)
        sent, dropped = drain(vehicle, service)
        assert service.stop() == 0
        final = service.final_counters()
    score = vehicle.score()
    # Paper noise (mag σ ≈ 0.25 µT on a 21.9 µT horizontal field: 0.65° of heading per sample, ÷3 after the
    # 10 Hz low-pass) plus the coarsest quantisation (ADIS accel 3.3 mg, ArduPilot mag 0.1 µT): RMS ≈ 0.3°.
    # A wrong unit or axis gives tens of degrees or no output; 1° RMS / 3° max separate the two.
    assert score.broken == 0
    assert score.angle_rms_deg < 1.0, score
    assert score.angle_max_deg < 3.0, score
    assert score.output_rate_hz == pytest.approx(50.0, abs=0.5)
    assert_all_outputs_valid(vehicle)
    # Counters agree with what went over the wire: every output the service counted arrived, and the
    # vehicle only streams once asked, so the service received all it was sent but what the kernel dropped
    # from its full receive buffer (none on an idle machine): exact, whatever the load.
    assert final["emitted"] == len(vehicle.attitude_log)
    assert final["received"] == sent - dropped
    assert final["acks.accepted"] >= 1 and final["rejected.decode"] == 0


def test_ardupilot_highres_magnetometer_bug_is_refused_not_flown() -> None:
    # ArduPilot's HIGHRES_IMU magnetometer is 10⁶ too large: the service must refuse it with the reason,
    # and send no attitude, rather than fly a wrong one.
    config = VehicleConfig(
        "udpin:127.0.0.1:0", profile="ardupilot", message="HIGHRES_IMU", highres_mag_bug=True, fly_when_asked=True
    )
    vehicle = FakeVehicle(scenarios.static(60.0), scenarios.paper_sensors(200.0), config)
    with vehicle, ServiceProcess(config_for(vehicle, **FAST_SERVICE)) as service:
        wait_counter(service, "rejected.decode", 100, timeout_s=START_TIMEOUT_S)
        assert service.wait_for_line("10⁶ too large", EVENT_TIMEOUT_S) is not None
        assert service.stop() == 0
        final = service.final_counters()
    assert vehicle.imu_sent >= 100
    assert final["emitted"] == 0 and not vehicle.attitude_log


@pytest.mark.parametrize("method", ["cgn", "ml", "triad", "fused"])
def test_each_estimator_method_through_the_service(fly: Callable[..., Any], method: str) -> None:
    # The other estimators the config offers, on the same slow rotation with the paper's noise. CGN's
    # equal weights and TRIAD's accelerometer-first split let the magnetometer noise into tilt; all stay
    # well under a degree here (the paper's Table 1 level); a wiring mistake would be tens of degrees.
    script = scenarios.slow_rotation(120.0)
    sensors = scenarios.paper_sensors(200.0)
    with fly(script, sensors, {"estimator": {"method": method}}, profile="px4", message="HIGHRES_IMU") as (v, svc):
        wait_outputs(v, 75)
        assert svc.stop() == 0
    score = v.score(since_script_s=0.5)
    assert score.broken == 0 and score.output_rate_hz == pytest.approx(50.0, abs=0.5)
    assert score.angle_rms_deg < 1.0, score
    assert_all_outputs_valid(v)
