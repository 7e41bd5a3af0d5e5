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
from mavattitude.sim.trajectory import GRAVITY_NED_MPS2, Fly, Hold, Script

from .conftest import assert_all_outputs_valid, wait_counter

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


def test_sustained_turn_holds_the_tilt_with_the_gps_velocity_live(fly: Callable[..., Any]) -> None:
    """A coordinated turn at a 27° bank for 20 s through the live service in fused mode: it asks the fake vehicle
    for GPS_RAW_INT, takes the vehicle's acceleration from its velocity (centripetal, 4.9 m/s² at the peak) and
    holds the tilt: measured 0.63° RMS, 0.86° at worst over the turn (without the velocity, ``gps_max_accel_mps2:
    0``: 1.48° RMS, 3.8° at worst). The bounds: 1° RMS (the harder SITL flight's target, 0.8°, with a margin for
    the link) and 2.5° at worst (its p99 target)."""
    script = Script(
        [Hold(3.0), Fly(3.0, delta_vel_ned_mps=(10.0, 0.0, 0.0)), Fly(20.0, turn_rad=2.0 * np.pi), Hold(2.0)],
        scenarios.DEFAULT_MAG_NED_UT,
    )
    service = {"estimator": {"method": "fused"}}
    with fly(script, scenarios.consumer_sensors(200.0), service, speed=4.0) as (v, svc):
        assert v.wait_for_script_time(script.duration_s - 0.5, 30.0)
        gps_updates = wait_counter(svc, "fused.gps_updates", 500.0)
    assert_all_outputs_valid(v)
    c = v.comparison(since_script_s=8.0)  # the turn's sustained part on
    turn = c.t_s < 26.0
    tilt = np.degrees(tilt_error(c.q_est[turn], c.q_true[turn]))
    assert np.sqrt(np.mean(tilt**2)) < 1.0 and tilt.max() < 2.5, f"tilt RMS {np.sqrt(np.mean(tilt**2)):.2f}°"
    assert gps_updates >= 500  # 50 Hz updates with the acceleration removed: from the second fix on
