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


@dataclass(frozen=True)
class _Moments:
    """A block's per-axis sum and sum of squares of one sensor's samples, about its first sample (no cancellation)."""

    n: int
    origin: Vec3
    s1: tuple[float, ...]
    s2: tuple[float, ...]

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
        self._new_block((0.0,) * 3, (0.0,) * 3)

    def add(self, time_s: float, acc: Vec3, mag: Vec3 | None, gyr: Vec3) -> bool:
        """One tick; True when it closed a still block that changed :attr:`measured`."""
        elapsed = time_s - self._start_s
        if not 0.0 <= elapsed < BLOCK_S:  # NaN at the first tick, a block's end, or the clock gone back (a reboot)
            changed = elapsed >= BLOCK_S and self._close(elapsed)  # a block a reboot cut is dropped
            self._start_s = time_s
            self._new_block(acc, gyr)
            if changed:
                self.updated_s = time_s
                if self.since_s != self.since_s:  # NaN: the first time
                    self.since_s = time_s
        else:
            changed = False
        # The block's sums about its first sample, written out on local floats in one call a tick (an accumulator
        # object per sensor cost three calls and twice the time, at every tick of IGN and every fused sample taken).
        (a0, a1, a2), (g0, g1, g2) = acc, gyr
        o0, o1, o2, o3, o4, o5 = self._origin
        d0, d1, d2, d3, d4, d5 = a0 - o0, a1 - o1, a2 - o2, g0 - o3, g1 - o4, g2 - o5
        s0, s1, s2, s3, s4, s5, q0, q1, q2, q3, q4, q5 = self._sums
        self._sums = (
            s0 + d0, s1 + d1, s2 + d2, s3 + d3, s4 + d4, s5 + d5,
            q0 + d0 * d0, q1 + d1 * d1, q2 + d2 * d2, q3 + d3 * d3, q4 + d4 * d4, q5 + d5 * d5,
        )  # fmt: skip
        self._n += 1
        if mag is not None:
            if self._n_mag == 0:
                self._origin_mag = mag
            (m0, m1, m2), (o0, o1, o2) = mag, self._origin_mag
            d0, d1, d2 = m0 - o0, m1 - o1, m2 - o2
            s0, s1, s2, q0, q1, q2 = self._sums_mag
            self._sums_mag = (s0 + d0, s1 + d1, s2 + d2, q0 + d0 * d0, q1 + d1 * d1, q2 + d2 * d2)
            self._n_mag += 1
        return changed

    def _new_block(self, acc: Vec3, gyr: Vec3) -> None:
        """A block starts at this tick: its accelerometer and gyro sums about it (the magnetometer's about the first
        tick that carries a reading)."""
        self._n = self._n_mag = 0
        self._origin = (*acc, *gyr)
        self._origin_mag: Vec3 = (0.0, 0.0, 0.0)
        self._sums = (0.0,) * 12  # Σd per axis (accelerometer x y z, gyro x y z), then Σd², the same order
        self._sums_mag = (0.0,) * 6

    def _block(self) -> tuple[_Moments, _Moments, _Moments]:
        """The block's moments: accelerometer, magnetometer, gyro."""
        n, o, s = self._n, self._origin, self._sums
        return (
            _Moments(n, o[:3], s[0:3], s[6:9]),
            _Moments(self._n_mag, self._origin_mag, self._sums_mag[:3], self._sums_mag[3:]),
            _Moments(n, o[3:], s[3:6], s[9:12]),
        )

    def _close(self, span_s: float) -> bool:
        acc_m, mag_m, gyr_m = self._block()
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
        if not (_measured(accel_std, MIN_ACCEL_STD_MPS2) and _measured(mag_std, MIN_MAG_STD_UT)):
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
#: Nor is a σ below this, on any axis: a billionth of gravity and of a weak Earth's field (25 µT), where a
#: navigation-grade sensor's noise is a millionth, and a constant input's rounding (a stream with no noise at all)
#: is 1e-15 of the value: IGN's weights would be ~1e30 and its solve would fail
MIN_ACCEL_STD_MPS2 = 1e-9 * 9.80665
MIN_MAG_STD_UT = 1e-9 * 25.0


def _measured(std: tuple[float, ...], floor: float) -> bool:
    """Whether a sensor's per-axis σ are all noise: none below ``floor`` (a quantised sensor that never moved, a
    noise-free stream) nor lost in rounding beside the others (:data:`MIN_AXIS_FRACTION`)."""
    return min(std) > max(MIN_AXIS_FRACTION * max(std), floor)
