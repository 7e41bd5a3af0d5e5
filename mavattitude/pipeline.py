"""The streaming attitude pipeline that the service, ``solve``, ``replay`` and the validation share.

``AttitudePipeline(config).push(sample)`` takes one decoded :class:`~mavattitude.sensors.units.ImuSample`
and returns everything it produced as one :class:`Pushed`: the attitude outputs it completes (zero or more:
the 50 Hz ticks), the ticks it refused by reason, the compass verdict's changes, and once, at the input's start,
what the units check found (:mod:`mavattitude.sensors.unitcheck`: a magnitude that says the units are wrong)::

    ImuSample ─► FrontEnd (clock, screen, calibrate + mount, low-pass, resample) ─► estimator ─► AttitudeOutput

The estimator is a small strategy chosen by ``estimator.method``:

- :class:`SnapshotEstimator` (``ign``, ``cgn``, ``ml``, ``triad``): one Wahba solve per front-end tick, each
  from TRIAD (no tick's answer depends on the ticks before it), the noise σ scaled up on the vectors the
  front end flagged as suspect;
- :class:`FusedEstimator` (``fused``): the gyro-aided filter of :mod:`mavattitude.estimation.fused`, fed
  every calibrated input sample (the front end's low-pass and resampling off: the filter integrates the gyro
  at the input rate and makes its own output ticks).

Before the estimator, every tick with a magnetometer reading feeds the compass monitor
(:mod:`mavattitude.estimation.compass`, ``compass:`` in the config): the dip and |B| it measures while
quiet (low acceleration, slow rotation) against the reference, and the field's turn against the gyroscope's.
While it judges the compass inconsistent, or before it has vouched for it (consistent in dip, and in a
turn about more than one axis) while this tick's own dip is off by more than the noise, the tick is flagged
``MAG_INCONSISTENT``; the snapshot estimator then takes only heading from the magnetometer, as it does
for a tick whose |B| the front end flagged (``MAG_NORM``): the accelerometer's direction is kept exactly
(TRIAD, accelerometer primary), the output flagged ``MAG_HEADING_ONLY`` and its covariance given the
heading σ of a heading uniform over ±180°. A compass vouched for and undisturbed leaves IGN the paper's IGN.
The verdict's changes are returned in :attr:`Pushed.compass` for the service and replay.

A sample the solver cannot use (degenerate geometry, bad numbers) is counted by exception type (in the
pipeline's counters and the :attr:`Pushed.rejected` of the push), logged at debug level and not emitted; so is
a tick without a magnetometer reading, or before the magnetic reference is known (``reference.magnetic: auto``
waits for :meth:`AttitudePipeline.set_position`, which looks the field up in the World Magnetic Model through
:mod:`mavattitude.sensors.magref`). The pipeline is the one gate of every output, live or offline: a
quaternion that is not finite and unit (:func:`~mavattitude.estimation.conventions.is_unit_quaternion_parts`)
or rates that are not finite are never output: counted as ``invalid_quaternion`` / ``invalid_rates``, and the
estimator's state dropped.
"""

from __future__ import annotations

import datetime as dt
import functools
import logging
import math
from collections import Counter
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field, replace
from typing import Any, Protocol

import numpy as np
from numpy.typing import NDArray

from mavattitude import collector
from mavattitude.config import Config
from mavattitude.errors import ConfigError, InputError, MavAttitudeError
from mavattitude.estimation import METHODS, NoiseModel, solve, solve_each
from mavattitude.estimation.compass import CompassEvent, CompassMonitor, heading_uncertain
from mavattitude.estimation.conventions import Array, Vec3, is_unit_quaternion_parts, tilt_quat_parts
from mavattitude.estimation.crosscheck import GyroDrift
from mavattitude.estimation.restnoise import RestNoise
from mavattitude.estimation.solve import SolveResult
from mavattitude.sensors.frontend import (
    BatchOutput,
    FrontEnd,
    FrontEndCounters,
    FrontEndSettings,
    ProcessedSample,
    SampleFlag,
    flag_set,
    process_batch,
)
from mavattitude.sensors.magref import DECLINATION_PARAMETERS, ReferenceTracker
from mavattitude.sensors.mounting import TRIM_LIMIT_RAD, TRIM_PARAMETERS
from mavattitude.sensors.unitcheck import UnitsCheck, UnitsFinding
from mavattitude.sensors.units import GpsVelocity, ImuSample

log = logging.getLogger(__name__)

COMPASS_PERIOD_S = 0.0199  # the monitor takes one tick per 20 ms (50 Hz) at most; just under: ticks jitter
PROGRESS_TICKS = 5000  # push_batch says its progress this often: ~0.1 s of the fused filter's work


def _compass_skips(since_s: float) -> bool:
    """Whether the compass monitor passes over a tick ``since_s`` after the last it took (the one rule of the
    live ticks and a replayed batch's): within ``COMPASS_PERIOD_S``; a negative interval (a reboot) is taken."""
    return 0.0 <= since_s < COMPASS_PERIOD_S


@dataclass(slots=True)
class AttitudeOutput:
    """One attitude: at ``time_s`` (vehicle clock), ``q`` = ``[w, x, y, z]`` body FRD → NED, unit, finite.

    ``rates_radps``: body rates from the calibrated gyro (low-passed with the other sensors, or with the
    bias the fused filter estimated removed). ``covariance``: the
    predicted 3×3 body-frame error-angle covariance (rad²), computed on first access. ``flags``: names of
    what the front end or the estimator noticed (``RESET``, ``ACC_NORM``, ``MAG_NORM``, ``MAG_HELD``,
    ``NOT_CONVERGED``, ``MAG_DISTURBED``, ``MAG_INCONSISTENT``, ``MAG_HEADING_ONLY``), the front end's
    :class:`~mavattitude.sensors.frontend.SampleFlag` set with the estimator's added.
    Not frozen: one is built per output tick, and a frozen dataclass's construction costs seven times as much.
    """

    time_s: float
    q: Array
    rates_radps: Array
    iterations: int
    converged: bool
    flags: SampleFlag = SampleFlag.NONE
    covariance_source: Callable[[], Array] | None = field(default=None, repr=False, compare=False)
    _covariance: Array | None = field(default=None, init=False, repr=False, compare=False)  # computed once

    @property
    def covariance(self) -> Array:
        if self._covariance is None:
            if self.covariance_source is None:
                raise InputError("this output carries no covariance")
            self._covariance = self.covariance_source()
        return self._covariance

    def covariance_or_nan(self) -> Array:
        """The covariance, or all NaN where there is none (a singular information matrix): for outputs
        that always carry the figure (ATTITUDE_QUATERNION_COV, the CSV columns)."""
        try:
            return self.covariance
        except MavAttitudeError:
            return np.full((3, 3), np.nan)


