"""Gyro-aided attitude: a multiplicative error-state Kalman filter whose measurement is the IGN solution.

The paper (Liu et al. 2014) ends by noting that the accelerometer + magnetometer solution should aid a gyro,
because under sustained acceleration the accelerometer no longer points along gravity. This module is that
filter. Pure math: no I/O, no clock (time comes from the samples), no logging (events are counted in
:attr:`FusedFilter.counters` for the caller to report). ``docs/fused.md`` has the same equations, the
tuning and the measured figures.

State and error state
---------------------
Nominal state: attitude ``q`` (body → NED, scalar first) and gyro bias ``b`` (rad/s). Error state
``x = [δθ, δb]`` (6), with ``q_true = q ⊗ exp(δθ)`` (body-frame error angles, the paper's Eq. 14/28–30)
and ``b_true = b + δb``; ``P = E[x xᵀ]``.

Propagation — every input sample ``k``, ``Δt = t_k − t_{k−1}``, ``ω = g_k − b`` (calibrated gyro)::

    q ← q ⊗ exp(ω Δt),   exp(φ) = [cos(|φ|/2), sin(|φ|/2) φ/|φ|]
    δθ̇ = −[ω×] δθ − δb − n_g,   δḃ = n_b

The increments are composed in plain floats into ``Δq`` (the rotation since the last update); ``P`` is
propagated once per update interval ``T`` (``update_rate_hz``; a due update waits up to half an interval
for a sample that carries a magnetometer reading) with the exact attitude block and a trapezoidal bias
coupling::

    Φ = [[A(Δq), −T (I + A(Δq)) / 2], [0, I]],   A(Δq) = R(Δq)ᵀ
    P ← Φ P Φᵀ + diag((σ_g² T + (s_g θ)²) I, σ_b² T I)

``θ = Σ |ω| Δt`` is the angle turned in the interval: ``s_g`` covers gyro scale-factor error, so the
filter trusts the gyro less while it turns fast.

Accelerometer pre-filter (quasi-inertial low-pass)
--------------------------------------------------
Zero-mean non-gravitational acceleration (hand motion, vibration, manoeuvres that end) averages out in
an earth-fixed frame, not in the rotating body frame. With ``q_g`` the gyro-only attitude (propagated like
``q`` but never corrected, so the filter's corrections do not feed back into it)::

    a_I ← LP₂(R(q_g) a),   ã = A(q_g) a_I

``LP₂`` a second-order Butterworth low-pass at the update rate, cut-off ``√2 / (2π τ_a)``
(``accel_lowpass_s``; VQF's pre-filter, Laidig & Seel 2023). ``ã`` is what the accelerometer reads with
the oscillating part of the acceleration removed; sustained acceleration passes and is handled by the
rejection below.

Measurement 1 — the IGN solution (both vectors usable)
------------------------------------------------------
``q_m = solve(ã, m, mag_ref, NoiseModel(σ_a', σ_m'), method="ign").q`` with the error model
``q_m = q_true ⊗ exp(ν)``, ``ν ~ N(0, P_m)``, ``P_m`` IGN's predicted (sandwich) covariance — for isotropic
σ it is ``(Σᵢ (|Wᵢ|² I − Wᵢ Wᵢᵀ)/σᵢ²)⁻¹`` (:func:`ign_covariance`, equal to the estimation core's)::

    z = log(q* ⊗ q_m) ≈ δθ + ν,   H = [I 0],   R = P_m
    S = H P Hᵀ + R,   K = P Hᵀ S⁻¹,   x̂ = K z,   P ← (I − K H) P (I − K H)ᵀ + K R Kᵀ
    q ← q ⊗ exp(δθ̂),   b ← b + δb̂

Measurement 2 — tilt only (magnetometer disturbed, missing, or collinear with ``ã``)
----------------------------------------------------------------------------------
The unit specific force ``u = ã/|ã|`` against its prediction ``h = A(q) v_a`` (``v_a = acc_ref``)::

    u ≈ h + [h×] δθ,   z = u − h,   H = [[h×] 0],   R = (σ_a'/|ã|)² I,   K_θ ← (I − h hᵀ) K_θ

The projection keeps the correction off the vertical, so the heading coasts on the gyro (the Joseph form
keeps ``P`` exact for this sub-optimal gain).

Zero-rate update (rest)
-----------------------
With ``ḡ``, ``ā`` first-order low-passes (``rest_filter_s``) of gyro and accelerometer, the vehicle is at
rest once ``|g − ḡ|``, ``|ḡ − b|`` < ``rest_gyro_threshold_radps`` and ``|a − ā|`` <
``rest_accel_threshold_mps2`` have held for ``rest_min_s``; then ``z = ḡ − b``, ``H = [0 I]``,
``R = σ_r² I``: the bias converges in seconds at start-up and in every pause.

Acceleration rejection (smooth covariance inflation, never a switch)
--------------------------------------------------------------------
::

    σ_a'² = σ_a² + (k_n (|ã| − g))² + (k_r g ε)²

``ε``: the IGN residual as an angle — the measured angle between ``ã`` and ``m`` minus the reference
angle; not used when the magnetometer is disturbed (it would then accuse the accelerometer).

Magnetic-disturbance rejection
------------------------------
Field magnitude and dip against the reference, the dip measured against the *predicted* vertical::

    d = max(| |m| − |m_ref| | / (τ_n |m_ref|),  |δ(m, q) − δ_ref| / (τ_δ + 3 √tr P_θθ))

``|m_ref|`` is the magnitude as calibrated on the vehicle: learnt (a running mean) over the first
``mag_reference_s`` of clean field from start-up, so a calibration scale that differs from the reference's
(WMM's intensity, say) is not a permanent disturbance. A field disturbed for ``mag_relearn_s`` without a
break is adopted as the new reference (magnitude and dip): the vehicle has moved, not the magnet.

``d ≥ 1``: disturbed — the magnetometer updates nothing, measurement 2 runs, the heading coasts.
``d < 1``: measurement 1 with ``σ_m'² = σ_m² (1 + (d/d₀)²) ρ``; after a disturbance that lasted
``T_c`` the recovery factor ``ρ = 1 + (ρ₀ − 1) min(1, T_c/T_r) max(0, 1 − t_clean/T_r)`` takes the
heading error accrued while coasting back over seconds, without a jump.

Start-up and gaps
-----------------
The first sample with both vectors initialises ``q`` (and ``q_g``) from IGN and ``P_θθ`` from its
covariance, ``P_bb = σ_b0² I``. A gap longer than ``max_gap_s`` restarts from IGN, keeping the bias and
its covariance.

Output
------
:meth:`FusedFilter.push` returns a :class:`FusedEstimate` for every ``output_rate_hz`` tick passed (50 Hz,
ATTITUDE_QUATERNION's rate): the attitude carried to the tick with the current rate, the bias-corrected
body rates, the 3×3 attitude-error covariance and whether the magnetometer is being rejected.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike

from mavattitude.errors import DegenerateGeometryError, InputError
from mavattitude.estimation import NoiseModel, solve
from mavattitude.estimation.conventions import (
    Array,
    quat_from_rotvec_parts,
    quat_multiply_parts,
    quat_normalize_parts,
    rotate_ned_to_body_parts,
    rotation_matrix_parts,
    rotvec_from_quat_parts,
    skew,
)
from mavattitude.estimation.kernel import sym_det_adj

Quat = tuple[float, float, float, float]
_EYE3 = np.eye(3)


def _norm(v: Sequence[float]) -> float:
    return math.sqrt(v[0] * v[0] + v[1] * v[1] + v[2] * v[2])


def _butterworth(tau_s: float, rate_hz: float) -> tuple[float, float, float, float, float]:
    """Second-order Butterworth low-pass ``(b0, b1, b2, a1, a2)``, cut-off ``√2 / (2π τ)`` (VQF's choice)."""
    if tau_s <= 0.0:
        return (1.0, 0.0, 0.0, 0.0, 0.0)
    k = math.tan(math.pi * min(math.sqrt(2.0) / (2.0 * math.pi * tau_s), 0.45 * rate_hz) / rate_hz)
    norm = 1.0 / (1.0 + math.sqrt(2.0) * k + k * k)
    b0 = k * k * norm
    return (b0, 2.0 * b0, b0, 2.0 * (k * k - 1.0) * norm, (1.0 - math.sqrt(2.0) * k + k * k) * norm)


# 3×3 blocks as row-major 9-tuples of floats: the covariance algebra of every update runs on these (a numpy
# call costs about a microsecond, which on 3×3 and 6×6 matrices is more than the arithmetic).
Mat3 = tuple[float, float, float, float, float, float, float, float, float]
_ZERO3: Mat3 = (0.0,) * 9  # type: ignore[assignment]


def _mm(a: Mat3, b: Mat3, k: float = 0.0, c: Mat3 | None = None) -> Mat3:
    """``a b + k c`` (one call where the updates need both: a call costs as much as the sum)."""
    a0, a1, a2, a3, a4, a5, a6, a7, a8 = a
    b0, b1, b2, b3, b4, b5, b6, b7, b8 = b
    c0, c1, c2, c3, c4, c5, c6, c7, c8 = _ZERO3 if c is None else c
    return (
        a0 * b0 + a1 * b3 + a2 * b6 + k * c0,
        a0 * b1 + a1 * b4 + a2 * b7 + k * c1,
        a0 * b2 + a1 * b5 + a2 * b8 + k * c2,
        a3 * b0 + a4 * b3 + a5 * b6 + k * c3,
        a3 * b1 + a4 * b4 + a5 * b7 + k * c4,
        a3 * b2 + a4 * b5 + a5 * b8 + k * c5,
        a6 * b0 + a7 * b3 + a8 * b6 + k * c6,
        a6 * b1 + a7 * b4 + a8 * b7 + k * c7,
        a6 * b2 + a7 * b5 + a8 * b8 + k * c8,
    )


def _transpose(a: Mat3) -> Mat3:
    return (a[0], a[3], a[6], a[1], a[4], a[7], a[2], a[5], a[8])


def _axpy(a: Mat3, k: float, b: Mat3) -> Mat3:
    """``a + k b``."""
    return (
        a[0] + k * b[0],
        a[1] + k * b[1],
        a[2] + k * b[2],
        a[3] + k * b[3],
        a[4] + k * b[4],
        a[5] + k * b[5],
        a[6] + k * b[6],
        a[7] + k * b[7],
        a[8] + k * b[8],
    )


def _symmetric(a: Mat3, diag: float = 0.0) -> Mat3:
    """``(a + aᵀ)/2 + diag I``: removes the rounding asymmetry of a covariance update."""
    xy, xz, yz = 0.5 * (a[1] + a[3]), 0.5 * (a[2] + a[6]), 0.5 * (a[5] + a[7])
    return (a[0] + diag, xy, xz, xy, a[4] + diag, yz, xz, yz, a[8] + diag)


def _matvec(a: Mat3, x: Sequence[float]) -> tuple[float, float, float]:
    return (
        a[0] * x[0] + a[1] * x[1] + a[2] * x[2],
        a[3] * x[0] + a[4] * x[1] + a[5] * x[2],
        a[6] * x[0] + a[7] * x[1] + a[8] * x[2],
    )


def _block_update(
    p_mm: Mat3, p_om: Mat3, p_oo: Mat3, r: Mat3, z: Sequence[float]
) -> tuple[Mat3, Mat3, Mat3, tuple[float, float, float], tuple[float, float, float]]:
    """Kalman update for a direct measurement of one 3-block ``m`` of the error state (``H`` = [I 0] or [0 I]).

    ``S = P_mm + R``, ``K = P[:, m] S⁻¹``, ``P ← P − K P[m, :]``, ``x̂ = K z``; the other block is ``o``
    (``p_om`` its rows, ``m``'s columns). Returns ``(P_mm, P_om, P_oo, x̂_m, x̂_o)``. Written with
    ``G = −K`` (from ``(−S)⁻¹``, which is exactly ``−S⁻¹``) so that each block is one ``a b + c``.
    """
    neg_s_inv = _inverse_sym3(
        -p_mm[0] - r[0], -p_mm[1] - r[1], -p_mm[2] - r[2], -p_mm[4] - r[4], -p_mm[5] - r[5], -p_mm[8] - r[8]
    )
    g_m, g_o = _mm(p_mm, neg_s_inv), _mm(p_om, neg_s_inv)
    neg_z = (-z[0], -z[1], -z[2])
    return (
        _symmetric(_mm(g_m, p_mm, 1.0, p_mm)),
        _mm(g_o, p_mm, 1.0, p_om),
        _symmetric(_mm(g_o, _transpose(p_om), 1.0, p_oo)),
        _matvec(g_m, neg_z),
        _matvec(g_o, neg_z),
    )


def _attitude_h(h_theta: Array) -> Array:
    """``H = [h_θ 0]``: a measurement of the attitude error only."""
    return np.hstack([h_theta, np.zeros((h_theta.shape[0], 3))])


def ign_covariance(acc: Sequence[float], mag: Sequence[float], sigma_acc: float, sigma_mag: float) -> Array:
    """IGN's predicted error-angle covariance (rad²) for isotropic per-sensor noise, in closed form.

    With ``R = σ² I`` the unit-vector covariance is ``σ²/|W|² (I − ŵŵᵀ)`` and the paper's weight
    ``a = 3|W|²/(2σ²)``, so the sandwich of :func:`~mavattitude.estimation.predicted_covariance`
    collapses to ``P = (Σᵢ (|wᵢ|² I − wᵢ wᵢᵀ))⁻¹`` with ``wᵢ = Wᵢ/σᵢ`` — the same matrix (tested), in
    plain floats.
    """
    a = (acc[0] / sigma_acc, acc[1] / sigma_acc, acc[2] / sigma_acc)
    m = (mag[0] / sigma_mag, mag[1] / sigma_mag, mag[2] / sigma_mag)
    return np.array(_ign_covariance_parts(a, m)).reshape(3, 3)


def _ign_covariance_parts(a: Sequence[float], m: Sequence[float]) -> Mat3:
    """:func:`ign_covariance` for vectors already in units of their σ, as a 9-tuple."""
    ax, ay, az = a
    mx, my, mz = m
    return _inverse_sym3(
        ay * ay + az * az + my * my + mz * mz,
        -ax * ay - mx * my,
        -ax * az - mx * mz,
        ax * ax + az * az + mx * mx + mz * mz,
        -ay * az - my * mz,
        ax * ax + ay * ay + mx * mx + my * my,
    )


def _inverse_sym3(xx: float, xy: float, xz: float, yy: float, yz: float, zz: float) -> Mat3:
    """Inverse of a symmetric 3×3 matrix by cofactors (:func:`~.kernel.sym_det_adj`), as a 9-tuple.

    Not :func:`~.kernel.sym_inverse`: that one is NaN unless the matrix is positive definite, and
    :func:`_block_update` inverts the negative definite ``−S``.
    """
    det, (c00, c01, c02, c11, c12, c22) = sym_det_adj((xx, xy, xz, yy, yz, zz))
    k = 1.0 / det
    c00, c01, c02, c11, c12, c22 = c00 * k, c01 * k, c02 * k, c11 * k, c12 * k, c22 * k
    return (c00, c01, c02, c01, c11, c12, c02, c12, c22)


@dataclass(frozen=True)
class FusedSettings:
    """Tuning of the gyro-aided filter (one configuration for every vehicle unless a profile says otherwise).

    The σ values are *effective* noise: they include model error (sensor calibration residue,
    non-gravitational acceleration, local field) as well as sensor noise, which is why they are far above
    a data sheet's figures.
    """

    gyro_noise_radps: float = 0.003  # σ_g, angle random walk, rad/s/√Hz
    gyro_scale_std: float = 0.005  # s_g, gyro scale-factor error, per rad turned
    gyro_bias_walk_radps2: float = 3e-5  # σ_b, bias random walk, rad/s/√s
    gyro_bias_init_radps: float = 0.02  # σ_b0, start-up bias uncertainty, rad/s (≈ 1°/s)
    accel_std_mps2: float = 0.2  # σ_a, per axis, of the pre-filtered specific force
    accel_lowpass_s: float = 0.7  # τ_a of the quasi-inertial pre-filter (0: off)
    accel_norm_gain: float = 6.0  # k_n: σ added per m/s² of | |ã| − g |
    accel_residual_gain: float = 0.0  # k_r: σ added per g·rad of IGN residual
    mag_std_uT: float = 3.5  # σ_m, per axis
    mag_norm_tolerance: float = 0.1  # τ_n, fraction of |m_ref| beyond which the field is disturbed
    mag_dip_tolerance_deg: float = 10.0  # τ_δ
    mag_reference_s: float = 20.0  # τ_ref: the field's magnitude is learnt over this much clean field
    mag_relearn_s: float = 60.0  # T_new: a field disturbed this long without a break becomes the new reference
    mag_soft_fraction: float = 0.5  # d₀: inflation scale below the hard threshold
    mag_recovery_factor: float = 10.0  # ρ₀: σ_m² multiplier just after a long disturbance
    mag_recovery_s: float = 3.0  # T_r
    rest_gyro_threshold_radps: float = math.radians(2.0)
    rest_accel_threshold_mps2: float = 0.5
    rest_min_s: float = 1.5
    rest_filter_s: float = 0.5  # τ_r of the rest detector's low-passes
    rest_gyro_std_radps: float = 0.002  # σ_r of the zero-rate pseudo-measurement (0: off)
    gravity_mps2: float = 9.80665
    update_rate_hz: float = 50.0
    output_rate_hz: float = 50.0
    max_gap_s: float = 0.5

    def __post_init__(self) -> None:
        for name, value in vars(self).items():
            if not math.isfinite(value) or value < 0.0:
                raise InputError(f"FusedSettings.{name} must be finite and non-negative, got {value!r}")
        positive = (
            "gravity_mps2",
            "mag_reference_s",
            "mag_relearn_s",
            "rest_filter_s",
            "update_rate_hz",
            "output_rate_hz",
            "max_gap_s",
            "mag_norm_tolerance",
        )
        for name in positive:
            if getattr(self, name) <= 0.0:
                raise InputError(f"FusedSettings.{name} must be positive, got {getattr(self, name)!r}")


@dataclass(frozen=True)
class FusedEstimate:
    """One output tick: attitude (body → NED), body rates with the bias removed, 3×3 error covariance (rad²)."""

    time_s: float
    q: Array
    rates_radps: Array
    covariance: Array
    bias_radps: Array
    mag_disturbed: bool


@dataclass
class _Interval:
    """Gyro integration since the last measurement update, in plain floats (the per-sample hot path)."""

    dq: Quat = (1.0, 0.0, 0.0, 0.0)
    duration_s: float = 0.0
    angle_rad: float = 0.0


class FusedFilter:
    """The gyro-aided filter; feed it every calibrated IMU sample with :meth:`push`."""

    def __init__(
        self,
        settings: FusedSettings,
        mag_ref: ArrayLike,
        acc_ref: ArrayLike = (0.0, 0.0, -1.0),
    ) -> None:
        self.settings = settings
        self.acc_ref = np.asarray(acc_ref, dtype=float)
        self._q: Quat | None = None
        self.set_mag_ref(mag_ref)
        self._field_n = 0.0
        self._noise = NoiseModel(accel_std=(settings.accel_std_mps2,) * 3, mag_std=(settings.mag_std_uT,) * 3)
        self.counters: dict[str, int] = {
            "ign_updates": 0,
            "tilt_updates": 0,
            "mag_disturbed": 0,
            "degenerate": 0,
            "skipped_updates": 0,
            "restarts": 0,
            "rest_updates": 0,
            "mag_relearned": 0,
        }
        self._bias = (0.0, 0.0, 0.0)
        # P = [[P_θθ, P_θb], [P_θbᵀ, P_bb]] as three 9-tuples (see _mm)
        self._p_tt = self._p_tb = self._p_bb = _ZERO3
        self._t_last = 0.0
        self._gyr_last = (0.0, 0.0, 0.0)
        self._interval = _Interval()
        self._update_period_s = 1.0 / settings.update_rate_hz
        self._output_period_s = 1.0 / settings.output_rate_hz
        self._next_update_s = 0.0
        self._next_output_s = 0.0
        self._clean_since_s = -math.inf
        self._disturbed_since_s = -math.inf
        self._coast_s = 0.0
        self._q_gyro: Quat = (1.0, 0.0, 0.0, 0.0)
        self._acc_lp: list[list[float]] | None = None
        self._biquad = _butterworth(settings.accel_lowpass_s, settings.update_rate_hz)
        self._lp: list[float] | None = None  # low-passed gyro and accelerometer (rest detection)
        self._still_since_s = math.inf
        self._rest_alpha = 1.0 - math.exp(-self._update_period_s / settings.rest_filter_s)
        self._disturbed = False

    # --- public state -------------------------------------------------------------------------------
    @property
    def q(self) -> Array:
        """Current attitude, body → NED, ``w ≥ 0``."""
        return np.array(self._current_q())

    @property
    def bias_radps(self) -> Array:
        return np.array(self._bias)

    @property
    def covariance(self) -> Array:
        """6×6 covariance of ``[δθ (rad), δb (rad/s)]`` at the last update."""
        return self._p_matrix()

    def _p_matrix(self) -> Array:
        """``P`` as a 6×6 array."""
        tt, tb, bb = (np.array(m).reshape(3, 3) for m in (self._p_tt, self._p_tb, self._p_bb))
        return np.block([[tt, tb], [tb.T, bb]])

    def _set_p(self, p: Array) -> None:
        """Store a 6×6 ``P`` (symmetrised) as the three blocks."""
        p = 0.5 * (p + p.T)
        self._p_tt = tuple(p[:3, :3].ravel().tolist())
        self._p_tb = tuple(p[:3, 3:].ravel().tolist())
        self._p_bb = tuple(p[3:, 3:].ravel().tolist())

    def set_mag_ref(self, mag_ref: ArrayLike) -> None:
        """A new NED field (e.g. WMM after a move): used from the next update on, the state kept.

        Its magnitude is a start value only (it is learnt from the data, see the module docstring)."""
        mag = np.asarray(mag_ref, dtype=float)
        if mag.shape != (3,) or self.acc_ref.shape != (3,):
            raise InputError(f"references must be 3-vectors, got {mag_ref!r} and {self.acc_ref!r}")
        norms = float(np.linalg.norm(mag)), float(np.linalg.norm(self.acc_ref))
        if not all(math.isfinite(n) and n > 0.0 for n in norms):
            raise InputError(f"references must be finite and non-zero, got {mag_ref!r} and {self.acc_ref!r}")
        self.mag_ref = mag
        self._mag_ref_t, self._acc_ref_t = tuple(mag.tolist()), tuple(self.acc_ref.tolist())  # solve's fast path
        self._v_acc = tuple(float(v) / norms[1] for v in self.acc_ref)
        # Reference angle between the two vectors, and the field's dip below the horizontal.
        cos_ref = float(self.acc_ref @ mag) / (norms[0] * norms[1])
        self._ref_angle = math.acos(max(-1.0, min(1.0, cos_ref)))
        self._dip_ref = math.asin(max(-1.0, min(1.0, -cos_ref)))
        if self._q is None:
            self._norm_ref = norms[0]

    # --- the per-sample entry point -----------------------------------------------------------------
    def push(
        self,
        time_s: float,
        gyr_radps: ArrayLike,
        acc_mps2: ArrayLike,
        mag_uT: ArrayLike | None,
    ) -> list[FusedEstimate]:
        """Take one calibrated sample (body frame, SI, vehicle time); return the output ticks it completes."""
        gx, gy, gz = gyr = (float(gyr_radps[0]), float(gyr_radps[1]), float(gyr_radps[2]))
        if not math.isfinite(gx + gy + gz + time_s):
            raise InputError(f"non-finite gyro sample or time at t={time_s!r}")
        if self._q is None:
            return self._start(time_s, gyr, acc_mps2, mag_uT)
        dt = time_s - self._t_last
        if dt <= 0.0:
            raise InputError(f"sample time {time_s!r} s does not advance past {self._t_last!r} s")
        if dt > self.settings.max_gap_s:
            self.counters["restarts"] += 1
            return self._start(time_s, gyr, acc_mps2, mag_uT)
        self._integrate(dt, gx, gy, gz)
        self._t_last = time_s
        self._gyr_last = gyr
        # A due update waits up to half a period for a sample that carries a magnetometer reading.
        due = self._next_update_s
        if time_s >= due and (mag_uT is not None or time_s >= due + 0.5 * self._update_period_s):
            self._next_update_s = max(due + self._update_period_s, time_s)
            self._update(acc_mps2, mag_uT, time_s)
        if time_s < self._next_output_s:
            return []
        return self._outputs(time_s)

    # --- propagation --------------------------------------------------------------------------------
    def _integrate(self, dt: float, gx: float, gy: float, gz: float) -> None:
        """``Δq ← Δq ⊗ exp(ω Δt)`` in plain floats, with the sample's bias-corrected rate."""
        b = self._bias
        vx, vy, vz = dt * (gx - b[0]), dt * (gy - b[1]), dt * (gz - b[2])
        iv = self._interval
        iv.dq = quat_multiply_parts(iv.dq, quat_from_rotvec_parts(vx, vy, vz))
        iv.duration_s += dt
        iv.angle_rad += math.sqrt(vx * vx + vy * vy + vz * vz)

    def _current_q(self) -> Quat:
        if self._q is None:
            raise InputError("the fused filter has no attitude yet: it needs one sample with acc and mag")
        if self._interval.duration_s == 0.0:  # just updated: q is already normalised, with w ≥ 0
            return self._q
        return quat_normalize_parts(quat_multiply_parts(self._q, self._interval.dq))

    def _propagate(self) -> None:
        """Move the interval's rotation into ``q`` and propagate ``P`` over it (``Φ`` in the docstring)."""
        s, iv = self.settings, self._interval
        t = iv.duration_s
        r = rotation_matrix_parts(iv.dq)  # R(Δq), row-major; A(Δq) = R(Δq)ᵀ
        a, c = _transpose(r), -0.5 * t
        # Φ = [[A, c (I + A)], [0, I]] by blocks: with X = [A, c (I + A)] P = A Y + c [P_θbᵀ, P_bb],
        # Y = [P_θθ + c P_θbᵀ, P_θb + c P_bb]: P_θb ← X_b, P_θθ ← (X_θ + c X_b) Aᵀ + c X_b.
        tt, tb, bb = self._p_tt, self._p_tb, self._p_bb
        bt = _transpose(tb)
        x_t = _mm(a, _axpy(tt, c, bt), c, bt)
        x_b = _mm(a, _axpy(tb, c, bb), c, bb)
        q_theta = s.gyro_noise_radps**2 * t + (s.gyro_scale_std * iv.angle_rad) ** 2
        q_bias = s.gyro_bias_walk_radps2**2 * t
        self._p_tt = _symmetric(_mm(_axpy(x_t, c, x_b), r, c, x_b), q_theta)
        self._p_tb = x_b
        self._p_bb = _symmetric(bb, q_bias)
        self._q = self._current_q()
        self._q_gyro = quat_normalize_parts(quat_multiply_parts(self._q_gyro, iv.dq))
        iv.dq, iv.duration_s, iv.angle_rad = (1.0, 0.0, 0.0, 0.0), 0.0, 0.0

    # --- measurement updates ------------------------------------------------------------------------
    def _update(self, acc_mps2: ArrayLike, mag_uT: ArrayLike | None, time_s: float) -> None:
        """Propagate ``P`` to now, then the zero-rate, IGN or tilt-only update (module docstring)."""
        self._propagate()
        s = self.settings
        raw = (float(acc_mps2[0]), float(acc_mps2[1]), float(acc_mps2[2]))
        if not math.isfinite(raw[0] + raw[1] + raw[2]) or _norm(raw) < 1e-3 * s.gravity_mps2:
            self.counters["skipped_updates"] += 1
            return
        if s.rest_gyro_std_radps > 0.0:
            self._rest_update(raw, time_s)
        acc = self._inertial_lowpass(raw)
        acc_norm = _norm(acc)
        mag = None if mag_uT is None else (float(mag_uT[0]), float(mag_uT[1]), float(mag_uT[2]))
        d = mag_norm = math.inf
        if mag is not None:
            d, mag_norm, dip = self._mag_check(mag)
            self._track_disturbance(d >= 1.0, time_s)
            if math.isfinite(d):
                self._learn_field(mag_norm, dip, d >= 1.0, time_s)
        sigma_a2 = s.accel_std_mps2**2 + (s.accel_norm_gain * (acc_norm - s.gravity_mps2)) ** 2
        if mag is not None and d < 1.0:
            residual = self._vector_residual(acc, acc_norm, mag, mag_norm)
            sigma_a2 += (s.accel_residual_gain * s.gravity_mps2 * residual) ** 2
        # Past half a radian of direction noise the accelerometer tells nothing the gyro does not know; the
        # cap keeps the σ the solver accepts (σ/|vector| ≤ 1).
        sigma_a = min(math.sqrt(sigma_a2), _MAX_UNIT_STD * acc_norm)
        if mag is not None and d < 1.0:
            sigma_m2 = s.mag_std_uT**2 * (1.0 + (d / s.mag_soft_fraction) ** 2) * self._recovery_factor(time_s)
            sigma_m = min(math.sqrt(sigma_m2), _MAX_UNIT_STD * mag_norm)
            try:
                self._ign_update(acc, mag, sigma_a, sigma_m)
                return
            except DegenerateGeometryError:
                self.counters["degenerate"] += 1
        self._tilt_update(acc, acc_norm, sigma_a)

    def _inertial_lowpass(self, acc: tuple[float, float, float]) -> tuple[float, float, float]:
        """Specific force low-passed in the gyro-only (quasi-inertial) frame, expressed in the body frame."""
        r = rotation_matrix_parts(self._q_gyro)
        x = _matvec(r, acc)  # R(q_g) a
        if self._acc_lp is None:
            self._acc_lp = [[v, v, v, v] for v in x]  # x1, x2, y1, y2 at steady state
        b0, b1, b2, a1, a2 = self._biquad
        y = []
        for v, st in zip(x, self._acc_lp, strict=True):
            out = b0 * v + b1 * st[0] + b2 * st[1] - a1 * st[2] - a2 * st[3]
            st[1], st[0], st[3], st[2] = st[0], v, st[2], out
            y.append(out)
        return rotate_ned_to_body_parts(r, y)

    def _mag_check(self, mag: tuple[float, float, float]) -> tuple[float, float, float]:
        """``(d, |m|, dip)``: ``d`` of the module docstring (≥ 1 disturbed), the dip against the predicted vertical."""
        s = self.settings
        norm = _norm(mag)
        if not math.isfinite(norm) or norm == 0.0:
            return math.inf, norm, 0.0
        r = rotation_matrix_parts(self._q)
        dip = math.asin(max(-1.0, min(1.0, (r[6] * mag[0] + r[7] * mag[1] + r[8] * mag[2]) / norm)))
        d_norm = abs(norm - self._norm_ref) / (s.mag_norm_tolerance * self._norm_ref)
        if s.mag_dip_tolerance_deg == 0.0:
            return d_norm, norm, dip
        # The predicted vertical is itself uncertain: widen the dip tolerance by 3σ of the attitude error.
        p = self._p_tt
        tolerance = math.radians(s.mag_dip_tolerance_deg) + 3.0 * math.sqrt(p[0] + p[4] + p[8])
        return max(d_norm, abs(dip - self._dip_ref) / tolerance), norm, dip

    def _learn_field(self, norm: float, dip: float, disturbed: bool, time_s: float) -> None:
        """Learn the local field's magnitude over the first ``τ_ref`` of clean field; adopt a new field after ``T_new``.

        The magnitude as calibrated on this vehicle (a scale that differs from the reference's, e.g. WMM, is
        then not a permanent disturbance); the dip stays the reference's until a new field is adopted.
        """
        if disturbed:
            if time_s - self._disturbed_since_s < self.settings.mag_relearn_s:
                return
            self.counters["mag_relearned"] += 1
            self._disturbed_since_s, self._field_n, self._dip_ref = time_s, 0.0, dip
        if self._field_n * self._update_period_s >= self.settings.mag_reference_s:
            return
        self._field_n += 1.0
        self._norm_ref += (norm - self._norm_ref) / self._field_n

    def _vector_residual(
        self, acc: tuple[float, ...], acc_norm: float, mag: tuple[float, ...], mag_norm: float
    ) -> float:
        """IGN residual as an angle: measured angle between the vectors minus the reference angle."""
        cos_m = (acc[0] * mag[0] + acc[1] * mag[1] + acc[2] * mag[2]) / (acc_norm * mag_norm)
        return abs(math.acos(max(-1.0, min(1.0, cos_m))) - self._ref_angle)

    def _track_disturbance(self, disturbed: bool, time_s: float) -> None:
        """Remember when a disturbance started and how long the last one lasted (the recovery ramp)."""
        if disturbed:
            self.counters["mag_disturbed"] += 1
            if not self._disturbed:
                self._disturbed_since_s = time_s
        elif self._disturbed:
            self._clean_since_s = time_s
            self._coast_s = time_s - self._disturbed_since_s
        self._disturbed = disturbed

    def _recovery_factor(self, time_s: float) -> float:
        """``ρ``: σ_m² multiplier after a disturbance, scaled by how long the heading coasted."""
        s = self.settings
        elapsed = time_s - self._clean_since_s
        if s.mag_recovery_s == 0.0 or not elapsed < s.mag_recovery_s:
            return 1.0
        depth = min(1.0, self._coast_s / s.mag_recovery_s)
        return 1.0 + (s.mag_recovery_factor - 1.0) * depth * (1.0 - elapsed / s.mag_recovery_s)

    def _ign_update(self, acc: tuple[float, ...], mag: tuple[float, ...], sigma_a: float, sigma_m: float) -> None:
        """Measurement 1. The vectors go to the solver in units of their own σ with a unit noise model: the
        same solution (only σ/|W| matters to IGN) without building a NoiseModel per update. No warm start
        from ``q``: TRIAD converges as fast (2.0 corrections per update against 2.07 from ``q``) and the
        warm start's two loss evaluations cost a quarter of the solve (bench turning stream at 50 Hz)."""
        w_acc = (acc[0] / sigma_a, acc[1] / sigma_a, acc[2] / sigma_a)
        w_mag = (mag[0] / sigma_m, mag[1] / sigma_m, mag[2] / sigma_m)
        r = solve(w_acc, w_mag, self._mag_ref_t, _UNIT_NOISE, acc_ref=self._acc_ref_t)
        w, x, y, z = self._q
        z_theta = rotvec_from_quat_parts(quat_multiply_parts((w, -x, -y, -z), tuple(r.q.tolist())))
        # H = [I 0]
        self._p_tt, bt, self._p_bb, d_theta, d_bias = _block_update(
            self._p_tt, _transpose(self._p_tb), self._p_bb, _ign_covariance_parts(w_acc, w_mag), z_theta
        )
        self._p_tb = _transpose(bt)
        self._apply_parts(d_theta, d_bias)
        self.counters["ign_updates"] += 1

    def _tilt_update(self, acc: tuple[float, ...], acc_norm: float, sigma_a: float) -> None:
        """Measurement 2: the accelerometer direction only; its gain is kept off the vertical (heading coasts)."""
        h = rotate_ned_to_body_parts(rotation_matrix_parts(self._q), self._v_acc)
        z = np.array([acc[0] / acc_norm - h[0], acc[1] / acc_norm - h[1], acc[2] / acc_norm - h[2]])
        keep = _EYE3 - np.outer(h, h)
        self._correct(_attitude_h(skew(h)), z, (sigma_a / acc_norm) ** 2 * _EYE3, keep)
        self.counters["tilt_updates"] += 1

    def _rest_update(self, acc: tuple[float, float, float], time_s: float) -> None:
        """Zero-rate update of the bias once the gyro and accelerometer have been still for ``rest_min_s``."""
        s = self.settings
        g = self._gyr_last
        if self._lp is None:
            self._lp = [*g, *acc]
        k, lp = self._rest_alpha, self._lp
        lp = self._lp = [
            lp[0] + k * (g[0] - lp[0]),
            lp[1] + k * (g[1] - lp[1]),
            lp[2] + k * (g[2] - lp[2]),
            lp[3] + k * (acc[0] - lp[3]),
            lp[4] + k * (acc[1] - lp[4]),
            lp[5] + k * (acc[2] - lp[5]),
        ]
        b = self._bias
        dev_g2 = (g[0] - lp[0]) ** 2 + (g[1] - lp[1]) ** 2 + (g[2] - lp[2]) ** 2
        dev_a2 = (acc[0] - lp[3]) ** 2 + (acc[1] - lp[4]) ** 2 + (acc[2] - lp[5]) ** 2
        rate2 = (lp[0] - b[0]) ** 2 + (lp[1] - b[1]) ** 2 + (lp[2] - b[2]) ** 2
        th_g2 = s.rest_gyro_threshold_radps**2
        if not (dev_g2 < th_g2 and rate2 < th_g2 and dev_a2 < s.rest_accel_threshold_mps2**2):
            self._still_since_s = math.inf
            return
        self._still_since_s = min(self._still_since_s, time_s)
        if time_s - self._still_since_s < s.rest_min_s:
            return
        # H = [0 I]
        self._p_bb, self._p_tb, self._p_tt, d_bias, d_theta = _block_update(
            self._p_bb,
            self._p_tb,
            self._p_tt,
            _symmetric(_ZERO3, s.rest_gyro_std_radps**2),
            (lp[0] - b[0], lp[1] - b[1], lp[2] - b[2]),
        )
        self._apply_parts(d_theta, d_bias)
        self.counters["rest_updates"] += 1

    def _correct(self, h: Array, z: Array, r: Array, keep: Array) -> None:
        """Kalman update with ``H`` (k×6, Joseph form), then reset the error state into q and b.

        ``keep`` (3×3 projector) restricts the attitude part of the gain to a subspace; the Joseph form
        keeps ``P`` exact for such a sub-optimal gain.
        """
        p = self._p_matrix()
        ph = p @ h.T  # P Hᵀ (6×k)
        k = np.linalg.solve(h @ ph + r, ph.T).T
        k[:3] = keep @ k[:3]
        ikh = _EYE6 - k @ h
        self._set_p(ikh @ p @ ikh.T + k @ r @ k.T)
        dx = (k @ z).tolist()
        self._apply_parts(dx[:3], dx[3:])

    def _apply_parts(self, d_theta: Sequence[float], d_bias: Sequence[float]) -> None:
        """Reset: move the estimated error state ``[δθ, δb]`` into the nominal ``q`` and ``b``."""
        correction = quat_from_rotvec_parts(d_theta[0], d_theta[1], d_theta[2])
        self._q = quat_normalize_parts(quat_multiply_parts(self._q, correction))
        b = self._bias
        self._bias = (b[0] + d_bias[0], b[1] + d_bias[1], b[2] + d_bias[2])

    # --- start-up and output ------------------------------------------------------------------------
    def _start(
        self, time_s: float, gyr: tuple[float, float, float], acc: ArrayLike, mag: ArrayLike | None
    ) -> list[FusedEstimate]:
        """(Re)initialise from IGN on a sample with both vectors; a restart keeps the bias and its covariance."""
        if mag is None:
            self._q = None
            return []
        r = solve(acc, mag, self.mag_ref, self._noise, acc_ref=self.acc_ref)
        restart = self._q is not None
        self._q = self._q_gyro = quat_normalize_parts(tuple(float(v) for v in r.q))
        self._acc_lp = None
        self._p_tt, self._p_tb = tuple(r.covariance.ravel().tolist()), _ZERO3
        if not restart:
            self._p_bb = _symmetric(_ZERO3, self.settings.gyro_bias_init_radps**2)
            # The field's magnitude as calibrated here, not as the reference says.
            self._norm_ref = _norm((float(mag[0]), float(mag[1]), float(mag[2])))
            self._field_n = 1.0
        self._interval = _Interval()
        self._t_last = time_s
        self._gyr_last = gyr
        self._next_update_s = time_s + self._update_period_s
        self._next_output_s = time_s
        return self._outputs(time_s)

    def _outputs(self, time_s: float) -> list[FusedEstimate]:
        """Estimates for every output tick up to ``time_s``, the attitude carried back to the tick time."""
        b, g = self._bias, self._gyr_last
        wx, wy, wz = g[0] - b[0], g[1] - b[1], g[2] - b[2]
        rates = np.array([wx, wy, wz])
        q_now = self._current_q()
        out = []
        while self._next_output_s <= time_s:
            back = self._next_output_s - time_s
            carry = quat_from_rotvec_parts(wx * back, wy * back, wz * back)
            q_tick = np.array(quat_normalize_parts(quat_multiply_parts(q_now, carry)))
            cov = np.array(self._p_tt).reshape(3, 3)
            out.append(FusedEstimate(self._next_output_s, q_tick, rates, cov, np.array(b), self._disturbed))
            self._next_output_s += self._output_period_s
        return out


_MAX_UNIT_STD = 0.5  # rad: the largest direction noise handed to a measurement update
_EYE6 = np.eye(6)
_UNIT_NOISE = NoiseModel(accel_std=1.0, mag_std=1.0)  # vectors are handed over in units of their σ
