"""The front end: decoded IMU samples → screened, calibrated, body-frame, low-passed 50 Hz samples.

Per input sample (:meth:`FrontEnd.push`, plain floats: the per-message cost is what the service pays):

1. vehicle clock (:mod:`.clock`): wrap unwrapped, duplicates and reordered datagrams dropped, a reboot
   restarts everything;
2. screening of the raw sample: a non-finite or saturated (integer limit or sensor full scale)
   accelerometer or gyroscope drops the sample; a non-finite or saturated magnetometer drops the
   magnetometer reading only; each counted by reason. So does a *dead* vector, one too short for a live
   sensor (``dead_fraction``: 5 % of g, or of ``|B₀|`` when known, else of the weakest surface field
   on Earth, ``WEAKEST_FIELD_UT``): ``dead_acc`` drops the sample, ``dead`` the magnetometer reading.
   A sensor on a glitching bus reads exactly zero; filtered, those zeros would not just shorten the
   vector but make the low-pass undershoot through zero, flipping its direction (a 180° attitude). No
   live accelerometer reads under 0.05 g except in free fall, where it shows no direction either (the
   gyroscope's sample is lost with it: the accelerometer and gyroscope are one filtered stream). A
   magnetometer reading all zeros in an integer message is no compass at all (``mag_uT`` is ``None``,
   :mod:`.units`); in a float message it is this dead reading: either way no reading enters the filter,
   and the ticks hold the last one, then have none (``MAG_HELD``, ``NO_MAG``);
3. calibration, mounting and the autopilot's level trim (:mod:`.calibration`, :mod:`.mounting`: ``trim_rad``,
   ArduPilot's AHRS_TRIM, known from its parameters) as one affine map per sensor, into the vehicle's frame;
4. the 2nd-order Butterworth low-pass (:mod:`mavattitude.lowpass`) per axis, designed for the measured input rate
   (mean of the last ``rate_window`` intervals; re-designed when it moves by more than ``rate_tolerance``,
   continuing from the last two inputs and outputs, so without a jump), started at the steady state of
   the first sample. It treats the samples of a segment as evenly spaced: jitter and a dropped message
   shift its delay by up to one input interval (5 ms at 200 Hz). Accelerometer and gyroscope share the
   IMU's times; the magnetometer runs on its own times (it may be slower: PX4's ~87 Hz beside a 250 Hz IMU);
5. resampling at every tick ``k / output_rate_hz`` of the vehicle clock: the tick's value is the linear
   interpolation of the filtered stream between the two input samples around it. A gap longer than
   ``input_timeout_s`` restarts the filter and the ticks (never bridged), counted and flagged ``RESET``.
   The magnetometer at a tick is interpolated when samples on both sides are in, else held from the last
   one (``MAG_HELD``) for at most ``input_timeout_s``, else absent (``NO_MAG``, ``mag_uT`` is ``None``); a
   held reading's age (the tick's time minus the reading's) goes with it, ``mag_age_s``, so that an estimator
   that knows the body's rotation can carry it to the tick (a 10 Hz magnetometer's reading is up to 0.1 s old).
   A message that repeats the newest reading until the next (``ImuSample.mag_repeats``: MAVLink's integer
   IMU messages) is read as a log's separate magnetometer stream is: a screened reading exactly equal to the
   last one taken, at most :func:`repeat_hold_s` after it, is that reading again and is held, not taken as a
   new one. A field that stays the same for longer (a quiet compass at rest, quantised to the same integers)
   is taken again after that, so it is never lost; a genuinely new reading equal to the last one is held
   instead of taken, which changes only its age;
6. screening of the tick: ``| |a| − g | > acc_norm_tolerance · g`` (``ACC_NORM``) or
   ``| |B| − B₀ | > mag_norm_tolerance · B₀`` (``MAG_NORM``, once the expected ``B₀`` is known) are
   flagged, counted and down-weighted: ``acc_std_scale`` / ``mag_std_scale`` (× the σ of the noise model)
   become ``suspect_std_scale``. A tick whose gyro turns faster than ``moving_rate_dps`` or whose specific force
   is off g by more than ``moving_accel_fraction · g`` is flagged ``MOVING`` (:func:`moving`), nothing else: a
   snapshot attitude, which reads the specific force as gravity, may be off there (what the autopilot
   cross-check waits out).

With ``filter_enabled`` false, steps 4–5 are skipped: every accepted input sample is one output.

**The input's pace.** Each stream keeps its last ``rate_window`` intervals (across gaps, not across a reboot).
A gap is an interval longer than ``input_timeout_s`` *and* than
:data:`~mavattitude.estimation.conventions.GAP_INTERVALS` (2.5) of the median of the intervals before it, so a
2 Hz stream's 0.5 s steps are its pace, not gaps (a stream's first interval, its pace unknown, starts the
stream anew without counting a gap). When most of the IMU's last intervals are longer than
:func:`pace_intervals_s` (the input slower than 2.2 times the low-pass cutoff: 22 Hz, so a 20 Hz stream with
its jitter; fast again above 25 Hz, between the two it stays what it was), the input is too slow to
filter: each accepted sample is one tick at its own time, its values unfiltered (the magnetometer the newest
unfiltered reading), flagged ``PER_SAMPLE``; the filters keep running underneath, so when the pace rises again
the 50 Hz ticks start afresh on the grid (``RESET``), as after a gap.

No check of the *filtered* vector against the dead floor is needed: with dead inputs refused, every
input to the low-pass is a live vector, and the filter (Q = 1/√2, 4 % overshoot) can bring its output
near zero or turn it around only if its input reverses within its ~0.1 s memory, which neither gravity
nor the Earth's field does. Comparing the tick with the newest raw sample instead would refuse good
ticks under vibration, which swings the raw vector by as much as g (what the filter is there to remove).

:func:`process_batch` is the same computation vectorised over arrays (offline replay); fed the same
samples, it gives the same ticks and flags, and values equal to rounding (~1e-12).
"""

from __future__ import annotations

import dataclasses
import logging
import math
from collections import Counter, deque
from collections.abc import Iterator, Sequence
from dataclasses import dataclass, field
from enum import IntFlag
from typing import Any

import numpy as np
from numpy.typing import NDArray

from mavattitude.estimation import motion
from mavattitude.estimation.conventions import Array, Vec3, gap_limit_s
from mavattitude.estimation.motion import norm, norm2, norm2_rows, norm_rows
from mavattitude.lowpass import butter2, filter_batch
from mavattitude.sensors.calibration import Calibration, sensor_affines
from mavattitude.sensors.clock import ClockEvent, VehicleClock
from mavattitude.sensors.mounting import mounting_matrix, trim_matrix
from mavattitude.sensors.units import STANDARD_GRAVITY_MPS2, ImuSample

log = logging.getLogger(__name__)


class SampleFlag(IntFlag):
    """What the front end noticed about an output sample (and the pipeline and estimator about its attitude)."""

    NONE = 0
    RESET = 1  # first output after the start, a gap, a reboot, or a change of the input's pace (PER_SAMPLE)
    ACC_NORM = 2  # |a| far from g: down-weighted
    MAG_NORM = 4  # |B| far from the expected magnitude: down-weighted
    MAG_HELD = 8  # magnetometer held from its last sample, not interpolated
    NO_MAG = 16  # no magnetometer within input_timeout_s: mag_uT is None
    MAG_INCONSISTENT = 32  # set by the pipeline: the compass monitor judges this field not the Earth's
    NOT_CONVERGED = 64  # set by the estimator: the solve stopped at its iteration bound
    MAG_DISTURBED = 128  # set by the fused filter: it rejected or down-weighted this magnetometer update
    MAG_HEADING_ONLY = 256  # set by the estimator: the magnetometer set heading only (TRIAD, accelerometer first)
    PER_SAMPLE = 512  # the input is too slow to filter: this tick is one input sample, unfiltered
    NO_HEADING = 1024  # set by the estimator: no magnetometer, roll and pitch only (yaw held at 0, unknown)
    MOVING = 2048  # turning or accelerating (:func:`moving`): a snapshot attitude may read acceleration as tilt
    GPS_AIDED = 4096  # set by the fused filter: its tilt update took the GPS receiver's acceleration out


