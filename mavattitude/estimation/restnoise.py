"""The sensors' noise measured from the stream while the vehicle is still: the R of the paper's Eq. 2 from the data.

IGN weighs each vector by its noise (Eq. 7–9 and the weight of Eq. 21 on ``R = diag(σ²)``) and reports the
covariance that weighting predicts; both are only as right as ``R``. A data sheet's σ (the config's ``noise:``)
is not the noise of the samples IGN sees: the front end's low-pass and resampling shrink it, the mounting and
the vehicle's vibration add to it. So the ticks themselves are measured, in blocks of ``BLOCK_S``:

- a block is *still* when the gyro's mean is below ``STILL_RATE_RADPS`` (a MEMS bias is well below it), its
  spread below ``STILL_GYRO_STD_RADPS`` and the accelerometer's below ``STILL_ACCEL_STD_MPS2`` on every axis
  (motion, taps, motors running: the noise is then not the sensor's alone);
- the still blocks' within-block variances are pooled per axis (``Σ (nᵢ − 1) sᵢ² / Σ (nᵢ − 1)``: each block's
  own mean removed, so a vehicle at rest in several attitudes, or a slow drift between blocks, adds nothing),
  for the accelerometer, the magnetometer (the ticks that carry a reading) and the gyroscope, whose pooled mean
  is its bias (:attr:`RestNoise.gyro_bias_radps`, with its standard error ``σ_g / √n`` per axis in
  :attr:`RestNoise.gyro_bias_std_radps`);
- once ``rest_s`` of still blocks are in, :attr:`RestNoise.measured` is the :class:`NoiseModel` of those σ,
  re-made as more rest comes (every block; :attr:`RestNoise.updated_s` the tick time it last was). Until then
  the caller keeps its prior.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from .conventions import Vec3
from .noise import NoiseModel

BLOCK_S = 1.0  # the still test's window, s
STILL_RATE_RADPS = math.radians(3.0)  # |mean gyro| below this: not turning (a consumer gyro's bias is < 1°/s)
STILL_GYRO_STD_RADPS = math.radians(1.0)  # the gyro's spread within a block: a tick's noise, not motion
STILL_ACCEL_STD_MPS2 = 0.2  # the accelerometer's spread within a block: no motion, tap or running motor
_MIN_SAMPLES = 5  # a block with fewer ticks (a gap) is not judged


class _Moments:
    """Per-axis sum and sum of squares of a block's samples, about its first sample (no cancellation)."""

    __slots__ = ("n", "origin", "s1", "s2")

    def __init__(self) -> None:
        self.n = 0
        self.origin: Vec3 = (0.0, 0.0, 0.0)
        self.s1 = [0.0, 0.0, 0.0]
        self.s2 = [0.0, 0.0, 0.0]

    def add(self, v: Vec3) -> None:
        if self.n == 0:
            self.origin = v
        self.n += 1
        (x, y, z), (ox, oy, oz), s1, s2 = v, self.origin, self.s1, self.s2
        dx, dy, dz = x - ox, y - oy, z - oz  # written out: a loop over the axes costs twice as much, every tick
        s1[0] += dx
        s1[1] += dy
        s1[2] += dz
        s2[0] += dx * dx
        s2[1] += dy * dy
        s2[2] += dz * dz

    def mean(self) -> Vec3:
        return tuple(o + s / self.n for o, s in zip(self.origin, self.s1, strict=True))  # type: ignore[return-value]

    def scatter(self) -> Vec3:
        """``(n − 1) s²`` per axis: the sum of squared deviations from the block's mean."""
        return tuple(max(0.0, s2 - s1 * s1 / self.n) for s1, s2 in zip(self.s1, self.s2, strict=True))  # type: ignore[return-value]


@dataclass
class _Pool:
    """Still blocks pooled: summed scatter and degrees of freedom per sensor, the gyro's summed mean."""

    acc: list[float]
    mag: list[float]
    gyr: list[float]
    gyr_sum: list[float]
    dof_acc: int = 0
    dof_mag: int = 0
    blocks: int = 0


