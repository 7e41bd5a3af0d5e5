"""The accelerometer's earth-frame pre-filters (``docs/fused.md``, "Accelerometer pre-filters").

Second-order Butterworth low-passes of a quasi-inertial vector (``R(q_g) a``), cut-off ``√2 / (2π τ)``
(VQF's pre-filter, Laidig & Seel 2023), designed by :func:`mavattitude.lowpass.butter2`.
"""

from __future__ import annotations

import math

from mavattitude.estimation.conventions import Vec3
from mavattitude.lowpass import Biquad, butter2

_UNUSED = (0.25, 0.0, 0.0)  # an output that is the input (τ = 0) runs as a 4-sample mean, never returned


class EarthFramePrefilters:
    """The two accelerometer pre-filters (module docstring): second-order Butterworth low-passes of the same
    quasi-inertial vector, cut-offs ``√2 / (2π τ)`` for ``τ_a`` and ``τ_j`` (τ = 0: that output is the input),
    started at steady state on their first input. A Butterworth low-pass's numerator is ``b₀ (1, 2, 1)``, so
    ``x + 2 x₋₁ + x₋₂`` is formed once for both: 39 float operations a step instead of 54."""

    def __init__(self, taus_s: tuple[float, float], rate_hz: float) -> None:
        self._taus_s = taus_s
        self._passed = (taus_s[0] == 0.0, taus_s[1] == 0.0)  # τ = 0: the input as it is
        self.biquads: tuple[Biquad | None, Biquad | None] = (None, None)
        self._coefficients = (_UNUSED, _UNUSED)  # (b₀, a₁, a₂) of each, read once a step
        self.design(rate_hz)
        self._state: tuple[Vec3, Vec3, Vec3, Vec3, Vec3, Vec3] | None = None

    def design(self, rate_hz: float) -> None:
        """(Re-)design for inputs at ``rate_hz``; the state (the last inputs and outputs) carries on."""
        self.biquads = tuple(  # type: ignore[assignment]
            butter2(math.sqrt(2.0) / (2.0 * math.pi * tau_s), rate_hz) if tau_s > 0.0 else None
            for tau_s in self._taus_s
        )
        self._coefficients = tuple(  # type: ignore[assignment]
            _UNUSED if bq is None else (bq.b0, bq.a1, bq.a2) for bq in self.biquads
        )

    def reset(self) -> None:
        self._state = None

    def step(self, x: Vec3) -> tuple[Vec3, Vec3]:
        """Both outputs for the next input ``x``."""
        if self._state is None:
            self._state = (x, x, x, x, x, x)  # x₋₁, x₋₂ and each filter's y₋₁, y₋₂, at steady state
        x_1, x_2, y_1, y_2, z_1, z_2 = self._state
        (p0, p1, p2), (q0, q1, q2) = x_1, x_2
        x0, x1, x2 = x
        s0, s1, s2 = x0 + 2.0 * p0 + q0, x1 + 2.0 * p1 + q1, x2 + 2.0 * p2 + q2
        (b, a1, a2), (c, e1, e2) = self._coefficients
        (m0, m1, m2), (n0, n1, n2) = y_1, y_2
        y = (b * s0 - a1 * m0 - a2 * n0, b * s1 - a1 * m1 - a2 * n1, b * s2 - a1 * m2 - a2 * n2)
        (m0, m1, m2), (n0, n1, n2) = z_1, z_2
        z = (c * s0 - e1 * m0 - e2 * n0, c * s1 - e1 * m1 - e2 * n1, c * s2 - e1 * m2 - e2 * n2)
        self._state = (x, x_1, y, y_1, z, z_1)
        passed_y, passed_z = self._passed
        return (x if passed_y else y), (x if passed_z else z)