@dataclass(frozen=True)
class FrontEndSettings:
    """Everything the front end needs (:func:`mavattitude.pipeline.frontend_settings` reads the config's)."""

    mounting: Any = "NONE"  # ArduPilot rotation name or a 3×3 board → body matrix
    trim_rad: tuple[float, float] = (0.0, 0.0)  # the autopilot's level trim, roll and pitch, after the mounting
    calibration: Calibration = field(default_factory=Calibration)
    filter_enabled: bool = True
    cutoff_hz: float = 10.0
    output_rate_hz: float = 50.0
    input_timeout_s: float = 0.5
    gravity_mps2: float = STANDARD_GRAVITY_MPS2
    expected_field_uT: float | None = None  # |B₀| for screening; None until known
    acc_norm_tolerance: float = 0.1  # fraction of g
    mag_norm_tolerance: float = 0.15  # fraction of |B₀|
    suspect_std_scale: float = 10.0  # σ multiplier of a flagged vector
    # MOVING: a snapshot's heading trails the turn by ~0.1 s (the filter's and the compass's delay), 1° at 10°/s,
    # a fifth of the cross-check's threshold; and a copter's steady acceleration at 14° of tilt or more lifts
    # | |a| − g | above 3 % of g (g / cos 14° = 1.03 g)
    moving_rate_dps: float = 10.0
    moving_accel_fraction: float = 0.03
    # and a sustained turn, which neither sees: at 10 m/s a turn about the vertical at 2°/s leans the specific force
    # 2° (the centripetal v ψ̇, 0.35 m/s²), which the field's dip doubles in heading: 4.5° in all, under the 5° of
    # the cross-check's threshold
    moving_turn_rate_dps: float = 2.0
    dead_fraction: float = 0.05  # a raw |a| < this·g or |B| < this·|B₀| is a dead sensor: refused
    acc_full_scale_mps2: float = 16.0 * STANDARD_GRAVITY_MPS2
    gyr_full_scale_radps: float = math.radians(2000.0)
    mag_full_scale_uT: float = 800.0
    rate_window: int = 32  # input intervals averaged to measure the rate
    rate_tolerance: float = 0.1  # relative rate change that re-designs the filter
    reorder_window_s: float = 1.0  # a time further back than this is a reboot


@dataclass(slots=True)
class ProcessedSample:
    """One output sample: body frame (FRD), calibrated, filtered, at a tick of the vehicle clock.

    Not frozen: one is built per tick (per input sample for the fused filter), and a frozen dataclass's
    construction costs four times as much."""

    time_s: float
    acc_mps2: Vec3
    mag_uT: Vec3 | None
    gyr_radps: Vec3
    flags: SampleFlag
    acc_std_scale: float = 1.0
    mag_std_scale: float = 1.0
    mag_age_s: float = 0.0  # how long before time_s the magnetometer reading was taken (held), s


@dataclass
class FrontEndCounters:
    """What the front end did, for the service's periodic log line."""

    received: int = 0
    accepted: int = 0
    emitted: int = 0
    rejected: Counter[str] = field(default_factory=Counter)  # whole input samples dropped, by reason
    mag_rejected: Counter[str] = field(default_factory=Counter)  # magnetometer readings dropped, by reason
    flagged: Counter[str] = field(default_factory=Counter)  # output samples flagged, by flag name
    gap_resets: int = 0
    mag_gap_resets: int = 0
    per_sample: int = 0  # ticks that are one input sample each, unfiltered: the input too slow to filter
    reboots: int = 0
    wraps: int = 0
    redesigns: int = 0

    def add(self, other: FrontEndCounters) -> None:
        """Count what ``other`` counted too (a batch run's counters into the stream's)."""
        for f in dataclasses.fields(self):
            mine, theirs = getattr(self, f.name), getattr(other, f.name)
            if isinstance(mine, Counter):
                mine.update(theirs)
            else:
                setattr(self, f.name, mine + theirs)


def first_tick(t_s: float, rate_hz: float) -> int:
    """The smallest ``k`` with ``k / rate_hz >= t_s``."""
    k = math.ceil(t_s * rate_hz)
    while (k - 1) / rate_hz >= t_s:
        k -= 1
    while k / rate_hz < t_s:
        k += 1
    return k


def last_tick(t_s: float, rate_hz: float) -> int:
    """The largest ``k`` with ``k / rate_hz <= t_s``."""
    k = math.floor(t_s * rate_hz)
    while (k + 1) / rate_hz <= t_s:
        k += 1
    while k / rate_hz > t_s:
        k -= 1
    return k


#: |B₀| for the dead-magnetometer floor while the reference magnitude is unknown: the weakest field at
#: the Earth's surface (the South Atlantic anomaly, ~22 µT; WMM2025).
WEAKEST_FIELD_UT = 22.0


def dead_floors2(settings: FrontEndSettings, expected_field_uT: float | None) -> tuple[float, float]:
    """Squared magnitudes below which a raw accelerometer (m/s²) and magnetometer (µT) vector is dead."""
    f = settings.dead_fraction
    b0 = WEAKEST_FIELD_UT if expected_field_uT is None else expected_field_uT
    return (f * settings.gravity_mps2) ** 2, (f * b0) ** 2


CONTINUED, STARTED, GAP = 0, 1, 2

#: The slowest input rate served without a silence taken for its loss before its rhythm is known: a telemetry
#: link's IMU stream at 1-2 Hz has first intervals longer than ``input_timeout_s``
SLOWEST_STREAM_HZ = 1.0


#: The input's pace against the low-pass cutoff ``f_c``: slower than ``SLOW_PACE · f_c`` it turns too slow to
#: filter, faster than ``FAST_PACE · f_c`` it is filtered again, and between the two it keeps what it was: a
#: 20 Hz stream (its intervals 50 ms ± a few) is slow for sure, a DataFlash log's 25 Hz IMU filtered for sure,
#: and neither flips at every other sample as a single threshold at 20 Hz would make it.
SLOW_PACE, FAST_PACE = 2.2, 2.5
#: Intervals the window needs before the pace between the two holds: fewer are no pace to keep (a log's first
#: interval, 0.16 s before a 200 Hz stream's second, would make it slow until most of 32 are short)
STICKY_INTERVALS = 8


def pace_intervals_s(settings: FrontEndSettings) -> tuple[float, float]:
    """``(slow, fast)``: when most of a stream's last intervals are longer than ``slow`` it is too slow to
    filter, until most are no longer than ``fast`` (:data:`SLOW_PACE`, :data:`FAST_PACE`). Below about twice the
    low-pass cutoff the sampling has already folded whatever lies above the cutoff into the band the filter
    keeps, so the filter would only delay the signal, and 50 Hz ticks would be interpolated between samples
    further apart than the motion they should show (a multirotor's attitude moves at up to the same ~10 Hz)."""
    return 1.0 / (SLOW_PACE * settings.cutoff_hz), 1.0 / (FAST_PACE * settings.cutoff_hz)


def median_rate_hz(time_s: Array) -> float:
    """A stream's rate: one over the median of its intervals (NaN with fewer than two samples)."""
    d = np.diff(np.asarray(time_s, dtype=float))
    d = d[d > 0.0]
    return 1.0 / float(np.median(d)) if len(d) else math.nan


