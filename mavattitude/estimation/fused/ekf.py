"""The error-state (multiplicative) Kalman filter on attitude and gyro bias: propagation and one update.

Nominal state ``q`` (body → NED, scalar first) and gyro bias ``b`` (rad/s); error state ``x = [δθ, δb]``
with ``q_true = q ⊗ exp(δθ)`` (body-frame error angles, the paper's Eq. 14/28–30), ``b_true = b + δb``,
``P = E[x xᵀ]`` kept as three 3×3 blocks ``P_θθ``, ``P_θb``, ``P_bb`` (:mod:`.mat3`).

Propagation — every input sample, ``ω = g − b``: ``q ← q ⊗ exp(ω Δt)``, composed in plain floats into
``Δq`` (the rotation since the last update); ``P`` once per update interval ``T``::

    Φ = [[A(Δq), −T (I + A(Δq)) / 2], [0, I]],   A(Δq) = R(Δq)ᵀ
    P ← Φ P Φᵀ + diag((σ_g² T + (s_g θ)²) I, σ_b² T I),   θ = Σ |ω| Δt

Update — one scalar measurement ``z ≈ hᵀ x + ν``, ``ν ~ N(0, r)`` (vector measurements with independent
components are a sequence of these, which is exact for a diagonal ``R``)::

    u = P h,   s = hᵀ u + r,   K = u / s,   x̂ ← x̂ + K (z − hᵀ x̂)

and after the update's measurements the reset ``q ← q ⊗ exp(δθ̂)``, ``b ← b + δb̂``, ``x̂ ← 0``.

The gain may be restricted to a direction (``on``: only that component of ``K_θ`` and ``K_b``) or kept off
one (``off``: that component of ``K_θ`` removed), so that a measurement corrects only what it is trusted
for; for any such gain ``P ← (I − K hᵀ) P (I − K hᵀ)ᵀ + r K Kᵀ`` (Joseph) is exact, and with
``v = (s/2) K − u`` it is ``P + K vᵀ + v Kᵀ`` (``v = −u/2`` for the optimal gain): symmetric as written,
four float operations an entry.
"""

from __future__ import annotations

import math

from mavattitude.estimation.conventions import (
    Quat,
    Vec3,
    quat_from_rotvec_parts,
    quat_multiply_parts,
    quat_normalize_parts,
    rotation_matrix_parts,
)

from . import mat3 as m3
from .mat3 import ZERO3, Block

IDENTITY_Q: Quat = (1.0, 0.0, 0.0, 0.0)


