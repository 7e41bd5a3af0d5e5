"""Predicted error-angle covariances (rad², body frame, first order) and the Cramér–Rao bound.

Error angles are the body-frame ``δα`` of Eq. 14 / 28–30 (``q̂ = q_true ⊗ [1, δα/2]``). Everything is
evaluated at the measured unit vectors ``ŵᵢ`` with ``R_unit,i`` of Eq. 9, vectorised over leading axes.

- Scalar weights (``ign``, ``cgn``): the sandwich ``P = M⁻¹ (Σ aᵢ² [ŵᵢ×] R_unit,i [ŵᵢ×]ᵀ) M⁻¹``,
  ``M = Σ aᵢ (I − ŵᵢŵᵢᵀ)``. Not the paper's Eq. 17/23, which treats ``1/aᵢ = tr(R_unit)/3`` as a per-axis
  variance and under-states the error (NOTES.md); nor its Eq. 39, a factor-2 slip of Eq. 23.
- ``ml``: the Cramér–Rao bound, ``CRB⁻¹ = Σ [ŵᵢ×]ᵀ R_unit,i⁺ [ŵᵢ×]``, which the maximum-likelihood
  solve attains to first order.
- ``triad``: the linearised TRIAD (accelerometer primary), which fits the primary direction exactly
  and the secondary only in the plane the two span.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

from . import kernel
from .conventions import skew
from .noise import NoiseModel, sym_to_matrix

Array = NDArray[np.float64]


def _sensor(raw: ArrayLike, var: tuple) -> tuple[tuple, Array, tuple]:
    raw = np.asarray(raw, dtype=float)
    parts = tuple(raw[..., k] for k in range(3))
    n = kernel.norm(parts)
    w = kernel.scaled(parts, 1.0 / n)
    return w, n, kernel.unit_covariance(w, n, var)


def predicted_covariance(acc: ArrayLike, mag: ArrayLike, noise: NoiseModel, method: str = "ign") -> Array:
    """First-order covariance ``(..., 3, 3)`` of the body error angles of ``method`` at these measurements."""
    w_acc, n_acc, r_acc = _sensor(acc, noise.accel_var)
    w_mag, n_mag, r_mag = _sensor(mag, noise.mag_var)
    if method == "ml":
        # The radial part of the ML weight drops out here: [ŵ×]ᵀ ŵŵᵀ [ŵ×] = 0.
        info = (
            sym_to_matrix(kernel.cross_sandwich(w, kernel.ml_weight(w, r, kernel.paper_weight(w, n, var))))
            for w, n, r, var in ((w_mag, n_mag, r_mag, noise.mag_var), (w_acc, n_acc, r_acc, noise.accel_var))
        )
        return np.linalg.inv(sum(info))
    if method == "triad":
        return _triad(w_acc, sym_to_matrix(r_acc), w_mag, sym_to_matrix(r_mag))
    if method == "cgn":
        a_mag = a_acc = np.ones_like(n_acc)
    else:
        a_mag, a_acc = (
            kernel.paper_weight(w_mag, n_mag, noise.mag_var),
            kernel.paper_weight(w_acc, n_acc, noise.accel_var),
        )
    m = sum(np.asarray(a)[..., None, None] * (np.eye(3) - _outer(w)) for a, w in ((a_mag, w_mag), (a_acc, w_acc)))
    s = sum(
        np.asarray(a * a)[..., None, None] * sym_to_matrix(kernel.cross_sandwich(w, r))
        for a, w, r in ((a_mag, w_mag, r_mag), (a_acc, w_acc, r_acc))
    )
    m_inv = np.linalg.inv(m)
    return m_inv @ s @ m_inv


def cramer_rao_bound(acc: ArrayLike, mag: ArrayLike, noise: NoiseModel) -> Array:
    """The Cramér–Rao bound ``(..., 3, 3)`` (rad²) on body error angles for these two measurements."""
    return predicted_covariance(acc, mag, noise, method="ml")


def _outer(w: tuple) -> Array:
    v = np.stack(w, -1)
    return v[..., :, None] * v[..., None, :]


def _triad(w_p: tuple, r_p: Array, w_s: tuple, r_s: Array) -> Array:
    """Linearised TRIAD: ``δα = Gₚ nₚ + Gₛ nₛ`` for unit-vector noises ``nᵢ`` (covariance ``R_unit,i``).

    The primary fit ``ŵₚ ∥ Â vₚ`` gives the error perpendicular to ``e = ŵₚ``: ``δ⊥ = −[e×] nₚ``. The
    secondary must lie in the plane of ``ŵₚ, ŵₛ``, which fixes the part along ``e``:
    ``(e·δ) = ((c × ŵₛ)·δ⊥ − c·nₛ) / |c|²`` with ``c = e × ŵₛ``.
    """
    e, u = np.stack(w_p, -1), np.stack(w_s, -1)
    c = np.cross(e, u)
    c2 = np.sum(c * c, -1)[..., None, None]
    k = -skew(e)
    g_p = k + e[..., :, None] * (np.cross(c, u)[..., None, :] @ k) / c2
    g_s = -e[..., :, None] * c[..., None, :] / c2
    t = np.swapaxes
    return g_p @ r_p @ t(g_p, -1, -2) + g_s @ r_s @ t(g_s, -1, -2)
