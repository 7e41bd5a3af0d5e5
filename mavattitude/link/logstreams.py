"""A log's sensor streams as arrays, and those streams handed out as a live link's items: the types every log
reader (:mod:`.dataflash`, :mod:`.ulog`, :mod:`.tlog`) and the format table (:mod:`.logs`) share.

A reader turns its file into :class:`LogStreams`: arrays in SI units on the vehicle clock, converted by the
format's units module; :class:`StreamSource` hands them out as the items a live link would give, in time
order:

- one :class:`~mavattitude.sensors.units.ImuSample` per IMU record, carrying the newest magnetometer
  reading logged at or before its time if that reading is new since the previous sample, else none (the
  front end holds the last one, as it does for a live IMU message without a new magnetometer). A slower
  magnetometer is thus held, never interpolated towards a reading that comes later; an all-zero reading
  is no reading, as in MAVLink's integer messages;
- the autopilot's attitude and the positions (with the log's date, for the World Magnetic Model);
- the GPS receiver's velocities (:class:`~mavattitude.estimation.velocity.GpsVelocity`), for the fused filter;
- the autopilot's parameters (:class:`~mavattitude.link.source.AutopilotParameter`: its level trim, its
  declination, whether it uses a compass), each record at its time, as the live service hears them: a
  declination set at the first GPS fix comes when the fix does, not before the field measured without one.
"""

from __future__ import annotations

import datetime as dt
import functools
import logging
import re
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass, field, replace
from typing import Protocol

import numpy as np
from numpy.typing import NDArray

from mavattitude.errors import DataFileError
from mavattitude.estimation.conventions import Array
from mavattitude.link.source import AutopilotAttitude, AutopilotParameter, PositionFix, Received, Sender
from mavattitude.sensors.units import GpsVelocity, ImuSample, Position

log = logging.getLogger(__name__)

#: What a vehicle without a magnetometer gets, said once where that is found (a log, the live stream).
TILT_ONLY = "roll and pitch from the accelerometer (and the gyroscope with fused), heading unknown (yaw NaN)"

#: The sender of every item from a log the autopilot wrote itself (DataFlash, ULog): it holds one vehicle.
LOG_VEHICLE: Sender = (1, 1)
CHUNK_ITEMS = 8192  # items per recv(): large enough to amortise the call, small enough for progress


_STRUCT_TO_NUMPY = {
    "b": "i1", "B": "u1", "h": "i2", "H": "u2", "i": "i4", "I": "u4", "q": "i8", "Q": "u8",
    "f": "f4", "d": "f8", "e": "f2",
}  # fmt: skip


def struct_dtype(names: Sequence[str], struct_format: str) -> np.dtype:
    """The numpy record type of a little-endian ``struct`` layout (``<QBff4f16s``: arrays and strings as one
    field each), its fields named ``names``: how DataFlash and MAVLink records are unpacked as columns."""
    fields: list[tuple] = []
    codes = re.findall(r"(\d*)([a-zA-Z])", struct_format.lstrip("<"))
    for name, (count, code) in zip(names, codes, strict=True):
        if code == "s":
            fields.append((name, f"S{count}"))
        elif count and int(count) > 1:
            fields.append((name, "<" + _STRUCT_TO_NUMPY[code], (int(count),)))
        else:
            fields.append((name, "<" + _STRUCT_TO_NUMPY[code]))
    return np.dtype(fields)


class Follower(Protocol):
    """What chooses a log's records and counts the rest: the dispatcher's lock-on and sender rule, as arrays
    (:class:`~mavattitude.dispatch.Dispatcher`); the log layer knows only these two calls."""

    def follow(self, senders: NDArray[np.int64], heartbeats: Iterable[tuple[int, Received]]) -> NDArray[np.bool_]:
        """Which records (``senders``: ``system << 8 | component`` each) are the followed vehicle's."""
        ...

    def undecodable(self, error: BaseException, count: int = 1) -> None:
        """``count`` input messages of the vehicle that could not be decoded."""
        ...


