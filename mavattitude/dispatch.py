"""The one dispatcher between a message source and the attitude pipeline: the service's rules, and replay's.

:class:`Dispatcher` takes what a :class:`~mavattitude.link.source.MessageSource` received and

- locks onto the autopilot: ``system_id`` (``link.vehicle_system_id``), or with 0 the first autopilot
  HEARTBEAT; that ``(system, component)`` is the only sender listened to, everything else (and
  everything before the lock) is ignored and counted. A log written by the autopilot itself names its
  vehicle (``source.vehicle``) and is locked onto from the start;
- routes the vehicle's items: IMU samples into the pipeline (its outputs to the listener), positions to
  the pipeline's magnetic reference (``wants_position``: ``reference.magnetic: auto``), the GPS receiver's
  velocities to the pipeline (the fused filter's acceleration), the autopilot's parameters to the pipeline
  (its level trim) and then the listener, the autopilot's attitude and any other message to the listener;
  an undecodable input message, a pipeline failure or a message whose decoding failed
  (:class:`~mavattitude.link.source.Broken`, from any sender) is counted as a reject and told to the
  listener, and the next one goes on.

The service (:mod:`mavattitude.service`) and ``replay`` are two listeners on this one dispatcher, so a
log replayed offline and the same messages arriving live give the same attitudes.
"""

from __future__ import annotations

import logging
from collections.abc import Iterable
from dataclasses import dataclass, field
from typing import Any, Protocol

import numpy as np
from numpy.typing import NDArray

from mavattitude.errors import MavAttitudeError
from mavattitude.link.source import (
    AutopilotAttitude,
    AutopilotParameter,
    Broken,
    Heartbeat,
    PositionFix,
    Received,
    Sender,
    Undecodable,
    locks_on,
)
from mavattitude.pipeline import Pushed
from mavattitude.sensors.units import GpsVelocity, ImuSample

log = logging.getLogger(__name__)

DISPATCH_REJECTS = ("decode", "pipeline_error", "internal_error")


@dataclass
class DispatchCounters:
    """What the dispatcher saw: the service's counters extend these."""

    received: int = 0  # input (IMU) messages from the autopilot
    ignored: int = 0  # items from other senders, or before locking on
    #: the senders of an autopilot HEARTBEAT other than the vehicle followed (a swarm's, or a second vehicle's log)
    other_autopilots: set[Sender] = field(default_factory=set)
    rejected: dict[str, int] = field(default_factory=lambda: dict.fromkeys(DISPATCH_REJECTS, 0))
    positions: int = 0  # vehicle positions handed to the pipeline (magnetic reference ``auto``)


class SampleSink(Protocol):
    """Where the vehicle's samples and positions go: the :class:`AttitudePipeline` (or what only collects)."""

    mag_ref_ned_uT: Any

    def push(self, sample: ImuSample) -> Pushed: ...

    def set_position(self, lat_deg: float, lon_deg: float, alt_m: float, when: Any = None) -> bool: ...

    def set_velocity(self, velocity: GpsVelocity) -> None: ...

    def set_autopilot_parameter(self, name: str, value: float) -> bool: ...


class Listener(Protocol):
    """What the dispatcher tells its owner (the service, replay)."""

    def on_lock(self, vehicle: Sender) -> None:
        """Locked onto the autopilot ``vehicle``."""

    def on_input(self, sample: ImuSample, t_rx: float) -> None:
        """An input sample from the vehicle, about to enter the pipeline."""

    def on_outputs(self, pushed: Pushed, t_rx: float) -> None:
        """What the pipeline made of the last input sample, when it made anything (an output, a reject, a
        compass verdict): most samples complete no tick, and the listener is not called for them."""

    def on_autopilot_attitude(self, attitude: AutopilotAttitude, t_rx: float) -> None:
        """The autopilot's own attitude estimate."""

    def on_parameter(self, parameter: AutopilotParameter) -> None:
        """One of the autopilot's parameters, after the pipeline took it."""

    def on_message(self, msg: Any, t_rx: float) -> None:
        """Any other MAVLink message from the vehicle (COMMAND_ACK, …)."""

    def on_reject(self, reason: str, exc: BaseException) -> None:
        """An input dropped: ``reason`` is one of :data:`DISPATCH_REJECTS` (counted already)."""


