"""The sensor noise model (Eq. 1–2) and its unit-vector form (Eq. 7, 9) with the paper's weights (Eq. 21).

``NoiseModel`` holds the per-axis standard deviations of each sensor in its own units; the diagonal
covariance ``R = diag(σx², σy², σz²)`` is Eq. 2. The unit-vector covariance ``R_unit = J R Jᵀ`` (Eq. 9)
and the weight ``a = 1/κ², κ² = tr(R_unit)/3`` (Eq. 21) are evaluated at each measured vector by
:mod:`.kernel`; :func:`unit_covariance` and :func:`paper_weight` are their array forms.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import ArrayLike, NDArray

from ..errors import InputError
from . import kernel


def _sigmas(name: str, value: float | Sequence[float]) -> tuple[float, float, float]:
    try:
        if type(value) is tuple and len(value) == 3:  # the usual form, without numpy (a measurement's, every second)
            sig = (float(value[0]), float(value[1]), float(value[2]))
        else:
            sig = tuple(float(s) for s in np.broadcast_to(np.asarray(value, dtype=float), (3,)))
    except (TypeError, ValueError) as exc:
        raise InputError(f"{name} must be one σ or three per-axis σ (x, y, z), got {value!r}") from exc
    if not all(s > 0.0 and 0.0 < s * s < math.inf for s in sig):  # σ² must neither overflow nor underflow
        raise InputError(f"{name} must be finite and > 0 on every axis (1e-150 < σ < 1e150), got {sig}")
    return sig  # type: ignore[return-value]


@dataclass(frozen=True)
class NoiseModel:
    """Per-axis white-noise σ of each sensor, in that sensor's own units (any units: only ratios to
    the measured magnitude matter). A single number means the same σ on all three axes."""

    accel_std: tuple[float, float, float]
    mag_std: tuple[float, float, float]

    accel_var: tuple[float, float, float] = field(init=False, repr=False)  # diagonal of R₂ (Eq. 2), units²
    mag_var: tuple[float, float, float] = field(init=False, repr=False)  # diagonal of R₁ (Eq. 2), units²

    def __post_init__(self) -> None:
        for name in ("accel", "mag"):
            sig = _sigmas(f"{name}_std", getattr(self, f"{name}_std"))
            object.__setattr__(self, f"{name}_std", sig)
            object.__setattr__(self, f"{name}_var", tuple(s * s for s in sig))


def unit_covariance(w_raw: ArrayLike, var: Sequence[float]) -> NDArray[np.float64]:
    """``R_unit = J R Jᵀ`` (Eq. 9) at measured vectors ``(..., 3)``: ``(..., 3, 3)``, singular along ``ŵ``."""
    w, n = unit_parts(w_raw)
    return sym_to_matrix(kernel.unit_covariance(w, n, tuple(var)))


def paper_weight(w_raw: ArrayLike, var: Sequence[float]) -> NDArray[np.float64]:
    """The paper's scalar weight ``a = 1/κ² = 3/tr(R_unit)`` (Eq. 21) at measured vectors ``(..., 3)``."""
    w, n = unit_parts(w_raw)
    return np.asarray(kernel.paper_weight(w, n, tuple(var)))


def unit_parts(w_raw: ArrayLike) -> tuple[tuple, NDArray[np.float64]]:
    """``(ŵ, |Ŵ|)`` of vectors ``(..., 3)``, ``ŵ`` as a 3-tuple of arrays (the kernel's form)."""
    w_raw = np.asarray(w_raw, dtype=float)
    return kernel.unit(tuple(w_raw[..., k] for k in range(3)))


def sym_to_matrix(m: tuple) -> NDArray[np.float64]:
    """A symmetric 6-tuple ``(xx, xy, xz, yy, yz, zz)`` of floats or arrays as ``(..., 3, 3)``."""
    xx, xy, xz, yy, yz, zz = (np.asarray(e, dtype=float) for e in m)
    return np.stack([np.stack([xx, xy, xz], -1), np.stack([xy, yy, yz], -1), np.stack([xz, yz, zz], -1)], -2)
