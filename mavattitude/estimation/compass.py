"""Compass consistency: is the magnetometer's field the Earth's field as the accelerometer sees it?

Two figures need no attitude at all, so they can judge the magnetometer before any attitude is trusted:

- the **dip** (inclination) measured in the body, ``asin(d̂ · b̂)`` with ``d̂ = −f̂`` the down direction the
  accelerometer's specific force shows at low acceleration and ``b̂`` the field's direction. For a
  correctly mounted and calibrated compass it is the reference's inclination ``asin(B_D / |B|)`` (NED)
  whatever the attitude: the angle between two vectors does not depend on the frame they are written in.
  A compass mounted upside down reads the opposite dip, one rotated 90° about a horizontal axis shows it
  as soon as the vehicle sits level; a rotation about the vertical shows only when the vehicle tilts;
- the **field ratio** ``|B| / |B₀|`` against the reference's intensity (when it is known).

A third needs no attitude either, and sees what the dip cannot (a compass turned about the vertical,
or mirrored in a vertical plane, keeps its dip while the vehicle is level, which a multicopter is whenever
it does not accelerate): the **turn**. Seen from the body, the Earth's field turns opposite to the body's
rotation, which the gyroscope measures: carried into a frame the integrated gyroscope keeps fixed, a good
field stays put. :class:`TurnCheck` compares, over steps of ``TURN_SPAN_S`` that turned by at least
``MIN_TURN_DEG``, how far the field moved in that frame with how far it moved in the body:
``mismatch = Σ |F_k − F_j|² / Σ |B_k − B_j|²``. A field that turns with the body as the gyroscope says
gives ~0 (0.01–0.05 on every shared recording, 0.27 with a magnet attached to the sensor, an uncorrected
hard iron); a compass mounted in another orientation than the gyroscope turns the other way about some
axis, ≥ 0.4 (flips and 90° turns about any axis, on the SITL flight and the BROAD trials).

Each reading is compared at its own time: a reading held on a later tick (``mag_age_s``: a 10 Hz compass on
25 Hz ticks is up to 0.1 s old, 20° at 200°/s) is turned with the integrated attitude at the tick's time minus
its age (``HISTORY_S`` of attitudes kept). What is left is a lag ``d`` common to the readings (a reading that
is the mean over its interval; a slower stream's longer low-pass delay): the field moves by
``G = R (ω × B)`` per second of lag, so ``F_k − d G_k`` is the reading carried back by ``d``, and the window's
residual ``Σ |ΔF − d ΔG|²`` is least at ``d = Σ ΔF·ΔG / Σ |ΔG|²``, taken within ``[0, MAX_LAG_S]`` and no longer
than a reading was seen held (its age: a reading that is the mean over its interval lags by half of it; a
compass read at every tick, by nothing the ticks can show), so that it cannot absorb a slow turn's
misorientation. The
mismatch is that residual over ``Σ |B_k − B_j|²``. A lag turns the field about the rotation axis in
proportion to the rate; a misorientation by a fixed rotation, which no lag undoes.

The threshold is ``turn_allowance + k · (noise's share)``: ``Σ E|δΔF|² / Σ |B_k − B_j|²`` with, per step,
the magnetometer's noise ``6 σ̄_mag²``; each end's held reading's time uncertain over its tick interval
``Δt`` (uniform; an interpolated one is the stream's at the tick), ``|ω × B|² Δt² / 12``. The gyroscope is
integrated by the trapezoid rule (the rate at a tick standing for the whole interval before it would turn the
attitude by ``(Δt/2)(ω_k − ω_j)`` over a step: 4° at 25 Hz between ±200°/s; the trapezoid leaves
``Δt² ω̈ / 12`` a tick). The turn judged off counts once it is still off ``PERSIST_S = TURN_SPAN_S +
MAX_LAG_S`` after it first went off (not back under ``CLEAR_FRACTION`` meanwhile): by then a step that shares no
reading with the first one off says so too (one late or bad reading sways only the steps within a span and a
lag of it).

A turn mostly about a misorientation's own axis shows it only in the small rest of the turn (a mirror or a
rotation commutes with rotations about its axis), too small a share of the field's change for that ratio.
So the same steps also score every other axis-aligned mounting ``M`` (:data:`MOUNTINGS`): the residual
``S_M`` of "the compass reads ``M b``" (:meth:`TurnCheck.better_mounting`). Only the part of the turn that
tells ``M`` from the configured mounting separates ``S_M`` from ``S_I``, however small its share of the whole
turn; and what the gyroscope and the calibration leave (a bias, a hard-iron residual) is no closer to a
wrong mounting than to the right one. With the steps' noise ``n`` (per-axis variance ``2σ̄²``) and ``D`` the
hypotheses' separation, a good compass gives ``S_I − S_M = −D − 2 Σ d·n``, whose noise is at most
``4 σ̄ √D``: it exceeds ``4 k² σ̄²`` only on a noise excursion beyond ``k`` of its σ, whatever ``D``
(the least ``(D + 4k²σ̄²) / (4σ̄√D)`` is ``k``, at ``D = 4k²σ̄²``). The turn is judged off too when another
mounting gains more than that on the configured one and explains at least ``MIN_EXPLAINED_SHARE`` of its
residual (a hard-iron residual the size of the turn can favour another mounting a little: 7 % on BROAD 33).

Only *quiet* samples count for the dip and |B|: low acceleration (``| |f| − g | ≤ low_accel_fraction · g``),
slow rotation (``|ω| ≤ max_rate_dps``) and a slower turn about the vertical (``|f̂ · ω| ≤ max_turn_rate_dps``: a
coordinated turn at 10 m/s and 7°/s leans the specific force by 7°, 1.2 m/s² of centripetal acceleration, for
as long as it lasts, where ``|f|`` is off g by 0.75 %: under the 10° dip allowance; a vehicle circling, a
copter's CIRCLE mode, is not quiet): elsewhere the specific force is not gravity (linear acceleration; or the
centripetal and tangential acceleration of a sensor off the rotation axis, and the small time offset
between the filtered accelerometer and magnetometer, which together bias the dip by −6° on BROAD's fast
rotation trial at 100–800°/s) and the dip is not the field's. :class:`CompassMonitor` keeps both figures over a
sliding window of vehicle time (mean and spread; ``window_s``, or as long as the stream takes to give
``min_samples`` ticks when that is longer: a telemetry stream's 2 Hz fills ``window_s`` = 10 s with 20, and would
never be judged) and over the first minute, and judges the compass
*inconsistent* when a window mean is further from its reference than the threshold (or the turn mismatch,
below, is beyond its own):

``dip threshold = dip_allowance_deg + k σ_dip``, ``σ_dip = √(σ̄_mag² / |B₀|² + σ̄_acc² / g²)`` (rad),

``field threshold = field_allowance + k σ̄_mag / |B₀|``,

with ``σ̄`` the noise model's RMS per-axis σ (Eq. 2), ``k = NOISE_SIGMAS``: the per-sample direction noise
of each unit vector (Eq. 9, ``tr R_unit = 2σ²/|W|²`` for isotropic noise, ``σ²/|W|²`` per perpendicular
axis) widened by the allowance for what calibration and the field model leave (docs/vehicle.md). It is
consistent again when all three are back within ``CLEAR_FRACTION`` of their thresholds (hysteresis: no
flip-flop at the edge).

Pure functions and a small state machine on plain floats; no I/O (the service and replay say what it found).
"""

