"""The paper's equations, written once, on components that are plain floats *or* equal-shape arrays.

Vectors are 3-tuples, symmetric 3×3 matrices 6-tuples ``(xx, xy, xz, yy, yz, zz)``, quaternions 4-tuples.
Only ``+ − × /``, powers and comparisons joined by ``& |`` appear, so every function runs unchanged
on Python floats (the per-sample path in :mod:`.solve`, free of numpy's per-call overhead) and on
``(N,)`` arrays (the vectorised :mod:`.batch`). Both paths therefore evaluate the same equations in the same order.

Index ``i`` = 1 magnetometer, 2 accelerometer, as in the paper.

- :func:`unit_covariance` — Eq. 7 and 9: ``R_unit = J R Jᵀ``, ``J = (I − ŵŵᵀ)/|Ŵ|``.
- :func:`paper_weight` — Eq. 19–21: ``a = 1/κ²``, ``κ² = tr(R_unit)/3``.
- :func:`ml_weight` — the maximum-likelihood weight matrix ``R_unit⁺ + ŵŵᵀ/κ²`` (beyond the paper).
- :func:`triad` — the closed-form TRIAD attitude (the accelerometer is the primary vector).
- :func:`scalar_weight_step` — one Gauss–Newton correction, Eq. 32–35, for scalar weights (IGN, CGN),
  with a Newton safeguard for inconsistent vectors.
- :func:`matrix_weight_step` — the tangent-space Newton correction for matrix weights (ML).
- :func:`covariance` — the predicted body error-angle covariance of each method (see
  :mod:`.covariance` for the formulas and why not the paper's Eq. 23 / 39).
- :data:`RULES` — the method table: each snapshot method's observation weights, its step (none for TRIAD)
  and its covariance, the one place the kernel tells the methods apart.

Eq. 34 in three dimensions: ``A(q)v`` is quadratic in ``q``, so with ``u = A(q)v`` and any correction
written in the orthogonal basis ``Δq = q ⊗ [c, δ/2]`` the Jacobian ``H`` of Eq. 32 gives exactly
``H Δq = 2c u + [u×] δ``. The two parts are orthogonal (``uᵀ[u×] = 0``), so the 4×4 normal equations
of Eq. 34 split into ``(Σ aᵢ (I − uᵢuᵢᵀ)) δ = Σ aᵢ ŵᵢ × uᵢ`` and ``c = Σ aᵢ (uᵢ·ŵᵢ − 1) / (2 Σ aᵢ)``, and
Eq. 35 (``q + Δq``, normalised) is ``q ⊗ [1 + c, δ/2]`` normalised. This is the literal Eq. 34–35 (the
tests check it against the 4×4 form), at a fraction of its cost; ``|δ|`` is the correction's angle.

No 3×3 system divides by zero: one is solved only where its matrix is positive definite
(:func:`sym_solve`): Newton's Hessian, which is indefinite far from the optimum, gives way there to the
Gauss–Newton matrix, positive definite for non-collinear vectors; where even that one is not, the step
returns NaN, which the drivers (:mod:`.solve`, :mod:`.batch`) turn into a typed error.
"""

from __future__ import annotations

from collections.abc import Callable
from functools import partial
from typing import Any, NamedTuple

from .conventions import quat_multiply_parts, rotate_ned_to_body_parts, rotation_matrix_parts

# A float, or an ndarray of floats; every component of a tuple has the same type and shape.
Scalar = Any
Vec = tuple[Scalar, Scalar, Scalar]
Sym = tuple[Scalar, Scalar, Scalar, Scalar, Scalar, Scalar]
QuatParts = tuple[Scalar, Scalar, Scalar, Scalar]


def norm(v: Vec) -> Scalar:
    return (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]) ** 0.5


def scaled(v: Vec, s: Scalar) -> Vec:
    return (v[0] * s, v[1] * s, v[2] * s)


def unit(v: Vec) -> tuple[Vec, Scalar]:
    """``(ŵ, |Ŵ|)`` of a vector (Eq. 3–4)."""
    n = norm(v)
    return scaled(v, 1.0 / n), n


