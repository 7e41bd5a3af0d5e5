"""Frames, quaternions and Euler angles: the project's one statement of its conventions.

- Earth frame NED, body frame FRD.
- Quaternions scalar-first ``[w, x, y, z]``, Hamilton product, rotating body vectors into NED:
  ``v_ned = q ⊗ v_body ⊗ q*``. This is MAVLink's ATTITUDE_QUATERNION ``q1..q4`` and the quaternion
  of the autopilot's ATTITUDE (ZYX Euler: ``q = q_yaw ⊗ q_pitch ⊗ q_roll``).
- ``R(q)`` rotates body → NED; the paper's attitude matrix (Eq. 27, Shuster's sign)
  ``A(q) = (w² − ρᵀρ) I + 2ρρᵀ − 2w[ρ×] = R(q)ᵀ`` maps NED → body: ``w_body = A v_ned``.
- Error angles live in the body frame (Eq. 14, 28–30): ``q̂ = q_true ⊗ [1, δα/2]``.

Every array function is vectorised over leading axes: a quaternion argument is ``(..., 4)``, a vector
``(..., 3)``. The ``*_parts`` functions are the same formulas on components (a quaternion as a 4-tuple,
a vector as a 3-tuple, a matrix as a row-major 9-tuple) whose entries are plain floats *or* equal-shape
arrays: the array functions delegate to them, and the estimation core calls them directly with floats on
its per-sample path (no numpy call overhead) and with arrays on its batch path — one formula each. Those
that branch or call ``math`` (the scalar twins of an array function) take plain floats only.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

# The package's array and plain-float types: arrays are float64; a vector, quaternion or matrix as plain floats is
# a tuple (a matrix as its rows, as a config file writes it).
Array = NDArray[np.float64]
Vec3 = tuple[float, float, float]
Quat = tuple[float, float, float, float]
Mat3 = tuple[Vec3, Vec3, Vec3]

STANDARD_GRAVITY_MPS2 = 9.80665  # the g of "mG" in MAVLink and of ArduPilot's GRAVITY_MSS
ACC_REF_NED = (0.0, 0.0, -1.0)  # an accelerometer at rest reads the specific force, up: −z in NED

#: ``| |q|² − 1 |`` at or beyond this is a numerical failure, not an attitude: float64 rounding leaves a
#: normalised quaternion within ~1e-15 of unit, and an estimate gone wrong (a diverged solve, a filter
#: state that blew up) is off by orders of magnitude more. (Near 1, ``|q|² − 1 ≈ 2 (|q| − 1)``.)
UNIT_NORM2_TOLERANCE = 1e-6


def is_unit_quaternion_parts(q: tuple) -> bool:
    """Finite and unit to :data:`UNIT_NORM2_TOLERANCE`: the one test an attitude passes before it is output."""
    norm2 = q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3]  # NaN or inf if any component is
    return math.isfinite(norm2) and abs(norm2 - 1.0) < UNIT_NORM2_TOLERANCE


def skew(v: ArrayLike) -> Array:
    """Cross-product matrix ``[v×]``, so that ``skew(v) @ x == np.cross(v, x)``."""
    v = np.asarray(v, dtype=float)
    x, y, z = v[..., 0], v[..., 1], v[..., 2]
    # Filled in place rather than stacked: 3 µs instead of 17 for one vector (the fused filter's tilt update).
    m = np.zeros((*v.shape, 3))
    m[..., 0, 1], m[..., 0, 2], m[..., 1, 2] = -z, y, -x
    m[..., 1, 0], m[..., 2, 0], m[..., 2, 1] = z, -y, x
    return m


def _parts(a: ArrayLike) -> tuple:
    a = np.asarray(a, dtype=float)
    return tuple(a[..., k] for k in range(a.shape[-1]))


def quat_multiply_parts(p: tuple, q: tuple) -> tuple:
    """Hamilton product ``p ⊗ q`` on components."""
    pw, px, py, pz = p
    qw, qx, qy, qz = q
    return (
        pw * qw - px * qx - py * qy - pz * qz,
        pw * qx + px * qw + py * qz - pz * qy,
        pw * qy - px * qz + py * qw + pz * qx,
        pw * qz + px * qy - py * qx + pz * qw,
    )


def quat_multiply(p: ArrayLike, q: ArrayLike) -> Array:
    """Hamilton product ``p ⊗ q``."""
    return np.stack(quat_multiply_parts(_parts(p), _parts(q)), -1)


def quat_conjugate(q: ArrayLike) -> Array:
    """``q*``: the inverse rotation of a unit quaternion."""
    q = np.array(q, dtype=float)
    q[..., 1:] *= -1.0
    return q


def quat_normalize(q: ArrayLike) -> Array:
    """Unit quaternion with a non-negative scalar part (``q`` and ``−q`` are the same rotation)."""
    q = np.asarray(q, dtype=float)
    q = q / np.linalg.norm(q, axis=-1, keepdims=True)
    return np.where(q[..., :1] < 0.0, -q, q)


def clip_unit(x: float) -> float:
    """``x`` clamped to [−1, 1] for ``asin`` / ``acos`` (NaN gives 1.0, as ``max(-1.0, min(1.0, x))`` does),
    without the builtins, which parse their arguments: ten times the cost of the comparisons (per-sample paths)."""
    x = x if x < 1.0 else 1.0
    return x if x > -1.0 else -1.0


def wrap_deg(angle_deg: float) -> float:
    """An angle, or a difference of two, in degrees wrapped to [−180, 180): ours at −179° and another at +179°
    differ by 2°, not 358°."""
    return (angle_deg + 180.0) % 360.0 - 180.0


#: An interval longer than this many times the usual one (the median of the recent ones) is a gap in a stream,
#: never a gap when shorter than the configured floor (``input.input_timeout_s``): a 2 Hz stream's 0.5 s steps
#: are its rhythm, not gaps; one dropped message (twice the interval) is bridged, two are not.
GAP_INTERVALS = 2.5


def gap_limit_s(floor_s: float, usual_interval_s: float) -> float:
    """The longest interval of a stream that is not a gap: ``floor_s``, or :data:`GAP_INTERVALS` × the usual
    interval when that is longer (NaN when the usual interval is not known yet: the floor)."""
    scaled = GAP_INTERVALS * usual_interval_s
    return scaled if scaled > floor_s else floor_s


def quat_normalize_parts(q: tuple) -> tuple[float, float, float, float]:
    """Scalar (plain-float) twin of :func:`quat_normalize`: unit, ``w ≥ 0``."""
    w, x, y, z = q
    n = math.sqrt(w * w + x * x + y * y + z * z)
    if w < 0.0:
        n = -n
    return (w / n, x / n, y / n, z / n)


def rotation_matrix_parts(q: tuple) -> tuple:
    """``R(q)`` of a unit quaternion on components, row-major ``(r00, r01, ..., r22)``. The constants are
    floats: an int operand takes CPython's slow mixed-type path, twice the time on plain floats (same values).

    The doubled products (``2xy`` as ``x (2y)``): doubling is exact, so each entry is the float of
    ``2 (xy − wz)`` and ``1 − 2 (yy + zz)``, in 24 float operations rather than 30 (three R(q) a filter update)."""
    w, x, y, z = q
    x2, y2, z2 = 2.0 * x, 2.0 * y, 2.0 * z
    xx, yy, zz, xy, xz, yz, wx, wy, wz = x * x2, y * y2, z * z2, x * y2, x * z2, y * z2, w * x2, w * y2, w * z2
    return (
        1.0 - (yy + zz), xy - wz, xz + wy,
        xy + wz, 1.0 - (xx + zz), yz - wx,
        xz - wy, yz + wx, 1.0 - (xx + yy),
    )  # fmt: skip


def rotation_matrix(q: ArrayLike) -> Array:
    """``R(q)``: body → NED rotation matrix of a unit quaternion."""
    r = rotation_matrix_parts(_parts(q))
    return np.stack([np.stack(r[0:3], -1), np.stack(r[3:6], -1), np.stack(r[6:9], -1)], -2)


def rotate_body_to_ned_parts(r: tuple, v: tuple) -> tuple:
    """``R(q) v`` on components, given ``r = rotation_matrix_parts(q)`` (any row-major matrix times ``v``). Unpacked
    once: an index costs three times a local's load, and these run several times a sample."""
    r0, r1, r2, r3, r4, r5, r6, r7, r8 = r
    x, y, z = v
    return (r0 * x + r1 * y + r2 * z, r3 * x + r4 * y + r5 * z, r6 * x + r7 * y + r8 * z)