class Dispatcher:
    """Lock-on and routing; see the module docstring. ``handle`` one received item at a time."""

    def __init__(
        self,
        pipeline: SampleSink,
        listener: Listener,
        *,
        system_id: int = 0,
        vehicle: Sender | None = None,
        counters: DispatchCounters | None = None,
        wants_position: bool = False,
    ) -> None:
        self.pipeline = pipeline
        self.listener = listener
        self.system_id = system_id
        self.counters = counters if counters is not None else DispatchCounters()
        self.wants_position = wants_position
        self.vehicle: Sender | None = None
        self.vehicle_profile: str | None = None  # the unit profile of its firmware, from the HEARTBEAT locked on
        self.vehicle_heard_s: float | None = None  # the arrival (t_rx) of its latest HEARTBEAT
        if vehicle is not None:
            self._lock(vehicle)

    def handle(self, received: Received) -> None:
        t_rx, sender, item = received
        kind = type(item)
        if kind is Broken:  # whoever sent it: a bug is reported
            self._reject("internal_error", item.error)
            return
        if sender != self.vehicle:
            if self.vehicle is None and locks_on(item, sender, self.system_id):
                self.vehicle_profile, self.vehicle_heard_s = item.profile, t_rx
                self._lock(sender)
            else:
                self.counters.ignored += 1
                if kind is Heartbeat and item.autopilot:
                    self.counters.other_autopilots.add(sender)
            return
        if kind is ImuSample:
            self._on_sample(item, t_rx)
        elif kind is AutopilotAttitude:
            self.listener.on_autopilot_attitude(item, t_rx)
        elif kind is PositionFix:
            if self.wants_position:
                self._on_position(item)
            if item.velocity is not None:
                self.pipeline.set_velocity(item.velocity)
        elif kind is GpsVelocity:
            self.pipeline.set_velocity(item)
        elif kind is AutopilotParameter:
            self.pipeline.set_autopilot_parameter(item.name, item.value)
            self.listener.on_parameter(item)
        elif kind is Undecodable:
            self.undecodable(item.error)
        elif kind is Heartbeat:
            self.vehicle_heard_s = t_rx
        elif item is not None:
            self.listener.on_message(item, t_rx)

    def follow(self, senders: NDArray[np.int64], heartbeats: Iterable[tuple[int, Received]]) -> NDArray[np.bool_]:
        """:meth:`handle`'s lock-on and sender rule for a log read as arrays: which of its records it takes.

        ``senders`` holds every record's sender (``system << 8 | component``) in log order, ``heartbeats``
        the HEARTBEAT items with their record's place, in order. They go through :meth:`handle` until it
        locks; the records after the one it locked on, from the vehicle, are taken, and the others counted
        ignored, as :meth:`handle` counts them (the locking heartbeat excepted), other autopilots' HEARTBEATs among
        them kept in ``other_autopilots`` as :meth:`handle` keeps them.
        """
        locked_at, fed = -1, 0
        for index, received in heartbeats:
            if self.vehicle is None:
                self.handle(received)
                locked_at, fed = index, fed + 1
            elif received[1] != self.vehicle and received[2].autopilot:  # (counted ignored below)
                self.counters.other_autopilots.add(received[1])
        if self.vehicle is None:
            taken = np.zeros(len(senders), dtype=bool)
        else:
            taken = senders == (self.vehicle[0] << 8 | self.vehicle[1])
            taken[: locked_at + 1] = False
        self.counters.ignored += len(senders) - int(np.count_nonzero(taken)) - fed
        return taken

    def undecodable(self, error: BaseException, count: int = 1) -> None:
        """``count`` input messages from the vehicle that could not be decoded (``error`` says why)."""
        self.counters.received += count
        self._reject("decode", error, count)

    def _lock(self, vehicle: Sender) -> None:
        self.vehicle = vehicle
        self.listener.on_lock(vehicle)

    def _on_sample(self, sample: ImuSample, t_rx: float) -> None:
        self.counters.received += 1
        self.listener.on_input(sample, t_rx)
        try:
            pushed = self.pipeline.push(sample)
        except MavAttitudeError as exc:  # the pipeline counts what it refuses; anything it raises is kept alive
            self._reject("pipeline_error", exc)
            return
        except Exception as exc:  # a bug below us: the sample is dropped, the listener decides what to say
            self._reject("internal_error", exc)
            return
        if pushed:
            self.listener.on_outputs(pushed, t_rx)

    def _on_position(self, fix: PositionFix) -> None:
        p = fix.position
        self.counters.positions += 1
        self.pipeline.set_position(p.lat_deg, p.lon_deg, p.alt_m, fix.date)  # a new reference is logged there

    def _reject(self, reason: str, exc: BaseException, count: int = 1) -> None:
        self.counters.rejected[reason] = self.counters.rejected.get(reason, 0) + count
        self.listener.on_reject(reason, exc)