def cross(a: Vec, b: Vec) -> Vec:
    return (a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0])


def sym_det_adj(m: Sym) -> tuple[Scalar, Sym]:
    """Determinant and adjugate of a symmetric 3×3 matrix."""
    xx, xy, xz, yy, yz, zz = m
    adj = (
        yy * zz - yz * yz,
        xz * yz - xy * zz,
        xy * yz - xz * yy,
        xx * zz - xz * xz,
        xy * xz - xx * yz,
        xx * yy - xy * xy,
    )
    return xx * adj[0] + xy * adj[1] + xz * adj[2], adj


_NAN = float("nan")


def _nan_unless(ok: Scalar) -> Scalar:
    """1.0 where ``ok``, NaN where not (``x⁰ = 1`` for every ``x``, NaN included): a mask in arithmetic."""
    return _NAN ** (1 - ok)


def positive_definite(m: Sym, det: Scalar, adj: Sym) -> Scalar:
    """Sylvester's criterion, given :func:`sym_det_adj`: the leading minors ``xx``, ``xx·yy − xy²`` (the
    adjugate's last entry) and ``det`` all positive; false for NaN."""
    return (m[0] > 0.0) & (adj[5] > 0.0) & (det > 0.0)


def _inverse_det(m: Sym) -> tuple[Scalar, Sym]:
    """``1/det`` where ``m`` is positive definite, NaN elsewhere (never a division by zero), and the adjugate."""
    det, adj = sym_det_adj(m)
    return _nan_unless(positive_definite(m, det, adj)) / (det + (det == 0.0)), adj


def sym_solve(m: Sym, b: Vec) -> Vec:
    """``m⁻¹ b`` by the adjugate (Cramer's rule), exact enough for the well-posed 3×3 systems here; NaN
    where ``m`` is not positive definite (every ``m`` solved here should be)."""
    inv, (axx, axy, axz, ayy, ayz, azz) = _inverse_det(m)
    return (
        (axx * b[0] + axy * b[1] + axz * b[2]) * inv,
        (axy * b[0] + ayy * b[1] + ayz * b[2]) * inv,
        (axz * b[0] + ayz * b[1] + azz * b[2]) * inv,
    )


def sym_inverse(m: Sym) -> Sym:
    """``m⁻¹``; NaN where ``m`` is not positive definite."""
    inv, (xx, xy, xz, yy, yz, zz) = _inverse_det(m)
    return (xx * inv, xy * inv, xz * inv, yy * inv, yz * inv, zz * inv)


def sym_add(a: Sym, b: Sym, k: Scalar = 1.0) -> Sym:
    """``a + k b`` (written out: this is on the per-sample path)."""
    return (a[0] + k * b[0], a[1] + k * b[1], a[2] + k * b[2], a[3] + k * b[3], a[4] + k * b[4], a[5] + k * b[5])


def newton_or_gauss_newton(newton: Scalar, gauss_newton: Sym, curvature: Sym) -> tuple[Scalar, Sym]:
    """The Hessian ``gauss_newton + curvature`` where ``newton`` is asked and it is positive definite (Newton
    then heads for a minimum), the Gauss–Newton matrix elsewhere; returns ``(newton actually used, matrix)``."""
    hessian = sym_add(gauss_newton, curvature)
    use = newton & positive_definite(hessian, *sym_det_adj(hessian))
    return use, sym_add(gauss_newton, curvature, use)


def sym_matvec(m: Sym, v: Vec) -> Vec:
    xx, xy, xz, yy, yz, zz = m
    return (xx * v[0] + xy * v[1] + xz * v[2], xy * v[0] + yy * v[1] + yz * v[2], xz * v[0] + yz * v[1] + zz * v[2])