#: A heading whose σ is over this is none to compare (one uniform over ±180° has 104°, an estimate's a few degrees).
NO_HEADING_STD_RAD = math.radians(30.0)


def comparable_heading(q: Any, covariance: Any, flags: Any) -> Any:
    """The cross-check's heading rule, for one output or many (``q`` (…, 4), ``covariance`` (…, 3, 3), ``flags`` the
    :class:`SampleFlag` ints): a heading to compare is not flagged ``NO_HEADING`` and its σ about the body's
    vertical (``v̂ᵀ P v̂``) is within ``NO_HEADING_STD_RAD``. The fused filter started in a field of another dip, or
    a snapshot of nearly parallel vectors, has none: the yaw difference there would be ours, not the autopilot's.
    A covariance unknown (NaN) refuses nothing."""
    q, p = np.asarray(q), np.asarray(covariance)
    w, x, y, z = q[..., 0], q[..., 1], q[..., 2], q[..., 3]
    # A(q) e_D, the body's vertical, written out: one live output's costs 11 µs so, 30 µs through a matrix and einsum
    down = (2.0 * (x * z - w * y), 2.0 * (y * z + w * x), w * w - x * x - y * y + z * z)
    variance = sum(down[i] * p[..., i, j] * down[j] for i in range(3) for j in range(3))
    return ((np.asarray(flags) & _NO_HEADING) == 0) & ~(variance > NO_HEADING_STD_RAD**2)


class CrossCheckGate:
    """Which of our outputs, in time order, may read the vehicle's acceleration as tilt, which the autopilot
    cross-check does not judge: at a tick where the vehicle turned or accelerated (``MOVING``), or where ours turns
    unlike the gyro (:class:`~mavattitude.estimation.crosscheck.GyroDrift`: a steady acceleration at a gentle tilt,
    which ``MOVING`` does not see), unless the fused filter took the acceleration out with the GPS receiver's
    (``GPS_AIDED``). A snapshot solve always reads the specific force as gravity; the fused filter without GPS
    velocity leans in a sustained acceleration (2-3° held from a 17° bank on the shared GPS-less SITL flight) and
    is slow to come back."""

    def __init__(self) -> None:
        self._drift = GyroDrift()

    def moving(self, output: AttitudeOutput) -> bool:
        drifting = self._drift.update(output.time_s, output.q, output.rates_radps)  # every output, in order
        flags = int(output.flags)
        return bool(drifting or flags & _MOVING) and not flags & _GPS_AIDED


@dataclass(slots=True)
class Pushed:
    """Everything one :meth:`AttitudePipeline.push` (or ``push_batch``) produced."""

    outputs: list[AttitudeOutput] = field(default_factory=list)
    rejected: dict[str, int] = field(default_factory=dict)  # ticks not emitted, by reason (as the counters')
    compass: list[CompassEvent] = field(default_factory=list)  # the compass verdict's changes, in order
    units: list[UnitsFinding] = field(default_factory=list)  # sensors whose units look wrong (said once)

    def reject(self, reason: str) -> None:
        self.rejected[reason] = self.rejected.get(reason, 0) + 1

    def __bool__(self) -> bool:
        """Whether anything was produced (most samples complete no tick)."""
        return bool(self.outputs or self.rejected or self.compass or self.units)


@dataclass
class PipelineCounters:
    """What the pipeline did, for the service's counters line and the offline summary
    (:mod:`mavattitude.reports`)."""

    frontend: FrontEndCounters
    ticks: int = 0  # front-end outputs handed to the estimator
    waiting: int = 0  # ticks before ``reference.magnetic: auto`` had a position: a state, not a reject
    emitted: int = 0
    rejected: Counter[str] = field(default_factory=Counter)  # ticks not emitted, by reason
    iterations: int = 0  # summed over emitted outputs
    not_converged: int = 0
    estimator: Callable[[], dict[str, float]] = dict  # the estimator's own counters (the fused filter's)
    estimator_prefix: str = ""  # their names' prefix in the counters line (the method's ``counters_prefix``)

    @property
    def mean_iterations(self) -> float:
        return self.iterations / self.emitted if self.emitted else math.nan


class Estimator(Protocol):
    """The solver step: front-end samples in, attitudes out (not yet checked: the pipeline does that)."""

    #: Whether the front end should low-pass and resample for this estimator (``filter.enabled`` permitting).
    wants_filtered: bool
    #: Whether ticks may be held and estimated many at once (``estimate_each(samples, refs)``: each one's outputs
    #: or error, as :meth:`estimate` one by one); an estimator whose ticks interleave with what else it is handed
    #: (the GPS velocities) has not.
    solves_together: bool

    def estimate(self, sample: ProcessedSample, mag_ref_ned_uT: Array) -> list[AttitudeOutput]:
        """Outputs for one front-end sample; a ``RESET`` flag (start, gap, reboot) is the estimator's to act on."""
        ...

    def reset(self) -> None:
        """Forget the state (the pipeline calls it after an invalid output)."""
        ...

    def wait(self, sample: ProcessedSample) -> None:
        """A tick before the magnetic reference is known (nothing is emitted): what the estimator can learn from
        it without a field."""
        ...

    def counters(self) -> dict[str, float]:
        """The estimator's own counters since the start (name → number), for the counters line."""
        ...

    def velocity(self, velocity: GpsVelocity) -> None:
        """The GPS receiver's velocity, received after the last sample (what uses it: the fused filter)."""
        ...


def _noise_model(config: Config) -> NoiseModel:
    return NoiseModel(accel_std=config.noise.accel_std_mps2, mag_std=config.noise.mag_std_uT)


