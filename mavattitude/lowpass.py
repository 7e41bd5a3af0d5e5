"""Second-order Butterworth low-pass: design, steady-state start, and a vectorised batch form.

A signal helper below both the front end (:mod:`mavattitude.sensors.frontend`) and the fused filter's
pre-filters (:mod:`mavattitude.estimation.fused`): it imports neither.

Design (the bilinear transform with pre-warping, as ``scipy.signal.butter(2, fc, fs=fs)``): with
``K = tan(π fc / fs)``, ``b = [K², 2K², K²] / n``, ``a = [1, 2(K² − 1) / n, (1 − √2 K + K²) / n]``,
``n = 1 + √2 K + K²``. The streaming form is direct form I,
``y = b₀x + b₁x₋₁ + b₂x₋₂ − a₁y₋₁ − a₂y₋₂``: its state is the last two inputs and outputs, signals that
mean the same under any coefficients, so a re-design (the input rate changed) continues without a jump.
The steady state at level ``L`` (DC gain 1) is ``x₋₁ = x₋₂ = y₋₁ = y₋₂ = L``.

The batch form (:func:`filter_batch`) splits ``H(z) = d + r / (1 − p z⁻¹) + r̄ / (1 − p̄ z⁻¹)`` into
one complex first-order recurrence ``w[n] = p w[n−1] + x[n]``, ``y = d x + 2 Re(r w)``, solved in blocks
of ``L`` samples with a cumulative sum (``|p|⁻ᴸ ≤ 10⁴`` bounds the rounding to ~10⁻¹² relative) and the
block-to-block carry ``W_{b+1} = pᴸ W_b + e_b`` summed as a short geometric series.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from mavattitude.errors import SensorError

Array = NDArray[np.float64]

#: A cutoff at or above Nyquist cannot be designed; a slower input than 2.5 × cutoff is filtered at this
#: fraction of its rate instead (its sampling has already removed what lies above).
MAX_CUTOFF_FRACTION = 0.4
_BLOCK_GROWTH_LIMIT = 1e4  # |p|^-L within a block
_CARRY_NEGLIGIBLE = 1e-18  # |q|^K below which the block carry series stops
_CHUNK_SAMPLES = 1 << 15  # keeps the complex temporaries in cache-sized pieces


@dataclass(frozen=True)
class Biquad:
    """One designed section: ``y = (b0 + b1 z⁻¹ + b2 z⁻²) / (1 + a1 z⁻¹ + a2 z⁻²) x``."""

    b0: float
    b1: float
    b2: float
    a1: float
    a2: float
    fs_hz: float
    cutoff_hz: float

    def response_state(self, x1: Array, x2: Array, y1: Array, y2: Array) -> tuple[Array, Array]:
        """The transposed direct form II state ``(z1, z2)`` equal to a direct form I history."""
        z2 = self.b2 * x1 - self.a2 * y1
        return self.b1 * x1 - self.a1 * y1 + self.b2 * x2 - self.a2 * y2, z2


def butter2(cutoff_hz: float, fs_hz: float) -> Biquad:
    """The 2nd-order Butterworth low-pass for a sample rate (cutoff clamped to 0.4 × rate)."""
    if not (math.isfinite(fs_hz) and fs_hz > 0.0 and cutoff_hz > 0.0):
        raise SensorError(f"cannot design a low-pass at {cutoff_hz} Hz for a {fs_hz} Hz input")
    fc = min(cutoff_hz, MAX_CUTOFF_FRACTION * fs_hz)
    k = math.tan(math.pi * fc / fs_hz)
    kk = k * k
    n = 1.0 + math.sqrt(2.0) * k + kk
    b0 = kk / n
    return Biquad(b0, 2.0 * b0, b0, 2.0 * (kk - 1.0) / n, (1.0 - math.sqrt(2.0) * k + kk) / n, fs_hz, fc)


def filter_batch(bq: Biquad, x: Array, x_hist: Array, y_hist: Array) -> Array:
    """Filter ``x`` (channels, n: channels first, time contiguous) after the history
    ``x_hist = [x₋₁, x₋₂]``, ``y_hist = [y₋₁, y₋₂]`` (each (2, channels); all four equal to a level for
    the steady state there). Returns (channels, n)."""
    x = np.asarray(x, dtype=float)
    p = complex(np.roots([1.0, bq.a1, bq.a2])[0])
    d = bq.b2 / bq.a2
    r = (bq.b0 + bq.b1 / p + bq.b2 / (p * p)) / (1.0 - p.conjugate() / p)
    # the modal state w₋₁ whose free response, 2 Re(r pⁿ⁺¹ w₋₁), is the history's: y₀ = z1, y₁ = −a1 z1 + z2
    z1, z2 = bq.response_state(*np.asarray(x_hist, dtype=float), *np.asarray(y_hist, dtype=float))
    c1, c2 = 2.0 * r * p, 2.0 * r * p * p
    system = np.array([[c1.real, -c1.imag], [c2.real, -c2.imag]])
    u, v = np.linalg.solve(system, np.stack([z1, -bq.a1 * z1 + z2]))
    state = r * (u + 1j * v)  # carried as r·w: then y = d x + 2 Re(r w) needs no multiply by r
    block = max(1, math.floor(math.log(_BLOCK_GROWTH_LIMIT) / -math.log(abs(p))))
    chunk = block * max(1, _CHUNK_SAMPLES // block)
    j = np.tile(np.arange(block), chunk // block)
    tables = (r * p**-j, p**j, p ** (j + 1))  # the same for every chunk: computed once
    y = np.empty_like(x)
    for start in range(0, x.shape[1], chunk):
        y[:, start : start + chunk], state = _filter_chunk(p, d, block, tables, x[:, start : start + chunk], state)
    return y


def _filter_chunk(
    p: complex,
    d: float,
    block: int,
    tables: tuple[NDArray[np.complex128], ...],
    x: Array,
    state: NDArray[np.complex128],
) -> tuple[Array, NDArray[np.complex128]]:
    """One stretch of :func:`filter_batch`: ``(y, r·w)`` from ``x`` (channels, n) and ``r·w`` before it."""
    channels, n = x.shape
    blocks = -(-n // block)
    size = blocks * block
    r_p_neg, p_pos, p_pos1 = (table[:size] for table in tables)
    # time contiguous: every elementwise operation runs over long inner loops; zeros pad the last block
    xt = x if size == n else np.concatenate([x, np.zeros((channels, size - n))], axis=1)
    w = np.cumsum((xt * r_p_neg).reshape(channels, blocks, block), axis=2).reshape(channels, -1)
    w *= p_pos
    ends = w[:, block - 1 :: block]
    q = p**block
    # W_b, the state before block b: W_{b+1} = q W_b + e_b, summed until q^m is negligible
    carry = (q ** np.arange(blocks))[None, :] * state[:, None]
    terms = blocks if q == 0.0 else min(blocks, math.ceil(math.log(_CARRY_NEGLIGIBLE) / math.log(abs(q))))
    q_m = 1.0 + 0.0j
    for m in range(max(terms, 1)):
        carry[:, m + 1 :] += q_m * ends[:, : blocks - m - 1]
        q_m *= q
    w += np.repeat(carry, block, axis=1) * p_pos1
    y = d * xt + 2.0 * w.real
    return y[:, :n], w[:, n - 1]
