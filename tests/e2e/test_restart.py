"""An autopilot that restarts in flight, end to end: silent for seconds (no HEARTBEAT, deaf to requests), then back
with its streams off, as ArduPilot boots. The service says the silence and asks for its stream as soon as it hears
the HEARTBEAT again, not at its next periodic request."""

from __future__ import annotations

import time
from collections.abc import Callable
from typing import Any

import pytest

from mavattitude.service import HEARTBEAT_LOST_S
from mavattitude.sim import scenarios

from .conftest import EVENT_TIMEOUT_S, wait_counter

pytestmark = pytest.mark.e2e

REPEAT_S = 60.0  # the periodic request: far beyond the test, so only the return's own request restarts the stream
DOWN_S = HEARTBEAT_LOST_S + 1.5  # silent long enough to count as lost (its 1 Hz HEARTBEAT missed 5 s)
BACK_WITHIN_S = 2.0  # its first HEARTBEAT (≤ 1 s after boot), a request, the stream, a 50 Hz tick: well under 2 s


def test_a_restarted_autopilot_is_said_and_streams_again_as_soon_as_it_is_back(fly: Callable[..., Any]) -> None:
    service_config = {"link": {"request_repeat_s": REPEAT_S}}
    with fly(scenarios.static(120.0), scenarios.paper_sensors(200.0), service_config) as (vehicle, service):
        vehicle.reboot(down_s=DOWN_S)
        said = service.wait_for_line("no HEARTBEAT from the autopilot", DOWN_S + EVENT_TIMEOUT_S)
        outputs = len(vehicle.attitude_log)
        booted = time.monotonic() + max(0.0, DOWN_S - HEARTBEAT_LOST_S)
        assert vehicle.wait_for_outputs(outputs + 1, DOWN_S + EVENT_TIMEOUT_S), service.log_tail()
        back_s = time.monotonic() - booted
        assert wait_counter(service, "autopilot_silent", 1) == 1
        assert service.stop() == 0
    assert said is not None and "(system 1, component 1)" in said
    assert back_s < BACK_WITHIN_S, (back_s, service.log_tail())
