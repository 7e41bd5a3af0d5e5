"""MAVLink 2 signing required: the genuine (signed) vehicle is served; a forger's unsigned or wrongly
signed IMU messages, claiming the vehicle's own system id, are ignored and counted."""

from __future__ import annotations

import os
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest

from mavattitude.sim import scenarios
from mavattitude.sim.trajectory import Hold, Script
from mavattitude.sim.vehicle import FakeVehicle, VehicleConfig

from .conftest import Flight, assert_all_outputs_valid, counter, flight, wait_counter, wait_outputs

pytestmark = pytest.mark.e2e

HEALTHY_DEG = 2.0  # paper noise, static: ≈ 0.3° RMS (see test_faults)


@pytest.fixture(scope="module")
def signed(tmp_path_factory: pytest.TempPathFactory) -> Iterator[tuple[Flight, bytes]]:
    key = np.random.default_rng(11).bytes(32)
    key_file = Path(tmp_path_factory.mktemp("signing")) / "vehicle.key"
    key_file.write_bytes(key)
    os.chmod(key_file, 0o600)
    service = {"link": {"signing": {"key_file": str(key_file), "require_signing": True}}}
    script = scenarios.static(3600.0)
    with flight(script, scenarios.paper_sensors(200.0), service, signing_key=key) as f:
        yield f, key
        assert f[1].stop() == 0
        assert_all_outputs_valid(f[0])


@pytest.mark.parametrize("forger_key", [None, b"\x5a" * 32], ids=["unsigned", "wrong-key"])
def test_forged_imu_is_rejected_and_counted(signed: tuple[Flight, bytes], forger_key: bytes | None) -> None:
    (v, svc), key = signed
    assert forger_key != key
    rejected = counter(svc, "signature_rejected")
    index = len(v.attitude_log)
    # The forger claims to be the autopilot (system 1, component 1) and says the vehicle is upside down.
    upside_down = Script([Hold(3600.0)], scenarios.DEFAULT_MAG_NED_UT, q0=(0.0, 1.0, 0.0, 0.0))
    host, port = v.peers()[0]  # the service: the first peer the vehicle heard
    forger = VehicleConfig(f"udpout:{host}:{port}", stream_on_start=True, signing_key=forger_key, seed=9)
    with FakeVehicle(upside_down, scenarios.paper_sensors(200.0), forger):
        wait_counter(svc, "signature_rejected", rejected + 100)
        wait_outputs(v, 25)
    s = v.score(index)
    # Not one forged sample reached the solver: the attitude never left the genuine one.
    assert s.broken == 0 and s.angle_max_deg < HEALTHY_DEG, s
    assert counter(svc, "rejected.decode") == 0
