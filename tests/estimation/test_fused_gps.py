"""The fused filter's GPS-velocity acceleration: the gates, sustained turns, glitches, and no GPS as before.

Synthetic flights from :mod:`mavattitude.sim` (truth script, consumer sensors and a GPS receiver model, seeded).
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from mavattitude.estimation.fused import FusedFilter, FusedSettings
from mavattitude.estimation.fused.gps import GpsAcceleration
from mavattitude.sensors.units import GpsVelocity, decode_gps_velocity
from mavattitude.sim import scenarios
from mavattitude.sim.scoring import tilt_error
from mavattitude.sim.sensors import GpsModel
from mavattitude.sim.trajectory import Script

SEED = 20261128
MAG_NED_UT = np.array(scenarios.DEFAULT_MAG_NED_UT)


def _velocity(t_s: float, vel: tuple[float, float, float], fix: int = 3, satellites: int = 10) -> GpsVelocity:
    return GpsVelocity(t_s, vel, True, fix, satellites)


def _fly(
    script: Script, gps: tuple[np.ndarray, list[GpsVelocity]] | None, settings: FusedSettings | None = None
) -> tuple[FusedFilter, np.ndarray, np.ndarray]:
    """The filter over the script's consumer-sensor samples at 50 Hz, the velocities handed in between samples
    as the pipeline hands them; its ticks' times and attitudes."""
    rng = np.random.default_rng(SEED)
    sensors = scenarios.consumer_sensors(50.0)
    t = sensors.sample_times(0.0, script.duration_s, rng)
    acc, gyr, mag = sensors.measure(script, t, rng)
    f = FusedFilter(settings or FusedSettings(), MAG_NED_UT)
    gps_t, velocities = gps if gps is not None else (np.empty(0), [])
    handed = np.searchsorted(t, gps_t)  # each velocity before the first sample at or after its time
    out, k = [], 0
    for i in range(len(t)):
        while k < len(handed) and handed[k] <= i:
            f.set_velocity(velocities[k])
            k += 1
        out += f.push(t[i], gyr[i], acc[i], mag[i])
    return f, np.array([o.time_s for o in out]), np.array([o.q for o in out])


def _tilt_deg(script: Script, times: np.ndarray, q: np.ndarray, since_s: float = 0.0) -> tuple[float, float]:
    """RMS and largest tilt error, degrees, of the ticks from ``since_s`` on."""
    keep = times >= since_s
    err = np.degrees(tilt_error(q[keep], script.attitude(times[keep])))
    return float(np.sqrt(np.mean(err**2))), float(err.max())


# --- the gates ----------------------------------------------------------------------------------------


def test_the_acceleration_is_the_differenced_velocity_held_until_stale() -> None:
    g = GpsAcceleration(FusedSettings())
    g.push(_velocity(10.0, (1.0, 2.0, 0.5)), now_s=10.1)
    assert g.at(10.1) is None  # one velocity: nothing to difference yet
    g.push(_velocity(10.2, (2.0, 1.0, 0.5)), now_s=10.3)
    assert g.at(10.3) == pytest.approx((5.0, -5.0, 0.0))
    assert g.at(10.3 + 1.0) == pytest.approx((5.0, -5.0, 0.0))  # held up to gps_max_interval_s
    assert g.at(10.3 + 1.0001) is None  # then stale: the receiver stopped
    assert (g.accepted, g.refused, g.interval_s, g.age_s) == (1, 0, pytest.approx(0.2), pytest.approx(0.1))


def test_an_unknown_vertical_speed_is_not_differenced() -> None:
    g = GpsAcceleration(FusedSettings())
    g.push(GpsVelocity(0.0, (0.0, 0.0, 0.0), False, 3, 10), now_s=0.0)
    g.push(GpsVelocity(0.2, (1.0, 0.0, 0.0), False, 3, 10), now_s=0.2)
    assert g.at(0.2) == pytest.approx((5.0, 0.0, 0.0))


@pytest.mark.parametrize(
    ("second", "why"),
    [
        (_velocity(0.2, (1.0, 0.0, 0.0), fix=2), "a 2D fix"),
        (_velocity(0.2, (1.0, 0.0, 0.0), satellites=5), "five satellites (ArduPilot's AHRS_GPS_MINSATS is 6)"),
        (_velocity(1.2, (1.0, 0.0, 0.0)), "1.2 s since the last fix: more than gps_max_interval_s"),
        (_velocity(0.0, (1.0, 0.0, 0.0)), "a fix time that does not advance"),
        (_velocity(0.2, (4.1, 0.0, 0.0)), "4.1 m/s in 0.2 s: 20.5 m/s², beyond gps_max_accel_mps2"),
        (_velocity(0.2, (float("nan"), 0.0, 0.0)), "a NaN velocity"),
    ],
)
def test_a_velocity_that_cannot_be_trusted_is_refused_and_drops_the_acceleration(second, why) -> None:
    g = GpsAcceleration(FusedSettings())
    g.push(_velocity(-0.2, (0.0, 0.0, 0.0)), now_s=0.0)
    g.push(_velocity(0.0, (0.0, 0.0, 0.0)), now_s=0.0)
    assert g.at(0.0) == (0.0, 0.0, 0.0)
    g.push(second, now_s=0.1)
    assert g.at(0.1) is None, why
    assert g.refused == 1, why


