"""The vehicle clock, ArduPilot mounting rotations and the calibration models."""

from __future__ import annotations

import numpy as np
import pytest

from mavattitude.config import from_dict
from mavattitude.errors import ConfigError
from mavattitude.sensors.calibration import hard_iron_with_body_offset, mag_block, sensor_affines
from mavattitude.sensors.clock import ClockEvent, VehicleClock, first_repeats
from mavattitude.sensors.mounting import ARDUPILOT_ROTATIONS, mounting_matrix, rotation_angles_deg

WRAP_MS = 2.0**32 * 1e-3


def test_clock_unwraps_time_boot_ms() -> None:
    clock = VehicleClock()
    assert clock.update(WRAP_MS - 0.010, WRAP_MS) == (WRAP_MS - 0.010, ClockEvent.OK)
    t, event = clock.update(0.010, WRAP_MS)
    assert event is ClockEvent.WRAP and t == pytest.approx(WRAP_MS + 0.010, abs=1e-9)
    t, event = clock.update(0.030, WRAP_MS)
    assert event is ClockEvent.OK and t == pytest.approx(WRAP_MS + 0.030, abs=1e-9)


def test_clock_drops_duplicates_and_reordered_and_restarts_on_reboot() -> None:
    clock = VehicleClock(reorder_window_s=1.0)
    clock.update(100.0, None)
    assert clock.update(100.0, None) == (None, ClockEvent.DUPLICATE)
    assert clock.update(99.99, None) == (None, ClockEvent.OUT_OF_ORDER)
    assert clock.update(100.01, None) == (100.01, ClockEvent.OK)
    assert clock.update(2.0, None) == (2.0, ClockEvent.REBOOT)  # 98 s back: the autopilot restarted
    assert clock.update(2.01, None) == (2.01, ClockEvent.OK)


@pytest.mark.parametrize("first", [True, False])
def test_a_time_that_is_no_number_is_dropped_and_leaves_the_clock_as_it_was(first: bool) -> None:
    """A CSV's nan or inf: taken, NaN would make every later time a reboot (no comparison with it holds) and
    inf every later one a step back."""
    clock = VehicleClock()
    if not first:
        clock.update(100.0, None)
    for bad in (np.nan, np.inf, -np.inf):
        assert clock.update(bad, None) == (None, ClockEvent.NO_TIME)
    assert clock.update(100.01, None) == (100.01, ClockEvent.OK)
    assert clock.update(100.02, None) == (100.02, ClockEvent.OK)


def test_uint64_time_never_wraps_but_reboots() -> None:
    clock = VehicleClock()
    clock.update(5000.0, None)
    assert clock.update(3.0, None)[1] is ClockEvent.REBOOT


@pytest.mark.parametrize(
    ("times", "expected"),
    [
        ([1, 1, 2, 2, 3, 3, 4, 4], 4),  # a stream arriving twice: every sample's copy
        ([1, 1, 1, 2, 2, 2], 2),  # three times: one first copy per sample
        ([1, 2, 3, 3, 3, 3, 3, 3, 3, 3], 1),  # a clock that stands still: one run
        ([1, 2, 3], 0),
        ([5, 5], 1),
        ([], 0),
    ],
)
def test_first_repeats_count_a_copy_per_sample_and_a_run_once(times: list[int], expected: int) -> None:
    assert first_repeats(times) == expected


def test_ardupilot_rotations_match_vector3_rotate() -> None:
    v = np.array([1.0, 2.0, 3.0])
    # AP_Math/vector3.cpp Vector3::rotate, written out there case by case
    assert mounting_matrix("ROLL_180_YAW_90") @ v == pytest.approx([2.0, 1.0, -3.0])
    assert mounting_matrix("ROTATION_ROLL_90_YAW_270") @ v == pytest.approx([-3.0, -1.0, 2.0])
    assert mounting_matrix("YAW_90") @ v == pytest.approx([-2.0, 1.0, 3.0])
    assert mounting_matrix("PITCH_180") @ v == pytest.approx([-1.0, 2.0, -3.0])
    assert mounting_matrix("ROLL_180") @ v == pytest.approx([1.0, -2.0, -3.0])
    assert mounting_matrix("NONE") @ v == pytest.approx(v)
    # the two documented duplicates of rotations.h
    assert mounting_matrix("PITCH_180_YAW_90") == pytest.approx(mounting_matrix("ROLL_180_YAW_270"), abs=1e-15)
    assert mounting_matrix("PITCH_180_YAW_270") == pytest.approx(mounting_matrix("ROLL_180_YAW_90"), abs=1e-15)


