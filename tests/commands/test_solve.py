"""`mavattitude solve`: CSV in, attitude CSV out, through the service's pipeline; flags over config."""

from __future__ import annotations

import csv
import gzip
import io
import re
import warnings
from pathlib import Path

import numpy as np
import pytest
import yaml

from mavattitude.cli import main
from mavattitude.commands._offline import OUTPUT_COLUMNS, Progress
from mavattitude.config import ENV_VAR, load_config
from mavattitude.estimation.conventions import angle_between, euler_from_quat, quat_from_euler, rotate_ned_to_body
from mavattitude.sensors.magref import field_from_angles
from tests.commands.process import run_cli
from tests.shared import shared_path

G = 9.80665
Q_TRUE = quat_from_euler(np.radians(-5.0), np.radians(30.0), np.radians(-100.0))
DECL, INCL, F_UT = 3.0, 55.0, 48.0
REF = ["--declination", str(DECL), "--inclination", str(INCL)]
ACC_STD, MAG_STD = 0.05, 0.5  # the config's default σ, used to draw the noise
# Per-sample heading σ: magnetometer 0.5 µT / (48 µT cos 55°) = 1.04°, and the tilt error (0.05 / 9.81 rad =
# 0.29°) × tan 55° = 0.42°: 1.12° together. The 10 Hz Butterworth passes 11.1 Hz of the 50 Hz input band
# (100 Hz input): σ × 0.47 ≈ 0.53°. Bound: 4σ.
MAX_ERR_DEG = 2.1


def write_csv(
    path: Path,
    n: int = 200,
    rate_hz: float = 100.0,
    gyro: bool = True,
    extra: bool = False,
    units: tuple[float, float] = (1.0, 1.0),
) -> Path:
    """A vehicle at rest at Q_TRUE, seeded sensor noise; columns shuffled, optionally extra ones; ``units``: the
    accelerometer's in m/s² and the magnetometer's in µT (the file's numbers divided by them)."""
    rng = np.random.default_rng(7)
    t = 5.0 + np.arange(n) / rate_hz
    acc = rotate_ned_to_body(Q_TRUE, [0.0, 0.0, -G]) + rng.normal(0, ACC_STD, (n, 3))
    mag = rotate_ned_to_body(Q_TRUE, field_from_angles(DECL, INCL, F_UT)) + rng.normal(0, MAG_STD, (n, 3))
    cols = {"t_s": t}
    cols |= {f"mag_{a}_uT": mag[:, i] / units[1] for i, a in enumerate("xyz")}
    cols |= {f"acc_{a}_mps2": acc[:, i] / units[0] for i, a in enumerate("xyz")}
    if gyro:
        cols |= {f"gyr_{a}_radps": rng.normal(0, 1e-3, n) for a in "xyz"}
    if extra:
        cols["note"] = np.arange(n)
    opener = gzip.open if path.suffix == ".gz" else open
    with opener(path, "wt", newline="") as f:
        w = csv.writer(f)
        w.writerow(cols)
        w.writerows(zip(*cols.values(), strict=True))
    return path


def read_output(path: Path) -> tuple[list[str], np.ndarray]:
    opener = gzip.open if path.suffix == ".gz" else open
    with opener(path, "rt") as f:
        header = f.readline().strip().split(",")
        return header, np.loadtxt(f, delimiter=",", ndmin=2)


