"""MAVLink IMU messages ⇄ SI samples: the project's only MAVLink unit conversions.

A *unit profile* says, for each IMU message an autopilot sends, how many m/s², rad/s and µT one field unit
is. :func:`decode` turns a message (a pymavlink message, or any object with the MAVLink field attributes and
``get_type()``) into an :class:`ImuSample` in the sensor/board frame with the vehicle's sample time;
:func:`encode` is its exact inverse (up to the message's integer or float32 quantisation) and is what the
fake vehicle sends. :func:`decode_position` reads the vehicle's position for the magnetic reference and
:func:`decode_gps_velocity` the receiver's own velocity for the fused filter's acceleration;
:func:`time_boot_ms` turns a vehicle-clock time back into MAVLink's wrapping millisecond field.

Units, checked against the senders:
- ArduPilot RAW_IMU and SCALED_IMU/2/3 (``GCS_Common.cpp``): acceleration in mG (``1000 / GRAVITY_MSS``,
  g = 9.80665), gyroscope in mrad/s, magnetometer in mgauss. RAW_IMU is already calibrated and in the body
  frame there, identical to SCALED_IMU. Its HIGHRES_IMU magnetometer is 10⁶ too large: the plausibility
  bound on |B| refuses it.
- PX4 HIGHRES_IMU: m/s², rad/s, gauss, ``fields_updated`` bits 6–8 set when the magnetometer is new; PX4
  SCALED_IMU as ArduPilot's.
- The integer messages carry the newest compass reading in every message (ArduPilot's ``send_raw_imu`` reads
  ``compass.get_field()`` when it sends; a 10 Hz compass under a 50 Hz stream is repeated five times), so
  their samples are marked ``mag_repeats``: the front end takes an exact repeat as the same reading held.
  HIGHRES_IMU says which readings are new (``fields_updated``): its repeats are new readings.
- ADIS16405 counts in RAW_IMU: 14-bit two's complement (upper register bits, the ND/EA flags, are
  ignored), accelerometer 3.33 mg/LSB, gyroscope 0.05 °/s/LSB, magnetometer 0.5 mgauss/LSB.
1 gauss = 100 µT; 1 mG = 9.80665e-3 m/s².
"""

from __future__ import annotations

import datetime as dt
import itertools
import math
import operator
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from functools import cached_property
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from mavattitude.errors import SensorError
from mavattitude.estimation.conventions import STANDARD_GRAVITY_MPS2, Vec3
from mavattitude.estimation.velocity import GPS_FIX_3D, GpsVelocity
from mavattitude.fields import ranged

MG_MPS2 = STANDARD_GRAVITY_MPS2 * 1e-3
MILLIGAUSS_UT = 0.1
GAUSS_UT = 100.0

#: A magnetometer reading above this is not a magnetic field a vehicle can fly in (the Earth's is ≤ 66 µT,
#: magnetometers saturate at a few thousand µT): the sender's units are wrong, so the sample is refused.
MAX_PLAUSIBLE_FIELD_UT = 2000.0

INT16_MIN, INT16_MAX = -32768, 32767

BOOT_MS_WRAP_S = 2.0**32 * 1e-3  # a uint32 of milliseconds wraps after this (≈ 49.7 days)

HIGHRES_ACC_GYRO_UPDATED = 0x3F  # fields_updated bits 0–5
HIGHRES_MAG_UPDATED = 0x1C0  # fields_updated bits 6–8


@dataclass(frozen=True)
class MessageLayout:
    """An IMU message's time field (unit, wrap period) and kind of fields, as every conversion here reads them.
    ``integer``: int16 fields, saturated at their limits, an all-zero magnetometer is none and the newest one is
    repeated (:attr:`ImuSample.mag_repeats`); else ``fields_updated`` marks a new magnetometer (HIGHRES_IMU)."""

    time_field: str
    time_unit_s: float
    time_wrap_s: float | None
    integer: bool


_BOOT_MS = MessageLayout("time_boot_ms", 1e-3, BOOT_MS_WRAP_S, integer=True)
LAYOUTS: dict[str, MessageLayout] = {
    "RAW_IMU": MessageLayout("time_usec", 1e-6, None, integer=True),
    "SCALED_IMU": _BOOT_MS,
    "SCALED_IMU2": _BOOT_MS,
    "SCALED_IMU3": _BOOT_MS,
    "HIGHRES_IMU": MessageLayout("time_usec", 1e-6, None, integer=False),
}
#: The IMU messages the project reads (``input.message``) and the fake vehicle sends.
MESSAGES = tuple(LAYOUTS)

