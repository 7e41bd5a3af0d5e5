"""The gyro-aided filter: error-state Kalman filter + accelerometer tilt + magnetometer heading.

The paper (Liu et al. 2014) ends by noting that the accelerometer + magnetometer solution should aid a
gyro, because under sustained acceleration the accelerometer no longer points along gravity. This is that
filter. Pure math: no I/O, no clock (time comes from the samples), no logging (events are counted in
:attr:`FusedFilter.counters` for the caller to report). ``docs/fused.md`` has the equations, the tuning
and the measured figures; the parts are :mod:`.ekf` (state, propagation, the update),
:mod:`.rest` (zero-rate update), :mod:`.magnetic` (checks, field learning, hard-iron offset).

Accelerometer pre-filters (quasi-inertial low-passes): with ``q_g`` the gyro-only attitude,
``a_I ← LP₂(R(q_g) a)``, ``ã = A(q_g) a_I`` — second-order Butterworth low-passes at the update rate,
cut-off ``√2 / (2π τ)`` (VQF's pre-filter, Laidig & Seel 2023), designed by
:func:`mavattitude.lowpass.butter2` like the front end's. Two of them: ``ã`` (``τ_a``) is what
the tilt update measures — long, so that hand motion and vibration, which average out in an earth-fixed
frame, are gone; ``ã_j`` (``τ_j``, shorter) is what the rejection watches, since it sees an acceleration
start (and end) sooner.

Tilt update — ``u = ã/|ã|`` against ``h = A(q) v_a``: ``u − h ≈ [h×] δθ``; along two unit vectors
``e₁, e₂ ⊥ h``: ``zᵢ = eᵢ·(u − h)``, ``h_θ = eᵢ × h``, ``r = (σ_a'/|ã|)²``, gain kept off ``h`` (the
heading), with the acceleration rejection (smooth covariance inflation, never a switch)::

    σ_a'² = σ_a² + (k_n (|ã_j| − g))² + (k_d |a_I − a_I,j|)²

``|ã_j| − g``: a sustained acceleration (it changes |a|); ``|a_I − a_I,j|``: the two pre-filters disagree,
so the long one still holds an acceleration that started or ended within ``τ_a`` (a flight's manoeuvre,
which hand motion is not).

Heading update — the horizontal field ``m_h`` (of ``R(q) (m − o)``) against the reference's
horizontal direction ``n``: ``z = atan2(m_h × n, m_h · n)``, ``h_θ = A(q) e_D`` (the vertical in the body),
``r = σ_m'² / |m_h|²``, gain only along ``h_θ`` (attitude and bias): the magnetometer sets the heading and
nothing else, so a wrong or disturbed field can never move roll and pitch. ``σ_m'²`` (:mod:`.magnetic`) gains
``(τ_m |ω × m|)²``: the field error of a sample-time skew ``τ_m`` between gyro and magnetometer in a turn.

Start-up and gaps: the first sample with both vectors initialises ``q`` from IGN and ``P_θθ`` from its
covariance, ``P_bb = σ_b0² I`` (or the bias measured at rest: :meth:`FusedFilter.set_rest_noise`); with its dip off
the reference's (the field check's dip term, :mod:`.magnetic`) the heading IGN gives is another field's, and
``P_θθ`` starts with the heading unknown about the vertical, for the heading updates to set it (held unknown on
the current vertical at every update until one is taken: :meth:`.ekf.ErrorStateFilter.hold_heading_unknown`); a
gap longer than ``max_gap_s``, or a time before the last (the autopilot rebooted: its clock starts again),
restarts from IGN, keeping the bias. With no magnetometer reading for ``max_gap_s`` from the first sample (a
vehicle without a compass), it starts on roll and pitch alone
(:func:`~mavattitude.estimation.conventions.tilt_quat_parts`, yaw 0, ``P_θθ`` the tilt's σ with a heading
uniform over ±180°, held so likewise): the gyro and the tilt updates carry roll and pitch, and the heading stays
unknown (:attr:`FusedFilter.heading_known` false) until a reading comes, which turns the attitude about the
vertical to the field's heading and keeps roll, pitch and the bias (the pipeline runs the filter so while it
waits for a magnetic reference, its outputs dropped: the reference, when it comes, only gives it a heading).

Schedule and output: update ``k`` is due at the start time plus ``k`` update periods and output tick ``k`` at
the start time plus ``k`` output periods (a count, not a running sum of periods, whose rounding would put
about half the ticks a hair after the sample at their time, and so one sample late). :meth:`FusedFilter.push`
returns a :class:`FusedEstimate` for every tick up to the sample, after the sample's update, the attitude
carried back to the tick with the current rate; a tick at the sample's time (within 1 µs) is the sample's.
"""

