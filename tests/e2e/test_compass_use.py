"""Whether the autopilot uses the compass our heading comes from, end to end: a fake vehicle that set its first
compass aside (COMPASS_USE 0) answers the service's PARAM_REQUEST_READ, and the service says so to the pilot."""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import pytest

from mavattitude.sim import scenarios

from .conftest import EVENT_TIMEOUT_S

pytestmark = pytest.mark.e2e

TEXT = "mavattitude: compass 1 unused by autopilot"


def test_a_compass_the_autopilot_set_aside_is_said_to_the_pilot(fly: Callable[..., Any]) -> None:
    with fly(scenarios.static(120.0), scenarios.paper_sensors(200.0), compass_use=(0, 1, 1)) as (vehicle, service):
        assert vehicle.wait_until(lambda: TEXT in vehicle.statustexts, EVENT_TIMEOUT_S), vehicle.statustexts
        said = service.wait_for_line("does not use compass 1", EVENT_TIMEOUT_S)
        assert service.stop() == 0
    assert said is not None and "(COMPASS_USE 0)" in said
    assert said.endswith("it uses compass 2: input.message SCALED_IMU2 carries it")  # its COMPASS_USE2 1
    assert vehicle.statustexts.count(TEXT) == 1  # answered again at each repeat of the asking: said once
