"""Truth trajectories for the fake vehicle, in SI, NED/FRD, composable in time.

A :class:`Script` is a sequence of segments; each segment starts from the attitude and velocity the
previous one ended with, so scripts compose without jumps (a jump is refused). Sampling is vectorised:
``Script.sample(t_s)`` gives the attitude ``q`` (body → NED), the body rates, the NED velocity and
acceleration, the specific force in the body frame (what an ideal accelerometer reads, trajectory
acceleration included) and the magnetic field in the body frame.

Segments:

- :class:`Hold` — static at the start attitude (constant velocity).
- :class:`Rotate` — constant body rate (slow rotation, or a spin).
- :class:`Flip` — a rotation by a given angle about a body axis with a smooth (cosine) rate profile:
  fast flips through 180°.
- :class:`Fly` — a multirotor-like flight segment: a smooth acceleration profile (sustained
  accelerations, climbs) and a turn (heading change); the attitude follows the thrust direction (body z
  opposite the specific force) and the heading. This is the maneuvering flight: during it the specific
  force is *not* along gravity, which is exactly what an accelerometer + magnetometer attitude cannot
  see, and the scorer can quantify.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from numpy.typing import ArrayLike

from mavattitude.errors import InputError
from mavattitude.estimation.conventions import (
    Array,
    angle_between,
    euler_from_quat,
    quat_conjugate,
    quat_from_rotation_matrix,
    quat_from_rotvec,
    quat_multiply,
    rotate_ned_to_body,
    rotvec_from_quat,
)
from mavattitude.sensors.units import STANDARD_GRAVITY_MPS2

GRAVITY_NED_MPS2 = np.array([0.0, 0.0, STANDARD_GRAVITY_MPS2])
# Central-difference step for body rates: the truncation error (~h² ω³) is far below any sensor noise.
_RATE_STEP_S = 1e-5
# Segments must join within this angle (rad): a jump would be an infinite body rate.
_JOIN_TOLERANCE_RAD = np.radians(0.05)


@dataclass(frozen=True)
class Start:
    """The state a segment starts from."""

    q: Array  # (4,) body → NED
    vel_ned_mps: Array  # (3,)


class Segment:
    """A piece of a script: ``duration_s`` and attitude / velocity / acceleration of relative time."""

    duration_s: float

    def attitude(self, t_s: Array, start: Start) -> Array:
        return np.broadcast_to(start.q, (*np.shape(t_s), 4)).copy()

    def velocity(self, t_s: Array, start: Start) -> Array:
        return np.broadcast_to(start.vel_ned_mps, (*np.shape(t_s), 3)).copy()

    def acceleration(self, t_s: Array, start: Start) -> Array:
        return np.zeros((*np.shape(t_s), 3))


def _smooth_fraction(t_s: Array, duration_s: float) -> Array:
    """0 → 1 with zero slope at both ends: ``(1 − cos(π t/T)) / 2``."""
    return (1.0 - np.cos(np.pi * np.clip(t_s / duration_s, 0.0, 1.0))) / 2.0


@dataclass(frozen=True)
class Hold(Segment):
    duration_s: float


@dataclass(frozen=True)
class Rotate(Segment):
    """Constant body rate ``rate_radps`` (FRD) for ``duration_s``."""

    duration_s: float
    rate_radps: tuple[float, float, float]

    def attitude(self, t_s: Array, start: Start) -> Array:
        return quat_multiply(start.q, quat_from_rotvec(np.multiply.outer(t_s, np.asarray(self.rate_radps, float))))


@dataclass(frozen=True)
class Flip(Segment):
    """Rotate by ``angle_rad`` about the body ``axis`` with a cosine profile (peak rate π/2 · angle/T)."""

    duration_s: float
    axis: tuple[float, float, float]
    angle_rad: float

    def attitude(self, t_s: Array, start: Start) -> Array:
        axis = np.asarray(self.axis, float)
        axis = axis / np.linalg.norm(axis)
        angle = self.angle_rad * _smooth_fraction(np.asarray(t_s, float), self.duration_s)
        return quat_multiply(start.q, quat_from_rotvec(np.multiply.outer(angle, axis)))


@dataclass(frozen=True)
class Fly(Segment):
    """A flight segment: velocity changes by ``delta_vel_ned_mps`` and the heading by ``turn_rad``.

    The acceleration has a raised-cosine profile (zero at both ends, sustained in the middle). The turn
    rotates the velocity vector about the vertical (so it adds a centripetal acceleration) and the heading
    with it. The attitude is that of a multirotor: body z along minus the specific force, nose at the
    heading. The segment must start level (the attitude it derives at t = 0 is level).
    """

    duration_s: float
    delta_vel_ned_mps: tuple[float, float, float] = (0.0, 0.0, 0.0)
    turn_rad: float = 0.0

    def _heading_offset(self, t_s: Array) -> Array:
        return self.turn_rad * _smooth_fraction(t_s, self.duration_s)

    def _heading_rate(self, t_s: Array) -> Array:
        tau = np.clip(t_s / self.duration_s, 0.0, 1.0)
        return self.turn_rad * np.pi / (2.0 * self.duration_s) * np.sin(np.pi * tau)

    def _linear_velocity(self, t_s: Array) -> Array:
        # ∫ (1 − cos 2πτ) dτ over [0, τ] = τ − sin(2πτ)/(2π): velocity change reaches Δv at τ = 1.
        tau = np.clip(t_s / self.duration_s, 0.0, 1.0)
        return np.multiply.outer(tau - np.sin(2 * np.pi * tau) / (2 * np.pi), np.asarray(self.delta_vel_ned_mps))

    def _linear_acceleration(self, t_s: Array) -> Array:
        tau = np.clip(t_s / self.duration_s, 0.0, 1.0)
        profile = (1.0 - np.cos(2 * np.pi * tau)) / self.duration_s
        return np.multiply.outer(profile, np.asarray(self.delta_vel_ned_mps))

    def velocity(self, t_s: Array, start: Start) -> Array:
        t_s = np.asarray(t_s, float)
        v = start.vel_ned_mps + self._linear_velocity(t_s)
        return _yaw_rotate(v, self._heading_offset(t_s))

    def acceleration(self, t_s: Array, start: Start) -> Array:
        t_s = np.asarray(t_s, float)
        psi = self._heading_offset(t_s)
        v = _yaw_rotate(start.vel_ned_mps + self._linear_velocity(t_s), psi)
        # d/dt [Rz(ψ) u] = Rz(ψ) u̇ + ψ̇ ẑ × Rz(ψ) u
        centripetal = self._heading_rate(t_s)[..., None] * np.cross([0.0, 0.0, 1.0], v)
        return _yaw_rotate(self._linear_acceleration(t_s), psi) + centripetal

    def attitude(self, t_s: Array, start: Start) -> Array:
        t_s = np.asarray(t_s, float)
        yaw0 = euler_from_quat(start.q)[2]  # heading of the body x axis on the horizontal plane
        specific_force_ned = self.acceleration(t_s, start) - GRAVITY_NED_MPS2
        z_body = -specific_force_ned / np.linalg.norm(specific_force_ned, axis=-1, keepdims=True)
        psi = yaw0 + self._heading_offset(t_s)
        nose = np.stack([np.cos(psi), np.sin(psi), np.zeros_like(psi)], -1)
        y_body = np.cross(z_body, nose)
        y_body /= np.linalg.norm(y_body, axis=-1, keepdims=True)
        x_body = np.cross(y_body, z_body)
        return quat_from_rotation_matrix(np.stack([x_body, y_body, z_body], -1))


def _yaw_rotate(v: Array, psi: Array) -> Array:
    c, s = np.cos(psi), np.sin(psi)
    return np.stack([c * v[..., 0] - s * v[..., 1], s * v[..., 0] + c * v[..., 1], v[..., 2]], -1)


@dataclass(frozen=True)
class TruthSamples:
    """The truth at an array of script times (all arrays have a leading axis N)."""

    t_s: Array
    q: Array
    gyr_radps: Array
    vel_ned_mps: Array
    acc_ned_mps2: Array
    specific_force_mps2: Array  # body frame
    mag_uT: Array  # body frame


@dataclass
class Script:
    """Segments in sequence, from ``q0`` and ``vel0_ned_mps``, in a magnetic field ``mag_ned_uT``.

    The script holds its last state for any time past its end, so a vehicle may run longer than it.
    """

    segments: list[Segment]
    mag_ned_uT: tuple[float, float, float]
    q0: tuple[float, float, float, float] = (1.0, 0.0, 0.0, 0.0)
    vel0_ned_mps: tuple[float, float, float] = (0.0, 0.0, 0.0)
    _starts: list[Start] = field(init=False, repr=False)
    _offsets_s: Array = field(init=False, repr=False)

    def __post_init__(self) -> None:
        if not self.segments:
            raise InputError("a script needs at least one segment")
        if any(not np.isfinite(s.duration_s) or s.duration_s <= 0 for s in self.segments):
            raise InputError("every segment needs a positive, finite duration_s")
        q0 = np.asarray(self.q0, float)
        self._starts = [Start(q0 / np.linalg.norm(q0), np.asarray(self.vel0_ned_mps, float))]
        for i, segment in enumerate(self.segments):
            start = self._starts[-1]
            q_begin = segment.attitude(np.array(0.0), start)
            if angle_between(q_begin, start.q) > _JOIN_TOLERANCE_RAD:
                raise InputError(f"segment {i} ({type(segment).__name__}) does not start at the previous attitude")
            end = np.array(segment.duration_s)
            self._starts.append(Start(segment.attitude(end, start), segment.velocity(end, start)))
        self._offsets_s = np.concatenate([[0.0], np.cumsum([s.duration_s for s in self.segments])])

    @property
    def duration_s(self) -> float:
        return float(self._offsets_s[-1])

    def then(self, *segments: Segment) -> Script:
        """A new script: this one followed by ``segments``."""
        return Script([*self.segments, *segments], self.mag_ned_uT, self.q0, self.vel0_ned_mps)

    def _piecewise(self, t_s: Array, what: str, width: int) -> Array:
        t_s = np.asarray(t_s, float)
        index = np.clip(np.searchsorted(self._offsets_s, t_s, side="right") - 1, 0, len(self.segments))
        out = np.empty((*t_s.shape, width))
        for i in np.unique(index):
            mask = index == i
            if i == len(self.segments):  # past the end: hold the final state
                final = Hold(1.0)
                out[mask] = getattr(final, what)(np.zeros(mask.sum()), self._starts[-1])
                continue
            segment = self.segments[i]
            out[mask] = getattr(segment, what)(t_s[mask] - self._offsets_s[i], self._starts[i])
        return out

    def attitude(self, t_s: ArrayLike) -> Array:
        return self._piecewise(np.asarray(t_s, float), "attitude", 4)

    def sample(self, t_s: ArrayLike) -> TruthSamples:
        t_s = np.atleast_1d(np.asarray(t_s, float))
        q = self.attitude(t_s)
        # Body rate from the relative rotation over a small symmetric step (sign-safe through 180°).
        q_before, q_after = self.attitude(t_s - _RATE_STEP_S), self.attitude(t_s + _RATE_STEP_S)
        gyr = rotvec_from_quat(quat_multiply(quat_conjugate(q_before), q_after)) / (2 * _RATE_STEP_S)
        acc_ned = self._piecewise(t_s, "acceleration", 3)
        return TruthSamples(
            t_s=t_s,
            q=q,
            gyr_radps=gyr,
            vel_ned_mps=self._piecewise(t_s, "velocity", 3),
            acc_ned_mps2=acc_ned,
            specific_force_mps2=rotate_ned_to_body(q, acc_ned - GRAVITY_NED_MPS2),
            mag_uT=rotate_ned_to_body(q, np.broadcast_to(np.asarray(self.mag_ned_uT, float), acc_ned.shape)),
        )
