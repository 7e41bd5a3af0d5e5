"""Replay: the service's pipeline and dispatcher over a finite message source, as fast as the CPU goes.

:func:`replay` reads a log source (:mod:`mavattitude.link.logs`) to its end through the same
:class:`~mavattitude.dispatch.Dispatcher` as the live service (lock-on, routing), and the vehicle's samples
through the same pipeline, keeping every attitude output and the autopilot's own attitudes.

The pipeline takes the samples at once (:meth:`AttitudePipeline.push_batch`: the vectorised front end,
then the same estimator step per tick), which is what makes replay fast: a DataFlash or ULog log already
holds its streams as arrays, from one vehicle; a telemetry log is read as arrays too, its rows those of
the autopilot the dispatcher's lock-on chooses (:meth:`~mavattitude.dispatch.Dispatcher.follow`). That
needs one magnetic reference for the whole log (fixed, or the WMM's at the log's first position when the
vehicle stays within the distance after which the service would look it up again, or the field measured
from the compass of a log without a position: :class:`~mavattitude.sensors.magref.ReferenceTracker`'s rule,
which the pipeline applies to the batch's ticks as it would one by one); otherwise, and with
``at_once=False``, the samples go into the pipeline one by one as they would live. A telemetry log across a
reboot of the autopilot is read item by item in its own order (:func:`_replay_in_log_order`). The autopilot's
parameters (its level trim, its declination) are taken before the first sample, each at its last value in the
log, when the batch has one reference; one by one, each record where it comes in the log, as live.
"""

from __future__ import annotations

import functools
import logging
import math
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray

from mavattitude import collector
from mavattitude.config import Config
from mavattitude.dispatch import DispatchCounters, Dispatcher
from mavattitude.estimation.compass import CompassEvent, CompassMonitor
from mavattitude.estimation.conventions import Array
from mavattitude.estimation.crosscheck import CrossCheck, CrossCheckEvent, Difference, cross_check_log
from mavattitude.link.logs import LogSource
from mavattitude.link.logstreams import LogStreams
from mavattitude.link.source import AutopilotAttitude, AutopilotParameter, MessageSource, Sender
from mavattitude.link.tlog import TlogSource
from mavattitude.pipeline import (
    AttitudeOutput,
    AttitudePipeline,
    CrossCheckGate,
    Pushed,
    comparable_heading,
    output_covariances,
)
from mavattitude.sensors.frontend import SampleFlag, median_rate_hz
from mavattitude.sensors.magref import distance_km
from mavattitude.sensors.units import COMPASS_INSTANCES, ImuSample

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class JudgedCompass:
    """One magnetometer of a log as the compass monitor judged it over the whole log (docs/vehicle.md)."""

    instance: int
    events: list[CompassEvent]
    monitor: CompassMonitor

    @property
    def warnings(self) -> int:
        return self.monitor.warnings

    def verdict(self) -> str:
        """``ok``, ``not judged`` (too few quiet or turning ticks), or what was off when it was first warned about."""
        warned = next((e for e in self.events if e.inconsistent), None)
        if warned is not None:
            return warned.figures.short()
        return "ok" if self.monitor.ever_judged else "not judged"