class SnapshotEstimator:
    """One accelerometer + magnetometer solve per tick, from TRIAD.

    Not from the previous tick's answer: Gauss–Newton takes a tilt error down only linearly, so in motion that
    start costs the solver's warm-start attempt and then TRIAD's corrections too. Replayed on the shared logs, a
    warm start took 3.2–4.5 corrections per tick on the ArduCopter SITL flights against 2.3–2.7 from TRIAD, and
    2.1 against 2.0 on PX4's sample.ulg, for the same answers (docs/paper-reproduction.md, which also has the
    paper's simulation, where it saved none)."""

    wants_filtered = True
    solves_together = True

    def __init__(self, config: Config, method: str | None = None) -> None:
        e = config.estimator
        self.method = method or e.method
        self.options = {"max_iterations": e.max_iterations, "tolerance": e.tolerance, "min_angle_deg": e.min_angle_deg}
        self.noise = _noise_model(config)
        self._scaled: dict[tuple[float, float], NoiseModel] = {(1.0, 1.0): self.noise}
        rest_s = config.noise.rest_s
        self.rest_noise = RestNoise(rest_s) if rest_s > 0.0 else None
        self._measured_said = False

    def reset(self) -> None:
        """Nothing is carried from one tick to the next."""

    def wait(self, sample: ProcessedSample) -> None:
        """A snapshot needs the field: nothing to carry to the ticks after it."""

    def counters(self) -> dict[str, float]:
        """With the noise measured at rest: the still time seen (s) and whether its σ are the ones in use."""
        rest = self.rest_noise
        if rest is None:
            return {}
        return {"noise_rest_s": round(rest.still_s, 1), "noise_measured": int(rest.measured is not None)}

    def _measure_noise(self, rest: RestNoise, sample: ProcessedSample) -> None:
        """The tick into the rest-noise measurement; its σ replace the config's once the vehicle has been still
        long enough (:mod:`mavattitude.estimation.restnoise`), said once in the log (then at debug level)."""
        if not rest.add(sample.time_s, sample.acc_mps2, sample.mag_uT, sample.gyr_radps):
            return
        self.noise = rest.measured  # type: ignore[assignment]
        self._scaled = {(1.0, 1.0): self.noise}
        log.log(
            logging.DEBUG if self._measured_said else logging.INFO,
            "t=%.1f s: noise measured at rest over %.0f s, in use instead of the config's: accel σ %s m/s², "
            "mag σ %s µT, gyro bias %s rad/s",
            sample.time_s,
            rest.still_s,
            _axes(self.noise.accel_std),
            _axes(self.noise.mag_std),
            _axes(rest.gyro_bias_radps or ()),
        )
        self._measured_said = True

    def velocity(self, velocity: GpsVelocity) -> None:
        """A snapshot has no time to difference a velocity over: unused."""

    def _noise_for(self, acc_scale: float, mag_scale: float) -> NoiseModel:
        """The noise model with the front end's down-weighting (few distinct scales: cached)."""
        key = (acc_scale, mag_scale)
        if key not in self._scaled:
            n = self.noise
            self._scaled[key] = NoiseModel(
                accel_std=tuple(s * acc_scale for s in n.accel_std), mag_std=tuple(s * mag_scale for s in n.mag_std)
            )
        return self._scaled[key]

    def estimate(self, sample: ProcessedSample, mag_ref_ned_uT: Array) -> list[AttitudeOutput]:
        flags, noise = self._tick(sample)
        if sample.mag_uT is None:
            return [tilt_output(sample, noise, flags)]
        r = solve(sample.acc_mps2, sample.mag_uT, mag_ref_ned_uT, noise, self._method(flags), **self.options)
        return [self._output(sample, r, flags)]

    def estimate_each(
        self, samples: list[ProcessedSample], refs_ned_uT: list[Array]
    ) -> list[list[AttitudeOutput] | MavAttitudeError]:
        """:meth:`estimate` of each sample in turn, each one's outputs or the error it raises, the solves made
        together (:func:`~mavattitude.estimation.batch.solve_each`) for each noise model, method and reference."""
        out: list[list[AttitudeOutput] | MavAttitudeError] = [[] for _ in samples]
        groups: dict[tuple[NoiseModel, str, int], list[tuple[int, int]]] = {}
        for i, (sample, ref) in enumerate(zip(samples, refs_ned_uT, strict=True)):
            flags, noise = self._tick(sample)
            if sample.mag_uT is None:
                out[i] = [tilt_output(sample, noise, flags)]
            else:  # (the references are alive in refs_ned_uT: their ids are distinct)
                groups.setdefault((noise, self._method(flags), id(ref)), []).append((i, flags))
        for (noise, method, _), rows in groups.items():
            acc, mag = (np.array([getattr(samples[i], name) for i, _ in rows]) for name in ("acc_mps2", "mag_uT"))
            solved = solve_each(acc, mag, refs_ned_uT[rows[0][0]], noise, method, **self.options)
            for (i, flags), r in zip(rows, solved, strict=True):
                out[i] = r if isinstance(r, MavAttitudeError) else [self._output(samples[i], r, flags)]
        return out

    def _tick(self, sample: ProcessedSample) -> tuple[int, NoiseModel]:
        """The tick's flags (plain int bits: IntFlag arithmetic costs a microsecond per operation) and the noise
        model it is solved with, the tick having fed the rest-noise measurement."""
        if self.rest_noise is not None:
            self._measure_noise(self.rest_noise, sample)
        return int(sample.flags), self._noise_for(sample.acc_std_scale, sample.mag_std_scale)

    def _method(self, flags: int) -> str:
        return HEADING_ONLY_METHOD if flags & _MAG_OFF else self.method

    @staticmethod
    def _output(sample: ProcessedSample, r: SolveResult, flags: int) -> AttitudeOutput:
        if not r.converged:
            flags |= _NOT_CONVERGED
        rates = np.array(sample.gyr_radps, dtype=float)
        if flags & _MAG_OFF:
            flags |= _HEADING_ONLY
            covariance = _heading_uncertain(r, sample.acc_mps2)
        else:
            covariance = _SolutionCovariance(r)
        return AttitudeOutput(sample.time_s, r.q, rates, r.iterations, r.converged, flag_set(flags), covariance)


def _axes(values: Any) -> str:
    return "(" + ", ".join(f"{v:.3g}" for v in values) + ")"