def cross_sandwich(u: Vec, m: Sym) -> Sym:
    """``[u×]ᵀ m [u×]`` for symmetric ``m`` (equal to ``[u×] m [u×]ᵀ``)."""
    x, y, z = u
    xx, xy, xz, yy, yz, zz = m
    # Columns of m [u×], i.e. m (u × e_k) for k = x, y, z; then [u×]ᵀ applied to each.
    c0 = (xy * z - xz * y, yy * z - yz * y, yz * z - zz * y)  # m [u×] e_x
    c1 = (xz * x - xx * z, yz * x - xy * z, zz * x - xz * z)  # m [u×] e_y
    c2 = (xx * y - xy * x, xy * y - yy * x, xz * y - yz * x)  # m [u×] e_z
    # [u×]ᵀ c = c × u
    r0, r1, r2 = cross(c0, u), cross(c1, u), cross(c2, u)
    return (r0[0], r1[0], r2[0], r1[1], r2[1], r2[2])


def unit_covariance(w: Vec, n: Scalar, var: Vec) -> Sym:
    """``R_unit = J R Jᵀ`` (Eq. 7, 9) at a measured vector ``Ŵ = n ŵ`` (``ŵ`` unit, ``n = |Ŵ|``).

    ``var`` is the diagonal of ``R`` (Eq. 2) in the sensor's units². ``ŵ`` is the null vector of ``R_unit``.
    """
    rw = (var[0] * w[0], var[1] * w[1], var[2] * w[2])
    s = rw[0] * w[0] + rw[1] * w[1] + rw[2] * w[2]
    k = 1.0 / (n * n)
    # (I − ŵŵᵀ) R (I − ŵŵᵀ) = R − ŵ(Rŵ)ᵀ − (Rŵ)ŵᵀ + (ŵᵀRŵ) ŵŵᵀ
    return (
        (var[0] - 2.0 * w[0] * rw[0] + s * w[0] * w[0]) * k,
        (-w[0] * rw[1] - rw[0] * w[1] + s * w[0] * w[1]) * k,
        (-w[0] * rw[2] - rw[0] * w[2] + s * w[0] * w[2]) * k,
        (var[1] - 2.0 * w[1] * rw[1] + s * w[1] * w[1]) * k,
        (-w[1] * rw[2] - rw[1] * w[2] + s * w[1] * w[2]) * k,
        (var[2] - 2.0 * w[2] * rw[2] + s * w[2] * w[2]) * k,
    )


def paper_weight(w: Vec, n: Scalar, var: Vec) -> Scalar:
    """Eq. 19–21: ``a = 1/κ² = 3 / tr(R_unit)`` with ``tr(R_unit) = (tr R − ŵᵀRŵ) / |Ŵ|²``.

    ``tr R − ŵᵀRŵ = Σₖ varₖ (1 − ŵₖ²)`` is summed with ``1 − ŵₖ²`` written as the other two components
    squared: no cancellation, so it stays positive however different the three variances are.
    """
    xx, yy, zz = w[0] * w[0], w[1] * w[1], w[2] * w[2]
    return 3.0 * n * n / (var[0] * (yy + zz) + var[1] * (xx + zz) + var[2] * (xx + yy))


def ml_weight(w: Vec, r_unit: Sym, a: Scalar) -> Sym:
    """``R_unit⁺ + ŵŵᵀ/κ² = (R_unit + κ² ŵŵᵀ)⁻¹`` (``ŵ`` is ``R_unit``'s unit null vector, ``κ² = 1/a``).

    The radial term keeps the matrix-weighted cost from gaining a spurious zero 180° away (docs/paper-notes.md);
    writing the sum as one inverse keeps it well conditioned.
    """
    k2 = 1.0 / a
    xx, xy, xz, yy, yz, zz = r_unit
    m = (
        xx + k2 * w[0] * w[0],
        xy + k2 * w[0] * w[1],
        xz + k2 * w[0] * w[2],
        yy + k2 * w[1] * w[1],
        yz + k2 * w[1] * w[2],
        zz + k2 * w[2] * w[2],
    )
    return sym_inverse(m)