@dataclass
class Replayed:
    """What a replay produced: every output, the autopilot's attitudes, the compass verdict's changes, and the
    counters."""

    outputs: list[AttitudeOutput]
    autopilot: list[AutopilotAttitude]
    counters: DispatchCounters
    pipeline: AttitudePipeline
    vehicle: Sender | None
    first_sample_s: float = float("nan")
    last_sample_s: float = float("nan")
    sample_times_s: list[float] = field(default_factory=list)  # the vehicle's IMU sample times, for its rate
    internal_errors: list[BaseException] = field(default_factory=list)
    compass: list[CompassEvent] = field(default_factory=list)
    #: every magnetometer judged (the replayed one's from the pipeline), where the log holds several
    compasses: list[JudgedCompass] = field(default_factory=list)
    compass_used: str = ""  # which magnetometer was replayed and why ("1: the autopilot's: COMPASS_USE 0, …")
    #: (instance, parameter, value) when the log's parameters say the autopilot does not use the one replayed
    unused_compass: tuple[int, str, float] | None = None
    #: each magnetometer judged that the autopilot does not use, and the parameter that says so ("COMPASS_USE2 0")
    unused_compasses: dict[int, str] = field(default_factory=dict)

    @functools.cached_property
    def covariances(self) -> np.ndarray:
        """Every output's covariance, ``(N, 3, 3)`` (:func:`output_covariances`): the cross-check's and the CSV's,
        computed once."""
        return output_covariances(self.outputs)

    def output_array(self) -> np.ndarray:
        """Rows ``t_s, qw, qx, qy, qz`` of every output."""
        if not self.outputs:
            return np.empty((0, 5))
        return np.array([(o.time_s, *o.q.tolist()) for o in self.outputs])

    @property
    def input_rate_hz(self) -> float:
        """The rate the vehicle's IMU samples came at (one over their median interval)."""
        return median_rate_hz(np.array(self.sample_times_s))

    def autopilot_array(self) -> np.ndarray:
        """Rows ``t_s, qw, qx, qy, qz`` of the autopilot's attitudes."""
        if not self.autopilot:
            return np.empty((0, 5))
        return np.array([(a.time_s, *a.q) for a in self.autopilot])

    def cross_check(self) -> tuple[CrossCheck, list[Difference], list[CrossCheckEvent]]:
        """The service's cross-check over the whole replay (:func:`cross_check_log`): ours against the autopilot's
        attitudes, each pair judged as live (the yaw not where ours has no heading to compare,
        :func:`comparable_heading`; nor where :class:`CrossCheckGate` says it may be fooled by the vehicle's
        acceleration)."""
        ours, autopilot = self.output_array(), self.autopilot_array()
        gate = CrossCheckGate()
        moving = np.array([gate.moving(o) for o in self.outputs], dtype=bool)
        flags = np.array([int(o.flags) for o in self.outputs], dtype=np.int64)
        t, q = ours[:, 0], ours[:, 1:5]
        judged = comparable_heading(q, self.covariances, flags)
        settings = self.pipeline.config.crosscheck
        return cross_check_log(t, q, autopilot[:, 0], autopilot[:, 1:5], settings, self.heading(), moving, judged)

    def heading(self) -> NDArray[np.bool_]:
        """Which outputs have a heading (not flagged ``NO_HEADING``: their yaw means something)."""
        return np.array([not o.flags & SampleFlag.NO_HEADING for o in self.outputs], dtype=bool)


class _Collector:
    """The dispatcher's listener in replay: keeps what the service would have sent."""

    def __init__(self, result: Replayed) -> None:
        self.result = result

    def on_lock(self, vehicle: Sender) -> None:
        if self.result.vehicle != vehicle:
            self.result.vehicle = vehicle
            log.info("following the autopilot at system %d, component %d", *vehicle)

    def on_input(self, sample: ImuSample, t_rx: float) -> None:
        r = self.result
        if r.first_sample_s != r.first_sample_s:  # NaN: the first one
            r.first_sample_s = sample.time_s
        r.last_sample_s = sample.time_s
        r.sample_times_s.append(sample.time_s)

    def on_outputs(self, pushed: Pushed, t_rx: float) -> None:
        self.result.outputs += pushed.outputs
        self.result.compass += pushed.compass

    def on_autopilot_attitude(self, attitude: AutopilotAttitude, t_rx: float) -> None:
        self.result.autopilot.append(attitude)

    def on_parameter(self, parameter: AutopilotParameter) -> None:
        """Taken by the pipeline; nothing to ask for offline."""

    def on_message(self, msg: Any, t_rx: float) -> None:
        """Other messages mean nothing offline."""

    def on_reject(self, reason: str, exc: BaseException) -> None:
        if reason == "internal_error":
            self.result.internal_errors.append(exc)
        log.debug("rejected (%s): %s", reason, exc)


def replay(
    source: LogSource,
    config: Config,
    progress: Callable[[int, int], None] | None = None,
    at_once: bool = True,
) -> Replayed:
    """Run ``source`` to its end through the service's dispatcher and pipeline (see the module docstring).

    The collector is paused throughout (:mod:`mavattitude.collector`): every output is kept."""
    with collector.paused():
        return _replay(source, config, progress, at_once)


def _replay(source: LogSource, config: Config, progress: Callable[[int, int], None] | None, at_once: bool) -> Replayed:
    pipeline = AttitudePipeline(config)
    result = Replayed([], [], DispatchCounters(), pipeline, None)
    if not at_once:
        return _replay_items(source, result, progress)
    streams = source.streams_for(_dispatcher(source, None, result))  # the dispatcher's rules choose the rows
    vehicle = result.vehicle
    if vehicle is None:  # a .tlog without an autopilot's HEARTBEAT: no row is the vehicle's
        return result
    if isinstance(source, TlogSource) and _reboots(streams, pipeline.frontend.settings.reorder_window_s):
        return _replay_in_log_order(source, streams, config, progress)
    if _one_reference(streams, pipeline):
        return _replay_arrays(streams, result, vehicle, progress)
    from mavattitude.link.logstreams import StreamSource  # the vehicle's streams, one by one

    c = result.counters
    # what reading the log counted
    counters = DispatchCounters(
        received=c.rejected["decode"],
        ignored=c.ignored,
        rejected=dict(c.rejected),
        other_autopilots=set(c.other_autopilots),
    )
    result = Replayed([], [], counters, AttitudePipeline(config), vehicle)  # locked on already, and said so
    undecided = streams.compasses is not None and streams.compasses.why is None
    others = _judge_compasses(streams, result.pipeline, -math.inf) if undecided else []  # each on its own field
    streams = _chosen_compass(streams, others, result)
    result = _replay_items(StreamSource(source.name, streams, vehicle), result, progress)
    if not undecided:  # the others on the reference the replay ended with
        others = _judge_compasses(streams, result.pipeline, -math.inf)
    _collect_compasses(streams, others, result)
    return result


