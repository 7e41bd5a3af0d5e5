"""Predicted error-angle covariances (rad², body frame, first order) and the Cramér–Rao bound.

Error angles are the body-frame ``δα`` of Eq. 14 / 28–30 (``q̂ = q_true ⊗ [1, δα/2]``). Everything is
evaluated at the measured unit vectors ``ŵᵢ`` with ``R_unit,i`` of Eq. 9; the formulas are
:func:`.kernel.covariance` (shared with ``SolveResult.covariance``), here vectorised over leading axes.

- Scalar weights (``ign``, ``cgn``): the sandwich ``P = M⁻¹ (Σ aᵢ² [ŵᵢ×] R_unit,i [ŵᵢ×]ᵀ) M⁻¹``,
  ``M = Σ aᵢ (I − ŵᵢŵᵢᵀ)``. Not the paper's Eq. 17/23, which treats ``1/aᵢ = tr(R_unit)/3`` as a per-axis
  variance (it is ``tr/2`` for unit-vector noise) and so under-states the error, at 0.65× the Cramér–Rao
  bound in the paper's scenario (docs/paper-notes.md); nor its printed Eq. 39, about 2× Eq. 23.
- ``ml``: the Cramér–Rao bound, ``CRB⁻¹ = Σ [ŵᵢ×]ᵀ R_unit,i⁺ [ŵᵢ×]``, which the maximum-likelihood
  solve attains to first order.
- ``triad``: the linearised TRIAD (accelerometer primary), which fits the primary direction exactly
  and the secondary only in the plane the two span.
"""

from __future__ import annotations

from numpy.typing import ArrayLike

from . import kernel
from .conventions import Array
from .noise import NoiseModel, sym_to_matrix, unit_parts


def _sensor(raw: ArrayLike, var: tuple) -> tuple:
    w, n = unit_parts(raw)
    return w, n, var


def predicted_covariance(acc: ArrayLike, mag: ArrayLike, noise: NoiseModel, method: str) -> Array:
    """First-order covariance ``(..., 3, 3)`` of the body error angles of ``method`` at these measurements."""
    return sym_to_matrix(kernel.covariance(method, _sensor(mag, noise.mag_var), _sensor(acc, noise.accel_var)))


def cramer_rao_bound(acc: ArrayLike, mag: ArrayLike, noise: NoiseModel) -> Array:
    """The Cramér–Rao bound ``(..., 3, 3)`` (rad²) on body error angles for these two measurements."""
    return predicted_covariance(acc, mag, noise, method="ml")
