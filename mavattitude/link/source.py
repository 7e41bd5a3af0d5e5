"""Message sources: where the service, ``replay`` and ``calibrate`` read the vehicle's data from.

A :class:`MessageSource` hands out what arrived as ``(t_rx, sender, item)`` triples (:data:`Received`):
``t_rx`` is ``time.monotonic()`` at arrival for a live link and the log's own receive time for a log,
``sender`` the MAVLink ``(system, component)``, and ``item`` one decoded event:

- :class:`~mavattitude.sensors.units.ImuSample`: an IMU reading in SI units, the vehicle's sample time;
- :class:`PositionFix`: a vehicle position (for the World Magnetic Model), with the log's date if known, and
  from GPS_RAW_INT the receiver's velocity;
- :class:`~mavattitude.estimation.velocity.GpsVelocity`: a receiver's velocity on its own (DataFlash GPS, ULog);
- :class:`AutopilotAttitude`: the autopilot's own attitude estimate, to compare with;
- :class:`AutopilotParameter`: one of the autopilot's parameters (PARAM_VALUE; its level trim is used);
- :class:`Heartbeat`: whether the sender is an autopilot (what the dispatcher locks onto);
- :class:`Undecodable`: an input message whose fields could not be turned into a sample;
- any other MAVLink message, as pymavlink decoded it (COMMAND_ACK, …), for the service to read.

A live link (:class:`MavlinkSource` over a :class:`~mavattitude.link.connection.MavlinkLink`, or over
the in-memory :class:`~mavattitude.link.memory.MemoryLink` in tests) and the log sources (``.tlog``,
DataFlash ``.bin``, ULog ``.ulg``: :func:`mavattitude.link.logs.open_log`) all produce the same items, so
:class:`~mavattitude.dispatch.Dispatcher` routes them with one set of rules.
"""

from __future__ import annotations

import datetime as dt
import math
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any, Protocol

from mavattitude.config import Config
from mavattitude.errors import SensorError
from mavattitude.estimation.conventions import quat_from_euler_parts
from mavattitude.link.connection import DirectFrame, MavlinkLink, Message, Sender
from mavattitude.link.mavlink2 import mavlink2, message_id
from mavattitude.sensors import units

Received = tuple[float, Sender, Any]  # (t_rx, sender, item): see the module docstring

ATTITUDE_MESSAGES = ("ATTITUDE", "ATTITUDE_QUATERNION")  # the autopilot's own attitude, as Euler angles or q


# the unit profile of the messages an autopilot firmware sends, by its HEARTBEAT's autopilot field
FIRMWARE_PROFILES = {mavlink2.MAV_AUTOPILOT_ARDUPILOTMEGA: "ardupilot", mavlink2.MAV_AUTOPILOT_PX4: "px4"}


@dataclass(frozen=True, slots=True)
class Heartbeat:
    """A HEARTBEAT; ``autopilot`` when it comes from a flight controller, ``profile`` the unit profile its
    firmware's messages follow (:data:`FIRMWARE_PROFILES`; None: another firmware, or not said)."""

    autopilot: bool
    profile: str | None = None


def locks_on(item: Any, sender: Sender, system_id: int) -> bool:
    """Whether a dispatcher not yet locked locks onto ``sender`` on receiving ``item``: the first autopilot
    HEARTBEAT, from ``system_id`` unless it is 0 (any system)."""
    return type(item) is Heartbeat and item.autopilot and system_id in (0, sender[0])


@dataclass(frozen=True, slots=True)
class PositionFix:
    """A vehicle position; ``date`` is the vehicle's GPS date or the day a log was recorded; ``None``: unknown
    (the companion's clock is the fallback)."""

    position: units.Position
    date: dt.date | None = None
    velocity: units.GpsVelocity | None = None  # the receiver's own (GPS_RAW_INT), never a fused one


@dataclass(frozen=True, slots=True)
class AutopilotAttitude:
    """The autopilot's attitude at ``time_s`` (vehicle clock): ``q`` = [w, x, y, z] body FRD → NED."""

    time_s: float
    q: tuple[float, float, float, float]


@dataclass(frozen=True, slots=True)
class AutopilotParameter:
    """One of the autopilot's parameters as it said it (PARAM_VALUE, a DataFlash PARM record)."""

    name: str
    value: float


@dataclass(frozen=True, slots=True)
class Undecodable:
    """An input message that could not be decoded (implausible units, a message the profile does not read)."""

    error: SensorError


@dataclass(frozen=True, slots=True)
class Broken:
    """A message whose decoding raised what no message should (a bug met on one odd message): dropped and
    reported as an internal error, the link going on."""

    error: Exception


class MessageSource(Protocol):
    """What the dispatcher reads: decoded items from one link or log.

    ``vehicle`` is the sender of a log written by the autopilot itself (DataFlash, ULog: there is no
    other), so nothing needs locking onto; ``None`` where the autopilot must be found by its HEARTBEAT.
    ``finished`` turns true when a log has been read to its end (a live link never finishes).
    """

    name: str
    vehicle: Sender | None
    finished: bool

    def recv(self, timeout_s: float) -> list[Received]:
        """What arrived within ``timeout_s`` (a log returns its next chunk at once)."""
        ...