#: The IMU fields of every message, in :func:`decode_columns`' column order: acceleration, rates, field.
IMU_FIELDS = ("xacc", "yacc", "zacc", "xgyro", "ygyro", "zgyro", "xmag", "ymag", "zmag")
_imu_fields = operator.attrgetter(*IMU_FIELDS)

#: The fields of each message that the IMU fields do not cover, with the values :func:`encode` sends.
_OTHER_FIELDS: dict[str, dict[str, int | float]] = {
    "RAW_IMU": {"id": 0, "temperature": 0},
    "SCALED_IMU": {"temperature": 0},
    "SCALED_IMU2": {"temperature": 0},
    "SCALED_IMU3": {"temperature": 0},
    "HIGHRES_IMU": {"abs_pressure": 0.0, "diff_pressure": 0.0, "pressure_alt": 0.0, "temperature": 0.0, "id": 0},
}


@dataclass(slots=True)
class ImuSample:
    """One IMU reading in SI units, sensor/board frame, at ``time_s`` on the vehicle's clock.

    ``mag_uT`` is ``None`` when the message carries no new magnetometer reading (HIGHRES_IMU
    ``fields_updated``, or an all-zero field: no compass). ``time_wrap_s`` is the period after which the
    sender's time field wraps (a uint32 of milliseconds: 2³² ms), ``None`` when it never does in practice:
    what the front end's clock needs to unwrap it, whichever message or log format the sample came from.
    ``saturated`` names the sensors (``"acc"``,
    ``"gyr"``, ``"mag"``) whose raw value sat at its integer limit, so the front end can screen them.
    ``mag_repeats``: the message repeats the newest magnetometer reading until there is a new one (the
    integer messages), so a reading exactly equal to the last one is that reading again, not a new one.
    Not frozen: building it is on the per-message path, and a frozen dataclass costs twice as much.
    """

    time_s: float
    acc_mps2: Vec3
    gyr_radps: Vec3
    mag_uT: Vec3 | None
    time_wrap_s: float | None = None
    saturated: frozenset[str] = field(default=frozenset())
    mag_repeats: bool = False


@dataclass(frozen=True)
class MessageScale:
    """SI units per field unit of one message; ``count_bits`` for raw two's-complement counts of that width."""

    acc_mps2: float
    gyr_radps: float
    mag_uT: float
    count_bits: int | None = None

    @cached_property
    def limits(self) -> tuple[int, int]:
        """The range of an integer field: int16, or two's-complement counts of ``count_bits``."""
        bits = self.count_bits
        return (INT16_MIN, INT16_MAX) if bits is None else (-(1 << (bits - 1)), (1 << (bits - 1)) - 1)


@dataclass(frozen=True)
class UnitProfile:
    """The messages one kind of sender emits and the units of each."""

    name: str
    messages: Mapping[str, MessageScale]  # the first is the one its sender streams by default

    @property
    def default_message(self) -> str:
        return next(iter(self.messages))

    def scale(self, message: str) -> MessageScale:
        try:
            return self.messages[message]
        except KeyError:
            raise SensorError(
                f"profile {self.name!r} does not read {message}; it reads {', '.join(self.messages)}"
            ) from None


_SCALED = MessageScale(acc_mps2=MG_MPS2, gyr_radps=1e-3, mag_uT=MILLIGAUSS_UT)
_HIGHRES = MessageScale(acc_mps2=1.0, gyr_radps=1.0, mag_uT=GAUSS_UT)
_SCALED_FAMILY = {"SCALED_IMU": _SCALED, "SCALED_IMU2": _SCALED, "SCALED_IMU3": _SCALED}

PROFILES: dict[str, UnitProfile] = {
    "ardupilot": UnitProfile("ardupilot", {"RAW_IMU": _SCALED, **_SCALED_FAMILY, "HIGHRES_IMU": _HIGHRES}),
    "px4": UnitProfile("px4", {"HIGHRES_IMU": _HIGHRES, **_SCALED_FAMILY}),
    "adis16405": UnitProfile(
        "adis16405",
        {
            "RAW_IMU": MessageScale(
                acc_mps2=3.33 * MG_MPS2,
                gyr_radps=math.radians(0.05),
                mag_uT=0.5 * MILLIGAUSS_UT,
                count_bits=14,
            )
        },
    ),
}
#: Every ``input.profile``: the fixed ones above, and ``custom`` (scales from ``input.custom``).
PROFILE_NAMES = (*PROFILES, "custom")


