"""The shared logs without a GPS position, replayed on the field measured from the compass: none refused."""

from __future__ import annotations

import re
from pathlib import Path

import pytest

from mavattitude.cli import main
from tests.commands.test_replay_logs import summary
from tests.shared import shared_path

EXAMPLE_CONFIG = Path(__file__).resolve().parents[2] / "configs" / "ardupilot.yaml"
MEASURED = re.compile(r"measured: dip (-?[\d.]+)°, ([\d.]+) µT, magnetic north")


def measured(row: dict[str, str]) -> tuple[float, float]:
    """The dip and |B| of a summary row's reference, which must be the measured field and only that."""
    found = MEASURED.fullmatch(row["reference"])
    assert found, row["reference"]
    return float(found[1]), float(found[2])


def test_the_gps_less_sitl_flight_with_the_example_config(tmp_path, capsys):
    """nogps.BIN, the example config and no flags: the field measured, fused within the targets of the
    autopilot's ATT (whose yaw is magnetic there too: COMPASS_DEC stayed 0)."""
    flight = shared_path("data", "ardupilot-sitl", "nogps.BIN")
    out = tmp_path / "out"
    assert main(["replay", str(flight), "-o", str(out), "--config", str(EXAMPLE_CONFIG), "--method", "fused"]) == 0
    said = [line for line in capsys.readouterr().err.splitlines() if "no GPS position" in line]
    # said once, of the replayed compass, naming the log: the log's two other compasses, judged beside it, each
    # measure a field of their own without saying so (their verdicts are the summary's compasses column)
    assert len(said) == 1 and f"{flight}: no GPS position: heading is magnetic north" in said[0]
    row = summary(out / "summary.csv")["nogps.BIN"]
    dip, intensity = measured(row)
    # the simulator's field is the WMM's at CMAC (README: inclination −65.77°, 58.0 µT); SITL's compass is exact
    # but for its noise, and the vehicle sat still for the 5 s measured
    assert dip == pytest.approx(-65.77, abs=0.5) and intensity == pytest.approx(58.0, abs=0.5)
    # the targets (roll / pitch within 1.5° RMS of ATT, itself 0.8° from the truth; heading within 5°); measured
    # 1.21 / 1.23°, yaw 1.78° with the filter started when the field was measured; 1.12 / 1.06°, 1.64° with it
    # tracking the tilt while the field is measured
    assert float(row["roll_rms_deg"]) <= 1.5 and float(row["pitch_rms_deg"]) <= 1.5
    assert float(row["yaw_rms_deg"]) <= 5.0


def test_the_other_shared_logs_without_a_position_are_replayed(tmp_path):
    """nogps.tlog (GPS_RAW_INT all fix_type 0, GLOBAL_POSITION_INT all 0), the ArduSub dive (no fix, RAW_IMU at
    2 Hz) and the PX4 sample (no position): each on the field its compass measured, none refused."""
    logs = [
        shared_path("data", "ardupilot-sitl", "nogps.tlog"),
        shared_path("data", "real", "ardusub41_2023-04-18.tlog"),
        shared_path("data", "px4", "sample.ulg"),
    ]
    out = tmp_path / "out"
    assert main(["replay", *map(str, logs), "-o", str(out), "--no-plot"]) == 0
    table = summary(out / "summary.csv")
    assert {row["status"] for row in table.values()} == {"ok"}
    dip, intensity = measured(table["nogps.tlog"])
    assert dip == pytest.approx(-65.77, abs=0.5) and intensity == pytest.approx(58.0, abs=0.5)  # as the .BIN
    # the dive's compass reads |B| 751 ± 36 mG (its README): the quiet mean lies within that spread
    assert measured(table["ardusub41_2023-04-18.tlog"])[1] == pytest.approx(75.1, abs=3.6)
    measured(table["sample.ulg"])


def test_the_fused_filter_waits_for_the_measured_field_on_a_tracked_tilt(tmp_path):
    """PX4's sample: a board moved by hand for its first 6 s, then still. The field is measured 5 s in, mid-motion;
    the filter ran on roll and pitch alone meanwhile, so the field only gives it a heading. Started from a snapshot
    there instead (as before), it was 1.07 / 0.40° roll / pitch and 3.24° yaw RMS from the autopilot, settling over
    ~40 s; with the field given by hand, 0.12 / 0.12 / 0.33° (the filter then starts at rest, 5 s earlier)."""
    out = tmp_path / "out"
    log = shared_path("data", "px4", "sample.ulg")
    assert main(["replay", str(log), "-o", str(out), "--method", "fused", "--no-plot"]) == 0
    row = summary(out / "summary.csv")["sample.ulg"]
    measured(row)
    # the tilt within IGN's on this log (0.12 / 0.13°: the board at rest after 6 s, where a snapshot is as good as it
    # gets), the heading within the given-field run's 0.33° plus a fifth; measured 0.04 / 0.08°, yaw 0.25°
    assert float(row["roll_rms_deg"]) <= 0.15 and float(row["pitch_rms_deg"]) <= 0.15
    assert float(row["yaw_rms_deg"]) <= 0.4
