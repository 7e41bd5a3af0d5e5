"""`replay` at whatever rates a log has: every autopilot attitude inside our output span compared, or why not."""

from __future__ import annotations

import csv
from pathlib import Path

import numpy as np
import pytest

from mavattitude.cli import main
from mavattitude.estimation.conventions import quat_from_euler, rotate_ned_to_body
from mavattitude.link.logstreams import TILT_ONLY
from mavattitude.sensors.magref import field_from_angles
from mavattitude.sim.logwriter import SensorLog, static_log, write_dataflash, write_tlog
from tests.shared import shared_path

CONFIG = Path(__file__).resolve().parents[2] / "configs" / "ardupilot.yaml"
MIN_SHARE_PCT = 95.0  # the target: the autopilot's attitudes inside our output span that are compared
REF = ["--declination", "0", "--inclination", "63.5"]  # static_log's field, magnetic north


def summary_row(out: Path) -> dict[str, str]:
    with (out / "summary.csv").open(encoding="utf-8") as f:
        (row,) = csv.DictReader(f)
    return row


def replay_dir(tmp_path: Path, log: Path, *args: str) -> dict[str, str]:
    """One log replayed into a directory (its summary row: the columns this file checks)."""
    out = tmp_path / "out"
    main(["replay", str(log), "-o", str(out), "--config", str(CONFIG), "--no-plot", *args])
    return summary_row(out)


def test_ours_starting_at_the_first_gps_fix_still_pair_every_later_autopilot_attitude(tmp_path):
    """twocompass.tlog: ATTITUDE at 50 Hz from the start, ours from the GPS position on; only 250 were compared
    when the replay's pairing ran one output ahead per autopilot attitude before our first."""
    row = replay_dir(tmp_path, shared_path("data", "ardupilot-sitl", "twocompass.tlog"))
    assert float(row["compared_pct"]) >= MIN_SHARE_PCT and int(row["compared"]) > 10_000


def low_rate_log(seconds: float = 60.0, yaw_rate_dps: float = 10.0, seed: int = 1) -> SensorLog:
    """static_log's turning vehicle as a ground station records it by default: RAW_IMU at 2 Hz (its compass in
    every message), each 0.5 s apart ± 30 ms (many intervals longer than input_timeout_s, 0.5 s)."""
    log = static_log(seconds, imu_rate_hz=2.0, mag_rate_hz=2.0, yaw_rate_dps=yaw_rate_dps)
    jitter = np.random.default_rng(seed).uniform(-0.03, 0.03, len(log.imu_t_s))
    log.imu_t_s = log.imu_t_s + 0.013 + jitter  # off the 50 Hz grid
    log.mag_t_s = log.imu_t_s.copy()
    log.mag_uT = _turned_field(log.mag_t_s, yaw_rate_dps)
    log.gyr_radps = np.tile([0.0, 0.0, np.radians(yaw_rate_dps)], (len(log.imu_t_s), 1))
    return log


def _turned_field(t_s: np.ndarray, yaw_rate_dps: float) -> np.ndarray:
    """static_log's field (48 µT, 63.5° inclination) in the body of a vehicle level at yaw rate × (t − 1 s)."""
    inc, yaw = np.radians(63.5), np.radians(yaw_rate_dps) * (t_s - 1.0)
    north, down = 48.0 * np.cos(inc), 48.0 * np.sin(inc)
    return np.column_stack([np.cos(yaw) * north, -np.sin(yaw) * north, np.full(len(t_s), down)])