def _dispatcher(source: MessageSource, sink: Any, result: Replayed) -> Dispatcher:
    config = result.pipeline.config
    return Dispatcher(
        sink,
        _Collector(result),
        system_id=config.link.vehicle_system_id,
        vehicle=source.vehicle,
        counters=result.counters,
        wants_position=config.reference.magnetic.mode == "auto",
    )


def _dispatch(source: MessageSource, sink: Any, result: Replayed, progress: Callable[[int, int], None] | None) -> None:
    handle = _dispatcher(source, sink, result).handle
    while not source.finished:
        for received in source.recv(0.0):
            handle(received)
        if progress is not None:
            progress(source.done, source.total)


def _replay_items(source: MessageSource, result: Replayed, progress: Callable[[int, int], None] | None) -> Replayed:
    """Every item through the dispatcher into the pipeline, one by one, as live."""
    _dispatch(source, result.pipeline, result, progress)
    if result.internal_errors:  # offline, a bug is reported, not served around
        raise result.internal_errors[0]
    return result


def _replay_in_log_order(
    source: TlogSource, streams: LogStreams, config: Config, progress: Callable[[int, int], None] | None
) -> Replayed:
    """A telemetry log across a reboot, item by item in its own order: its times go back, so only the order
    places a position or a GPS velocity among the samples. As live, the compass the IMU message carries is
    replayed, and the log's others are judged beside it."""
    result = _replay_items(source, Replayed([], [], DispatchCounters(), AttitudePipeline(config), None), progress)
    message = source.decoder.message
    own = COMPASS_INSTANCES.get(message)
    if streams.compasses is not None and own in streams.compasses.readings:
        streams = streams.with_compass(own, f"{message}'s own, as live")
        result.compass_used = f"{own}: {message}'s own, as live"
        _collect_compasses(streams, _judge_compasses(streams, result.pipeline, -math.inf), result)
    result.unused_compass = streams.unused_compass()
    return result


def _reboots(streams: LogStreams, reorder_window_s: float) -> bool:
    """Whether the IMU clock goes back by more than ``reorder_window_s`` somewhere: the autopilot rebooted (the
    wrap of an old log's uint32 ms field is no reboot), and the arrays' times no longer say what came first."""
    back = -np.diff(streams.imu_t_s)
    wrap = streams.time_wrap_s
    return bool(np.any((back > reorder_window_s) & (back <= (0.5 * wrap if wrap else np.inf))))


def _one_reference(streams: LogStreams, pipeline: AttitudePipeline) -> bool:
    """Whether one magnetic reference serves the whole log: fixed; ``auto`` without a position (the field
    measured from the compass); or ``auto`` with a first position before the field would be measured, and
    every later one within the re-lookup distance."""
    if not pipeline.waiting_for_reference:
        return True
    if len(streams.position_t_s) == 0:
        return True
    if len(streams.imu_t_s) and streams.position_t_s[0] >= streams.imu_t_s[0] + pipeline.magref.position_wait_s:
        return False  # measured first, then the WMM's
    lat0, lon0, _ = streams.position[0].tolist()
    limit_km = pipeline.magref.recompute_distance_km
    return all(distance_km(lat0, lon0, lat, lon) <= limit_km for lat, lon, _ in streams.position.tolist())


