"""The service on a serial device: a real tty (a pseudo-terminal, read through pyserial) whose far end carries
the fake vehicle's bytes, as a companion computer wired straight to the autopilot's UART has it."""

from __future__ import annotations

import pytest

from mavattitude.sim import scenarios
from mavattitude.sim.daemon import ServiceProcess, config_for
from mavattitude.sim.relay import serial_relay
from mavattitude.sim.vehicle import FakeVehicle, VehicleConfig

from .conftest import FAST_SERVICE, START_TIMEOUT_S, assert_healthy, counter, merged, wait_counter

pytestmark = pytest.mark.e2e

HEALTHY_DEG = 2.0  # paper noise, static: ≈ 0.3° RMS (see test_faults)


def test_serial_device_link() -> None:
    config = VehicleConfig("udpin:127.0.0.1:0", fly_when_asked=True)
    vehicle = FakeVehicle(scenarios.static(3600.0), scenarios.paper_sensors(200.0), config)
    with vehicle as v, serial_relay(v.port) as device:
        service = config_for(v, **merged(FAST_SERVICE))
        service["link"]["connect"] = f"{device},921600"
        with ServiceProcess(service) as svc:
            # the service found the vehicle on the device (its heartbeat), asked for the IMU and answers
            assert v.wait_for_outputs(1, START_TIMEOUT_S), svc.log_tail()
            assert_healthy(v, HEALTHY_DEG)
            wait_counter(svc, "received", 200)
            assert counter(svc, "bad_data") == 0  # every frame whole across the tty's reads
            assert svc.stop() == 0
