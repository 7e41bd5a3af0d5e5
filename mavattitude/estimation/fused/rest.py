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
        g0, g1, g2 = gyr
        a0, a1, a2 = acc
        if self._lp is None:
            self._lp = (g0, g1, g2, a0, a1, a2)
        k, (l0, l1, l2, l3, l4, l5) = self._alpha, self._lp
        l0, l1, l2 = l0 + k * (g0 - l0), l1 + k * (g1 - l1), l2 + k * (g2 - l2)
        l3, l4, l5 = l3 + k * (a0 - l3), l4 + k * (a1 - l4), l5 + k * (a2 - l5)
        self._lp = (l0, l1, l2, l3, l4, l5)
        # Squares written x * x, not x ** 2 (a libm pow call): they are only compared with thresholds. Each
        # test, and the difference it tests, only once the one before has passed: a moving sensor fails the
        # first or the second (the same outcome).
        x0, x1, x2 = g0 - l0, g1 - l1, g2 - l2
        if x0 * x0 + x1 * x1 + x2 * x2 < self._gyro2:
            w0, w1, w2 = l0 - bias[0], l1 - bias[1], l2 - bias[2]
            if w0 * w0 + w1 * w1 + w2 * w2 < self._gyro2:
                y0, y1, y2 = a0 - l3, a1 - l4, a2 - l5
                if y0 * y0 + y1 * y1 + y2 * y2 < self._accel2:
                    self._still_since_s = min(self._still_since_s, time_s)
                    return (w0, w1, w2) if time_s - self._still_since_s >= self._min_s else None
        self._still_since_s = math.inf
        return None
