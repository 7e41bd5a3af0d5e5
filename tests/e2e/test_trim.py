"""ArduPilot's level trim end to end: a fake vehicle whose board sits turned in its frame (its RAW_IMU the
board's, its ATTITUDE and the truth the frame's) answers the service's PARAM_REQUEST_READ of AHRS_TRIM_X/Y, and
the service's attitude is the frame's."""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import pytest

from mavattitude.sim import scenarios

from .conftest import assert_all_outputs_valid, counter, wait_outputs

pytestmark = pytest.mark.e2e

TRIM_DEG = (3.0, -6.0)  # the board 6.7° off the frame: an attitude of the board's would score that much


def test_the_vehicles_level_trim_is_asked_for_and_the_attitude_is_its_frames(fly: Callable[..., Any]) -> None:
    script = scenarios.slow_rotation(120.0)
    with fly(script, scenarios.paper_sensors(200.0), trim_deg=TRIM_DEG) as (vehicle, service):
        wait_outputs(vehicle, 100)
        assert service.stop() == 0
        # the trim's two and the use of each of the three compasses, each answered at the first asking
        assert counter(service, "parameter_requests") == 5
    assert not [t for t in vehicle.statustexts if "compass" in t]  # it uses that compass: nothing to say
    # the trim arrives before the IMU stream's first second is through; scored after it, as test_profiles'
    # estimator runs are (under a degree with the paper's noise)
    score = vehicle.score(since_script_s=1.0)
    assert score.broken == 0 and score.angle_rms_deg < 1.0, score
    assert_all_outputs_valid(vehicle)
