"""The autopilot's level trim in logs: ArduPilot's attitude is of the vehicle's frame, its IMU readings of the
board's, and the two differ by AHRS_TRIM_X/Y, which ``replay`` reads from the log's parameters (a real dive's
PARAM_VALUE, a DataFlash log's PARM)."""

from __future__ import annotations

import csv
from pathlib import Path

import numpy as np
import pytest
import yaml

from mavattitude.cli import main
from mavattitude.config import load_config
from mavattitude.estimation.conventions import angle_between, quat_from_euler, rotate_ned_to_body
from mavattitude.link.logs import open_log
from mavattitude.replay import replay
from mavattitude.sim.logwriter import static_log, write_dataflash
from tests.shared import shared_path

DIVE = ("data", "real", "ardusub41_2023-04-18.tlog")  # AHRS_TRIM_X 0.0071 rad, AHRS_TRIM_Y 0.0287 rad (1.64°)


def _summary(out: Path, *args: str) -> dict[str, str]:
    # no GPS fix underwater: the field is measured from the compass (the default reference, auto)
    assert main(["replay", str(shared_path(*DIVE)), "-o", str(out), "--no-plot", *args]) == 0
    with (out / "summary.csv").open(encoding="utf-8") as f:
        return next(csv.DictReader(f))


def test_the_dive_s_level_trim_is_applied_and_explains_its_pitch_offset(tmp_path):
    trimmed = _summary(tmp_path / "trimmed")
    off = tmp_path / "off.yaml"
    off.write_text(yaml.safe_dump({"mounting": {"autopilot_trim": False}}), encoding="utf-8")
    untrimmed = _summary(tmp_path / "untrimmed", "--config", str(off))
    assert trimmed["trim_deg"] == "0.41, 1.64" and untrimmed["trim_deg"] == ""
    # Without the trim ours pitches 1.7° from the autopilot's all dive long (RMS 1.76°); with it what is left is
    # the 2 Hz snapshots' own scatter in the thruster-driven motion (0.38°), roll likewise (0.57° → 0.47°).
    assert float(untrimmed["pitch_rms_deg"]) > 1.5 and float(trimmed["pitch_rms_deg"]) < 0.6
    assert float(trimmed["roll_rms_deg"]) < float(untrimmed["roll_rms_deg"])
    # a roll and pitch trim: the heading is the same, but for the yaw angle's second-order share of two small
    # turns (0.41° · 1.64° ≈ 0.01°) and the compass's heading-only samples after its tilted spell (docs/vehicle.md)
    assert float(trimmed["yaw_rms_deg"]) == pytest.approx(float(untrimmed["yaw_rms_deg"]), abs=0.05)


def _board_turned_log(path: Path, trim: dict[str, float]) -> Path:
    """A level vehicle on the ground (its ATT level) whose autopilot board sits rolled 3° and pitched down 6° in
    its frame: the IMU and MAG records are the board's, with the trim ``trim`` in PARM records (or none)."""
    log = static_log(20.0)
    board_in_frame = quat_from_euler(np.radians(3.0), np.radians(-6.0), 0.0)
    log.acc_mps2, log.gyr_radps, log.mag_uT = (
        rotate_ned_to_body(board_in_frame, v) for v in (log.acc_mps2, log.gyr_radps, log.mag_uT)
    )
    return write_dataflash(path, log, parameters=trim)


def test_a_dataflash_log_s_trim_is_read_from_its_parm_records_at_once_and_one_by_one(tmp_path):
    trim = {"AHRS_TRIM_X": float(np.radians(3.0)), "AHRS_TRIM_Y": float(np.radians(-6.0))}
    config = load_config(None, {"reference.magnetic": {"declination_deg": 0, "inclination_deg": 63.5}}, env={})
    with_trim = _board_turned_log(tmp_path / "trim.bin", trim)
    at_once = replay(open_log(with_trim, config), config)
    one_by_one = replay(open_log(with_trim, config), config, at_once=False)
    untrimmed = replay(open_log(_board_turned_log(tmp_path / "none.bin", {}), config), config)
    level = quat_from_euler(0.0, 0.0, 0.0)
    off_deg = [np.degrees(angle_between(r.output_array()[-1, 1:], level)) for r in (at_once, one_by_one, untrimmed)]
    # noise-free but for the MAG records' 0.1 µT steps: ±0.05 µT of a 21.4 µT horizontal field, up to 0.13° of
    # heading; the board is 6.7° off the frame
    assert off_deg[0] < 0.2 and off_deg[1] < 0.2 and off_deg[2] > 6.0
    a, b = at_once.output_array(), one_by_one.output_array()
    assert np.array_equal(a[:, 0], b[:, 0]) and np.max(angle_between(a[:, 1:], b[:, 1:])) < 1e-9
