"""Compass consistency: is the magnetometer's field the Earth's field as the accelerometer sees it?

Two figures need no attitude at all, so they can judge the magnetometer before any attitude is trusted:

- the **dip** (inclination) measured in the body, ``asin(d̂ · b̂)`` with ``d̂ = −f̂`` the down direction the
  accelerometer's specific force shows at low acceleration and ``b̂`` the field's direction. For a
  correctly mounted and calibrated compass it is the reference's inclination ``asin(B_D / |B|)`` (NED)
  whatever the attitude: the angle between two vectors does not depend on the frame they are written in.
  A compass mounted upside down reads the opposite dip, one rotated 90° about a horizontal axis shows it
  as soon as the vehicle sits level; a rotation about the vertical shows only when the vehicle tilts;
- the **field ratio** ``|B| / |B₀|`` against the reference's intensity (when it is known).

Only *quiet* samples count: low acceleration (``| |f| − g | ≤ low_accel_fraction · g``) and slow rotation
(``|ω| ≤ max_rate_dps``): elsewhere the specific force is not gravity (linear acceleration; or the
centripetal and tangential acceleration of a sensor off the rotation axis, and the small time offset
between the filtered accelerometer and magnetometer, which together bias the dip by −6° on BROAD's fast
rotation trial at 100–800°/s) and the dip is not the field's. :class:`CompassMonitor` keeps both figures over a
sliding window of vehicle time (mean and spread) and over the first minute, and judges the compass
*inconsistent* when a window mean is further from its reference than the threshold:

``dip threshold = dip_allowance_deg + k σ_dip``, ``σ_dip = √(σ̄_mag² / |B₀|² + σ̄_acc² / g²)`` (rad),

``field threshold = field_allowance + k σ̄_mag / |B₀|``,

with ``σ̄`` the noise model's RMS per-axis σ (Eq. 2), ``k = NOISE_SIGMAS``: the per-sample direction noise
of each unit vector (Eq. 9, ``tr R_unit = 2σ²/|W|²`` for isotropic noise, ``σ²/|W|²`` per perpendicular
axis) widened by the allowance for what calibration and the field model leave (docs/vehicle.md). It is
consistent again when both are back within ``CLEAR_FRACTION`` of their thresholds (hysteresis: no
flip-flop at the edge).

Pure functions and a small state machine on plain floats; no I/O (the service and replay say what it found).
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

Vec3 = tuple[float, float, float]

STANDARD_GRAVITY_MPS2 = 9.80665
NOISE_SIGMAS = 3.0  # k: a window mean this many per-sample σ off is not noise
CLEAR_FRACTION = 0.75  # consistent again below this fraction of the thresholds
FIRST_PERIOD_S = 60.0  # "over the first minute": from the first judged sample, vehicle time
HEADING_UNKNOWN_STD_RAD = math.pi / math.sqrt(3.0)  # σ of a heading uniform over ±180°


def _norm(v: Vec3) -> float:
    return math.sqrt(v[0] * v[0] + v[1] * v[1] + v[2] * v[2])


def measured_dip_deg(acc_mps2: Vec3, mag_uT: Vec3) -> float:
    """The field's dip below the horizontal the accelerometer shows, degrees (positive: field points down)."""
    dot = -(acc_mps2[0] * mag_uT[0] + acc_mps2[1] * mag_uT[1] + acc_mps2[2] * mag_uT[2])
    return math.degrees(math.asin(max(-1.0, min(1.0, dot / (_norm(acc_mps2) * _norm(mag_uT))))))


def reference_dip_deg(field_ned_uT: Vec3) -> float:
    """The inclination of a NED reference field, degrees (positive down)."""
    return math.degrees(math.asin(max(-1.0, min(1.0, field_ned_uT[2] / _norm(field_ned_uT)))))


def rms_sigma(std: Vec3) -> float:
    """The RMS of three per-axis σ."""
    return math.sqrt((std[0] ** 2 + std[1] ** 2 + std[2] ** 2) / 3.0)


@dataclass(frozen=True)
class CompassSettings:
    """How the monitor judges (see the module docstring); ``config.compass`` in the project config."""

    enabled: bool = True
    window_s: float = 10.0
    low_accel_fraction: float = 0.05
    max_rate_dps: float = 60.0
    dip_allowance_deg: float = 10.0
    field_allowance: float = 0.15
    min_samples: int = 25  # quiet samples in the window before judging (0.5 s at 50 Hz)