from __future__ import annotations

import itertools
import math
from collections import deque
from dataclasses import dataclass
from typing import ClassVar

import numpy as np
from numpy.typing import NDArray

from mavattitude.fields import described, ranged

from .conventions import (
    STANDARD_GRAVITY_MPS2,
    Array,
    Vec3,
    clip_unit,
    quat_from_rotvec_parts,
    quat_multiply_parts,
    quat_normalize_parts,
    rotate_body_to_ned_parts,
    rotation_matrix_parts,
)
from .motion import dot, dot_rows, moving, norm, norm_rows, turning

NOISE_SIGMAS = 3.0  # k: a window mean this many per-sample σ off is not noise
CLEAR_FRACTION = 0.75  # consistent again below this fraction of the thresholds
FIRST_PERIOD_S = 60.0  # "over the first minute": from the first judged sample, vehicle time
HEADING_UNKNOWN_STD_RAD = math.pi / math.sqrt(3.0)  # σ of a heading uniform over ±180°
TURN_SPAN_S = 0.2  # the field's turn is compared over steps this long ...
MIN_TURN_DEG = 5.0  # ... that turned the body by at least this much (else noise dominates)
MAX_TURN_GAP_S = 0.1  # a longer gap between ticks restarts the gyroscope's integration
HISTORY_S = 0.5  # attitudes kept to carry a held reading to its own time (the default input_timeout_s)
MAX_LAG_S = 0.1  # the fitted lag of the readings behind their times is at most this (module docstring)
PERSIST_S = TURN_SPAN_S + MAX_LAG_S  # the turn judged off this long counts: by steps sharing no reading
MIN_SECOND_AXIS_SHARE = 0.1  # a turn vouches for a compass when this share of it was about a second axis
MIN_EXPLAINED_SHARE = 0.5  # another mounting must explain at least this share of the configured one's turn residual


def measured_dip_deg(acc_mps2: Vec3, mag_uT: Vec3) -> float:
    """The field's dip below the horizontal the accelerometer shows, degrees (positive: field points down);
    NaN when either vector is zero (it has no direction, so there is no dip)."""
    norms = norm(acc_mps2) * norm(mag_uT)
    if norms == 0.0:
        return math.nan
    dot = -(acc_mps2[0] * mag_uT[0] + acc_mps2[1] * mag_uT[1] + acc_mps2[2] * mag_uT[2])
    return math.degrees(math.asin(clip_unit(dot / norms)))


def measured_dip_deg_rows(acc_mps2: Array, mag_uT: Array) -> Array:
    """:func:`measured_dip_deg` of each row, the same operations in the same order (``asin`` by :mod:`math`:
    numpy's vectorised one differs in the last bit)."""
    dot = -(acc_mps2[:, 0] * mag_uT[:, 0] + acc_mps2[:, 1] * mag_uT[:, 1] + acc_mps2[:, 2] * mag_uT[:, 2])
    norms = norm_rows(acc_mps2) * norm_rows(mag_uT)
    with np.errstate(divide="ignore", invalid="ignore"):  # a zero vector's row: NaN below
        ratio = dot / norms
    ratio = np.where(ratio < 1.0, ratio, 1.0)  # clip_unit's comparisons: NaN becomes 1, as there
    ratio = np.where(ratio > -1.0, ratio, -1.0)
    ratio = np.where(norms == 0.0, np.nan, ratio)  # no direction, no dip, as there
    return np.degrees(np.fromiter(map(math.asin, ratio.tolist()), float, len(ratio)))


def reference_dip_deg(field_ned_uT: Vec3) -> float:
    """The inclination of a NED reference field, degrees (positive down)."""
    return math.degrees(math.asin(clip_unit(field_ned_uT[2] / norm(field_ned_uT))))