#: Tick flags under which the magnetometer sets heading only: its |B| is off, or the compass is judged off.
_MAG_OFF = int(SampleFlag.MAG_NORM | SampleFlag.MAG_INCONSISTENT)
HEADING_ONLY_METHOD = "triad"  # the accelerometer's direction kept exactly, the magnetometer's heading only
_RESET, _NOT_CONVERGED, _HEADING_ONLY, _DISTURBED, _INCONSISTENT, _PER_SAMPLE, _GPS_AIDED, _MOVING = (
    int(f)
    for f in (
        SampleFlag.RESET,
        SampleFlag.NOT_CONVERGED,
        SampleFlag.MAG_HEADING_ONLY,
        SampleFlag.MAG_DISTURBED,
        SampleFlag.MAG_INCONSISTENT,
        SampleFlag.PER_SAMPLE,
        SampleFlag.GPS_AIDED,
        SampleFlag.MOVING,
    )
)
_NO_HEADING = int(SampleFlag.NO_HEADING)
#: The reference handed to an estimator for a tick without a magnetometer reading before the field is known: a
#: tick without one compares nothing with it (the fused filter takes the real field when it comes).
NO_FIELD_NED_UT = np.array([1.0, 0.0, 0.0])
#: What the fused method solves a tick of an input too slow to integrate with (``PER_SAMPLE``).
SLOW_INPUT_METHOD = "ign"
#: The fused method's rest-noise measurement takes one sample per this interval (50 Hz at most; just under: jitter)
REST_NOISE_PERIOD_S = 0.0199


class _SolutionCovariance:
    """An output's covariance from its solution, computed when asked (:func:`output_covariances` computes many
    at once)."""

    __slots__ = ("result",)

    def __init__(self, result: Any) -> None:
        self.result = result

    def __call__(self) -> Array:
        return self.result.covariance


def output_covariances(outputs: list[AttitudeOutput]) -> Array:
    """``[o.covariance_or_nan() for o in outputs]`` as ``(N, 3, 3)``: the snapshot solutions' in one batch
    (:func:`mavattitude.estimation.solve.covariances`, the same values), the others one by one."""
    from mavattitude.estimation.solve import covariances

    solved = [i for i, o in enumerate(outputs) if type(o.covariance_source) is _SolutionCovariance]
    out = np.empty((len(outputs), 3, 3))
    if solved:
        out[solved] = covariances([outputs[i].covariance_source.result for i in solved])  # type: ignore[union-attr]
    for i in sorted(set(range(len(outputs))) - set(solved)):
        out[i] = outputs[i].covariance_or_nan()
    return out


def _heading_uncertain(result: Any, acc_mps2: Any) -> Callable[[], Array]:
    return lambda: heading_uncertain(result.covariance, acc_mps2)


def tilt_output(sample: ProcessedSample, noise: NoiseModel, flags: int) -> AttitudeOutput:
    """A tick without a magnetometer: roll and pitch from the accelerometer, yaw held at 0 and flagged
    ``NO_HEADING``; its covariance the tilt's (the accelerometer's σ over |a| about each axis) with a heading
    uniform over ±180° (:func:`~mavattitude.estimation.compass.heading_uncertain`)."""
    acc = sample.acc_mps2
    q = np.array(tilt_quat_parts(acc))
    sigma_rad = max(noise.accel_std) / math.sqrt(acc[0] * acc[0] + acc[1] * acc[1] + acc[2] * acc[2])
    tilt = np.eye(3) * sigma_rad**2
    covariance = functools.partial(heading_uncertain, tilt, acc)
    rates = np.array(sample.gyr_radps, dtype=float)
    return AttitudeOutput(sample.time_s, q, rates, 0, True, flag_set(flags | _NO_HEADING), covariance)