@dataclass(frozen=True)
class Thresholds:
    """What a window mean may differ from the reference by: dip in degrees, field as a fraction of |B₀|."""

    dip_deg: float
    field: float
    dip_noise_deg: float  # k σ_dip alone: a single sample's dip further off than this is not noise


def thresholds(settings: CompassSettings, accel_std_mps2: Vec3, mag_std_uT: Vec3, field_uT: float) -> Thresholds:
    """The thresholds from the noise model (module docstring) at a reference intensity ``field_uT``."""
    rel_mag = rms_sigma(mag_std_uT) / field_uT
    rel_acc = rms_sigma(accel_std_mps2) / STANDARD_GRAVITY_MPS2
    sigma_dip_deg = math.degrees(math.sqrt(rel_mag * rel_mag + rel_acc * rel_acc))
    noise_deg = NOISE_SIGMAS * sigma_dip_deg
    return Thresholds(
        settings.dip_allowance_deg + noise_deg, settings.field_allowance + NOISE_SIGMAS * rel_mag, noise_deg
    )


@dataclass(frozen=True)
class CompassFigures:
    """The monitor's figures now: window means and spreads, the first minute's means, and the verdict.

    NaN where nothing was measured (no quiet sample yet; ``field_*`` also when the reference
    gives no intensity).
    """

    samples: int  # quiet samples seen in all
    dip_deg: float  # window mean
    dip_std_deg: float
    expected_dip_deg: float
    field_ratio: float  # window mean of |B| / |B₀|
    field_std: float
    first_dip_deg: float  # the first minute's mean
    first_field_ratio: float
    threshold_dip_deg: float
    threshold_field: float
    inconsistent: bool
    warnings: int  # times it turned inconsistent

    def describe(self) -> str:
        """One line for a person: what was measured against what was expected."""
        text = f"compass dip {self.dip_deg:+.0f}° vs expected {self.expected_dip_deg:+.0f}°"
        if self.field_ratio == self.field_ratio:
            text += f", |B| {100.0 * self.field_ratio:.0f} % of the expected"
        return text


@dataclass(frozen=True)
class CompassEvent:
    """The verdict changed at ``time_s`` (vehicle clock): ``inconsistent`` or consistent again."""

    time_s: float
    inconsistent: bool
    figures: CompassFigures


class _Stats:
    """Count, mean and spread of (dip, field) pairs: running sums, so adding and removing are O(1)."""

    __slots__ = ("dip", "dip2", "field", "field2", "n", "nf")

    def __init__(self) -> None:
        self.n = self.nf = 0
        self.dip = self.dip2 = self.field = self.field2 = 0.0

    def add(self, dip: float, field: float | None, sign: int = 1) -> None:
        self.n += sign
        self.dip += sign * dip
        self.dip2 += sign * dip * dip
        if field is not None:
            self.nf += sign
            self.field += sign * field
            self.field2 += sign * field * field

    def dip_mean(self) -> float:
        return self.dip / self.n if self.n else math.nan

    def dip_std(self) -> float:
        return _std(self.n, self.dip, self.dip2)

    def field_mean(self) -> float:
        return self.field / self.nf if self.nf else math.nan

    def field_std(self) -> float:
        return _std(self.nf, self.field, self.field2)


def _std(n: int, s: float, s2: float) -> float:
    if n < 2:
        return math.nan
    return math.sqrt(max(s2 / n - (s / n) ** 2, 0.0))