def rms_sigma(std: Vec3) -> float:
    """The RMS of three per-axis σ."""
    return math.sqrt((std[0] ** 2 + std[1] ** 2 + std[2] ** 2) / 3.0)


@dataclass(frozen=True)
class CompassSettings:
    """How the monitor judges (see the module docstring): the config's ``compass`` section itself."""

    enabled: bool = described(True, "judge the compass (dip, |B|); off, IGN takes only heading from it")
    window_s: float = ranged(10.0, "sliding window of the dip and |B| figures, s", 1.0, 3600.0)
    low_accel_fraction: float = ranged(0.05, "samples with ||a| − g| below this · g count", 0.0, 0.5, lo_open=True)
    max_rate_dps: float = ranged(60.0, "and rotating slower than this, deg/s", 0.0, 2000.0, lo_open=True)
    max_turn_rate_dps: float = ranged(
        7.0,
        "and turning about the vertical slower than this (a sustained turn leans the gravity), deg/s",
        0.0,
        2000.0,
        lo_open=True,
    )
    dip_allowance_deg: float = ranged(10.0, "dip error calibration and field model explain, deg", 0.0, 90.0)
    field_allowance: float = ranged(0.15, "|B| error calibration and field model explain, fraction", 0.0, 1.0)
    turn_allowance: float = ranged(0.2, "share of the field's turn it may make unlike the gyroscope", 0.0, 10.0)
    others_rate_hz: float = ranged(
        0.0, "live: ask for the other compasses' IMU messages at this rate, to judge them too (0: if sent)", 0.0, 50.0
    )
    min_samples: ClassVar[int] = 25  # quiet samples in the window before judging (0.5 s at 50 Hz)


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
    turn_mismatch: float  # window Σ|F_k − F_j|² / Σ|B_k − B_j|²: ~0 for a field that turns as the gyroscope says
    threshold_turn: float
    mounting_share: float  # share of the configured mounting's turn residual the best other mounting explains
    mounting_off: bool  # that mounting explains the turns better beyond the noise (module docstring)
    inconsistent: bool
    warnings: int  # times it turned inconsistent
    reference_measured: bool = False  # the reference is the compass's own field at the start (no position)

    @property
    def expected(self) -> str:
        """What the dip and |B| are held against, in words."""
        return "measured at the start" if self.reference_measured else "expected"

    def describe(self) -> str:
        """One line for a person: what was measured against what was expected."""
        text = f"compass dip {self.dip_deg:+.0f}° vs {self.expected} {self.expected_dip_deg:+.0f}°"
        if self.field_ratio == self.field_ratio:
            text += f", |B| {100.0 * self.field_ratio:.0f} % of the {self.expected}"
        if self.turn_mismatch == self.turn_mismatch:
            text += f", turns unlike the gyroscope by {100.0 * self.turn_mismatch:.0f} %"
        if self.mounting_off:
            text += f", {100.0 * self.mounting_share:.0f} % of that explained by a compass mounted otherwise"
        return text

    def short(self) -> str:
        """What was off, in a few words with the likely cause ("turns unlike the gyro: turned?"), for a summary cell."""
        off = []
        if abs(self.dip_deg - self.expected_dip_deg) > self.threshold_dip_deg:
            off.append("dip off: mounted or calibrated wrongly?")
        if abs(self.field_ratio - 1.0) > self.threshold_field:
            off.append("|B| off: calibration, magnet?")
        if self.turn_off:
            off.append("turns unlike the gyro: turned?")
        return ", ".join(off) or "off"

    @property
    def turn_off(self) -> bool:
        """The turn is off: its mismatch beyond its threshold, or another mounting explains it (named first)."""
        return self.turn_mismatch > self.threshold_turn or self.mounting_off


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