@pytest.mark.parametrize("method", ["ign", "fused"])
def test_a_low_rate_telemetry_log_gives_one_attitude_per_sample_compared_at_both_rates(tmp_path, method):
    log = low_rate_log()
    path = write_tlog(tmp_path / "slow.tlog", log)
    row = replay_dir(tmp_path, path, "--method", method, *REF)
    # the first sample, its pace unknown, starts a filtered stream: no 50 Hz tick (ign) or the filter's first
    assert row["status"] == "ok" and int(row["outputs"]) >= len(log.imu_t_s) - 1
    slow = "one attitude per sample"
    if method == "fused":
        slow = "too slow to integrate the gyro: one IGN attitude per sample"
    assert row["rate_handling"] == f"RAW_IMU at 2.0 Hz: {slow}, no filtering"
    assert float(row["compared_pct"]) == 100.0 and row["not_compared"] == ""
    # noise-free, the compass read with each sample: heading to the int16 milligauss rounding (0.15°), ATT's
    # float32 degrees and our interpolation between two outputs 0.5 s apart in a 10°/s turn (chord: ~1e-3°)
    assert max(float(row[f"{a}_p99_deg"]) for a in ("roll", "pitch", "yaw")) < 0.3


@pytest.mark.parametrize("method", ["ign", "fused"])
def test_the_shared_low_rate_logs_are_processed_per_sample_and_compared_at_their_rates(tmp_path, method):
    """lowrate.tlog (SITL, RAW_IMU 2 Hz, ATTITUDE 4 Hz, 60°/s turns) and a real ArduSub dive (RAW_IMU 2 Hz,
    ATTITUDE 20 Hz, no GPS: the field given): one attitude per sample, nearly all of the autopilot's compared."""
    sitl = replay_dir(tmp_path / "sitl", shared_path("data", "ardupilot-sitl", "lowrate.tlog"), "--method", method)
    sub = replay_dir(
        tmp_path / "sub",
        shared_path("data", "real", "ardusub41_2023-04-18.tlog"),
        *("--method", method, "--declination", "0", "--inclination", "60"),
    )
    for row in (sitl, sub):
        assert row["status"] == "ok" and row["rate_handling"].startswith("RAW_IMU at 2.0 Hz: ")
        assert "attitude per sample, no filtering" in row["rate_handling"]
        assert float(row["compared_pct"]) >= MIN_SHARE_PCT
    assert int(sitl["compared"]) > 700 and int(sub["compared"]) > 6000  # 4 Hz over 185 s, 20 Hz over 313 s


def tilted_without_compass(kind: str) -> SensorLog:
    """static_log's vehicle held at 10° of roll, still, with no GPS: ``kind`` "none" has no magnetometer
    records, "zero" has them all reading zero (an autopilot that logs a compass it does not have)."""
    log = static_log(20.0, imu_rate_hz=50.0)
    roll = np.radians(10.0)
    log.acc_mps2 = np.tile([0.0, -9.80665 * np.sin(roll), -9.80665 * np.cos(roll)], (len(log.imu_t_s), 1))
    log.attitude_rpy_rad[:, 0] = roll
    log.position_t_s = log.position = None
    if kind == "none":
        log.mag_t_s, log.mag_uT = np.empty(0), np.empty((0, 3))
    else:
        log.mag_uT = np.zeros_like(log.mag_uT)
    return log