def _scale(doc: str) -> Any:
    """An ``input.custom`` scale: a positive number of SI units per raw unit, or unset."""
    return ranged(None, doc, 0.0, math.inf, lo_open=True)


@dataclass(frozen=True)
class CustomScales:
    """``input.custom``: the scales of profile ``custom``, one per sensor for every message (the config
    reads and checks them by each field's range and description)."""

    accel_mps2_per_lsb: float | None = _scale("m/s² per raw unit")
    gyro_radps_per_lsb: float | None = _scale("rad/s per raw unit")
    mag_uT_per_lsb: float | None = _scale("µT per raw unit")


def custom_profile(
    accel_mps2_per_lsb: float,
    gyro_radps_per_lsb: float,
    mag_uT_per_lsb: float,
    messages: tuple[str, ...] = MESSAGES,
) -> UnitProfile:
    """A profile with one scale per sensor for every message (``input.custom`` in the config)."""
    for name, value in (
        ("accel_mps2_per_lsb", accel_mps2_per_lsb),
        ("gyro_radps_per_lsb", gyro_radps_per_lsb),
        ("mag_uT_per_lsb", mag_uT_per_lsb),
    ):
        if not (math.isfinite(value) and value > 0.0):
            raise SensorError(f"custom profile: {name} must be a positive number, got {value!r}")
    scale = MessageScale(accel_mps2_per_lsb, gyro_radps_per_lsb, mag_uT_per_lsb)
    return UnitProfile("custom", {m: scale for m in messages})


def get_profile(name: str, custom: CustomScales | None = None) -> UnitProfile:
    """The named profile; ``custom`` needs its scales (the config's ``input.custom``)."""
    if name == "custom":
        if custom is None:
            raise SensorError("profile 'custom' needs input.custom scales")
        return custom_profile(custom.accel_mps2_per_lsb, custom.gyro_radps_per_lsb, custom.mag_uT_per_lsb)
    try:
        return PROFILES[name]
    except KeyError:
        raise SensorError(f"unknown unit profile {name!r}; known: {', '.join(PROFILE_NAMES)}") from None


def _sign_extend(counts: Any, bits: int) -> Any:
    """Two's-complement counts of ``bits`` (the bits above ignored) as signed numbers: an int or an integer array."""
    counts = counts & ((1 << bits) - 1)
    return counts - ((counts >> (bits - 1)) << bits)


def _at_limits(values: NDArray[np.float64], lo: int, hi: int) -> NDArray[np.bool_]:
    """Which sensors (acc, gyr, mag: (n, 3)) have a field of ``values`` (n, 9: :data:`IMU_FIELDS`) at a limit.
    The three fields or'd one by one: numpy's reduction over an axis of three costs four times as much."""
    at = ((values <= lo) | (values >= hi)).reshape(-1, 3, 3)
    return at[:, :, 0] | at[:, :, 1] | at[:, :, 2]


_NONE_SATURATED: frozenset[str] = frozenset()
_SENSORS = ("acc", "gyr", "mag")


def _sensor_names(flags: list[bool]) -> frozenset[str]:
    return frozenset(itertools.compress(_SENSORS, flags)) or _NONE_SATURATED


def decode(msg: Any, profile: UnitProfile) -> ImuSample:
    """One IMU message → :class:`ImuSample` (SI, board frame, time from the message): :func:`decode_columns`
    for one message, by the same table and rules, in floats (it runs on every message of the live link).

    Raises :class:`SensorError` for a message the profile does not read and for an implausible field
    magnitude (wrong units at the sender, e.g. ArduPilot's HIGHRES_IMU magnetometer).
    """
    kind = msg.get_type()
    profile.scale(kind)  # a message the profile does not read raises here, before its fields are read
    layout = LAYOUTS[kind]
    fields_updated = 0 if layout.integer else msg.fields_updated
    return decode_fields(kind, getattr(msg, layout.time_field), _imu_fields(msg), fields_updated, profile)