def triad(w_acc: Vec, w_mag: Vec, v_acc: Vec, v_mag: Vec, s_body: Scalar, s_ref: Scalar) -> tuple:
    """TRIAD (accelerometer primary): the rotation matrix body → NED as a row-major 9-tuple.

    Inputs are unit vectors; ``s_body = |ŵ_acc × ŵ_mag|`` and ``s_ref = |v̂_acc × v̂_mag|`` (already computed
    to check the geometry). ``R = Σₖ rₖ tₖᵀ`` over the body triad ``t`` and the reference triad ``r``.
    """
    t1, r1 = w_acc, v_acc
    t2 = scaled(cross(w_acc, w_mag), 1.0 / s_body)
    r2 = scaled(cross(v_acc, v_mag), 1.0 / s_ref)
    t3, r3 = cross(t1, t2), cross(r1, r2)
    a0, a1, a2 = r1
    b0, b1, b2 = r2
    c0, c1, c2 = r3
    x0, x1, x2 = t1
    y0, y1, y2 = t2
    z0, z1, z2 = t3
    return (
        a0 * x0 + b0 * y0 + c0 * z0, a0 * x1 + b0 * y1 + c0 * z1, a0 * x2 + b0 * y2 + c0 * z2,
        a1 * x0 + b1 * y0 + c1 * z0, a1 * x1 + b1 * y1 + c1 * z1, a1 * x2 + b1 * y2 + c1 * z2,
        a2 * x0 + b2 * y0 + c2 * z0, a2 * x1 + b2 * y1 + c2 * z1, a2 * x2 + b2 * y2 + c2 * z2,
    )  # fmt: skip


def scalar_weight_step(q: QuatParts, obs: tuple, newton: Scalar = False) -> tuple[QuatParts, Scalar]:
    """One IGN/CGN iteration, Eq. 34–35, for ``obs = ((ŵ₁, v₁, a₁), (ŵ₂, v₂, a₂))`` (unit vectors).

    Returns the corrected, normalised quaternion and the correction's angle ``|δ|`` (rad). Written out
    in full: it is the per-sample hot loop.

    ``newton`` (a bool, or a bool array on the batch path) is the safeguard for inconsistent vectors:
    Eq. 34 is Gauss–Newton, whose rate is linear and of the size of the residuals; with a large
    disagreement between the two vectors (a hard maneuver, a magnetic disturbance) it crawls or cycles.
    Where ``newton`` is true the normal matrix ``M = Σ aᵢ (I − uᵢuᵢᵀ)`` becomes the exact Hessian of the
    loss, ``Σ aᵢ ((ŵᵢ·uᵢ) I − ½(ŵᵢuᵢᵀ + uᵢŵᵢᵀ))`` (``M`` plus the residual curvature, as in
    :func:`matrix_weight_step`), and the radial part ``c`` is dropped: Newton's method, quadratic, to the
    same optimum. For consistent vectors the two matrices agree to the size of the residuals. Where the
    Hessian is not positive definite (far from the optimum) the step stays Gauss–Newton's; where ``M`` is
    not either (collinear in floating point), the returned quaternion and angle are NaN.
    """
    r = rotation_matrix_parts(q)
    (w1, v1, a1), (w2, v2, a2) = obs
    x1, y1, z1 = rotate_ned_to_body_parts(r, v1)  # u₁ = A(q) v₁
    x2, y2, z2 = rotate_ned_to_body_parts(r, v2)  # u₂ = A(q) v₂
    # g = Σ aᵢ ŵᵢ × uᵢ
    g0 = a1 * (w1[1] * z1 - w1[2] * y1) + a2 * (w2[1] * z2 - w2[2] * y2)
    g1 = a1 * (w1[2] * x1 - w1[0] * z1) + a2 * (w2[2] * x2 - w2[0] * z2)
    g2 = a1 * (w1[0] * y1 - w1[1] * x1) + a2 * (w2[0] * y2 - w2[1] * x2)
    # M = Σ aᵢ (I − uᵢuᵢᵀ)
    asum = a1 + a2
    m = (
        asum - a1 * x1 * x1 - a2 * x2 * x2,
        -a1 * x1 * y1 - a2 * x2 * y2,
        -a1 * x1 * z1 - a2 * x2 * z2,
        asum - a1 * y1 * y1 - a2 * y2 * y2,
        -a1 * y1 * z1 - a2 * y2 * z2,
        asum - a1 * z1 * z1 - a2 * z2 * z2,
    )
    e1 = w1[0] * x1 + w1[1] * y1 + w1[2] * z1  # ŵᵢ·uᵢ
    e2 = w2[0] * x2 + w2[1] * y2 + w2[2] * z2
    # ½ aᵢ |ŵᵢ − uᵢ|² = aᵢ (1 − ŵᵢ·uᵢ) for unit vectors; c = Σ aᵢ uᵢ·(ŵᵢ − uᵢ) / (2 Σ aᵢ) = −loss / (2 Σ aᵢ).
    c = -(a1 * (1.0 - e1) + a2 * (1.0 - e2)) / (2.0 * asum)
    if newton is not False:
        s1, s2 = _outer_sym(w1, (x1, y1, z1)), _outer_sym(w2, (x2, y2, z2))
        diag = a1 * e1 + a2 * e2
        h = tuple((diag if k in (0, 3, 5) else 0.0) - 0.5 * (a1 * s1[k] + a2 * s2[k]) for k in range(6))
        newton, m = newton_or_gauss_newton(newton, m, sym_add(h, m, -1.0))  # type: ignore[arg-type]
        c = c * (1 - newton)
    d0, d1, d2 = sym_solve(m, (g0, g1, g2))
    q_next = quat_multiply_parts(q, (1.0 + c, 0.5 * d0, 0.5 * d1, 0.5 * d2))
    return _normalised(q_next), (d0 * d0 + d1 * d1 + d2 * d2) ** 0.5


