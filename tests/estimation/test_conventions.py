"""The conventions module against pymavlink's own quaternion code and scipy's rotations."""

from __future__ import annotations

import numpy as np
import pytest
from pymavlink.quaternion import QuaternionBase as Quaternion
from scipy.spatial.transform import Rotation

from mavattitude.estimation import conventions as cv

RNG_SEED = 20140401


@pytest.fixture
def random_quats() -> np.ndarray:
    rng = np.random.default_rng(RNG_SEED)
    return cv.quat_normalize(rng.normal(size=(200, 4)))


def test_rotation_matrix_matches_pymavlink_dcm(random_quats):
    # pymavlink's Quaternion.dcm is the body -> earth (NED) matrix of MAVLink's q1..q4.
    for q in random_quats[:50]:
        np.testing.assert_allclose(cv.rotation_matrix(q), Quaternion(list(q)).dcm, atol=1e-12)


def test_euler_both_ways_match_pymavlink():
    rng = np.random.default_rng(RNG_SEED)
    for _ in range(50):
        euler = rng.uniform([-np.pi, -1.5, -np.pi], [np.pi, 1.5, np.pi])
        q_ours = cv.quat_from_euler(*euler)
        q_mav = np.array(Quaternion(list(euler)).q)
        assert cv.angle_between(q_ours, q_mav) < 1e-12
        np.testing.assert_allclose(cv.euler_from_quat(q_mav), Quaternion(list(q_mav)).euler, atol=1e-12)


def test_matches_scipy_scalar_first(random_quats):
    rot = Rotation.from_quat(random_quats, scalar_first=True)
    np.testing.assert_allclose(cv.rotation_matrix(random_quats), rot.as_matrix(), atol=1e-12)
    np.testing.assert_allclose(cv.euler_from_quat(random_quats), rot.as_euler("ZYX")[:, ::-1], atol=1e-9)
    v = np.random.default_rng(1).normal(size=(200, 3))
    np.testing.assert_allclose(cv.rotate_body_to_ned(random_quats, v), rot.apply(v), atol=1e-12)
    np.testing.assert_allclose(cv.rotate_ned_to_body(random_quats, v), rot.inv().apply(v), atol=1e-12)


def test_product_is_hamilton_composition(random_quats):
    p, q = random_quats[:100], random_quats[100:]
    expected = (Rotation.from_quat(p, scalar_first=True) * Rotation.from_quat(q, scalar_first=True)).as_matrix()
    np.testing.assert_allclose(cv.rotation_matrix(cv.quat_multiply(p, q)), expected, atol=1e-12)


def test_attitude_matrix_is_papers_eq27(random_quats):
    # Eq. 27 with Shuster's sign: A = (w² − ρᵀρ) I + 2ρρᵀ − 2w[ρ×].
    for q in random_quats[:20]:
        w, rho = q[0], q[1:]
        a = (w * w - rho @ rho) * np.eye(3) + 2 * np.outer(rho, rho) - 2 * w * cv.skew(rho)
        np.testing.assert_allclose(cv.attitude_matrix(q), a, atol=1e-12)


def test_matrix_to_quat_round_trip_including_180_degrees(random_quats):
    axes = np.random.default_rng(3).normal(size=(50, 3))
    half_turns = cv.quat_from_rotvec(np.pi * axes / np.linalg.norm(axes, axis=1, keepdims=True))
    for qs in (random_quats, half_turns, np.eye(4)):
        back = cv.quat_from_rotation_matrix(cv.rotation_matrix(qs))
        assert np.all(back[:, 0] >= 0.0)
        assert np.max(cv.angle_between(back, qs)) < 1e-12


def test_rotvec_maps_are_inverse_and_match_scipy():
    rng = np.random.default_rng(RNG_SEED)
    theta = rng.normal(size=(100, 3))
    theta *= (rng.uniform(0, np.pi, 100) / np.linalg.norm(theta, axis=1))[:, None]
    q = cv.quat_from_rotvec(theta)
    np.testing.assert_allclose(q, Rotation.from_rotvec(theta).as_quat(scalar_first=True), atol=1e-12)
    np.testing.assert_allclose(cv.rotvec_from_quat(q), theta, atol=1e-12)
    tiny = np.array([1e-12, -2e-12, 3e-12])
    np.testing.assert_allclose(cv.rotvec_from_quat(cv.quat_from_rotvec(tiny)), tiny, rtol=1e-9)


def test_plain_float_rotvec_map_matches_the_array_one():
    rng = np.random.default_rng(RNG_SEED)
    for v in [*rng.normal(size=(20, 3)), np.zeros(3), np.full(3, 1e-10), np.array([np.pi - 1e-6, 0.0, 0.0])]:
        q = np.array(cv.quat_from_rotvec_parts(*v))
        assert np.allclose(q, cv.quat_from_rotvec(v), atol=1e-14)


def test_plain_float_euler_map_matches_the_array_one():
    angles = np.random.default_rng(RNG_SEED).uniform(-4.0, 4.0, size=(50, 3))
    parts = np.array([cv.quat_from_euler_parts(*a) for a in angles.tolist()])
    # the same products of the same cosines and sines: math's and numpy's agree to the last bit or two
    np.testing.assert_allclose(parts, cv.quat_from_euler(*angles.T), rtol=0, atol=1e-15)


def test_body_error_angles_follow_eq_28():
    q_true = cv.quat_from_euler(0.3, -0.2, 2.0)
    d_alpha = np.array([1e-3, -2e-3, 5e-4])
    q_est = cv.quat_multiply(q_true, cv.quat_from_rotvec(d_alpha))
    np.testing.assert_allclose(cv.body_error_angles(q_est, q_true), d_alpha, atol=1e-15)
    assert cv.angle_between(q_est, q_true) == pytest.approx(np.linalg.norm(d_alpha), rel=1e-9)


def test_level_specific_force_reads_minus_g_on_z():
    # FRD body, NED earth: an accelerometer at rest measures specific force, i.e. "up" = −z.
    q_level = cv.quat_from_euler(0.0, 0.0, 1.0)
    np.testing.assert_allclose(cv.rotate_ned_to_body(q_level, [0, 0, -9.81]), [0, 0, -9.81], atol=1e-12)
    q_nose_up = cv.quat_from_euler(0.0, np.radians(30), 0.0)
    f_body = cv.rotate_ned_to_body(q_nose_up, [0, 0, -9.81])
    assert f_body[0] > 0  # nose up: the forward axis sees part of "up"


def test_the_output_check_is_on_the_squared_norm_within_its_tolerance():
    # Just inside and just outside |q|² − 1 = 1e-6 (|q| − 1 ≈ 5e-7); any non-finite component fails.
    inside, outside = np.sqrt(1.0 + 0.9e-6), np.sqrt(1.0 + 1.1e-6)
    assert cv.is_unit_quaternion_parts((inside, 0.0, 0.0, 0.0))
    assert not cv.is_unit_quaternion_parts((outside, 0.0, 0.0, 0.0))
    assert cv.is_unit_quaternion_parts(tuple(cv.quat_normalize([1.0, -2.0, 3.0, 0.5])))
    for bad in (np.nan, np.inf):
        assert not cv.is_unit_quaternion_parts((1.0, 0.0, bad, 0.0))
