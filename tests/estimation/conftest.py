"""Shared scenario for the estimation tests: the paper's sensor noise (Eq. 36) and field geometry."""

from __future__ import annotations

import numpy as np
import pytest

from mavattitude.estimation import NoiseModel
from mavattitude.estimation import conventions as cv

SEED = 20140401
# Eq. 36: R1 = diag(2², 3², 2.5²)·1e-14 T² → σ in µT; R2 = diag(10², 9², 9.5²)·1e-6 (m/s²)² (docs/paper-notes.md).
PAPER_NOISE = NoiseModel(accel_std=(0.010, 0.009, 0.0095), mag_std=(0.2, 0.3, 0.25))
# A mid-latitude NED field (µT), 65° inclination like the paper's scenario, and specific force "up".
MAG_REF_UT = np.array([22.0, 1.5, 47.0])
ACC_REF = np.array([0.0, 0.0, -9.80665])


def simulate(q_true: np.ndarray, rng: np.random.Generator, noise=PAPER_NOISE, scale: float = 1.0):
    """Body accelerometer / magnetometer readings of attitudes ``q_true`` (N, 4) with Gaussian noise."""
    q_true = np.atleast_2d(q_true)
    n = q_true.shape[0]
    acc = cv.rotate_ned_to_body(q_true, ACC_REF) + scale * rng.normal(size=(n, 3)) * noise.accel_std
    mag = cv.rotate_ned_to_body(q_true, MAG_REF_UT) + scale * rng.normal(size=(n, 3)) * noise.mag_std
    return acc, mag


@pytest.fixture
def rng() -> np.random.Generator:
    return np.random.default_rng(SEED)
