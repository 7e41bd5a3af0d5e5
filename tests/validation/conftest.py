"""Shared fixtures: the real recordings in ../shared/data, loaded once per test session (≈ 0.2 s each)."""

from __future__ import annotations

from pathlib import Path

import pytest

from mavattitude.validation import Recording, load_recording
from tests.shared import shared_path

FILES = {
    "01": ("data", "broad", "01_undisturbed_slow_rotation_A.csv.gz"),
    "04": ("data", "broad", "04_undisturbed_slow_rotation_with_breaks_A.csv.gz"),
    "06": ("data", "broad", "06_undisturbed_fast_rotation_A.csv.gz"),
    "08": ("data", "broad", "08_undisturbed_fast_rotation_with_breaks_A.csv.gz"),
    "12": ("data", "broad", "12_undisturbed_slow_translation_C.csv.gz"),
    "28": ("data", "broad", "28_disturbed_stationary_magnet_A.csv.gz"),
    "px4": ("data", "px4", "px4_sample_sensors.csv.gz"),
}


@pytest.fixture(scope="session")
def px4_csv() -> Path:
    return shared_path(*FILES["px4"])


@pytest.fixture(scope="session")
def recordings() -> dict[str, Recording]:
    return {key: load_recording(shared_path(*parts)) for key, parts in FILES.items()}
