"""The Earth's magnetic field in NED (µT): the solver's magnetometer reference.

:class:`MagneticReference` is the config's ``reference.magnetic`` (how the field is known),
:class:`ReferenceField` the field known at a moment, :class:`ReferenceTracker` the one the service and
replay keep current, by one rule. From the config: two angles (declination ``D``, inclination ``I``,
optional intensity ``F``): ``B = F [cos I cos D, cos I sin D, sin I]`` (without ``F`` a unit vector: the
direction only, and no |B| screening); or a vector ``field_ned_uT``. ``auto``: the World Magnetic Model at
the vehicle's position, through ``pygeomag`` (pure Python, no compiled dependency on a companion computer),
with the model whose five-year span holds the date (WMM2010, WMM2015v2, WMM2020, WMM2025: 2010–2029). It is
recomputed when the vehicle moves more than ``recompute_distance_km``. The model's date is the vehicle's
GPS date (or a log's), the companion's clock only as a fallback (a board without a real-time clock is
wrong until NTP); a date outside every model's span is clamped to the nearest edge, with one warning,
never an error.

Until a position arrives the reference is *waiting*. A vehicle without a position (no GPS, no fix, indoors,
under water) is given a *measured* reference after ``position_wait_s`` of vehicle time from its first tick:
the inclination and intensity the compass itself shows while the vehicle is quiet: the mean of the dip
``asin(d̂ · b̂)`` and of ``|B|`` over the quiet ticks seen so far (at least ``MIN_MEASURED_TICKS``; the compass
monitor's quiet test and dip, :mod:`mavattitude.estimation.compass`), and declination 0: heading is magnetic
north, unless the autopilot says the declination it heads by (:meth:`ReferenceTracker.set_declination`:
ArduPilot's ``COMPASS_DEC``, set from its last GPS fix or by hand; PX4's ``EKF2_MAG_DECL``, saved from its last
fix's lookup at disarm or set by hand). Then heading is true north, as the
autopilot's is and as MAVLink's NED frame is, and the two attitudes compare on one north; a constant yaw
difference of the local declination (13° in much of the United States or Australia) would otherwise read as
a disagreement. A position that arrives later replaces it with the WMM's field, the autopilot's word on the
declination no longer used (an independent model is the better second opinion).
"""

from __future__ import annotations

import datetime as dt
import logging
import math
from dataclasses import dataclass
from typing import Any

from mavattitude.errors import ConfigError, SensorError
from mavattitude.estimation.conventions import Vec3

log = logging.getLogger(__name__)

EARTH_RADIUS_KM = 6371.0088
MIN_MEASURED_TICKS = 25  # the fewest quiet ticks a measured field is the mean of (as the compass monitor judges on)
#: The autopilots' declination parameters, east of true north, and degrees per unit of each: ArduPilot's in radians
#: (from its last GPS fix with COMPASS_AUTODEC, else as set), PX4's EKF2 in degrees (saved from its last fix's
#: lookup at disarm with EKF2_DECL_TYPE bit 1, else as set). Each heads by it while it has no GPS position.
DECLINATION_PARAMETERS = {"COMPASS_DEC": math.degrees(1.0), "EKF2_MAG_DECL": 1.0}


def declination_parameter(profile: str) -> str:
    """The declination parameter of the autopilot that sends ``profile``'s IMU messages (input.profile)."""
    return "EKF2_MAG_DECL" if profile == "px4" else "COMPASS_DEC"


@dataclass(frozen=True)
class WmmModel:
    """One World Magnetic Model release: its coefficient file in pygeomag and the days it is valid for."""

    name: str
    coefficients: str
    first_day: dt.date
    last_day: dt.date


#: The releases pygeomag ships, oldest first (WMM2015v2: the 2019 out-of-cycle correction of WMM2015).
WMM_MODELS = tuple(
    WmmModel(name, f"wmm/{file}.COF", dt.date(year, 1, 1), dt.date(year + 4, 12, 31))
    for name, file, year in (
        ("WMM2010", "WMM_2010", 2010),
        ("WMM2015v2", "WMM_2015v2", 2015),
        ("WMM2020", "WMM_2020", 2020),
        ("WMM2025", "WMM_2025", 2025),
    )
)
WMM_FIRST_DAY, WMM_LAST_DAY = WMM_MODELS[0].first_day, WMM_MODELS[-1].last_day