from __future__ import annotations

import math
from collections import deque
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike

from mavattitude.errors import InputError
from mavattitude.estimation import NoiseModel, solve
from mavattitude.estimation.compass import HEADING_UNKNOWN_STD_RAD, heading_uncertain
from mavattitude.estimation.conventions import (
    ACC_REF_NED,
    Array,
    Quat,
    Vec3,
    rotate_ned_to_body_parts,
    rotation_matrix_parts,
    tilt_quat_parts,
)
from mavattitude.estimation.velocity import GpsVelocity

from .ekf import ErrorStateFilter, rotated
from .gps import GpsCompensation
from .magnetic import MagneticChecks
from .mat3 import ZERO3, Block, cross, plus_diagonal
from .mat3 import matvec as _matvec
from .prefilter import EarthFramePrefilters
from .rest import RestDetector
from .settings import FusedSettings

COUNTERS = (
    "updates",
    "tilt_only_updates",
    "rest_updates",
    "rest_refused",
    "mag_disturbed",
    "mag_relearned",
    "mag_offset_learned",
    "restarts",
    "degenerate",
    "skipped_updates",
    "gps_updates",
    "gps_refused",
    "start_heading_unknown",
)
_MAX_UNIT_STD = 0.5  # rad: the largest direction noise handed to a measurement update
# A zero-rate measurement the bias's uncertainty cannot explain (beyond χ²'s 99.9 % point, 3 degrees of freedom) is
# a rotation, not the bias: a turn that starts slowly, which the rest detector takes for stillness
_REST_GATE_CHI2 = 16.27
# The update pace is the mean of the last PACE_WINDOW update intervals, measured once PACE_MIN_INTERVALS are
# in (the first interval, from a start, is up to one input period long); the per-update filters are designed
# again when it moves by more than PACE_TOLERANCE (as the front end's low-pass: jitter does not re-design).
PACE_WINDOW = 32
PACE_MIN_INTERVALS = 4
PACE_TOLERANCE = 0.1
# The timestamps' resolution (MAVLink's and the logs' microseconds): a scheduled time within it of a sample's is
# the sample's time (the schedule's float rounding is ~1e-11 s; no two samples are closer than this).
_SAME_TIME_S = 1e-6
_SAME_TIME_BACK_S = -_SAME_TIME_S  # a tick this far before a sample is carried back to
_MIN_HORIZONTAL = math.sin(math.radians(5.0))  # |m_h| / |m| below this: no heading from the field


@dataclass(slots=True)  # not frozen: a frozen dataclass's __init__ costs four times as much, every tick
class FusedEstimate:
    """One output tick: attitude (body → NED), body rates with the bias removed, 3×3 error covariance (rad²).

    The covariance and bias are kept as the filter's plain floats and made arrays on access: most ticks'
    are never read (only the covariance of the ticks sent with ATTITUDE_QUATERNION_COV or written out)."""

    time_s: float
    q: Array
    rates_radps: Array
    mag_disturbed: bool
    p_tt: Block  # the attitude error covariance, row-major
    bias: Vec3  # the gyro bias, rad/s

    @property
    def covariance(self) -> Array:
        return np.fromiter(self.p_tt, float, 9).reshape(3, 3)

    @property
    def bias_radps(self) -> Array:
        return np.fromiter(self.bias, float, 3)


