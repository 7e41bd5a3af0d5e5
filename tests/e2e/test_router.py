"""The service behind MAVProxy as the router between autopilot and companion computer."""

from __future__ import annotations

from pathlib import Path

import pytest

from mavattitude.sim import scenarios

from .conftest import assert_all_outputs_valid, routed_flight, wait_outputs

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