class RestNoise:
    """Feed every tick the estimator sees (:meth:`add`); :attr:`measured` once ``rest_s`` of still blocks are in."""

    def __init__(self, rest_s: float) -> None:
        self.rest_s = rest_s
        self.still_s = 0.0  # still time pooled so far
        self.measured: NoiseModel | None = None
        self.since_s = math.nan  # the tick time :attr:`measured` was first there
        self.gyro_bias_radps: Vec3 | None = None
        self.gyro_bias_std_radps: Vec3 | None = None  # the bias's standard error per axis, rad/s
        self.updated_s = math.nan  # the tick time :attr:`measured` and the bias were last re-made
        self._pool = _Pool([0.0] * 3, [0.0] * 3, [0.0] * 3, [0.0] * 3)
        self._start_s = math.nan
        self._block = (_Moments(), _Moments(), _Moments())

    def add(self, time_s: float, acc: Vec3, mag: Vec3 | None, gyr: Vec3) -> bool:
        """One tick; True when it closed a still block that changed :attr:`measured`."""
        if not time_s - self._start_s < BLOCK_S:  # NaN at the first tick: a block starts
            changed = self._close(time_s - self._start_s)
            self._start_s = time_s
            self._block = (_Moments(), _Moments(), _Moments())
            if changed:
                self.updated_s = time_s
                if self.since_s != self.since_s:  # NaN: the first time
                    self.since_s = time_s
        else:
            changed = False
        acc_m, mag_m, gyr_m = self._block
        acc_m.add(acc)
        gyr_m.add(gyr)
        if mag is not None:
            mag_m.add(mag)
        return changed

    def _close(self, span_s: float) -> bool:
        acc_m, mag_m, gyr_m = self._block
        if acc_m.n < _MIN_SAMPLES or not self._still(acc_m, gyr_m):
            return False
        p = self._pool
        for total, block in ((p.acc, acc_m), (p.gyr, gyr_m)):
            for i, s in enumerate(block.scatter()):
                total[i] += s
        for i, m in enumerate(gyr_m.mean()):
            p.gyr_sum[i] += m * gyr_m.n
        p.dof_acc += acc_m.n - 1
        if mag_m.n >= _MIN_SAMPLES:
            for i, s in enumerate(mag_m.scatter()):
                p.mag[i] += s
            p.dof_mag += mag_m.n - 1
        p.blocks += 1
        self.still_s += span_s
        if self.still_s < self.rest_s or p.dof_mag == 0:
            return False
        accel_std = tuple(math.sqrt(s / p.dof_acc) for s in p.acc)
        mag_std = tuple(math.sqrt(s / p.dof_mag) for s in p.mag)
        if not (_measured(accel_std) and _measured(mag_std)):
            return False
        self.measured = NoiseModel(accel_std=accel_std, mag_std=mag_std)
        n_gyr = p.dof_acc + p.blocks  # every block's ticks: the gyro and accelerometer come together
        self.gyro_bias_radps = tuple(s / n_gyr for s in p.gyr_sum)  # type: ignore[assignment]
        self.gyro_bias_std_radps = tuple(math.sqrt(s / p.dof_acc / n_gyr) for s in p.gyr)  # type: ignore[assignment]
        return True

    @staticmethod
    def _still(acc: _Moments, gyr: _Moments) -> bool:
        n = gyr.n
        rate = math.sqrt(sum(m * m for m in gyr.mean()))
        gyr_std = max(math.sqrt(s / (n - 1)) for s in gyr.scatter())
        acc_std = max(math.sqrt(s / (acc.n - 1)) for s in acc.scatter())
        return rate < STILL_RATE_RADPS and gyr_std < STILL_GYRO_STD_RADPS and acc_std < STILL_ACCEL_STD_MPS2


#: An axis whose σ is this far below the sensor's largest is no noise measured but the arithmetic's rounding
#: (a simulator's noise-free axis: 2e-14 m/s² beside 3e-3), and IGN would take it as a vector known exactly
MIN_AXIS_FRACTION = 1e-6


def _measured(std: tuple[float, ...]) -> bool:
    """Whether a sensor's per-axis σ are all noise: none zero (a quantised sensor that never moved) nor lost in
    rounding beside the others (:data:`MIN_AXIS_FRACTION`)."""
    return min(std) > MIN_AXIS_FRACTION * max(std)