def euler_attitude(time_s: float, roll_rad: float, pitch_rad: float, yaw_rad: float) -> AutopilotAttitude:
    """An autopilot attitude given as ZYX Euler angles (MAVLink ATTITUDE, DataFlash ATT); an angle that is not
    finite gives a NaN quaternion, which the cross-check counts as no attitude."""
    if not math.isfinite(roll_rad + pitch_rad + yaw_rad):
        return AutopilotAttitude(time_s, (math.nan,) * 4)
    return AutopilotAttitude(time_s, quat_from_euler_parts(roll_rad, pitch_rad, yaw_rad))


@dataclass
class MavlinkDecoder:
    """MAVLink message → item: the input message through its unit profile, positions, the autopilot's
    attitude and heartbeats decoded; anything else handed on as it is.

    A position's date (for the World Magnetic Model) is the vehicle's GPS date when it has sent one
    (SYSTEM_TIME, or a GPS_RAW_INT stamped in Unix time), else ``date_of(msg)``, the recording date of a
    message in a log, else ``None`` (live: the companion's clock, the last resort).
    """

    message: str
    profile: units.UnitProfile
    date_of: Callable[[Message], dt.date | None] | None = None
    _routes: dict[str, Callable[[Message], Any]] = field(init=False, repr=False)
    vehicle_date: dt.date | None = field(default=None, init=False)
    direct: DirectFrame = field(init=False, repr=False)  # the input message, decoded from its frame by the link

    def __post_init__(self) -> None:
        self._routes = {
            self.message: self._imu,
            "HEARTBEAT": _heartbeat,
            **dict(zip(ATTITUDE_MESSAGES, (_attitude, _attitude_quaternion), strict=True)),
            **dict.fromkeys(units.POSITION_MESSAGES, self._position),
            "SYSTEM_TIME": self._system_time,
            "PARAM_VALUE": _parameter,
        }
        frame = mavlink2.mavlink_map[message_id(self.message)]
        at = dict(zip(frame.fieldnames, frame.orders, strict=True))  # each field's place in the unpacked payload
        self.direct = DirectFrame(frame.id, units.wire_decoder(self.message, self.profile, at), Undecodable, Broken)

    @classmethod
    def from_config(cls, config: Config, date_of: Callable[[Message], dt.date | None] | None = None) -> MavlinkDecoder:
        """The config's input message through its unit profile (``input.custom`` scales for ``custom``)."""
        return cls(config.input.message, units.get_profile(config.input.profile, config.input.custom), date_of)

    @property
    def types(self) -> frozenset[str]:
        """The message types this decoder turns into data (what a log reader needs to read)."""
        return frozenset(self._routes)

    def __call__(self, msg: Message) -> Any:
        route = self._routes.get(msg.get_type())
        if route is None:
            return msg
        try:
            return route(msg)
        except Exception as exc:  # a bug met on one odd message: that message is lost, not the service
            return Broken(exc)

    def _imu(self, msg: Message) -> Any:
        try:
            return units.decode(msg, self.profile)
        except SensorError as exc:
            return Undecodable(exc)

    def _system_time(self, msg: Message) -> None:
        self.vehicle_date = units.decode_utc_date(msg) or self.vehicle_date

    def _position(self, msg: Message) -> PositionFix | units.GpsVelocity | None:
        self.vehicle_date = units.decode_utc_date(msg) or self.vehicle_date
        position = units.decode_position(msg)
        velocity = units.decode_gps_velocity(msg) if msg.get_type() == "GPS_RAW_INT" else None
        if position is None:
            return velocity
        if self.vehicle_date is not None:
            return PositionFix(position, self.vehicle_date, velocity)
        return PositionFix(position, self.date_of(msg) if self.date_of is not None else None, velocity)


def _heartbeat(msg: Message) -> Heartbeat:
    return Heartbeat(MavlinkLink.is_autopilot_heartbeat(msg), FIRMWARE_PROFILES.get(msg.autopilot))


def _parameter(msg: Message) -> AutopilotParameter:
    return AutopilotParameter(msg.param_id, float(msg.param_value))


def _attitude(msg: Message) -> AutopilotAttitude:
    return euler_attitude(msg.time_boot_ms * 1e-3, msg.roll, msg.pitch, msg.yaw)


def _attitude_quaternion(msg: Message) -> AutopilotAttitude:
    return AutopilotAttitude(msg.time_boot_ms * 1e-3, (msg.q1, msg.q2, msg.q3, msg.q4))


class MavlinkSource:
    """The live link as a message source: :meth:`MavlinkLink.recv_items` through a :class:`MavlinkDecoder`."""

    vehicle: Sender | None = None
    finished = False

    def __init__(self, link: MavlinkLink, decoder: MavlinkDecoder) -> None:
        self.link = link
        self.decoder = decoder
        self.name = link.endpoint.address

    def recv(self, timeout_s: float) -> list[Received]:
        return self.link.recv_items(timeout_s, self.decoder, self.decoder.direct)
