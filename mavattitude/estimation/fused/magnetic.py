"""Magnetic checks, field learning and the hard-iron offset the filter learns while the vehicle turns.

Disturbance measure — field magnitude and dip against the reference, the dip measured against the
*predicted* vertical (so an accelerating vehicle does not look magnetically disturbed)::

    d = max(| |m| − |m_ref| | / (τ_n |m_ref|),  |δ(m, q) − δ_ref| / (τ_δ + 3 σ_v)),   σ_v² = tr P_θθ − v̂ᵀ P_θθ v̂

``σ_v``: the predicted vertical ``v̂``'s own error (the rotation about it, the heading's, moves no dip: a heading
unknown leaves the test as strict as a known one).

``|m_ref|`` and ``δ_ref`` are the magnitude and dip as this magnetometer measures them here, learnt from the
clean field from start-up on: a running mean (from the reference's) over the first ``τ_ref =
mag_reference_s``, then a first-order low-pass of time constant ``τ_ref`` (the running mean's count held at
``τ_ref`` / period), so a field that differs where the body moves from where it rested is followed rather
than weighed as a heading error. The reference sets the heading (its horizontal direction), the data the
field the checks compare with, so a reference off by 8 % in strength or 3° in dip (a model, another rest
spot) changes nothing. ``d ≥ 1``: disturbed, the magnetometer updates nothing.
``d < 1``: ``σ_m'² = σ_m² (1 + (d/d₀)⁶) ρ``, with the recovery factor after a disturbance that lasted
``T_c``: ``ρ = 1 + (ρ₀ − 1) min(1, T_c/T_r) max(0, 1 − t_clean/T_r)``. The sixth power keeps the weight
flat near the reference, where ``d`` is calibration residue and noise (BROAD's clean field: ``d`` ≲ 0.45),
and drops it steeply towards the threshold, where the field is most likely another one (BROAD's motion
volume, ‖B‖ +7.5 %, dip −1.8°: its heading 4° off the reference's).

A field disturbed for ``mag_relearn_s`` without a break is adopted as the new reference (magnitude and
dip: the vehicle has moved, not the magnet). The magnetometer corrects only the heading (the filter's
heading update), so an adopted field — right or wrong — never moves roll and pitch.

Hard-iron offset — a magnet fixed to the body adds a constant ``o`` in the body frame: ``m = A(q) B + o``.
While the field is disturbed the heading coasts on the gyro, and the residual ``e = m − o − A(q) B``
(``B``: the reference direction with the learnt magnitude and dip) is gathered over ``mag_offset_window_s``.
If over that window the body turned (the predicted field direction moved: ``1 − |mean(A(q) B̂)| ≥
mag_offset_turn_fraction``, which separates a body-fixed offset from an earth-fixed disturbance) and the
residual stayed constant (RMS about its mean below ``τ_n |m_ref|``) and did not follow the predicted field
direction ``ĥ = A(q) B̂``, its mean is added to ``o``; the corrected field ``m − o`` then passes the checks
and the magnetometer corrects the heading again. A window that fails a test starts again.

The last test separates an offset from a field of another strength: that leaves ``e = k ĥ`` (``k``: the
strength error), whose spread about its mean is small when the body turns little, and a mean that is no
offset. The share of the residual's spread that follows ``ĥ`` (a squared correlation over the window)::

    r² = cov(e, ĥ)² / (var(e) var(ĥ)),  cov(e, ĥ) = mean(e·ĥ) − mean(e)·mean(ĥ),  var(ĥ) = 1 − |mean(ĥ)|²

is 1 for a pure strength error and 0 for a constant offset; a window with ``r² > mag_offset_scale_r2`` is
refused.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

from ..conventions import Vec3, clip_unit
from .mat3 import dot
from .settings import FusedSettings


class MagneticChecks:
    """Reference, disturbance state, recovery and the learnt hard-iron offset (``offset_uT``)."""

    def __init__(self, settings: FusedSettings, period_s: float) -> None:
        self.s = settings
        self._dip_tolerance_rad = math.radians(settings.mag_dip_tolerance_deg)
        self.set_period(period_s)
        self.norm_ref = 1.0
        self.dip_ref = 0.0
        self.north: tuple[float, float] = (1.0, 0.0)  # horizontal direction of the reference, NED
        self._field_n = 0.0
        self.disturbed = False
        self._disturbed_since_s = -math.inf
        self._clean_since_s = -math.inf
        self._coast_s = 0.0
        self.offset_uT: Vec3 = (0.0, 0.0, 0.0)
        self._window = _OffsetWindow()  # one window from a disturbance on
        self._window_start_s = 0.0
        self.gathering = False  # a window is open: learn_offset() does something only then or when disturbed

    def set_period(self, period_s: float) -> None:
        """The interval between updates, s (the filter keeps it to the measured one): the field learning's count
        is held at ``τ_ref`` / period."""
        self._held_n = self.s.mag_reference_s / period_s

    def set_reference(self, field_ned_uT: Vec3, acc_ref_unit: Vec3, started: bool) -> None:
        """A new reference direction (magnitude too before the start: it is learnt from the data after)."""
        norm = math.sqrt(dot(field_ned_uT, field_ned_uT))
        self.dip_ref = math.asin(clip_unit(-dot(field_ned_uT, acc_ref_unit) / norm))
        horizontal = math.hypot(field_ned_uT[0], field_ned_uT[1])
        if horizontal > 0.0:
            self.north = (field_ned_uT[0] / horizontal, field_ned_uT[1] / horizontal)
        if not started:
            self.norm_ref = norm

    def start(self, mag: Vec3) -> None:
        self.norm_ref = math.sqrt(dot(mag, mag))
        self._field_n = 1.0

    def corrected(self, mag: Vec3) -> Vec3:
        o = self.offset_uT
        return (mag[0] - o[0], mag[1] - o[1], mag[2] - o[2])

    def check(self, mag: Vec3, down_body: Vec3, vertical_var: float) -> tuple[float, float, float]:
        """``(d, |m|, dip)``: ``d`` of the module docstring (≥ 1 disturbed); ``down_body``: the predicted
        vertical (NED down in the body frame), ``vertical_var``: ``σ_v²``."""
        s = self.s
        (m0, m1, m2), (v0, v1, v2) = mag, down_body  # the dot products written out: a call costs as much
        norm = math.sqrt(m0 * m0 + m1 * m1 + m2 * m2)
        if not math.isfinite(norm) or norm == 0.0:
            return math.inf, norm, 0.0
        dip = math.asin(clip_unit((v0 * m0 + v1 * m1 + v2 * m2) / norm))
        d_norm = abs(norm - self.norm_ref) / (s.mag_norm_tolerance_fraction * self.norm_ref)
        d_dip = self.dip_deviation(dip, vertical_var)
        return (d_dip if d_dip > d_norm else d_norm), norm, dip  # max(): the builtin parses its arguments

    def dip_deviation(self, dip: float, vertical_var: float) -> float:
        """The dip's term of ``d``: off the reference's dip by its tolerance, widened by 3σ of the predicted
        vertical's error (itself uncertain); 0 with the dip test off."""
        if self._dip_tolerance_rad == 0.0:
            return 0.0
        return abs(dip - self.dip_ref) / (self._dip_tolerance_rad + 3.0 * math.sqrt(vertical_var))

    def observe(self, d: float, norm: float, dip: float, time_s: float) -> bool:
        """Track the disturbance and learn the field; True when a disturbed field was adopted."""
        relearned = False
        if d >= 1.0:
            if not self.disturbed:
                self.disturbed, self._disturbed_since_s = True, time_s
            if time_s - self._disturbed_since_s < self.s.mag_relearn_s:
                return False
            self._disturbed_since_s, self._field_n, self.dip_ref = time_s, 0.0, dip
            relearned = True
        elif self.disturbed:
            self.disturbed, self._clean_since_s = False, time_s
            self._coast_s = time_s - self._disturbed_since_s
        # A running mean over the first τ_ref, then a low-pass of time constant τ_ref: the count held there.
        n, held = self._field_n + 1.0, self._held_n
        self._field_n = n = n if n < held else held  # not min(): the builtin parses its arguments, every update
        self.norm_ref += (norm - self.norm_ref) / n
        self.dip_ref += (dip - self.dip_ref) / n
        return relearned

    def sigma2_factor(self, d: float, time_s: float) -> float:
        """``(1 + (d/d₀)⁶) ρ``: the σ_m² multiplier below the disturbance threshold."""
        s = self.s
        x = d / s.mag_soft_fraction
        x2 = x * x
        factor = 1.0 + x2 * x2 * x2  # not ** 6: a float's ** is a libm pow call, every update
        elapsed = time_s - self._clean_since_s
        if s.mag_recovery_s == 0.0 or not elapsed < s.mag_recovery_s:
            return factor
        depth = min(1.0, self._coast_s / s.mag_recovery_s)
        return factor * (1.0 + (s.mag_recovery_factor - 1.0) * depth * (1.0 - elapsed / s.mag_recovery_s))

    def predicted_body(self, r: Sequence[float]) -> Vec3:
        """``A(q) B``: the reference direction with the learnt magnitude and dip, in the body frame (``r``: R(q))."""
        c, sd = self.norm_ref * math.cos(self.dip_ref), self.norm_ref * math.sin(self.dip_ref)
        b = (c * self.north[0], c * self.north[1], sd)
        return (
            r[0] * b[0] + r[3] * b[1] + r[6] * b[2],
            r[1] * b[0] + r[4] * b[1] + r[7] * b[2],
            r[2] * b[0] + r[5] * b[1] + r[8] * b[2],
        )

    def learn_offset(self, mag: Vec3, r: Sequence[float], time_s: float) -> bool:
        """Gather ``e = m − o − A(q) B`` over windows (``r``: R(q)); True when a window's mean was added to ``o``."""
        if not self.gathering:  # no window open: one opens on a disturbance
            if not self.disturbed or self.s.mag_offset_window_s == 0.0:
                return False
            self._window, self._window_start_s, self.gathering = _OffsetWindow(), time_s, True
        self._window.add(mag, self.predicted_body(r), self.norm_ref, self.disturbed)
        if time_s - self._window_start_s < self.s.mag_offset_window_s:
            return False
        self.gathering = False
        mean = self._window.offset(self.s, self.norm_ref)
        if mean is None:
            return False
        o = self.offset_uT
        self.offset_uT = (o[0] + mean[0], o[1] + mean[1], o[2] + mean[2])
        return True