class TurnCheck:
    """Whether the field turns in the body as the gyroscope says it should (see the module docstring)."""

    def __init__(self, window_s: float) -> None:
        self.window_s = window_s
        self._q = (1.0, 0.0, 0.0, 0.0)  # body → a frame the integrated gyroscope keeps fixed
        self._t: float | None = None
        self._history: deque[tuple[float, tuple, Vec3]] = deque()  # (t, q, ω) within HISTORY_S: readings' times
        # [t, q at the reading's time, B, ω then, (F, G) or None] within TURN_SPAN_S: F, the field in the fixed
        # frame, and G, its rate of change per second of lag, are made when a step needs them
        self._recent: deque[list] = deque()
        # (t, |ΔF|², |ΔB|², ΔF·ΔG, |ΔG|², the step's timing variance, its turn v vᵀ: 6 terms, |B_j|² + |B_k|²,
        # Q ⊗ B_j B_kᵀ) within window_s
        self._steps: deque[tuple] = deque()
        self.moved2 = self.changed2 = self.lagged = self.lag2 = self.timing2 = 0.0
        self.held_s = 0.0  # the longest a reading was held (its age at a tick), s
        self._axes = [0.0] * 6  # Σ v vᵀ of the steps' turns (body frame): xx yy zz xy xz yz
        self._norms2 = 0.0  # Σ |B_j|² + |B_k|²
        self._products = np.zeros(81)  # Σ Q_jk ⊗ B_j B_kᵀ: every mounting's residual is linear in it
        self._scored: tuple[float, float] | None = None  # better_mounting() of the window as it is (None: changed)

    @property
    def steps(self) -> int:
        return len(self._steps)

    def lag_s(self) -> float:
        """The magnetometer's lag behind its readings' times that best explains the window's turns, within
        ``[0, min(held, MAX_LAG_S)]`` (module docstring)."""
        if self.lag2 <= 0.0:
            return 0.0
        return min(max(self.lagged / self.lag2, 0.0), self.held_s, MAX_LAG_S)

    def residual2(self) -> float:
        """``Σ |ΔF − d ΔG|²`` at the fitted lag ``d``: what the turns leave unexplained, µT²."""
        d = self.lag_s()
        return max(self.moved2 - 2.0 * d * self.lagged + d * d * self.lag2, 0.0)

    def mismatch(self) -> float:
        if not self._steps:
            return math.nan
        if self.changed2 <= 0.0:  # the body turned and the field did not move in it at all
            return math.inf if self.moved2 > 0.0 else math.nan
        return self.residual2() / self.changed2

    def update(self, time_s: float, mag_uT: Vec3, gyr_radps: Vec3, mag_age_s: float = 0.0) -> None:
        history = self._history
        if self._t is None or not 0.0 < time_s - self._t <= MAX_TURN_GAP_S:
            self._recent.clear()  # a gap or a reset: the integration starts over
            history.clear()
            dt = 0.0
        else:
            dt = time_s - self._t
            w0 = history[-1][2]  # the trapezoid rule: the rate at a tick does not stand for the whole interval
            h = 0.5 * dt
            step = quat_from_rotvec_parts(
                (w0[0] + gyr_radps[0]) * h, (w0[1] + gyr_radps[1]) * h, (w0[2] + gyr_radps[2]) * h
            )
            self._q = quat_normalize_parts(quat_multiply_parts(self._q, step))
        self._t = time_s
        self.held_s = max(self.held_s, mag_age_s)
        history.append((time_s, self._q, gyr_radps))
        while history[0][0] < time_s - HISTORY_S:
            history.popleft()
        q_read, w_read = _attitude_at(history, time_s - mag_age_s) if mag_age_s > 0.0 else (self._q, gyr_radps)
        recent = self._recent
        now = [time_s, q_read, mag_uT, w_read, None, dt, dt if mag_age_s > 0.0 else 0.0]
        recent.append(now)
        while len(recent) > 1 and recent[1][0] <= time_s - TURN_SPAN_S:
            recent.popleft()
        then = recent[0]
        t0, q0, b0 = then[0], then[1], then[2]
        if time_s - t0 >= TURN_SPAN_S and self._turned(q0, q_read):
            f1, g1 = _fixed(now)
            f0, g0 = _fixed(then)
            a = (f1[0] - f0[0], f1[1] - f0[1], f1[2] - f0[2])
            g = (g1[0] - g0[0], g1[1] - g0[1], g1[2] - g0[2])
            self._add(
                time_s,
                _dot(a, a),
                _distance2(mag_uT, b0),
                _dot(a, g),
                _dot(g, g),
                _timing_variance(now, then),
                _turn_outer(q0, q_read),
                _dot(b0, b0) + _dot(mag_uT, mag_uT),
                _step_products(q0, q_read, b0, mag_uT),
                1,
            )
        steps = self._steps
        while steps and steps[0][0] <= time_s - self.window_s:
            self._add(*steps.popleft(), -1)
            if not steps:  # nothing in the window: the running sums start again from exact zeros
                self.moved2 = self.changed2 = self.lagged = self.lag2 = self.timing2 = self._norms2 = 0.0
                self._axes = [0.0] * 6
                self._products[:] = 0.0

    def _add(
        self,
        time_s: float,
        moved2: float,
        changed2: float,
        lagged: float,
        lag2: float,
        timing2: float,
        outer: tuple[float, ...],
        norms2: float,
        products: NDArray[np.float64],
        sign: int,
    ) -> None:
        if sign > 0:
            self._steps.append((time_s, moved2, changed2, lagged, lag2, timing2, outer, norms2, products))
        self.moved2 += sign * moved2
        self.changed2 += sign * changed2
        self.lagged += sign * lagged
        self.lag2 += sign * lag2
        self.timing2 += sign * timing2
        self._axes = [a + sign * o for a, o in zip(self._axes, outer, strict=True)]
        self._norms2 += sign * norms2
        if sign > 0:
            self._products += products
        else:
            self._products -= products
        self._scored = None

    def better_mounting(self) -> tuple[float, float]:
        """How much better the best other axis-aligned mounting explains the window's turns than the configured one.

        For a compass mounted as ``M`` (its reading ``M b`` of the body's field ``b``), ``R_k Mᵀ B_k`` stays
        put in the gyroscope's fixed frame; the window's residual of that hypothesis is
        ``S_M = Σ |R_k Mᵀ B_k − R_j Mᵀ B_j|² = Σ (|B_j|² + |B_k|²) − 2 tr(M Q_jk Mᵀ B_j B_kᵀ)``, ``Q_jk = R_kᵀ R_j``,
        linear in the window's ``Σ Q_jk ⊗ B_j B_kᵀ``: every candidate of :data:`MOUNTINGS` is scored at once.
        Returns ``S_I − min S_M`` (µT²) over the candidates other than the configured one, and the share of
        ``S_I`` it explains (0 without a residual: nothing to explain). A turn about a mirror's or a
        misorientation's own axis moves both hypotheses alike, so only the part of the turn that tells them apart
        counts, however small its share of the whole turn; and what the gyroscope and the calibration leave (a
        bias, a hard-iron residual) is no closer to a wrong mounting than to the configured one, so it needs no
        allowance here.
        """
        if self._scored is None:
            scores = self._norms2 - 2.0 * (_MOUNTING_WEIGHTS @ self._products)
            configured = float(scores[0])
            gain = configured - float(scores[1:].min())
            self._scored = (gain, gain / configured if configured > 0.0 else 0.0)
        return self._scored

    def second_axis_share(self) -> float:
        """The share of the window's turn about its second principal axis (0: all about one axis).

        A compass mirrored or turned about an axis turns like a good one while the body turns about that
        axis only (its misorientation commutes with those rotations): the turn vouches for a compass only
        when the body turned about a second axis too.
        """
        xx, yy, zz, xy, xz, yz = self._axes
        total = xx + yy + zz
        if total <= 0.0:
            return 0.0
        eigen = np.linalg.eigvalsh(np.array([[xx, xy, xz], [xy, yy, yz], [xz, yz, zz]]))
        return float(eigen[1] / total)

    @staticmethod
    def _turned(q0: tuple, q: tuple) -> bool:
        return abs(q0[0] * q[0] + q0[1] * q[1] + q0[2] * q[2] + q0[3] * q[3]) <= _COS_HALF_MIN_TURN


