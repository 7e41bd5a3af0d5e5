"""The per-sample solver: agreement with the closed-form weighted Wahba optimum, convergence, errors."""

from __future__ import annotations

import contextlib

import numpy as np
import pytest
from hypothesis import example, given, settings
from hypothesis import strategies as st
from scipy.spatial.transform import Rotation

from mavattitude.errors import DegenerateGeometryError, InputError, MavAttitudeError
from mavattitude.estimation import SNAPSHOT_METHODS, NoiseModel, solve, solve_batch
from mavattitude.estimation import conventions as cv
from mavattitude.estimation.noise import paper_weight

from .conftest import ACC_REF, MAG_REF_UT, PAPER_NOISE, simulate


def scipy_optimum(acc, mag, weights):
    """Closed-form weighted Wahba optimum (SVD): scipy maps body vectors onto the NED references."""
    refs = [MAG_REF_UT / np.linalg.norm(MAG_REF_UT), ACC_REF / np.linalg.norm(ACC_REF)]
    body = [mag / np.linalg.norm(mag), acc / np.linalg.norm(acc)]
    rot, _ = Rotation.align_vectors(refs, body, weights=weights)
    return rot.as_quat(scalar_first=True)


def test_ign_equals_weighted_wahba_optimum_and_cgn_the_unweighted(rng):
    q_true = cv.quat_normalize(rng.normal(size=(300, 4)))
    acc, mag = simulate(q_true, rng)
    for i in range(len(q_true)):
        weights = [paper_weight(mag[i], PAPER_NOISE.mag_var), paper_weight(acc[i], PAPER_NOISE.accel_var)]
        ign = solve(acc[i], mag[i], MAG_REF_UT, PAPER_NOISE)
        cgn = solve(acc[i], mag[i], MAG_REF_UT, PAPER_NOISE, method="cgn")
        assert ign.converged and cgn.converged and ign.iterations <= 3
        # 1e-9 rad: the project's agreement bound; both are the same optimum computed two ways.
        assert cv.angle_between(ign.q, scipy_optimum(acc[i], mag[i], weights)) < 1e-9
        assert cv.angle_between(cgn.q, scipy_optimum(acc[i], mag[i], [1.0, 1.0])) < 1e-9
        assert ign.q[0] >= 0.0


def test_result_fields(rng):
    acc, mag = simulate(cv.quat_from_euler(0.1, -0.2, 2.5), rng)
    for method in SNAPSHOT_METHODS:
        r = solve(acc[0], mag[0], MAG_REF_UT, PAPER_NOISE, method=method)
        assert r.q.shape == (4,) and abs(np.linalg.norm(r.q) - 1.0) < 1e-12
        assert r.covariance.shape == (3, 3) and np.all(np.linalg.eigvalsh(r.covariance) > 0)
        assert np.isfinite(r.loss) and r.loss >= 0.0
        assert r.converged and (r.iterations == 0) == (method == "triad")


@pytest.mark.parametrize(
    ("acc", "mag", "match"),
    [
        ((0.0, 0.0, 0.0), (20.0, 0.0, 40.0), "acc must be finite and non-zero"),
        ((0.0, 0.0, -9.8), (np.nan, 0.0, 40.0), "mag must be finite and non-zero"),
        ((0.0, np.inf, -9.8), (20.0, 0.0, 40.0), "acc must be finite"),
        ((0.0, -9.8), (20.0, 0.0, 40.0), "acc must be a 3-vector"),
    ],
)
def test_bad_vectors_raise_input_error(acc, mag, match):
    with pytest.raises(InputError, match=match):
        solve(acc, mag, MAG_REF_UT, PAPER_NOISE)


def test_near_collinear_raises_with_configurable_angle():
    acc = np.array([0.0, 0.0, -9.8])
    mag = np.array([np.sin(np.radians(4.0)), 0.0, -np.cos(np.radians(4.0))]) * 50.0  # 4° from acc
    with pytest.raises(DegenerateGeometryError, match=r"acc and mag are 4\.00° from collinear \(minimum 5°\)"):
        solve(acc, mag, MAG_REF_UT, PAPER_NOISE)
    with pytest.raises(DegenerateGeometryError, match="acc and mag"):
        solve(acc, -mag, MAG_REF_UT, PAPER_NOISE)  # anti-parallel is collinear too
    assert solve(acc, mag, MAG_REF_UT, PAPER_NOISE, min_angle_deg=3.0).converged
    with pytest.raises(DegenerateGeometryError, match="acc_ref and mag_ref"):
        solve(acc, mag, (0.0, 0.1, -50.0), PAPER_NOISE, min_angle_deg=3.0)