def matrix_weight_step(q: QuatParts, obs: tuple, newton: Scalar = True) -> tuple[QuatParts, Scalar]:
    """One maximum-likelihood Newton iteration for ``obs = ((ŵ₁, v₁, W₁), (ŵ₂, v₂, W₂))`` (:func:`ml_weight`).

    Cost ``½ Σ rᵢᵀ Wᵢ rᵢ`` with ``rᵢ(δ) = ŵᵢ − A(q ⊗ exp δ)vᵢ = rᵢ − [uᵢ×]δ − ½ δ×(δ×uᵢ) + …`` in the body
    error angle ``δ`` of Eq. 14. Gradient ``−Σ (Wᵢrᵢ) × uᵢ``; Hessian the Gauss–Newton ``Σ [uᵢ×]ᵀ Wᵢ [uᵢ×]``
    plus the curvature ``Σ (pᵢ·uᵢ) I − ½(pᵢuᵢᵀ + uᵢpᵢᵀ)``, ``pᵢ = Wᵢrᵢ``. Without that term the iteration is
    only linear, at a rate of the size of the weighted residual (0.07 per step on a 2.4σ sample of the
    paper's scenario); with it, quadratic. ``q ← q ⊗ [1, δ/2]``, normalised. Returns like
    :func:`scalar_weight_step`; Newton wherever the Hessian is positive definite, else Gauss–Newton
    (``newton`` is accepted for the drivers' uniform call).
    """
    r = rotation_matrix_parts(q)
    gn_sum: Sym = (0.0, 0.0, 0.0, 0.0, 0.0, 0.0)
    curv_sum: Sym = gn_sum
    g: Vec = (0.0, 0.0, 0.0)
    for w, v, wm in obs:
        u = rotate_ned_to_body_parts(r, v)
        p = sym_matvec(wm, (w[0] - u[0], w[1] - u[1], w[2] - u[2]))  # Wᵢ rᵢ
        pu = p[0] * u[0] + p[1] * u[1] + p[2] * u[2]
        gi = cross(p, u)
        g = (g[0] + gi[0], g[1] + gi[1], g[2] + gi[2])
        gn = cross_sandwich(u, wm)
        curv = (
            pu - p[0] * u[0],
            -0.5 * (p[0] * u[1] + u[0] * p[1]),
            -0.5 * (p[0] * u[2] + u[0] * p[2]),
            pu - p[1] * u[1],
            -0.5 * (p[1] * u[2] + u[1] * p[2]),
            pu - p[2] * u[2],
        )
        gn_sum, curv_sum = sym_add(gn_sum, gn), sym_add(curv_sum, curv)
    _, h = newton_or_gauss_newton(True, gn_sum, curv_sum)
    d = sym_solve(h, g)
    return _normalised(quat_multiply_parts(q, (1.0, 0.5 * d[0], 0.5 * d[1], 0.5 * d[2]))), norm(d)


