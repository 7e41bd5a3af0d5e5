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


def tmm_shift(r: Block, y: Block, k: float, e: Block) -> Block:
    """``rᵀ (y + k eᵀ) + k eᵀ`` written out (the covariance propagation, once per update); ``k eᵀ`` once, ``e``
    read transposed rather than transposed into a new tuple."""
    r0, r1, r2, r3, r4, r5, r6, r7, r8 = r
    e0, e3, e6, e1, e4, e7, e2, e5, e8 = e
    e0, e1, e2, e3, e4, e5, e6, e7, e8 = k * e0, k * e1, k * e2, k * e3, k * e4, k * e5, k * e6, k * e7, k * e8
    y0, y1, y2, y3, y4, y5, y6, y7, y8 = y
    z0, z1, z2, z3, z4, z5, z6, z7, z8 = y0 + e0, y1 + e1, y2 + e2, y3 + e3, y4 + e4, y5 + e5, y6 + e6, y7 + e7, y8 + e8
    return (
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


def mm_shift_sym(y: Block, k: float, e: Block, r: Block, diag: float) -> Block:
    """``(y + k e) r + k e + diag I`` for a sum known to be symmetric (the propagated ``P_θθ``): the upper
    triangle written out and mirrored, which is symmetric without averaging and costs two thirds of the product."""
    r0, r1, r2, r3, r4, r5, r6, r7, r8 = r
    e0, e1, e2, e3, e4, e5, e6, e7, e8 = e
    e0, e1, e2, e3, e4, e5, e6, e7, e8 = k * e0, k * e1, k * e2, k * e3, k * e4, k * e5, k * e6, k * e7, k * e8
    y0, y1, y2, y3, y4, y5, y6, y7, y8 = y
    z0, z1, z2, z3, z4, z5, z6, z7, z8 = y0 + e0, y1 + e1, y2 + e2, y3 + e3, y4 + e4, y5 + e5, y6 + e6, y7 + e7, y8 + e8
    xy = z0 * r1 + z1 * r4 + z2 * r7 + e1
    xz = z0 * r2 + z1 * r5 + z2 * r8 + e2
    yz = z3 * r2 + z4 * r5 + z5 * r8 + e5
    return (
        z0 * r0 + z1 * r3 + z2 * r6 + e0 + diag, xy, xz,
        xy, z3 * r1 + z4 * r4 + z5 * r7 + e4 + diag, yz,
        xz, yz, z6 * r2 + z7 * r5 + z8 * r8 + e8 + diag,
    )  # fmt: skip


def plus_diagonal(a: Block, diag: float) -> Block:
    """``a + diag I``."""
    a0, a1, a2, a3, a4, a5, a6, a7, a8 = a
    return (a0 + diag, a1, a2, a3, a4 + diag, a5, a6, a7, a8 + diag)


def dot(a: Sequence[float], b: Sequence[float]) -> float:
    return a[0] * b[0] + a[1] * b[1] + a[2] * b[2]


def cross(a: Sequence[float], b: Sequence[float]) -> Vec3:
    return (a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0])
