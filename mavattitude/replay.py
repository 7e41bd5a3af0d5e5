"""Replay: the service's pipeline and dispatcher over a finite message source, as fast as the CPU goes.

:func:`replay` reads a log source (:mod:`mavattitude.link.logs`) to its end through the same
:class:`~mavattitude.dispatch.Dispatcher` as the live service (lock-on, routing, the pipeline), keeping every
attitude output and the autopilot's own attitudes; no I/O of its own beyond the source.
"""

from __future__ import annotations

import logging
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from mavattitude.config import Config
from mavattitude.dispatch import DispatchCounters, Dispatcher
from mavattitude.link.source import AutopilotAttitude, MessageSource, Sender
from mavattitude.pipeline import AttitudeOutput, AttitudePipeline
from mavattitude.sensors.units import ImuSample

log = logging.getLogger(__name__)


@dataclass
class Replayed:
    """What a replay produced: every output, the autopilot's attitudes, and the counters."""

    outputs: list[AttitudeOutput]
    autopilot: list[AutopilotAttitude]
    counters: DispatchCounters
    pipeline: AttitudePipeline
    vehicle: Sender | None
    first_sample_s: float = float("nan")
    last_sample_s: float = float("nan")
    internal_errors: list[BaseException] = field(default_factory=list)

    def output_array(self) -> np.ndarray:
        """Rows ``t_s, qw, qx, qy, qz`` of every output."""
        if not self.outputs:
            return np.empty((0, 5))
        return np.array([(o.time_s, *o.q.tolist()) for o in self.outputs])

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

    def on_outputs(self, outputs: list[AttitudeOutput], t_rx: float) -> None:
        self.result.outputs += outputs

    def on_autopilot_attitude(self, attitude: AutopilotAttitude, t_rx: float) -> None:
        self.result.autopilot.append(attitude)

    def on_message(self, msg: Any, t_rx: float) -> None:
        """Other messages mean nothing offline."""

    def on_reject(self, reason: str, exc: BaseException) -> None:
        if reason == "internal_error":
            self.result.internal_errors.append(exc)
        log.debug("rejected (%s): %s", reason, exc)


def replay(source: MessageSource, config: Config, progress: Callable[[MessageSource], None] | None = None) -> Replayed:
    """Run ``source`` to its end through the service's dispatcher and pipeline."""
    pipeline = AttitudePipeline(config)
    counters = DispatchCounters()
    result = Replayed([], [], counters, pipeline, None)
    dispatcher = Dispatcher(
        pipeline, _Collector(result), system_id=config.link.vehicle_system_id, vehicle=source.vehicle, counters=counters
    )
    handle = dispatcher.handle
    while not source.finished:
        for received in source.recv(0.0):
            handle(received)
        if progress is not None:
            progress(source)
    if result.internal_errors:  # offline, a bug is reported, not served around
        raise result.internal_errors[0]
    return result