def test_solve_writes_the_documented_columns(tmp_path):
    out = tmp_path / "out.csv"
    assert main(["solve", str(write_csv(tmp_path / "in.csv", extra=True)), "-o", str(out), *REF]) == 0
    header, rows = read_output(out)
    assert tuple(header) == OUTPUT_COLUMNS
    assert len(rows) == 100  # 2 s at 100 Hz → 50 Hz ticks 5.00 … 6.98 s
    assert np.allclose(np.diff(rows[:, 0]), 0.02)
    q = rows[:, 1:5]
    assert np.allclose(np.linalg.norm(q, axis=1), 1.0, atol=1e-8)  # 9 decimals written
    assert np.degrees(angle_between(q[10:], Q_TRUE)).max() < MAX_ERR_DEG
    assert np.allclose(rows[:, 5:8], np.degrees(euler_from_quat(q)), atol=1e-3)  # 4 decimals written
    assert set(rows[:, 9]) == {1.0}
    assert np.all(rows[:, 8] == np.round(rows[:, 8]))
    variances = rows[:, [10, 13, 15]]  # cov_xx, cov_yy, cov_zz: rad², body frame
    assert np.all(variances > 0.0) and np.sqrt(variances).max() < np.radians(5.0)


@pytest.mark.parametrize("method", ["ign", "fused"])
def test_without_a_reference_the_field_is_measured_from_the_compass_after_the_wait(tmp_path, capsys, method):
    """The default ``reference.magnetic: auto`` on a CSV (no position): replay's rule for a log without GPS. The
    measured field has no declination, so the answer is the true attitude turned to magnetic north."""
    out = tmp_path / "out.csv"
    assert main(["solve", str(write_csv(tmp_path / "in.csv", n=1000)), "-o", str(out), "--method", method]) == 0
    said = re.search(r"field measured from the compass: dip ([\d.]+)°, ([\d.]+) µT", capsys.readouterr().err)
    dip, intensity = float(said[1]), float(said[2])
    # the mean of ≥ 25 quiet ticks of a 0.5 µT noise on 48 µT: within 0.1° and 0.2 µT
    assert dip == pytest.approx(INCL, abs=0.1) and intensity == pytest.approx(F_UT, abs=0.2)
    _, rows = read_output(out)
    assert rows[0, 0] >= 10.0 and len(rows) >= 200  # the samples start at 5 s, the field after 5 s more
    q_magnetic = quat_from_euler(np.radians(-5.0), np.radians(30.0), np.radians(-100.0 - DECL))
    assert np.degrees(angle_between(rows[10:, 1:5], q_magnetic)).max() < MAX_ERR_DEG


def test_a_time_column_in_milliseconds_shows_as_a_slow_input_in_plain_words(tmp_path, capsys):
    """Times written in ms instead of s: 100 Hz samples read as 0.1 Hz. Solve says the rate it read and what it
    did at it, and the compass line gives a spread, not ``nan``: the window keeps the last 25 quiet samples of a
    stream too slow to have them in its 10 s (250 s here), not the one sample 10 s would hold."""
    src = write_csv(tmp_path / "in.csv", n=50)
    lines = src.read_text().splitlines()
    header = lines[0].split(",")
    column = header.index("t_s")
    rows = [line.split(",") for line in lines[1:]]
    for row in rows:
        row[column] = repr(float(row[column]) * 1000.0)
    src.write_text("\n".join([lines[0], *(",".join(r) for r in rows)]) + "\n")
    assert main(["solve", str(src), "-o", str(tmp_path / "o.csv"), *REF]) == 0
    err = capsys.readouterr().err
    assert "samples at 0.1 Hz: one attitude per sample, no filtering" in err
    # and what the rate would be if t_s were in ms or µs, said first (100 Hz written, read 1000× slower)
    assert (
        "t_s advances 10 s a sample (0.1 Hz): t_s must be in seconds; in milliseconds the samples would be at 100 Hz"
    ) in err
    assert "nan" not in err and re.search(r"compass: dip [-\d.]+° \(spread [\d.]+°", err), err


def test_one_sample_is_solved_and_its_unknown_rate_said_in_words(tmp_path, capsys):
    src = write_csv(tmp_path / "in.csv", n=1)
    assert main(["solve", str(src), "-o", str(tmp_path / "o.csv"), *REF]) == 0
    err = capsys.readouterr().err
    assert "samples at a rate unknown (one sample)" in err and "nan" not in err