# Sanity bounds on the Eq. 21 weights a = 3/tr(R_unit), i.e. on the unit-vector noise σ/|Ŵ|:
# - a < 1: the noise is as large as the vector itself, which has no direction left;
# - a > 3e20: σ/|Ŵ| < 1e-10, finer than any sensor resolves (σ in other units than the vector);
# - weights 1e8 apart: one unit-vector noise 1e4× the other's (legitimate sensors stay below ~1e6
#   apart; beyond ~1e12 the lighter vector's information is lost to rounding next to the heavier one's).
MIN_WEIGHT, MAX_WEIGHT, MAX_WEIGHT_RATIO = 1.0, 3e20, 1e8


def weights_usable(a1: Scalar, a2: Scalar) -> Scalar:
    """True where both weights are within the bounds above (false for NaN)."""
    in_range = (a1 >= MIN_WEIGHT) & (a1 <= MAX_WEIGHT) & (a2 >= MIN_WEIGHT) & (a2 <= MAX_WEIGHT)
    return in_range & (a1 <= MAX_WEIGHT_RATIO * a2) & (a2 <= MAX_WEIGHT_RATIO * a1)


def observations(method: str, mag: tuple, acc: tuple) -> tuple:
    """The solver's ``((ŵ₁, v₁, weight₁), (ŵ₂, v₂, weight₂))`` from ``(ŵ, |Ŵ|, v̂, var, a)`` per sensor,
    ``a`` the paper's weight (:func:`paper_weight`), weighted by the method's rule (:data:`RULES`)."""
    weight = RULES[method].weight
    return tuple((w, v, weight(w, n, var, a)) for w, n, v, var, a in (mag, acc))


def _paper_weights(w: Vec, n: Scalar, var: Vec, a: Scalar) -> Scalar:
    """The paper's scalar weight (Eq. 21): IGN, and TRIAD's loss."""
    return a


def _equal_weights(w: Vec, n: Scalar, var: Vec, a: Scalar) -> Scalar:
    """CGN: equal weights."""
    return 1.0


def _matrix_weights(w: Vec, n: Scalar, var: Vec, a: Scalar) -> Sym:
    """ML: the weight matrix of :func:`ml_weight`."""
    return ml_weight(w, unit_covariance(w, n, var), a)


def sym_congruence(a: Sym, s: Sym) -> Sym:
    """``a s a`` for symmetric ``a`` and ``s`` (symmetric)."""
    c0, c1, c2 = sym_matvec(s, (a[0], a[1], a[2])), sym_matvec(s, (a[1], a[3], a[4])), sym_matvec(s, (a[2], a[4], a[5]))
    r0, r1, r2 = sym_matvec(a, c0), sym_matvec(a, c1), sym_matvec(a, c2)  # columns of a (s a)
    return (r0[0], r1[0], r2[0], r1[1], r2[1], r2[2])


def _outer_sym(x: Vec, y: Vec) -> Sym:
    """``x yᵀ + y xᵀ``."""
    return (2.0 * x[0] * y[0], x[0] * y[1] + y[0] * x[1], x[0] * y[2] + y[0] * x[2],
            2.0 * x[1] * y[1], x[1] * y[2] + y[1] * x[2], 2.0 * x[2] * y[2])  # fmt: skip


def covariance(method: str, mag: tuple, acc: tuple) -> Sym:
    """Predicted covariance of the body error angles for ``(ŵ, |Ŵ|, var)`` of each sensor (rad², 6-tuple), by
    the method's rule (:data:`RULES`)."""
    (w1, n1, var1), (w2, n2, var2) = mag, acc
    return RULES[method].covariance(
        w1, n1, var1, unit_covariance(w1, n1, var1), w2, n2, var2, unit_covariance(w2, n2, var2)
    )


