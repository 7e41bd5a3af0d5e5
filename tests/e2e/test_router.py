"""The service behind MAVProxy as the router between autopilot and companion computer."""

from __future__ import annotations

import time
from collections import Counter
from pathlib import Path

import pytest
from pymavlink import mavutil

from mavattitude.sim import scenarios
from mavattitude.sim.daemon import ServiceProcess, config_for
from mavattitude.sim.vehicle import FakeVehicle, VehicleConfig

from .conftest import (
    EVENT_TIMEOUT_S,
    FAST_SERVICE,
    assert_all_outputs_valid,
    routed_flight,
    udp_router,
    wait_outputs,
)

GCS_IMU_SAMPLES = 200  # one second of the vehicle's 200 Hz RAW_IMU, seen by the ground station

pytestmark = pytest.mark.e2e


@pytest.mark.parametrize(("profile", "message"), [("ardupilot", "RAW_IMU"), ("px4", "HIGHRES_IMU")])
def test_through_mavproxy_the_service_works_and_the_router_injects_nothing(
    tmp_path: Path, profile: str, message: str
) -> None:
    script = scenarios.tour(60.0)
    sensors = scenarios.paper_sensors(200.0)
    with routed_flight(script, sensors, tmp_path, profile=profile, message=message, speed=2.0) as (v, svc):
        start = len(v.attitude_log)
        wait_outputs(v, 150)
        assert svc.stop() == 0
        final = svc.final_counters()
    assert_all_outputs_valid(v)
    # The tour's first seconds are a level hold and the start of the acceleration: tilt follows the
    # specific force (see test_maneuver), heading stays within a degree.
    score = v.score(start, since_script_s=0.0)
    assert score.broken == 0 and score.output_rate_hz == pytest.approx(50.0, abs=0.5)
    assert score.heading_rms_deg < 1.0, score
    # Everything the vehicle heard came from the service (system 1, component 191) through the router:
    # MAVProxy sent no heartbeat, stream request or parameter fetch of its own (it is system 255).
    sources = {(sysid, compid) for sysid, compid, _ in v.received}
    assert sources == {(1, 191)}, v.received
    kinds = {kind for _, _, kind in v.received}
    assert {"HEARTBEAT", "COMMAND_LONG", "ATTITUDE_QUATERNION"} <= kinds
    # The service's ACK came back through the router too, and it counted every output that arrived.
    assert final["acks.accepted"] >= 1
    assert final["emitted"] == len(v.attitude_log)
    assert final["same_id"] == 0  # no program but the service spoke as (1, 191): none said to


def test_mavproxy_does_not_route_between_its_outputs_so_a_second_ground_station_never_sees_the_attitude(
    tmp_path: Path,
) -> None:
    """What the README warns about: a ground station on another --out sees the autopilot, not the service."""
    gcs = mavutil.mavlink_connection("udpin:127.0.0.1:0", source_system=255)
    gcs_port = gcs.port.getsockname()[1]
    seen: Counter[str] = Counter()
    script = scenarios.static(60.0)
    with routed_flight(
        script, scenarios.paper_sensors(200.0), tmp_path, other_outs=[f"udpout:127.0.0.1:{gcs_port}"]
    ) as (v, _):
        start = len(v.attitude_log)
        deadline = time.monotonic() + EVENT_TIMEOUT_S
        while seen["RAW_IMU"] < GCS_IMU_SAMPLES and time.monotonic() < deadline:
            msg = gcs.recv_match(blocking=True, timeout=0.1)
            if msg is not None:
                seen[msg.get_type()] += 1
        routed_to_vehicle = len(v.attitude_log) - start
    gcs.close()
    assert seen["RAW_IMU"] >= GCS_IMU_SAMPLES, seen  # the autopilot's messages do reach the second output
    # ~1 s of the vehicle's 200 Hz stream: the service sent ~50 ATTITUDE_QUATERNION through MAVProxy meanwhile.
    assert routed_to_vehicle > 0
    assert seen["ATTITUDE_QUATERNION"] == 0, seen


SAME_ID = "another program sends HEARTBEATs as system 1, component 191, our id"


def test_two_services_behind_one_router_each_say_the_other_is_under_its_id() -> None:
    """The systemd service and a `mavattitude run` started by hand, both behind one router (mavlink-router's wiring,
    which routes each client's messages to the others): both speak as system 1, component 191. Alone behind the
    router a service says nothing; once the second runs, each says the other is under its id (log and
    STATUSTEXT)."""
    script = scenarios.static(60.0)
    with (
        FakeVehicle(script, scenarios.paper_sensors(200.0), VehicleConfig("udpin:127.0.0.1:0")) as v,
        udp_router(v.port) as port,
    ):
        config = config_for(v, **FAST_SERVICE)
        config["link"]["connect"] = f"udpout:127.0.0.1:{port}"
        with ServiceProcess(config) as first:
            wait_outputs(v, 100)  # two seconds of attitudes through the router: two of its 1 Hz HEARTBEATs or more
            alone = list(first.lines)
            with ServiceProcess(config) as second:
                for svc in (first, second):
                    assert svc.wait_for_line(SAME_ID, EVENT_TIMEOUT_S) is not None, svc.log_tail()
                said = "mavattitude: comp 191 also used by another"
                assert v.wait_until(lambda: said in v.statustexts, EVENT_TIMEOUT_S)
                assert second.stop() == 0
            assert first.stop() == 0
    assert not any(SAME_ID in line for line in alone)
