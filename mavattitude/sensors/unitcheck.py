"""Whether the input's units are right: its accelerometer's and magnetometer's magnitudes, once, at the start.

A wrong unit scale is silent in the attitude of a snapshot solve (each vector is normalised) but not in
anything that reads a magnitude: the motion test (``| |f| − g |``) sees a vehicle that never rests, so the
compass is never judged, no noise is measured at rest and no field is measured without GPS; the fused filter
refuses every accelerometer update; and the weights of the paper's Eq. 21 (``a = 3 / tr(R_unit)``, with
``R_unit`` scaled by ``1 / |W|²``) tip toward the sensor read too large. Typical causes: a profile of another
autopilot or sensor (an ADIS16405's 3.33 mg per count read as ArduPilot's mg: 3.33 g), a CSV in g for m/s²
(0.102 g) or in milligauss for µT (10× the field).

The median magnitude of each sensor over the first ``WINDOW_S`` of samples (at least ``MIN_SAMPLES``; a
reading of exact zeros is no sensor and is left to the dead-sensor screening) is judged once:

- the specific force: ``g / 2 ≤ median |f| ≤ 2 g``. Averaged over seconds a vehicle's specific force is
  gravity's (it does not keep climbing); a coordinated 60° bank held throughout reads 2 g, and no vehicle falls
  at half of g for seconds. The shared recordings read 0.98–1.01 g;
- the magnetic field: the Earth's, 22–67 µT, within :data:`~mavattitude.sensors.magfit.UNITS_MARGIN` (the rule
  ``calibrate`` judges its fit by, :func:`~mavattitude.sensors.magfit.unlike_earth`). The shared recordings read
  41–76 µT (the ArduSub dive's compass the strongest).

A finding is said once, with what it measured; the remedy depends on where the units come from (the service's
``input.profile``, a CSV's columns), so the caller says it. No I/O.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from mavattitude.estimation.conventions import STANDARD_GRAVITY_MPS2, Array, Vec3
from mavattitude.estimation.motion import norm_rows
from mavattitude.sensors.magfit import unlike_earth

WINDOW_S = 5.0  # vehicle time from the first sample: a log's compass has spoken by then, a 2 Hz stream 10 times
MIN_SAMPLES = 10  # the fewest IMU samples judged on (a 2 Hz telemetry stream's first 5 s)
GRAVITY_BAND = (0.5, 2.0)  # median |f| / g (module docstring)
#: Unit slips with a name, by the factor they scale the reading: the one within 15 % of the ratio is suggested.
ACC_SLIPS = {
    1.0 / STANDARD_GRAVITY_MPS2: "readings in g taken for m/s²",
    STANDARD_GRAVITY_MPS2: "readings in m/s² taken for g",
}
SLIP_TOLERANCE = 1.15


@dataclass(frozen=True)
class UnitsFinding:
    """One sensor whose magnitude says its units are wrong: ``text`` for the log, ``short`` for a STATUSTEXT."""

    sensor: str  # "accelerometer" or "magnetometer"
    time_s: float  # the vehicle time it was judged at
    text: str
    short: str
    reads: str  # the median it read, with its unit ("3.33 g", "480 µT")


def unlike_gravity(median_mps2: float, what: str = "the median |f|") -> str | None:
    """Why a median specific force of ``median_mps2`` (``what``) cannot be a vehicle's, or ``None`` when it can."""
    ratio = median_mps2 / STANDARD_GRAVITY_MPS2
    low, high = GRAVITY_BAND
    if low <= ratio <= high:
        return None
    slips = [words for factor, words in ACC_SLIPS.items() if abs(math.log(ratio / factor)) < math.log(SLIP_TOLERANCE)]
    guess = f" ({slips[0]}?)" if slips else ""
    return f"{what} is {ratio:.3g} g, where a vehicle's is about 1 g{guess}"


class UnitsCheck:
    """The magnitudes of the first :data:`WINDOW_S` of samples, judged once (module docstring)."""

    def __init__(self) -> None:
        self.open = True  # still collecting: False once judged
        self.findings: list[UnitsFinding] = []
        self._first_s = math.nan
        self._acc: list[Array] = []
        self._mag: list[Array] = []
        self._samples = 0

    def add(self, time_s: Array, acc_mps2: Array, mag_uT: Array) -> list[UnitsFinding]:
        """Samples in order (``mag_uT`` NaN in rows without a reading); the findings when this judged them."""
        if not self.open or not len(time_s):
            return []
        if self._first_s != self._first_s:  # NaN: the first samples
            self._first_s = float(time_s[0])
        # the window ends with the first sample WINDOW_S on, once MIN_SAMPLES are in
        late = np.flatnonzero(time_s - self._first_s >= WINDOW_S)
        end = len(time_s) if not len(late) else max(int(late[0]) + 1, MIN_SAMPLES - self._samples)
        self._samples += min(end, len(time_s))
        self._acc.append(norm_rows(acc_mps2[:end]))
        self._mag.append(norm_rows(mag_uT[:end]))
        if end >= len(time_s) and not (len(late) and self._samples >= MIN_SAMPLES):
            return []
        self.open = False
        self.findings = self._judge(float(time_s[min(end, len(time_s)) - 1]))
        self._acc = self._mag = []
        return self.findings

    def add_sample(self, time_s: float, acc_mps2: Vec3, mag_uT: Vec3 | None) -> list[UnitsFinding]:
        """:meth:`add` of one sample (``mag_uT`` ``None``: no reading)."""
        mag = (math.nan,) * 3 if mag_uT is None else mag_uT
        return self.add(np.array([time_s]), np.array([acc_mps2], dtype=float), np.array([mag], dtype=float))

    def _judge(self, time_s: float) -> list[UnitsFinding]:
        findings = []
        acc, mag = _readings(self._acc), _readings(self._mag)
        over = f"over the first {WINDOW_S:g} s"
        if len(acc) and (why := unlike_gravity(float(np.median(acc)), f"its median |f| {over}")) is not None:
            g = f"{np.median(acc) / STANDARD_GRAVITY_MPS2:.3g} g"
            text, short = f"accelerometer: {why}: wrong units", f"accel reads {g}: check units, profile"
            findings.append(UnitsFinding("accelerometer", time_s, text, short, g))
        if len(mag) and (why := unlike_earth(float(np.median(mag)), f"its median |B| {over}")) is not None:
            field = f"{np.median(mag):.3g}"
            guess = "readings in gauss (100 µT) or milligauss (0.1 µT)?"
            text = f"magnetometer: {why}: wrong units ({guess})"
            short = f"compass reads {field} uT: check units, profile"  # (STATUSTEXT is ASCII)
            findings.append(UnitsFinding("magnetometer", time_s, text, short, f"{field} µT"))
        return findings


def _readings(norms: list[Array]) -> Array:
    """The magnitudes collected that are readings: finite, and not the exact zeros of a sensor that is not there."""
    every = np.concatenate(norms) if norms else np.empty(0)
    return every[every > 0.0]  # (NaN compares False)