@dataclass(frozen=True)
class ReferenceField:
    """The reference field, or ``field_ned_uT is None`` while waiting for a position."""

    field_ned_uT: Vec3 | None
    intensity_uT: float | None  # |B₀| for screening; None when only the direction is known
    source: str  # "config", "wmm", "measured" or "waiting"
    label: str = ""  # for a person: which field, from where and when

    @property
    def waiting(self) -> bool:
        return self.field_ned_uT is None


WAITING = ReferenceField(None, None, "waiting", "none")
MODES = ("auto", "angles", "vector")


@dataclass(frozen=True)
class MagneticReference:
    """How the NED field is known: ``auto`` (WMM at the vehicle's position), two angles, or a vector.

    Checked on construction; a :class:`~mavattitude.errors.ConfigError` names the key at fault (the
    config prefixes it with ``reference.magnetic.``).
    """

    mode: str = "auto"
    declination_deg: float | None = None
    inclination_deg: float | None = None
    intensity_uT: float | None = None
    field_ned_uT: Vec3 | None = None

    def __post_init__(self) -> None:
        if self.mode not in MODES:
            raise ConfigError(f"mode: {self.mode!r}: expected {', '.join(MODES)}")
        if self.mode == "angles":
            for key in ("declination_deg", "inclination_deg"):
                if getattr(self, key) is None:
                    raise ConfigError(f"{key}: missing (give declination_deg and inclination_deg, or field_ned_uT)")
        if self.mode == "vector" and (self.field_ned_uT is None or math.hypot(*self.field_ned_uT) == 0.0):
            raise ConfigError("field_ned_uT: the field vector is zero")

    def fixed_field(self) -> ReferenceField:
        """The field the config gives (``WAITING`` for ``auto``, known only once a position arrives)."""
        if self.mode == "angles":
            vec = field_from_angles(self.declination_deg, self.inclination_deg, self.intensity_uT or 1.0)
            label = f"given: declination {self.declination_deg:g}°, inclination {self.inclination_deg:g}°"
            label += "" if self.intensity_uT is None else f", {self.intensity_uT:g} µT"
            return ReferenceField(vec, self.intensity_uT, "config", label)
        if self.mode == "vector":
            vec = (float(self.field_ned_uT[0]), float(self.field_ned_uT[1]), float(self.field_ned_uT[2]))
            return ReferenceField(vec, math.hypot(*vec), "config", "given: N {:g} E {:g} D {:g} µT".format(*vec))
        return WAITING

    def to_yaml(self) -> Any:
        if self.mode == "auto":
            return "auto"
        if self.mode == "vector":
            return {"field_ned_uT": list(self.field_ned_uT or ())}
        out = {"declination_deg": self.declination_deg, "inclination_deg": self.inclination_deg}
        return out if self.intensity_uT is None else {**out, "intensity_uT": self.intensity_uT}


def field_from_angles(declination_deg: float, inclination_deg: float, intensity_uT: float = 1.0) -> Vec3:
    """NED field from declination (east of true north), inclination (down from horizontal) and intensity."""
    d, i = math.radians(declination_deg), math.radians(inclination_deg)
    h = intensity_uT * math.cos(i)
    return (h * math.cos(d), h * math.sin(d), intensity_uT * math.sin(i))


def decimal_year(when: dt.date) -> float:
    start = dt.date(when.year, 1, 1)
    days = (dt.date(when.year + 1, 1, 1) - start).days
    return when.year + (when - start).days / days


def wmm_model(when: dt.date) -> WmmModel:
    """The release whose span holds ``when`` (outside them all: the nearest)."""
    return next((m for m in WMM_MODELS if when <= m.last_day), WMM_MODELS[-1])