@dataclass(frozen=True)
class Compasses:
    """Every magnetometer a log holds, and which of them :class:`LogStreams` replays and why."""

    readings: dict[int, tuple[Array, Array]]  # instance → (times s, field µT body frame), each in time order
    used: int  # the instance in LogStreams.mag_t_s / mag_uT
    #: why that one ("--mag 1", "the autopilot's: COMPASS_USE 1, COMPASS_USE2 0"); None: the log does not say
    why: str | None = None
    #: those the autopilot has disabled, where its parameters number them otherwise than ArduPilot's COMPASS_USE…
    #: do (PX4's CAL_MAGn_EN, matched by device id, 0): instance → the parameter, "CAL_MAG0_EN"
    disabled: Mapping[int, str] = field(default_factory=dict)


def no_such_instance(path: object, records: str, kind: str, option: str, present: Iterable[int]) -> DataFileError:
    """``--imu``/``--mag`` asked for an instance the log lacks, where it has others: the refusal naming them (a
    typo replayed with another sensor, or none, would be silently not what was asked)."""
    has = sorted(present)
    listed = ", ".join(map(str, has))
    return DataFileError(f"{path}: no {records} records; the log has {kind} instance {listed}: {option} {has[0]}")


def compass_use_parameter(instance: int) -> str:
    """ArduPilot's parameter that says whether it uses compass ``instance`` (0-based: COMPASS_USE, COMPASS_USE2, …)."""
    return f"COMPASS_USE{instance + 1 if instance else ''}"


def autopilot_compass(params: Mapping[str, float], instances: Sequence[int]) -> tuple[int, str] | None:
    """The compass ArduPilot uses for heading, from its parameters, and the parameters that say so; ``None``
    when none of them is in the log. Its primary (``COMPASS_PRIMARY``, 0-based, older firmware) if that one is
    used, else the first instance whose ``COMPASS_USE``/``USE2``/``USE3`` is 1 (an absent one defaults to 1)."""
    use_names = {k: compass_use_parameter(k) for k in instances}
    said = [name for name in ("COMPASS_PRIMARY", *use_names.values()) if name in params]
    if not said:
        return None
    why = "the autopilot's: " + ", ".join(f"{name} {params[name]:g}" for name in said)
    used = [k for k in sorted(instances) if params.get(use_names[k], 1.0) != 0.0]
    primary = int(params.get("COMPASS_PRIMARY", -1))
    if primary in used:
        return primary, why
    return (used[0], why) if used else None


