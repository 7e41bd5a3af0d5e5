"""The project's one exception hierarchy.

Every error mavattitude raises on purpose is a :class:`MavAttitudeError`, so callers (the service loop,
the CLI) can tell a reported failure from a bug. Subclasses name the layer that failed.
"""

from __future__ import annotations


class MavAttitudeError(Exception):
    """Base class of every error mavattitude raises on purpose."""


class InputError(MavAttitudeError, ValueError):
    """A measurement or parameter that the math cannot use: zero, NaN or infinite vectors, bad noise."""


class DegenerateGeometryError(InputError):
    """The two observed directions are too close to collinear to fix the attitude."""


class ConvergenceError(MavAttitudeError):
    """An iterative solver hit its iteration bound without meeting its tolerance."""


class SensorError(MavAttitudeError):
    """A MAVLink IMU message that cannot be turned into a trustworthy SI sample."""


class CalibrationError(MavAttitudeError):
    """Calibration data or a calibration fit that cannot be trusted."""


class ConfigError(MavAttitudeError):
    """A configuration file, environment variable or flag that is invalid."""


class LinkError(MavAttitudeError):
    """A MAVLink connection that cannot be opened or kept."""


class SigningError(LinkError):
    """A MAVLink 2 signing key or signing set-up that cannot be used."""


class DataFileError(MavAttitudeError):
    """An input data file (CSV, telemetry log) that cannot be read as asked."""