def _cramer_rao(w1: Vec, n1: Scalar, var1: Vec, r1: Sym, w2: Vec, n2: Scalar, var2: Vec, r2: Sym) -> Sym:
    """ml: the Cramér–Rao bound ``(Σ [ŵᵢ×]ᵀ Wᵢ [ŵᵢ×])⁻¹`` (the radial part of ``Wᵢ`` drops out there)."""
    a1, a2 = paper_weight(w1, n1, var1), paper_weight(w2, n2, var2)
    info1 = cross_sandwich(w1, ml_weight(w1, r1, a1))
    info2 = cross_sandwich(w2, ml_weight(w2, r2, a2))
    return sym_inverse(tuple(x + y for x, y in zip(info1, info2, strict=True)))  # type: ignore[arg-type]


def _triad_rule_covariance(w1: Vec, n1: Scalar, var1: Vec, r1: Sym, w2: Vec, n2: Scalar, var2: Vec, r2: Sym) -> Sym:
    """triad: :func:`triad_covariance`, the accelerometer primary."""
    return triad_covariance(w2, r2, w1, r1)


def _sandwich(
    weight: Callable, w1: Vec, n1: Scalar, var1: Vec, r1: Sym, w2: Vec, n2: Scalar, var2: Vec, r2: Sym
) -> Sym:
    """Scalar weights ``aᵢ`` (ign: the paper's, cgn: equal): ``M⁻¹ (Σ aᵢ² [ŵᵢ×] R_unit,i [ŵᵢ×]ᵀ) M⁻¹``,
    ``M = Σ aᵢ (I − ŵᵢŵᵢᵀ)``."""
    a1, a2 = weight(w1, n1, var1), weight(w2, n2, var2)
    asum = a1 + a2
    m = (
        asum - a1 * w1[0] * w1[0] - a2 * w2[0] * w2[0],
        -a1 * w1[0] * w1[1] - a2 * w2[0] * w2[1],
        -a1 * w1[0] * w1[2] - a2 * w2[0] * w2[2],
        asum - a1 * w1[1] * w1[1] - a2 * w2[1] * w2[1],
        -a1 * w1[1] * w1[2] - a2 * w2[1] * w2[2],
        asum - a1 * w1[2] * w1[2] - a2 * w2[2] * w2[2],
    )
    b1, b2 = cross_sandwich(w1, r1), cross_sandwich(w2, r2)
    aa1, aa2 = a1 * a1, a2 * a2
    middle = (
        aa1 * b1[0] + aa2 * b2[0],
        aa1 * b1[1] + aa2 * b2[1],
        aa1 * b1[2] + aa2 * b2[2],
        aa1 * b1[3] + aa2 * b2[3],
        aa1 * b1[4] + aa2 * b2[4],
        aa1 * b1[5] + aa2 * b2[5],
    )
    return sym_congruence(sym_inverse(m), middle)


def _equal(w: Vec, n: Scalar, var: Vec) -> Scalar:
    return 1.0


def triad_covariance(e: Vec, r_p: Sym, u: Vec, r_s: Sym) -> Sym:
    """Linearised TRIAD, primary ``e = ŵₚ`` (accelerometer), secondary ``u = ŵₛ``: ``δα = Gₚ nₚ + Gₛ nₛ``.

    The primary fit ``ŵₚ ∥ Â vₚ`` gives the error perpendicular to ``e``: ``δ⊥ = −[e×] nₚ``. The
    secondary must lie in the plane of ``ŵₚ, ŵₛ``, which fixes the part along ``e``:
    ``e·δ = (h·nₚ − c·nₛ/|c|²)`` with ``c = e × u`` and ``h = e × (c × u)/|c|²``. Hence ``Gₚ = −[e×] + e hᵀ``,
    ``Gₛ = −e cᵀ/|c|²`` and ``P = [e×]Rₚ[e×]ᵀ − (z eᵀ + e zᵀ) + (hᵀRₚh + cᵀRₛc/|c|⁴) e eᵀ``, ``z = e × Rₚh``.
    """
    c = cross(e, u)
    c2 = c[0] * c[0] + c[1] * c[1] + c[2] * c[2]
    h = scaled(cross(e, cross(c, u)), 1.0 / c2)
    rh = sym_matvec(r_p, h)
    z = cross(e, rh)
    rc = sym_matvec(r_s, c)
    k = h[0] * rh[0] + h[1] * rh[1] + h[2] * rh[2] + (c[0] * rc[0] + c[1] * rc[1] + c[2] * rc[2]) / (c2 * c2)
    base, mixed = cross_sandwich(e, r_p), _outer_sym(z, e)
    ee = (e[0] * e[0], e[0] * e[1], e[0] * e[2], e[1] * e[1], e[1] * e[2], e[2] * e[2])
    return tuple(b - x + k * y for b, x, y in zip(base, mixed, ee, strict=True))  # type: ignore[return-value]


