"""Sensor models for the fake vehicle: turn a truth trajectory into noisy IMU samples in SI.

Per sensor (accelerometer m/s², gyroscope rad/s, magnetometer µT), in this order::

    measured = saturate(M · truth + bias + noise)

with ``M = (I + misalignment) · diag(scale)`` for the accelerometer and gyroscope, and for the
magnetometer ``M = soft_iron`` and ``bias = hard_iron`` (the distortion that the calibration
``S (raw − h)`` undoes with ``S = soft_iron⁻¹``, ``h = hard_iron``). Noise is white Gaussian, per-axis σ.
Sample times run at ``rate_hz`` with optional Gaussian jitter (kept monotonic) and dropped samples.
:class:`GpsModel` is a GPS receiver's velocity (the fused filter's acceleration).
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field

import numpy as np

from mavattitude.errors import InputError
from mavattitude.estimation.conventions import Array, Mat3, Vec3
from mavattitude.sensors.units import GpsVelocity
from mavattitude.sim.trajectory import Script

_IDENTITY: Mat3 = ((1.0, 0.0, 0.0), (0.0, 1.0, 0.0), (0.0, 0.0, 1.0))


@dataclass(frozen=True)
class AxisModel:
    """One triaxial sensor: ``saturate(matrix · truth + bias + N(0, σ²))``."""

    noise_std: Vec3 = (0.0, 0.0, 0.0)
    bias: Vec3 = (0.0, 0.0, 0.0)
    matrix: Mat3 = _IDENTITY
    full_scale: float = np.inf  # |component| limit, sensor units

    @staticmethod
    def scaled(scale: Vec3, misalignment_rad: Vec3 = (0.0, 0.0, 0.0), **kwargs: object) -> AxisModel:
        """Scale factors and small non-orthogonality angles (rad): ``T · diag(scale)``.

        ``T`` is lower-triangular (x is the reference axis, y leans towards x by ``mz``, z towards x and
        y by ``my`` and ``mx``): the usual triaxial non-orthogonality model, not a rotation.
        """
        mx, my, mz = misalignment_rad
        mis = np.array([[1.0, 0.0, 0.0], [mz, 1.0, 0.0], [-my, mx, 1.0]])
        matrix = mis @ np.diag(scale)
        return AxisModel(matrix=tuple(map(tuple, matrix)), **kwargs)  # type: ignore[arg-type]

    def apply(self, truth: Array, rng: np.random.Generator) -> Array:
        out = truth @ np.asarray(self.matrix, float).T + np.asarray(self.bias, float)
        out = out + rng.standard_normal(truth.shape) * np.asarray(self.noise_std, float)
        return np.clip(out, -self.full_scale, self.full_scale)


DEFAULT_RATE_HZ = 200.0  # the fake vehicle's IMU rate unless told otherwise


@dataclass(frozen=True)
class SensorModel:
    """The vehicle's IMU: three sensors, a rate, jitter and drop-outs."""

    accel: AxisModel = field(default_factory=AxisModel)
    gyro: AxisModel = field(default_factory=AxisModel)
    mag: AxisModel = field(default_factory=AxisModel)
    rate_hz: float = DEFAULT_RATE_HZ
    jitter_std_s: float = 0.0
    drop_probability: float = 0.0

    def __post_init__(self) -> None:
        if not (np.isfinite(self.rate_hz) and self.rate_hz > 0):
            raise InputError(f"rate_hz must be positive, got {self.rate_hz}")
        if not 0.0 <= self.drop_probability < 1.0:
            raise InputError(f"drop_probability must be in [0, 1), got {self.drop_probability}")
        if self.jitter_std_s < 0 or self.jitter_std_s * self.rate_hz > 0.25:
            raise InputError("jitter_std_s must be ≥ 0 and under a quarter of the sample period")

    def at_rate(self, rate_hz: float) -> SensorModel:
        """The same sensors streamed at another rate (a SET_MESSAGE_INTERVAL arrived).

        Jitter is scheduling noise in seconds, so it is kept, but capped at the quarter period this model
        can represent without reordering samples: a ground station raising the rate must not crash the vehicle.
        """
        return dataclasses.replace(self, rate_hz=rate_hz, jitter_std_s=min(self.jitter_std_s, 0.25 / rate_hz))

    def sample_times(self, start_s: float, stop_s: float, rng: np.random.Generator) -> Array:
        """Sample times in ``[start_s, stop_s)``: nominal grid + jitter, minus dropped samples."""
        return self.ticks(int(np.ceil(start_s * self.rate_hz)), stop_s, rng)[0]

    def ticks(self, first: int, stop_s: float, rng: np.random.Generator) -> tuple[Array, int]:
        """The samples of grid ticks ``first, first + 1, …`` due before ``stop_s``, and the next tick.

        Tick ``k`` is nominally at ``k / rate_hz``; the times returned carry jitter and miss dropped samples.
        A stream counts its ticks, not their times: ``k / rate_hz * rate_hz`` comes out above ``k`` for one
        ``k`` in 22 at 200 Hz, so a stream resumed from the time of its next tick would skip that tick.
        """
        stop = max(first, int(np.ceil(stop_s * self.rate_hz)))
        t = np.arange(first, stop) / self.rate_hz
        if self.jitter_std_s > 0:
            # Clipped at ±0.4 period so the stream stays strictly increasing.
            half = 0.4 / self.rate_hz
            t = t + np.clip(rng.standard_normal(t.shape) * self.jitter_std_s, -half, half)
        if self.drop_probability > 0:
            t = t[rng.random(t.shape) >= self.drop_probability]
        return t, stop

    def measure(self, script: Script, t_s: Array, rng: np.random.Generator) -> tuple[Array, Array, Array]:
        """``(acc_mps2, gyr_radps, mag_uT)`` measured at script times ``t_s`` (each ``(N, 3)``)."""
        truth = script.sample(t_s)
        return (
            self.accel.apply(truth.specific_force_mps2, rng),
            self.gyro.apply(truth.gyr_radps, rng),
            self.mag.apply(truth.mag_uT, rng),
        )


@dataclass(frozen=True)
class GpsModel:
    """A GPS receiver's velocity: the truth at fixes ``1 / rate_hz`` apart, white noise per axis (m/s),
    rounded to ``resolution_mps`` (MAVLink's cm/s), handed in ``latency_s`` after its fix."""

    rate_hz: float = 5.0
    noise_std_mps: float = 0.05
    resolution_mps: float = 0.01
    latency_s: float = 0.1
    satellites: int = 12

    def measure(self, script: Script, stop_s: float, rng: np.random.Generator) -> tuple[Array, list[GpsVelocity]]:
        """The times the velocities are handed in at, and the velocities (3D fix, vertical known)."""
        fix_t = np.arange(0.0, stop_s - self.latency_s, 1.0 / self.rate_hz)
        vel = script.sample(fix_t).vel_ned_mps + rng.normal(0.0, self.noise_std_mps, (len(fix_t), 3))
        vel = np.round(vel / self.resolution_mps) * self.resolution_mps
        rows = [
            GpsVelocity(t, (n, e, d), True, 3, self.satellites)
            for t, (n, e, d) in zip(fix_t.tolist(), vel.tolist(), strict=True)
        ]
        return fix_t + self.latency_s, rows