def test_every_named_rotation_is_proper_and_the_odd_one_matches_ardupilots_quaternion() -> None:
    assert len(ARDUPILOT_ROTATIONS) == 44
    for name in ARDUPILOT_ROTATIONS.values():
        m = mounting_matrix(name)
        assert m @ m.T == pytest.approx(np.eye(3), abs=1e-12) and np.linalg.det(m) == pytest.approx(1.0)
    # quaternion_from_rotation for ROLL_90_PITCH_68_YAW_293 in AP_Math/quaternion.cpp (w, x, y, z)
    w, x, y, z = 0.26774500501681575, 0.7069880468895242, 0.012957683254962660, -0.6544559666536361
    expected = np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
            [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
            [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
        ]
    )
    assert mounting_matrix("ROLL_90_PITCH_68_YAW_293") == pytest.approx(expected, abs=1e-6)
    assert rotation_angles_deg("roll_45") == (45.0, 0.0, 0.0)


def test_bad_mountings_are_config_errors() -> None:
    with pytest.raises(ConfigError, match="unknown mounting rotation 'ROLL_30'"):
        mounting_matrix("ROLL_30")
    with pytest.raises(ConfigError, match="must be a rotation"):
        mounting_matrix([[1, 0, 0], [0, 1, 0], [0, 0, -1]])  # a reflection
    with pytest.raises(ConfigError, match="3×3"):
        mounting_matrix([[1, 0], [0, 1]])


def test_calibration_chain_is_mounting_after_the_sensor_models() -> None:
    cal = _calibration(
        {
            "accel": {"bias_mps2": [0.1, -0.2, 0.3], "matrix": [[1.01, 0.002, 0], [0, 0.99, 0], [0, 0.001, 1.0]]},
            "mag": {"hard_iron_uT": [5, -3, 2], "soft_iron": [[1.1, 0.02, 0], [0.02, 0.9, 0], [0, 0, 1.05]]},
            "gyro": {"bias_radps": [0.01, 0.0, -0.02]},
        }
    )
    r = mounting_matrix("ROLL_180")
    maps = sensor_affines(cal, r)
    raw = np.array([1.0, -2.0, 9.0])
    for sensor, m, b in (
        ("acc", cal.accel.matrix, cal.accel.bias_mps2),
        ("mag", cal.mag.soft_iron, cal.mag.hard_iron_uT),
        ("gyr", np.eye(3), cal.gyro.bias_radps),
    ):
        a, c = maps[sensor]
        assert a @ raw - c == pytest.approx(r @ (np.asarray(m) @ (raw - np.asarray(b))), abs=1e-12)


def test_calibration_yaml_keys_and_errors() -> None:
    block = mag_block([1, 2, 3], np.diag([1.0, 2.0, 3.0]))
    assert block == {
        "calibration": {"mag": {"hard_iron_uT": [1.0, 2.0, 3.0], "soft_iron": [[1, 0, 0], [0, 2, 0], [0, 0, 3]]}}
    }
    again = _calibration(block["calibration"])
    assert again.mag.soft_iron[1][1] == 2.0 and again.accel.matrix[0][0] == 1.0  # missing keys: identity
    with pytest.raises(ConfigError, match=r"calibration\.mag\.hard_iron_uT: expected a list of 3 numbers"):
        _calibration({"mag": {"hard_iron_uT": [1, 2]}})


def _calibration(block: dict):
    """The ``calibration`` section as the config reads it from YAML."""
    return from_dict({"calibration": block}).calibration


def test_a_body_frame_offset_folds_into_the_hard_iron() -> None:
    """``R S (raw − h') = R S (raw − h) − o`` for the fused filter's learnt offset ``o`` (rounding only)."""
    rng = np.random.default_rng(7)
    soft = np.eye(3) + 0.1 * rng.normal(size=(3, 3))
    cal = from_dict({"calibration": {"mag": {"hard_iron_uT": [3.0, -2.0, 5.0], "soft_iron": soft.tolist()}}})
    mag = cal.calibration.mag
    r, raw, offset = mounting_matrix("ROLL_180_YAW_90"), rng.normal(size=3) * 40.0, np.array([-3.0, 1.0, 25.0])
    h_new = hard_iron_with_body_offset(mag, r, offset)
    before = r @ soft @ (raw - np.array(mag.hard_iron_uT))
    assert np.allclose(r @ soft @ (raw - h_new), before - offset, atol=1e-9)
