"""Truth scripts: physics the fake vehicle must get right before anything is scored against it."""

from __future__ import annotations

import numpy as np
import pytest

from mavattitude.errors import InputError
from mavattitude.estimation.conventions import (
    angle_between,
    quat_from_euler,
    quat_from_rotvec,
    quat_multiply,
    rotate_body_to_ned,
)
from mavattitude.sensors.units import STANDARD_GRAVITY_MPS2
from mavattitude.sim import scenarios
from mavattitude.sim.trajectory import Flip, Fly, Hold, Rotate, Script

MAG_NED = scenarios.DEFAULT_MAG_NED_UT


def test_level_and_static_reads_minus_g_and_the_field() -> None:
    truth = scenarios.static(5.0).sample(np.linspace(0, 5, 11))
    np.testing.assert_allclose(truth.specific_force_mps2, np.tile([0, 0, -STANDARD_GRAVITY_MPS2], (11, 1)), atol=1e-12)
    np.testing.assert_allclose(truth.mag_uT, np.tile(MAG_NED, (11, 1)), atol=1e-12)
    np.testing.assert_allclose(truth.gyr_radps, 0.0, atol=1e-9)


def test_paper_static_reproduces_the_papers_body_vectors() -> None:
    truth = scenarios.paper_static(1.0).sample([0.5])
    # The paper's w2 is gravity (|w2| = 9.8 there, 9.80665 here: compare directions); we read −w2.
    w2 = scenarios.PAPER_GRAVITY_BODY_MPS2
    f = truth.specific_force_mps2[0]
    np.testing.assert_allclose(f / np.linalg.norm(f), -w2 / np.linalg.norm(w2), atol=1e-12)
    np.testing.assert_allclose(truth.mag_uT[0], scenarios.PAPER_MAG_BODY_UT, atol=1e-9)
    # docs/paper-notes.md: roll 20°, pitch −30°, yaw 142.2° from magnetic north (printed to 0.1°;
    # 9.8 vs g moves it 1e-4°).
    expected = quat_from_euler(np.radians(20.0), np.radians(-30.0), np.radians(142.2))
    assert np.degrees(angle_between(scenarios.PAPER_Q, expected)) < 0.01


def test_rotate_has_its_constant_body_rate_and_integrates_to_its_attitude() -> None:
    rate = np.array([0.1, -0.2, 0.3])
    script = Script([Rotate(10.0, tuple(rate))], MAG_NED, q0=tuple(quat_from_euler(0.2, 0.1, 1.0)))
    truth = script.sample(np.linspace(0.1, 9.9, 50))
    # Central difference of an exact exponential: error ~ h² |ω|³ ≈ 1e-11 rad/s.
    np.testing.assert_allclose(truth.gyr_radps, np.tile(rate, (50, 1)), atol=1e-6)
    expected = quat_multiply(script.q0, quat_from_rotvec(np.multiply.outer(truth.t_s, rate)))
    assert np.max(angle_between(truth.q, expected)) < 1e-12


def test_flip_passes_through_180_degrees_and_ends_where_it_should() -> None:
    script = Script([Hold(1.0), Flip(0.5, (1.0, 0.0, 0.0), np.pi), Hold(1.0)], MAG_NED)
    inverted = quat_from_euler(np.pi, 0.0, 0.0)
    assert angle_between(script.attitude([2.0])[0], inverted) < 1e-12
    # Integrate the reported body rates (midpoint rule, 0.1 ms): they must carry the attitude there too.
    t = np.arange(1.0, 1.5, 1e-4)
    truth = script.sample(t + 5e-5)
    q = np.array([1.0, 0.0, 0.0, 0.0])
    for w in truth.gyr_radps:
        q = quat_multiply(q, quat_from_rotvec(w * 1e-4))
    assert np.degrees(angle_between(q, inverted)) < 1e-3
    # Peak rate of a cosine profile: (π/2)·angle/T.
    assert np.max(np.abs(truth.gyr_radps[:, 0])) == pytest.approx(np.pi / 2 * np.pi / 0.5, rel=1e-4)


def test_flight_specific_force_includes_the_trajectory_acceleration() -> None:
    script = Script([Hold(1.0), Fly(4.0, delta_vel_ned_mps=(8.0, 0.0, 0.0)), Fly(6.0, turn_rad=np.pi / 2)], MAG_NED)
    t = np.linspace(0.0, script.duration_s, 400)
    truth = script.sample(t)
    # In NED, the specific force is a − g whatever the attitude.
    f_ned = rotate_body_to_ned(truth.q, truth.specific_force_mps2)
    np.testing.assert_allclose(f_ned, truth.acc_ned_mps2 - [0.0, 0.0, STANDARD_GRAVITY_MPS2], atol=1e-9)
    # A multirotor: thrust along body −z, so the accelerometer reads only z.
    np.testing.assert_allclose(truth.specific_force_mps2[:, :2], 0.0, atol=1e-9)
    # The acceleration is the derivative of the velocity (central difference, 1 ms).
    dv = (script.sample(t + 1e-3).vel_ned_mps - script.sample(t - 1e-3).vel_ned_mps) / 2e-3
    inside = (t > 1e-3) & (t < script.duration_s - 1e-3)
    np.testing.assert_allclose(dv[inside], truth.acc_ned_mps2[inside], atol=1e-4)
    # End state: heading east at 8 m/s after the 90° turn, level.
    np.testing.assert_allclose(truth.vel_ned_mps[-1], [0.0, 8.0, 0.0], atol=1e-9)
    assert angle_between(truth.q[-1], quat_from_euler(0.0, 0.0, np.pi / 2)) < 1e-9
    # The peak of the raised-cosine acceleration is 2Δv/T = 4 m/s².
    assert np.max(np.abs(truth.acc_ned_mps2[:, 0])) == pytest.approx(4.0, rel=1e-3)


def test_scripts_compose_and_a_jump_is_refused() -> None:
    tour = scenarios.tour(60.0)
    assert tour.duration_s == pytest.approx(60.0)
    t = np.arange(0.0, 60.0, 0.002)
    q = tour.attitude(t)
    # Continuity: at most peak rate × step between samples (~700 °/s × 2 ms = 1.4°).
    assert np.degrees(np.max(angle_between(q[1:], q[:-1]))) < 1.5
    # Past the end the script holds its final state.
    assert angle_between(tour.attitude([1e3])[0], q[-1]) < 1e-6
    with pytest.raises(InputError, match="does not start at the previous attitude"):
        Script([Flip(1.0, (1.0, 0.0, 0.0), np.pi / 4), Fly(2.0, delta_vel_ned_mps=(1.0, 0.0, 0.0))], MAG_NED)
    with pytest.raises(InputError, match="positive"):
        Script([Hold(0.0)], MAG_NED)
    with pytest.raises(InputError, match="unknown script"):
        scenarios.script_named("loop-the-loop", 10.0)