def decode_fields(
    kind: str, time_value: float, values: tuple[float, ...], fields_updated: int, profile: UnitProfile
) -> ImuSample:
    """:func:`decode` from the message's raw field values: its time field, :data:`IMU_FIELDS` in order and
    ``fields_updated`` (HIGHRES_IMU; ignored for the integer messages). What the live link calls with the
    fields it unpacked from a frame itself, skipping pymavlink's message object."""
    scale = profile.messages.get(kind) or profile.scale(kind)
    layout = LAYOUTS[kind]
    saturated = _NONE_SATURATED
    if layout.integer:
        if scale.count_bits is not None:
            values = tuple(_sign_extend(int(v), scale.count_bits) for v in values)
        lo, hi = scale.limits
        if not (lo < min(values) and max(values) < hi):  # only then can _at_limits find one
            saturated = _sensor_names(_at_limits(np.array([values], dtype=float), lo, hi)[0].tolist())
        has_mag = any(values[6:])  # an integer message with no compass reads exactly zero
    else:
        has_mag = bool(fields_updated & HIGHRES_MAG_UPDATED)
    ax, ay, az, gx, gy, gz, mx, my, mz = values
    sa, sg = scale.acc_mps2, scale.gyr_radps
    mag: Vec3 | None = None
    if has_mag:
        sm = scale.mag_uT
        mag = (mx * sm, my * sm, mz * sm)
        norm = math.sqrt(mag[0] * mag[0] + mag[1] * mag[1] + mag[2] * mag[2])
        if norm > MAX_PLAUSIBLE_FIELD_UT:
            raise _implausible(kind, profile, norm)
    return ImuSample(
        time_value * layout.time_unit_s,
        (ax * sa, ay * sa, az * sa),
        (gx * sg, gy * sg, gz * sg),
        mag,
        layout.time_wrap_s,
        saturated,
        layout.integer,
    )


def wire_decoder(kind: str, profile: UnitProfile, at: Mapping[str, int]) -> Callable[[Sequence[Any]], ImuSample]:
    """:func:`decode_fields` on a message's fields as its frame's payload unpacks them (the MAVLink library's wire
    order), ``at`` giving each field's place: what the live link decodes its input message with."""
    imu = operator.itemgetter(*(at[name] for name in IMU_FIELDS))
    time_at, updated_at = at[LAYOUTS[kind].time_field], at.get("fields_updated")

    def decode_wire(wire: Sequence[Any]) -> ImuSample:
        updated = 0 if updated_at is None else wire[updated_at]
        return decode_fields(kind, wire[time_at], imu(wire), updated, profile)

    return decode_wire


@dataclass
class ImuColumns:
    """Many IMU messages of one kind decoded at once (:func:`decode_columns`): what :func:`decode` gives each.

    ``mag_uT`` rows are NaN where ``has_mag`` is false; ``saturated`` (n, 3) flags acc, gyr, mag at their
    integer limit; ``refused`` rows are what :func:`decode` raises for (:meth:`error` says why).
    """

    kind: str
    profile: UnitProfile
    time_s: NDArray[np.float64]
    acc_mps2: NDArray[np.float64]
    gyr_radps: NDArray[np.float64]
    mag_uT: NDArray[np.float64]
    has_mag: NDArray[np.bool_]
    saturated: NDArray[np.bool_]
    refused: NDArray[np.bool_]
    field_uT: NDArray[np.float64]

    @property
    def time_wrap_s(self) -> float | None:
        return LAYOUTS[self.kind].time_wrap_s

    @property
    def mag_repeats(self) -> bool:
        """:attr:`ImuSample.mag_repeats` of every row."""
        return LAYOUTS[self.kind].integer

    def error(self, row: int) -> SensorError:
        return _implausible(self.kind, self.profile, float(self.field_uT[row]))

    def samples(self) -> list[ImuSample | None]:
        """Each row as :func:`decode` returns it; ``None`` for a refused row."""
        wrap, repeats = self.time_wrap_s, self.mag_repeats
        sat = [_sensor_names(row) for row in self.saturated.tolist()]
        mag = [tuple(m) if has else None for m, has in zip(self.mag_uT.tolist(), self.has_mag.tolist(), strict=True)]
        rows = zip(self.time_s.tolist(), self.acc_mps2.tolist(), self.gyr_radps.tolist(), mag, sat, strict=True)
        return [
            None if bad else ImuSample(t, tuple(a), tuple(g), m, wrap, s, repeats)  # type: ignore[arg-type]
            for (t, a, g, m, s), bad in zip(rows, self.refused.tolist(), strict=True)
        ]


