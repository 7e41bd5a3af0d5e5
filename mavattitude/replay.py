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
``at_once=False``, the samples go into the pipeline one by one as they would live.
"""

from __future__ import annotations

import logging
import math
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from mavattitude.config import Config
from mavattitude.dispatch import DispatchCounters, Dispatcher
from mavattitude.estimation.compass import CompassEvent
from mavattitude.link.logs import LogSource
from mavattitude.link.logstreams import LogStreams
from mavattitude.link.source import AutopilotAttitude, MessageSource, Sender
from mavattitude.pipeline import AttitudeOutput, AttitudePipeline, Pushed
from mavattitude.sensors.frontend import median_rate_hz
from mavattitude.sensors.magref import distance_km
from mavattitude.sensors.units import ImuSample

log = logging.getLogger(__name__)


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


class _Collector:
    """The dispatcher's listener in replay: keeps what the service would have sent."""

    def __init__(self, result: Replayed) -> None:
        self.result = result

    def on_lock(self, vehicle: Sender) -> None:
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
    """Run ``source`` to its end through the service's dispatcher and pipeline (see the module docstring)."""
    pipeline = AttitudePipeline(config)
    result = Replayed([], [], DispatchCounters(), pipeline, None)
    if not at_once:
        return _replay_items(source, result, progress)
    streams = source.streams_for(_dispatcher(source, None, result))  # the dispatcher's rules choose the rows
    if result.vehicle is not None and _one_reference(streams, pipeline):
        return _replay_arrays(streams, result, result.vehicle)
    from mavattitude.link.logstreams import StreamSource  # the vehicle's streams, one by one

    c = result.counters
    counters = DispatchCounters(c.rejected["decode"], c.ignored, dict(c.rejected))  # what reading the log counted
    result = Replayed([], [], counters, AttitudePipeline(config), None)
    return _replay_items(StreamSource(source.name, streams), result, progress)


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


def _replay_arrays(s: LogStreams, result: Replayed, vehicle: Sender) -> Replayed:
    """The arrays of a log through :meth:`AttitudePipeline.push_batch`, as the items would go one by one."""
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
    carried = s.carried_mag()
    mag = np.full((len(carried), 3), np.nan)
    mag[carried >= 0] = s.mag_uT[carried[carried >= 0]]
    pushed = pipeline.push_batch(
        s.imu_t_s,
        s.acc_mps2,
        s.gyr_radps,
        mag,
        carried >= 0,
        s.time_wrap_s,
        reference_after_s,
        s.mag_repeats,
        (s.gps_t_s, s.gps_velocity),
    )
    result.outputs, result.compass = pushed.outputs, pushed.compass
    counters.received += len(s.imu_t_s)
    if len(s.imu_t_s):
        result.first_sample_s, result.last_sample_s = float(s.imu_t_s[0]), float(s.imu_t_s[-1])
        result.sample_times_s = s.imu_t_s.tolist()
    result.autopilot = [
        AutopilotAttitude(t, tuple(q)) for t, q in zip(s.attitude_t_s.tolist(), s.attitude_q.tolist(), strict=True)
    ]
    counters.autopilot_attitudes = len(result.autopilot)
    return result
