"""Logs without a GPS position, replayed on the field measured from the compass: the shared ones, none refused,
and the autopilot's declination (a written log) turning it to true north."""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pytest

from mavattitude.cli import main
from mavattitude.commands.replay import Job, replay_log
from mavattitude.config import load_config
from mavattitude.sim.logwriter import static_log, write_dataflash
from tests.commands.test_replay_logs import summary
from tests.shared import shared_path

EXAMPLE_CONFIG = Path(__file__).resolve().parents[2] / "configs" / "ardupilot.yaml"
#: the dip, |B| and north of a measured field: these logs' autopilots never had a fix, their COMPASS_DEC 0 (the
#: ArduPilot logs'), or say no declination (PX4's)
MEASURED = re.compile(
    r"measured: dip (-?[\d.]+)°, ([\d.]+) µT, "
    r"(magnetic north|north as the autopilot's: declination \+0\.0° \(COMPASS_DEC\))"
)


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
    north = "north as the autopilot's: declination +0.0° (COMPASS_DEC)"  # its PARM: never a fix, COMPASS_DEC 0
    assert len(said) == 1 and f"{flight}: no GPS position: heading is {north}" in said[0]
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


def test_the_autopilots_declination_in_a_log_without_a_position_makes_the_heading_true(tmp_path):
    """A vehicle turning slowly on the ground where the declination is +12.8°, in a log with no position: on the
    field measured from the compass its heading is magnetic, 12.8° off the autopilot's ATT (true); with the
    autopilot's COMPASS_DEC among its PARM records, true."""
    log = static_log(20.0, yaw_rate_dps=1.5)  # judged by the cross-check: under 2°/s about the vertical
    log.position_t_s = log.position = None
    assert log.attitude_rpy_rad is not None
    log.attitude_rpy_rad[:, 2] += np.radians(12.8)  # the field's north is magnetic: true north is 12.8° west of it
    declination = {"COMPASS_DEC": float(np.radians(12.8))}
    config = load_config(None, {}, env={})
    rows = {}
    for name, parameters in (("with", declination), ("without", {})):
        path = write_dataflash(tmp_path / f"{name}.bin", log, parameters=parameters)
        rows[name] = replay_log(Job(path, tmp_path / f"{name}.csv", None, config, 0, None, False)).row()
    # noise-free but for the logged MAG's 0.1 mGauss steps and the 10 Hz compass's lag in the 1.5°/s turn
    assert float(rows["with"]["yaw_rms_deg"]) < 0.3 and float(rows["without"]["yaw_rms_deg"]) == pytest.approx(
        12.8, abs=0.3
    )
    # without it the cross-check warns of the declination, which is no fault of either attitude
    assert (rows["with"]["xc_warnings"], rows["without"]["xc_warnings"]) == (0, 1)
    assert rows["with"]["reference"].endswith("north as the autopilot's: declination +12.8° (COMPASS_DEC)")
    assert rows["without"]["reference"].endswith("magnetic north")


def test_a_declination_set_at_the_first_fix_is_taken_when_it_comes_not_before(tmp_path):
    """An ArduPilot with COMPASS_AUTODEC logs COMPASS_DEC 0 at its start, and the declination its first GPS fix
    gives when that comes (here 12.8°, at 16 s). Before the fix its heading is of that 0, as the field measured
    from the compass is: taken from the start, the later value would turn ours 12.8° off the autopilot's for the
    10 s measured, and warn. Each record is taken where it comes, as the live service hears it."""
    log = static_log(30.0, yaw_rate_dps=5.0)
    assert log.position_t_s is not None and log.position is not None
    fixed = log.position_t_s >= 16.0
    log.position_t_s, log.position = log.position_t_s[fixed], log.position[fixed]
    path = write_dataflash(
        tmp_path / "fix.bin",
        log,
        parameters={"COMPASS_DEC": 0.0},
        parameter_changes=[(16.0, "COMPASS_DEC", float(np.radians(12.8)))],
    )
    config = load_config(None, {}, env={})
    row = replay_log(Job(path, tmp_path / "fix.csv", None, config, 0, None, False)).row()
    assert row["reference"].startswith("measured: dip 63.5°, 48.0 µT, north as the autopilot's: declination +0.0°")
    assert row["xc_warnings"] == 0
    ours = np.loadtxt(tmp_path / "fix.csv", delimiter=",", skiprows=1, usecols=(0, 7))
    measured = (ours[:, 0] > 6.5) & (ours[:, 0] < 15.5)  # the field measured (5 s in), the WMM's from 16 s
    truth_deg = 5.0 * (ours[measured, 0] - 1.0)  # the log's ATT: 5°/s from 0 at its start
    error_deg = (ours[measured, 1] - truth_deg + 180.0) % 360.0 - 180.0
    # noise-free but for the 10 Hz compass held between readings in the 5°/s turn (up to 0.5°, and the MAG
    # records' 0.1 mGauss steps): far under the 12.8° the later declination would turn it by
    assert np.abs(error_deg).max() < 1.0
