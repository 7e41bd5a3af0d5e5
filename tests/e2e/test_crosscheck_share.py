"""The live cross-check pairs every ATTITUDE inside our output span, at the IMU's full rate, at a telemetry
rate too slow to filter (one attitude per sample), and with a magnetometer that reads zero (roll and pitch
only): the daemon as a real subprocess against the fake vehicle, the share read from its counters line."""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from typing import Any

import numpy as np
import pytest

from mavattitude.estimation.conventions import euler_from_quat, rotate_ned_to_body
from mavattitude.sim import scenarios
from mavattitude.sim.daemon import ServiceProcess
from mavattitude.sim.sensors import AxisModel
from mavattitude.sim.trajectory import Hold, Rotate, Script
from mavattitude.sim.vehicle import FakeVehicle

from .conftest import EVENT_TIMEOUT_S, drain, wait_outputs

pytestmark = pytest.mark.e2e

MIN_SHARE = 0.95  # the target: the autopilot's attitudes inside our output span that are paired
FIELD = (21.5, 1.3, 43.3)  # µT NED, the field the config gives (no GPS wait)
SERVICE = {"reference": {"magnetic": {"field_ned_uT": list(FIELD)}}}


def _turning() -> Script:
    return Script([Hold(1.0), Rotate(59.0, (0.03, -0.05, 0.08))], FIELD)


def _settled(v: FakeVehicle, svc: ServiceProcess) -> dict[str, float]:
    """Stop the IMU, wait until the service has sent every output the vehicle got and logged them; its counters."""
    drain(v, svc)
    ok = svc.wait_until(
        lambda: bool(svc.counters) and svc.counters[-1].get("emitted", 0.0) >= len(v.attitude_log), EVENT_TIMEOUT_S
    )
    assert ok, svc.log_tail()
    return svc.latest_counters()


def _inside_span(v: FakeVehicle) -> int:
    """ATTITUDE messages the vehicle sent between our first and last output (vehicle time)."""
    ours = [row[1] for row in v.attitude_log]
    sent = np.array(v.attitudes_sent_s)
    return int(np.count_nonzero((sent >= ours[0]) & (sent <= ours[-1])))


def _assert_share(c: dict[str, float], inside: int) -> None:
    pairs, missed = c["xc_pairs"], c["xc_missed"]
    assert pairs >= MIN_SHARE * inside and pairs + missed <= inside, (c, inside)


@pytest.mark.parametrize(
    ("rate_hz", "outputs", "method"),
    [(200.0, 250, "ign"), (2.0, 8, "ign"), (2.0, 8, "fused")],
    ids=["full_rate", "telemetry_2hz", "telemetry_2hz_fused"],
)
def test_every_autopilot_attitude_inside_our_span_is_paired(
    fly: Callable[..., Any], rate_hz: float, outputs: int, method: str
) -> None:
    service = {**SERVICE, "estimator": {"method": method}}
    with fly(_turning(), scenarios.paper_sensors(200.0), service, link_max_imu_hz=rate_hz) as (v, svc):
        wait_outputs(v, outputs, timeout_s=EVENT_TIMEOUT_S + outputs / min(rate_hz, 50.0))
        c = _settled(v, svc)
        what = "too slow to integrate the gyro: one IGN attitude" if method == "fused" else "one attitude"
        slow = svc.wait_for_line(rf"RAW_IMU at [\d.]+ Hz: {what} per sample, no filtering", 0.0)
    _assert_share(c, _inside_span(v))
    assert (slow is not None) == (rate_hz < 20.0) and c["input_lost"] == 0  # a 2 Hz stream is no silence
    assert (c["per_sample"] >= outputs) == (rate_hz < 20.0)


def _tilt_error_deg(v: FakeVehicle) -> np.ndarray:
    """The angle between the vertical in our attitudes and in the truth's, per output (heading left out)."""
    _, t, q = v.outputs_since(0)
    truth = v.script.attitude(t)
    down = np.array([0.0, 0.0, 1.0])
    ours_down = np.array([rotate_ned_to_body(qi, down) for qi in q])
    true_down = np.array([rotate_ned_to_body(qi, down) for qi in truth])
    return np.degrees(np.arccos(np.clip(np.sum(ours_down * true_down, axis=1), -1.0, 1.0)))


def test_a_magnetometer_reading_zero_gives_roll_and_pitch_and_is_still_compared(fly: Callable[..., Any]) -> None:
    """RAW_IMU's magnetometer all zero (no compass): after input_timeout_s without a reading, attitudes with roll
    and pitch from the accelerometer, yaw held at 0 and said unknown; paired with ATTITUDE on the tilt."""
    no_compass = dataclasses.replace(scenarios.paper_sensors(200.0), mag=AxisModel(matrix=((0.0,) * 3,) * 3))
    with fly(_turning(), no_compass, SERVICE) as (v, svc):
        wait_outputs(v, 250)
        c = _settled(v, svc)
        said = svc.wait_for_line(r"no RAW_IMU magnetometer reading: roll and pitch from the accelerometer", 0.0)
    assert said is not None and c["emitted"] >= 250
    _assert_share(c, _inside_span(v))
    # paper accelerometer noise through the 10 Hz low-pass (~0.1° of tilt) and a 0.1 rad/s turn's lag: 1° is
    # far outside both and far inside a heading mistaken for tilt
    assert np.percentile(_tilt_error_deg(v), 99) < 1.0
    _, _, q = v.outputs_since(0)
    assert np.max(np.abs(np.degrees(euler_from_quat(q)[:, 2]))) < 1e-6  # yaw held at 0