@dataclass
class LogStreams:
    """A log's sensor streams, SI units, on the vehicle clock (s); rows in time order within each stream."""

    imu_t_s: Array  # (n,)
    acc_mps2: Array  # (n, 3) board frame
    gyr_radps: Array  # (n, 3)
    mag_t_s: Array  # (m,)
    mag_uT: Array  # (m, 3)
    attitude_t_s: Array  # (k,) the autopilot's attitude
    attitude_q: Array  # (k, 4) [w, x, y, z] body → NED
    position_t_s: Array  # (p,)
    position: Array  # (p, 3) latitude °, longitude °, altitude m AMSL
    date: dt.date | None = None  # the day the log was recorded (GPS time), for the World Magnetic Model
    time_wrap_s: float | None = None  # the IMU time field's wrap period (old DataFlash: uint32 ms)
    damage: str | None = None  # where the file is truncated or damaged, if it is
    #: the magnetometer row each IMU sample carries (-1: none), where the source knows it (a telemetry log's
    #: messages carry their own); otherwise the newest reading at or before the sample, if new (mag_for_imu)
    imu_mag_index: NDArray[np.int64] | None = None
    #: the IMU messages repeat the newest magnetometer reading (:attr:`ImuSample.mag_repeats`: a telemetry log's
    #: integer messages); a DataFlash or ULog magnetometer stream has each reading once
    mag_repeats: bool = False
    #: the GPS receiver's own velocities (never the autopilot's fused one), each at the vehicle time it is handed
    #: in at (before the IMU sample at or after it), in time order
    gps_t_s: Array = field(default_factory=lambda: np.empty(0))
    gps_velocity: list[GpsVelocity] = field(default_factory=list)
    compasses: Compasses | None = None  # every magnetometer, where the log holds several
    #: the autopilot's parameters, each at its last value in the log (replay at once uses them from the start)
    parameters: dict[str, float] = field(default_factory=dict)
    #: every parameter record, in time order, at the vehicle time it is handed in at (before the IMU sample at or
    #: after it): what replay item by item takes (:meth:`set_parameters`)
    parameter_t_s: Array = field(default_factory=lambda: np.empty(0))
    parameter_records: list[tuple[str, float]] = field(default_factory=list)
    #: the autopilot's number (0-based) of the compass in mag_uT, where it numbers them as its parameters do
    #: (ArduPilot's COMPASS_USE, COMPASS_USE2, …); None: a ULog's (PX4's field has no such parameter)
    mag_instance: int | None = None

    def with_compass(self, instance: int, why: str | None) -> LogStreams:
        """These streams with the magnetometer ``instance`` of :attr:`compasses` replayed (and ``why``)."""
        assert self.compasses is not None
        compasses = replace(self.compasses, used=instance, why=why)
        if instance == self.compasses.used:  # its streams as they are (a caller may have changed them)
            return replace(self, compasses=compasses, mag_instance=instance)
        mag_t, mag = self.compasses.readings[instance]
        return replace(self, mag_t_s=mag_t, mag_uT=mag, imu_mag_index=None, compasses=compasses, mag_instance=instance)

    def set_parameters(self, time_s: Array, names: Sequence[str], values: Sequence[float]) -> None:
        """The log's parameter records in log order, at vehicle times ``time_s``: each at its last value in
        :attr:`parameters`, every record in time order in :attr:`parameter_records`."""
        order = np.argsort(time_s, kind="stable").tolist()
        self.parameter_t_s = np.asarray(time_s, dtype=float)[order]
        self.parameter_records = [(names[i], values[i]) for i in order]
        self.parameters = dict(zip(names, values, strict=True))  # in log order: the last record's value stays

    def unused_compass(self) -> tuple[int, str, float] | None:
        """``(instance, parameter, value)`` when the log's parameters say the autopilot does not use the compass
        replayed (its ``COMPASS_USE…`` is 0), else ``None``: the live service's question, asked of the log."""
        if self.mag_instance is None:
            return None
        unused = self.unused_by_autopilot(self.mag_instance)
        return None if unused is None else (self.mag_instance, *unused)

    def unused_by_autopilot(self, instance: int) -> tuple[str, float] | None:
        """The parameter and its value by which the autopilot says it does not use compass ``instance``
        (``COMPASS_USE2`` 0, PX4's ``CAL_MAG0_EN`` 0), else ``None``."""
        if self.compasses is not None and instance in self.compasses.disabled:
            return self.compasses.disabled[instance], 0.0
        if self.mag_instance is None:  # not numbered as ArduPilot's parameters number them
            return None
        name = compass_use_parameter(instance)
        return (name, 0.0) if self.parameters.get(name) == 0.0 else None

    def carried_mag(self) -> NDArray[np.int64]:
        """Which magnetometer row each IMU sample carries, -1 where none."""
        if self.imu_mag_index is not None:
            return self.imu_mag_index
        return mag_for_imu(self.imu_t_s, self.mag_t_s, self.mag_uT)

    def check(self, path: str, imu: str, mag: str) -> None:
        """What replay cannot do without, as one :class:`DataFileError` naming the file and the record: an IMU.
        Without a magnetometer (no records, or all reading zero: then dropped) roll and pitch are still there,
        said in one line."""
        if len(self.imu_t_s) == 0:
            raise DataFileError(f"{path}: no {imu} records{self._damage_note()}")
        if len(self.mag_t_s) and np.any(self.mag_uT):
            return
        why = f"{mag} reads zero in all {len(self.mag_t_s)} records" if len(self.mag_t_s) else f"no {mag} records"
        log.warning("%s: %s: no magnetometer: %s", path, why, TILT_ONLY)
        self.mag_t_s, self.mag_uT = np.empty(0), np.empty((0, 3))

    def _damage_note(self) -> str:
        return f" ({self.damage})" if self.damage else ""