def rotate_ned_to_body_parts(r: tuple, v: tuple) -> tuple:
    """``A v = R(q)ᵀ v`` (Eq. 27) on components, given ``r = rotation_matrix_parts(q)`` (unpacked once, as above)."""
    r0, r1, r2, r3, r4, r5, r6, r7, r8 = r
    x, y, z = v
    return (r0 * x + r3 * y + r6 * z, r1 * x + r4 * y + r7 * z, r2 * x + r5 * y + r8 * z)


def attitude_matrix(q: ArrayLike) -> Array:
    """The paper's ``A(q)`` (Eq. 27): NED → body, ``A(q) = R(q)ᵀ``."""
    return np.swapaxes(rotation_matrix(q), -1, -2)


def rotate_body_to_ned(q: ArrayLike, v_body: ArrayLike) -> Array:
    """``R(q) v``: a body-frame vector expressed in NED."""
    return np.einsum("...ij,...j->...i", rotation_matrix(q), np.asarray(v_body, dtype=float))


def rotate_ned_to_body(q: ArrayLike, v_ned: ArrayLike) -> Array:
    """``A(q) v``: a NED vector expressed in the body frame."""
    return np.einsum("...ij,...j->...i", attitude_matrix(q), np.asarray(v_ned, dtype=float))


