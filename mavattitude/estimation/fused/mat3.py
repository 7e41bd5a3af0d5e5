"""3×3 blocks and 3-vectors as plain-float tuples: the covariance algebra of the filter runs on these.

A numpy call costs about a microsecond, which on 3×3 matrices is more than the arithmetic; matrices are
row-major 9-tuples.
"""

from __future__ import annotations

from collections.abc import Sequence

from ..conventions import Vec3, rotate_body_to_ned_parts

Block = tuple[float, float, float, float, float, float, float, float, float]  # a 3×3 block, row-major
ZERO3: Block = (0.0,) * 9  # type: ignore[assignment]
matvec = rotate_body_to_ned_parts  # a x


def propagated(
    r: Block, c: float, tt: Block, tb: Block, bb: Block, diag: float, walk: float
) -> tuple[Block, Block, Block]:
    """``P_θθ``, ``P_θb`` and ``P_bb`` propagated over an interval (``ekf.ErrorStateFilter.propagate``), written
    out in one call: with ``A = R(Δq)ᵀ`` (``r`` = R(Δq), row-major), ``X_θ = A (P_θθ + c P_θbᵀ) + c P_θbᵀ``,
    ``X_b = A (P_θb + c P_bb) + c P_bb`` (``P_bb`` symmetric), ``P_θb ← X_b``,
    ``P_θθ ← (X_θ + c X_b) Aᵀ + c X_b + diag I``, symmetric: its upper triangle mirrored, without averaging, and
    ``P_bb ← P_bb + walk I`` (symmetric as it is: every update writes it so)."""
    r0, r1, r2, r3, r4, r5, r6, r7, r8 = r
    # X_θ, with P_θb read transposed in place
    e0, e3, e6, e1, e4, e7, e2, e5, e8 = tb
    e0, e1, e2, e3, e4, e5, e6, e7, e8 = c * e0, c * e1, c * e2, c * e3, c * e4, c * e5, c * e6, c * e7, c * e8
    y0, y1, y2, y3, y4, y5, y6, y7, y8 = tt
    z0, z1, z2, z3, z4, z5, z6, z7, z8 = y0 + e0, y1 + e1, y2 + e2, y3 + e3, y4 + e4, y5 + e5, y6 + e6, y7 + e7, y8 + e8
    t0, t1, t2 = r0 * z0 + r3 * z3 + r6 * z6 + e0, r0 * z1 + r3 * z4 + r6 * z7 + e1, r0 * z2 + r3 * z5 + r6 * z8 + e2
    t3, t4, t5 = r1 * z0 + r4 * z3 + r7 * z6 + e3, r1 * z1 + r4 * z4 + r7 * z7 + e4, r1 * z2 + r4 * z5 + r7 * z8 + e5
    t6, t7, t8 = r2 * z0 + r5 * z3 + r8 * z6 + e6, r2 * z1 + r5 * z4 + r8 * z7 + e7, r2 * z2 + r5 * z5 + r8 * z8 + e8
    # X_b
    f0, f1, f2, f3, f4, f5, f6, f7, f8 = bb
    e0, e1, e2, e4, e5, e8 = c * f0, c * f1, c * f2, c * f4, c * f5, c * f8
    e3, e6, e7 = e1, e2, e5  # c P_bb: P_bb is symmetric (every update writes it so), its lower triangle mirrored
    y0, y1, y2, y3, y4, y5, y6, y7, y8 = tb
    z0, z1, z2, z3, z4, z5, z6, z7, z8 = y0 + e0, y1 + e1, y2 + e2, y3 + e3, y4 + e4, y5 + e5, y6 + e6, y7 + e7, y8 + e8
    x_b = b0, b1, b2, b3, b4, b5, b6, b7, b8 = (
        r0 * z0 + r3 * z3 + r6 * z6 + e0,
        r0 * z1 + r3 * z4 + r6 * z7 + e1,
        r0 * z2 + r3 * z5 + r6 * z8 + e2,
        r1 * z0 + r4 * z3 + r7 * z6 + e3,
        r1 * z1 + r4 * z4 + r7 * z7 + e4,
        r1 * z2 + r4 * z5 + r7 * z8 + e5,
        r2 * z0 + r5 * z3 + r8 * z6 + e6,
        r2 * z1 + r5 * z4 + r8 * z7 + e7,
        r2 * z2 + r5 * z5 + r8 * z8 + e8,
    )
    # (X_θ + c X_b) Aᵀ + c X_b + diag I: the upper triangle
    e0, e1, e2, e4, e5, e8 = c * b0, c * b1, c * b2, c * b4, c * b5, c * b8
    z0, z1, z2, z3, z4, z5 = t0 + e0, t1 + e1, t2 + e2, t3 + c * b3, t4 + e4, t5 + e5
    z6, z7, z8 = t6 + c * b6, t7 + c * b7, t8 + e8
    xy = z0 * r1 + z1 * r4 + z2 * r7 + e1
    xz = z0 * r2 + z1 * r5 + z2 * r8 + e2
    yz = z3 * r2 + z4 * r5 + z5 * r8 + e5
    p_tt = (
        z0 * r0 + z1 * r3 + z2 * r6 + e0 + diag, xy, xz,
        xy, z3 * r1 + z4 * r4 + z5 * r7 + e4 + diag, yz,
        xz, yz, z6 * r2 + z7 * r5 + z8 * r8 + e8 + diag,
    )  # fmt: skip
    return p_tt, x_b, (f0 + walk, f1, f2, f3, f4 + walk, f5, f6, f7, f8 + walk)


def plus_diagonal(a: Block, diag: float) -> Block:
    """``a + diag I``."""
    a0, a1, a2, a3, a4, a5, a6, a7, a8 = a
    return (a0 + diag, a1, a2, a3, a4 + diag, a5, a6, a7, a8 + diag)


def dot(a: Sequence[float], b: Sequence[float]) -> float:
    return a[0] * b[0] + a[1] * b[1] + a[2] * b[2]


def cross(a: Sequence[float], b: Sequence[float]) -> Vec3:
    return (a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0])
