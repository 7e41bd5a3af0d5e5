"""The service on a TCP link (``tcp:`` client to a ``tcpin`` vehicle), and its reconnection when the
link drops."""

from __future__ import annotations

import pytest

from mavattitude.sim import scenarios
from mavattitude.sim.daemon import ServiceProcess, config_for
from mavattitude.sim.vehicle import FakeVehicle, VehicleConfig

from .conftest import FAST_SERVICE, START_TIMEOUT_S, assert_healthy, merged, wait_counter

pytestmark = pytest.mark.e2e

HEALTHY_DEG = 2.0  # paper noise, static: ≈ 0.3° RMS (see test_faults)


def test_tcp_link_and_reconnect_after_a_drop() -> None:
    config = VehicleConfig("tcpin:127.0.0.1:0", fly_when_asked=True)
    with FakeVehicle(scenarios.static(3600.0), scenarios.paper_sensors(200.0), config) as v:
        service = config_for(v, **merged(FAST_SERVICE))
        service["link"]["connect"] = f"tcp:127.0.0.1:{v.port}"
        with ServiceProcess(service) as svc:
            assert v.wait_for_outputs(1, START_TIMEOUT_S), svc.log_tail()
            assert_healthy(v, HEALTHY_DEG)
            reconnects = svc.counters[-1].get("reconnects", 0.0)
            v.drop_client()
            # The service notices, reconnects with back-off, asks for the IMU again and carries on.
            wait_counter(svc, "reconnects", reconnects + 1)
            assert_healthy(v, HEALTHY_DEG)
            assert svc.stop() == 0
