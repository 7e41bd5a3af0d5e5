"""Every magnetometer of a log judged, and the one replayed chosen as the autopilot did (its parameters), else
the most consistent: on the shared two-compass SITL flight and on logs the tests write."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from mavattitude.commands.replay import Job, replay_log
from mavattitude.config import load_config
from mavattitude.errors import DataFileError
from mavattitude.link.logs import open_log
from mavattitude.replay import Replayed, replay
from mavattitude.sim.logwriter import manoeuvring_log, write_dataflash, write_tlog
from tests.shared import shared_path

C45 = math.sqrt(0.5)
TURNED_45_Z = np.array([[C45, C45, 0.0], [-C45, C45, 0.0], [0.0, 0.0, 1.0]])  # ArduPilot's ROTATION_YAW_45
TRUE_FIELD = {"reference.magnetic": {"declination_deg": 12.8, "inclination_deg": -65.77}}  # the SITL's (its README)


def _replayed(path: Path, mag: int | None = None) -> Replayed:
    config = load_config(None, TRUE_FIELD, env={})
    return replay(open_log(path, config, mag_instance=mag), config)


def _verdicts(result: Replayed) -> dict[int, str]:
    return {j.instance: j.verdict() for j in result.compasses}


@pytest.mark.parametrize("name", ["twocompass.BIN", "twocompass.tlog"])
def test_the_turned_compass_of_the_two_compass_flight_is_named_and_the_autopilots_used(name):
    # compass 2 (MAG[1], SCALED_IMU2) turned 45° about z and not told, COMPASS_USE2 0: the autopilot used compass 1
    result = _replayed(shared_path("data", "ardupilot-sitl", name))
    verdicts = _verdicts(result)
    assert verdicts[0] == "ok" and verdicts[1] == "turns unlike the gyro: turned?"
    assert verdicts.get(2, "ok") == "ok"  # the .BIN's third compass is compass 1's copy
    assert result.compass_used.startswith("0: the autopilot's: COMPASS_USE 1, COMPASS_USE2 0")
    assert result.compass == []  # the replayed compass is never warned about
    # named once it tilts: its pitch manoeuvre starts at 77 s (the yaw turns before commute with a turn about z)
    warned = next(e for j in result.compasses for e in j.events if e.inconsistent)
    assert 77.0 < warned.time_s < 77.0 + 10.0


def _two_compass_log(tmp_path: Path, parameters: dict[str, float] | None = None) -> Path:
    """A hard 60 s flight (simulated, .BIN rates) with two compasses: instance 0 turned 45°, instance 1 good."""
    turned = manoeuvring_log(60.0, mag_turn=TURNED_45_Z, seed=1)
    return write_dataflash(
        tmp_path / "two.bin", manoeuvring_log(60.0, seed=1), instances=2, mags=[turned.mag_uT], parameters=parameters
    )


def test_without_the_autopilots_word_the_most_consistent_compass_is_replayed(tmp_path):
    result = _replayed(_two_compass_log(tmp_path))
    assert result.compass_used == "1: the most consistent of 2"
    assert _verdicts(result) == {0: "turns unlike the gyro: turned?", 1: "ok"}
    assert result.pipeline.compass.warnings == 0


def test_the_compass_the_autopilot_used_is_replayed_even_when_it_is_off(tmp_path):
    # the autopilot's choice is what the cross-check compares with: replayed, and said to be off
    result = _replayed(_two_compass_log(tmp_path, {"COMPASS_USE": 1.0, "COMPASS_USE2": 1.0}))
    assert result.compass_used == "0: the autopilot's: COMPASS_USE 1, COMPASS_USE2 1"
    assert _verdicts(result)[0] == "turns unlike the gyro: turned?" and result.pipeline.compass.warnings == 1
    chosen = _replayed(_two_compass_log(tmp_path, {"COMPASS_USE": 0.0, "COMPASS_USE2": 1.0}))
    assert chosen.compass_used == "1: the autopilot's: COMPASS_USE 0, COMPASS_USE2 1"
    assert _replayed(_two_compass_log(tmp_path), mag=0).compass_used == "0: --mag 0"


def test_a_telemetry_logs_compasses_are_its_imu_messages(tmp_path):
    # RAW_IMU carries compass 1 (turned here), SCALED_IMU2 compass 2; no PARAM_VALUE: the most consistent is used
    turned = manoeuvring_log(60.0, imu_rate_hz=50.0, mag_turn=TURNED_45_Z, seed=1)
    second = manoeuvring_log(60.0, imu_rate_hz=50.0, seed=1)
    second.attitude_t_s = second.position_t_s = None  # the same vehicle: its attitude and position sent once
    path = write_tlog(tmp_path / "two.tlog", turned, others=[(second, 1, "SCALED_IMU2")])
    result = _replayed(path)
    assert result.compass_used == "1: the most consistent of 2"
    assert _verdicts(result) == {0: "turns unlike the gyro: turned?", 1: "ok"}


def test_the_summary_says_which_compass_and_every_ones_verdict(tmp_path):
    config = load_config(None, TRUE_FIELD, env={})
    job = Job(_two_compass_log(tmp_path), tmp_path / "out.csv", None, config, 0, None, False)
    columns = replay_log(job).columns
    assert columns["compass"] == "1: the most consistent of 2"
    assert columns["compasses"] == "0 turns unlike the gyro: turned?; 1 ok"


def test_a_compass_the_autopilot_does_not_use_is_said_so_with_its_verdict(tmp_path, caplog):
    """A compass found off that the autopilot has set aside matters less to a pilot than one it heads by: its
    verdict and its warning say it is unused, and by which parameter."""
    config = load_config(None, TRUE_FIELD, env={})
    log = _two_compass_log(tmp_path, {"COMPASS_USE": 0.0, "COMPASS_USE2": 1.0})
    columns = replay_log(Job(log, tmp_path / "out.csv", None, config, 0, None, False)).columns
    assert columns["compasses"] == "0 turns unlike the gyro: turned? (unused by the autopilot: COMPASS_USE 0); 1 ok"
    (warned,) = [r.getMessage() for r in caplog.records if r.getMessage().startswith("magnetometer 0:")]
    assert warned.endswith("(unused by the autopilot: COMPASS_USE 0)")


def test_a_px4_logs_magnetometers_are_listed_with_the_one_px4_selected():
    # two sensor_mag (internal 589858, external 592905), sensor_selection's mag_device_id 592905: the external one,
    # whose calibrated field is vehicle_magnetometer, the one replayed
    path = shared_path("data", "px4", "sample_log_small.ulg")
    config = load_config(None, {}, env={})
    result = replay(open_log(path, config), config)
    assert (
        result.compass_used
        == "1: the autopilot's: sensor_selection's mag_device_id 592905 (its field: vehicle_magnetometer)"
    )
    assert [j.instance for j in result.compasses] == [0, 1]
    assert result.unused_compasses == {0: "CAL_MAG0_EN 0"}  # the internal one's calibration slot is disabled


@pytest.mark.parametrize(
    ("name", "verdicts"),
    [("twocompass.tlog", {0: "ok", 1: "turns unlike the gyro: turned?"}), ("nogps.BIN", {0: "ok", 1: "ok", 2: "ok"})],
)
def test_with_the_example_config_every_compass_is_judged_on_the_reference_the_replay_has(name, verdicts):
    # reference.magnetic auto: twocompass.tlog's first position comes after the field is measured (the samples
    # go one by one, measured field then WMM), nogps has none (the field measured from the compass)
    config = load_config(Path(__file__).parents[2] / "configs" / "ardupilot.yaml", {}, env={})
    result = replay(open_log(shared_path("data", "ardupilot-sitl", name), config), config)
    assert _verdicts(result) == verdicts and result.compass_used.startswith("0: the autopilot's: COMPASS_USE 1")


@pytest.mark.parametrize("name", ["twocompass.BIN", "twocompass.tlog"])
@pytest.mark.parametrize(("mag", "unused"), [(None, None), (1, (1, "COMPASS_USE2", 0.0))])
def test_a_compass_the_autopilot_did_not_use_is_known_when_it_is_replayed(name, mag, unused):
    # the two-compass flight's compass 2 (MAG[1], SCALED_IMU2) has COMPASS_USE2 0; --mag 1 replays it all the same
    result = _replayed(shared_path("data", "ardupilot-sitl", name), mag=mag)
    assert result.unused_compass == unused
    assert result.unused_compasses == {1: "COMPASS_USE2 0"}  # among those judged, replayed or not


def test_the_only_compass_of_a_log_unused_by_the_autopilot_is_said(tmp_path, caplog):
    # one MAG instance, its COMPASS_USE 0: replayed (there is no other), with the live service's words
    config = load_config(None, TRUE_FIELD, env={})
    log = write_dataflash(tmp_path / "one.bin", manoeuvring_log(20.0, seed=1), parameters={"COMPASS_USE": 0.0})
    columns = replay_log(Job(log, tmp_path / "out.csv", None, config, 0, None, False)).columns
    assert columns["compass"] == "the only one; unused by the autopilot (COMPASS_USE 0)"
    said = [r.getMessage() for r in caplog.records if "does not use compass" in r.getMessage()]
    assert said == [
        "the autopilot does not use compass 1 (COMPASS_USE 0), the one our heading comes from: it may have set it "
        "aside for a reason (interference, its mounting); --mag I replays another the log holds"
    ]
    in_use = write_dataflash(tmp_path / "used.bin", manoeuvring_log(20.0, seed=1), parameters={"COMPASS_USE": 1.0})
    assert replay_log(Job(in_use, tmp_path / "out2.csv", None, config, 0, None, False)).columns["compass"] == (
        "the only one"
    )


@pytest.mark.parametrize(
    ("where", "mag", "refusal"),
    [
        (("ardupilot-sitl", "twocompass.tlog"), 7, "no compass 7 records; the log has compass instance 0, 1: --mag 0"),
        (("ardupilot-sitl", "twocompass.BIN"), 7, r"no MAG\[I=7\] records; the log has MAG instance 0, 1, 2: --mag 0"),
        (("px4", "sample.ulg"), 3, r"no vehicle_magnetometer\[3\] records; the log has magnetometer instance 0"),
    ],
)
def test_a_compass_the_log_lacks_is_refused_naming_those_it_has(where, mag, refusal):
    """--mag with a typo: replayed, the .tlog took the autopilot's compass, the .BIN none (roll and pitch only)
    and the .ulg its one, each without a word of what was asked."""
    with pytest.raises(DataFileError, match=refusal):
        _replayed(shared_path("data", *where), mag=mag)


def test_our_mag_calibration_is_applied_to_the_replayed_compass_only(tmp_path):
    """calibration.mag fitted to the replayed compass (25 µT of hard iron in its readings), the other calibrated by
    the autopilot: judged as it comes, ok; with our hard iron it read dip and |B| off."""
    log = manoeuvring_log(60.0, seed=1)
    hard_iron = np.array([25.0, -10.0, 5.0])
    path = write_dataflash(
        tmp_path / "cal.bin",
        log,
        instances=2,
        mags=[log.mag_uT + hard_iron, log.mag_uT],
        parameters={"COMPASS_USE": 1.0, "COMPASS_USE2": 1.0},
    )
    config = load_config(None, {"calibration.mag.hard_iron_uT": hard_iron.tolist()}, env={})  # the WMM's field
    result = replay(open_log(path, config), config)
    assert result.compass_used.startswith("0: the autopilot's")
    assert _verdicts(result) == {0: "ok", 1: "ok"}
