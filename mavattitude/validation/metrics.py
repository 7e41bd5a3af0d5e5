"""The real-data metrics: BROAD's (Laidig et al., Data 6(7):72, 2021) and the PX4 comparison.

BROAD: ``q_err = q_est ⊗ q_gt*`` with both quaternions sensor → ENU (the error in the earth frame);
total error = the rotation angle of ``q_err``, heading error = its rotation about the vertical
``2·atan(|z/w|)``, inclination error = the rest ``2·acos(√(w² + z²))``. RMS over the movement samples and,
separately, over the rest samples at least 1 s from movement; samples without ground truth are excluded.

PX4: the autopilot's roll and pitch are the reference: RMS of the wrapped roll and pitch differences;
its yaw is relative to magnetic north, so the heading difference is reported as mean (an offset the
magnetic reference may carry) and standard deviation (the spread that matters).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from mavattitude.estimation.conventions import Array, euler_from_quat, quat_conjugate, quat_multiply
from mavattitude.validation.frames import enu_from_ned


def broad_errors(q_est_ned: Array, q_truth_ned: Array) -> Array:
    """``(N, 3)`` total, heading and inclination error (rad) of body → NED estimates, in BROAD's ENU."""
    q_err = quat_multiply(enu_from_ned(q_est_ned), quat_conjugate(enu_from_ned(q_truth_ned)))
    q_err = q_err / np.linalg.norm(q_err, axis=-1, keepdims=True)
    w, z = np.abs(q_err[..., 0]), np.abs(q_err[..., 3])
    total = 2.0 * np.arctan2(np.linalg.norm(q_err[..., 1:], axis=-1), w)
    heading = 2.0 * np.arctan2(z, w)  # = 2·atan(|z/w|), also where w = 0
    inclination = 2.0 * np.arccos(np.clip(np.hypot(w, z), 0.0, 1.0))
    return np.stack([total, heading, inclination], axis=-1)


def euler_differences(q_est: Array, q_truth: Array) -> Array:
    """``(N, 3)`` roll, pitch, yaw of the estimate minus the truth's, wrapped to (−π, π] (rad)."""
    return np.angle(np.exp(1j * (euler_from_quat(q_est) - euler_from_quat(q_truth))))


def rms_deg(x: Array) -> float:
    """RMS in degrees of radians, NaN for no samples."""
    return float(np.degrees(np.sqrt(np.mean(x**2)))) if len(x) else float("nan")


@dataclass(frozen=True)
class ErrorRms:
    """RMS errors over one set of samples, degrees."""

    total_deg: float
    heading_deg: float
    inclination_deg: float
    samples: int

    @classmethod
    def of(cls, errors_rad: Array) -> ErrorRms:
        errors_rad = errors_rad[~np.isnan(errors_rad).any(axis=1)]
        return cls(*(rms_deg(errors_rad[:, i]) for i in range(3)), samples=len(errors_rad))


@dataclass(frozen=True)
class BroadScore:
    """BROAD's metric: RMS over the movement phases and over the rest samples ≥ 1 s from motion."""

    movement: ErrorRms
    rest: ErrorRms

    @classmethod
    def of(cls, errors_rad: Array, movement: Array, rest: Array) -> BroadScore:
        """The score of :func:`broad_errors` already computed."""
        return cls(movement=ErrorRms.of(errors_rad[movement]), rest=ErrorRms.of(errors_rad[rest]))

    def columns(self) -> dict[str, float]:
        return {
            f"{label} {kind}": getattr(rms, f"{kind}_deg")
            for label, rms in (("move", self.movement), ("rest", self.rest))
            for kind in ("total", "heading", "inclination")
        }


@dataclass(frozen=True)
class Px4Score:
    """Agreement with the autopilot's own attitude, degrees."""

    roll_rms_deg: float
    pitch_rms_deg: float
    heading_mean_deg: float
    heading_std_deg: float
    samples: int

    @classmethod
    def of(cls, differences_rad: Array) -> Px4Score:
        """The score of :func:`euler_differences` already computed."""
        d = differences_rad[~np.isnan(differences_rad).any(axis=1)]
        # Heading statistics on the circle's tangent at the mean, so a ±180° wrap cannot split them.
        mean = np.arctan2(np.sin(d[:, 2]).mean(), np.cos(d[:, 2]).mean())
        spread = np.angle(np.exp(1j * (d[:, 2] - mean)))
        return cls(
            roll_rms_deg=rms_deg(d[:, 0]),
            pitch_rms_deg=rms_deg(d[:, 1]),
            heading_mean_deg=float(np.degrees(mean)),
            heading_std_deg=float(np.degrees(spread.std())),
            samples=len(d),
        )

    def columns(self) -> dict[str, float]:
        return {
            "roll rms": self.roll_rms_deg,
            "pitch rms": self.pitch_rms_deg,
            "heading mean": self.heading_mean_deg,
            "heading std": self.heading_std_deg,
        }


def score_broad(q_est_ned: Array, q_truth_ned: Array, movement: Array, rest: Array) -> BroadScore:
    """BROAD's metric of estimates against the ground truth at the same instants."""
    return BroadScore.of(broad_errors(q_est_ned, q_truth_ned), movement, rest)


def score_px4(q_est_ned: Array, q_autopilot_ned: Array) -> Px4Score:
    """Roll/pitch RMS and heading mean/std of the estimates against the autopilot's attitude."""
    return Px4Score.of(euler_differences(q_est_ned, q_autopilot_ned))