def test_gzip_in_and_out_and_no_gyro_columns(tmp_path):
    out = tmp_path / "out.csv.gz"
    src = write_csv(tmp_path / "in.csv.gz", gyro=False)
    assert main(["solve", str(src), "-o", str(out), *REF]) == 0
    header, rows = read_output(out)
    assert tuple(header) == OUTPUT_COLUMNS and len(rows) == 100


def test_no_filter_solves_every_row(tmp_path):
    out = tmp_path / "out.csv"
    assert main(["solve", str(write_csv(tmp_path / "in.csv", n=37)), "-o", str(out), *REF, "--no-filter"]) == 0
    _, rows = read_output(out)
    assert np.allclose(rows[:, 0], 5.0 + np.arange(37) / 100.0)


def test_the_reference_as_a_vector_equals_the_angles(tmp_path):
    src = write_csv(tmp_path / "in.csv")
    a, b = tmp_path / "a.csv", tmp_path / "b.csv"
    vector = [f"{v:.12f}" for v in field_from_angles(DECL, INCL, F_UT)]
    assert main(["solve", str(src), "-o", str(a), *REF]) == 0
    assert main(["solve", str(src), "-o", str(b), "--mag-ref-ned", *vector]) == 0
    # Same field direction; only the |B| screening differs (on for the vector, off for angles alone).
    assert np.allclose(read_output(a)[1][:, 1:5], read_output(b)[1][:, 1:5], atol=2e-9)


def test_flags_override_the_env_file_which_overrides_the_config_file(tmp_path, monkeypatch):
    src = write_csv(tmp_path / "in.csv")
    config = tmp_path / "c.yaml"
    config.write_text(yaml.safe_dump({"estimator": {"method": "cgn"}, "filter": {"enabled": False}}))
    site = tmp_path / "site.yaml"
    site.write_text(yaml.safe_dump({"estimator": {"method": "triad"}}))
    out = tmp_path / "out.csv"

    def iterations(*flags: str) -> np.ndarray:
        assert main(["solve", str(src), "-o", str(out), *REF, "--config", str(config), *flags]) == 0
        return read_output(out)[1]

    rows = iterations()
    assert len(rows) == 200 and rows[:, 8].max() > 0  # the file: cgn iterates, no filter
    monkeypatch.setenv(ENV_VAR, str(site))
    assert iterations()[:, 8].max() == 0  # the env file: triad, closed form
    rows = iterations("--method", "ign", "--filter")
    assert rows[:, 8].max() > 0 and len(rows) == 100  # the flags: ign, filtered


def test_the_fused_filter_runs_from_the_command_line(tmp_path):
    out = tmp_path / "out.csv"
    assert main(["solve", str(write_csv(tmp_path / "in.csv")), "-o", str(out), *REF, "--method", "fused"]) == 0
    _, rows = read_output(out)
    assert len(rows) > 50 and np.degrees(angle_between(rows[-1, 1:5], Q_TRUE)) < MAX_ERR_DEG


def test_the_learnt_offset_is_saved_as_a_calibration_the_config_reads(tmp_path):
    """At rest nothing is learnt: the file holds the config's own calibration, in the `calibrate` format."""
    out, cal = tmp_path / "out.csv", tmp_path / "cal.yaml"
    args = ["solve", str(write_csv(tmp_path / "in.csv")), "-o", str(out), *REF, "--method", "fused"]
    assert main([*args, "--save-mag-offset", str(cal)]) == 0
    config = load_config(cal, env={})
    assert config.calibration.mag.hard_iron_uT == (0.0, 0.0, 0.0)
    assert "learnt by `mavattitude solve --method fused`" in cal.read_text(encoding="utf-8")


def test_fused_needs_gyro_columns(tmp_path, capsys):
    src = write_csv(tmp_path / "in.csv", gyro=False)
    assert main(["solve", str(src), "-o", str(tmp_path / "o.csv"), *REF, "--method", "fused"]) == 2
    assert "fused needs a gyroscope" in capsys.readouterr().err


