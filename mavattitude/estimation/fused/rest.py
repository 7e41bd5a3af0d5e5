"""Rest detection for the zero-rate update of the gyro bias.

With ``ḡ``, ``ā`` first-order low-passes (time constant ``τ_r``) of gyro and accelerometer, the sensor is at
rest once ``|g − ḡ|``, ``|ḡ − b|`` < ``rest_gyro_threshold_radps`` and ``|a − ā|`` <
``rest_accel_threshold_mps2`` have held for ``rest_min_s``; the filter then measures the bias with
``z = ḡ − b``, ``H = [0 I]``, ``R = σ_r² I``.
"""

from __future__ import annotations

import math

from ..conventions import Vec3
from .settings import FusedSettings


class RestDetector:
    """Called once per update with the latest gyro and accelerometer samples."""

    def __init__(self, settings: FusedSettings, period_s: float) -> None:
        self._tau_s = settings.rest_filter_s
        self.set_period(period_s)
        self._gyro2 = settings.rest_gyro_threshold_radps**2
        self._accel2 = settings.rest_accel_threshold_mps2**2
        self._min_s = settings.rest_min_s
        self._lp: tuple[float, ...] | None = None
        self._still_since_s = math.inf

    def set_period(self, period_s: float) -> None:
        """The interval between calls, s (the low-passes' step)."""
        self._alpha = 1.0 - math.exp(-period_s / self._tau_s)

    def rate(self, gyr: Vec3, acc: Vec3, bias: Vec3, time_s: float) -> Vec3 | None:
        """``ḡ − b`` once at rest for ``rest_min_s``, else None."""
        if self._lp is None:
            self._lp = (*gyr, *acc)
        k, lp = self._alpha, self._lp
        lp = self._lp = (
            lp[0] + k * (gyr[0] - lp[0]),
            lp[1] + k * (gyr[1] - lp[1]),
            lp[2] + k * (gyr[2] - lp[2]),
            lp[3] + k * (acc[0] - lp[3]),
            lp[4] + k * (acc[1] - lp[4]),
            lp[5] + k * (acc[2] - lp[5]),
        )
        dev_g2 = (gyr[0] - lp[0]) ** 2 + (gyr[1] - lp[1]) ** 2 + (gyr[2] - lp[2]) ** 2
        dev_a2 = (acc[0] - lp[3]) ** 2 + (acc[1] - lp[4]) ** 2 + (acc[2] - lp[5]) ** 2
        rate = (lp[0] - bias[0], lp[1] - bias[1], lp[2] - bias[2])
        rate2 = rate[0] ** 2 + rate[1] ** 2 + rate[2] ** 2
        if not (dev_g2 < self._gyro2 and rate2 < self._gyro2 and dev_a2 < self._accel2):
            self._still_since_s = math.inf
            return None
        self._still_since_s = min(self._still_since_s, time_s)
        return rate if time_s - self._still_since_s >= self._min_s else None
