"""The Earth's magnetic field in NED (µT): the solver's magnetometer reference.

:class:`MagneticReference` is the config's ``reference.magnetic`` (how the field is known),
:class:`ReferenceField` the field known at a moment, :class:`ReferenceTracker` the one the service keeps
current. From the config: two angles (declination ``D``, inclination ``I``, optional intensity ``F``):
``B = F [cos I cos D, cos I sin D, sin I]`` (without ``F`` a unit vector: the direction only, and no
|B| screening); or a vector ``field_ned_uT``. ``auto``: the World Magnetic Model at the vehicle's
position, through ``pygeomag`` (pure Python, WMM2025 coefficients valid 2025–2030, kept current with each
WMM release by its maintainer; no compiled dependency on a companion computer). It is recomputed when the
vehicle moves more than ``recompute_distance_km``; until a position arrives the reference is *waiting*
and nothing is guessed. The model's date is the vehicle's GPS date (or a log's), the companion's clock
only as a fallback (a board without a real-time clock is wrong until NTP); a date outside the model's
span is clamped to its edge, with one warning, never an error.
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
WMM_COEFFICIENTS = "wmm/WMM_2025.COF"
WMM_FIRST_DAY, WMM_LAST_DAY = dt.date(2025, 1, 1), dt.date(2029, 12, 31)  # WMM2025's span


@dataclass(frozen=True)
class ReferenceField:
    """The reference field, or ``field_ned_uT is None`` while waiting for a position."""

    field_ned_uT: Vec3 | None
    intensity_uT: float | None  # |B₀| for screening; None when only the direction is known
    source: str  # "config", "wmm" or "waiting"

    @property
    def waiting(self) -> bool:
        return self.field_ned_uT is None


WAITING = ReferenceField(None, None, "waiting")
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
            return ReferenceField(vec, self.intensity_uT, "config")
        if self.mode == "vector":
            vec = (float(self.field_ned_uT[0]), float(self.field_ned_uT[1]), float(self.field_ned_uT[2]))
            return ReferenceField(vec, math.hypot(*vec), "config")
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


def wmm_field_ned_uT(lat_deg: float, lon_deg: float, alt_m: float, when: dt.date) -> Vec3:
    """The WMM2025 main field at a position and date, NED, µT (pygeomag gives nT, altitude in km)."""
    from pygeomag import GeoMag  # imported on first use: only `auto` needs it

    try:
        result = _geomag(GeoMag).calculate(glat=lat_deg, glon=lon_deg, alt=alt_m / 1000.0, time=decimal_year(when))
    except Exception as exc:  # pygeomag raises plain exceptions for dates outside the model
        raise SensorError(f"World Magnetic Model failed at {lat_deg:.5f}°, {lon_deg:.5f}° on {when}: {exc}") from exc
    return (result.x / 1000.0, result.y / 1000.0, result.z / 1000.0)


_GEOMAG: Any = None


def _geomag(cls: Any) -> Any:
    """One model instance (reading the coefficient file is the slow part)."""
    global _GEOMAG
    if _GEOMAG is None:
        _GEOMAG = cls(coefficients_file=WMM_COEFFICIENTS, high_resolution=False)
    return _GEOMAG


def distance_km(lat1_deg: float, lon1_deg: float, lat2_deg: float, lon2_deg: float) -> float:
    """Great-circle distance (haversine)."""
    p1, p2 = math.radians(lat1_deg), math.radians(lat2_deg)
    dp, dl = p2 - p1, math.radians(lon2_deg - lon1_deg)
    a = math.sin(dp / 2) ** 2 + math.cos(p1) * math.cos(p2) * math.sin(dl / 2) ** 2
    return 2.0 * EARTH_RADIUS_KM * math.asin(min(1.0, math.sqrt(a)))


class ReferenceTracker:
    """The reference for the service: fixed from the config, or from WMM as positions arrive."""

    def __init__(self, setting: MagneticReference, recompute_distance_km: float = 5.0) -> None:
        self.mode = setting.mode
        self.recompute_distance_km = recompute_distance_km
        self._at: tuple[float, float] | None = None
        self._when: dt.date | None = None  # the vehicle's date the reference was taken on (None: the clock's)
        self._clamp_said = False
        self.reference = setting.fixed_field()

    @property
    def waiting(self) -> bool:
        return self.reference.waiting

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
        self.reference = ReferenceField(vec, math.hypot(*vec), "wmm")
        log.info(
            "magnetic reference from WMM2025 at %.4f°, %.4f°, %.0f m on %s (%s): N %.2f E %.2f D %.2f µT",
            lat_deg,
            lon_deg,
            alt_m,
            day,
            "the vehicle's GPS date" if when is not None else "the companion's clock",
            *vec,
        )
        return True

    def _model_day(self, when: dt.date | None) -> dt.date:
        """``when`` (default: the companion's clock, the last resort) within the model's span, said once if not."""
        day = when or dt.datetime.now(dt.timezone.utc).date()
        clamped = clamp_to_model(day)
        if clamped != day and not self._clamp_said:
            self._clamp_said = True
            log.warning(
                "the date %s is outside WMM2025's span (%s to %s): the field is taken on %s. If the clock is "
                "right and that is too far off, give the field instead: --declination DEG --inclination DEG "
                "(reference.magnetic: {declination_deg, inclination_deg} in the config)",
                day,
                WMM_FIRST_DAY,
                WMM_LAST_DAY,
                clamped,
            )
        return clamped


def clamp_to_model(day: dt.date) -> dt.date:
    """The nearest day within WMM2025's span."""
    return min(max(day, WMM_FIRST_DAY), WMM_LAST_DAY)
