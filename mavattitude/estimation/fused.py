"""Gyro-aided attitude: a multiplicative error-state Kalman filter whose measurement is the IGN solution.

The paper (Liu et al. 2014) ends by noting that the accelerometer + magnetometer solution should aid a gyro,
because under sustained acceleration the accelerometer no longer points along gravity. This module is that
filter. Pure math: no I/O, no clock (time comes from the samples), no logging (events are counted in
:attr:`FusedFilter.counters` for the caller to report).

State and error state
---------------------
Nominal state: attitude ``q`` (body → NED, scalar first) and gyro bias ``b`` (rad/s). Error state
``x = [δθ, δb]`` (6), with the true attitude ``q_true = q ⊗ exp(δθ)`` (body-frame error angles, the
paper's Eq. 14/28–30 up to sign) and ``b_true = b + δb``; ``P = E[x xᵀ]``.

Propagation (every input sample ``k``, over ``Δt = t_k − t_{k−1}`` with ``ω = g_k − b`` from the calibrated gyro)::

    q ← q ⊗ exp(ω Δt)                            exp(φ) = [cos(|φ|/2), sin(|φ|/2) φ/|φ|]
    δθ̇ = −[ω×] δθ − δb − n_g,    δḃ = n_b

The quaternion increments are composed in plain floats at the input rate into ``Δq`` (the rotation since
the last update); the covariance is propagated once per update interval ``T`` with the exact attitude
block and a trapezoidal bias coupling::

    Φ = [[A(Δq), −T (I + A(Δq)) / 2], [0, I]],   A(Δq) = R(Δq)ᵀ
    P ← Φ P Φᵀ + diag((σ_g² T + (s_g θ)²) I, σ_b² T I)

where ``θ = Σ |ω| Δt`` is the angle turned in the interval (``s_g`` covers gyro scale-factor error).

Measurement 1 — the IGN solution (both vectors usable)
------------------------------------------------------
``q_m, P_m = solve(acc, mag, mag_ref, NoiseModel(σ_a', σ_m'), method="ign", q0=q)``, whose error model is
``q_m = q_true ⊗ exp(ν)``, ``ν ~ N(0, P_m)`` (the sandwich covariance of NOTES.md). Innovation and update::

    z = log(q* ⊗ q_m) ≈ δθ + ν,   H = [I 0],   R = P_m
    S = H P Hᵀ + R,   K = P Hᵀ S⁻¹,   x̂ = K z,   P ← (I − K H) P (I − K H)ᵀ + K R Kᵀ
    q ← q ⊗ exp(δθ̂),   b ← b + δb̂

Measurement 2 — tilt only (magnetometer disturbed or missing)
-------------------------------------------------------------
The unit specific force ``u = a / |a|`` against its prediction ``h = A(q) v_a`` (``v_a = acc_ref``)::

    u ≈ A(q ⊗ exp(δθ)) v_a ≈ h + [h×] δθ,   z = u − h,   H = [[h×] 0],   R = σ_u² I,  σ_u = σ_a' / |a|

which has no component about the vertical: the heading coasts on the gyro.

Acceleration rejection (smooth)
-------------------------------
The accelerometer's σ handed to both measurements is inflated, never switched off::

    σ_a'² = σ_a² + (k_n (|a| − g))² + (k_r g ε)²

with ``ε`` the IGN residual: the angle between the measured vectors minus the angle between their
references (|dip error|), which is non-zero when the specific force is not gravity. With the
magnetometer disturbed ``ε`` says nothing about the accelerometer and is not used.

Magnetic-disturbance rejection
------------------------------
The field is checked against the reference, with the dip measured against the *predicted* vertical
(so an accelerating vehicle does not look magnetically disturbed)::

    d = max(| |m| − |m_ref| | / (τ_n |m_ref|),  |δ(m, q) − δ_ref| / τ_δ)

``d ≥ 1``: disturbed — the magnetometer updates nothing, measurement 2 runs, the heading coasts.
``d < 1``: measurement 1 with ``σ_m'² = σ_m² (1 + (d / d₀)²) · ρ(t)``, where the recovery factor
``ρ = 1 + (ρ₀ − 1) max(0, 1 − t_clean / T_r)`` falls linearly from ``ρ₀`` to 1 over ``T_r`` seconds of
clean field, so the heading error accrued while coasting is taken back over seconds, without a jump.

Start-up
--------
The first sample with both vectors initialises ``q`` from IGN and ``P_θθ`` from its covariance,
``P_bb = σ_b0² I``; at rest the updates then observe all three bias components (tilt observes the
horizontal ones, heading the vertical one). A gap longer than ``max_gap_s`` restarts from IGN, keeping
the bias estimate and its covariance.

Output
------
:meth:`FusedFilter.push` returns a :class:`FusedEstimate` for every ``output_rate_hz`` tick passed (50 Hz,
the ATTITUDE_QUATERNION rate): the attitude carried to the tick time and the bias-corrected body rates.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike

from mavattitude.errors import DegenerateGeometryError, InputError
from mavattitude.estimation import NoiseModel, solve
from mavattitude.estimation.conventions import Array, quat_multiply_parts, rotation_matrix_parts

Quat = tuple[float, float, float, float]
_EYE3 = np.eye(3)


def _exp(vx: float, vy: float, vz: float) -> Quat:
    """Quaternion of a rotation vector (rad), plain floats (the per-sample path)."""
    half = 0.5 * math.sqrt(vx * vx + vy * vy + vz * vz)
    s = 0.5 * math.sin(half) / half if half > 1e-9 else 0.5 - half * half / 12.0
    return (math.cos(half), s * vx, s * vy, s * vz)


def _log(q: Quat) -> tuple[float, float, float]:
    """Rotation vector (rad, angle ≤ π) of a unit quaternion, plain floats."""
    w, x, y, z = q if q[0] >= 0.0 else (-q[0], -q[1], -q[2], -q[3])
    n = math.sqrt(x * x + y * y + z * z)
    scale = 2.0 * math.atan2(n, w) / n if n > 1e-12 else 2.0
    return (scale * x, scale * y, scale * z)


def _normalize(q: Quat) -> Quat:
    n = math.sqrt(q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3])
    if q[0] < 0.0:
        n = -n
    return (q[0] / n, q[1] / n, q[2] / n, q[3] / n)


def _skew(x: float, y: float, z: float) -> Array:
    return np.array([[0.0, -z, y], [z, 0.0, -x], [-y, x, 0.0]])


def ign_covariance(acc: Sequence[float], mag: Sequence[float], sigma_acc: float, sigma_mag: float) -> Array:
    """IGN's predicted error-angle covariance (rad²) for isotropic per-sensor noise, in closed form.

    With ``R = σ² I`` the unit-vector covariance is ``σ²/|W|² (I − ŵŵᵀ)`` and the paper's weight
    ``a = 3|W|²/(2σ²)``, so the sandwich of :func:`~mavattitude.estimation.predicted_covariance`
    collapses to ``P = (Σᵢ (|Wᵢ|² I − Wᵢ Wᵢᵀ) / σᵢ²)⁻¹`` — the same matrix (tested) at a tenth of the cost.
    """
    info = np.zeros((3, 3))
    for (x, y, z), sigma in ((acc, sigma_acc), (mag, sigma_mag)):
        v = np.array([x, y, z])
        info += (np.dot(v, v) * _EYE3 - np.outer(v, v)) / (sigma * sigma)
    return np.linalg.inv(info)


@dataclass(frozen=True)
class FusedSettings:
    """Tuning of the gyro-aided filter (one configuration for every vehicle unless a profile says otherwise).

    The σ values are *effective* noise: they include model error (sensor calibration residue,
    non-gravitational acceleration, local field) as well as sensor noise, which is why they are far above
    a data sheet's figures.
    """

    gyro_noise_radps: float = 0.003  # σ_g, angle random walk, rad/s/√Hz
    gyro_scale_std: float = 0.002  # s_g, gyro scale-factor error, per rad turned
    gyro_bias_walk_radps2: float = 3e-5  # σ_b, bias random walk, rad/s/√s
    gyro_bias_init_radps: float = 0.02  # σ_b0, start-up bias uncertainty, rad/s
    accel_std_mps2: float = 0.3  # σ_a, per axis
    accel_norm_gain: float = 3.0  # k_n: σ added per m/s² of | |a| − g |
    accel_rate_gain: float = 0.0  # k_ω: σ added per rad/s of body rate
    accel_residual_gain: float = 3.0  # k_r: σ added per g·rad of IGN residual
    mag_std_uT: float = 3.0  # σ_m, per axis
    mag_norm_tolerance: float = 0.1  # τ_n, fraction of |m_ref| beyond which the field is disturbed
    mag_dip_tolerance_deg: float = 5.0  # τ_δ
    mag_soft_fraction: float = 0.5  # d₀: inflation scale below the hard threshold
    mag_recovery_factor: float = 10.0  # ρ₀: σ_m² multiplier just after a disturbance
    mag_recovery_s: float = 3.0  # T_r
    gravity_mps2: float = 9.80665
    update_rate_hz: float = 50.0
    output_rate_hz: float = 50.0
    max_gap_s: float = 0.5
    split_updates: float = 0.0

    def __post_init__(self) -> None:
        for name, value in vars(self).items():
            if not math.isfinite(value) or value < 0.0:
                raise InputError(f"FusedSettings.{name} must be finite and non-negative, got {value!r}")
        for name in ("gravity_mps2", "update_rate_hz", "output_rate_hz", "max_gap_s", "mag_norm_tolerance"):
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
        self.mag_ref = np.asarray(mag_ref, dtype=float)
        self.acc_ref = np.asarray(acc_ref, dtype=float)
        if self.mag_ref.shape != (3,) or self.acc_ref.shape != (3,):
            raise InputError(f"references must be 3-vectors, got {mag_ref!r} and {acc_ref!r}")
        norms = float(np.linalg.norm(self.mag_ref)), float(np.linalg.norm(self.acc_ref))
        if not all(math.isfinite(n) and n > 0.0 for n in norms):
            raise InputError(f"references must be finite and non-zero, got {mag_ref!r} and {acc_ref!r}")
        self._mag_ref_norm = norms[0]
        self._v_acc = tuple(float(v) / norms[1] for v in self.acc_ref)
        # Reference angle between the two vectors, and the field's dip below the horizontal.
        cos_ref = float(self.acc_ref @ self.mag_ref) / (norms[0] * norms[1])
        self._ref_angle = math.acos(max(-1.0, min(1.0, cos_ref)))
        self._ref_dip = math.asin(max(-1.0, min(1.0, -cos_ref)))
        self._ref_heading = math.atan2(float(self.mag_ref[1]), float(self.mag_ref[0]))
        self._noise = NoiseModel(accel_std=(settings.accel_std_mps2,) * 3, mag_std=(settings.mag_std_uT,) * 3)
        self.counters: dict[str, int] = {
            "ign_updates": 0,
            "tilt_updates": 0,
            "mag_disturbed": 0,
            "degenerate": 0,
            "skipped_updates": 0,
            "restarts": 0,
        }
        self._q: Quat | None = None
        self._bias = (0.0, 0.0, 0.0)
        self._p = np.zeros((6, 6))
        self._t_last = 0.0
        self._gyr_last = (0.0, 0.0, 0.0)
        self._interval = _Interval()
        self._update_period_s = 1.0 / settings.update_rate_hz
        self._output_period_s = 1.0 / settings.output_rate_hz
        self._next_update_s = 0.0
        self._next_output_s = 0.0
        self._clean_since_s = -math.inf
        self._disturbed = False

    # --- public state -------------------------------------------------------------------------------
    @property
    def initialised(self) -> bool:
        return self._q is not None

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
        return self._p.copy()

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
        if time_s >= self._next_update_s:
            self._next_update_s = max(self._next_update_s + self._update_period_s, time_s)
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
        iv.dq = quat_multiply_parts(iv.dq, _exp(vx, vy, vz))
        iv.duration_s += dt
        iv.angle_rad += math.sqrt(vx * vx + vy * vy + vz * vz)

    def _current_q(self) -> Quat:
        if self._q is None:
            raise InputError("the fused filter has no attitude yet: it needs one sample with acc and mag")
        return _normalize(quat_multiply_parts(self._q, self._interval.dq))

    def _propagate(self) -> None:
        """Move the interval's rotation into ``q`` and propagate ``P`` over it (``Φ`` in the docstring)."""
        s, iv = self.settings, self._interval
        a = np.array(rotation_matrix_parts(iv.dq)).reshape(3, 3).T
        t = iv.duration_s
        phi = np.eye(6)
        phi[:3, :3] = a
        phi[:3, 3:] = -0.5 * t * (np.eye(3) + a)
        p = phi @ self._p @ phi.T
        q_theta = s.gyro_noise_radps**2 * t + (s.gyro_scale_std * iv.angle_rad) ** 2
        p[_DIAG_THETA] += q_theta
        p[_DIAG_BIAS] += s.gyro_bias_walk_radps2**2 * t
        self._p = p
        self._q = self._current_q()
        self._interval = _Interval()

    # --- measurement updates ------------------------------------------------------------------------
    def _update(self, acc_mps2: ArrayLike, mag_uT: ArrayLike | None, time_s: float) -> None:
        self._propagate()
        s = self.settings
        ax, ay, az = acc = (float(acc_mps2[0]), float(acc_mps2[1]), float(acc_mps2[2]))
        acc_norm = math.sqrt(ax * ax + ay * ay + az * az)
        if not math.isfinite(acc_norm) or acc_norm < 1e-3 * s.gravity_mps2:
            self.counters["skipped_updates"] += 1
            return
        mag = None if mag_uT is None else (float(mag_uT[0]), float(mag_uT[1]), float(mag_uT[2]))
        d = math.inf if mag is None else self._mag_disturbance(mag)
        self._track_disturbance(d >= 1.0, time_s)
        g = self._gyr_last
        rate2 = (g[0] - self._bias[0]) ** 2 + (g[1] - self._bias[1]) ** 2 + (g[2] - self._bias[2]) ** 2
        sigma_a2 = (
            s.accel_std_mps2**2 + (s.accel_norm_gain * (acc_norm - s.gravity_mps2)) ** 2 + s.accel_rate_gain**2 * rate2
        )
        if mag is not None and d < 1.0:
            residual = self._vector_residual(acc, acc_norm, mag)
            sigma_a2 += (s.accel_residual_gain * s.gravity_mps2 * residual) ** 2
            sigma_m2 = s.mag_std_uT**2 * (1.0 + (d / s.mag_soft_fraction) ** 2) * self._recovery_factor(time_s)
            if s.split_updates:
                self._tilt_update(acc, acc_norm, math.sqrt(sigma_a2))
                self._heading_update(mag, math.sqrt(sigma_m2))
                return
            try:
                self._ign_update(acc, mag, math.sqrt(sigma_a2), math.sqrt(sigma_m2))
                return
            except DegenerateGeometryError:
                self.counters["degenerate"] += 1
        self._tilt_update(acc, acc_norm, math.sqrt(sigma_a2))

    def _heading_update(self, mag: tuple[float, ...], sigma_m: float) -> None:
        r = rotation_matrix_parts(self._q)
        mn = r[0] * mag[0] + r[1] * mag[1] + r[2] * mag[2]
        me = r[3] * mag[0] + r[4] * mag[1] + r[5] * mag[2]
        horizontal = math.hypot(mn, me)
        if horizontal < 1e-9:
            return
        z = self._ref_heading - math.atan2(me, mn)
        z = (z + math.pi) % (2.0 * math.pi) - math.pi
        h = np.array([[r[6], r[7], r[8]]])
        self._correct(h, np.array([z]), np.array([[(sigma_m / horizontal) ** 2]]))

    def _mag_disturbance(self, mag: tuple[float, float, float]) -> float:
        """``d`` of the module docstring: ≥ 1 means disturbed; the dip uses the predicted vertical."""
        s = self.settings
        norm = math.sqrt(mag[0] * mag[0] + mag[1] * mag[1] + mag[2] * mag[2])
        if not math.isfinite(norm) or norm == 0.0:
            return math.inf
        r = rotation_matrix_parts(self._q)
        down = (r[6] * mag[0] + r[7] * mag[1] + r[8] * mag[2]) / norm  # NED "down" of the unit field
        d_norm = abs(norm - self._mag_ref_norm) / (s.mag_norm_tolerance * self._mag_ref_norm)
        if s.mag_dip_tolerance_deg == 0.0:
            return d_norm
        dip = math.asin(max(-1.0, min(1.0, down)))
        return max(d_norm, abs(dip - self._ref_dip) / math.radians(s.mag_dip_tolerance_deg))

    def _vector_residual(self, acc: tuple[float, ...], acc_norm: float, mag: tuple[float, ...]) -> float:
        """IGN residual as an angle: measured angle between the vectors minus the reference angle."""
        mag_norm = math.sqrt(mag[0] * mag[0] + mag[1] * mag[1] + mag[2] * mag[2])
        cos_m = (acc[0] * mag[0] + acc[1] * mag[1] + acc[2] * mag[2]) / (acc_norm * mag_norm)
        return abs(math.acos(max(-1.0, min(1.0, cos_m))) - self._ref_angle)

    def _track_disturbance(self, disturbed: bool, time_s: float) -> None:
        if disturbed:
            self.counters["mag_disturbed"] += 1
        elif self._disturbed:
            self._clean_since_s = time_s
        self._disturbed = disturbed

    def _recovery_factor(self, time_s: float) -> float:
        s = self.settings
        elapsed = time_s - self._clean_since_s
        if s.mag_recovery_s == 0.0 or not elapsed < s.mag_recovery_s:
            return 1.0
        return 1.0 + (s.mag_recovery_factor - 1.0) * (1.0 - elapsed / s.mag_recovery_s)

    def _ign_update(self, acc: tuple[float, ...], mag: tuple[float, ...], sigma_a: float, sigma_m: float) -> None:
        noise = NoiseModel(accel_std=(sigma_a,) * 3, mag_std=(sigma_m,) * 3)
        r = solve(acc, mag, self.mag_ref, noise, acc_ref=self.acc_ref, q0=np.array(self._q))
        w, x, y, z = self._q
        innovation = _log(quat_multiply_parts((w, -x, -y, -z), tuple(r.q.tolist())))
        self._correct(_EYE3, np.array(innovation), ign_covariance(acc, mag, sigma_a, sigma_m))
        self.counters["ign_updates"] += 1

    def _tilt_update(self, acc: tuple[float, ...], acc_norm: float, sigma_a: float) -> None:
        r = rotation_matrix_parts(self._q)
        vx, vy, vz = self._v_acc
        h = (r[0] * vx + r[3] * vy + r[6] * vz, r[1] * vx + r[4] * vy + r[7] * vz, r[2] * vx + r[5] * vy + r[8] * vz)
        z = np.array([acc[i] / acc_norm - h[i] for i in range(3)])
        self._correct(_skew(*h), z, (sigma_a / acc_norm) ** 2 * _EYE3)
        self.counters["tilt_updates"] += 1

    def _correct(self, h_theta: Array, z: Array, r: Array) -> None:
        """Kalman update with ``H = [h_theta 0]`` (Joseph form), then reset the error state into q and b."""
        p = self._p
        ph = p[:, :3] @ h_theta.T  # P Hᵀ (6×3)
        k = np.linalg.solve(h_theta @ ph[:3] + r, ph.T).T
        dx = (k @ z).tolist()
        ikh = np.eye(6)
        ikh[:, :3] -= k @ h_theta
        p = ikh @ p @ ikh.T + k @ r @ k.T
        self._p = 0.5 * (p + p.T)
        self._q = _normalize(quat_multiply_parts(self._q, _exp(dx[0], dx[1], dx[2])))
        b = self._bias
        self._bias = (b[0] + dx[3], b[1] + dx[4], b[2] + dx[5])

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
        self._q = _normalize(tuple(float(v) for v in r.q))
        p = np.zeros((6, 6))
        p[:3, :3] = r.covariance
        p[3:, 3:] = self._p[3:, 3:] if restart else np.eye(3) * self.settings.gyro_bias_init_radps**2
        self._p = p
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
            q_tick = np.array(_normalize(quat_multiply_parts(q_now, _exp(wx * back, wy * back, wz * back))))
            cov = self._p[:3, :3].copy()
            out.append(FusedEstimate(self._next_output_s, q_tick, rates, cov, np.array(b), self._disturbed))
            self._next_output_s += self._output_period_s
        return out


_DIAG_THETA = (0, 1, 2), (0, 1, 2)
_DIAG_BIAS = (3, 4, 5), (3, 4, 5)