def decode_columns(kind: str, fields: Mapping[str, NDArray[Any]], profile: UnitProfile) -> ImuColumns:
    """:func:`decode` for many messages of ``kind`` at once, ``fields`` the message's columns: the same
    numbers, the same units (a log read as arrays). Raises :class:`SensorError` if the profile does not read
    ``kind``."""
    scale = profile.scale(kind)
    layout = LAYOUTS[kind]
    values = np.empty((len(fields[IMU_FIELDS[0]]), 9))
    for i, name in enumerate(IMU_FIELDS):
        values[:, i] = fields[name]
    if layout.integer:
        if scale.count_bits is not None:
            values = _sign_extend(values.astype(np.int64), scale.count_bits).astype(np.float64)
        saturated = _at_limits(values, *scale.limits)
        has_mag = (values[:, 6] != 0.0) | (values[:, 7] != 0.0) | (values[:, 8] != 0.0)
    else:
        saturated = np.zeros((len(values), 3), dtype=bool)
        has_mag = (fields["fields_updated"] & HIGHRES_MAG_UPDATED) != 0
    mag = values[:, 6:] * scale.mag_uT
    field_uT = np.sqrt(np.einsum("ij,ij->i", mag, mag))
    mag[~has_mag] = np.nan
    field_uT[~has_mag] = 0.0
    return ImuColumns(
        kind,
        profile,
        fields[layout.time_field] * layout.time_unit_s,
        values[:, :3] * scale.acc_mps2,
        values[:, 3:6] * scale.gyr_radps,
        mag,
        has_mag,
        saturated,
        field_uT > MAX_PLAUSIBLE_FIELD_UT,
        field_uT,
    )


def _implausible(kind: str, profile: UnitProfile, norm: float) -> SensorError:
    hint = (
        " (ArduPilot's HIGHRES_IMU magnetometer is known to be 10⁶ too large: read RAW_IMU or SCALED_IMU)"
        if profile.name == "ardupilot" and kind == "HIGHRES_IMU"
        else ""
    )
    return SensorError(
        f"{kind} magnetometer |B| = {norm:.4g} µT is implausible (> {MAX_PLAUSIBLE_FIELD_UT:g} µT) "
        f"with profile {profile.name!r}{hint}"
    )


def encode(sample: ImuSample, profile: UnitProfile, message: str) -> dict[str, int | float]:
    """The inverse of :func:`decode`: every field of ``message`` as a dict,
    ready for pymavlink's ``<message>_send(**fields)``.

    Integer fields are rounded and clipped to their range (a clipped value decodes as saturated);
    ``time_boot_ms`` wraps at 2³² ms as on the vehicle. A ``None`` magnetometer is sent as zeros, or, in
    HIGHRES_IMU, with the magnetometer bits of ``fields_updated`` clear.
    """
    kind = message
    scale = profile.scale(kind)
    layout = LAYOUTS[kind]
    ticks = round(sample.time_s / layout.time_unit_s)
    wrap_s = layout.time_wrap_s
    fields: dict[str, int | float] = {
        layout.time_field: ticks % round(wrap_s / layout.time_unit_s) if wrap_s else ticks
    }
    mag = sample.mag_uT if sample.mag_uT is not None else (0.0, 0.0, 0.0)
    values = [v / scale.acc_mps2 for v in sample.acc_mps2]
    values += [v / scale.gyr_radps for v in sample.gyr_radps]
    values += [v / scale.mag_uT for v in mag]
    if layout.integer:
        lo, hi = scale.limits
        values = [min(hi, max(lo, round(v))) for v in values]
    fields.update(zip(IMU_FIELDS, values, strict=True))
    fields.update(_OTHER_FIELDS[kind])
    if kind == "HIGHRES_IMU":
        updated = HIGHRES_ACC_GYRO_UPDATED | (HIGHRES_MAG_UPDATED if sample.mag_uT is not None else 0)
        fields["fields_updated"] = updated
    return fields