def _median(values: Sequence[float]) -> float:
    """The median (upper of the two middle values for an even count); NaN when empty."""
    if not values:
        return math.nan
    ordered = sorted(values)
    return ordered[len(ordered) // 2]


def repeat_hold_s(settings: FrontEndSettings) -> float:
    """How long a repeated magnetometer reading (``ImuSample.mag_repeats``) is held before the same value is
    taken again as a new reading: half the hold of any reading (``input_timeout_s``), so a constant field is
    taken again well before the ticks would lose it, and far longer than a compass's interval (0.1 s at 10 Hz)."""
    return 0.5 * settings.input_timeout_s


# --- the screening rules, stated once for one sample (numpy bools, floats) and for arrays of them --------


def sample_rejects(finite: Any, saturated_acc: Any, saturated_gyr: Any, dead_acc: Any) -> dict[str, Any]:
    """Why input samples are dropped, the first reason that applies: non-finite accelerometer or gyroscope,
    then saturated accelerometer, saturated gyroscope, dead accelerometer. Arguments and results are
    numpy booleans: one sample's (the stream) or arrays (the batch); at most one result is true per sample."""
    return {
        "nonfinite": ~finite,
        "saturated_acc": finite & saturated_acc,
        "saturated_gyr": finite & ~saturated_acc & saturated_gyr,
        "dead_acc": finite & ~saturated_acc & ~saturated_gyr & dead_acc,
    }


def mag_rejects(finite: Any, saturated: Any, dead: Any) -> dict[str, Any]:
    """Why magnetometer readings are dropped (the sample kept), the first that applies; as :func:`sample_rejects`."""
    return {"nonfinite": ~finite, "saturated": finite & saturated, "dead": finite & ~saturated & dead}


def acc_suspect(norm_mps2: Any, settings: FrontEndSettings) -> Any:
    """``| |a| − g | > acc_norm_tolerance · g``: the tick's specific force is not gravity alone (``ACC_NORM``)."""
    return motion.off_gravity(norm_mps2, settings.acc_norm_tolerance, settings.gravity_mps2)


def moving(acc_norm_mps2: Any, gyr_norm_radps: Any, acc_dot_gyr: Any, settings: FrontEndSettings) -> Any:
    """``|ω| > moving_rate_dps``, ``| |a| − g | > moving_accel_fraction · g`` or a turn about the vertical faster
    than ``moving_turn_rate_dps`` (``acc_dot_gyr``: ``a · ω``): the vehicle turns or accelerates (``MOVING``)."""
    s = settings
    return motion.moving(
        acc_norm_mps2, gyr_norm_radps, s.moving_accel_fraction, math.radians(s.moving_rate_dps), s.gravity_mps2
    ) | motion.turning(acc_dot_gyr, acc_norm_mps2, math.radians(s.moving_turn_rate_dps))


def mag_suspect(norm_uT: Any, expected_uT: float, settings: FrontEndSettings) -> Any:
    """``| |B| − B₀ | > mag_norm_tolerance · B₀``: the tick's field is not the Earth's alone (``MAG_NORM``)."""
    return abs(norm_uT - expected_uT) > settings.mag_norm_tolerance * expected_uT


def _first(verdicts: dict[str, Any]) -> str | None:
    return next((reason for reason, hit in verdicts.items() if hit), None)


class _Stream:
    """Low-pass of a few channels over irregular times: rate measurement, (re)design, gap restart."""

    __slots__ = (
        "coef",
        "cutoff_hz",
        "fast_s",
        "fs_hz",
        "intervals",
        "slow",
        "slow_count",
        "slow_s",
        "t_last",
        "t_prev",
        "timeout_s",
        "times",
        "tolerance",
        "unfast_count",
        "window",
        "x1",
        "x2",
        "x_last",
        "x_prev",
        "y1",
        "y2",
        "y_last",
        "y_prev",
    )

    def __init__(
        self, cutoff_hz: float | None, timeout_s: float, window: int, tolerance: float, pace_s: tuple[float, float]
    ) -> None:
        self.cutoff_hz = cutoff_hz
        self.timeout_s = timeout_s
        self.tolerance = tolerance
        self.slow_s, self.fast_s = pace_s
        self.times: deque[float] = deque(maxlen=window + 1)
        # the stream's rhythm: its last intervals across gaps (within one boot), and how many are slow
        self.window = window
        self.intervals: deque[float] = deque(maxlen=window)
        self.reboot()

    def reboot(self) -> None:
        """The vehicle rebooted: the stream and its rhythm start over."""
        self.intervals.clear()
        # of the intervals, those longer than slow_s and than fast_s (:func:`pace_intervals_s`)
        self.slow_count = self.unfast_count = 0
        self.slow = False  # the stream is too slow to filter
        self.restart()

    @property
    def gap_limit_s(self) -> float:
        """The longest interval that is no gap now (:func:`~mavattitude.estimation.conventions.gap_limit_s`)."""
        return gap_limit_s(self.timeout_s, _median(self.intervals))

    def _beyond(self, dt: float) -> int:
        """An interval longer than ``timeout_s``: ``GAP`` when longer than :attr:`gap_limit_s` too, ``STARTED``
        when no pace is known yet (a stream's first interval starts it anew, uncounted), else ``CONTINUED``."""
        if dt <= self.gap_limit_s:
            return CONTINUED
        return GAP if self.intervals else STARTED

    def restart(self) -> None:
        self.times.clear()
        self.t_last: float | None = None
        self.y_last: list[float] = []
        self.x_last: Sequence[float] = ()  # the input unfiltered, for ticks of a slow stream
        self.t_prev: float | None = None  # the sample before the last, in the same segment
        self.y_prev: list[float] = []
        self.x_prev: Sequence[float] = ()
        self.coef: tuple[float, float, float, float, float] | None = None
        self.fs_hz = 0.0

    def design(self, fs_hz: float) -> None:
        assert self.cutoff_hz is not None
        bq = butter2(self.cutoff_hz, fs_hz)
        self.coef, self.fs_hz = (bq.b0, bq.b1, bq.b2, bq.a1, bq.a2), fs_hz

    def push(self, t: float, x: Sequence[float]) -> tuple[int, bool]:
        """Filter one sample; returns (CONTINUED | STARTED | GAP, re-designed)."""
        t_last = self.t_last
        if t_last is None:
            status = STARTED
        else:  # the interval against the ones before it, then among them (inline: this runs per sample)
            dt = t - t_last
            status = self._beyond(dt) if dt > self.timeout_s else CONTINUED
            intervals, fast_s = self.intervals, self.fast_s
            if len(intervals) == self.window and intervals[0] > fast_s:  # the oldest leaves the window
                self.unfast_count -= 1
                self.slow_count -= intervals[0] > self.slow_s
            if dt > fast_s:
                self.unfast_count += 1
                self.slow_count += dt > self.slow_s
            intervals.append(dt)
            if self.unfast_count or self.slow:  # a fast stream's common case: nothing slow in the window
                n = len(intervals)
                stays = self.slow and n >= STICKY_INTERVALS
                self.slow = 2 * (self.unfast_count if stays else self.slow_count) > n
        if status != CONTINUED:
            self.restart()
            self.times.append(t)
            self.t_last, self.y_last, self.x_last = t, x, x
            return status, False
        times = self.times
        times.append(t)
        self.t_prev, self.y_prev, self.t_last = t_last, self.y_last, t
        self.x_prev, self.x_last = self.x_last, x
        if self.cutoff_hz is None:
            self.y_last = x
            return CONTINUED, False
        fs = (len(times) - 1) / (t - times[0])
        redesigned = False
        if self.coef is None:  # second sample of a segment: the history is the steady state at the first
            self.design(fs)
            self.x1 = self.x2 = self.y1 = self.y2 = self.y_last
        elif abs(fs - self.fs_hz) > self.tolerance * self.fs_hz:
            self.design(fs)
            redesigned = True
        b0, b1, b2, a1, a2 = self.coef  # type: ignore[misc]
        x1, x2, y1, y2 = self.x1, self.x2, self.y1, self.y2
        y = [b0 * x[i] + b1 * x1[i] + b2 * x2[i] - a1 * y1[i] - a2 * y2[i] for i in range(len(x))]
        self.x1, self.x2, self.y1, self.y2, self.y_last = x, x1, y, y1, y
        return CONTINUED, redesigned


def _finite(v: Sequence[float]) -> bool:
    return math.isfinite(v[0]) and math.isfinite(v[1]) and math.isfinite(v[2])


def _within(v: Sequence[float], limit: float) -> bool:
    """All components strictly inside ±limit (False for NaN)."""
    return -limit < v[0] < limit and -limit < v[1] < limit and -limit < v[2] < limit


def body_affines(settings: FrontEndSettings) -> dict[str, tuple[Array, Array]]:
    """Each sensor's map into the vehicle's body frame: calibration, mounting, then the autopilot's level trim."""
    board_to_body = trim_matrix(*settings.trim_rad) @ mounting_matrix(settings.mounting)
    return sensor_affines(settings.calibration, board_to_body)


def _affine_rows(a: Array, c: Array) -> tuple[tuple[float, ...], ...]:
    return tuple((*(float(v) for v in row), float(ci)) for row, ci in zip(a, c, strict=True))


class FrontEnd:
    """The streaming front end: :meth:`push` one :class:`ImuSample`, get the 0+ output ticks it completes."""

    def __init__(self, settings: FrontEndSettings | None = None) -> None:
        self.settings = s = settings or FrontEndSettings()
        self.counters = FrontEndCounters()
        self.set_expected_field_uT(s.expected_field_uT)
        self._set_affines()
        cutoff = s.cutoff_hz if s.filter_enabled else None
        self._clock = VehicleClock(s.reorder_window_s)
        pace = pace_intervals_s(s)
        self._imu = _Stream(cutoff, s.input_timeout_s, s.rate_window, s.rate_tolerance, pace)
        self._mag = _Stream(cutoff, s.input_timeout_s, s.rate_window, s.rate_tolerance, pace)
        self.per_sample = False  # the input is slow: one tick per sample, unfiltered (the module docstring)
        self._mag_taken: Vec3 | None = None  # the last magnetometer reading taken, as received
        self._repeat_hold_s = repeat_hold_s(s)
        self._gridded = s.filter_enabled  # ticks on the output rate's grid (while the input is not slow)
        self._set_next_tick(0)  # the next tick, k / output_rate_hz: _next_tick_s
        self._pending_reset = False

    def _set_affines(self) -> None:
        affines = body_affines(self.settings)
        self._acc = _affine_rows(*affines["acc"])
        self._gyr = _affine_rows(*affines["gyr"])
        self._mag_cal = _affine_rows(*affines["mag"])

    def set_trim(self, roll_rad: float, pitch_rad: float) -> None:
        """The autopilot's level trim (when it becomes known or changes): readings from the next on turn by it."""
        self.settings = dataclasses.replace(self.settings, trim_rad=(roll_rad, pitch_rad))
        self._set_affines()

    def set_expected_field_uT(self, magnitude_uT: float | None) -> None:
        """|B₀| of the magnetic reference (when it becomes known or changes), for the |B| screening."""
        self.expected_field_uT = magnitude_uT
        self._acc_floor2, self._mag_floor2 = dead_floors2(self.settings, magnitude_uT)

    def push(self, sample: ImuSample) -> list[ProcessedSample]:
        """Take one decoded sample; return the output ticks it completes (usually 0 or 1, none while its
        time is a duplicate, reordered or the sample is rejected). Counters say why, never an exception."""
        c = self.counters
        c.received += 1
        t, event = self._clock.update(sample.time_s, sample.time_wrap_s)
        if t is None:
            c.rejected[event.value] += 1
            return []
        if event is not _CLOCK_OK:  # (one comparison on the common path: an Enum member's lookup costs 0.1 µs)
            self._clock_event(t, event)
        s = self.settings
        acc, gyr, mag = sample.acc_mps2, sample.gyr_radps, sample.mag_uT
        # one chained comparison per vector is the fast path (NaN fails it too); the reason only on failure
        if (
            sample.saturated
            or not (_within(acc, s.acc_full_scale_mps2) and _within(gyr, s.gyr_full_scale_radps))
            or norm2(acc) < self._acc_floor2
        ):
            reason = self._reject_reason(sample)
            if reason is not None:
                c.rejected[reason] += 1
                return []
        c.accepted += 1
        if mag is not None:
            if "mag" in sample.saturated or not _within(mag, s.mag_full_scale_uT) or norm2(mag) < self._mag_floor2:
                c.mag_rejected[self._mag_reject_reason(mag, sample.saturated)] += 1
            elif not (sample.mag_repeats and self._repeated(t, mag)):
                self._mag_taken = mag
                status, redesigned = self._mag.push(t, _apply(self._mag_cal, mag))
                if status or redesigned:
                    c.mag_gap_resets += status == GAP
                    c.redesigns += redesigned
        imu = self._imu
        status, redesigned = imu.push(t, _apply(self._acc, acc) + _apply(self._gyr, gyr))
        c.redesigns += redesigned
        if status != CONTINUED or imu.slow != self.per_sample:
            self._restart_ticks(t, status)
        elif t < self._next_tick_s and self._gridded and not self.per_sample:
            return []  # most samples of a filtered stream complete no tick
        return self._emit(t)

    def _restart_ticks(self, t: float, status: int) -> None:
        """After a (re)start of the input's filter or a change of its pace: the ticks start afresh at ``t``."""
        if status == GAP:
            self.counters.gap_resets += 1
            limit_s = self._imu.gap_limit_s  # (the gap among the intervals now: the median barely moves)
            log.warning("input gap longer than %.3g s before %.3f s: filter restarted", limit_s, t)
        self._pending_reset = True
        self._set_next_tick(first_tick(t, self.settings.output_rate_hz))
        self.per_sample = self._imu.slow

    def _set_next_tick(self, k: int) -> None:
        self._next_k = k
        self._next_tick_s = k / self.settings.output_rate_hz

    def _clock_event(self, t: float, event: ClockEvent) -> None:
        c = self.counters
        if event is ClockEvent.REBOOT:
            c.reboots += 1
            _say_reboot(t)
            self._imu.reboot()
            self._mag.reboot()
            self.per_sample = False
        elif event is ClockEvent.WRAP:
            c.wraps += 1

    @property
    def rate_hz(self) -> float:
        """The input's rate now: one over the median of its last intervals (NaN before two samples)."""
        return 1.0 / _median(self._imu.intervals) if self._imu.intervals else math.nan

    @property
    def gap_limit_s(self) -> float:
        """The longest silence of the input that is no gap at its present rhythm (``input_timeout_s``, or
        :data:`~mavattitude.estimation.conventions.GAP_INTERVALS` of a slower stream's usual interval); before
        the stream has shown one (its first interval, as the streams take it: a start, no gap), that of the
        slowest stream served, :data:`SLOWEST_STREAM_HZ`."""
        imu = self._imu
        return imu.gap_limit_s if imu.intervals else gap_limit_s(imu.timeout_s, 1.0 / SLOWEST_STREAM_HZ)

    def _repeated(self, t: float, mag: Vec3) -> bool:
        """Whether ``mag`` is the last reading taken again, within :func:`repeat_hold_s` of it: held."""
        t_last = self._mag.t_last  # None after a restart: nothing to repeat
        return t_last is not None and t - t_last <= self._repeat_hold_s and mag == self._mag_taken

    def _reject_reason(self, sample: ImuSample) -> str | None:
        """The fast path in :meth:`push` found something: which rule it is (None: only the magnetometer)."""
        s, acc, gyr = self.settings, sample.acc_mps2, sample.gyr_radps
        return _first(
            sample_rejects(
                np.bool_(_finite(acc) and _finite(gyr)),
                np.bool_("acc" in sample.saturated or not _within(acc, s.acc_full_scale_mps2)),
                np.bool_("gyr" in sample.saturated or not _within(gyr, s.gyr_full_scale_radps)),
                np.bool_(norm2(acc) < self._acc_floor2),
            )
        )

    def _mag_reject_reason(self, mag: Vec3, saturated: frozenset[str]) -> str:
        return (
            _first(
                mag_rejects(
                    np.bool_(_finite(mag)),
                    np.bool_("mag" in saturated or not _within(mag, self.settings.mag_full_scale_uT)),
                    np.bool_(norm2(mag) < self._mag_floor2),
                )
            )
            or "dead"
        )  # the fast path saw it fail; only the dead floor is left

    def _emit(self, t: float) -> list[ProcessedSample]:
        s, imu = self.settings, self._imu
        out: list[ProcessedSample] = []
        if self.per_sample:
            self.counters.per_sample += 1
            out.append(self._tick(t, imu.x_last, raw=True))
            return out
        if not s.filter_enabled:
            out.append(self._tick(t, imu.y_last))
            return out
        rate = s.output_rate_hz
        k = self._next_k
        while k / rate <= t:
            tk = k / rate
            exact = imu.t_prev is None or tk == t
            y = imu.y_last if exact else _lerp(imu.t_prev, imu.y_prev, t, imu.y_last, tk)
            out.append(self._tick(tk, y))
            k += 1
        self._set_next_tick(k)
        return out

    def _tick(self, tk: float, y: Sequence[float], raw: bool = False) -> ProcessedSample:
        """The tick at ``tk`` from the IMU values ``y``; ``raw``: one per sample of a slow stream (unfiltered)."""
        s = self.settings
        flags = _PER_SAMPLE if raw else 0  # plain int bits while building: IntFlag arithmetic costs a microsecond
        if self._pending_reset:
            flags |= _RESET
            self._pending_reset = False
        acc, gyr = (y[0], y[1], y[2]), (y[3], y[4], y[5])
        mag, mag_flag, mag_age_s = self._mag_at(tk, raw)
        flags |= mag_flag
        acc_scale = mag_scale = 1.0
        acc_norm = norm(acc)
        if acc_suspect(acc_norm, s):
            flags |= _ACC_NORM
            acc_scale = s.suspect_std_scale
        if moving(acc_norm, norm(gyr), motion.dot(acc, gyr), s):
            flags |= _MOVING
        b0 = self.expected_field_uT
        if mag is not None and b0 is not None and mag_suspect(norm(mag), b0, s):
            flags |= _MAG_NORM
            mag_scale = s.suspect_std_scale
        c = self.counters
        c.emitted += 1
        if flags & _COUNTED:
            for flag in _COUNTED_FLAGS:
                if flags & flag:
                    c.flagged[flag.name or ""] += 1
        return ProcessedSample(tk, acc, mag, gyr, _FLAGS[flags], acc_scale, mag_scale, mag_age_s)

    def _mag_at(self, tk: float, raw: bool = False) -> tuple[Vec3 | None, int, float]:
        """The magnetometer at a tick, its flag, and its age (the tick's time minus the held reading's); ``raw``:
        from the unfiltered readings."""
        m = self._mag
        if m.t_last is None:
            return None, _NO_MAG, 0.0
        if raw:
            last, prev = m.x_last, m.x_prev
        else:
            last, prev = m.y_last, m.y_prev
        if m.t_last >= tk:
            if m.t_prev is not None and m.t_prev < tk:
                return _vec(_lerp(m.t_prev, prev, m.t_last, last, tk)), 0, 0.0
            return _vec(last), _MAG_HELD, 0.0
        if tk - m.t_last <= self.settings.input_timeout_s:
            return _vec(last), _MAG_HELD, tk - m.t_last
        return None, _NO_MAG, 0.0


_RESET, _ACC_NORM, _MAG_NORM, _MAG_HELD, _NO_MAG = (
    int(f) for f in (SampleFlag.RESET, SampleFlag.ACC_NORM, SampleFlag.MAG_NORM, SampleFlag.MAG_HELD, SampleFlag.NO_MAG)
)
_PER_SAMPLE, _MOVING = int(SampleFlag.PER_SAMPLE), int(SampleFlag.MOVING)
_CLOCK_OK = ClockEvent.OK


class _FlagTable(dict[int, SampleFlag]):
    """Each combination of flags built once, when first met: building all 2 048 up front cost 60 ms of every
    command's start (IntFlag's constructor searches its members for each)."""

    def __missing__(self, bits: int) -> SampleFlag:
        self[bits] = flag = SampleFlag(bits)
        return flag


_FLAGS = _FlagTable()
#: The flag set of plain int bits (a table look-up: IntFlag arithmetic costs a microsecond per operation).
flag_set = _FLAGS.__getitem__
_COUNTED_FLAGS = (SampleFlag.RESET, SampleFlag.ACC_NORM, SampleFlag.MAG_NORM, SampleFlag.NO_MAG)
_COUNTED = int(SampleFlag.RESET | SampleFlag.ACC_NORM | SampleFlag.MAG_NORM | SampleFlag.NO_MAG)


def _apply(rows: tuple[tuple[float, ...], ...], v: Sequence[float]) -> Vec3:
    """``A v − c`` with rows ``(A_i0, A_i1, A_i2, c_i)``."""
    x, y, z = v[0], v[1], v[2]
    r0, r1, r2 = rows
    return (
        r0[0] * x + r0[1] * y + r0[2] * z - r0[3],
        r1[0] * x + r1[1] * y + r1[2] * z - r1[3],
        r2[0] * x + r2[1] * y + r2[2] * z - r2[3],
    )


def _lerp(t0: float, y0: Sequence[float], t1: float, y1: Sequence[float], t: float) -> list[float]:
    frac = (t - t0) / (t1 - t0)
    return [a + (b - a) * frac for a, b in zip(y0, y1, strict=True)]


def _vec(y: Sequence[float]) -> Vec3:
    return (y[0], y[1], y[2])


# --- the batch path ------------------------------------------------------------------------------------


@dataclass
class BatchOutput:
    """The output ticks of :func:`process_batch` as arrays; ``mag_uT`` rows are NaN where absent."""

    time_s: Array
    acc_mps2: Array
    mag_uT: Array
    gyr_radps: Array
    flags: NDArray[np.int64]
    acc_std_scale: Array
    mag_std_scale: Array
    mag_age_s: Array
    counters: FrontEndCounters

    def __len__(self) -> int:
        return len(self.time_s)

    def samples(self) -> list[ProcessedSample]:
        """The same ticks as :class:`ProcessedSample` objects (what :meth:`FrontEnd.push` returns)."""
        vectors = (_tuples(self.acc_mps2), _tuples(self.mag_uT), _tuples(self.gyr_radps))
        scalars = (c.tolist() for c in (self.flags, self.acc_std_scale, self.mag_std_scale, self.mag_age_s))
        return [
            ProcessedSample(t, a, None if m[0] != m[0] else m, g, _FLAGS[f], sa, sm, age)  # NaN: no mag
            for t, a, m, g, f, sa, sm, age in zip(self.time_s.tolist(), *vectors, *scalars, strict=True)
        ]


def _tuples(rows: Array) -> Iterator[tuple[float, ...]]:
    """The rows of an (n, 3) array as tuples of floats, made from its columns (no list per row)."""
    return zip(*rows.T.tolist(), strict=True)


def batch_inputs(samples: Sequence[ImuSample]) -> dict[str, Any]:
    """Keyword arguments of :func:`process_batch` for a list of decoded samples (one time field)."""
    n = len(samples)
    mag = np.full((n, 3), np.nan)
    mag_new = np.zeros(n, dtype=bool)
    for i, sample in enumerate(samples):
        if sample.mag_uT is not None:
            mag[i] = sample.mag_uT
            mag_new[i] = True
    wraps = {sample.time_wrap_s for sample in samples}
    return {
        "time_s": np.array([sample.time_s for sample in samples], dtype=float),
        "acc_mps2": np.array([sample.acc_mps2 for sample in samples], dtype=float).reshape(n, 3),
        "gyr_radps": np.array([sample.gyr_radps for sample in samples], dtype=float).reshape(n, 3),
        "mag_uT": mag,
        "mag_new": mag_new,
        "mag_repeats": np.array([sample.mag_repeats for sample in samples], dtype=bool),
        "saturated": {
            sensor: np.array([sensor in sample.saturated for sample in samples], dtype=bool)
            for sensor in ("acc", "gyr", "mag")
        },
        "wrap_period_s": wraps.pop() if len(wraps) == 1 else None,
    }


def process_batch(
    settings: FrontEndSettings,
    time_s: Array,
    acc_mps2: Array,
    gyr_radps: Array,
    mag_uT: Array | None = None,
    *,
    mag_new: NDArray[np.bool_] | None = None,
    mag_repeats: NDArray[np.bool_] | bool = False,
    saturated: dict[str, NDArray[np.bool_]] | None = None,
    wrap_period_s: float | None = None,
    expected_field_uT: float | None = None,
    say_reboots: bool = True,
) -> BatchOutput:
    """The front end over whole arrays (sensor/board frame, SI): what :meth:`FrontEnd.push` gives, sample
    by sample, for the same input. ``mag_new`` marks rows with a new magnetometer reading (default: rows
    where ``mag_uT`` is given), ``mag_repeats`` the rows (or all) whose message repeats the newest one
    (:attr:`ImuSample.mag_repeats`); ``saturated`` maps ``"acc"``/``"gyr"``/``"mag"`` to rows at an integer limit.
    A reboot in the times is logged as :meth:`FrontEnd.push` logs it, unless ``say_reboots`` is false (a second
    pass over the same samples).
    """
    s = settings
    t = np.asarray(time_s, dtype=float)
    n = len(t)
    acc = np.asarray(acc_mps2, dtype=float).reshape(n, 3)
    gyr = np.asarray(gyr_radps, dtype=float).reshape(n, 3)
    mag = np.full((n, 3), np.nan) if mag_uT is None else np.asarray(mag_uT, dtype=float).reshape(n, 3)
    if mag_new is None:
        mag_new = np.zeros(n, dtype=bool) if mag_uT is None else np.ones(n, dtype=bool)
    sat = {k: np.zeros(n, dtype=bool) for k in ("acc", "gyr", "mag")} | dict(saturated or {})
    c = FrontEndCounters(received=n)
    t, kept, epoch = _batch_clock(t, wrap_period_s, s.reorder_window_s, c, say_reboots)
    b0 = expected_field_uT if expected_field_uT is not None else s.expected_field_uT
    acc_floor2, mag_floor2 = dead_floors2(s, b0)

    ok_fin = _finite_rows(acc) & _finite_rows(gyr)
    # "not within" is "saturated" wherever the row is finite, which is the only place it is asked
    sat_acc = sat["acc"] | ~_within_rows(acc, s.acc_full_scale_mps2)
    sat_gyr = sat["gyr"] | ~_within_rows(gyr, s.gyr_full_scale_radps)
    mag_sat = sat["mag"] | ~_within_rows(mag, s.mag_full_scale_uT)
    with np.errstate(invalid="ignore", over="ignore"):  # NaN and huge rows are not dead (and already refused)
        acc_dead, mag_dead = norm2_rows(acc) < acc_floor2, norm2_rows(mag) < mag_floor2
    rejects = sample_rejects(ok_fin, sat_acc, sat_gyr, acc_dead)
    for reason, mask in rejects.items():
        count = int(np.count_nonzero(kept & mask))
        if count:
            c.rejected[reason] += count
    accepted = kept & ~np.logical_or.reduce(list(rejects.values()))
    c.accepted = int(accepted.sum())
    mag_fin = _finite_rows(mag)
    mag_in = accepted & mag_new
    mag_verdicts = mag_rejects(mag_fin, mag_sat, mag_dead)
    for reason, mask in mag_verdicts.items():
        count = int(np.count_nonzero(mag_in & mask))
        if count:
            c.mag_rejected[reason] += count
    mag_ok = mag_in & ~np.logical_or.reduce(list(mag_verdicts.values()))
    repeats = np.broadcast_to(np.asarray(mag_repeats, dtype=bool), (n,))
    if repeats.any():
        mag_ok &= ~_held_repeats(t, mag, mag_ok, repeats, epoch, repeat_hold_s(s))

    affines = body_affines(s)
    # from here on channels first, time contiguous: (6, n) for the IMU, (3, n) for the magnetometer
    imu_body = np.concatenate(
        [_apply_batch(affines["acc"], _rows(acc, accepted)), _apply_batch(affines["gyr"], _rows(gyr, accepted))]
    )
    mag_body = _apply_batch(affines["mag"], _rows(mag, mag_ok))
    t_imu, t_mag = _rows(t, accepted), _rows(t, mag_ok)
    epoch_imu, epoch_mag = _rows(epoch, accepted), _rows(epoch, mag_ok)

    pieces = []
    for e in range(int(epoch[-1]) + 1 if n else 0):
        ii, mm = epoch_imu == e, epoch_mag == e
        pieces.append(_batch_epoch(s, _rows(t_imu, ii), _cols(imu_body, ii), _rows(t_mag, mm), _cols(mag_body, mm), c))
    out = _concat(pieces, c)
    _screen_batch(s, out, b0)
    c.emitted = len(out)
    for flag in _COUNTED_FLAGS:
        count = int(np.count_nonzero(out.flags & flag))
        if count:
            c.flagged[flag.name or ""] += count
    return out


def _finite_rows(a: Array) -> NDArray[np.bool_]:
    """Per row, all three finite (column by column: a reduction over an axis of 3 is slow)."""
    return np.isfinite(a[:, 0]) & np.isfinite(a[:, 1]) & np.isfinite(a[:, 2])


def _within_rows(a: Array, limit: float) -> NDArray[np.bool_]:
    """:func:`_within` per row."""
    with np.errstate(invalid="ignore"):
        return (np.abs(a[:, 0]) < limit) & (np.abs(a[:, 1]) < limit) & (np.abs(a[:, 2]) < limit)


def _rows(a: Any, mask: NDArray[np.bool_]) -> Any:
    """``a[mask]``, without the copy when every row is kept (the usual case)."""
    return a if mask.all() else a[mask]


def _cols(a: Array, mask: NDArray[np.bool_]) -> Array:
    """``a[:, mask]`` of a channels-first array, without the copy when every column is kept."""
    return a if mask.all() else a[:, mask]


def _apply_batch(affine: tuple[Array, Array], v: Array) -> Array:
    """``A v − c`` for rows ``v`` (n, 3), as (3, n), in :func:`_apply`'s order of operations."""
    a, c = affine
    x, y, z = v[:, 0], v[:, 1], v[:, 2]
    return np.stack([a[i, 0] * x + a[i, 1] * y + a[i, 2] * z - c[i] for i in range(3)])


def _say_reboot(t_s: float) -> None:
    log.warning("vehicle clock went back from the newest sample to %.3f s: reboot, front end restarted", t_s)


def _batch_clock(
    t: Array, wrap_s: float | None, reorder_window_s: float, c: FrontEndCounters, say_reboots: bool
) -> tuple[Array, NDArray[np.bool_], NDArray[np.int64]]:
    """Unwrapped times, the rows the clock keeps, and each row's boot epoch."""
    n = len(t)
    if n == 0 or (np.all(np.diff(t) > 0.0) and np.isfinite(t[[0, -1]]).all()):  # increasing, ends finite: all are
        return t, np.ones(n, dtype=bool), np.zeros(n, dtype=np.int64)
    # irregular times are rare: the streaming clock, sample by sample, is then the reference
    clock = VehicleClock(reorder_window_s)
    out, kept, epoch = np.empty(n), np.zeros(n, dtype=bool), np.zeros(n, dtype=np.int64)
    e = 0
    for i, raw in enumerate(t.tolist()):
        ti, event = clock.update(raw, wrap_s)
        if ti is None:  # dropped, but in the epoch so far: the last row's epoch is the number of epochs less one
            c.rejected[event.value] += 1
            epoch[i] = e
            continue
        if event is ClockEvent.REBOOT:
            c.reboots += 1
            if say_reboots:
                _say_reboot(ti)
            e += 1
        elif event is ClockEvent.WRAP:
            c.wraps += 1
        out[i], kept[i], epoch[i] = ti, True, e
    return out, kept, epoch


def _held_repeats(
    t: Array,
    mag: Array,
    taken: NDArray[np.bool_],
    repeats: NDArray[np.bool_],
    epoch: NDArray[np.int64],
    hold_s: float,
) -> NDArray[np.bool_]:
    """The rows among ``taken`` that :meth:`FrontEnd._repeated` holds: a ``repeats`` row equal to the last
    reading taken in its boot epoch, at most ``hold_s`` after it. A held row equals the last one taken, so
    each run of equal consecutive readings keeps its first row, then every row more than ``hold_s`` after
    the last one it kept."""
    rows = np.flatnonzero(taken)
    held = np.zeros(len(t), dtype=bool)
    if not len(rows):  # no reading at all (a message whose magnetometer reads zero): nothing to hold
        return held
    m, tr, same = mag[rows], t[rows], np.zeros(len(rows), dtype=bool)
    same[1:] = repeats[rows[1:]] & (epoch[rows[1:]] == epoch[rows[:-1]]) & (m[1:] == m[:-1]).all(axis=1)
    starts = np.flatnonzero(~same)
    stops = np.append(starts[1:], len(rows))
    for a, b in zip(starts.tolist(), stops.tolist(), strict=True):
        if tr[b - 1] - tr[a] > hold_s:  # a run longer than the hold (a constant field at rest): taken again
            _retake(tr, a, b, hold_s, same)
    held[rows[same]] = True
    return held


def _retake(tr: Array, a: int, b: int, hold_s: float, same: NDArray[np.bool_]) -> None:
    """In the run ``a:b`` of one repeated reading, clear ``same`` for the rows taken again: each the first
    more than ``hold_s`` after the last one taken (the comparison :meth:`FrontEnd._repeated` makes)."""
    run = tr[a:b]  # increasing: one boot epoch
    k = 0
    while True:
        j = max(k + 1, int(np.searchsorted(run, run[k] + hold_s, side="right")))
        while j > k + 1 and run[j - 1] - run[k] > hold_s:  # the search's rounding, corrected to the rule's
            j -= 1
        while j < len(run) and not run[j] - run[k] > hold_s:
            j += 1
        if j >= len(run):
            return
        same[a + j] = False
        k = j


def _segments(t: Array, timeout_s: float, window: int) -> list[tuple[int, int]]:
    """``(start, stop)`` of each run without a gap (:meth:`_Stream._take_interval`: longer than ``timeout_s`` and
    than :func:`gap_limit_s` of the median of the ``window`` intervals before it); one, ``(0, 0)``, when empty."""
    d = np.diff(t)
    gaps = [i for i in np.flatnonzero(d > timeout_s).tolist() if d[i] > _batch_gap_limit_s(d, i, timeout_s, window)]
    starts = [0, *(i + 1 for i in gaps)]
    return list(zip(starts, [*starts[1:], len(t)], strict=True))


def _gaps(segments: list[tuple[int, int]]) -> int:
    """The gaps between ``segments`` (:meth:`_Stream.push`: after the first interval, which starts anew uncounted)."""
    return sum(a > 1 for a, _ in segments[1:])


def _batch_gap_limit_s(d: Array, i: int, timeout_s: float, window: int) -> float:
    """:attr:`_Stream.gap_limit_s` before interval ``d[i]``: from the (up to) ``window`` intervals before it."""
    before = d[max(0, i - window) : i]
    return gap_limit_s(timeout_s, float(np.sort(before)[len(before) // 2]) if len(before) else math.nan)


def _slow_rows(t: Array, s: FrontEndSettings) -> NDArray[np.bool_]:
    """Per sample, :attr:`_Stream.slow` after it: it turns slow where most of the (up to) ``rate_window``
    intervals up to it are longer than the slow interval, and stays so while most are longer than the fast one,
    of at least :data:`STICKY_INTERVALS` (:func:`pace_intervals_s`). So a sample is slow when it turns, or when
    it may stay and the one before was slow: in each run of samples that turn or may stay, from the first that
    turns to the run's end."""
    slow = np.zeros(len(t), dtype=bool)
    if len(t) < 2:
        return slow
    i = np.arange(1, len(t))
    first = np.maximum(i - s.rate_window, 0)
    turns, stays = np.zeros(len(t), dtype=bool), np.zeros(len(t), dtype=bool)
    for most, interval_s in ((turns, pace_intervals_s(s)[0]), (stays, pace_intervals_s(s)[1])):
        long = np.concatenate([[0], np.cumsum(np.diff(t) > interval_s)])  # long intervals up to each sample
        most[1:] = 2 * (long[i] - long[first]) > i - first
    stays[1:] &= i - first >= STICKY_INTERVALS
    allowed = (turns | stays).view(np.int8)
    edges = np.flatnonzero(np.diff(np.concatenate([[0], allowed, [0]])))
    for a, b in zip(edges[::2].tolist(), edges[1::2].tolist(), strict=True):  # each run where it may be slow
        turned = np.flatnonzero(turns[a:b])
        if len(turned):
            slow[a + turned[0] : b] = True
    return slow


def _filter_batch_stream(
    s: FrontEndSettings, t: Array, x: Array, segments: list[tuple[int, int]], c: FrontEndCounters
) -> tuple[Array, NDArray[np.int64]]:
    """Filtered values (channels, n) and segment ids of one stream (IMU or magnetometer) in one boot epoch."""
    y = x.copy()
    seg = np.zeros(len(t), dtype=np.int64)
    for number, (a, b) in enumerate(segments):
        seg[a:b] = number
        if not s.filter_enabled or b - a < 2:
            continue
        ts = t[a:b]
        i = np.arange(1, b - a)
        m = np.minimum(i, s.rate_window)
        fs = m / (ts[i] - ts[i - m])  # fs[k] is the rate measured at sample k + 1
        start = 1
        while start < b - a:
            fs_d = fs[start - 1]
            stop = _next_redesign(fs, start, fs_d, s.rate_tolerance)
            c.redesigns += start > 1
            bq = butter2(s.cutoff_hz, fs_d)
            if start == 1:  # the steady state at the first sample
                x_hist = y_hist = np.stack([x[:, a], x[:, a]])
            else:
                back = [a + start - 1, a + start - 2]
                x_hist, y_hist = x[:, back].T, y[:, back].T
            y[:, a + start : a + stop] = filter_batch(bq, x[:, a + start : a + stop], x_hist, y_hist)
            start = stop
    return y, seg


def _next_redesign(fs: Array, start: int, fs_d: float, tolerance: float) -> int:
    """The first sample after ``start`` whose measured rate is off the design by more than the tolerance
    (``fs[k]`` belongs to sample ``k + 1``); scanned in growing windows so frequent re-designs stay linear."""
    window = 256
    lo = start
    while lo < len(fs):
        hi = min(len(fs), lo + window)
        moved = np.abs(fs[lo:hi] - fs_d) > tolerance * fs_d
        if moved.any():
            return lo + 1 + int(np.argmax(moved))
        lo, window = hi, window * 4
    return len(fs) + 1


def _batch_epoch(
    s: FrontEndSettings, t: Array, imu: Array, tm: Array, mag: Array, c: FrontEndCounters
) -> tuple[Array, Array, Array, NDArray[np.int64], Array]:
    """Ticks of one boot epoch: (times, IMU values (6, ·), magnetometer (·, 3) NaN-padded, flags, its age)."""
    if len(t) == 0:
        return _NO_TICKS
    segments = _segments(t, s.input_timeout_s, s.rate_window)
    mag_segments = _segments(tm, s.input_timeout_s, s.rate_window)
    y, _ = _filter_batch_stream(s, t, imu, segments, c)
    ym, segm = _filter_batch_stream(s, tm, mag, mag_segments, c)
    c.gap_resets += _gaps(segments)
    c.mag_gap_resets += _gaps(mag_segments)
    slow = _slow_rows(t, s)
    c.per_sample += int(np.count_nonzero(slow))
    times, values, idx_all, flags = [], [], [], []
    for a, b in segments:
        for r0, r1 in _runs(slow, a, b):  # a change of pace starts the ticks over, as a gap does
            tk, idx, val = _run_ticks(s, t[a:b], y[:, a:b], imu[:, a:b], r0 - a, r1 - a, bool(slow[r0]))
            if len(tk) == 0:
                continue
            f = np.full(len(tk), _PER_SAMPLE if slow[r0] else 0, dtype=np.int64)
            f[0] |= SampleFlag.RESET
            times.append(tk)
            values.append(val)
            idx_all.append(a + idx)
            flags.append(f)
    if not times:
        return _NO_TICKS
    tk, idx, f = (np.concatenate(v) for v in (times, idx_all, flags))
    val = np.concatenate(values, axis=1)
    mag_out, age = np.full((len(tk), 3), np.nan), np.zeros(len(tk))
    raw = (f & _PER_SAMPLE) != 0
    for rows, values_m in ((~raw, ym), (raw, mag)):  # a slow stream's ticks take the readings unfiltered
        if rows.any():
            f_rows = f[rows]
            mag_out[rows], age[rows] = _mag_at_batch(s, tk[rows], t[idx[rows]], tm, values_m, segm, f_rows)
            f[rows] = f_rows
    return tk, val, mag_out, f, age


def _runs(slow: NDArray[np.bool_], a: int, b: int) -> list[tuple[int, int]]:
    """``(start, stop)`` of the runs of one pace (``slow`` constant) in the segment ``a:b``."""
    starts = [a, *(a + 1 + np.flatnonzero(slow[a + 1 : b] != slow[a : b - 1])).tolist()]
    return list(zip(starts, [*starts[1:], b], strict=True))


def _run_ticks(
    s: FrontEndSettings, ts: Array, ys: Array, xs: Array, r0: int, r1: int, slow: bool
) -> tuple[Array, NDArray[np.int64], Array]:
    """The ticks of the samples ``r0:r1`` of one segment (times ``ts``, filtered ``ys``, unfiltered ``xs``):
    times, the sample each is emitted by, values. A slow run: each sample, unfiltered; else the 50 Hz ticks
    interpolated in the filtered stream (or each sample, filtering off)."""
    if slow or not s.filter_enabled:
        idx = np.arange(r0, r1)
        return ts[r0:r1].copy(), idx, (xs if slow else ys)[:, r0:r1]
    r = s.output_rate_hz
    tk = np.arange(first_tick(float(ts[r0]), r), last_tick(float(ts[r1 - 1]), r) + 1) / r
    idx = np.searchsorted(ts, tk, side="left")
    exact = ts[idx] == tk
    prev = np.maximum(idx - 1, 0)
    with np.errstate(invalid="ignore", divide="ignore"):
        frac = (tk - ts[prev]) / (ts[idx] - ts[prev])
    return tk, idx, np.where(exact[None, :], ys[:, idx], ys[:, prev] + (ys[:, idx] - ys[:, prev]) * frac[None, :])


_NO_TICKS = (np.empty(0), np.empty((6, 0)), np.empty((0, 3)), np.empty(0, dtype=np.int64), np.empty(0))


def _mag_at_batch(
    s: FrontEndSettings,
    tk: Array,
    t_emit: Array,
    tm: Array,
    ym: Array,
    segm: NDArray[np.int64],
    flags: NDArray[np.int64],
) -> tuple[Array, Array]:
    """The magnetometer at each tick from the samples in by the time the tick is emitted (``t_emit``), and
    its age (:meth:`FrontEnd._mag_at`)."""
    out = np.full((len(tk), 3), np.nan)
    age = np.zeros(len(tk))
    if len(tm) == 0:
        flags |= SampleFlag.NO_MAG
        return out, age
    jl = np.searchsorted(tm, t_emit, side="right") - 1
    none = jl < 0
    jl = np.maximum(jl, 0)
    jp = np.maximum(jl - 1, 0)
    after = tm[jl] >= tk
    interp = after & (jl >= 1) & (segm[jp] == segm[jl]) & (tm[jp] < tk)
    held = (after & ~interp) | (~after & (tk - tm[jl] <= s.input_timeout_s))
    with np.errstate(invalid="ignore", divide="ignore"):
        frac = (tk - tm[jp]) / (tm[jl] - tm[jp])
        lerp = (ym[:, jp] + (ym[:, jl] - ym[:, jp]) * frac[None, :]).T
    use_interp, use_held = interp & ~none, held & ~none & ~interp
    out[use_interp] = lerp[use_interp]
    out[use_held] = ym[:, jl[use_held]].T
    age[use_held & ~after] = (tk - tm[jl])[use_held & ~after]
    flags[use_held] |= SampleFlag.MAG_HELD
    flags[~(use_interp | use_held)] |= SampleFlag.NO_MAG
    return out, age


def _concat(pieces: list[tuple[Array, Array, Array, NDArray[np.int64], Array]], c: FrontEndCounters) -> BatchOutput:
    tk, val, mag, flags, age = _NO_TICKS
    if pieces:
        tk, mag, flags, age = (np.concatenate([piece[k] for piece in pieces]) for k in (0, 2, 3, 4))
        val = np.concatenate([piece[1] for piece in pieces], axis=1)
    ones = np.ones(len(tk))
    acc, gyr = np.ascontiguousarray(val[:3].T), np.ascontiguousarray(val[3:].T)
    return BatchOutput(tk, acc, mag, gyr, flags, ones, ones.copy(), age, c)


def _screen_batch(s: FrontEndSettings, out: BatchOutput, b0: float | None) -> None:
    acc_norm = norm_rows(out.acc_mps2)
    acc_bad = acc_suspect(acc_norm, s)
    out.flags[acc_bad] |= SampleFlag.ACC_NORM
    turn = motion.dot_rows(out.acc_mps2, out.gyr_radps)
    out.flags[moving(acc_norm, norm_rows(out.gyr_radps), turn, s)] |= SampleFlag.MOVING
    out.acc_std_scale[acc_bad] = s.suspect_std_scale
    if b0 is not None:
        with np.errstate(invalid="ignore"):
            mag_bad = mag_suspect(norm_rows(out.mag_uT), b0, s)
        out.flags[mag_bad] |= SampleFlag.MAG_NORM
        out.mag_std_scale[mag_bad] = s.suspect_std_scale