@pytest.mark.parametrize("bad", [0.0, -1.0, np.nan, np.inf, (0.1, 0.0, 0.1), "x"])
def test_bad_noise_raises(bad):
    with pytest.raises(InputError, match="accel_std must be"):
        NoiseModel(accel_std=bad, mag_std=0.3)


def test_unknown_method_and_settings_raise(rng):
    acc, mag = simulate(cv.quat_from_euler(0.0, 0.0, 0.0), rng)
    with pytest.raises(InputError, match="unknown method 'quest'"):
        solve(acc[0], mag[0], MAG_REF_UT, PAPER_NOISE, method="quest")
    with pytest.raises(InputError, match="max_iterations"):
        solve(acc[0], mag[0], MAG_REF_UT, PAPER_NOISE, max_iterations=0)
    with pytest.raises(InputError, match="tolerance"):
        solve(acc[0], mag[0], MAG_REF_UT, PAPER_NOISE, tolerance=-1.0)


def test_non_convergence_is_reported_not_hidden(rng):
    acc, mag = simulate(cv.quat_from_euler(0.3, 0.2, 1.0), rng)
    r = solve(acc[0], mag[0], MAG_REF_UT, PAPER_NOISE, max_iterations=1)
    # From TRIAD the first correction is ~1e-3 rad (the magnetometer's unit noise), far above 1e-12.
    assert not r.converged and r.iterations == 1


def test_batch_equals_per_sample(rng):
    q_true = cv.quat_normalize(rng.normal(size=(500, 4)))
    acc, mag = simulate(q_true, rng)
    for method in SNAPSHOT_METHODS:
        res = solve_batch(acc, mag, MAG_REF_UT, PAPER_NOISE, method=method, full_output=True)
        for i in range(0, 500, 5):
            r = solve(acc[i], mag[i], MAG_REF_UT, PAPER_NOISE, method=method)
            assert cv.angle_between(res.q[i], r.q) < 1e-9  # the project's agreement bound
            assert res.iterations[i] == r.iterations and res.converged[i] == r.converged


def test_vector_buried_in_noise_or_sigma_in_wrong_units_is_refused():
    acc, mag = (0.0, 0.0, -9.8), (20.0, 0.0, 40.0)
    # Magnetometer σ of 100 µT on a 45 µT field: no direction left. (The message's figure is
    # κ = √(tr R_unit / 3) = √(2/3)·σ/|Ŵ| for an isotropic σ: 8.3e-4 and 1.8.)
    with pytest.raises(InputError, match=r"σ/\|vector\| ≈ 8\.3e-04 for acc and 1\.8e\+00 for mag"):
        solve(acc, mag, MAG_REF_UT, NoiseModel(accel_std=0.01, mag_std=100.0))
    # σ given in tesla while the field is in µT: a unit-vector noise of 1e-8, 1e5× finer than the
    # accelerometer's — beyond the 1e4 allowed between the two.
    with pytest.raises(InputError, match="not in its measurement's units"):
        solve(acc, mag, MAG_REF_UT, NoiseModel(accel_std=0.01, mag_std=3e-7))
    with pytest.raises(InputError, match="not in its measurement's units"):
        solve_batch([acc], [mag], MAG_REF_UT, NoiseModel(accel_std=0.01, mag_std=3e-7))


@settings(max_examples=300, deadline=None)
@given(
    st.tuples(*[st.floats(width=64)] * 3),
    st.tuples(*[st.floats(width=64)] * 3),
    st.sampled_from(SNAPSHOT_METHODS),
    st.floats(min_value=1e-12, max_value=1e12),
)
@example((0.0, 1.0, 0.0), (947.0, 0.0, 435.0), "ign", 1.0)  # σ as large as acc: the paths land 1.07e-9 rad apart
def test_any_input_gives_an_answer_or_a_typed_error(acc, mag, method, sigma):
    # Arbitrary floats, NaN and ±inf included: either InputError (or its subclass) or a finite unit
    # quaternion with a finite covariance, the same from both paths. Never NaN, never another exception.
    noise = NoiseModel(accel_std=sigma, mag_std=1.0)
    try:
        r = solve(acc, mag, MAG_REF_UT, noise, method=method)
    except InputError:
        with pytest.raises(InputError):
            solve_batch([acc], [mag], MAG_REF_UT, noise, method=method)
        return
    assert abs(np.linalg.norm(r.q) - 1.0) < 1e-12 and np.isfinite(r.covariance).all() and np.isfinite(r.loss)
    b = solve_batch([acc], [mag], MAG_REF_UT, noise, method=method, full_output=True)
    assert b.converged[0] == r.converged
    assert not r.converged or cv.angle_between(b.q[0], r.q) < agreement_bound_rad(r.covariance)