class ErrorStateFilter:
    """Attitude, gyro bias and their covariance; the gyro-only attitude ``q_gyro`` rides along (never
    corrected, for the accelerometer pre-filter)."""

    def __init__(self, gyro_noise_radps: float, gyro_scale_fraction: float, gyro_bias_walk_radps2: float) -> None:
        self._q_noise = (gyro_noise_radps**2, gyro_scale_fraction**2, gyro_bias_walk_radps2**2)
        self.q: Quat = IDENTITY_Q
        self.q_gyro: Quat = IDENTITY_Q
        self.bias: Vec3 = (0.0, 0.0, 0.0)
        self.p_tt: Block = ZERO3
        self.p_tb: Block = ZERO3
        self.p_bb: Block = ZERO3
        self.dx = _ZERO_DX  # the error state estimated since the last reset: [δθ, δb]
        self.dq: Quat = IDENTITY_Q  # rotation since the last propagation
        self.duration_s = 0.0
        self.angle_rad = 0.0

    def start(self, q: Quat, p_tt: Block, p_bb: Block | None = None) -> None:
        """(Re)initialise the attitude and its covariance; ``p_bb`` None keeps the bias and its covariance."""
        self.q = self.q_gyro = quat_normalize_parts(q)
        self.p_tt, self.p_tb = p_tt, ZERO3
        if p_bb is not None:
            self.p_bb = p_bb
        self.dq, self.duration_s, self.angle_rad = IDENTITY_Q, 0.0, 0.0

    def integrate(self, dt: float, gx: float, gy: float, gz: float) -> None:
        """``Δq ← Δq ⊗ exp(ω Δt)`` with the sample's bias-corrected rate."""
        b0, b1, b2 = self.bias
        vx, vy, vz = dt * (gx - b0), dt * (gy - b1), dt * (gz - b2)
        angle = math.sqrt(vx * vx + vy * vy + vz * vz)
        # quat_from_rotvec_parts written out (the same floats), its angle also the scale-factor noise's
        half = 0.5 * angle
        k = 0.5 * math.sin(half) / half if half > 1e-9 else 0.5 - half * half / 12.0
        step = (math.cos(half), k * vx, k * vy, k * vz)
        # The first sample after a propagation (every sample when each one is an update): Δq is the identity,
        # and the identity times the step is the step, the same floats.
        self.dq = step if self.duration_s == 0.0 else quat_multiply_parts(self.dq, step)
        self.duration_s += dt
        self.angle_rad += angle

    def current_q(self) -> Quat:
        if self.duration_s == 0.0:  # just propagated: q is already normalised, with w ≥ 0
            return self.q
        return _composed(self.q, self.dq)

    def propagate(self) -> None:
        """Move the interval's rotation into ``q`` (and ``q_gyro``) and propagate ``P`` over it (``Φ``)."""
        t = self.duration_s
        r, c = rotation_matrix_parts(self.dq), -0.5 * t  # R(Δq), row-major; A(Δq) = R(Δq)ᵀ
        # Φ = [[A, c (I + A)], [0, I]] by blocks: with X = [A, c (I + A)] P = A Y + c [P_θbᵀ, P_bb],
        # Y = [P_θθ + c P_θbᵀ, P_θb + c P_bb]: P_θb ← X_b, P_θθ ← (X_θ + c X_b) Aᵀ + c X_b.
        noise2, scale2, walk2 = self._q_noise
        angle = self.angle_rad
        self.p_tt, self.p_tb, self.p_bb = m3.propagated(
            r, c, self.p_tt, self.p_tb, self.p_bb, noise2 * t + scale2 * (angle * angle), walk2 * t
        )
        dq = self.dq
        if t != 0.0:  # current_q(), written out: a call per update
            self.q = _composed(self.q, dq)
        self.q_gyro = _composed(self.q_gyro, dq)
        self.dq, self.duration_s, self.angle_rad = IDENTITY_Q, 0.0, 0.0

    def update(
        self,
        z: float,
        h_theta: Vec3 | None,
        r: float,
        h_bias: Vec3 | None = None,
        *,
        on: Vec3 | None = None,
        off: Vec3 | None = None,
    ) -> None:
        """One scalar measurement ``z ≈ h_θᵀ δθ + h_bᵀ δb + ν`` (module docstring) of the error against the
        nominal state as it was at the last :meth:`reset`; ``on``/``off`` restrict the gain (unit vectors).
        Call :meth:`propagate` first (``q`` must carry the whole interval) and :meth:`reset` after the last."""
        tt, tb, bb = self.p_tt, self.p_tb, self.p_bb
        d0, d1, d2, d3, d4, d5 = self.dx
        # The blocks' entries as local floats, the products written out: a call, a tuple or an index costs as much
        # as the arithmetic (three updates a sample at 25 and 50 Hz). P_bb is symmetric: its upper triangle.
        t0, t1, t2, t3, t4, t5, t6, t7, t8 = tt
        c0, c1, c2, c3, c4, c5, c6, c7, c8 = tb
        b0, b1, b2, _, b4, b5, _, _, b8 = bb
        if h_theta is not None:
            h0, h1, h2 = h_theta
            ut0, ut1, ut2 = t0 * h0 + t1 * h1 + t2 * h2, t3 * h0 + t4 * h1 + t5 * h2, t6 * h0 + t7 * h1 + t8 * h2
            ub0, ub1, ub2 = c0 * h0 + c3 * h1 + c6 * h2, c1 * h0 + c4 * h1 + c7 * h2, c2 * h0 + c5 * h1 + c8 * h2
            s = r + (h0 * ut0 + h1 * ut1 + h2 * ut2)
            z -= h0 * d0 + h1 * d1 + h2 * d2
        else:
            ut0 = ut1 = ut2 = ub0 = ub1 = ub2 = 0.0
            s = r
        if h_bias is not None:
            z -= h_bias[0] * d3 + h_bias[1] * d4 + h_bias[2] * d5
            p_t, p_b = m3.matvec(tb, h_bias), m3.matvec(bb, h_bias)
            s += m3.dot(h_bias, p_b) + 2.0 * m3.dot(h_theta, p_t) if h_theta is not None else m3.dot(h_bias, p_b)
            ut0, ut1, ut2 = ut0 + p_t[0], ut1 + p_t[1], ut2 + p_t[2]
            ub0, ub1, ub2 = ub0 + p_b[0], ub1 + p_b[1], ub2 + p_b[2]
        inv_s = 1.0 / s
        kt0, kt1, kt2 = ut0 * inv_s, ut1 * inv_s, ut2 * inv_s
        kb0, kb1, kb2 = ub0 * inv_s, ub1 * inv_s, ub2 * inv_s
        if on is not None:
            o0, o1, o2 = on
            c_t, c_b = o0 * kt0 + o1 * kt1 + o2 * kt2, o0 * kb0 + o1 * kb1 + o2 * kb2
            kt0, kt1, kt2, kb0, kb1, kb2 = o0 * c_t, o1 * c_t, o2 * c_t, o0 * c_b, o1 * c_b, o2 * c_b
        if off is not None:
            o0, o1, o2 = off
            c = o0 * kt0 + o1 * kt1 + o2 * kt2
            kt0, kt1, kt2 = kt0 - c * o0, kt1 - c * o1, kt2 - c * o2
        m = 0.5 * s  # v = (s/2) K − u
        v0, v1, v2 = m * kt0 - ut0, m * kt1 - ut1, m * kt2 - ut2
        v3, v4, v5 = m * kb0 - ub0, m * kb1 - ub1, m * kb2 - ub2
        # P + K vᵀ + v Kᵀ on the three blocks, here rather than in a function of its own (a call and two 6-tuples
        # cost as much as a block's arithmetic); the diagonal blocks' entries above the diagonal computed once.
        xy, xz, yz = t1 + kt0 * v1 + v0 * kt1, t2 + kt0 * v2 + v0 * kt2, t5 + kt1 * v2 + v1 * kt2
        self.p_tt = (t0 + 2.0 * kt0 * v0, xy, xz, xy, t4 + 2.0 * kt1 * v1, yz, xz, yz, t8 + 2.0 * kt2 * v2)
        xy, xz, yz = b1 + kb0 * v4 + v3 * kb1, b2 + kb0 * v5 + v3 * kb2, b5 + kb1 * v5 + v4 * kb2
        self.p_bb = (b0 + 2.0 * kb0 * v3, xy, xz, xy, b4 + 2.0 * kb1 * v4, yz, xz, yz, b8 + 2.0 * kb2 * v5)
        self.p_tb = (
            c0 + kt0 * v3 + v0 * kb0,
            c1 + kt0 * v4 + v0 * kb1,
            c2 + kt0 * v5 + v0 * kb2,
            c3 + kt1 * v3 + v1 * kb0,
            c4 + kt1 * v4 + v1 * kb1,
            c5 + kt1 * v5 + v1 * kb2,
            c6 + kt2 * v3 + v2 * kb0,
            c7 + kt2 * v4 + v2 * kb1,
            c8 + kt2 * v5 + v2 * kb2,
        )
        self.dx = (d0 + kt0 * z, d1 + kt1 * z, d2 + kt2 * z, d3 + kb0 * z, d4 + kb1 * z, d5 + kb2 * z)

    def hold_heading_unknown(self, down: Vec3, var: float) -> None:
        """The rotation about ``down`` (the body's vertical, ``A(q) e_D``, unit) unknown, variance ``var``, and
        uncorrelated with the rest of the state: ``P_θθ ← Π P_θθ Π + var d dᵀ``, ``P_θb ← Π P_θb``, ``Π = I − d dᵀ``.

        While no heading has been measured this is the truth, and it must be re-stated as the tilt updates move
        the vertical: left on the axis where it was first put (a few mrad off the vertical once the tilt is
        corrected), the huge variance leaks through each tilt update into the heading–bias covariance, and a
        zero-rate update then turns the heading (100° on a compass whose dip is off at start) and takes a third
        off its σ with no heading measured."""
        d0, d1, d2 = down
        t0, t1, t2, t3, t4, t5, t6, t7, t8 = self.p_tt
        u0, u1, u2 = t0 * d0 + t1 * d1 + t2 * d2, t3 * d0 + t4 * d1 + t5 * d2, t6 * d0 + t7 * d1 + t8 * d2  # P d
        a = var + d0 * u0 + d1 * u1 + d2 * u2  # Π P Π = P − d uᵀ − u dᵀ + (dᵀ P d) d dᵀ, plus var d dᵀ
        w0, w1, w2 = u0 - a * d0, u1 - a * d1, u2 - a * d2  # P − d wᵀ − w dᵀ − a d dᵀ, with w = u − a d
        xy = t1 - d0 * w1 - w0 * d1 - a * d0 * d1
        xz = t2 - d0 * w2 - w0 * d2 - a * d0 * d2
        yz = t5 - d1 * w2 - w1 * d2 - a * d1 * d2
        self.p_tt = (
            t0 - 2.0 * d0 * w0 - a * d0 * d0, xy, xz,
            xy, t4 - 2.0 * d1 * w1 - a * d1 * d1, yz,
            xz, yz, t8 - 2.0 * d2 * w2 - a * d2 * d2,
        )  # fmt: skip
        c0, c1, c2, c3, c4, c5, c6, c7, c8 = self.p_tb
        r0, r1, r2 = d0 * c0 + d1 * c3 + d2 * c6, d0 * c1 + d1 * c4 + d2 * c7, d0 * c2 + d1 * c5 + d2 * c8  # dᵀ P_θb
        self.p_tb = (
            c0 - d0 * r0, c1 - d0 * r1, c2 - d0 * r2,
            c3 - d1 * r0, c4 - d1 * r1, c5 - d1 * r2,
            c6 - d2 * r0, c7 - d2 * r1, c8 - d2 * r2,
        )  # fmt: skip

    def turn_about_down(self, angle_rad: float) -> None:
        """``q ← q_z(angle) ⊗ q``: the attitude turned about NED down (north moved, the body did not). ``P`` is of
        body-frame errors, and the gyro-only ``q_gyro`` keeps a frame of its own: both unchanged."""
        half = 0.5 * angle_rad
        self.q = _composed((math.cos(half), 0.0, 0.0, math.sin(half)), self.q)

    def reset(self) -> None:
        """Move the estimated error state ``[δθ, δb]`` into the nominal ``q`` and ``b``."""
        dx = self.dx
        if not any(dx):
            return
        (d0, d1, d2, d3, d4, d5), (b0, b1, b2) = dx, self.bias
        self.q = rotated(self.q, d0, d1, d2)
        self.bias = (b0 + d3, b1 + d4, b2 + d5)
        self.dx = _ZERO_DX