def mag_for_imu(imu_t_s: Array, mag_t_s: Array, mag_uT: Array) -> NDArray[np.int64]:
    """For each IMU sample, the index of the magnetometer reading it carries (-1: none new)."""
    newest = np.searchsorted(mag_t_s, imu_t_s, side="right") - 1  # at or before the sample: never ahead
    carried = newest.copy()
    carried[1:][newest[1:] == newest[:-1]] = -1  # not new since the previous sample: held by the front end
    live = np.zeros(len(carried), dtype=bool)
    valid = carried >= 0
    live[valid] = np.any(mag_uT[carried[valid]] != 0.0, axis=1)  # all zero: no reading
    return np.where(live, carried, -1)


class StreamSource:
    """:class:`LogStreams` as a finite message source (see the module docstring)."""

    def __init__(self, name: str, streams: LogStreams, vehicle: Sender = LOG_VEHICLE) -> None:
        self.name = name
        self.vehicle: Sender | None = vehicle  # the streams are this sender's (a .tlog's autopilot, as it locked)
        self.streams = streams
        self.damage = streams.damage
        self.finished = False
        self._next = 0

    def streams_for(self, follower: Follower) -> LogStreams:
        """The log's streams: all of them its vehicle's, which ``follower`` follows from the start."""
        return self.streams

    @functools.cached_property
    def _items(self) -> tuple[list[float], list[int], list[int]]:
        """Every item's time, kind (0 position, 1 IMU sample, 2 attitude, 3 GPS velocity, 4 parameter) and row,
        in time order; at equal times a position, a velocity and a parameter first, the autopilot's attitude after
        the sample. Built at the first recv: a reader that takes the arrays (replay) never pays for it."""
        s = self.streams
        times = np.concatenate([s.position_t_s, s.imu_t_s, s.attitude_t_s, s.gps_t_s, s.parameter_t_s])
        counts = (len(s.position_t_s), len(s.imu_t_s), len(s.attitude_t_s), len(s.gps_t_s), len(s.parameter_t_s))
        kinds = np.repeat(np.arange(5, dtype=np.int8), counts)
        order_key = np.repeat(np.array([0, 1, 2, 0, 0], dtype=np.int8), counts)  # before the sample at its time
        index = np.concatenate([np.arange(n) for n in counts])
        order = np.lexsort((order_key, times))
        return times[order].tolist(), kinds[order].tolist(), index[order].tolist()

    @functools.cached_property
    def _rows(self) -> tuple[list, list, list, list, list]:
        s = self.streams
        return (
            s.imu_t_s.tolist(),
            s.acc_mps2.tolist(),
            s.gyr_radps.tolist(),
            s.mag_uT.tolist(),
            s.carried_mag().tolist(),
        )

    @property
    def total(self) -> int:
        """Items the source hands out in all (for progress)."""
        return len(self._items[0])

    @property
    def done(self) -> int:
        return self._next

    def recv(self, timeout_s: float = 0.0) -> list[Received]:
        times, kinds, index = self._items
        imu_t, acc, gyr, mag, mag_index = self._rows
        start, stop = self._next, min(self._next + CHUNK_ITEMS, len(times))
        self._next = stop
        self.finished = stop >= len(times)
        s, vehicle, wrap, repeats = self.streams, self.vehicle, self.streams.time_wrap_s, self.streams.mag_repeats
        out: list[Received] = []
        for t, kind, i in zip(times[start:stop], kinds[start:stop], index[start:stop], strict=True):
            if kind == 1:
                m = mag_index[i]
                a, g = acc[i], gyr[i]
                sample = ImuSample(
                    imu_t[i],
                    (a[0], a[1], a[2]),
                    (g[0], g[1], g[2]),
                    None if m < 0 else tuple(mag[m]),
                    wrap,
                    mag_repeats=repeats,
                )
                out.append((t, vehicle, sample))
            elif kind == 2:
                out.append((t, vehicle, AutopilotAttitude(t, tuple(s.attitude_q[i].tolist()))))
            elif kind == 3:
                out.append((t, vehicle, s.gps_velocity[i]))
            elif kind == 4:
                out.append((t, vehicle, AutopilotParameter(*s.parameter_records[i])))
            else:
                lat, lon, alt = s.position[i].tolist()
                out.append((t, vehicle, PositionFix(Position(lat, lon, alt), s.date)))
        return out