def time_boot_ms(time_s: float) -> int:
    """A vehicle-clock time as MAVLink's ``time_boot_ms`` (uint32, wraps at 2³² ms ≈ 49.7 days)."""
    return round(time_s * 1e3) % (1 << 32)


def time_usec(time_s: float) -> int:
    """A vehicle-clock time as MAVLink's ``time_usec`` (uint64 µs since boot; the largest a uint64 holds, as it
    came in, when the float's rounding takes it past)."""
    return min(max(round(time_s * 1e6), 0), (1 << 64) - 1)


@dataclass(frozen=True)
class Position:
    """A geodetic position: latitude and longitude in degrees, altitude above mean sea level in metres."""

    lat_deg: float
    lon_deg: float
    alt_m: float


POSITION_MESSAGES = ("GLOBAL_POSITION_INT", "GPS_RAW_INT")  # what decode_position reads
#: the IMU messages that carry a compass, and which (ArduPilot sends compass 1, 2, 3 in RAW_IMU, SCALED_IMU2, 3)
COMPASS_INSTANCES = {"RAW_IMU": 0, "SCALED_IMU": 0, "SCALED_IMU2": 1, "SCALED_IMU3": 2}
#: each compass's IMU message, the first that carries it (RAW_IMU for compass 1), by instance
_COMPASS_MESSAGES = dict(sorted({k: m for m, k in reversed(COMPASS_INSTANCES.items())}.items()))


def other_compasses(message: str) -> dict[int, str]:
    """The compasses other than the one ``message`` carries, by instance, each with the IMU message that carries
    it; none when ``message`` carries no numbered compass (HIGHRES_IMU, PX4's)."""
    own = COMPASS_INSTANCES.get(message)
    return {} if own is None else {k: m for k, m in _COMPASS_MESSAGES.items() if k != own}


#: The World Magnetic Model's altitudes (m above the ellipsoid): a position outside is a garbled field
WMM_ALT_RANGE_M = (-1_000.0, 850_000.0)


def is_position(lat_lon_alt: ArrayLike) -> Any:
    """Whether each (latitude °, longitude °, altitude m) row is a place: on the globe and within the magnetic
    model's altitudes (a garbled field is not, and the model would answer it all the same), and not exactly
    0°, 0°, what an autopilot without a position sends. NaN is no place."""
    lat, lon, alt = np.moveaxis(np.asarray(lat_lon_alt, dtype=float), -1, 0)
    low, high = WMM_ALT_RANGE_M
    on_globe = (np.abs(lat) <= 90.0) & (np.abs(lon) <= 180.0) & (alt >= low) & (alt <= high)
    return on_globe & ((lat != 0.0) | (lon != 0.0))


def decode_position(msg: Any) -> Position | None:
    """GLOBAL_POSITION_INT, or GPS_RAW_INT with a 3D fix or better, → :class:`Position`; ``None`` otherwise,
    and where it is no place (:func:`is_position`). Both carry degrees × 10⁷ and millimetres."""
    kind = msg.get_type()
    if kind == "GPS_RAW_INT" and msg.fix_type < GPS_FIX_3D:
        return None
    if kind not in POSITION_MESSAGES or not is_position((msg.lat * 1e-7, msg.lon * 1e-7, msg.alt * 1e-3)):
        return None
    return Position(lat_deg=msg.lat * 1e-7, lon_deg=msg.lon * 1e-7, alt_m=msg.alt * 1e-3)


def encode_position(position: Position) -> tuple[int, int, int]:
    """:func:`decode_position`'s inverse: latitude and longitude in degrees × 10⁷, altitude in millimetres."""
    return round(position.lat_deg * 1e7), round(position.lon_deg * 1e7), round(position.alt_m * 1e3)


def decode_position_columns(kind: str, fields: Mapping[str, NDArray[Any]]) -> tuple[NDArray[np.bool_], NDArray[Any]]:
    """:func:`decode_position` for many messages of ``kind``: which rows are a position, and every row's
    latitude °, longitude °, altitude m (n, 3)."""
    position = np.column_stack([fields["lat"] * 1e-7, fields["lon"] * 1e-7, fields["alt"] * 1e-3])
    valid = is_position(position)
    if kind == "GPS_RAW_INT":
        valid &= fields["fix_type"] >= GPS_FIX_3D
    return valid, position


