"""Score received ATTITUDE_QUATERNION messages against the truth at the same vehicle time.

- Angle error: the total rotation angle between estimate and truth.
- Tilt error: the angle between the true and the estimated "down" direction seen in the body frame
  (independent of heading).
- Heading error: the twist about the NED vertical of the NED-frame error rotation ``q̂ ⊗ q*``
  (well defined at any attitude, unlike a difference of Euler yaws near ±90° pitch or when inverted).
- Output rate on the vehicle's clock; latency from the send of the first IMU sample at or after the
  output's vehicle time (the sample that made that output possible) to the output's arrival.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from mavattitude.estimation.conventions import (
    Array,
    angle_between,
    body_error_angles,
    quat_conjugate,
    quat_multiply,
    rotate_ned_to_body,
)

_DOWN_NED = np.array([0.0, 0.0, 1.0])
# A quaternion further than this from unit norm is counted as broken (the service must never send one;
# MAVLink floats carry ~1e-7 relative precision).
UNIT_NORM_TOLERANCE = 1e-4


def tilt_error(q_est: Array, q_true: Array) -> Array:
    """Angle (rad) between the true and estimated down direction in the body frame."""
    d_est = rotate_ned_to_body(q_est, _DOWN_NED)
    d_true = rotate_ned_to_body(q_true, _DOWN_NED)
    return np.arctan2(np.linalg.norm(np.cross(d_est, d_true), axis=-1), np.sum(d_est * d_true, -1))


def heading_error(q_est: Array, q_true: Array) -> Array:
    """Signed twist (rad, (−π, π]) about NED down of the error rotation ``q̂ ⊗ q*``."""
    e = quat_multiply(q_est, quat_conjugate(q_true))
    return np.angle(np.exp(1j * 2.0 * np.arctan2(e[..., 3], e[..., 0])))


@dataclass(frozen=True)
class Score:
    """Error statistics of one run (angles in degrees, rates in Hz, latency in milliseconds)."""

    count: int
    broken: int  # received quaternions that were not finite or not unit
    angle_rms_deg: float
    angle_p95_deg: float
    angle_max_deg: float
    tilt_rms_deg: float
    heading_rms_deg: float
    output_rate_hz: float
    latency_p50_ms: float
    latency_p99_ms: float

    def row(self) -> str:
        return (
            f"{self.count:6d} {self.angle_rms_deg:8.3f} {self.angle_p95_deg:8.3f} {self.angle_max_deg:8.3f} "
            f"{self.tilt_rms_deg:8.3f} {self.heading_rms_deg:8.3f} {self.output_rate_hz:7.1f} "
            f"{self.latency_p50_ms:7.2f} {self.latency_p99_ms:7.2f}"
        )

    @staticmethod
    def header() -> str:
        return (
            "     n  err_rms  err_p95  err_max tilt_rms head_rms   rate_Hz  lat_p50 lat_p99\n"
            "         (deg)    (deg)    (deg)    (deg)    (deg)             (ms)    (ms)"
        )


@dataclass(frozen=True)
class Comparison:
    """Per-output arrays: vehicle time, estimate, truth and body-frame error angles (rad)."""

    t_s: Array
    q_est: Array
    q_true: Array
    error_body_rad: Array
    latency_s: Array


def compare(
    t_s: Array, q_est: Array, recv_mono_s: Array, q_true: Array, sent_t_s: Array, sent_mono_s: Array
) -> Comparison:
    """Pair outputs with truth and with the IMU send that enabled each (``sent_*`` sorted by time)."""
    index = np.searchsorted(sent_t_s, t_s - 1e-6)
    has_source = index < len(sent_t_s)
    latency = np.full(len(t_s), np.nan)
    latency[has_source] = recv_mono_s[has_source] - sent_mono_s[index[has_source]]
    with np.errstate(invalid="ignore", divide="ignore"):  # a broken estimate gives NaN angles, counted by score
        errors = body_error_angles(q_est, q_true)
    return Comparison(t_s, q_est, q_true, errors, latency)


def score(c: Comparison) -> Score:
    finite = np.all(np.isfinite(c.q_est), axis=-1)
    unit = finite & (np.abs(np.linalg.norm(np.where(finite[:, None], c.q_est, 0.0), axis=-1) - 1) < UNIT_NORM_TOLERANCE)
    q_est, q_true = c.q_est[unit], c.q_true[unit]
    if not len(q_est):
        nan = float("nan")
        return Score(len(c.t_s), int((~unit).sum()), nan, nan, nan, nan, nan, nan, nan, nan)
    angle = np.degrees(angle_between(q_est, q_true))
    tilt = np.degrees(tilt_error(q_est, q_true))
    heading = np.degrees(heading_error(q_est, q_true))
    span = c.t_s.max() - c.t_s.min()
    latency = c.latency_s[np.isfinite(c.latency_s)] * 1e3
    lat50, lat99 = np.percentile(latency, [50, 99]) if len(latency) else (np.nan, np.nan)
    return Score(
        count=len(c.t_s),
        broken=int((~unit).sum()),
        angle_rms_deg=float(np.sqrt(np.mean(angle**2))),
        angle_p95_deg=float(np.percentile(angle, 95)),
        angle_max_deg=float(angle.max()),
        tilt_rms_deg=float(np.sqrt(np.mean(tilt**2))),
        heading_rms_deg=float(np.sqrt(np.mean(heading**2))),
        output_rate_hz=float((len(c.t_s) - 1) / span) if span > 0 else float("nan"),
        latency_p50_ms=float(lat50),
        latency_p99_ms=float(lat99),
    )