def wmm_field_ned_uT(lat_deg: float, lon_deg: float, alt_m: float, when: dt.date) -> Vec3:
    """The WMM main field at a position and date (the release of that date), NED, µT (pygeomag gives nT,
    altitude in km)."""
    model = wmm_model(when)
    try:
        result = _geomag(model.coefficients).calculate(
            glat=lat_deg, glon=lon_deg, alt=alt_m / 1000.0, time=decimal_year(when)
        )
    except Exception as exc:  # pygeomag raises plain exceptions for dates outside the model
        raise SensorError(f"World Magnetic Model failed at {lat_deg:.5f}°, {lon_deg:.5f}° on {when}: {exc}") from exc
    return (result.x / 1000.0, result.y / 1000.0, result.z / 1000.0)


_GEOMAG: dict[str, Any] = {}


def _geomag(coefficients: str) -> Any:
    """One model instance per release (reading the coefficient file is the slow part)."""
    from pygeomag import GeoMag  # imported on first use: only `auto` needs it

    if coefficients not in _GEOMAG:
        _GEOMAG[coefficients] = GeoMag(coefficients_file=coefficients, high_resolution=False)
    return _GEOMAG[coefficients]


def distance_km(lat1_deg: float, lon1_deg: float, lat2_deg: float, lon2_deg: float) -> float:
    """Great-circle distance (haversine)."""
    p1, p2 = math.radians(lat1_deg), math.radians(lat2_deg)
    dp, dl = p2 - p1, math.radians(lon2_deg - lon1_deg)
    a = math.sin(dp / 2) ** 2 + math.cos(p1) * math.cos(p2) * math.sin(dl / 2) ** 2
    return 2.0 * EARTH_RADIUS_KM * math.asin(min(1.0, math.sqrt(a)))