def test_a_glitch_refuses_the_step_and_the_step_back() -> None:
    g = GpsAcceleration(FusedSettings())
    for i, north in enumerate((0.0, 0.0, 5.0, 0.0, 0.0)):  # one fix 5 m/s off: 25 m/s² each way
        g.push(_velocity(0.2 * i, (north, 0.0, 0.0)), now_s=0.2 * i)
    assert (g.accepted, g.refused) == (2, 2)
    assert g.at(0.8) == (0.0, 0.0, 0.0)


def test_gps_raw_int_speed_and_course_are_a_horizontal_velocity() -> None:
    from pymavlink.dialects.v20 import common

    msg = common.MAVLink_gps_raw_int_message(12_345_000, 3, 0, 0, 0, 65535, 65535, 500, 9000, 11)
    v = decode_gps_velocity(msg)
    assert v is not None and not v.vertical_known and (v.fix_type, v.satellites) == (3, 11)
    assert v.fix_time_s == pytest.approx(12.345) and v.vel_ned_mps == pytest.approx((0.0, 5.0, 0.0), abs=1e-12)
    unknown_speed = common.MAVLink_gps_raw_int_message(0, 3, 0, 0, 0, 65535, 65535, 65535, 9000, 11)
    no_fix = common.MAVLink_gps_raw_int_message(0, 2, 0, 0, 0, 65535, 65535, 500, 9000, 11)
    assert decode_gps_velocity(unknown_speed) is None and decode_gps_velocity(no_fix) is None


# --- flights ------------------------------------------------------------------------------------------


def test_sustained_turns_hold_the_tilt_with_the_gps_velocity() -> None:
    """Coordinated turns at a 27° bank for a minute: without a velocity no gyro + accelerometer filter can tell
    the centripetal acceleration from a tilt (measured 3.0° RMS, 6.9° at worst); with the receiver's (5 Hz,
    0.05 m/s noise, cm/s, handed in 0.1 s after its fix) the tilt holds (measured 0.22° RMS, 0.70° at worst).
    The model's receiver has no latency of its own (``gps_latency_s`` 0): the filter measures the 0.1 s from
    the fix times. The bounds: a fifth of the first, and 1° (the harder SITL flight's target, 0.8° RMS, plus
    margin)."""
    script = scenarios.turns()
    gps = GpsModel().measure(script, script.duration_s, np.random.default_rng(SEED + 1))
    settings = dataclasses.replace(FusedSettings(), gps_latency_s=0.0)
    _, t_without, q_without = _fly(script, None, settings)
    f, t_with, q_with = _fly(script, gps, settings)
    without_rms, _ = _tilt_deg(script, t_without, q_without, since_s=10.0)
    with_rms, with_max = _tilt_deg(script, t_with, q_with, since_s=10.0)
    assert without_rms > 2.5  # the turns really do fool the accelerometer
    assert with_rms <= min(without_rms / 5.0, 1.0) and with_max <= 2.5  # 2.5°: the harder flight's p99 target
    assert f.counters["gps_updates"] > 0.9 * f.counters["updates"] and f.counters["gps_refused"] == 0


def test_without_gps_or_with_it_off_the_filter_is_the_filter_without_gps() -> None:
    """Outputs bit for bit: ``gps_max_accel_mps2: 0`` ignores the velocities, and no velocity changes nothing."""
    script = scenarios.maneuver()
    gps = GpsModel().measure(script, script.duration_s, np.random.default_rng(SEED + 1))
    off = dataclasses.replace(FusedSettings(), gps_max_accel_mps2=0.0)
    f_off, _, q_off = _fly(script, gps, off)
    _, _, q_none = _fly(script, None)
    np.testing.assert_array_equal(q_off, q_none)
    assert f_off.counters["gps_updates"] == 0


def test_a_glitching_receiver_does_not_tilt_a_vehicle_at_rest() -> None:
    """A vehicle on the ground whose receiver jumps by 5 m/s for one fix in ten, for a minute: every jump is
    refused (25 m/s² each way), and the tilt stays within 0.1° of the run without GPS (measured 0.00°)."""
    script = scenarios.static(60.0)
    t_fix = np.arange(0.0, 59.9, 0.2)
    glitches = [_velocity(t, (5.0 if i % 10 == 5 else 0.0, 0.0, 0.0)) for i, t in enumerate(t_fix.tolist())]
    f, _, q_gps = _fly(script, (t_fix + 0.1, glitches))
    _, _, q_none = _fly(script, None)
    assert np.degrees(tilt_error(q_gps, q_none)).max() < 0.1
    assert f.counters["gps_refused"] == 2 * 30
