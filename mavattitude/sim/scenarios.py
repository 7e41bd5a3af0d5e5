"""Named truth scripts and sensor presets: what the tests, the demo and `mavattitude simulate` fly.

- ``paper_static``: the static scenario of Section 5.1 of the paper (body vectors, noise and attitude
  from ``docs/paper-notes.md``): pitch −30°, roll 20°, yaw 142.2° from magnetic north, inclination
  64.98°, |B| = 54.6 µT. The paper's ``w2`` is the gravity vector; an accelerometer reads ``−w2``.
- ``slow_rotation``: a constant body rate of a few °/s about all three axes.
- ``maneuver``: a multirotor flight: accelerate north to 8 m/s, a 90° coordinated turn, a climb, a
  braking stop (sustained accelerations up to ~4 m/s², bank up to ~25°), with level holds between.
- ``flips``: fast 180° and 360° flips about roll and pitch (peak rates up to ~700 °/s).
- ``tour``: all of the above in one script.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from typing import TypeVar

import numpy as np

from mavattitude.errors import InputError
from mavattitude.estimation.conventions import Array, quat_from_rotation_matrix
from mavattitude.sensors.units import STANDARD_GRAVITY_MPS2
from mavattitude.sim.sensors import DEFAULT_RATE_HZ, AxisModel, SensorModel
from mavattitude.sim.trajectory import Flip, Fly, Hold, Rotate, Script

# Paper, Section 5.1 (docs/paper-notes.md): body vectors and noise.
PAPER_MAG_BODY_UT = np.array([89.3847, 44.7538, 536.8714]) * 0.1  # 1e-7 T = 0.1 µT
PAPER_GRAVITY_BODY_MPS2 = np.array([4.9000, 2.9027, 7.9752])
PAPER_MAG_STD_UT = (0.2, 0.3, 0.25)  # R1 = diag(2², 3², 2.5²)·1e-14 T²
PAPER_ACCEL_STD_MPS2 = (0.010, 0.009, 0.0095)  # R2 = diag(10², 9², 9.5²)·1e-6 (m/s²)²

T = TypeVar("T")

# A mid-latitude field for the other scripts (declination 0°, inclination ≈ 64°, 50 µT).
DEFAULT_MAG_NED_UT = (21.9, 0.0, 44.9)


def _paper_truth() -> tuple[Array, Array]:
    """The attitude and NED field that make the paper's body vectors exact (TRIAD, down first)."""
    down_b = PAPER_GRAVITY_BODY_MPS2 / np.linalg.norm(PAPER_GRAVITY_BODY_MPS2)
    mag_b = PAPER_MAG_BODY_UT
    inclination = np.pi / 2 - np.arccos(down_b @ mag_b / np.linalg.norm(mag_b))
    mag_ned = np.linalg.norm(mag_b) * np.array([np.cos(inclination), 0.0, np.sin(inclination)])

    def triad(a: Array, b: Array) -> Array:
        t1 = a / np.linalg.norm(a)
        t2 = np.cross(t1, b)
        t2 /= np.linalg.norm(t2)
        return np.stack([t1, t2, np.cross(t1, t2)], -1)

    r_body_to_ned = triad(np.array([0.0, 0.0, 1.0]), mag_ned) @ triad(down_b, mag_b).T
    return quat_from_rotation_matrix(r_body_to_ned), mag_ned


PAPER_Q, PAPER_MAG_NED_UT = _paper_truth()


def paper_static(duration_s: float = 60.0) -> Script:
    return Script([Hold(duration_s)], tuple(PAPER_MAG_NED_UT), q0=tuple(PAPER_Q))


def static(duration_s: float = 60.0) -> Script:
    return Script([Hold(duration_s)], DEFAULT_MAG_NED_UT)


def slow_rotation(duration_s: float = 60.0) -> Script:
    return Script([Hold(1.0), Rotate(duration_s - 1.0, (0.03, -0.05, 0.08))], DEFAULT_MAG_NED_UT)


def _maneuver_segments() -> list[Fly | Hold]:
    return [
        Hold(2.0),
        Fly(4.0, delta_vel_ned_mps=(8.0, 0.0, 0.0)),  # accelerate north, peak 4 m/s²
        Fly(6.0, turn_rad=np.pi / 2),  # coordinated 90° turn at 8 m/s, peak ≈ 2 m/s² centripetal
        Fly(4.0, delta_vel_ned_mps=(0.0, 0.0, -4.0)),  # climb (NED down velocity −4 m/s)
        Fly(4.0, delta_vel_ned_mps=(0.0, 0.0, 4.0)),  # level off
        Fly(4.0, delta_vel_ned_mps=(0.0, -8.0, 0.0)),  # brake to a stop (now heading east)
        Hold(2.0),
    ]


def maneuver(duration_s: float = 26.0) -> Script:
    segments = _maneuver_segments()
    return _fit(Script(segments, DEFAULT_MAG_NED_UT), duration_s)


def _flip_segments() -> list[Flip | Hold]:
    return [
        Hold(1.0),
        Flip(0.5, (1.0, 0.0, 0.0), np.pi),  # roll through 180° (inverted)
        Hold(1.0),
        Flip(0.5, (1.0, 0.0, 0.0), np.pi),  # and back upright
        Hold(1.0),
        Flip(1.0, (0.0, 1.0, 0.0), 2 * np.pi),  # a full pitch loop
        Hold(1.0),
    ]