def _attitude_at(history: deque[tuple[float, tuple, Vec3]], time_s: float) -> tuple[tuple, Vec3]:
    """The integrated attitude and the rate at ``time_s`` (a reading's time, at or before the newest tick): the
    tick before it turned on by the next tick's rate, as the integration steps (the oldest kept, if older)."""
    newer = history[-1]
    for entry in reversed(history):
        if entry[0] <= time_s:
            dt = time_s - entry[0]
            w = newer[2]
            if dt <= 0.0:
                return entry[1], w
            return quat_normalize_parts(
                quat_multiply_parts(entry[1], quat_from_rotvec_parts(w[0] * dt, w[1] * dt, w[2] * dt))
            ), w
        newer = entry
    return newer[1], newer[2]


def _fixed(entry: list) -> tuple[Vec3, Vec3]:
    """A recent tick's field carried into the gyroscope's fixed frame ``F = R B``, and ``G = R (ω × B)``, by how
    much ``F`` moves per second the reading lags its time; made once (most ticks end no step)."""
    if entry[4] is None:
        r = rotation_matrix_parts(entry[1])
        b, w = entry[2], entry[3]
        cross = (w[1] * b[2] - w[2] * b[1], w[2] * b[0] - w[0] * b[2], w[0] * b[1] - w[1] * b[0])
        entry[4] = (rotate_body_to_ned_parts(r, b), rotate_body_to_ned_parts(r, cross))
    return entry[4]


def _timing_variance(now: list, then: list) -> float:
    """``E |δF|²`` of one step from what the samples cannot resolve in time (module docstring): each end's held
    reading's time uncertain over its tick interval, ``|ω × B|² Δt² / 12`` (an interpolated one is the stream's at
    the tick), µT²."""
    total = 0.0
    for entry in (now, then):
        _, g = _fixed(entry)
        total += _dot(g, g) * entry[6] * entry[6] / 12.0
    return total


def _turn_outer(q0: tuple, q1: tuple) -> tuple[float, ...]:
    """``v vᵀ`` (xx yy zz xy xz yz) of the vector part ``v`` of ``q0* ⊗ q1``: the turn between two attitudes,
    in the body frame, its length ``sin(θ/2)``."""
    _, x, y, z = quat_multiply_parts((q0[0], -q0[1], -q0[2], -q0[3]), q1)
    return (x * x, y * y, z * z, x * y, x * z, y * z)


def _step_products(q0: tuple, q1: tuple, b0: Vec3, b1: Vec3) -> NDArray[np.float64]:
    """``Q ⊗ B_j B_kᵀ`` (81 terms, index ``(b, c, d, a)``: ``Q_bc B_j,d B_k,a``) of one step from attitude ``q0``
    (field ``b0``) to ``q1`` (``b1``): ``Q = R_kᵀ R_j = R(q1* ⊗ q0)``."""
    turn = rotation_matrix_parts(quat_multiply_parts((q1[0], -q1[1], -q1[2], -q1[3]), q0))
    x0, y0, z0 = b0
    x1, y1, z1 = b1
    fields = np.array((x0 * x1, x0 * y1, x0 * z1, y0 * x1, y0 * y1, y0 * z1, z0 * x1, z0 * y1, z0 * z1))
    return np.multiply.outer(np.array(turn), fields).ravel()


def _mountings() -> NDArray[np.float64]:
    """The 24 rotations that take the configured axes onto themselves (every 90° turn and their products), the
    configured mounting (identity) first.

    The mirrors need no candidates of their own: ``M`` and ``−M`` turn alike (``M Q Mᵀ`` is the same matrix),
    and a mirror ``S`` is ``−`` the rotation by 180° about its axis, which the dip tells apart."""
    signed = (
        np.eye(3)[list(order)] * np.array(signs)[:, None]
        for order in itertools.permutations(range(3))
        for signs in itertools.product((1.0, -1.0), repeat=3)
    )
    return np.array([m for m in signed if np.linalg.det(m) > 0.0])


MOUNTINGS = _mountings()
# tr(M Q Mᵀ C) = Σ M_ab Q_bc M_dc C_da: each mounting's weights on the (b, c, d, a) terms of Q ⊗ C
_MOUNTING_WEIGHTS = np.einsum("mab,mdc->mbcda", MOUNTINGS, MOUNTINGS).reshape(len(MOUNTINGS), 81)


def _dot(a: Vec3, b: Vec3) -> float:
    return float(a[0] * b[0] + a[1] * b[1] + a[2] * b[2])


def _floats(v: Vec3) -> Vec3:
    return (float(v[0]), float(v[1]), float(v[2]))


def _distance2(a: Vec3, b: Vec3) -> float:
    x, y, z = a[0] - b[0], a[1] - b[1], a[2] - b[2]
    return float(x * x + y * y + z * z)


_COS_HALF_MIN_TURN = math.cos(math.radians(MIN_TURN_DEG) / 2.0)


