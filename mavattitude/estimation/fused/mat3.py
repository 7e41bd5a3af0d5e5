"""3×3 blocks and 3-vectors as plain-float tuples: the covariance algebra of the filter runs on these.

A numpy call costs about a microsecond, which on 3×3 matrices is more than the arithmetic; matrices are
row-major 9-tuples.
"""

from __future__ import annotations

from collections.abc import Sequence

from ..conventions import Vec3

Block = tuple[float, float, float, float, float, float, float, float, float]  # a 3×3 block, row-major
ZERO3: Block = (0.0,) * 9  # type: ignore[assignment]


def mm(a: Block, b: Block, k: float = 0.0, c: Block | None = None) -> Block:
    """``a b + k c`` (one call where the propagation needs both: a call costs as much as the sum)."""
    a0, a1, a2, a3, a4, a5, a6, a7, a8 = a
    b0, b1, b2, b3, b4, b5, b6, b7, b8 = b
    c0, c1, c2, c3, c4, c5, c6, c7, c8 = ZERO3 if c is None else c
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


def transpose(a: Block) -> Block:
    return (a[0], a[3], a[6], a[1], a[4], a[7], a[2], a[5], a[8])


def axpy(a: Block, k: float, b: Block) -> Block:
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


def symmetric(a: Block, diag: float = 0.0) -> Block:
    """``(a + aᵀ)/2 + diag I``: removes the rounding asymmetry of a covariance update."""
    xy, xz, yz = 0.5 * (a[1] + a[3]), 0.5 * (a[2] + a[6]), 0.5 * (a[5] + a[7])
    return (a[0] + diag, xy, xz, xy, a[4] + diag, yz, xz, yz, a[8] + diag)


def matvec(a: Block, x: Sequence[float]) -> Vec3:
    return (
        a[0] * x[0] + a[1] * x[1] + a[2] * x[2],
        a[3] * x[0] + a[4] * x[1] + a[5] * x[2],
        a[6] * x[0] + a[7] * x[1] + a[8] * x[2],
    )


def tmatvec(a: Block, x: Sequence[float]) -> Vec3:
    """``aᵀ x``."""
    return (
        a[0] * x[0] + a[3] * x[1] + a[6] * x[2],
        a[1] * x[0] + a[4] * x[1] + a[7] * x[2],
        a[2] * x[0] + a[5] * x[1] + a[8] * x[2],
    )


def dot(a: Sequence[float], b: Sequence[float]) -> float:
    return a[0] * b[0] + a[1] * b[1] + a[2] * b[2]


def cross(a: Sequence[float], b: Sequence[float]) -> Vec3:
    return (a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0])