class FusedFilter:
    """The gyro-aided filter; feed it every calibrated IMU sample with :meth:`push`."""

    def __init__(
        self,
        settings: FusedSettings,
        mag_ref: ArrayLike,
        acc_ref: ArrayLike = ACC_REF_NED,
        *,
        output_rate_hz: float = 50.0,
        max_gap_s: float = 0.5,
    ) -> None:
        if not (output_rate_hz > 0.0 and max_gap_s > 0.0):
            raise InputError(f"output_rate_hz and max_gap_s must be positive, got {output_rate_hz}, {max_gap_s}")
        self.settings = s = settings
        self.acc_ref = np.asarray(acc_ref, dtype=float)
        self.counters: dict[str, int] = dict.fromkeys(COUNTERS, 0)
        self._started = False
        self.heading_known = False  # a magnetometer reading started it: its yaw is a heading, not 0 held
        self._heading_held = False  # started with the heading unknown, and no heading update taken since
        self._first_s = math.nan  # the first sample's time, while no magnetometer reading has come
        self._update_period_s = 1.0 / s.update_rate_hz
        self._output_period_s = 1.0 / output_rate_hz
        self._max_gap_s = max_gap_s
        self._ekf = ErrorStateFilter(s.gyro_noise_radps, s.gyro_scale_fraction, s.gyro_bias_walk_radps2)
        self._mag = MagneticChecks(s, self._update_period_s)
        self._rest = RestDetector(s, self._update_period_s)
        self._gps = GpsCompensation(s, s.update_rate_hz) if s.gps_max_accel_mps2 > 0.0 else None
        self._prefilters = EarthFramePrefilters((s.accel_lowpass_s, s.accel_rejection_lowpass_s), s.update_rate_hz)
        self._design_period_s = self._update_period_s  # the update interval the per-update filters are for
        self._design_tolerance_s = PACE_TOLERANCE * self._design_period_s  # how far the pace moves before a re-design
        self._update_times: deque[float] = deque(maxlen=PACE_WINDOW + 1)
        # The squared settings the updates weigh with, once: a float's ** is a libm pow call, every update.
        self._accel_var, self._lag_gain2 = s.accel_std_mps2**2, s.accel_lag_gain**2
        self._mag_var, self._skew2 = s.mag_std_uT**2, s.mag_skew_s**2
        self._min_accel_mps2 = 1e-3 * s.gravity_mps2  # a weaker specific force is no direction: no update
        self._p_bb_start = plus_diagonal(ZERO3, s.gyro_bias_init_radps**2)  # P_bb of a first start
        self._noise = NoiseModel(accel_std=(s.accel_std_mps2,) * 3, mag_std=(s.mag_std_uT,) * 3)
        self._t_last = 0.0
        self._heading_at_s = 0.0  # the last heading update's time (or the last start's: IGN's heading)
        self._gyr_last: Vec3 = (0.0, 0.0, 0.0)
        self._start_s = 0.0  # the schedule's origin: the last (re)start
        self._next_update_s = 0.0
        self._next_output_s = 0.0
        # Output ticks since the start: the next is at _start_s + _ticks periods. A float (the same products):
        # an int times a float takes CPython's slow mixed-type path, every tick.
        self._ticks = 0.0
        self.set_mag_ref(mag_ref)

    # --- public state -------------------------------------------------------------------------------
    @property
    def q(self) -> Array:
        """Current attitude, body → NED, ``w ≥ 0``."""
        return np.array(self._current_q())

    @property
    def bias_radps(self) -> Array:
        return np.array(self._ekf.bias)

    @property
    def mag_offset_uT(self) -> Array:
        """The hard-iron offset learnt on top of the calibration (body frame, µT): subtract it from ``m``."""
        return np.array(self._mag.offset_uT)

    @property
    def mag_disturbed(self) -> bool:
        return self._mag.disturbed

    @property
    def gps_aided(self) -> bool:
        """Whether the last tilt update took the vehicle's acceleration from its GPS velocity out of the specific
        force (:mod:`.gps`): without it a sustained acceleration leans the tilt, as it does any snapshot's."""
        return self._gps is not None and self._gps.active

    @property
    def heading_gap_s(self) -> float:
        """How long the heading has come from the gyro alone (no heading update since), s: the compass
        rejected (disturbed), absent or degenerate for that long."""
        return self._t_last - self._heading_at_s if self._started else 0.0

    @property
    def covariance(self) -> Array:
        """6×6 covariance of ``[δθ (rad), δb (rad/s)]`` at the last update."""
        e = self._ekf
        tt, tb, bb = (np.array(m).reshape(3, 3) for m in (e.p_tt, e.p_tb, e.p_bb))
        return np.block([[tt, tb], [tb.T, bb]])

    def set_mag_ref(self, mag_ref: ArrayLike) -> None:
        """A new NED field (e.g. WMM after a move, or after a field measured from the compass): used from the next
        update on, the state kept, the attitude turned about the vertical by the field's change of declination
        (north moved, the body did not: magnetic north to true north at once, not over the heading updates).

        Its magnitude is a start value only (it is learnt from the data, see :mod:`.magnetic`)."""
        mag = np.asarray(mag_ref, dtype=float)
        if mag.shape != (3,) or self.acc_ref.shape != (3,):
            raise InputError(f"references must be 3-vectors, got {mag_ref!r} and {self.acc_ref!r}")
        norms = float(np.linalg.norm(mag)), float(np.linalg.norm(self.acc_ref))
        if not all(math.isfinite(n) and n > 0.0 for n in norms):
            raise InputError(f"references must be finite and non-zero, got {mag_ref!r} and {self.acc_ref!r}")
        if self._started:
            before = self.mag_ref
            self._ekf.turn_about_down(math.atan2(mag[1], mag[0]) - math.atan2(before[1], before[0]))
        self.mag_ref = mag
        self._v_acc: Vec3 = tuple(float(v) / norms[1] for v in self.acc_ref)  # type: ignore[assignment]
        self._v_acc_opposite: Vec3 = (-self._v_acc[0], -self._v_acc[1], -self._v_acc[2])
        self._acc_ref_up = self._v_acc == (0.0, 0.0, -1.0)
        field: Vec3 = tuple(mag.tolist())  # type: ignore[assignment]
        self._mag.set_reference(field, self._v_acc, self._started)

    def set_rest_noise(self, mag_std_uT: float, gyro_bias_radps: Vec3, gyro_bias_std_radps: Vec3) -> bool:
        """What the sensors showed at rest (:mod:`mavattitude.estimation.restnoise`): the magnetometer's σ per axis
        (its largest) floors ``σ_m`` from the next update on (an effective σ is never below the reading's own
        noise); before the start, the gyro bias is the one the filter starts from, ``P_bb`` its variance per axis
        (a start after this one keeps the filter's own bias, as a restart does). True when it took the bias."""
        s = self.settings
        self._mag_var = max(s.mag_std_uT * s.mag_std_uT, mag_std_uT * mag_std_uT)
        if self._started:
            return False
        self._ekf.bias = gyro_bias_radps
        p_bb = tuple(min(std * std, s.gyro_bias_init_radps**2) for std in gyro_bias_std_radps)
        self._p_bb_start = (p_bb[0], 0.0, 0.0, 0.0, p_bb[1], 0.0, 0.0, 0.0, p_bb[2])
        return True

    def set_velocity(self, velocity: GpsVelocity) -> None:
        """The GPS receiver's velocity, received after the last sample: its differences are the vehicle's
        acceleration, removed from the accelerometer's gravity from the next update on (:mod:`.gps`)."""
        if self._gps is not None:
            self._gps.source.push(velocity, self._t_last)
            self.counters["gps_refused"] = self._gps.source.refused

    # --- the per-sample entry point -----------------------------------------------------------------
    def push(
        self,
        time_s: float,
        gyr_radps: ArrayLike,
        acc_mps2: ArrayLike,
        mag_uT: ArrayLike | None,
        mag_age_s: float = 0.0,
    ) -> list[FusedEstimate]:
        """Take one calibrated sample (body frame, SI, vehicle time); return the output ticks it completes.
        ``mag_age_s``: how long before ``time_s`` the magnetometer reading was taken (a held reading)."""
        gx, gy, gz = gyr = (float(gyr_radps[0]), float(gyr_radps[1]), float(gyr_radps[2]))
        if not math.isfinite(gx + gy + gz + time_s):
            raise InputError(f"non-finite gyro sample or time at t={time_s!r}")
        if not self._started:
            return self._start(time_s, gyr, acc_mps2, mag_uT)
        dt = time_s - self._t_last
        if dt == 0.0:
            raise InputError(f"sample time {time_s!r} s does not advance past {self._t_last!r} s")
        if not 0.0 < dt <= self._max_gap_s:  # a gap, or the clock started again (an autopilot's reboot)
            self.counters["restarts"] += 1
            return self._start(time_s, gyr, acc_mps2, mag_uT)
        self._ekf.integrate(dt, gx, gy, gz)
        self._t_last = time_s
        self._gyr_last = gyr
        if mag_uT is not None and not self.heading_known:
            self._acquire_heading(mag_uT, time_s)
        # A due update waits up to half a period for a sample that carries a magnetometer reading.
        due = self._next_update_s - _SAME_TIME_S
        if time_s >= due and (mag_uT is not None or time_s >= due + 0.5 * self._update_period_s):
            # The next due time after this sample: dues it has passed (an input slower than the updates) lapse.
            start, period = self._start_s, self._update_period_s
            self._next_update_s = start + (math.floor((time_s + _SAME_TIME_S - start) / period) + 1) * period
            # The update: P propagated to now, the zero-rate, tilt and heading updates (module docstring), the reset.
            self._pace(time_s)
            self._ekf.propagate()
            self._measure(acc_mps2, mag_uT, time_s, mag_age_s)
            self._ekf.reset()
        if time_s + _SAME_TIME_S < self._next_output_s:
            return []
        return self._outputs(time_s)

    def _current_q(self) -> Quat:
        if not self._started:
            raise InputError("the fused filter has no attitude yet: it needs one sample with acc and mag")
        return self._ekf.current_q()

    # --- measurement updates ------------------------------------------------------------------------
    def _pace(self, time_s: float) -> None:
        """Keep the per-update filters (the two pre-filters, the rest detector, the field learning) designed
        for the interval updates really come at: ``1 / update_rate_hz`` from a faster input, the input's own
        from a slower one (a log's 25 Hz IMU: every sample is an update, and filters designed for 50 Hz would
        take twice their time constants)."""
        times = self._update_times
        times.append(time_s)
        intervals = len(times) - 1
        if intervals < PACE_MIN_INTERVALS:
            return
        period = (time_s - times[0]) / intervals
        if abs(period - self._design_period_s) > self._design_tolerance_s:
            self._design_period_s, self._design_tolerance_s = period, PACE_TOLERANCE * period
            self._prefilters.design(1.0 / period)
            if self._gps is not None:
                self._gps.design(1.0 / period)
            self._rest.set_period(period)
            self._mag.set_period(period)

    def _measure(self, acc_mps2: ArrayLike, mag_uT: ArrayLike | None, time_s: float, mag_age_s: float) -> None:
        """The update's measurements, each accumulated into the error state."""
        ekf, s = self._ekf, self.settings
        raw = r0, r1, r2 = (float(acc_mps2[0]), float(acc_mps2[1]), float(acc_mps2[2]))
        if not math.isfinite(r0 + r1 + r2) or math.sqrt(r0 * r0 + r1 * r1 + r2 * r2) < self._min_accel_mps2:
            self.counters["skipped_updates"] += 1
            return
        self.counters["updates"] += 1
        r = rotation_matrix_parts(ekf.q)
        down = (r[6], r[7], r[8])  # A(q) e_D: the field check's, the tilt's and the heading's, formed once
        if self._heading_held:
            ekf.hold_heading_unknown(down, HEADING_UNKNOWN_STD_RAD * HEADING_UNKNOWN_STD_RAD)
        if s.rest_gyro_std_radps > 0.0:
            rest_rate = self._rest.rate(self._gyr_last, raw, ekf.bias, time_s)
            if rest_rate is not None:
                self._rest_update(rest_rate)
        acc, sigma_a2 = self._prefiltered(raw, r, time_s)
        acc_norm = math.sqrt(acc[0] * acc[0] + acc[1] * acc[1] + acc[2] * acc[2])
        mag = None if mag_uT is None else self._mag.corrected((float(mag_uT[0]), float(mag_uT[1]), float(mag_uT[2])))
        # ω, the body's rate: the last gyro sample less the estimated bias (the same until the reset)
        (b0, b1, b2), (g0, g1, g2) = ekf.bias, self._gyr_last
        rate = (g0 - b0, g1 - b1, g2 - b2)
        if mag is not None and mag_age_s > 0.0:
            mag = _carried(mag, rate, mag_age_s)
        d = mag_norm = math.inf
        if mag is not None:
            d, mag_norm = self._check_field(mag, r, down, time_s)
        # Past half a radian of direction noise the accelerometer tells nothing the gyro does not know.
        sigma_a, sigma_max = math.sqrt(sigma_a2), _MAX_UNIT_STD * acc_norm
        self._tilt_update(acc, acc_norm, sigma_max if sigma_max < sigma_a else sigma_a, r, down)
        if mag is not None and d < 1.0:
            sigma_m2 = self._mag_var * self._mag.sigma2_factor(d, time_s) + self._skew_var(mag, rate)
            sigma_max = _MAX_UNIT_STD * mag_norm
            sigma_max2 = sigma_max * sigma_max
            sigma_m2 = sigma_max2 if sigma_max2 < sigma_m2 else sigma_m2
            if self._heading_update(mag, mag_norm, sigma_m2, r, down):
                self._heading_at_s = time_s
                self._heading_held = False
                return
        self.counters["tilt_only_updates"] += 1

    def _prefiltered(self, raw: Vec3, r: Sequence[float], time_s: float) -> tuple[Vec3, float]:
        """``ã`` (the long pre-filter, body frame) and ``σ_a'²`` (module docstring); with a GPS acceleration,
        both pre-filters' outputs are gravity alone (:mod:`.gps`)."""
        s = self.settings
        r_g = rotation_matrix_parts(self._ekf.q_gyro)
        a_earth = _matvec(r_g, raw)  # R(q_g) a
        lp = lp_m, lp_r = self._prefilters.step(a_earth)
        if self._gps is not None:
            gravity = self._gps.gravity(lp, r, r_g, time_s)
            if gravity is not None:
                self.counters["gps_updates"] += 1
                lp_m, lp_r = gravity
        m0, m1, m2 = lp_m
        j0, j1, j2 = lp_r
        # Squares as x * x, here and in every update: a float's ** is a libm pow call (same value to an ulp).
        l0, l1, l2 = m0 - j0, m1 - j1, m2 - j2
        norm_dev = s.accel_norm_gain * (math.sqrt(j0 * j0 + j1 * j1 + j2 * j2) - s.gravity_mps2)
        sigma_a2 = self._accel_var + norm_dev * norm_dev + self._lag_gain2 * (l0 * l0 + l1 * l1 + l2 * l2)
        return rotate_ned_to_body_parts(r_g, lp_m), sigma_a2

    def _check_field(self, mag: Vec3, r: Sequence[float], down: Vec3, time_s: float) -> tuple[float, float]:
        """``(d, |m|)``; the disturbance tracked, the field learnt, the hard-iron offset gathered (``r``: R(q),
        ``down``: A(q) e_D)."""
        d, mag_norm, dip = self._mag.check(mag, down, _vertical_variance(self._ekf.p_tt, down))
        # The counters written only when they count: a dict item's += costs as much as four float operations.
        if math.isfinite(d):
            checks = self._mag
            if checks.observe(d, mag_norm, dip, time_s):
                self.counters["mag_relearned"] += 1
            # The offset is gathered only while disturbed or in a window: the call spared on a clean field.
            if (checks.disturbed or checks.gathering) and checks.learn_offset(mag, r, time_s):
                self.counters["mag_offset_learned"] += 1
        if d >= 1.0:
            self.counters["mag_disturbed"] += 1
        return d, mag_norm

    def _skew_var(self, mag: Vec3, rate: Vec3) -> float:
        """``(τ_m ‖ω × m‖)²``: the field error a sample-time skew ``τ_m`` between gyro and magnetometer makes
        while the body turns at ``rate`` (``ω``, the gyro less its bias)."""
        (w0, w1, w2), (m0, m1, m2) = rate, mag
        t0, t1, t2 = w1 * m2 - w2 * m1, w2 * m0 - w0 * m2, w0 * m1 - w1 * m0  # ω × m, written out as below
        return self._skew2 * (t0 * t0 + t1 * t1 + t2 * t2)

    def _tilt_update(self, acc: Vec3, acc_norm: float, sigma_a: float, r: Sequence[float], down: Vec3) -> None:
        """The accelerometer direction, along the two axes it measures; its gain is kept off the heading
        (``down``: A(q) e_D)."""
        # g = −h = A(q) (−v_a), the reference's opposite in the body: for the usual reference (up, −e_D), A(q) e_D.
        # Every sum and product below of g is the one of h negated, the same floats (IEEE rounding is symmetric),
        # and the negations are spared.
        g0, g1, g2 = g = down if self._acc_ref_up else rotate_ned_to_body_parts(r, self._v_acc_opposite)
        d0, d1, d2 = acc[0] / acc_norm + g0, acc[1] / acc_norm + g1, acc[2] / acc_norm + g2  # u − h
        # The products written out: the cross and dot products cost as much as calls as in arithmetic.
        v0, v1, v2 = (0.0, -g2, g1) if -0.6 < g0 < 0.6 else (g2, 0.0, -g0)  # h × x̂, or h × ŷ near x̂
        n = math.sqrt(v0 * v0 + v1 * v1 + v2 * v2)
        e1 = v0, v1, v2 = v0 / n, v1 / n, v2 / n
        w0, w1, w2 = w = (g1 * v2 - g2 * v1, g2 * v0 - g0 * v2, g0 * v1 - g1 * v0)  # g × e₁ = −e₂ (e₂ = h × e₁)
        std = sigma_a / acc_norm
        var = std * std
        # Along e: z = e · (u − h), h_θ = e × h; for the orthonormal e₁, e₂ = h × e₁, h: e₁ × h = −e₂, e₂ × h = e₁.
        # The gain kept off g is the gain kept off h.
        self._ekf.update(v0 * d0 + v1 * d1 + v2 * d2, w, var, off=g)
        self._ekf.update(-(w0 * d0 + w1 * d1 + w2 * d2), e1, var, off=g)

    def _heading_update(self, mag: Vec3, mag_norm: float, sigma_m2: float, r: Sequence[float], down: Vec3) -> bool:
        """The field's horizontal direction against the reference's (``r``: R(q), ``down``: A(q) e_D): heading
        only. False if the field is too close to vertical to give one."""
        mn = r[0] * mag[0] + r[1] * mag[1] + r[2] * mag[2]
        me = r[3] * mag[0] + r[4] * mag[1] + r[5] * mag[2]
        horizontal2 = mn * mn + me * me
        min_horizontal = _MIN_HORIZONTAL * mag_norm
        if horizontal2 < min_horizontal * min_horizontal:  # a threshold: x * x, not a pow call
            self.counters["degenerate"] += 1
            return False
        n, e = self._mag.north
        z = math.atan2(mn * e - me * n, mn * n + me * e)
        self._ekf.update(z, down, sigma_m2 / horizontal2, on=down)
        return True

    def _rest_update(self, rate: Vec3) -> None:
        """Zero-rate update of the bias (``rate``: ``ḡ − b`` once the gyro and accelerometer have been still for
        ``rest_min_s``, :class:`~.rest.RestDetector`), refused when ``P_bb`` cannot explain it (``_REST_GATE_CHI2``,
        ``P_bb``'s diagonal). The detector compares the rate with the current bias: a turn that starts slowly passes
        it, and each update taken moved the bias toward the rate, which kept the next one passing as the rate grew
        (the simulator's circle at 3°/s: the bias took the turn, the heading went 24° off)."""
        var = self.settings.rest_gyro_std_radps**2
        (r0, r1, r2), bb = rate, self._ekf.p_bb
        if r0 * r0 / (bb[0] + var) + r1 * r1 / (bb[4] + var) + r2 * r2 / (bb[8] + var) > _REST_GATE_CHI2:
            self.counters["rest_refused"] += 1
            return
        for axis, h in enumerate(_AXES):
            self._ekf.update(rate[axis], None, var, h)
        self.counters["rest_updates"] += 1

    # --- start-up and output ------------------------------------------------------------------------
    def _start(self, time_s: float, gyr: Vec3, acc: ArrayLike, mag: ArrayLike | None) -> list[FusedEstimate]:
        """(Re)initialise from IGN on a sample with both vectors (a restart keeps the bias and its covariance), or
        on roll and pitch alone after ``max_gap_s`` without a magnetometer reading (module docstring)."""
        if mag is None:
            if not self._first_s <= time_s:  # the first sample (or the clock went back)
                self._first_s = time_s
            if self.heading_known or time_s - self._first_s <= self._max_gap_s:
                self._started = False
                return []
            q, p_tt = self._tilt_start(acc)
            self._heading_held = True
        else:
            r = solve(acc, mag, self.mag_ref, self._noise, acc_ref=self.acc_ref)
            q = tuple(float(v) for v in r.q)  # type: ignore[assignment]
            p_tt = tuple(r.covariance.ravel().tolist())
            # IGN's heading is the field's, whose dip may say it is another field's
            self._heading_held = self._dip_off(mag, q, p_tt)
            if self._heading_held:
                self.counters["start_heading_unknown"] += 1
                p_tt = tuple(heading_uncertain(r.covariance, acc).ravel().tolist())
        if self._started:
            self._ekf.start(q, p_tt)  # type: ignore[arg-type]
        else:
            self._ekf.start(q, p_tt, self._p_bb_start)  # type: ignore[arg-type]
        if mag is not None and not (self._started and self.heading_known):  # the field learnt anew
            self._mag.start(self._mag.corrected((float(mag[0]), float(mag[1]), float(mag[2]))))
            self.heading_known = True
        self._started = True
        self._prefilters.reset()
        if self._gps is not None:
            self._gps.reset()
        self._update_times.clear()
        self._t_last = self._heading_at_s = time_s  # IGN's heading is the field's
        self._gyr_last = gyr
        self._start_s = self._next_output_s = time_s
        self._next_update_s = time_s + self._update_period_s
        self._ticks = 0.0
        return self._outputs(time_s)

    def _dip_off(self, mag_uT: ArrayLike, q: Quat, p_tt: Sequence[float]) -> bool:
        """Whether a first reading's dip is off the reference's (the field check's dip term, its magnitude being
        learnt from it): the heading it gives then starts as unknown, for the field checks to judge the readings
        after it and the heading updates to set it when one passes."""
        r = rotation_matrix_parts(q)
        down = (r[6], r[7], r[8])
        vertical_var = _vertical_variance(p_tt, down)
        mag = self._mag.corrected((float(mag_uT[0]), float(mag_uT[1]), float(mag_uT[2])))
        _, _, dip = self._mag.check(mag, down, vertical_var)
        return self._mag.dip_deviation(dip, vertical_var) >= 1.0

    def _acquire_heading(self, mag_uT: ArrayLike, time_s: float) -> None:
        """The first magnetometer reading of a filter running on roll and pitch alone: the attitude turned about
        the vertical until the reading's horizontal part points along the reference's (the heading update's
        innovation, taken whole), roll, pitch and the gyro bias kept. ``P_θθ`` still holds the heading as
        unknown (a σ of ±180° uniform), so the heading updates that follow take the magnetometer's at full gain."""
        mag = self._mag.corrected((float(mag_uT[0]), float(mag_uT[1]), float(mag_uT[2])))
        r = rotation_matrix_parts(self._ekf.current_q())
        mn = r[0] * mag[0] + r[1] * mag[1] + r[2] * mag[2]
        me = r[3] * mag[0] + r[4] * mag[1] + r[5] * mag[2]
        n, e = self._mag.north
        self._ekf.turn_about_down(math.atan2(mn * e - me * n, mn * n + me * e))
        self._mag.start(mag)
        self.heading_known = True
        self._heading_at_s = time_s

    def _tilt_start(self, acc: ArrayLike) -> tuple[Quat, tuple[float, ...]]:
        """Roll and pitch from the accelerometer, yaw 0; ``P_θθ``: the tilt's σ (σ_a / |a|) with the heading
        uniform over ±180° about the body's vertical."""
        a = (float(acc[0]), float(acc[1]), float(acc[2]))
        norm2 = a[0] * a[0] + a[1] * a[1] + a[2] * a[2]
        p = np.eye(3) * self._noise.accel_std[0] ** 2 / norm2 + HEADING_UNKNOWN_STD_RAD**2 * np.outer(a, a) / norm2
        return tilt_quat_parts(a), tuple(p.ravel().tolist())

    def _outputs(self, time_s: float) -> list[FusedEstimate]:
        """Estimates for every output tick up to ``time_s`` (within 1 µs), the attitude carried back to the tick."""
        ekf = self._ekf
        b = ekf.bias
        (b0, b1, b2), (g0, g1, g2) = b, self._gyr_last  # ω: the gyro less its bias
        wx, wy, wz = g0 - b0, g1 - b1, g2 - b2
        rates = np.array((wx, wy, wz))  # numpy 2: np.array of a float tuple costs 5 % less than np.fromiter
        p_tt, disturbed, q_now = ekf.p_tt, self._mag.disturbed, ekf.current_q()
        start_s, period_s, ticks = self._start_s, self._output_period_s, self._ticks
        out = []
        tick_s, until_s = self._next_output_s, time_s + _SAME_TIME_S
        while tick_s <= until_s:
            back = tick_s - time_s
            q_tick = q_now
            # A tick within a microsecond of the sample (the timestamps' resolution) is the sample's: the
            # carry would turn it by less than |ω| × 1 µs, and costs a third of the tick.
            if back < _SAME_TIME_BACK_S:
                q_tick = rotated(q_now, wx * back, wy * back, wz * back)
            out.append(FusedEstimate(tick_s, np.array(q_tick), rates, disturbed, p_tt, b))
            ticks += 1.0
            tick_s = start_s + ticks * period_s
        self._ticks, self._next_output_s = ticks, tick_s
        return out


