"""The equations of the kernel against literal, independent numpy transcriptions of the paper."""

from __future__ import annotations

import numpy as np
import pytest

from mavattitude.estimation import conventions as cv
from mavattitude.estimation import kernel
from mavattitude.estimation.noise import paper_weight, sym_to_matrix, unit_covariance

from .conftest import ACC_REF, MAG_REF_UT, PAPER_NOISE, simulate


def eq27(q: np.ndarray) -> np.ndarray:
    """The paper's A(q), homogeneous of degree 2 (no unit-norm assumption)."""
    w, rho = q[0], q[1:]
    return (w * w - rho @ rho) * np.eye(3) + 2 * np.outer(rho, rho) - 2 * w * cv.skew(rho)


def jacobian_eq32(q: np.ndarray, v: np.ndarray) -> np.ndarray:
    """H = ∂(A(q)v)/∂q (3×4); central differences are exact for a quadratic up to rounding."""
    h = 1e-3
    return np.stack([(eq27(q + h * e) @ v - eq27(q - h * e) @ v) / (2 * h) for e in np.eye(4)], -1)


def unit(v):
    return np.asarray(v) / np.linalg.norm(v)


def test_scalar_weight_step_is_literal_eq_34_35(rng):
    q_true = cv.quat_from_euler(0.4, -0.3, 2.0)
    acc, mag = simulate(q_true, rng)
    w = [unit(mag[0]), unit(acc[0])]
    v = [unit(MAG_REF_UT), unit(ACC_REF)]
    a = [float(paper_weight(mag[0], PAPER_NOISE.mag_var)), float(paper_weight(acc[0], PAPER_NOISE.accel_var))]
    obs = tuple((tuple(wi), tuple(vi), ai) for wi, vi, ai in zip(w, v, a, strict=True))
    for size in (0.3, 0.02, 1e-4):  # starts from far to near the optimum
        q = cv.quat_multiply(q_true, cv.quat_from_rotvec(size * unit([1.0, -2.0, 0.5])))
        normal = sum(ai * jacobian_eq32(q, vi).T @ jacobian_eq32(q, vi) for ai, vi in zip(a, v, strict=True))
        rhs = sum(ai * jacobian_eq32(q, vi).T @ (wi - eq27(q) @ vi) for ai, vi, wi in zip(a, v, w, strict=True))
        q_literal = q + np.linalg.solve(normal, rhs)  # Eq. 34, 35
        q_literal /= np.linalg.norm(q_literal)
        q_kernel, angle = kernel.scalar_weight_step(tuple(q), obs)
        # 1e-12: both are exact; the 4×4 system's conditioning (weights ~1e6) costs a few digits.
        assert np.max(np.abs(np.array(q_kernel) - q_literal)) < 1e-12
        assert angle > 0.0


def test_unit_covariance_is_eq_9_and_weight_is_eq_21(rng):
    var = np.array(PAPER_NOISE.mag_var)
    for raw in rng.normal(size=(20, 3)) * 40.0:
        w_hat = unit(raw)
        j = (np.eye(3) - np.outer(w_hat, w_hat)) / np.linalg.norm(raw)  # Eq. 7
        r_unit = j @ np.diag(var) @ j.T  # Eq. 9
        np.testing.assert_allclose(unit_covariance(raw, var), r_unit, rtol=1e-12, atol=1e-20)
        assert np.linalg.norm(r_unit @ w_hat) < 1e-18  # Eq. 8, 10: ŵ is the null vector
        assert np.isclose(paper_weight(raw, var), 3.0 / np.trace(r_unit), rtol=1e-12, atol=0.0)


def test_ml_weight_is_pseudo_inverse_plus_radial_term(rng):
    var = PAPER_NOISE.accel_var
    raw = rng.normal(size=3) * 9.0
    w_hat, n = unit(raw), np.linalg.norm(raw)
    r_unit = unit_covariance(raw, var)
    a = float(paper_weight(raw, var))
    r6 = kernel.unit_covariance(tuple(w_hat), n, var)
    expected = np.linalg.pinv(r_unit, rcond=1e-10, hermitian=True) + np.outer(w_hat, w_hat) * a
    np.testing.assert_allclose(sym_to_matrix(kernel.ml_weight(tuple(w_hat), r6, a)), expected, rtol=1e-9)


def test_cross_sandwich_and_solve(rng):
    u = rng.normal(size=3)
    m = rng.normal(size=(3, 3))
    m = m @ m.T + np.eye(3)
    m6 = (m[0, 0], m[0, 1], m[0, 2], m[1, 1], m[1, 2], m[2, 2])
    s = cv.skew(u)
    np.testing.assert_allclose(sym_to_matrix(kernel.cross_sandwich(tuple(u), m6)), s.T @ m @ s, atol=1e-12)
    b = rng.normal(size=3)
    np.testing.assert_allclose(kernel.sym_solve(m6, tuple(b)), np.linalg.solve(m, b), rtol=1e-12)