class FusedEstimator:
    """The gyro-aided filter (:class:`~mavattitude.estimation.fused.FusedFilter`), set by ``estimator.fused``.

    A tick of an input too slow to filter (``PER_SAMPLE``: about twice the low-pass cutoff, 20 Hz or slower) is too
    slow to integrate too: the gyro's samples are snapshots of a rate that changes faster than they come (a 2 Hz
    RAW_IMU in a turn reaching 60°/s steps 30° between two, at angular accelerations of 100°/s² and more, so
    the rate held over a step is wrong by tens of degrees), so such a tick is solved from its accelerometer and
    magnetometer alone (:data:`SLOW_INPUT_METHOD`), as the snapshot methods do, and the filter starts afresh
    (from IGN) when the input is fast again.

    With ``noise.rest_s`` the samples (one per :data:`REST_NOISE_PERIOD_S`) feed a rest-noise measurement
    (:mod:`mavattitude.estimation.restnoise`): once the vehicle has been still that long, the magnetometer's σ
    floors the filter's ``σ_m`` and the gyro bias measured at rest is the one every filter started after it
    starts from (``P_bb`` its standard error plus the bias walk since); the log says so once, the counters
    (``noise_rest_s``, ``noise_measured``, ``bias_from_rest``) say which values are in use.
    """

    wants_filtered = False
    solves_together = False

    def __init__(self, config: Config) -> None:
        from mavattitude.estimation.fused import COUNTERS, FusedFilter  # loaded only for this method

        self.settings = config.estimator.fused
        self._counter_names = COUNTERS
        self._new_filter = functools.partial(
            FusedFilter,
            self.settings,
            output_rate_hz=config.filter.output_rate_hz,
            max_gap_s=config.input.input_timeout_s,
        )
        self._filter: Any = None
        self._mag_ref: Array | None = None
        self._past: Counter[str] = Counter()  # counters of the filters dropped by a reset
        # what the filter counted while the reference was awaited (its updates then are all without a heading: not
        # the compass's doing, and no finding), and whether it is awaited now
        self._waited: Counter[str] = Counter()
        self._waiting = False
        self._slow = SnapshotEstimator(config, SLOW_INPUT_METHOD)
        rest_s = config.noise.rest_s
        self.rest_noise = RestNoise(rest_s) if rest_s > 0.0 else None
        self._rest_next_s = -math.inf  # the next sample time the rest measurement takes
        self._bias_from_rest = 0  # filters started from the gyro bias measured at rest

    def reset(self) -> None:
        self._drop_filter()
        self._slow.reset()

    def wait(self, sample: ProcessedSample) -> None:
        """The filter runs on roll and pitch alone (the reading left out), its outputs dropped: it tracks the tilt
        and the gyro bias (at rest, the zero-rate updates) meanwhile, so the reference, when it comes, only gives
        it a heading (:meth:`FusedFilter.push`), however the vehicle moves then. What it counts meanwhile is left
        out of :meth:`counters`."""
        if int(sample.flags) & _PER_SAMPLE:  # a slow input is solved tick by tick: nothing to carry
            return
        before = Counter(self._filter.counters) if self._filter is not None else Counter()
        self.estimate(replace(sample, mag_uT=None), NO_FIELD_NED_UT)
        self._waited += Counter(self._filter.counters) - before
        self._waiting = True

    def _drop_filter(self) -> None:
        if self._filter is not None:
            self._past.update(self._filter.counters)
        self._filter = None

    def counters(self) -> dict[str, float]:
        """The filter's event counts (summed over resets), its learnt hard-iron offset, µT (body frame), and how
        long its heading has come from the gyro alone (``heading_gap_s``, whole seconds)."""
        counts = self._past + Counter(self._filter.counters if self._filter is not None else {}) - self._waited
        out: dict[str, float] = {k: counts[k] for k in self._counter_names}
        rest = self.rest_noise
        if rest is not None:
            out |= {"noise_rest_s": round(rest.still_s, 1), "noise_measured": int(rest.measured is not None)}
            out["bias_from_rest"] = self._bias_from_rest
        if self._filter is not None:
            x, y, z = self._filter.mag_offset_uT.tolist()
            out |= {"mag_offset_x_uT": x, "mag_offset_y_uT": y, "mag_offset_z_uT": z}
            # whole s: the line says what changed; none while the reference is awaited (the heading not yet sought)
            out["heading_gap_s"] = 0 if self._waiting else math.floor(self._filter.heading_gap_s)
        return out

    def velocity(self, velocity: GpsVelocity) -> None:
        if self._filter is not None:
            self._filter.set_velocity(velocity)

    def _measure_noise(self, rest: RestNoise, sample: ProcessedSample) -> None:
        """The sample into the rest measurement (the σ of a sample's noise is the σ of every sample's: one per
        :data:`REST_NOISE_PERIOD_S` measures it as well, at a bounded cost from a fast input); once measured,
        the magnetometer's σ floors the running filter's ``σ_m``, said once in the log (then at debug level)."""
        self._rest_next_s = sample.time_s + REST_NOISE_PERIOD_S
        if not rest.add(sample.time_s, sample.acc_mps2, sample.mag_uT, sample.gyr_radps):
            return
        if self._filter is not None:
            self._hand_over(self._filter, rest, sample.time_s)
        level = logging.INFO if rest.updated_s == rest.since_s else logging.DEBUG  # said once, the first time
        if not log.isEnabledFor(level):  # the figures formatted only to be said (a block a second at rest)
            return
        measured, bias = rest.measured, rest.gyro_bias_radps
        log.log(
            level,
            "t=%.1f s: noise measured at rest over %.0f s: gyro bias %s rad/s, the fused filter's start from now on; "
            "mag σ %s µT, the floor of its σ_m (%.3g µT); accel σ %s m/s² (its σ_a is of the pre-filtered specific "
            "force: not floored)",
            sample.time_s,
            rest.still_s,
            _axes(bias or ()),
            _axes(measured.mag_std),  # type: ignore[union-attr]
            self.settings.mag_std_uT,
            _axes(measured.accel_std),  # type: ignore[union-attr]
        )

    def _bias_std(self, rest: RestNoise, time_s: float) -> Vec3:
        """The measured bias's σ per axis at ``time_s``: its standard error and the bias walk since the measurement."""
        walk2 = self.settings.gyro_bias_walk_radps2**2 * max(0.0, time_s - rest.updated_s)
        return tuple(math.sqrt(s * s + walk2) for s in rest.gyro_bias_std_radps or (0.0,) * 3)  # type: ignore[return-value]

    def _hand_over(self, filt: Any, rest: RestNoise, time_s: float) -> bool:
        """What the rest showed, to the filter (:meth:`FusedFilter.set_rest_noise`: the bias only before its start)."""
        mag_std = max(rest.measured.mag_std)  # type: ignore[union-attr]
        return filt.set_rest_noise(mag_std, rest.gyro_bias_radps, self._bias_std(rest, time_s))

    def estimate(self, sample: ProcessedSample, mag_ref_ned_uT: Array) -> list[AttitudeOutput]:
        self._waiting = False
        if int(sample.flags) & _PER_SAMPLE:  # (plain int bits: an IntFlag operation costs 0.8 µs per sample)
            self._drop_filter()
            return self._slow.estimate(sample, mag_ref_ned_uT)
        rest = self.rest_noise
        if rest is not None and not 0.0 < self._rest_next_s - sample.time_s <= REST_NOISE_PERIOD_S:
            self._measure_noise(rest, sample)
        if self._filter is None:
            self._filter = self._new_filter(mag_ref_ned_uT)
            if rest is not None and rest.measured is not None:
                self._bias_from_rest += self._hand_over(self._filter, rest, sample.time_s)
        # The pipeline replaces its reference array when the field changes and never writes into it, so the
        # same object is the same field: the values are compared only when a new array arrives (rarely).
        elif mag_ref_ned_uT is not self._mag_ref and not np.array_equal(self._mag_ref, mag_ref_ned_uT):
            self._filter.set_mag_ref(mag_ref_ned_uT)  # a new field: the state kept, turned with north (no restart)
        self._mag_ref = mag_ref_ned_uT
        estimates = self._filter.push(sample.time_s, sample.gyr_radps, sample.acc_mps2, sample.mag_uT, sample.mag_age_s)
        front = int(sample.flags) & ~_RESET  # the filter acts on a reset itself; no output says it
        if not self._filter.heading_known:
            front |= _NO_HEADING
        if self._filter.gps_aided:
            front |= _GPS_AIDED
        return [
            AttitudeOutput(
                e.time_s,
                e.q,
                e.rates_radps,
                0,
                True,
                flag_set(front | _DISTURBED if e.mag_disturbed else front),
                functools.partial(_covariance, e),
            )
            for e in estimates
        ]


def _covariance(estimate: Any) -> Array:
    """A fused estimate's covariance, made an array when an output is asked for it."""
    return estimate.covariance


#: ``estimator.method`` → the estimator that runs it: a snapshot method's solve per tick, or the filter.
ESTIMATORS: dict[str, Callable[[Config], Estimator]] = {
    name: SnapshotEstimator if method.snapshot else FusedEstimator for name, method in METHODS.items()
}


def _invalid(output: AttitudeOutput) -> str | None:
    """Why an estimate must not be output, or ``None``."""
    if not is_unit_quaternion_parts(output.q.tolist()):
        return "invalid_quaternion"
    if not math.isfinite(sum(output.rates_radps.tolist())):  # inf − inf is NaN: any non-finite rate shows
        return "invalid_rates"
    return None