def _shepperd_candidates(r: tuple) -> tuple[tuple, tuple]:
    """Shepperd's pivots and four candidate (unnormalised) quaternions of a row-major 9-tuple matrix."""
    r00, r01, r02, r10, r11, r12, r20, r21, r22 = r
    trace = r00 + r11 + r22
    # Antisymmetric (d*) and symmetric (s*) off-diagonal combinations.
    dx, dy, dz = r21 - r12, r02 - r20, r10 - r01
    sxy, sxz, syz = r01 + r10, r02 + r20, r12 + r21
    candidates = (  # float constants: an int operand takes CPython's slow mixed-type path (same values)
        (1.0 + trace, dx, dy, dz),
        (dx, 1.0 + 2.0 * r00 - trace, sxy, sxz),
        (dy, sxy, 1.0 + 2.0 * r11 - trace, syz),
        (dz, sxz, syz, 1.0 + 2.0 * r22 - trace),
    )
    return (trace, r00, r11, r22), candidates


def quat_from_rotation_parts(r: tuple) -> tuple[float, float, float, float]:
    """Scalar (plain-float) twin of :func:`quat_from_rotation_matrix` on a row-major 9-tuple.

    Same candidates; the largest pivot is picked with a branch instead of a gather.
    """
    pivots, candidates = _shepperd_candidates(r)
    w, x, y, z = candidates[pivots.index(max(pivots))]
    n = (w * w + x * x + y * y + z * z) ** -0.5
    if w < 0.0:
        n = -n
    return w * n, x * n, y * n, z * n


def quat_from_rotation_matrix(r: ArrayLike) -> Array:
    """Unit quaternion (``w ≥ 0``) of a body → NED rotation matrix (Shepperd's method, branch-free).

    Of the four candidate formulas the one with the largest pivot is used per sample, so the result
    is accurate for every rotation, 180° included.
    """
    r = np.asarray(r, dtype=float)
    pivots, candidates = _shepperd_candidates(tuple(r[..., i, j] for i in range(3) for j in range(3)))
    candidates = np.stack([np.stack(c, -1) for c in candidates], -2)
    pivot = np.argmax(np.stack(pivots, -1), axis=-1)
    q = np.take_along_axis(candidates, pivot[..., None, None], axis=-2)[..., 0, :]
    return quat_normalize(q)


def _quat_from_half_angles(cr: float, sr: float, cp: float, sp: float, cy: float, sy: float) -> tuple:
    """``q_yaw ⊗ q_pitch ⊗ q_roll`` from the cosines and sines of the half angles."""
    return (
        cr * cp * cy + sr * sp * sy,
        sr * cp * cy - cr * sp * sy,
        cr * sp * cy + sr * cp * sy,
        cr * cp * sy - sr * sp * cy,
    )


def quat_from_euler(roll_rad: ArrayLike, pitch_rad: ArrayLike, yaw_rad: ArrayLike) -> Array:
    """Quaternion of ZYX Euler angles (yaw, then pitch, then roll), as MAVLink's ATTITUDE uses them."""
    hr, hp, hy = (np.asarray(a, dtype=float) / 2.0 for a in (roll_rad, pitch_rad, yaw_rad))
    return np.stack(_quat_from_half_angles(np.cos(hr), np.sin(hr), np.cos(hp), np.sin(hp), np.cos(hy), np.sin(hy)), -1)


def quat_from_euler_parts(roll_rad: float, pitch_rad: float, yaw_rad: float) -> tuple[float, float, float, float]:
    """Scalar (plain-float) twin of :func:`quat_from_euler`."""
    hr, hp, hy = 0.5 * roll_rad, 0.5 * pitch_rad, 0.5 * yaw_rad
    return _quat_from_half_angles(math.cos(hr), math.sin(hr), math.cos(hp), math.sin(hp), math.cos(hy), math.sin(hy))


def tilt_quat_parts(acc: tuple) -> tuple[float, float, float, float]:
    """The attitude with the roll and pitch the specific force ``acc`` (body FRD, at rest ``(0, 0, −g)``) shows
    and yaw 0: ``f = −g R(q)ᵀ e_D = g (sin θ, −sin φ cos θ, −cos φ cos θ)``, so ``φ = atan2(−f_y, −f_z)``,
    ``θ = atan2(f_x, √(f_y² + f_z²))``. What the accelerometer alone knows; the heading is not in it."""
    fx, fy, fz = float(acc[0]), float(acc[1]), float(acc[2])
    return quat_from_euler_parts(math.atan2(-fy, -fz), math.atan2(fx, math.hypot(fy, fz)), 0.0)