class CompassMonitor:
    """Dip and field ratio over a sliding window and the first minute; the consistency verdict.

    ``set_reference`` gives the expected field (its intensity ``None`` when only the direction is known);
    ``update`` takes each front-end tick's body-frame specific force, field and rates and returns a
    :class:`CompassEvent` when the verdict changes (else ``None``).
    """

    def __init__(self, settings: CompassSettings, accel_std_mps2: Vec3, mag_std_uT: Vec3) -> None:
        self.settings = settings
        self._max_rate_radps = math.radians(settings.max_rate_dps)
        self._sigmas = (accel_std_mps2, mag_std_uT)
        self._window: deque[tuple[float, float, float | None]] = deque()  # (t, dip, |B| or None)
        self._win = _Stats()
        self._first = _Stats()
        self._first_until_s = math.nan
        self._expected_dip = math.nan
        self._field_uT: float | None = None
        self._thresholds = Thresholds(math.nan, math.nan, math.nan)
        self.samples = 0
        self.inconsistent = False
        self.warnings = 0

    @property
    def judged(self) -> bool:
        """Enough quiet samples in the window to judge."""
        return self._win.n >= self.settings.min_samples

    def set_reference(self, field_ned_uT: Vec3, intensity_uT: float | None) -> None:
        self._expected_dip = reference_dip_deg(field_ned_uT)
        self._field_uT = intensity_uT
        scale = intensity_uT if intensity_uT is not None else _norm(field_ned_uT)
        self._thresholds = thresholds(self.settings, *self._sigmas, scale)

    def quiet(self, acc_mps2: Vec3, gyr_radps: Vec3) -> bool:
        """Low acceleration and slow rotation: the specific force shows gravity (module docstring)."""
        g = STANDARD_GRAVITY_MPS2
        return (
            abs(_norm(acc_mps2) - g) <= self.settings.low_accel_fraction * g
            and _norm(gyr_radps) <= self._max_rate_radps
        )

    def suspect(self, acc_mps2: Vec3, mag_uT: Vec3, gyr_radps: Vec3) -> bool:
        """Whether this one sample's field should set heading only.

        While the compass is judged inconsistent: always. Before it can be judged: when this sample's dip
        (when quiet) is beyond the threshold. Once it has been judged inconsistent (a compass
        found off stays suspect: a misorientation about a horizontal axis shows only while the vehicle
        tilts, and the window mean clears while it hovers level): when this sample's dip is further off
        than the noise model's ``k σ_dip``, at any acceleration.
        """
        if self.inconsistent:
            return True
        off = abs(measured_dip_deg(acc_mps2, mag_uT) - self._expected_dip)
        if self.warnings:
            return off > self._thresholds.dip_noise_deg
        return not self.judged and off > self._thresholds.dip_deg and self.quiet(acc_mps2, gyr_radps)

    def update(self, time_s: float, acc_mps2: Vec3, mag_uT: Vec3, gyr_radps: Vec3) -> CompassEvent | None:
        if not self.quiet(acc_mps2, gyr_radps) or self._expected_dip != self._expected_dip:
            return None
        dip = measured_dip_deg(acc_mps2, mag_uT)
        field = _norm(mag_uT) if self._field_uT is not None else None
        self.samples += 1
        if self._first_until_s != self._first_until_s:
            self._first_until_s = time_s + FIRST_PERIOD_S
        if time_s <= self._first_until_s:
            self._first.add(dip, field)
        self._window.append((time_s, dip, field))
        self._win.add(dip, field)
        while self._window and self._window[0][0] <= time_s - self.settings.window_s:
            _, old_dip, old_field = self._window.popleft()
            self._win.add(old_dip, old_field, -1)
        return self._judge(time_s) if self.judged else None

    def _excess(self) -> float:
        """The larger of the window's two distances from the reference, as a fraction of its threshold."""
        t = self._thresholds
        dip = abs(self._win.dip_mean() - self._expected_dip) / t.dip_deg
        if self._field_uT is None or not self._win.nf:
            return dip
        return max(dip, abs(self._win.field_mean() / self._field_uT - 1.0) / t.field)

    def _judge(self, time_s: float) -> CompassEvent | None:
        excess = self._excess()
        if not self.inconsistent and excess > 1.0:
            self.inconsistent = True
            self.warnings += 1
        elif self.inconsistent and excess < CLEAR_FRACTION:
            self.inconsistent = False
        else:
            return None
        return CompassEvent(time_s, self.inconsistent, self.figures())

    def figures(self) -> CompassFigures:
        b0 = self._field_uT or math.nan
        w, f = self._win, self._first
        return CompassFigures(
            samples=self.samples,
            dip_deg=w.dip_mean(),
            dip_std_deg=w.dip_std(),
            expected_dip_deg=self._expected_dip,
            field_ratio=w.field_mean() / b0,
            field_std=w.field_std() / b0,
            first_dip_deg=f.dip_mean(),
            first_field_ratio=f.field_mean() / b0,
            threshold_dip_deg=self._thresholds.dip_deg,
            threshold_field=self._thresholds.field,
            inconsistent=self.inconsistent,
            warnings=self.warnings,
        )


def heading_uncertain(covariance: NDArray[np.float64], acc_mps2: Vec3) -> NDArray[np.float64]:
    """``P + σ_h² d̂ d̂ᵀ``: a body error-angle covariance (rad², 3×3) with the rotation about the vertical
    ``d̂ = −f̂`` (body) made as uncertain as a heading uniform over ±180° (``HEADING_UNKNOWN_STD_RAD``)."""
    d = np.asarray(acc_mps2, dtype=float)
    d /= np.linalg.norm(d)
    return covariance + HEADING_UNKNOWN_STD_RAD**2 * np.outer(d, d)