_ZERO_DX: tuple[float, ...] = (0.0,) * 6


def _composed(q: Quat, p: Quat) -> Quat:
    """``q ⊗ p`` normalised (``w ≥ 0``): quat_normalize_parts(quat_multiply_parts(q, p)) in one call, the same
    floats (two quaternions an update)."""
    qw, qx, qy, qz = q
    pw, px, py, pz = p
    w = qw * pw - qx * px - qy * py - qz * pz
    x = qw * px + qx * pw + qy * pz - qz * py
    y = qw * py - qx * pz + qy * pw + qz * px
    z = qw * pz + qx * py - qy * px + qz * pw
    n = math.sqrt(w * w + x * x + y * y + z * z)
    if w < 0.0:
        n = -n
    return (w / n, x / n, y / n, z / n)


_SMALL_ANGLE2 = 1e-4  # rad²: below 0.01 rad, rotated() spares sin, cos and the square root


def rotated(q: Quat, vx: float, vy: float, vz: float) -> Quat:
    """``q ⊗ exp(v)``, normalised (``w ≥ 0``). Below 0.01 rad as ``q ⊗ (1, t v)`` normalised, with
    ``t = 1/2 + θ²/24``, ``tan(θ/2)/θ`` to O(θ⁴): the rotation is off by less than θ⁵/120 (8e-13 rad), and a
    filter update's correction (99 % below 1e-3 rad on BROAD) or an output tick's carry costs no libm call."""
    angle2 = vx * vx + vy * vy + vz * vz
    if angle2 >= _SMALL_ANGLE2:
        return _composed(q, quat_from_rotvec_parts(vx, vy, vz))
    t = 0.5 + angle2 / 24.0
    a0, a1, a2 = t * vx, t * vy, t * vz
    w, x, y, z = q
    # q ⊗ (1, a) and quat_normalize_parts, written out (the same floats): two calls, twice a sample at 25 Hz
    w, x, y, z = (
        w - x * a0 - y * a1 - z * a2,
        x + w * a0 + y * a2 - z * a1,
        y + w * a1 - x * a2 + z * a0,
        z + w * a2 + x * a1 - y * a0,
    )
    n = math.sqrt(w * w + x * x + y * y + z * z)
    if w < 0.0:
        n = -n
    return (w / n, x / n, y / n, z / n)
