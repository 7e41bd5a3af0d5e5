"""A GPS receiver's own velocity: what the fused filter differences into the vehicle's acceleration.

The decoders (:mod:`mavattitude.sensors.units` for MAVLink, the log readers' units modules) make it; the
filter (:mod:`mavattitude.estimation.fused.gps`) judges it. Never the autopilot's fused velocity.
"""

from __future__ import annotations

from dataclasses import dataclass

from .conventions import Vec3

GPS_FIX_3D = 3  # the fix type from which a receiver's position and velocity are used (MAVLink's GPS_FIX_TYPE)


@dataclass(frozen=True, slots=True)
class GpsVelocity:
    """A GPS receiver's velocity, NED, m/s, with what judges it.

    ``fix_time_s``: the receiver's time of the fix, any origin (only differences are used; a time on the
    vehicle clock also says how late it came); ``vertical_known``: false where the message has no vertical
    speed (GPS_RAW_INT), the down component then 0; ``satellites``: -1 where unknown."""

    fix_time_s: float
    vel_ned_mps: Vec3
    vertical_known: bool
    fix_type: int
    satellites: int
