"""Shared fixtures: the real recordings, loaded once per test session (≈ 0.2 s each)."""

from __future__ import annotations

from pathlib import Path

import pytest

from mavattitude.validation import Recording, load_recording

DATA = Path(__file__).resolve().parents[2] / ".." / "shared" / "data"
BROAD_04 = DATA / "broad" / "04_undisturbed_slow_rotation_with_breaks_A.csv.gz"
BROAD_08 = DATA / "broad" / "08_undisturbed_fast_rotation_with_breaks_A.csv.gz"
BROAD_28 = DATA / "broad" / "28_disturbed_stationary_magnet_A.csv.gz"
PX4 = DATA / "px4" / "px4_sample_sensors.csv.gz"


@pytest.fixture(scope="session")
def recordings() -> dict[str, Recording]:
    return {
        key: load_recording(path) for key, path in (("04", BROAD_04), ("08", BROAD_08), ("28", BROAD_28), ("px4", PX4))
    }