def frontend_settings(config: Config, **overrides: Any) -> FrontEndSettings:
    """The front end's settings from the config (``overrides`` replace fields)."""
    values = {
        "mounting": config.mounting.rotation,
        "calibration": config.calibration,
        "filter_enabled": config.filter.enabled,
        "cutoff_hz": config.filter.cutoff_hz,
        "output_rate_hz": config.filter.output_rate_hz,
        "input_timeout_s": config.input.input_timeout_s,
    }
    return FrontEndSettings(**{**values, **overrides})


class AttitudePipeline:
    """Front end + estimator, one sample at a time; see the module docstring."""

    def __init__(self, config: Config) -> None:
        self.config = config
        try:
            self.estimator: Estimator = ESTIMATORS[config.estimator.method](config)
        except KeyError:
            raise ConfigError(f"estimator.method: no estimator for {config.estimator.method!r}") from None
        filtered = config.filter.enabled and self.estimator.wants_filtered
        try:
            self.frontend = FrontEnd(frontend_settings(config, filter_enabled=filtered))
        except MavAttitudeError as exc:
            raise ConfigError(f"front end: {exc}") from exc
        method = METHODS[config.estimator.method]
        self.counters = PipelineCounters(
            self.frontend.counters,
            estimator=self.estimator.counters,
            estimator_prefix=method.counters_prefix or method.name,
        )
        # the sensors' per-sample σ (the defaults with fused, which refuses noise:), never the fused filter's
        # effective ones (docs/vehicle.md)
        self.compass = CompassMonitor(config.compass, config.noise.accel_std_mps2, config.noise.mag_std_uT)
        self._compass_at_s = -math.inf  # vehicle time of the last tick the monitor took
        self._compass_seen_s = math.nan  # vehicle time of the last tick with a magnetometer reading (or the first)
        self.compass_seen = False  # a tick had a magnetometer reading
        self.mag_ref_ned_uT: Array | None = None
        self.last_error: MavAttitudeError | None = None
        self._held: list[tuple[ProcessedSample, Array]] | None = None  # ticks push_batch holds to solve together
        reference = config.reference
        self.magref = ReferenceTracker(reference.magnetic, position_wait_s=reference.position_wait_s)
        self._apply_reference()
        self.units = UnitsCheck()  # the input's magnitudes at its start, judged once (findings in ``Pushed.units``)

    @property
    def waiting_for_reference(self) -> bool:
        """True while ``reference.magnetic: auto`` has neither a position nor a field measured from the compass
        (:class:`~mavattitude.sensors.magref.ReferenceTracker`): nothing is emitted."""
        return self.mag_ref_ned_uT is None

    def _measure_reference(self, tick: ProcessedSample) -> bool:
        """A tick while waiting for the reference, into the tracker's measured field (its quiet dip and |B|, as
        the compass monitor takes them); True when that became the reference."""
        if tick.mag_uT is None:
            return False
        dip, field = self.compass.quiet_dip_field(tick.acc_mps2, tick.mag_uT, tick.gyr_radps)
        if not self.magref.observe(tick.time_s, dip, field):
            return False
        self._apply_reference()
        return True

    def _measure_reference_rows(self, batch: BatchOutput) -> int:
        """:meth:`_measure_reference` of a batch's ticks in order, up to the one that made the measured field the
        reference: its row (it and the ticks after it take the reference); the batch's length if none did."""
        rows = np.flatnonzero(batch.mag_uT[:, 0] == batch.mag_uT[:, 0])  # NaN: no reading
        dips, norms = self.compass.quiet_dip_field_rows(batch.acc_mps2[rows], batch.mag_uT[rows], batch.gyr_radps[rows])
        times = batch.time_s[rows].tolist()
        for i, t, dip, norm in zip(rows.tolist(), times, dips.tolist(), norms.tolist(), strict=True):
            if self.magref.observe(t, dip, norm):
                self._apply_reference()
                return i
        return len(batch)

    def set_position(self, lat_deg: float, lon_deg: float, alt_m: float, when: dt.date | None = None) -> bool:
        """A vehicle position (``reference.magnetic: auto``): the WMM field there on ``when`` (default today)
        becomes the reference, recomputed after a move of a few km. True when the reference changed."""
        changed = self.magref.update_position(lat_deg, lon_deg, alt_m, when)
        if changed:
            self._apply_reference()
        return changed

    def _apply_reference(self) -> None:
        ref = self.magref.reference
        self.set_magnetic_reference(ref.field_ned_uT, ref.intensity_uT is not None, self.magref.measured)

    def set_magnetic_reference(
        self, field_ned_uT: Iterable[float] | None, magnitude_known: bool = True, measured: bool = False
    ) -> None:
        """The NED field (µT) the solver aligns to (``None``: unknown, nothing is emitted). With
        ``magnitude_known`` its norm also screens |B| in the front end; without, only its direction is used.
        ``measured``: the compass's own field (no position), which the compass monitor holds it to since."""
        if field_ned_uT is None:
            self.mag_ref_ned_uT = None
            self.frontend.set_expected_field_uT(None)
            return
        ref = np.array(list(field_ned_uT), dtype=float)
        if ref.shape != (3,) or not np.all(np.isfinite(ref)) or not np.any(ref):
            raise InputError(f"magnetic reference must be a finite, non-zero NED vector, got {ref!r}")
        self.mag_ref_ned_uT = ref
        intensity_uT = float(np.linalg.norm(ref)) if magnitude_known else None
        self.frontend.set_expected_field_uT(intensity_uT)
        self.compass.set_reference(tuple(ref.tolist()), intensity_uT, measured)

    def _set_declination(self, name: str, value: float) -> bool:
        declination_deg = value * DECLINATION_PARAMETERS[name]
        if not abs(declination_deg) <= 180.0:  # NaN too
            log.warning("%s %g is no declination (%g°): not applied", name, value, declination_deg)
            return False
        changed = self.magref.set_declination(declination_deg, name)
        if changed:
            self._apply_reference()
        return changed

    def push(self, sample: ImuSample, attitudes: bool = True) -> Pushed:
        """What one input sample completes (see :class:`Pushed`); ``attitudes=False``: the compass monitor's
        verdicts alone, no estimator (how the vehicle's other magnetometers are judged)."""
        pushed = Pushed()
        if attitudes and self.units.open:
            pushed.units += self.units.add_sample(sample.time_s, sample.acc_mps2, sample.mag_uT)
        for tick in self.frontend.push(sample):
            self.counters.ticks += 1
            if attitudes:
                self._estimate(tick, pushed)
            elif tick.mag_uT is not None and self.mag_ref_ned_uT is not None and self.compass.settings.enabled:
                self._judge_compass(tick, tick.mag_uT, pushed)
        return pushed

    def set_velocity(self, velocity: GpsVelocity) -> None:
        """The GPS receiver's own velocity, received after the last sample (the fused filter's acceleration)."""
        self.estimator.velocity(velocity)

    def set_autopilot_parameter(self, name: str, value: float) -> bool:
        """One of the autopilot's parameters (PARAM_VALUE, a log's PARM), received after the last sample. Its level
        trim (:data:`~mavattitude.sensors.mounting.TRIM_PARAMETERS`, with ``mounting.autopilot_trim``) turns the
        readings into the vehicle's frame from the next sample on; its declination (:data:`DECLINATION_PARAMETERS`)
        turns a field measured from the compass to true north
        (:meth:`~mavattitude.sensors.magref.ReferenceTracker.set_declination`). True when either changed."""
        if name in DECLINATION_PARAMETERS:
            return self._set_declination(name, value)
        if name not in TRIM_PARAMETERS or not self.config.mounting.autopilot_trim:
            return False
        if not abs(value) <= TRIM_LIMIT_RAD:  # NaN too
            log.warning("%s %g rad is no level trim (the autopilot keeps it within ±10°): not applied", name, value)
            return False
        trim = list(self.frontend.settings.trim_rad)
        trim[TRIM_PARAMETERS.index(name)] = value
        if tuple(trim) == self.frontend.settings.trim_rad:
            return False
        self.frontend.set_trim(*trim)
        log.info(
            "%s %.2f°: the autopilot's level trim, applied (attitudes of the vehicle's frame)",
            name,
            math.degrees(value),
        )
        return True

    def push_batch(
        self,
        time_s: Array,
        acc_mps2: Array,
        gyr_radps: Array,
        mag_uT: Array,
        mag_new: NDArray[np.bool_],
        time_wrap_s: float | None = None,
        reference_after_s: float = -math.inf,
        mag_repeats: bool = False,
        gps: tuple[Array, list[GpsVelocity]] = (np.empty(0), []),
        attitudes: bool = True,
        progress: Callable[[int, int], None] | None = None,
    ) -> Pushed:
        """:meth:`push` for a whole run of samples at once: what ``push`` gives fed them one by one, as one value.

        The front end runs vectorised (:func:`~mavattitude.sensors.frontend.process_batch`, ~20× faster per
        sample, ticks equal to rounding), then every tick is routed as in :meth:`push`; a snapshot method's ticks
        are held and solved together (the estimator's ``estimate_each``: each tick's outputs as ``estimate`` gives
        them, to rounding), a run of :data:`PROGRESS_TICKS` at a time. For offline replay, where the per-sample
        front end and solver are the cost. The magnetic reference is the one
        set now, for every tick from the first after ``reference_after_s`` on (the ticks before it wait, as before a
        position; a reboot's clock going back later does not undo it), or,
        with none set, the field the ticks measure (:meth:`_measure_reference`, the same rule as one by one);
        ``mag_new`` marks rows with a new magnetometer reading, ``mag_repeats`` that the messages repeat the newest
        one (:attr:`~mavattitude.sensors.units.ImuSample.mag_repeats`). ``gps``: the receiver's velocities and the
        times they are handed in at, each before the first tick at or after its time, as :meth:`set_velocity`.
        ``attitudes=False``: the compass monitor alone, no estimator (how a log's other magnetometers are judged).
        ``progress(done, total)``: ticks estimated, every :data:`PROGRESS_TICKS` and at the end.
        """
        fe = self.frontend
        pushed = Pushed()
        if attitudes and self.units.open:
            pushed.units += self.units.add(time_s, acc_mps2, mag_uT)
        inputs = (fe.settings, time_s, acc_mps2, gyr_radps, mag_uT)
        options = {"mag_new": mag_new, "mag_repeats": mag_repeats, "wrap_period_s": time_wrap_s}
        batch = process_batch(*inputs, **options, expected_field_uT=fe.expected_field_uT)
        # the first tick with the reference: the first after reference_after_s, in order (a reboot later in the
        # batch takes the clock back, not the reference), or the one whose field was measured
        after = batch.time_s > reference_after_s
        first = int(np.argmax(after)) if after.any() else len(batch)
        if self.mag_ref_ned_uT is None:
            # the field measured from the ticks themselves: the batch again with its |B| screening them
            first = max(first, self._measure_reference_rows(batch))
            if self.mag_ref_ned_uT is not None:
                batch = process_batch(*inputs, **options, expected_field_uT=fe.expected_field_uT, say_reboots=False)
        fe.counters.add(batch.counters)
        reference = self.mag_ref_ned_uT
        if reference is not None and self.compass.settings.enabled:
            pushed.compass = self._judge_compass_rows(batch, np.arange(len(batch)) >= first)
        if not attitudes:
            return pushed
        gps_t, velocities = gps[0].tolist(), gps[1]
        next_gps = 0
        self._held = [] if self.estimator.solves_together else None
        try:
            with collector.paused():
                for done, tick in enumerate(batch.samples()):
                    while next_gps < len(gps_t) and gps_t[next_gps] <= tick.time_s:
                        self.estimator.velocity(velocities[next_gps])
                        next_gps += 1
                    self.counters.ticks += 1
                    self.mag_ref_ned_uT = reference if done >= first else None
                    self._estimate(tick, pushed, judge=False)
                    if done % PROGRESS_TICKS == 0:
                        self._solve_held(pushed)
                        if progress is not None:
                            progress(done, len(batch))
                self._solve_held(pushed)
        finally:
            self._held = None
        if progress is not None:
            progress(len(batch), len(batch))
        self.mag_ref_ned_uT = reference
        return pushed

    def _judge_compass_rows(self, batch: BatchOutput, referenced: NDArray[np.bool_]) -> list[CompassEvent]:
        """:meth:`_judge_compass` of every tick of ``batch`` with a reference and a magnetometer reading, in order,
        the monitor taking all its ticks at once (:meth:`CompassMonitor.update_rows`): the flags set in ``batch``,
        the verdict's changes returned."""
        rows = np.flatnonzero(referenced & (batch.mag_uT[:, 0] == batch.mag_uT[:, 0])).tolist()  # NaN: no reading
        taken = []
        at_s = self._compass_at_s
        for i, t in zip(rows, batch.time_s[rows].tolist(), strict=True):
            if not _compass_skips(t - at_s):
                taken.append(i)
                at_s = t
        self._compass_at_s = at_s
        before = self.compass.inconsistent
        events, suspect, inconsistent = self.compass.update_rows(
            batch.time_s[taken],
            batch.acc_mps2[taken],
            batch.mag_uT[taken],
            batch.gyr_radps[taken],
            batch.mag_age_s[taken],
        )
        # a tick the monitor took is flagged when suspect, one it skipped when the verdict is inconsistent
        count = np.searchsorted(taken, rows, side="right")  # the ticks taken up to each row
        verdict = np.array([before, *inconsistent], dtype=bool)[count]
        flagged = np.where(np.isin(rows, taken), np.array([False, *suspect], dtype=bool)[count], verdict)
        batch.flags[np.asarray(rows, dtype=np.int64)[flagged]] |= _INCONSISTENT
        return [e for e in events if e is not None]

    def _estimate(self, tick: ProcessedSample, pushed: Pushed, judge: bool = True) -> None:
        """The tick's outputs into ``pushed``; ``judge=False``: the compass monitor and the reference's
        measurement have taken it already (:meth:`push_batch`)."""
        if tick.mag_uT is None:
            self._without_compass(tick, pushed)
            return
        self._compass_seen_s, self.compass_seen = tick.time_s, True
        if self.mag_ref_ned_uT is None and not (judge and self._measure_reference(tick)):
            self.counters.waiting += 1
            self.estimator.wait(tick)
            return
        if judge and self.compass.settings.enabled:
            tick = self._judge_compass(tick, tick.mag_uT, pushed)
        self._solve(tick, self.mag_ref_ned_uT, pushed)

    def _without_compass(self, tick: ProcessedSample, pushed: Pushed) -> None:
        """A tick without a magnetometer reading. The snapshot methods wait ``input_timeout_s`` for one (a log's
        first compass reading comes after its first IMU samples; a dropout is held that long by the front end),
        then give roll and pitch alone (:func:`tilt_output`), needing no field; the fused filter takes it as any
        sample (it starts on roll and pitch alone after the same wait)."""
        since_s = tick.time_s - self._compass_seen_s
        if not since_s >= 0.0:  # the first tick, or the clock went back (a reboot)
            self._compass_seen_s, since_s = tick.time_s, 0.0
        if self.estimator.wants_filtered and since_s <= self.config.input.input_timeout_s:
            self._reject("no_mag", pushed)
            return
        self._solve(tick, NO_FIELD_NED_UT if self.mag_ref_ned_uT is None else self.mag_ref_ned_uT, pushed)

    def _solve(self, tick: ProcessedSample, mag_ref_ned_uT: Array, pushed: Pushed) -> None:
        """The estimator's outputs for the tick into ``pushed``, those that pass the output check; held for
        :meth:`_solve_held` while :meth:`push_batch` holds ticks."""
        if self._held is not None:
            self._held.append((tick, mag_ref_ned_uT))
            return
        try:
            outputs: list[AttitudeOutput] | MavAttitudeError = self.estimator.estimate(tick, mag_ref_ned_uT)
        except MavAttitudeError as exc:
            outputs = exc
        self._take(tick, outputs, pushed)

    def _solve_held(self, pushed: Pushed) -> None:
        """The ticks held, estimated together (the estimator's ``estimate_each``), into ``pushed`` in order."""
        if not self._held:
            return
        ticks, refs = zip(*self._held, strict=True)
        self._held.clear()
        for tick, outputs in zip(ticks, self.estimator.estimate_each(list(ticks), list(refs)), strict=True):
            self._take(tick, outputs, pushed)

    def _take(self, tick: ProcessedSample, outputs: list[AttitudeOutput] | MavAttitudeError, pushed: Pushed) -> None:
        """A tick's outputs into ``pushed``, those that pass the output check, or the error it was refused with."""
        if isinstance(outputs, MavAttitudeError):
            self._reject(type(outputs).__name__, pushed)
            self.last_error = outputs
            log.debug("t=%.3f s: not solved: %s", tick.time_s, outputs)
            return
        pushed.outputs += [o for o in outputs if self._valid(o, pushed)]

    def _reject(self, reason: str, pushed: Pushed) -> None:
        self.counters.rejected[reason] += 1
        pushed.reject(reason)

    def _judge_compass(self, tick: ProcessedSample, mag_uT: Vec3, pushed: Pushed) -> ProcessedSample:
        """Feed the compass monitor (at most one tick per ``COMPASS_PERIOD_S``: the fused filter's ticks are its input
        samples, and the figures need no more); flag the tick ``MAG_INCONSISTENT`` when it judges the field off."""
        compass = self.compass
        if _compass_skips(tick.time_s - self._compass_at_s):
            return self._flagged(tick) if compass.inconsistent else tick
        self._compass_at_s = tick.time_s
        event, suspect = compass.update_and_suspect(tick.time_s, tick.acc_mps2, mag_uT, tick.gyr_radps, tick.mag_age_s)
        if event is not None:
            pushed.compass.append(event)
        return self._flagged(tick) if suspect else tick

    @staticmethod
    def _flagged(t: ProcessedSample) -> ProcessedSample:
        flags = flag_set(int(t.flags) | _INCONSISTENT)  # (built whole: dataclasses.replace costs three times more)
        return ProcessedSample(
            t.time_s, t.acc_mps2, t.mag_uT, t.gyr_radps, flags, t.acc_std_scale, t.mag_std_scale, t.mag_age_s
        )

    def _valid(self, output: AttitudeOutput, pushed: Pushed) -> bool:
        c = self.counters
        reason = _invalid(output)
        if reason:
            self._reject(reason, pushed)
            self.estimator.reset()
            log.warning(
                "t=%.3f s: estimator returned %s: q=%s, rates=%s", output.time_s, reason, output.q, output.rates_radps
            )
            return False
        c.emitted += 1
        c.iterations += output.iterations
        c.not_converged += not output.converged
        return True