def wahba_loss(q: QuatParts, obs: tuple, matrix_weights: bool) -> Scalar:
    """Eq. 11 at ``q``: ``½ Σ aᵢ |ŵᵢ − A(q)vᵢ|²``, or ``½ Σ rᵢᵀ Wᵢ rᵢ`` with matrix weights (ML)."""
    r = rotation_matrix_parts(q)
    loss = 0.0
    for w, v, weight in obs:
        u = rotate_ned_to_body_parts(r, v)
        res = (w[0] - u[0], w[1] - u[1], w[2] - u[2])
        wr = sym_matvec(weight, res) if matrix_weights else scaled(res, weight)
        loss = loss + 0.5 * (res[0] * wr[0] + res[1] * wr[1] + res[2] * wr[2])
    return loss


# From TRIAD with consistent vectors Eq. 34 shrinks its corrections ~1e-5 per step (1e-3 → 1e-8 rad);
# a ratio above 1e-3 means large residuals, where Newton converges in a few steps and Eq. 34 in tens.
NEWTON_RATIO = 1e-3


def slow(step: Scalar, previous: Scalar) -> Scalar:
    """Gauss–Newton is converging slowly (or not at all): the correction shrank by less than 1000×."""
    return step > NEWTON_RATIO * previous


def converged(step: Scalar, previous: Scalar, tolerance: float) -> Scalar:
    """Stop after a correction of angle ``step`` (rad) that followed one of angle ``previous``.

    Gauss–Newton on this problem converges linearly; with the observed ratio ``ρ = step/previous < 1``
    the error left after applying ``step`` is about ``step·ρ/(1 − ρ)``. Stop when that estimate, or the
    correction itself, is at most ``tolerance``. ``previous`` is NaN on the first iteration (no estimate).
    """
    return (step <= tolerance) | ((step < previous) & (step * step <= tolerance * (previous - step)))


def _normalised(q: QuatParts) -> QuatParts:
    k = (q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3]) ** -0.5
    return (q[0] * k, q[1] * k, q[2] * k, q[3] * k)


class Rule(NamedTuple):
    """How a snapshot method weighs, iterates and predicts its error (a row of :data:`RULES`)."""

    weight: Callable[[Vec, Scalar, Vec, Scalar], Any]  # (ŵ, |Ŵ|, var, paper's a) → the observation's weight
    step: Callable[..., tuple[QuatParts, Scalar]] | None  # one correction from TRIAD on; None: TRIAD itself
    matrix_weights: bool  # the weights are matrices (the loss and the step take them so)
    covariance: Callable[..., Sym]  # (ŵ₁, |Ŵ₁|, var₁, R₁, ŵ₂, |Ŵ₂|, var₂, R₂) → the error covariance


#: The kernel's method table: every snapshot method, by ``estimator.method`` name.
RULES: dict[str, Rule] = {
    "ign": Rule(_paper_weights, scalar_weight_step, False, partial(_sandwich, paper_weight)),
    "cgn": Rule(_equal_weights, scalar_weight_step, False, partial(_sandwich, _equal)),
    "ml": Rule(_matrix_weights, matrix_weight_step, True, _cramer_rao),
    "triad": Rule(_paper_weights, None, False, _triad_rule_covariance),
}