class _OffsetWindow:
    """The sums one hard-iron window gathers: the residual ``e``, ``|e|²``, ``ĥ``, ``e·ĥ``, disturbed samples."""

    __slots__ = ("disturbed", "e", "e2", "eh", "h", "n")

    def __init__(self) -> None:
        self.n = self.e2 = self.eh = self.disturbed = 0.0
        self.e = [0.0, 0.0, 0.0]
        self.h = [0.0, 0.0, 0.0]

    def add(self, mag: Vec3, predicted: Vec3, norm: float, disturbed: bool) -> None:
        e = (mag[0] - predicted[0], mag[1] - predicted[1], mag[2] - predicted[2])
        self.n += 1.0
        self.disturbed += disturbed
        for i in range(3):
            self.e[i] += e[i]
            self.h[i] += predicted[i] / norm
        self.e2 += dot(e, e)
        self.eh += dot(e, predicted) / norm

    def offset(self, s: FusedSettings, norm: float) -> Vec3 | None:
        """The window's mean residual if it passes the module docstring's tests (``norm``: ``|m_ref|``)."""
        n = self.n
        mean = (self.e[0] / n, self.e[1] / n, self.e[2] / n)
        h = (self.h[0] / n, self.h[1] / n, self.h[2] / n)
        spread2 = self.e2 / n - dot(mean, mean)
        var_h = 1.0 - dot(h, h)  # also the turn: 1 − |mean ĥ| ≈ var(ĥ)/2 for small turns
        cov = self.eh / n - dot(mean, h)
        if (
            self.disturbed < 0.5 * n  # mostly a disturbance: a clean field needs no offset
            or 1.0 - math.sqrt(dot(h, h)) < s.mag_offset_turn_fraction
            or spread2 > (s.mag_norm_tolerance_fraction * norm) ** 2
            or cov * cov > s.mag_offset_scale_r2 * spread2 * var_h
        ):
            return None
        return mean