class CompassMonitor:
    """Dip and field ratio over a sliding window and the first minute; the consistency verdict.

    ``set_reference`` gives the expected field (its intensity ``None`` when only the direction is known);
    ``update`` takes each front-end tick's body-frame specific force, field and rates and returns a
    :class:`CompassEvent` when the verdict changes (else ``None``).
    """

    def __init__(self, settings: CompassSettings, accel_std_mps2: Vec3, mag_std_uT: Vec3) -> None:
        self.settings = settings
        self._max_rate_radps = math.radians(settings.max_rate_dps)
        self._max_turn_radps = math.radians(settings.max_turn_rate_dps)
        self._sigmas = (accel_std_mps2, mag_std_uT)
        self._mag_sigma2 = rms_sigma(mag_std_uT) ** 2  # σ̄_mag², every judgement's
        self._window: deque[tuple[float, float, float | None]] = deque()  # (t, dip, |B| or None)
        self._win = _Stats()
        self._last_tick_s = math.nan
        self._intervals_s = (math.inf, math.inf)  # the last two between ticks: a stream's pace, not one gap's
        self.ever_judged = False  # the window once held enough quiet samples to judge
        self._first = _Stats()
        self._first_until_s = math.nan
        self._expected_dip = math.nan
        self._field_uT: float | None = None
        self._reference_measured = False
        self._thresholds = Thresholds(math.nan, math.nan, math.nan)
        self._turn = TurnCheck(settings.window_s)
        self._dip_excess = 0.0  # the dip's distance over its threshold, as last judged
        self._field_excess = 0.0  # |B|'s, as last judged
        self._judged_dip = math.nan  # the window's mean dip when last judged (NaN: never judged)
        self._turn_excess = 0.0  # the turn mismatch over its threshold, as last judged
        self._turn_off_since_s = math.nan  # vehicle time the turn excess last went over 1 (NaN: it is not)
        self._mounting_excess = 0.0  # another mounting's explanation of the turn over its thresholds, as last judged
        self._mounting_share = math.nan
        self.confirmed_at_s = math.nan  # vehicle time it was vouched for (NaN: not yet)
        self.samples = 0
        self.inconsistent = False
        self.warnings = 0

    @property
    def judged(self) -> bool:
        """Enough quiet samples in the window to judge the dip."""
        return self._win.n >= self.settings.min_samples

    @property
    def confirmed(self) -> bool:
        """Found consistent in dip and in turn (each within ``CLEAR_FRACTION`` of its threshold), never
        warned about: from then on every sample of it is trusted."""
        return self.confirmed_at_s == self.confirmed_at_s

    @property
    def turn_judged(self) -> bool:
        """Enough turning steps in the window to judge the turn."""
        return self._turn.steps >= self.settings.min_samples

    def _turn_threshold(self) -> float:
        """``turn_allowance`` plus k times the share of the field's change that its noise explains."""
        if not self._turn.changed2:
            return math.nan
        noise_share = (self._turn.steps * 6.0 * self._mag_sigma2 + self._turn.timing2) / self._turn.changed2
        return self.settings.turn_allowance + NOISE_SIGMAS * noise_share

    def _mounting_threshold_uT2(self) -> float:
        """``4 k² σ̄²``: what noise alone lets another mounting gain on the configured one (module docstring)."""
        return 4.0 * NOISE_SIGMAS * NOISE_SIGMAS * self._mag_sigma2

    def set_reference(self, field_ned_uT: Vec3, intensity_uT: float | None, measured: bool = False) -> None:
        """The field to hold the dip and |B| against; ``measured``: the compass's own at the start (no position),
        against which they show a change since, not an error (docs/vehicle.md)."""
        self._expected_dip = reference_dip_deg(field_ned_uT)
        self._field_uT = intensity_uT
        self._reference_measured = measured
        scale = intensity_uT if intensity_uT is not None else norm(field_ned_uT)
        self._thresholds = thresholds(self.settings, *self._sigmas, scale)

    def quiet(self, acc_mps2: Vec3, gyr_radps: Vec3) -> bool:
        """Low acceleration, slow rotation and a slower turn about the vertical: the specific force shows gravity
        (module docstring)."""
        acc_norm = norm(acc_mps2)
        return not (
            moving(acc_norm, norm(gyr_radps), self.settings.low_accel_fraction, self._max_rate_radps)
            or turning(dot(acc_mps2, gyr_radps), acc_norm, self._max_turn_radps)
        )

    def quiet_dip_field(self, acc_mps2: Vec3, mag_uT: Vec3, gyr_radps: Vec3) -> tuple[float, float]:
        """The dip (degrees) and |B| (µT) of one tick when it is quiet, NaN when not: what the monitor takes
        into its figures, for a reference measured from the compass (:mod:`mavattitude.sensors.magref`)."""
        acc_mps2, mag_uT, gyr_radps = _floats(acc_mps2), _floats(mag_uT), _floats(gyr_radps)
        if not self.quiet(acc_mps2, gyr_radps):
            return math.nan, math.nan
        return measured_dip_deg(acc_mps2, mag_uT), norm(mag_uT)

    def quiet_dip_field_rows(self, acc_mps2: Array, mag_uT: Array, gyr_radps: Array) -> tuple[Array, Array]:
        """:meth:`quiet_dip_field` of each row, the same operations in the same order."""
        quiet = self._quiet_rows(acc_mps2, gyr_radps)
        dip = np.where(quiet, measured_dip_deg_rows(acc_mps2, mag_uT), np.nan)
        return dip, np.where(quiet, norm_rows(mag_uT), np.nan)

    def suspect(self, acc_mps2: Vec3, mag_uT: Vec3, gyr_radps: Vec3) -> bool:
        """Whether this one sample's field should set heading only.

        While the compass is judged inconsistent: always. Once it has been found consistent in both dip and
        turn about two axes (:attr:`confirmed`): never. Before it can be judged: when this sample's dip (when quiet) is
        beyond the threshold. Judged consistent in dip but not yet vouched for in turn (a compass turned
        about the vertical, or mirrored in a vertical plane, keeps its dip while the vehicle is level; only
        a turn shows it, and a fast manoeuvre tilts the vehicle before the turn check has enough steps):
        when this sample's dip is further than the noise model's ``k σ_dip`` from the window's mean dip
        when last judged, at any acceleration. The tilt is dragged only by the field's part that disagrees
        with gravity, the dip error, weighted by the field's share of the Wahba weights: gating each sample
        at the noise bounds the drag from the first sample. Once it has been judged inconsistent (a compass
        found off stays suspect: a misorientation about a horizontal axis shows only while the vehicle
        tilts, and the window mean clears while it hovers level): when this sample's dip is further off
        than ``k σ_dip`` from the reference's, at any acceleration.
        """
        if self.inconsistent:
            return True
        if self.confirmed:
            return False  # a compass found consistent in dip and turn: every sample is trusted (IGN is the paper's)
        return self._dip_suspect(measured_dip_deg(_floats(acc_mps2), _floats(mag_uT)), self.quiet(acc_mps2, gyr_radps))

    def _dip_suspect(self, dip: float, quiet: bool) -> bool:
        """:meth:`suspect` of a sample whose dip is ``dip``, neither judged inconsistent nor confirmed."""
        if self.warnings:
            return abs(dip - self._expected_dip) > self._thresholds.dip_noise_deg
        if self._judged_dip != self._judged_dip:  # never judged yet
            return abs(dip - self._expected_dip) > self._thresholds.dip_deg and quiet
        return abs(dip - self._judged_dip) > self._thresholds.dip_noise_deg

    def update(
        self, time_s: float, acc_mps2: Vec3, mag_uT: Vec3, gyr_radps: Vec3, mag_age_s: float = 0.0
    ) -> CompassEvent | None:
        """One tick; ``mag_age_s``: how long before ``time_s`` the magnetometer reading was taken (held)."""
        if self._expected_dip != self._expected_dip:
            return None
        return self.update_and_suspect(time_s, acc_mps2, mag_uT, gyr_radps, mag_age_s)[0]

    def update_and_suspect(
        self, time_s: float, acc_mps2: Vec3, mag_uT: Vec3, gyr_radps: Vec3, mag_age_s: float = 0.0
    ) -> tuple[CompassEvent | None, bool]:
        """:meth:`update` then :meth:`suspect` of the same tick, its quietness and dip computed once (the live
        ticks' form of :meth:`update_rows`)."""
        if self._expected_dip != self._expected_dip:
            return None, self.suspect(acc_mps2, mag_uT, gyr_radps)
        # plain floats: numpy scalars (the batch front end's ticks) make this arithmetic ten times slower
        acc_mps2, mag_uT, gyr_radps = _floats(acc_mps2), _floats(mag_uT), _floats(gyr_radps)
        quiet = self.quiet(acc_mps2, gyr_radps)
        dip = measured_dip_deg(acc_mps2, mag_uT) if quiet else math.nan
        field = norm(mag_uT) if quiet and self._field_uT is not None else None
        event = self._take(float(time_s), mag_uT, gyr_radps, float(mag_age_s), quiet, dip, field)
        if self.inconsistent or self.confirmed:
            return event, self.inconsistent
        return event, self._dip_suspect(dip if quiet else measured_dip_deg(acc_mps2, mag_uT), quiet)

    def update_rows(
        self, time_s: Array, acc_mps2: Array, mag_uT: Array, gyr_radps: Array, mag_age_s: Array | None = None
    ) -> tuple[list[CompassEvent | None], list[bool], list[bool]]:
        """:meth:`update` then :meth:`suspect` for each row of ``(n,)`` times and ages and ``(n, 3)`` vectors, in order:
        each row's event, whether it is suspect, and whether the compass is judged inconsistent after it.

        What needs no state (quietness, dip, |B|) is computed for all rows at once, with the same operations as
        one by one (the same values); the state machine then steps through the rows on plain floats.
        """
        events: list[CompassEvent | None] = []
        suspect: list[bool] = []
        inconsistent: list[bool] = []
        known = self._expected_dip == self._expected_dip  # else update() judges nothing
        quiet = self._quiet_rows(acc_mps2, gyr_radps).tolist()
        dips = measured_dip_deg_rows(acc_mps2, mag_uT).tolist()
        fields = norm_rows(mag_uT).tolist() if self._field_uT is not None else [None] * len(time_s)
        ages = [0.0] * len(time_s) if mag_age_s is None else mag_age_s.tolist()
        for t, m, g, age, q, dip, field in zip(
            time_s.tolist(), mag_uT.tolist(), gyr_radps.tolist(), ages, quiet, dips, fields, strict=True
        ):
            events.append(self._take(t, tuple(m), tuple(g), age, q, dip, field) if known else None)
            suspect.append(self.inconsistent or (not self.confirmed and self._dip_suspect(dip, q)))
            inconsistent.append(self.inconsistent)
        return events, suspect, inconsistent

    def _quiet_rows(self, acc_mps2: Array, gyr_radps: Array) -> NDArray[np.bool_]:
        """:meth:`quiet` of each row, the same operations in the same order."""
        s, acc_norm = self.settings, norm_rows(acc_mps2)
        return ~(
            moving(acc_norm, norm_rows(gyr_radps), s.low_accel_fraction, self._max_rate_radps)
            | turning(dot_rows(acc_mps2, gyr_radps), acc_norm, self._max_turn_radps)
        )

    def _take(
        self,
        time_s: float,
        mag_uT: Vec3,
        gyr_radps: Vec3,
        mag_age_s: float,
        quiet: bool,
        dip: float,
        field: float | None,
    ) -> CompassEvent | None:
        """One tick into the turn check, the quiet window (when ``quiet``: its ``dip``, ``field``), the verdict."""
        interval = time_s - self._last_tick_s
        self._last_tick_s = time_s
        self._intervals_s = (self._intervals_s[1], interval if interval > 0.0 else math.inf)  # NaN: the first
        self._turn.update(time_s, mag_uT, gyr_radps, mag_age_s)
        if quiet:
            self._add_quiet(time_s, dip, field)
        if not (self.judged or self.turn_judged):
            return None
        self.ever_judged = True
        return self._judge(time_s)

    def _add_quiet(self, time_s: float, dip: float, field: float | None) -> None:
        self.samples += 1
        if self._first_until_s != self._first_until_s:
            self._first_until_s = time_s + FIRST_PERIOD_S
        if time_s <= self._first_until_s:
            self._first.add(dip, field)
        self._window.append((time_s, dip, field))
        self._win.add(dip, field)
        span_s = max(self.settings.window_s, self.settings.min_samples * min(self._intervals_s))  # (inf: first)
        while self._window and self._window[0][0] <= time_s - span_s:
            _, old_dip, old_field = self._window.popleft()
            self._win.add(old_dip, old_field, -1)

    def _excess(self, time_s: float) -> float:
        """The largest of the window's distances from the reference (dip, |B|) and of the turn mismatch, each
        as a fraction of its threshold (those never judged count 0)."""
        # Each figure's last judgement holds while it has too few samples to judge: a vehicle that stopped
        # turning, or that has not been quiet for a window, shows nothing new either way.
        t = self._thresholds
        if self.judged:
            self._judged_dip = self._win.dip_mean()
            self._dip_excess = abs(self._judged_dip - self._expected_dip) / t.dip_deg
            if self._field_uT is not None and self._win.nf:
                self._field_excess = abs(self._win.field_mean() / self._field_uT - 1.0) / t.field
        if self.turn_judged:
            gain, self._mounting_share = self._turn.better_mounting()
            self._mounting_excess = min(
                gain / self._mounting_threshold_uT2(), self._mounting_share / MIN_EXPLAINED_SHARE
            )
            self._turn_excess = max(self._turn.mismatch() / self._turn_threshold(), self._mounting_excess)
        return max(self._dip_excess, self._field_excess, self._persistent_turn_excess(time_s))

    def _persistent_turn_excess(self, time_s: float) -> float:
        """The turn's excess, held at 1 until it is over 1 ``PERSIST_S`` after it first went over, not having
        fallen back under ``CLEAR_FRACTION`` (what clears a verdict) in between (module docstring)."""
        if self._turn_excess < CLEAR_FRACTION:
            self._turn_off_since_s = math.nan
        elif self._turn_excess > 1.0 and self._turn_off_since_s != self._turn_off_since_s:
            self._turn_off_since_s = time_s
        if self._turn_excess <= 1.0 or time_s - self._turn_off_since_s >= PERSIST_S:
            return self._turn_excess
        return 1.0

    def _judge(self, time_s: float) -> CompassEvent | None:
        excess = self._excess(time_s)
        if not self.confirmed and self._vouched():
            self.confirmed_at_s = time_s
        if not self.inconsistent and excess > 1.0:
            self.inconsistent = True
            self.warnings += 1
        elif self.inconsistent and excess < CLEAR_FRACTION:
            self.inconsistent = False
        else:
            return None
        return CompassEvent(time_s, self.inconsistent, self.figures())

    def _vouched(self) -> bool:
        """Oriented as configured: consistent in dip (as last judged: a vehicle in continuous motion has few
        quiet samples) and in a turn about more than one axis, both clear of their thresholds (the turn's
        without the noise's share), never warned.
        Not |B|: a field whose intensity is off is screened sample by sample (the front end's ``MAG_NORM``)."""
        return (
            self._judged_dip == self._judged_dip
            and self.turn_judged
            and self._dip_excess < CLEAR_FRACTION
            # the allowance alone, not widened by the noise's share: a turn too small to judge well vouches for nothing
            and self._turn.mismatch() < CLEAR_FRACTION * self.settings.turn_allowance
            and self._mounting_excess < CLEAR_FRACTION
            and not self.warnings
            and self._turn.second_axis_share() >= MIN_SECOND_AXIS_SHARE
        )

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
            turn_mismatch=self._turn.mismatch(),
            threshold_turn=self._turn_threshold(),
            mounting_share=self._mounting_share,
            mounting_off=self._mounting_excess > 1.0,
            inconsistent=self.inconsistent,
            warnings=self.warnings,
            reference_measured=self._reference_measured,
        )


def heading_uncertain(covariance: NDArray[np.float64], acc_mps2: Vec3) -> NDArray[np.float64]:
    """``P + σ_h² d̂ d̂ᵀ``: a body error-angle covariance (rad², 3×3) with the rotation about the vertical
    ``d̂ = −f̂`` (body) made as uncertain as a heading uniform over ±180° (``HEADING_UNKNOWN_STD_RAD``)."""
    d = np.asarray(acc_mps2, dtype=float)
    d /= np.linalg.norm(d)
    return covariance + HEADING_UNKNOWN_STD_RAD**2 * np.outer(d, d)