def _replay_arrays(
    s: LogStreams, result: Replayed, vehicle: Sender, progress: Callable[[int, int], None] | None
) -> Replayed:
    """The arrays of a log through :meth:`AttitudePipeline.push_batch`, as the items would go one by one
    (``progress`` in output ticks)."""
    pipeline, counters = result.pipeline, result.counters
    result.vehicle = vehicle
    log.info("%d IMU samples of the autopilot at once", len(s.imu_t_s))
    reference_after_s = -math.inf
    if pipeline.waiting_for_reference and len(s.position_t_s):
        lat, lon, alt = s.position[0].tolist()
        pipeline.set_position(lat, lon, alt, s.date)
        counters.positions = len(s.position_t_s)
        before = s.imu_t_s[s.imu_t_s < s.position_t_s[0]]  # a tick is computed when the sample after it arrives
        reference_after_s = float(before[-1]) if len(before) else -math.inf
    for name, value in s.parameters.items():
        pipeline.set_autopilot_parameter(name, value)
    others = _judge_compasses(s, pipeline, reference_after_s)
    s = _chosen_compass(s, others, result)
    pushed = pipeline.push_batch(
        *_batch_arrays(s),
        s.time_wrap_s,
        reference_after_s,
        s.mag_repeats,
        (s.gps_t_s, s.gps_velocity),
        progress=progress,
    )
    result.outputs, result.compass = pushed.outputs, pushed.compass
    _collect_compasses(s, others, result)
    counters.received += len(s.imu_t_s)
    if len(s.imu_t_s):
        result.first_sample_s, result.last_sample_s = float(s.imu_t_s[0]), float(s.imu_t_s[-1])
        result.sample_times_s = s.imu_t_s.tolist()
    result.autopilot = [
        AutopilotAttitude(t, tuple(q)) for t, q in zip(s.attitude_t_s.tolist(), s.attitude_q.tolist(), strict=True)
    ]
    return result


def _collect_compasses(s: LogStreams, others: list[JudgedCompass], result: Replayed) -> None:
    """:attr:`Replayed.compasses`: the replayed magnetometer as the pipeline judged it, and the others."""
    if s.compasses is not None:
        used = JudgedCompass(s.compasses.used, result.compass, result.pipeline.compass)
        result.compasses = sorted([*(j for j in others if j.instance != used.instance), used], key=_instance)
        unused = {j.instance: s.unused_by_autopilot(j.instance) for j in result.compasses}
        result.unused_compasses = {k: f"{why[0]} {why[1]:g}" for k, why in unused.items() if why is not None}


def _instance(judged: JudgedCompass) -> int:
    return judged.instance


def _batch_arrays(s: LogStreams) -> tuple[Array, Array, Array, Array, NDArray[np.bool_]]:
    """:meth:`AttitudePipeline.push_batch`'s sample arrays: each IMU row with the magnetometer reading it carries."""
    carried = s.carried_mag()
    mag = np.full((len(carried), 3), np.nan)
    mag[carried >= 0] = s.mag_uT[carried[carried >= 0]]
    return s.imu_t_s, s.acc_mps2, s.gyr_radps, mag, carried >= 0


def _judge_compasses(s: LogStreams, pipeline: AttitudePipeline, reference_after_s: float) -> list[JudgedCompass]:
    """Every magnetometer of ``s`` but the replayed one, judged by a compass monitor of its own over the same
    IMU (:meth:`AttitudePipeline.push_batch` without attitudes: the replay's front end and reference); all of
    them where the log does not say which one the autopilot used (the most consistent is replayed)."""
    if s.compasses is None or not pipeline.compass.settings.enabled:
        return []
    judged = []
    for instance in s.compasses.readings:
        if instance == s.compasses.used and s.compasses.why is not None:
            continue  # the pipeline judges it
        config = pipeline.config if instance == s.compasses.used else pipeline.config.for_another_compass()
        judge = AttitudePipeline(config)
        judge.magref.level = logging.DEBUG  # its field is its own verdict's business: the log says the replayed one's
        if pipeline.mag_ref_ned_uT is not None:  # else each measures its own field: its turn is judged all the same
            known = pipeline.frontend.expected_field_uT is not None
            judge.set_magnetic_reference(pipeline.mag_ref_ned_uT, known, pipeline.magref.measured)
        streams = s.with_compass(instance, s.compasses.why)
        arrays = _batch_arrays(streams)
        pushed = judge.push_batch(*arrays, s.time_wrap_s, reference_after_s, streams.mag_repeats, attitudes=False)
        judged.append(JudgedCompass(instance, pushed.compass, judge.compass))
    return judged


def _chosen_compass(s: LogStreams, judged: list[JudgedCompass], result: Replayed) -> LogStreams:
    """``s`` with the magnetometer to replay: the one the log names (``--mag``, the autopilot's), else the most
    consistent of those judged (fewest warnings, then vouched for, then the lowest instance); said in
    :attr:`Replayed.compass_used`, and in :attr:`Replayed.unused_compass` whether the autopilot used it."""
    if s.compasses is None:
        result.compass_used = "the only one"
    else:
        if s.compasses.why is None and judged:
            best = min(judged, key=lambda j: (j.warnings, not j.monitor.confirmed, j.instance))
            s = s.with_compass(best.instance, f"the most consistent of {len(judged)}")
            if best.instance != 0:
                log.info("replaying magnetometer %d, the most consistent of %d", best.instance, len(judged))
        assert s.compasses is not None
        result.compass_used = f"{s.compasses.used}: {s.compasses.why or 'the first'}"
    result.unused_compass = s.unused_compass()
    return s