def _euler_terms(w: Any, x: Any, y: Any, z: Any) -> tuple:
    """What ZYX Euler angles take the atan2 / asin / atan2 of: roll's two terms, pitch's sine, yaw's two
    (one formula for arrays and plain floats)."""
    return (
        2.0 * (w * x + y * z),
        1.0 - 2.0 * (x * x + y * y),
        2.0 * (w * y - x * z),
        2.0 * (w * z + x * y),
        1.0 - 2.0 * (y * y + z * z),
    )


def euler_from_quat(q: ArrayLike) -> Array:
    """ZYX Euler angles ``[..., (roll, pitch, yaw)]`` in radians; yaw in (−π, π]."""
    q = np.asarray(q, dtype=float)
    roll_y, roll_x, sin_pitch, yaw_y, yaw_x = _euler_terms(q[..., 0], q[..., 1], q[..., 2], q[..., 3])
    pitch = np.arcsin(np.clip(sin_pitch, -1.0, 1.0))
    return np.stack([np.arctan2(roll_y, roll_x), pitch, np.arctan2(yaw_y, yaw_x)], -1)


def euler_from_quat_parts(q: tuple) -> Vec3:
    """Scalar (plain-float) twin of :func:`euler_from_quat`: ``(roll, pitch, yaw)``, rad."""
    roll_y, roll_x, sin_pitch, yaw_y, yaw_x = _euler_terms(*q)
    return math.atan2(roll_y, roll_x), math.asin(min(max(sin_pitch, -1.0), 1.0)), math.atan2(yaw_y, yaw_x)


def quat_from_rotvec(theta: ArrayLike) -> Array:
    """Exponential map: the quaternion of a rotation vector (axis × angle, rad)."""
    theta = np.asarray(theta, dtype=float)
    angle = np.linalg.norm(theta, axis=-1, keepdims=True)
    half = angle / 2.0
    # sin(x/2)/x → 1/2 as x → 0; the series keeps full precision for tiny angles.
    scale = np.where(angle > 1e-8, np.sin(half) / np.where(angle > 1e-8, angle, 1.0), 0.5 - angle**2 / 48.0)
    return np.concatenate([np.cos(half), scale * theta], -1)


def quat_from_rotvec_parts(vx: float, vy: float, vz: float) -> tuple[float, float, float, float]:
    """Scalar (plain-float) twin of :func:`quat_from_rotvec`, the vector's components as arguments."""
    half = 0.5 * math.sqrt(vx * vx + vy * vy + vz * vz)
    s = 0.5 * math.sin(half) / half if half > 1e-9 else 0.5 - half * half / 12.0
    return (math.cos(half), s * vx, s * vy, s * vz)


def rotvec_from_quat(q: ArrayLike) -> Array:
    """Logarithmic map: rotation vector (rad) of a unit quaternion, angle in [0, π]."""
    q = quat_normalize(q)
    vec = q[..., 1:]
    s = np.linalg.norm(vec, axis=-1, keepdims=True)
    angle = 2.0 * np.arctan2(s, q[..., :1])
    scale = np.where(s > 1e-12, angle / np.where(s > 1e-12, s, 1.0), 2.0)
    return scale * vec


def body_error_angles(q_est: ArrayLike, q_true: ArrayLike) -> Array:
    """Body-frame error angles ``δα`` with ``q_est = q_true ⊗ exp(δα)`` (Eq. 28–30), rad."""
    return rotvec_from_quat(quat_multiply(quat_conjugate(q_true), q_est))


def angle_between(q_a: ArrayLike, q_b: ArrayLike) -> Array:
    """Rotation angle (rad, in [0, π]) that takes one attitude to the other.

    Uses ``atan2`` of the relative quaternion rather than ``arccos`` of a dot product, which keeps
    full precision for tiny angles (the solvers are compared to 1e-9 rad).
    """
    d = quat_multiply(quat_conjugate(q_a), q_b)
    return 2.0 * np.arctan2(np.linalg.norm(d[..., 1:], axis=-1), np.abs(d[..., 0]))


def angle_between_parts(q_a: tuple, q_b: tuple) -> float:
    """Scalar (plain-float) twin of :func:`angle_between`."""
    w, x, y, z = quat_multiply_parts((q_a[0], -q_a[1], -q_a[2], -q_a[3]), q_b)
    return 2.0 * math.atan2(math.sqrt(x * x + y * y + z * z), abs(w))