class ReferenceTracker:
    """The reference for the service and replay: fixed from the config, or (``auto``) from WMM as positions
    arrive, measured from the compass when none has after ``position_wait_s`` (module docstring)."""

    def __init__(
        self, setting: MagneticReference, recompute_distance_km: float = 5.0, position_wait_s: float = 5.0
    ) -> None:
        self.mode = setting.mode
        self.recompute_distance_km = recompute_distance_km
        self.position_wait_s = position_wait_s
        self._at: tuple[float, float] | None = None
        self._when: dt.date | None = None  # the vehicle's date the reference was taken on (None: the clock's)
        self._clamp_said = False
        self._first_s = math.nan  # vehicle time of the first tick while waiting
        self._quiet = [0, 0.0, 0.0]  # quiet ticks while waiting: count, Σ dip (deg), Σ |B| (µT)
        self._measured = (math.nan, math.nan)  # the measured field's dip (deg) and |B| (µT), once there is one
        self._declination: tuple[float, str] | None = None  # the autopilot's (deg), and the parameter that said it
        self.reference = setting.fixed_field()
        # what describe() says: the first reference's label and the latest's, and how many came between
        self._labels: list[str] = [] if self.reference.waiting else [self.reference.label]
        self._between = 0
        #: the level the reference's changes are said at (a compass judged beside the replayed one: DEBUG)
        self.level = logging.INFO

    @property
    def waiting(self) -> bool:
        return self.reference.waiting

    @property
    def measured(self) -> bool:
        """The reference is the field measured from the compass (no position yet)."""
        return self.reference.source == "measured"

    def describe(self) -> str:
        """Which references were used, the first and the last (``none`` before any): for the replay summary."""
        more = f" (+{self._between} more WMM look-ups)" if self._between else ""
        return "; then ".join(self._labels or [WAITING.label]) + more

    def _use(self, reference: ReferenceField) -> None:
        self.reference = reference
        labels = self._labels
        if labels and labels[-1] == reference.label:
            return
        if len(labels) == 2:
            self._between += 1
            labels[1] = reference.label
        else:
            labels.append(reference.label)

    def observe(self, time_s: float, dip_deg: float, field_uT: float) -> bool:
        """A tick while waiting for a position (``auto``): its dip and |B| when the vehicle is quiet (NaN
        when not). True when the measured field became the reference: ``position_wait_s`` after the first
        tick, once ``MIN_MEASURED_TICKS`` quiet ticks were seen (a time going back, a reboot, starts over)."""
        if self.mode != "auto" or not self.waiting:
            return False
        if not time_s >= self._first_s:  # NaN: the first tick
            self._first_s, self._quiet = time_s, [0, 0.0, 0.0]
        if dip_deg == dip_deg and field_uT == field_uT:
            q = self._quiet
            q[0], q[1], q[2] = q[0] + 1, q[1] + dip_deg, q[2] + field_uT
        n, dip_sum, field_sum = self._quiet
        if time_s - self._first_s < self.position_wait_s or n < MIN_MEASURED_TICKS:
            return False
        self._measured = dip_sum / n, field_sum / n
        self._use_measured()
        log.log(
            self.level,
            "no GPS position: heading is %s, field measured from the compass: dip %.1f°, %.1f µT "
            "(%d quiet ticks in %.1f s)",
            self._north(),
            *self._measured,
            n,
            time_s - self._first_s,
        )
        return True

    def set_declination(self, declination_deg: float, parameter: str) -> bool:
        """The declination the autopilot heads by (said by its ``parameter``): a measured field's heading, now
        or when there is one, is then true north as the autopilot's (module docstring). True when that changed
        the reference."""
        if self._declination is not None and self._declination[0] == declination_deg:
            return False
        self._declination = declination_deg, parameter
        if not self.measured:
            return False
        self._use_measured()
        log.log(self.level, "heading is now %s (the field measured from the compass)", self._north())
        return True

    def _north(self) -> str:
        """The north a measured field's heading is."""
        if self._declination is None:
            return "magnetic north"
        return "north as the autopilot's: declination {:+.1f}° ({})".format(*self._declination)

    def _use_measured(self) -> None:
        dip, intensity = self._measured
        declination_deg = 0.0 if self._declination is None else self._declination[0]
        label = f"measured: dip {dip:.1f}°, {intensity:.1f} µT, {self._north()}"
        self._use(ReferenceField(field_from_angles(declination_deg, dip, intensity), intensity, "measured", label))

    def update_position(self, lat_deg: float, lon_deg: float, alt_m: float, when: dt.date | None = None) -> bool:
        """Feed a position (``auto`` only); True when the reference changed: the first position, a move
        of more than ``recompute_distance_km``, or a vehicle date other than the one the field was taken on."""
        if self.mode != "auto":
            return False
        moved = self._at is None or distance_km(*self._at, lat_deg, lon_deg) > self.recompute_distance_km
        # the vehicle's date arriving after the first position (SYSTEM_TIME after GLOBAL_POSITION_INT), or
        # changing, replaces the day the field was taken on: the companion's clock is only the last resort
        if not moved and (when is None or when == self._when):
            return False
        day = self._model_day(when)
        vec = wmm_field_ned_uT(lat_deg, lon_deg, alt_m, day)
        self._at, self._when = (lat_deg, lon_deg), when
        model = wmm_model(day).name
        label = f"{model} at {lat_deg:.4f}°, {lon_deg:.4f}° on {day}"
        self._use(ReferenceField(vec, math.hypot(*vec), "wmm", label))
        log.log(
            self.level,
            "magnetic reference from %s (%s): N %.2f E %.2f D %.2f µT",
            label.replace(" on", f", {alt_m:.0f} m on"),
            "the vehicle's GPS date" if when is not None else "the companion's clock",
            *vec,
        )
        return True

    def _model_day(self, when: dt.date | None) -> dt.date:
        """``when`` (default: the companion's clock, the last resort) within the models' span, said once if not."""
        day = when or dt.datetime.now(dt.timezone.utc).date()
        clamped = clamp_to_model(day)
        if clamped != day and not self._clamp_said:
            self._clamp_said = True
            log.warning(
                "the date %s is outside the World Magnetic Model's span (%s to %s): the field is taken on %s. If "
                "the clock is right and that is too far off, give the field instead: --declination DEG "
                "--inclination DEG (reference.magnetic: {declination_deg, inclination_deg} in the config)",
                day,
                WMM_FIRST_DAY,
                WMM_LAST_DAY,
                clamped,
            )
        return clamped


def clamp_to_model(day: dt.date) -> dt.date:
    """The nearest day within the models' span."""
    return min(max(day, WMM_FIRST_DAY), WMM_LAST_DAY)