def agreement_bound_rad(covariance: np.ndarray) -> float:
    """How far the scalar and the array path may land apart: the project's 1e-9 rad, or, on an ill-conditioned
    problem, what their different rounding allows. A rounding of ε in the normal equations moves the answer by
    ~ε κ about the weakest axis (κ: the condition number of the normal matrix, the covariance's own); 100 ε κ
    leaves margin (measured: 4.4 ε κ for a sensor with σ as large as its vector, κ 1.1e6)."""
    return max(1e-9, 100.0 * np.finfo(float).eps * float(np.linalg.cond(covariance)))


def test_nearly_collinear_references_beyond_floating_point_are_refused_by_both_paths():
    # min_angle_deg set far below what float64 resolves: references 1.8e-7° apart pass the angle check,
    # but the normal matrix Σ aᵢ(I − uᵢuᵢᵀ) is singular in floating point. The solver used to divide by
    # its determinant's rounding error and return an arbitrary rotation (with a negative "covariance").
    ref = (3.0810171887114787e-07, 0.0, -50.0)
    acc = (-0.5699176996906925, -8.481401123899932, -4.87657962009114)
    mag = (-2.907743402903299, -43.27245486435094, -24.88050799954821)
    noise = NoiseModel(accel_std=0.01, mag_std=0.3)
    for method in ("ign", "cgn", "ml"):
        with pytest.raises(DegenerateGeometryError, match="normal matrix is singular"):
            solve(acc, mag, ref, noise, method=method, acc_ref=(0.0, 0.0, -9.8), min_angle_deg=1.7e-7)
        with pytest.raises(DegenerateGeometryError, match=r"normal matrix is singular.*first: sample 1"):
            refs = [MAG_REF_UT, ref]  # the first sample is well posed, the second is not
            solve_batch([ACC_REF, acc], [MAG_REF_UT, mag], refs, noise, method=method, min_angle_deg=1.7e-7)


# Arbitrary finite floats, mixed with small exact values: exact cancellations (a determinant of exactly
# 0.0, a vector exactly reversed) come from those, not from random mantissas.
_component = st.one_of(
    st.floats(allow_nan=False, allow_infinity=False), st.sampled_from([0.0, 1.0, -1.0, 0.5, 2.0, -9.8, 20.0, 45.0])
)
_vector = st.tuples(_component, _component, _component)
_sigma = st.tuples(*[st.floats(1e-6, 1e3)] * 3)


@settings(max_examples=400, deadline=None)
@given(
    acc=_vector,
    mag=_vector,
    refs=st.tuples(_vector, _vector),
    q0=st.none() | st.tuples(_component, _component, _component, _component),
    method=st.sampled_from(SNAPSHOT_METHODS),
    sigmas=st.tuples(_sigma, _sigma),
    min_angle_deg=st.floats(1e-9, 89.0),
)
def test_solve_on_any_finite_input_gives_a_unit_quaternion_or_a_typed_error(
    acc, mag, refs, q0, method, sigmas, min_angle_deg
):
    # The service's promise rests on this: no ZeroDivisionError, OverflowError or NaN ever escapes the
    # solver. Anything but a MavAttitudeError propagates and fails the test.
    options = {"method": method, "acc_ref": refs[0], "min_angle_deg": min_angle_deg}
    noise = NoiseModel(accel_std=sigmas[0], mag_std=sigmas[1])
    try:
        r = solve(acc, mag, refs[1], noise, q0=q0, **options)
    except MavAttitudeError:
        r = None
    if r is not None:
        assert np.isfinite(r.q).all() and abs(np.linalg.norm(r.q) - 1.0) < 1e-12 and np.isfinite(r.loss)
        with contextlib.suppress(DegenerateGeometryError):  # refused on access (singular information), never NaN
            assert np.isfinite(r.covariance).all()
    try:
        b = solve_batch([acc], [mag], refs[1], noise, full_output=True, **options)
    except MavAttitudeError:
        return
    assert np.isfinite(b.q).all() and abs(np.linalg.norm(b.q[0]) - 1.0) < 1e-12 and np.isfinite(b.loss).all()
