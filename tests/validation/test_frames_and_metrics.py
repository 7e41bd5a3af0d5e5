"""Frames, loaders and metrics on hand-made cases and on the real files' own structure."""

from __future__ import annotations

import numpy as np
import pytest

from mavattitude.errors import DataFileError
from mavattitude.estimation.conventions import (
    angle_between,
    euler_from_quat,
    quat_from_euler,
    quat_from_rotvec,
    quat_multiply,
    rotate_body_to_ned,
)
from mavattitude.sensors.units import STANDARD_GRAVITY_MPS2
from mavattitude.validation import (
    Q_ENU_FROM_NED,
    broad_errors,
    enu_from_ned,
    load_recording,
    ned_from_enu,
    rest_mask,
    score_px4,
    truth_at,
)
from mavattitude.validation.loaders import _read_csv


def test_enu_from_ned_swaps_north_east_and_flips_down() -> None:
    # The identity attitude (body = NED axes) seen in ENU: body x (north) is ENU y, body z (down) is −z.
    r = rotate_body_to_ned(enu_from_ned(np.array([1.0, 0, 0, 0])), np.eye(3))
    np.testing.assert_allclose(r, [[0, 1, 0], [1, 0, 0], [0, 0, -1]], atol=1e-15)
    q = quat_from_euler(0.3, -0.2, 1.1)
    assert angle_between(ned_from_enu(enu_from_ned(q)), q) < 1e-12
    np.testing.assert_allclose(Q_ENU_FROM_NED, [0, np.sqrt(0.5), np.sqrt(0.5), 0])


def test_broad_truth_puts_the_resting_specific_force_up(recordings) -> None:
    # Converted truth (sensor → NED) must map the resting accelerometer (+9.81 on sensor z) to NED −g·z,
    # and the field to north/down: this checks the ENU → NED conversion on the real data.
    for key in ("04", "08", "28"):
        rec = recordings[key]
        rest = rec.rest & ~np.isnan(rec.truth_q).any(axis=1)
        f_ned = rotate_body_to_ned(rec.truth_q[rest], rec.acc_mps2[rest]).mean(axis=0)
        np.testing.assert_allclose(f_ned, [0, 0, -STANDARD_GRAVITY_MPS2], atol=0.15)  # 0.15 m/s²: a ≈ 0.5° tilt or bias
        b_ned = rotate_body_to_ned(rec.truth_q[rest], rec.mag_uT[rest]).mean(axis=0)
        assert b_ned[0] > 10 and b_ned[2] > 35 and abs(b_ned[1]) < 3  # README: (0, 13…17, −39…−43) ENU


def test_rest_reference_is_measured_not_copied(recordings) -> None:
    ref = recordings["04"].reference
    dip = np.degrees(np.arctan2(ref.field_ned_uT[2], ref.field_ned_uT[0]))
    assert 68 < dip < 73 and ref.field_ned_uT[1] == 0.0  # README's field at rest: dip 66–73°
    np.testing.assert_allclose(ref.mag_std_uT, 0.7, atol=0.1)  # README: ~0.7 µT rms noise


def test_broad_errors_split_heading_and_inclination() -> None:
    truth = quat_from_euler(0.4, -0.3, 2.0)[None]
    # An error about the earth's vertical is all heading; about a horizontal axis, all inclination.
    yawed = quat_multiply(quat_from_rotvec([0, 0, 0.1]), truth)
    tilted = quat_multiply(quat_from_rotvec([0.06, -0.08, 0]), truth)
    np.testing.assert_allclose(broad_errors(yawed, truth), [[0.1, 0.1, 0.0]], atol=1e-12)
    np.testing.assert_allclose(broad_errors(tilted, truth), [[0.1, 0.0, 0.1]], atol=1e-12)
    # Sign of the quaternion does not matter.
    np.testing.assert_allclose(broad_errors(-yawed, truth), [[0.1, 0.1, 0.0]], atol=1e-12)


def test_rest_mask_keeps_one_second_from_motion() -> None:
    t = np.arange(0, 10, 0.01)
    movement = (t >= 4) & (t < 5)
    rest = rest_mask(t, movement)
    assert not rest[(t > 3.0 + 1e-9) & (t < 6.0 - 0.01 - 1e-9)].any()
    assert rest[t <= 3.0 + 1e-9].all() and rest[t >= 5.99 - 1e-9].all()


def test_truth_at_interpolates_between_samples(recordings) -> None:
    rec = recordings["08"].slice(60, 61)
    q, _, _ = truth_at(rec, rec.time_s[:-1] + np.diff(rec.time_s) / 2)
    ok = ~np.isnan(q).any(axis=1)
    half = angle_between(rec.truth_q[:-1], rec.truth_q[1:]) / 2
    np.testing.assert_allclose(angle_between(rec.truth_q[:-1][ok], q[ok]), half[ok], atol=1e-6)
    # Flags come from the nearest sample.
    _, movement, rest = truth_at(rec, rec.time_s[:-1] + np.diff(rec.time_s) / 4)
    assert np.array_equal(movement, rec.movement[:-1]) and np.array_equal(rest, rec.rest[:-1])
    q_outside, _, _ = truth_at(rec, np.array([rec.time_s[0] - 1.0]))
    assert np.isnan(q_outside).all()


def test_px4_truth_euler_matches_the_logged_angles(px4_csv) -> None:
    # Our ZYX Euler convention must read the autopilot's quaternion as its own logged roll/pitch/yaw.
    columns = _read_csv(px4_csv)
    q = np.stack([columns[f"att_q{c}"] for c in "wxyz"], axis=1)
    logged = np.stack([columns[f"att_{a}_rad"] for a in ("roll", "pitch", "yaw")], axis=1)
    d = np.angle(np.exp(1j * (euler_from_quat(q) - logged)))
    assert np.abs(d).max() < 1e-5  # the CSV's 9 significant digits


def test_px4_score_of_a_known_offset(recordings) -> None:
    truth = recordings["px4"].truth_q[:500]
    offset = quat_multiply(quat_from_euler(0, 0, np.radians(3.0)), truth)
    s = score_px4(offset, truth)
    assert s.heading_mean_deg == pytest.approx(3.0, abs=1e-9) and s.heading_std_deg < 1e-9
    assert s.roll_rms_deg < 1e-9 and s.pitch_rms_deg < 1e-9


def test_bad_files_are_data_file_errors(tmp_path) -> None:
    wrong = tmp_path / "wrong.csv"
    wrong.write_text("a,b\n1,2\n3,4\n")
    with pytest.raises(DataFileError, match="neither a BROAD trial nor the PX4 log"):
        load_recording(wrong)
    broken = tmp_path / "broken.csv"
    broken.write_text("t_s,acc_x_mps2\n0,1\n\n0,x\n")
    with pytest.raises(DataFileError, match=r"broken\.csv:4: column acc_x_mps2: 'x' is not a number"):
        load_recording(broken)  # the file's own line: header 1, blank line 3 counted


def test_a_slice_outside_the_recording_is_refused(recordings) -> None:
    """Said with the recording's length (from ``--start`` alone: to its end)."""
    length = recordings["px4"].time_s[-1] - recordings["px4"].time_s[0]
    with pytest.raises(
        DataFileError, match=rf"1000 s to 1001 s holds fewer than 2 samples \(the recording is {length:.1f} s"
    ):
        recordings["px4"].slice(1000, 1001)
    with pytest.raises(DataFileError, match="500 s to the end holds fewer than 2 samples"):
        recordings["px4"].slice(500)