def test_accel_and_mag_std_take_one_or_three_values(tmp_path):
    src, out = write_csv(tmp_path / "in.csv"), tmp_path / "out.csv"
    assert main(["solve", str(src), "-o", str(out), *REF, "--accel-std", "0.1", "--mag-std", "0.2,0.2,0.4"]) == 0
    with pytest.raises(SystemExit) as exc:
        main(["solve", str(src), "-o", str(out), *REF, "--mag-std", "0.2,0.4"])
    assert exc.value.code == 2


@pytest.mark.parametrize(
    ("make_args", "message"),
    [
        (lambda src, out: [src, "-o", out, "--declination", "3"], r"--declination and --inclination go together"),
        (lambda src, out: [src, "-o", out, *REF, "--accel-std", "-1"], r"noise\.accel_std_mps2: -1.0 is out of range"),
        (lambda src, out: [src + ".missing", "-o", out, *REF], r"cannot open"),
        (
            lambda src, out: [src, "-o", out, *REF, "--method", "fused", "--mag-std", "0.3"],
            r"noise\.mag_std_uT: not used by estimator\.method fused.*estimator\.fused\.mag_std_uT",
        ),
        (lambda src, out: [src, "-o", out, *REF, "--save-mag-offset", out + ".yaml"], r"needs --method fused"),
    ],
)
def test_user_mistakes_are_one_line_and_exit_2(tmp_path, capsys, make_args, message):
    src = str(write_csv(tmp_path / "in.csv"))
    assert main(["solve", *make_args(src, str(tmp_path / "out.csv"))]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("mavattitude solve: error: ")
    assert re.search(message, err[0])


def test_missing_columns_are_named(tmp_path, capsys):
    bad = tmp_path / "bad.csv"
    bad.write_text("t_s,acc_x_mps2,acc_y_mps2,acc_z_mps2,mag_x_uT\n0,0,0,-9.8,20\n")
    assert main(["solve", str(bad), "-o", str(tmp_path / "o.csv"), *REF]) == 2
    assert "missing column(s) mag_y_uT, mag_z_uT" in capsys.readouterr().err


def test_a_spreadsheets_export_with_a_byte_order_mark_is_read_as_the_plain_file(tmp_path):
    """Excel's "CSV UTF-8" begins with a BOM, which made the first column's name "\ufefft_s", a missing t_s."""
    plain = write_csv(tmp_path / "plain.csv")
    marked = tmp_path / "marked.csv"
    marked.write_bytes(b"\xef\xbb\xbf" + plain.read_bytes())
    for src in (plain, marked):
        assert main(["solve", str(src), "-o", str(tmp_path / f"{src.stem}.out.csv"), *REF]) == 0
    assert (tmp_path / "marked.out.csv").read_bytes() == (tmp_path / "plain.out.csv").read_bytes()


@pytest.mark.parametrize("separator", [";", "\t"])
def test_a_file_separated_otherwise_is_told_what_to_change(tmp_path, capsys, separator):
    src = write_csv(tmp_path / "in.csv")
    src.write_text(src.read_text().replace(",", separator))
    assert main(["solve", str(src), "-o", str(tmp_path / "o.csv"), *REF]) == 2
    assert f"columns are separated by commas, and this header by {separator!r}" in capsys.readouterr().err


@pytest.mark.parametrize(
    ("cell", "said"), [("x", "'x' is not a number"), ("", "empty (write nan for a missing value)")]
)
def test_a_bad_row_is_named_by_the_files_own_line_number_and_column(tmp_path, capsys, cell, said):
    src = write_csv(tmp_path / "in.csv", n=20)
    lines = src.read_text().splitlines()
    fields = lines[5].split(",")
    lines[5] = ",".join([fields[0], cell, *fields[2:]])  # line 6 of the file (header = line 1)
    lines.insert(3, "")  # a blank line 4: counted by an editor, skipped by numpy
    src.write_text("\n".join(lines) + "\n")
    assert main(["solve", str(src), "-o", str(tmp_path / "o.csv"), *REF]) == 2
    err = capsys.readouterr().err.splitlines()
    column = lines[0].split(",")[1]
    assert err == [f"mavattitude solve: error: {src}:7: column {column}: {said}"]


def test_a_header_only_file_is_refused_without_a_numpy_warning(tmp_path, capsys):
    src = tmp_path / "empty.csv"
    src.write_text("t_s,acc_x_mps2,acc_y_mps2,acc_z_mps2,mag_x_uT,mag_y_uT,mag_z_uT\n")
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert main(["solve", str(src), "-o", str(tmp_path / "o.csv"), *REF]) == 2
    assert capsys.readouterr().err.splitlines() == [f"mavattitude solve: error: {src}: no data rows"]


def test_nothing_solvable_is_a_failure(tmp_path, capsys):
    bad = tmp_path / "collinear.csv"
    rows = [f"{i / 100},0,0,-9.8,0,0,-40" for i in range(100)]  # field along gravity: degenerate
    bad.write_text("t_s,acc_x_mps2,acc_y_mps2,acc_z_mps2,mag_x_uT,mag_y_uT,mag_z_uT\n" + "\n".join(rows) + "\n")
    assert main(["solve", str(bad), "-o", str(tmp_path / "o.csv"), *REF]) == 2
    assert "no attitude could be computed ({'DegenerateGeometryError': 50})" in capsys.readouterr().err


def test_an_input_shorter_than_the_wait_for_a_position_is_a_failure_that_says_what_to_give(tmp_path, capsys):
    out = tmp_path / "o.csv"
    assert main(["solve", str(write_csv(tmp_path / "in.csv")), "-o", str(out)]) == 2  # 2 s of samples
    assert re.search(
        r"error: .*in\.csv: reference\.magnetic is auto, the input holds no position with a fix, and no field was "
        r"measured from its compass \(5 s of reference\.position_wait_s .* give --declination DEG --inclination DEG",
        capsys.readouterr().err,
    )
    assert not out.exists()


def test_an_accelerometer_in_g_is_said_as_the_cause_when_no_field_is_measured(tmp_path, capsys):
    """acc_*_mps2 written in g: 0.102 g at rest, so the vehicle never reads as still and no field is measured
    without a reference: the warning names the slip and the columns, the error leads with it."""
    src = write_csv(tmp_path / "in.csv", n=1000, units=(G, 1.0))  # 10 s
    assert main(["solve", str(src), "-o", str(tmp_path / "o.csv")]) == 2
    err = capsys.readouterr().err
    assert (
        "t=10.0 s: accelerometer: its median |f| over the first 5 s is 0.102 g, where a vehicle's is about 1 g "
        "(readings in g taken for m/s²?): wrong units: check the CSV's acc_*_mps2 columns, read as m/s²"
    ) in err
    assert "wrong units, so the vehicle never read as still: fix them (the warning above), or give --declination" in err


def test_a_magnetometer_in_milligauss_is_said_and_still_solved(tmp_path, capsys):
    """mag_*_uT written in milligauss (10× the µT): a snapshot solve reads only its direction, so the attitude is
    right, but its weight against the accelerometer is not (Eq. 21): said, with the columns to check."""
    out = tmp_path / "o.csv"
    assert main(["solve", str(write_csv(tmp_path / "in.csv", n=700, units=(1.0, 0.1))), "-o", str(out), *REF]) == 0
    assert (
        "magnetometer: its median |B| over the first 5 s is 480 µT, where the Earth's is 22-67 µT: wrong units "
        "(readings in gauss (100 µT) or milligauss (0.1 µT)?): check the CSV's mag_*_uT, read as µT"
    ) in capsys.readouterr().err
    _, rows = read_output(out)
    assert np.degrees(angle_between(rows[10:, 1:5], Q_TRUE)).max() < MAX_ERR_DEG


def test_progress_goes_to_stderr(tmp_path, capsys):
    assert main(["solve", str(write_csv(tmp_path / "in.csv")), "-o", str(tmp_path / "o.csv"), *REF, "--progress"]) == 0
    captured = capsys.readouterr()
    assert "solve in.csv, output ticks: [####################] 100% 100/100" in captured.err  # 2 s at 50 Hz
    assert captured.out == ""


class _Terminal(io.StringIO):
    def isatty(self) -> bool:
        return True


@pytest.mark.parametrize("stream", [io.StringIO, _Terminal])
def test_the_progress_bar_is_redrawn_each_percent_on_a_terminal_and_each_10_percent_elsewhere(stream):
    out = stream()
    progress = Progress("x", stream=out)
    for done in range(1, 401):
        progress(done, 400)
    text = out.getvalue()
    assert text.endswith("\n") and "100% 400/400" in text.splitlines()[-1]
    if stream is _Terminal:
        assert text.count("\r") == 101 and text.count("\n") == 1  # 0 % … 100 %, one line
    else:
        assert "\r" not in text and [re.search(r"(\d+)%", line)[1] for line in text.splitlines()] == [
            str(p) for p in range(0, 101, 10)
        ]


def _measured_inclination_deg(acc: np.ndarray, mag: np.ndarray) -> float:
    """Dip of the field below the horizontal, from the mean vectors of a rest period."""
    a, m = acc.mean(0), mag.mean(0)
    return float(np.degrees(np.arcsin(-(a @ m) / np.linalg.norm(a) / np.linalg.norm(m))))


def test_real_px4_log_as_a_subprocess_agrees_with_the_autopilot(tmp_path):
    px4_csv = shared_path("data", "px4", "px4_sample_sensors.csv.gz")
    with gzip.open(px4_csv, "rt") as f:
        header = f.readline().strip().split(",")
        data = np.loadtxt(f, delimiter=",")
    col = {name: data[:, i] for i, name in enumerate(header)}
    first_s = col["t_s"] < col["t_s"][0] + 1.0  # the bench log starts at rest
    acc = np.stack([col[f"acc_{a}_mps2"] for a in "xyz"], 1)[first_s]
    mag = np.stack([col[f"mag_{a}_uT"] for a in "xyz"], 1)[first_s]
    out = tmp_path / "px4.csv"
    # The onboard estimator ran with declination 0: its yaw is magnetic, so is ours.
    args = ["solve", str(px4_csv), "-o", str(out), "--declination", "0", "--inclination"]
    args.append(f"{_measured_inclination_deg(acc, mag):.3f}")
    done = run_cli(args)
    assert done.returncode == 0, done.stderr
    _, rows = read_output(out)
    assert len(rows) == pytest.approx(69 * 50, rel=0.01)  # 69 s at 50 Hz
    att = np.stack([np.interp(rows[:, 0], col["t_s"], col[f"att_q{k}"]) for k in "wxyz"], 1)
    diff = rows[:, 5:8] - np.degrees(euler_from_quat(att / np.linalg.norm(att, axis=1, keepdims=True)))
    diff[:, 2] = (diff[:, 2] + 180.0) % 360.0 - 180.0
    rms_roll, rms_pitch = np.sqrt(np.mean(diff[:, :2] ** 2, axis=0))
    # The data README's per-sample reference (tilt + tilt-compensated heading): 0.60° / 0.41° RMS roll /
    # pitch and a heading spread of 2.2° (std); the filtered pipeline must do at least as well.
    assert rms_roll < 0.60 and rms_pitch < 0.41
    assert np.std(diff[:, 2]) < 2.2
