"""The vehicle's own acceleration from its GPS receiver's velocity, for the tilt update.

The accelerometer measures the specific force ``f = A(q) (a − g)`` (``a`` the vehicle's acceleration, NED;
``g = (0, 0, g)``). Gravity alone is ``f − A(q) a``; ``a`` is the receiver's velocity differenced,
``a_k = (v_k − v_{k−1}) / (t_k − t_{k−1})`` on the receiver's own fix times, as ArduPilot's DCM takes it
(``AP_AHRS_DCM::drift_correction``): raw GPS only, never the autopilot's fused velocity, so that the
attitude stays a second opinion. Without a vertical speed (MAVLink's GPS_RAW_INT) the down component is 0.

A glitch must not tilt the estimate, so a velocity is differenced only when it and the one before are
sound: a 3D fix, at least ``gps_min_satellites`` (ArduPilot's ``AHRS_GPS_MINSATS``), fix times that
advance by at most ``gps_max_interval_s``, and an acceleration within ``gps_max_accel_mps2`` (a step beyond
what the vehicle can do is the receiver's, not the vehicle's: it, and the step back, are refused). An
acceleration is held until ``gps_max_interval_s`` after the sample that brought it, then dropped (a stale
GPS): the filter is then exactly the filter without GPS.

The difference is late: it is the mean acceleration over the last fix interval ``Δt``, known ``L`` after the
interval's end and held until the next one, so what is removed follows the acceleration by about ``L + Δt``.
``L`` is the receiver's own latency (``gps_latency_s``) plus the fix's age when it is handed in, where the
fix time is on the vehicle clock (ArduPilot's GPS_RAW_INT.time_usec counts from boot: a telemetry link's
message comes ~0.1 s after its fix; a DataFlash GPS record is written at the fix). Gravity is constant in
the pre-filters' quasi-inertial frame (``R(q_g) a``, ``docs/fused.md``), so the accelerometer side is
compared as it was ``L + Δt`` ago, where it matches the acceleration removed (ArduPilot's DCM delays its
accelerometer sum by one GPS interval for the same reason): the pre-filtered ``a_I`` a delay line back,
minus the same pre-filters run on the acceleration, ``R(q_g) A(q) a``. What is lost is the gyro-only
attitude's drift over ``L + Δt``.
"""

from __future__ import annotations

import math
from collections import deque
from collections.abc import Sequence

from mavattitude.estimation.conventions import Vec3, rotate_ned_to_body_parts
from mavattitude.estimation.velocity import GPS_FIX_3D, GpsVelocity

from .mat3 import matvec
from .prefilter import EarthFramePrefilters
from .settings import FusedSettings

HISTORY_UPDATES = 128  # the delay line's length: L + Δt up to 2.5 s at 50 updates a second
_ZERO: Vec3 = (0.0, 0.0, 0.0)


