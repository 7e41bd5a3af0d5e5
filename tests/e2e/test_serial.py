"""The service on a serial device: a real tty (a pseudo-terminal, read through pyserial) whose far end carries
the fake vehicle's bytes, as a companion computer wired straight to the autopilot's UART has it."""

from __future__ import annotations

import re
import signal

import pytest
import yaml

from mavattitude.sim import scenarios
from mavattitude.sim.daemon import ServiceProcess, config_for
from mavattitude.sim.relay import serial_relay
from mavattitude.sim.vehicle import FakeVehicle, VehicleConfig
from tests.commands.process import cli_process
from tests.tools import ROOT

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


def test_simulate_offers_the_vehicle_on_a_serial_device_for_the_service() -> None:
    """`mavattitude simulate --serial` logs its pseudo-terminal; the daemon on the example config, pointed at it,
    attitudes the vehicle, which scores them when interrupted."""
    with cli_process("simulate", "--serial", "--duration", "600", timeout_s=120.0) as proc:
        assert proc.stderr is not None
        first = proc.stderr.readline()
        device = re.search(r"fake vehicle on (/dev/\S+):", first)
        assert device, first
        config = yaml.safe_load((ROOT / "configs" / "ardupilot.yaml").read_text())
        config["link"]["connect"] = f"{device[1]},921600"
        config["output"]["stats_interval_s"] = 0.2
        with ServiceProcess(config) as svc:
            wait_counter(svc, "received", 200)
            assert svc.stop() == 0
        proc.send_signal(signal.SIGINT)
        out, _ = proc.communicate(timeout=30.0)
    received = re.search(r"ATTITUDE_QUATERNION received: (\d+)", out)
    assert received and int(received[1]) > 0, out