#: GPS_RAW_INT: velocity and course unknown (UINT16_MAX), satellites unknown (UINT8_MAX); cm/s, centidegrees.
GPS_UNKNOWN_U16, GPS_UNKNOWN_SATELLITES = 65535, 255
CMPS_MPS, CDEG_RAD = 0.01, math.radians(0.01)


def decode_gps_velocity(msg: Any) -> GpsVelocity | None:
    """GPS_RAW_INT's ground speed and course → :class:`GpsVelocity` (vertical unknown); ``None`` without a 3D
    fix or with the speed or course unknown."""
    valid, rows = decode_gps_velocity_columns(
        {name: np.array([getattr(msg, name)]) for name in ("time_usec", "vel", "cog", "fix_type", "satellites_visible")}
    )
    return rows[0] if valid[0] else None


def decode_gps_velocity_columns(fields: Mapping[str, NDArray[Any]]) -> tuple[NDArray[np.bool_], list[GpsVelocity]]:
    """:func:`decode_gps_velocity` for many GPS_RAW_INT messages: which rows are a velocity, and every row's."""
    vel, cog, fix = (np.asarray(fields[k]) for k in ("vel", "cog", "fix_type"))
    valid = (fix >= GPS_FIX_3D) & (vel != GPS_UNKNOWN_U16) & (cog != GPS_UNKNOWN_U16)
    speed, course = vel * CMPS_MPS, cog * CDEG_RAD
    north, east = (speed * np.cos(course)).tolist(), (speed * np.sin(course)).tolist()
    sats = np.asarray(fields["satellites_visible"]).astype(np.int64)
    sats = np.where(sats == GPS_UNKNOWN_SATELLITES, -1, sats).tolist()
    t = (np.asarray(fields["time_usec"], dtype=float) * 1e-6).tolist()
    rows = [
        GpsVelocity(t_s, (n, e, 0.0), False, int(f), k)
        for t_s, n, e, f, k in zip(t, north, east, fix.tolist(), sats, strict=True)
    ]
    return valid, rows


# A Unix time outside these is not a GPS date: ArduPilot's GPS_RAW_INT.time_usec counts from boot (never
# 40 years), SYSTEM_TIME.time_unix_usec is 0 until the autopilot knows the time, a receiver without time says
# 1980 or 1999 (GPS week 0 or 1024), and a later one is a garbled field (a year past 9999 is not even a date
# Python can hold). The earliest is the oldest magnetic model's epoch: DataFlash logs from 2013 have dates.
EARLIEST_UNIX_S = 1_262_304_000  # 2010-01-01
LATEST_UNIX_S = 4_102_444_800  # 2100-01-01


#: The messages that may carry the vehicle's GPS time, and the field (µs since 1970, or since boot).
UTC_TIME_FIELDS = {"SYSTEM_TIME": "time_unix_usec", "GPS_RAW_INT": "time_usec"}


def is_date(unix_s: Any) -> Any:
    """Whether each Unix time (s) can be a GPS date (see :data:`EARLIEST_UNIX_S`; NaN cannot)."""
    return (unix_s >= EARLIEST_UNIX_S) & (unix_s < LATEST_UNIX_S)


def unix_date(unix_s: float) -> dt.date | None:
    """The UTC day of a Unix time, ``None`` when it cannot be a GPS date (:func:`is_date`)."""
    return dt.datetime.fromtimestamp(unix_s, dt.timezone.utc).date() if is_date(unix_s) else None


def decode_utc_date(msg: Any) -> dt.date | None:
    """The UTC date the vehicle's GPS gives: SYSTEM_TIME.time_unix_usec, or GPS_RAW_INT.time_usec when it is
    a Unix time (µs) rather than a time since boot; ``None`` when the message carries no such date."""
    name = UTC_TIME_FIELDS.get(msg.get_type())
    return None if name is None else unix_date(getattr(msg, name) * 1e-6)


def utc_time_columns(kind: str, fields: Mapping[str, NDArray[Any]]) -> NDArray[np.float64]:
    """:func:`decode_utc_date` for many messages of ``kind`` (one of :data:`UTC_TIME_FIELDS`): each row's
    Unix time in s, NaN where it is not a date (a time since boot, a garbled field)."""
    unix_s = np.asarray(fields[UTC_TIME_FIELDS[kind]], dtype=float) * 1e-6
    return np.where(is_date(unix_s), unix_s, np.nan)