_AXES: tuple[Vec3, Vec3, Vec3] = ((1.0, 0.0, 0.0), (0.0, 1.0, 0.0), (0.0, 0.0, 1.0))


def _carried(mag: Vec3, rate: Vec3, age_s: float) -> Vec3:
    """A reading taken ``age_s`` ago, in the body frame of now: the Earth's field turns in the body by
    ``−ω`` as the body turns by ``ω`` (``rate``, bias-corrected), ``m ← exp(−[ω×] age) m`` (Rodrigues).
    A 10 Hz magnetometer's reading held to a 60°/s turn's samples was up to 6° off in heading."""
    kx, ky, kz = rate[0] * age_s, rate[1] * age_s, rate[2] * age_s
    angle = math.sqrt(kx * kx + ky * ky + kz * kz)
    if angle < 1e-12:
        return mag
    kx, ky, kz = kx / angle, ky / angle, kz / angle
    c, s = math.cos(angle), math.sin(angle)
    along = (kx * mag[0] + ky * mag[1] + kz * mag[2]) * (1.0 - c)
    kxm = cross((kx, ky, kz), mag)
    return (
        mag[0] * c - kxm[0] * s + kx * along,
        mag[1] * c - kxm[1] * s + ky * along,
        mag[2] * c - kxm[2] * s + kz * along,
    )


def _vertical_variance(p: Sequence[float], down: Vec3) -> float:
    """``tr P − v̂ᵀ P v̂``: the variance of the predicted vertical's direction, the error about it (the heading's)
    left out (``p``: ``P_θθ`` row by row, ``down``: the unit vertical in the body)."""
    d0, d1, d2 = down
    about = (
        d0 * (p[0] * d0 + p[1] * d1 + p[2] * d2)
        + d1 * (p[3] * d0 + p[4] * d1 + p[5] * d2)
        + d2 * (p[6] * d0 + p[7] * d1 + p[8] * d2)
    )
    vertical = p[0] + p[4] + p[8] - about
    return vertical if vertical > 0.0 else 0.0  # (a heading variance far above the tilt's leaves rounding below 0)
