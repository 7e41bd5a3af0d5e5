"""The vectorised solver's input checks and failure reporting (its agreement is in test_solve)."""

from __future__ import annotations

import numpy as np
import pytest

from mavattitude.errors import ConvergenceError, DegenerateGeometryError, InputError
from mavattitude.estimation import BatchResult, NoiseModel, solve, solve_batch, solve_each
from mavattitude.estimation import conventions as cv

from .conftest import ACC_REF, MAG_REF_UT, PAPER_NOISE, simulate


@pytest.fixture
def samples(rng):
    return simulate(cv.quat_normalize(rng.normal(size=(10_000, 4))), rng)


def test_bad_sample_is_named(samples):
    acc, mag = (a.copy() for a in samples)
    acc[7321] = np.nan
    acc[9000] = 0.0
    named = r"acc must be finite and non-zero, got \(nan, nan, nan\): 2 bad sample.*first: sample 7321"
    with pytest.raises(InputError, match=named):
        solve_batch(acc, mag, MAG_REF_UT, PAPER_NOISE)
    mag = samples[1].copy()
    mag[5000] = samples[0][5000] * 5.0  # collinear with the accelerometer
    with pytest.raises(
        DegenerateGeometryError, match=r"acc and mag are 0\.00° from collinear.*: 1 bad sample\(s\), first: sample 5000"
    ):
        solve_batch(samples[0], mag, MAG_REF_UT, PAPER_NOISE)


def test_skip_unusable_leaves_out_exactly_what_the_per_sample_solver_refuses(samples):
    acc, mag = (a[:200].copy() for a in samples)
    acc[3], acc[50] = np.nan, 0.0
    mag[7] = acc[7] * 5.0  # collinear with the accelerometer
    mag[9] = mag[9] * 1e-9  # buried in its noise
    refused = np.zeros(len(acc), dtype=bool)
    for i in range(len(acc)):
        try:
            solve(acc[i], mag[i], MAG_REF_UT, PAPER_NOISE)
        except InputError:  # DegenerateGeometryError is one
            refused[i] = True
    assert np.flatnonzero(refused).tolist() == [3, 7, 9, 50]
    result = solve_batch(acc, mag, MAG_REF_UT, PAPER_NOISE, full_output=True, skip_unusable=True)
    assert np.array_equal(result.usable, ~refused)
    assert np.isnan(result.q[refused]).all() and not result.converged[refused].any()
    # The usable samples' answers are those of a batch of them alone, bit for bit.
    alone = solve_batch(acc[~refused], mag[~refused], MAG_REF_UT, PAPER_NOISE)
    assert np.array_equal(result.q[~refused], alone)
    assert np.array_equal(solve_batch(acc, mag, MAG_REF_UT, PAPER_NOISE, skip_unusable=True), result.q, equal_nan=True)


def test_shapes_are_checked(samples):
    acc, mag = samples
    with pytest.raises(InputError, match=r"mag must have shape \(10000, 3\) or \(3,\), got \(9999, 3\)"):
        solve_batch(acc, mag[1:], MAG_REF_UT, PAPER_NOISE)
    with pytest.raises(InputError, match=r"acc must have shape \(N, 3\)"):
        solve_batch(acc[0], mag, MAG_REF_UT, PAPER_NOISE)


def test_per_sample_references(samples, rng):
    acc, mag = samples[0][:100], samples[1][:100]
    refs = np.repeat(MAG_REF_UT[None], 100, axis=0) * rng.uniform(0.5, 2.0, size=(100, 1))  # only direction counts
    np.testing.assert_allclose(
        solve_batch(acc, mag, refs, PAPER_NOISE, acc_ref=np.repeat(ACC_REF[None], 100, axis=0)),
        solve_batch(acc, mag, MAG_REF_UT, PAPER_NOISE, acc_ref=ACC_REF),
        atol=1e-12,
    )


def test_non_convergence_raises_or_is_flagged(samples):
    acc, mag = samples
    with pytest.raises(ConvergenceError, match="10000 of 10000 samples did not converge in 1 iterations"):
        solve_batch(acc, mag, MAG_REF_UT, PAPER_NOISE, max_iterations=1)
    res = solve_batch(acc, mag, MAG_REF_UT, PAPER_NOISE, max_iterations=1, full_output=True)
    assert isinstance(res, BatchResult) and not res.converged.any() and (res.iterations == 1).all()
    r = solve(acc[3], mag[3], MAG_REF_UT, PAPER_NOISE, max_iterations=1)
    assert cv.angle_between(r.q, res.q[3]) < 1e-12 and r.loss == pytest.approx(res.loss[3], rel=1e-9)


def _solve_or_error(*args, **kwargs):
    try:
        return solve(*args, **kwargs)
    except InputError as exc:  # DegenerateGeometryError is one
        return exc


@pytest.mark.parametrize("method", ["ign", "cgn", "ml", "triad"])
def test_solve_each_is_solve_of_each_sample(samples, rng, method):
    """Each sample's result or refusal is the one solve() gives it: the same error type and words (the first of
    solve's checks it fails, in solve's order), the same corrections, the attitude and covariance to rounding."""
    acc, mag = (a[:300].copy() for a in samples)
    refs = np.repeat(MAG_REF_UT[None], 300, axis=0)
    acc[3], acc[50], mag[60] = np.nan, 0.0, np.inf
    mag[7] = acc[7] * 5.0  # collinear with the accelerometer
    mag[9] = mag[9] * 1e-9  # buried in its noise
    mag[11] = acc[11] * 1e-9  # both: solve says the geometry, its first check of the two
    refs[13] = ACC_REF * 50.0  # collinear references
    results = solve_each(acc, mag, refs, PAPER_NOISE, method)
    expected = [_solve_or_error(a, m, r, PAPER_NOISE, method) for a, m, r in zip(acc, mag, refs, strict=True)]
    refused = [i for i, e in enumerate(expected) if isinstance(e, InputError)]
    assert refused == [3, 7, 9, 11, 13, 50, 60]
    assert isinstance(expected[11], DegenerateGeometryError)
    for got, want in zip(results, expected, strict=True):
        assert type(got) is type(want)
        if isinstance(want, InputError):
            assert str(got) == str(want)
            continue
        assert cv.angle_between(got.q, want.q) < 1e-12  # rounding: the same equations on arrays
        assert (got.iterations, got.converged, got.method, got.noise) == (want.iterations, True, method, PAPER_NOISE)
        np.testing.assert_allclose(got.covariance, want.covariance, rtol=1e-9, atol=1e-30)
        assert got.loss == pytest.approx(want.loss, rel=1e-6, abs=1e-18)


def test_solve_each_returns_a_sample_singular_while_iterating_as_its_error():
    """References 1.8e-7° apart (min_angle_deg below what float64 resolves): the normal matrix is singular for
    that sample alone, which is refused as solve() refuses it; the sample beside it is solved."""
    ref = (3.0810171887114787e-07, 0.0, -50.0)
    acc = (-0.5699176996906925, -8.481401123899932, -4.87657962009114)
    mag = (-2.907743402903299, -43.27245486435094, -24.88050799954821)
    noise = NoiseModel(accel_std=0.01, mag_std=0.3)
    good, bad = solve_each([ACC_REF, acc], [MAG_REF_UT, mag], [MAG_REF_UT, ref], noise, min_angle_deg=1.7e-7)
    assert good.converged and cv.angle_between(good.q, [1.0, 0.0, 0.0, 0.0]) < 1e-9
    assert isinstance(bad, DegenerateGeometryError) and "normal matrix is singular" in str(bad)