def test_kernel_gives_the_same_numbers_on_floats_and_arrays(rng):
    acc, _ = simulate(cv.quat_normalize(rng.normal(size=(50, 4))), rng)
    w_acc, n_acc = kernel.scaled(tuple(acc.T), 1 / np.linalg.norm(acc, axis=1)), np.linalg.norm(acc, axis=1)
    r_arrays = kernel.unit_covariance(w_acc, n_acc, PAPER_NOISE.accel_var)
    for i in (0, 17, 49):
        r_float = kernel.unit_covariance(tuple(float(c[i]) for c in w_acc), float(n_acc[i]), PAPER_NOISE.accel_var)
        assert all(type(e) is float for e in r_float)
        np.testing.assert_array_equal([e[i] for e in r_arrays], r_float)


def test_sym_solve_never_divides_by_zero_and_refuses_what_is_not_positive_definite():
    singular, indefinite = (1.0, 0.0, 0.0, 0.0, 0.0, -1.0), (1.0, 0.0, 0.0, 2.0, 0.0, -3.0)
    for m6 in (singular, indefinite, (0.0,) * 6):
        assert np.isnan(kernel.sym_solve(m6, (1.0, 2.0, 3.0))).all()  # floats: no ZeroDivisionError
        assert np.isnan(kernel.sym_inverse(m6)).all()
    # Arrays: the same, row by row, without a warning (the suite does not filter them: they would show).
    rows = tuple(np.array([a, b]) for a, b in zip(singular, (2.0, 0.0, 0.0, 2.0, 0.0, 2.0), strict=True))
    with np.errstate(all="raise"):
        x = np.array(kernel.sym_solve(rows, (np.ones(2),) * 3))
    assert np.isnan(x[:, 0]).all() and x[:, 1] == pytest.approx([0.5, 0.5, 0.5])


def _saddle_obs(weight):
    """Observations at a stationary point 180° from the optimum for q = identity: the magnetometer's
    predicted direction u₁ = −ŵ₁, the accelerometer's u₂ = ŵ₂. With equal scalar weights the Newton Hessian
    Σ aᵢ((ŵᵢ·uᵢ)I − ½(ŵᵢuᵢᵀ + uᵢŵᵢᵀ)) = ŵ₁ŵ₁ᵀ − ŵ₂ŵ₂ᵀ is exactly singular (det = 0.0)."""
    w1, w2 = (1.0, 0.0, 0.0), (0.0, 0.0, 1.0)
    return ((w1, (-1.0, 0.0, 0.0), weight), (w2, w2, weight))


def test_newton_step_with_a_singular_hessian_falls_back_to_gauss_newton():
    # This used to raise ZeroDivisionError (1.0/det); the Gauss–Newton matrix diag(1, 2, 1) is positive
    # definite, and the gradient is zero at a stationary point: no correction, a finite unit quaternion.
    q, angle = kernel.scalar_weight_step((1.0, 0.0, 0.0, 0.0), _saddle_obs(1.0), newton=True)
    assert angle == 0.0 and np.linalg.norm(q) == pytest.approx(1.0, abs=1e-15)
    # Matrix weights (ML, always Newton): at W = I its Hessian is the same singular matrix.
    identity = (1.0, 0.0, 0.0, 1.0, 0.0, 1.0)
    q, angle = kernel.matrix_weight_step((1.0, 0.0, 0.0, 0.0), _saddle_obs(identity))
    assert angle == 0.0 and np.linalg.norm(q) == pytest.approx(1.0, abs=1e-15)


def test_newton_step_with_an_indefinite_hessian_still_descends():
    # Just off that saddle the Hessian is indefinite: Newton's step would head for the saddle (or a
    # maximum); the Gauss–Newton step taken instead lowers the loss.
    obs = _saddle_obs(1.0)
    q0 = tuple(cv.quat_from_rotvec(np.array([0.0, 0.05, 0.02])))
    q1, _ = kernel.scalar_weight_step(q0, obs, newton=True)
    assert kernel.wahba_loss(q1, obs, False) < kernel.wahba_loss(q0, obs, False)


def test_a_step_without_a_positive_definite_normal_matrix_returns_nan():
    # Collinear predicted directions (u₁ = u₂): even Gauss–Newton's Σ aᵢ(I − uᵢuᵢᵀ) is singular.
    obs = (((0.0, 0.6, 0.8), (0.0, 0.0, 1.0), 1.0), ((0.0, 0.0, 1.0), (0.0, 0.0, 1.0), 1.0))
    for newton in (False, True):
        q, angle = kernel.scalar_weight_step((1.0, 0.0, 0.0, 0.0), obs, newton)
        assert np.isnan(angle) and np.isnan(q).all()
