"""The autopilot's level trim on a real log: ArduPilot's attitude is of the vehicle's frame, its IMU readings of
the board's, and the two differ by AHRS_TRIM_X/Y, which ``replay`` reads from the log's parameters."""

from __future__ import annotations

import csv
from pathlib import Path

import yaml

from mavattitude.cli import main
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
    assert trimmed["yaw_rms_deg"] == untrimmed["yaw_rms_deg"]  # a roll and pitch trim: the heading is the same
