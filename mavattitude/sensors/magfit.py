"""Magnetometer calibration by ellipsoid fit: hard-iron offset ``h`` and soft-iron matrix ``S`` such that
``|S (m − h)|`` is the same for every orientation.

1. Algebraic fit of the quadric ``mᵀ A m + bᵀ m = 1`` (linear least squares, 9 unknowns); its centre is
   ``h = −A⁻¹ b / 2`` and ``(m − h)ᵀ Q (m − h) = 1`` with ``Q = A / (1 − ... )`` positive definite for an
   ellipsoid; ``S = R · Q^{1/2}`` (symmetric square root).
2. Geometric refinement: Gauss–Newton on ``r_i = |S (m_i − h)| − R`` over ``h`` and the six entries of the
   symmetric ``S`` (bounded iterations; the algebraic fit is biased by noise).
``R`` is the expected field magnitude when given, else ``S`` is scaled to determinant 1 (volume kept).
A symmetric ``S`` is the only part of a soft-iron matrix the data determines (a rotation of the sensor
frame leaves every ``|B|`` unchanged).

Coverage: the corrected directions are binned on the 26 directions of a cube's faces, edges and corners;
a fit from too few of them (hand turns about one axis only, a bench) is refused with the reason.
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from mavattitude.errors import CalibrationError
from mavattitude.estimation.conventions import Array

MIN_SAMPLES = 50
MIN_COVERAGE = 0.6  # fraction of the 26 direction cells holding a sample
MIN_PER_CELL = 2
MAX_AXIS_RATIO = 3.0  # a soft-iron matrix stretching one axis 3× the others is a bad fit or bad data
MIN_TURN_SPAN = 0.2  # readings spanning less than this fraction of |B| on every axis: the vehicle stayed put
#: The Earth's field at the surface lies between about 22 and 67 µT (the World Magnetic Model's total intensity);
#: a fitted |B| more than half as far again outside it is not a local disturbance but the wrong units
EARTH_FIELD_UT = (22.0, 67.0)
UNITS_MARGIN = 1.5
MAX_ITERATIONS = 50
TOLERANCE = 1e-10

_CUBE_DIRECTIONS = np.array([d for d in itertools.product((-1.0, 0.0, 1.0), repeat=3) if any(d)], dtype=float)
CELL_DIRECTIONS: Array = _CUBE_DIRECTIONS / np.linalg.norm(_CUBE_DIRECTIONS, axis=1, keepdims=True)


@dataclass(frozen=True)
class MagFit:
    hard_iron_uT: Array  # (3,)
    soft_iron: Array  # (3, 3), symmetric positive definite
    radius_uT: float  # the fitted |B|
    residual_rms_uT: float  # rms of |S (m − h)| − R
    coverage: float  # fraction of direction cells covered
    spread_before: float  # std(|m|) / mean(|m|)
    spread_after: float  # std(|S (m − h)|) / mean(|S (m − h)|)
    iterations: int
    samples: int

    def apply(self, mag_uT: ArrayLike) -> Array:
        return (np.asarray(mag_uT, dtype=float) - self.hard_iron_uT) @ self.soft_iron.T


def relative_spread(mag_uT: ArrayLike) -> float:
    """std(|B|) / mean(|B|): 0 for a perfect calibration."""
    norms = np.linalg.norm(np.asarray(mag_uT, dtype=float), axis=1)
    return float(np.std(norms) / np.mean(norms))


def coverage(directions: ArrayLike, min_per_cell: int = MIN_PER_CELL) -> tuple[float, NDArray[np.int64]]:
    """Fraction of the 26 cells with at least ``min_per_cell`` directions, and the count per cell."""
    counts = cell_counts(directions)
    return covered(counts, min_per_cell), counts


def cell_counts(directions: ArrayLike) -> NDArray[np.int64]:
    """How many of the directions fall in each of the 26 cells (a sum over the directions: additive)."""
    d = np.asarray(directions, dtype=float)
    norm = np.linalg.norm(d, axis=1, keepdims=True)
    d = d[norm[:, 0] > 0.0] / norm[norm[:, 0] > 0.0]  # a zero vector has no direction
    cells = np.argmax(d @ CELL_DIRECTIONS.T, axis=1)
    return np.bincount(cells, minlength=len(CELL_DIRECTIONS))


def covered(counts: NDArray[np.int64], min_per_cell: int = MIN_PER_CELL) -> float:
    """Fraction of the cells with at least ``min_per_cell`` directions."""
    return float(np.mean(counts >= min_per_cell))


def _algebraic(m: Array) -> tuple[Array, Array]:
    """Centre and shape matrix ``Q`` of the least-squares quadric through the points."""
    x, y, z = m.T
    design = np.column_stack([x * x, y * y, z * z, 2 * y * z, 2 * x * z, 2 * x * y, 2 * x, 2 * y, 2 * z])
    coef, *_ = np.linalg.lstsq(design, np.ones(len(m)), rcond=None)
    a = np.array([[coef[0], coef[5], coef[4]], [coef[5], coef[1], coef[3]], [coef[4], coef[3], coef[2]]])
    b = coef[6:9]
    try:
        centre = -np.linalg.solve(a, b)
    except np.linalg.LinAlgError as exc:
        raise CalibrationError("the samples do not determine an ellipsoid (singular fit)") from exc
    scale = 1.0 + centre @ a @ centre
    q = a / scale
    if not np.all(np.linalg.eigvalsh(q) > 0.0):
        raise CalibrationError("the samples do not lie on an ellipsoid (the fitted quadric is not one)")
    return centre, q


def _sqrtm(q: Array) -> Array:
    w, v = np.linalg.eigh(q)
    return (v * np.sqrt(w)) @ v.T


_SYM = [(0, 0), (1, 1), (2, 2), (0, 1), (0, 2), (1, 2)]


def _refine(m: Array, h: Array, s: Array, radius: float) -> tuple[Array, Array, int]:
    """Gauss–Newton on ``|S (m − h)| − R`` over ``h`` and the symmetric ``S``."""
    iterations = 0
    for iterations in range(1, MAX_ITERATIONS + 1):  # noqa: B007 (the count is reported)
        d = m - h
        v = d @ s.T
        norm = np.linalg.norm(v, axis=1)
        u = v / norm[:, None]
        r = norm - radius
        jac_h = -(u @ s)  # ∂|v|/∂h = −uᵀ S
        jac_s = np.column_stack(
            [u[:, i] * d[:, j] + (u[:, j] * d[:, i] if i != j else 0.0) for i, j in _SYM]
        )  # ∂|v|/∂S_ij for the symmetric pair
        jac = np.hstack([jac_h, jac_s])
        step, *_ = np.linalg.lstsq(jac, -r, rcond=None)
        h = h + step[:3]
        for k, (i, j) in enumerate(_SYM):
            s[i, j] += step[3 + k]
            s[j, i] = s[i, j]
        if np.max(np.abs(step)) < TOLERANCE * max(1.0, radius):
            break
    return h, s, iterations


def _require_turns(m: Array) -> None:
    """Readings that barely change are a vehicle left at rest, whatever an ellipsoid through them says."""
    span_uT = float(np.max(np.ptp(m, axis=0)))
    field_uT = float(np.median(np.linalg.norm(m, axis=1)))
    if span_uT < MIN_TURN_SPAN * field_uT:
        raise CalibrationError(
            f"the vehicle was not turned: the readings span {span_uT:.1f} µT on |B| ≈ {field_uT:.0f} µT; "
            "turn it through all attitudes, including upside down and on each side"
        )


def _require_coverage(frac: float, min_coverage: float) -> None:
    if frac < min_coverage:
        raise CalibrationError(
            f"the samples cover {frac:.0%} of the orientations (need {min_coverage:.0%}): "
            "turn the vehicle through all attitudes, including upside down and on each side"
        )


def fit_ellipsoid(
    mag_uT: ArrayLike,
    field_uT: float | None = None,
    min_coverage: float = MIN_COVERAGE,
) -> MagFit:
    """Fit hard and soft iron to magnetometer samples (sensor frame, µT), refusing poor data with the reason."""
    m = np.asarray(mag_uT, dtype=float)
    if m.ndim != 2 or m.shape[1] != 3:
        raise CalibrationError(f"expected magnetometer samples as rows of 3 values, got shape {m.shape}")
    m = m[np.all(np.isfinite(m), axis=1)]
    if len(m) < MIN_SAMPLES:
        raise CalibrationError(f"only {len(m)} finite magnetometer samples; at least {MIN_SAMPLES} are needed")
    _require_turns(m)
    spread = np.linalg.eigvalsh(np.cov((m - m.mean(axis=0)).T))
    if spread[0] < 1e-3 * spread[2]:
        raise CalibrationError(
            "the samples lie in a plane: the vehicle was turned about one axis only; turn it about all three"
        )
    try:
        h, q = _algebraic(m)
    except CalibrationError:
        _require_coverage(coverage(m)[0], min_coverage)  # the likely reason, when it is one
        raise
    frac, _ = coverage(m - h)
    _require_coverage(frac, min_coverage)
    s = _sqrtm(q)
    radius = float(field_uT) if field_uT is not None else float(np.linalg.det(s) ** (-1.0 / 3.0))
    s = s * radius
    h, s, iterations = _refine(m, h, s, radius)
    axes = np.linalg.eigvalsh(s)
    if axes[0] <= 0.0 or axes[2] / axes[0] > MAX_AXIS_RATIO:
        raise CalibrationError(
            f"the fitted soft-iron axes differ by {axes[2] / axes[0]:.2g}× (> {MAX_AXIS_RATIO:g}×): "
            "magnetic disturbance during the turns, or a broken sensor"
        )
    if field_uT is None:  # S positive definite (checked above): its determinant is > 0
        det = np.linalg.det(s)
        s, radius = s / det ** (1.0 / 3.0), radius / det ** (1.0 / 3.0)
    corrected = (m - h) @ s.T
    residual = np.linalg.norm(corrected, axis=1) - radius
    return MagFit(
        hard_iron_uT=h,
        soft_iron=s,
        radius_uT=radius,
        residual_rms_uT=float(np.sqrt(np.mean(residual**2))),
        coverage=frac,
        spread_before=relative_spread(m),
        spread_after=relative_spread(corrected),
        iterations=iterations,
        samples=len(m),
    )


def unlike_earth(field_uT: float, what: str = "the fitted field") -> str | None:
    """Why ``field_uT`` (``what``: a fitted |B|, or a compass's median) cannot be the Earth's field in µT, or
    ``None`` when it can."""
    low, high = EARTH_FIELD_UT
    if low / UNITS_MARGIN <= field_uT <= high * UNITS_MARGIN:
        return None
    return f"{what} is {field_uT:.3g} µT, where the Earth's is {low:g}-{high:g} µT"