def flips(duration_s: float = 6.0) -> Script:
    return _fit(Script(_flip_segments(), DEFAULT_MAG_NED_UT), duration_s)


def tour(duration_s: float = 60.0) -> Script:
    """Maneuvering flight, slow rotation, flips."""
    segments = [*_maneuver_segments(), Rotate(8.0, (0.03, -0.05, 0.08)), Hold(1.0)]
    # Flips start from whatever attitude the rotation ended at: they are relative to the body.
    segments += _flip_segments()
    return _fit(Script(segments, DEFAULT_MAG_NED_UT), duration_s)


def turns(duration_s: float = 90.0) -> Script:
    """Sustained coordinated turns at 10 m/s: two circles to the right (heading rate up to 0.49 rad/s: 4.9 m/s²
    centripetal, a 27° bank held for tens of seconds), one to the left, then hard stops and a dash."""
    segments = [
        Hold(5.0),
        Fly(5.0, delta_vel_ned_mps=(10.0, 0.0, 0.0)),
        Fly(40.0, turn_rad=4.0 * np.pi),
        Fly(20.0, turn_rad=-2.0 * np.pi),
        Fly(3.0, delta_vel_ned_mps=(-10.0, 0.0, 0.0)),
        Fly(3.0, delta_vel_ned_mps=(12.0, 0.0, 0.0)),
        Fly(3.0, delta_vel_ned_mps=(-12.0, 0.0, 0.0)),
        Hold(5.0),
    ]
    return _fit(Script(segments, DEFAULT_MAG_NED_UT), duration_s)


def _fit(script: Script, duration_s: float) -> Script:
    """Pad with a final hold up to ``duration_s`` (a script is never cut short)."""
    if duration_s > script.duration_s:
        return script.then(Hold(duration_s - script.duration_s))
    return script


SCRIPTS: dict[str, Callable[[float], Script]] = {
    "paper_static": paper_static,
    "static": static,
    "slow_rotation": slow_rotation,
    "maneuver": maneuver,
    "turns": turns,
    "flips": flips,
    "tour": tour,
}


def _named(table: Mapping[str, Callable[[float], T]], what: str, name: str, value: float) -> T:
    try:
        make = table[name]
    except KeyError:
        raise InputError(f"unknown {what} {name!r}; known: {', '.join(table)}") from None
    return make(value)


def script_named(name: str, duration_s: float) -> Script:
    return _named(SCRIPTS, "script", name, duration_s)


# --- sensor presets ------------------------------------------------------------------------------------

# Gyro noise of a consumer MEMS part (≈ 0.01 rad/s/√Hz at 200 Hz → σ ≈ 0.003 rad/s per sample).
_GYRO_STD_RADPS = (0.003, 0.003, 0.003)
# ±16 g, ±2000 °/s, ±4.9 gauss: the full scales of a typical MPU-9250-class IMU.
ACCEL_FULL_SCALE_MPS2 = 16 * STANDARD_GRAVITY_MPS2
GYRO_FULL_SCALE_RADPS = np.radians(2000.0)
MAG_FULL_SCALE_UT = 490.0


def paper_sensors(rate_hz: float = DEFAULT_RATE_HZ) -> SensorModel:
    """The paper's per-axis noise, no other errors."""
    return SensorModel(
        accel=AxisModel(noise_std=PAPER_ACCEL_STD_MPS2, full_scale=ACCEL_FULL_SCALE_MPS2),
        gyro=AxisModel(noise_std=_GYRO_STD_RADPS, full_scale=GYRO_FULL_SCALE_RADPS),
        mag=AxisModel(noise_std=PAPER_MAG_STD_UT, full_scale=MAG_FULL_SCALE_UT),
        rate_hz=rate_hz,
    )


def ideal_sensors(rate_hz: float = DEFAULT_RATE_HZ) -> SensorModel:
    """Noise-free and undistorted (only the message encoding's quantisation remains)."""
    return SensorModel(rate_hz=rate_hz)


def consumer_sensors(rate_hz: float = DEFAULT_RATE_HZ) -> SensorModel:
    """A consumer IMU on an ArduPilot board after its own calibration: noise, small residual errors, jitter."""
    return SensorModel(
        accel=AxisModel.scaled(
            (1.002, 0.998, 1.001),
            (0.001, -0.0005, 0.0008),
            noise_std=(0.03, 0.03, 0.04),
            bias=(0.02, -0.01, 0.03),
            full_scale=ACCEL_FULL_SCALE_MPS2,
        ),
        gyro=AxisModel(noise_std=_GYRO_STD_RADPS, bias=(0.002, -0.001, 0.0015), full_scale=GYRO_FULL_SCALE_RADPS),
        mag=AxisModel(noise_std=(0.4, 0.4, 0.5), bias=(0.5, -0.3, 0.4), full_scale=MAG_FULL_SCALE_UT),
        rate_hz=rate_hz,
        jitter_std_s=0.1 / rate_hz,
    )


SENSORS: dict[str, Callable[[float], SensorModel]] = {
    "paper": paper_sensors,
    "ideal": ideal_sensors,
    "consumer": consumer_sensors,
}


def sensors_named(name: str, rate_hz: float) -> SensorModel:
    return _named(SENSORS, "sensor preset", name, rate_hz)