@pytest.mark.parametrize("method", ["ign", "fused"])
def test_a_log_without_a_compass_gives_roll_and_pitch_with_the_heading_unknown(tmp_path, capsys, method):
    """Never a refusal of a log that has an IMU: no MAG records, MAG all zero (.bin), RAW_IMU's magnetometer all
    zero (.tlog), no GPS either (reference.magnetic auto: no field is needed for roll and pitch)."""
    logs = [
        write_dataflash(tmp_path / "none.bin", tilted_without_compass("none")),
        write_dataflash(tmp_path / "zero.bin", tilted_without_compass("zero")),
        write_tlog(tmp_path / "zero.tlog", tilted_without_compass("zero")),
    ]
    out = tmp_path / "out"
    main(["replay", *map(str, logs), "-o", str(out), "--config", str(CONFIG), "--method", method, "--no-plot"])
    with (out / "summary.csv").open(encoding="utf-8") as f:
        rows = list(csv.DictReader(f))
    said = [line for line in capsys.readouterr().err.splitlines() if TILT_ONLY in line]
    assert [next(str(p) for p in logs if f" {p}: " in line) for line in said] == list(map(str, logs))  # one each
    for log, row in zip(logs, rows, strict=True):
        assert row["status"] == "ok" and row["heading"] == "unknown: no magnetometer", row
        # the first input_timeout_s (0.5 s) waits for a compass reading: 25 of the 1000 samples
        assert int(row["outputs"]) >= 950 and float(row["compared_pct"]) == 100.0
        assert row["yaw_rms_deg"] == "nan" and row["not_compared"] == ""
        # still and noise-free: the accelerometer's roll, to RAW_IMU's milli-g integers (0.5 mG of 985: 0.03°)
        assert float(row["roll_p99_deg"]) < 0.05 and float(row["pitch_p99_deg"]) < 0.05
        written = np.genfromtxt(out / f"{log.name}.csv", delimiter=",", names=True)  # two logs named zero
        assert np.all(np.isnan(written["yaw_deg"])) and np.allclose(written["roll_deg"], 10.0, atol=0.05)
        assert np.all(written["cov_zz_rad2"] > 1.0)  # a heading uniform over ±180°: (π/√3)² = 3.3 rad²


def test_a_vehicle_upside_down_differs_from_its_autopilot_by_degrees_not_by_a_turn(tmp_path):
    """Ours at roll +179.5°, the autopilot's at −179.7° (the other side of ±180°): 0.8° apart in the summary,
    not 359.2°."""
    log = static_log(5.0, imu_rate_hz=50.0)
    q = quat_from_euler(np.radians(179.5), 0.0, 0.0)
    field = field_from_angles(0.0, 63.5, 48.0)  # static_log's field
    log.acc_mps2 = np.tile(rotate_ned_to_body(q, [0.0, 0.0, -9.80665]), (len(log.imu_t_s), 1))
    log.mag_uT = np.tile(rotate_ned_to_body(q, field), (len(log.mag_t_s), 1))
    log.gyr_radps = np.zeros_like(log.gyr_radps)
    log.attitude_rpy_rad = np.tile([np.radians(-179.7), 0.0, 0.0], (len(log.attitude_t_s), 1))
    row = replay_dir(tmp_path, write_dataflash(tmp_path / "inverted.bin", log), *REF)
    # noise-free: ours is the truth to the logged rounding (float32 acceleration, ATT's float32 degrees: 1e-5°)
    assert float(row["roll_p99_deg"]) == pytest.approx(0.8, abs=0.01)
    assert float(row["roll_rms_deg"]) == pytest.approx(0.8, abs=0.01)
    assert float(row["yaw_p99_deg"]) < 0.2  # MAG's integer milligauss: 0.05 µT of 21 µT horizontal, 0.15°


def test_the_compasses_of_a_2_hz_stream_are_judged(tmp_path, capsys):
    """The real ArduSub dive, RAW_IMU and SCALED_IMU2 at 2 Hz: a 10 s window holds 20 quiet samples, fewer than
    a judgement needs, so its compasses went unjudged (and were called ok). Judged over their last 25, both are
    found off when the sub holds 40° nose down from 504 s: the dip 10° (compass 0) and 13° (compass 1, whose
    window's samples turning about the vertical are not taken) lower, |B| 17 and 22 % less than at the start,
    which no calibrated compass shows under a turn (docs/vehicle.md)."""
    row = replay_dir(tmp_path, shared_path("data", "real", "ardusub41_2023-04-18.tlog"))
    assert row["compasses"] == (
        "0 |B| off: calibration, magnet?; 1 dip off: mounted or calibrated wrongly?, |B| off: calibration, magnet?"
    )
    warned = [line for line in capsys.readouterr().err.splitlines() if "magnetometer 0: t=" in line]
    # the 25 quiet samples' window must first hold enough of the nose-down spell: within 12.5 s of its start
    assert len(warned) == 1 and 504.0 < float(warned[0].split("t=")[1].split(" s")[0]) < 504.0 + 12.5
