"""Whether the specific force is gravity alone: the one rule, with each user's thresholds. No I/O.

An accelerometer reads the specific force ``f = a − g``; only when the vehicle neither accelerates nor turns is
``f`` the gravity every snapshot solve (the paper's Eq. 1–2 reference ``[0, 0, −1]``) and the compass's dip
assume. Two cheap symptoms say it is not: ``| |f| − g |`` beyond a fraction of g (a linear acceleration, a tap,
vibration) and ``|ω|`` beyond a rate (a turn, whose centripetal acceleration and lag the snapshot does not see).
Three users ask it with thresholds of their own purpose: the front end's ``ACC_NORM`` flag (the accelerometer's
weight inflated) and ``MOVING`` flag (the cross-check does not vouch for a snapshot), and the compass monitor's
*quiet* samples (the only ones its dip and |B| count).

A third symptom is for a vehicle in a sustained turn, which neither of those sees: a coordinated turn's
centripetal acceleration ``v ψ̇`` leans the specific force by ``atan(v ψ̇ / g)`` for as long as the turn lasts,
while ``|f|`` is off g by only ``1/cos − 1`` of it (0.75 % at 7°) and the body turns slowly. It turns about the
vertical, though, which the specific force still nearly shows: :func:`turning` is ``|f · ω| / |f|`` beyond a rate.

Each function takes plain floats or equal-shape arrays alike; :func:`norm` and :func:`norm_rows` are the same
operations in the same order (both square roots correctly rounded), so the per-sample and the batch paths agree
to the bit.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any

import numpy as np

from .conventions import STANDARD_GRAVITY_MPS2, Array


def norm2(v: Sequence[float]) -> float:
    """``|v|²`` of a 3-vector of plain floats."""
    return v[0] * v[0] + v[1] * v[1] + v[2] * v[2]


def norm(v: Sequence[float]) -> float:
    """``|v|`` of a 3-vector of plain floats."""
    return math.sqrt(v[0] * v[0] + v[1] * v[1] + v[2] * v[2])


def dot(a: Sequence[float], b: Sequence[float]) -> float:
    """``a · b`` of two 3-vectors of plain floats."""
    return a[0] * b[0] + a[1] * b[1] + a[2] * b[2]


def dot_rows(a: Array, b: Array) -> Array:
    """:func:`dot` of each row pair of two ``(n, 3)`` arrays, the same operations in the same order."""
    return a[:, 0] * b[:, 0] + a[:, 1] * b[:, 1] + a[:, 2] * b[:, 2]


def norm2_rows(a: Array) -> Array:
    """:func:`norm2` of each row of an ``(n, 3)`` array."""
    return a[:, 0] * a[:, 0] + a[:, 1] * a[:, 1] + a[:, 2] * a[:, 2]


def norm_rows(a: Array) -> Array:
    """:func:`norm` of each row of an ``(n, 3)`` array."""
    return np.sqrt(norm2_rows(a))


def off_gravity(acc_norm_mps2: Any, fraction: float, gravity_mps2: float = STANDARD_GRAVITY_MPS2) -> Any:
    """``| |f| − g | > fraction · g``: the specific force's magnitude is off g, above or below (False for NaN)."""
    return abs(acc_norm_mps2 - gravity_mps2) > fraction * gravity_mps2


def turning(acc_dot_gyr: Any, acc_norm_mps2: Any, rate_radps: float) -> Any:
    """Turning about the specific force's direction faster than ``rate_radps``: ``|f · ω| > rate · |f|``, with
    ``f · ω`` given (False for NaN)."""
    return abs(acc_dot_gyr) > rate_radps * acc_norm_mps2


def moving(
    acc_norm_mps2: Any,
    gyr_norm_radps: Any,
    accel_fraction: float,
    rate_radps: float,
    gravity_mps2: float = STANDARD_GRAVITY_MPS2,
) -> Any:
    """Turning faster than ``rate_radps`` or :func:`off_gravity` by ``accel_fraction``: the specific force may
    not be gravity (False for NaN)."""
    return (gyr_norm_radps > rate_radps) | off_gravity(acc_norm_mps2, accel_fraction, gravity_mps2)
