"""A maneuvering flight through the service: the tilt error is exactly what physics says it must be.

An accelerometer + magnetometer attitude takes the specific force for "up". In the multirotor flight
of ``scenarios.maneuver`` (accelerations up to 4 m/s², a coordinated turn, a climb) the specific force
leans away from the vertical by the *conflict angle* ∠(a − g, −g); the service's tilt error must track
that angle (and vanish in the holds), or the sensor plumbing, frames or time stamps are wrong.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numpy as np
import pytest

from mavattitude.sim import scenarios
from mavattitude.sim.scoring import tilt_error
from mavattitude.sim.trajectory import GRAVITY_NED_MPS2

from .conftest import assert_all_outputs_valid

pytestmark = pytest.mark.e2e

# The 2nd-order 10 Hz Butterworth delays a slow signal by its group delay ≈ √2/(2π·10 Hz) = 22.5 ms.
GROUP_DELAY_S = np.sqrt(2) / (2 * np.pi * 10.0)


def conflict_angle(script: Any, t_s: np.ndarray) -> np.ndarray:
    acc = script.sample(t_s).acc_ned_mps2
    f, up = acc - GRAVITY_NED_MPS2, -GRAVITY_NED_MPS2
    return np.arctan2(np.linalg.norm(np.cross(f, up), axis=-1), f @ up)


def test_maneuvering_flight_tilt_error_is_the_specific_force_conflict(fly: Callable[..., Any]) -> None:
    script = scenarios.maneuver(26.0)
    # Speed ×4: the 26 s flight in 6.5 s of wall time.
    with fly(script, scenarios.paper_sensors(200.0), speed=4.0) as (v, _svc):
        assert v.wait_for_script_time(25.5, 30.0)
    assert_all_outputs_valid(v)
    c = v.comparison(since_script_s=0.5)  # past the filter's start
    tilt = tilt_error(c.q_est, c.q_true)
    conflict = conflict_angle(script, c.t_s)
    assert np.degrees(conflict.max()) > 20.0  # the flight does lean the specific force hard
    # Bound on |tilt − conflict|: the magnetometer's share of the IGN weights pulls the answer back by
    # at most a_mag/(a_mag + a_acc) ≈ 4% of the conflict with the paper's noise (10% allowed); the
    # low-pass lags the conflict by its group delay; noise: where |a| departs from g (the climb) the front
    # end down-weights the accelerometer, and tilt carries magnetometer noise, 0.25 µT / 50 µT ≈ 0.29° per
    # sample, ÷3 after the low-pass: 5σ ≈ 0.5°.
    rate = np.abs(np.gradient(conflict, c.t_s))
    bound = 0.10 * conflict + 1.5 * GROUP_DELAY_S * rate + np.radians(0.5)
    worst = np.argmax(np.abs(tilt - conflict) - bound)
    assert np.all(np.abs(tilt - conflict) <= bound), (
        f"t={c.t_s[worst]:.2f} s tilt {np.degrees(tilt[worst]):.2f}° conflict {np.degrees(conflict[worst]):.2f}°"
    )
    # In the holds at both ends the attitude is right.
    hold = (c.t_s < 2.0) | (c.t_s > 24.2)
    assert np.degrees(np.max(np.linalg.norm(c.error_body_rad[hold], axis=1))) < 1.0