class GpsAcceleration:
    """The differenced GPS velocity, gated (module docstring). :meth:`push` each velocity as it comes,
    :meth:`at` the acceleration to remove at a sample's time (``None``: none, or stale)."""

    def __init__(self, settings: FusedSettings) -> None:
        self.max_accel_mps2 = settings.gps_max_accel_mps2
        self.min_satellites = settings.gps_min_satellites
        self.max_interval_s = settings.gps_max_interval_s
        self.interval_s = 0.0  # the last fix interval differenced over
        self.age_s = 0.0  # how long after its fix time the last velocity came, where the times tell it
        self.accepted = 0  # accelerations formed
        self.refused = 0  # velocities refused: no 3D fix, too few satellites, a gap, or an impossible step
        self._last: GpsVelocity | None = None
        self.accel: Vec3 | None = None  # the acceleration held (:meth:`at` drops it once stale)
        self._until_s = -math.inf

    def push(self, v: GpsVelocity, now_s: float) -> None:
        """A velocity received with the sample at ``now_s`` (vehicle clock) or just after it."""
        last, self._last = self._last, v
        if v.fix_type < GPS_FIX_3D or 0 <= v.satellites < self.min_satellites:
            self._last = None
            self._refuse()
            return
        if last is None:
            return
        dt = v.fix_time_s - last.fix_time_s
        if not 0.0 < dt <= self.max_interval_s:
            self._refuse()
            return
        both = v.vertical_known and last.vertical_known  # a down speed known in only one is not differenced
        (n1, e1, d1), (n0, e0, d0) = v.vel_ned_mps, last.vel_ned_mps
        a = ((n1 - n0) / dt, (e1 - e0) / dt, (d1 - d0) / dt if both else 0.0)
        if not math.sqrt(a[0] * a[0] + a[1] * a[1] + a[2] * a[2]) <= self.max_accel_mps2:  # NaN refused too
            self._refuse()
            return
        self.accepted += 1
        self.interval_s = dt
        age = now_s - v.fix_time_s  # a fix time on the vehicle clock (MAVLink from ArduPilot) says how late it came
        self.age_s = age if 0.0 < age <= self.max_interval_s else 0.0
        self.accel, self._until_s = a, now_s + self.max_interval_s

    def _refuse(self) -> None:
        self.refused += 1
        self.accel = None

    def at(self, time_s: float) -> Vec3 | None:
        """The acceleration to remove from a sample at ``time_s`` (NED, m/s²), or ``None``."""
        if self.accel is not None and time_s > self._until_s:
            self.accel = None  # stale: the receiver stopped
        return self.accel


class GpsCompensation:
    """The pre-filtered specific force with the GPS acceleration removed, compared as it was ``L + Δt`` ago
    (module docstring). :meth:`gravity` once per update, with the pre-filters' outputs of that update."""

    def __init__(self, settings: FusedSettings, rate_hz: float) -> None:
        self.source = GpsAcceleration(settings)
        self._latency_s = settings.gps_latency_s
        self._kinematic = EarthFramePrefilters((settings.accel_lowpass_s, settings.accel_rejection_lowpass_s), rate_hz)
        self._period_s = 1.0 / rate_hz
        self._history: deque[tuple[Vec3, Vec3]] = deque(maxlen=HISTORY_UPDATES)
        self._active = False

    def design(self, rate_hz: float) -> None:
        """The update rate moved: the acceleration's pre-filters re-designed, the delay counted in its periods."""
        self._kinematic.design(rate_hz)
        self._period_s = 1.0 / rate_hz

    @property
    def active(self) -> bool:
        """Whether the last update's gravity had a GPS acceleration taken out of it."""
        return self._active

    def reset(self) -> None:
        """A (re)start: the pre-filters start again, so their past is gone."""
        self._history.clear()
        self._active = False

    def gravity(
        self, lp: tuple[Vec3, Vec3], r: Sequence[float], r_g: Sequence[float], time_s: float
    ) -> tuple[Vec3, Vec3] | None:
        """The two pre-filters' outputs ``lp`` of this update, gravity alone: the outputs ``L + Δt`` back minus
        the acceleration's; ``None`` without a current GPS acceleration (``lp`` is then the measurement).
        ``r``, ``r_g``: ``R(q)`` and ``R(q_g)``."""
        history = self._history
        history.append(lp)
        source = self.source
        # No acceleration held, at() would answer None: its call spared every update without GPS.
        accel = None if source.accel is None else source.at(time_s)
        if accel is None:
            self._active = False
            return None
        if not self._active:  # the acceleration's pre-filters start from rest, like the vehicle on the ground
            self._kinematic.reset()
            self._kinematic.step(_ZERO)
            self._active = True
        km, kr = self._kinematic.step(matvec(r_g, rotate_ned_to_body_parts(r, accel)))  # R(q_g) A(q) a
        back = round((self._latency_s + source.age_s + source.interval_s) / self._period_s)
        (m0, m1, m2), (j0, j1, j2) = history[-1 - back] if back < len(history) else history[0]
        return (m0 - km[0], m1 - km[1], m2 - km[2]), (j0 - kr[0], j1 - kr[1], j2 - kr[2])
