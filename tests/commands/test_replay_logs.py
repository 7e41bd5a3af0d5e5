"""`mavattitude replay` over DataFlash and ULog files, several at once, and bad ones among them."""

from __future__ import annotations

import csv
import datetime as dt
import re

import numpy as np
import pytest

from mavattitude.cli import main
from mavattitude.errors import DataFileError
from mavattitude.estimation.conventions import angle_between, quat_from_euler
from mavattitude.sim.logwriter import LAYOUTS, static_log, write_dataflash, write_tlog
from tests.commands.process import run_cli
from tests.commands.test_replay import read_rows
from tests.link.dataflash_text import write_text_log
from tests.shared import shared_path

YAW_RATE_DPS = 10.0
# static_log's field: 48 µT at 63.5° inclination, declination 0 (magnetic north)
REF = ["--declination", "0", "--inclination", "63.5"]
# Noise-free input, int16 milligauss magnetometer (0.05 µT of 21 µT horizontal: 0.15° of heading). The
# 10 Hz magnetometer is held between readings (never interpolated ahead): up to 0.1 s × 10°/s = 1.0° behind
# in the turn, and the 10 Hz low-pass delays it by ~22 ms more (0.2°): 1.4° bounds them.
MAX_ERR_DEG = 1.4


def errors_deg(rows: np.ndarray) -> np.ndarray:
    yaw = np.radians(YAW_RATE_DPS) * (rows[:, 0] - 1.0)
    truth = quat_from_euler(np.zeros(len(rows)), np.zeros(len(rows)), yaw)
    return np.degrees(angle_between(rows[:, 1:5], truth))


def summary(path) -> dict[str, dict[str, str]]:
    with path.open(encoding="utf-8") as f:
        return {row["log"].rsplit("/", 1)[1]: row for row in csv.DictReader(f)}


@pytest.mark.parametrize("layout", LAYOUTS)
def test_one_dataflash_log_of_every_layout(tmp_path, capsys, layout):
    log = write_dataflash(tmp_path / "f.bin", static_log(3.0, yaw_rate_dps=YAW_RATE_DPS), layout=layout)
    out = tmp_path / "f.csv"
    assert main(["replay", str(log), "-o", str(out), *REF, "--no-plot"]) == 0
    rows = read_rows(out)
    assert len(rows) == pytest.approx(150, abs=2)  # 3 s at 50 Hz
    assert errors_deg(rows[10:]).max() < MAX_ERR_DEG
    assert "autopilot attitudes compared with ours" in capsys.readouterr().out


def test_workers_start_as_fresh_processes_not_copies_of_the_caller(tmp_path, monkeypatch):
    # -j's workers start the same way on every Python (forkserver): forked from the caller, as Python up to
    # 3.13 does on Linux, they carried its state, here a replay that refuses every log.
    def refuse(*_: object, **__: object) -> None:
        raise DataFileError("the caller's replay, not a fresh process's")

    monkeypatch.setattr("mavattitude.replay.replay", refuse)
    logs = [write_dataflash(tmp_path / f"{name}.bin", static_log(1.0)) for name in "ab"]
    out = tmp_path / "out"
    assert main(["replay", *map(str, logs), "-o", str(out), "-j", "2", "--no-plot", *REF]) == 0
    assert [row["status"] for row in summary(out / "summary.csv").values()] == ["ok", "ok"]


def test_workers_log_as_the_command_line_does(tmp_path):
    # A fork inherited the command line's logging; a fresh worker is given it. Run as a user runs it: in a
    # process of its own, whose forkserver (one per process, started with the first pool) writes to this
    # stderr. Within pytest, a server started by an earlier test keeps that test's captured stderr.
    logs = [write_dataflash(tmp_path / f"{name}.bin", static_log(1.0)) for name in "ab"]
    args = ["replay", *map(str, logs), "-o", str(tmp_path / "out"), "-j", "2", "--no-plot", *REF]
    done = run_cli(args, timeout_s=120.0)
    assert done.returncode == 0, done.stderr
    for log in logs:
        named = re.escape(str(log))
        assert re.search(rf" INFO mavattitude\.commands\.replay: {named}: wrote \d+ attitudes", done.stderr)
        # the library's lines too, which do not know the file: the two workers' lines interleave
        assert re.search(rf" INFO mavattitude\.replay: {named}: following the autopilot", done.stderr)


def test_old_logs_give_their_position_and_date_to_the_model_of_their_epoch(tmp_path):
    """GPS records of every layout (no POS before 3.3): the WMM release of the log's own date, at its place."""
    logs = tmp_path / "logs"
    logs.mkdir()
    flight = static_log(3.0, yaw_rate_dps=YAW_RATE_DPS)
    for layout, day in (("3.0", dt.date(2013, 5, 4)), ("3.2", dt.date(2014, 8, 20)), ("3.3", dt.date(2016, 4, 18))):
        flight.gps_time_s = (day - dt.date(1980, 1, 6)).days * 86_400.0 + 17.0  # leap seconds: a date is enough
        write_dataflash(logs / f"v{layout}.bin", flight, layout=layout)
    out = tmp_path / "out"
    assert main(["replay", str(logs), "-o", str(out), "--no-plot"]) == 0
    table = summary(out / "summary.csv")
    assert [table[f"v{v}.bin"]["reference"] for v in ("3.0", "3.2", "3.3")] == [
        "WMM2010 at 47.4000°, 8.5000° on 2013-05-04",
        "WMM2010 at 47.4000°, 8.5000° on 2014-08-20",
        "WMM2015v2 at 47.4000°, 8.5000° on 2016-04-18",
    ]
    # the written field has declination 0, the model's there and then 1.7–2.2° east: the yaw is off by that much
    assert all(float(row["yaw_rms_deg"]) < 3.0 for row in table.values())


def test_a_directory_of_logs_with_bad_ones_among_them(tmp_path, capsys):
    logs = tmp_path / "logs"
    logs.mkdir()
    good = write_dataflash(logs / "a.bin", static_log(3.0, yaw_rate_dps=YAW_RATE_DPS))
    write_dataflash(logs / "b.bin", static_log(3.0, yaw_rate_dps=YAW_RATE_DPS), layout="3.2")
    data = good.read_bytes()
    (logs / "c_cut.bin").write_bytes(data[: len(data) // 2 + 7])
    (logs / "d_junk.ulg").write_bytes(b"\x00" * 100)
    out = tmp_path / "out"
    assert main(["replay", str(logs), "-o", str(out), "-j", "2", *REF]) == 2
    err = capsys.readouterr().err.strip().splitlines()[-1]
    assert err.startswith("mavattitude replay: error: 2 of 4 logs not fully replayed")
    table = summary(out / "summary.csv")
    assert [table[n]["status"] for n in ("a.bin", "b.bin", "c_cut.bin", "d_junk.ulg")] == [
        "ok",
        "ok",
        "damaged",
        "failed",
    ]
    assert "truncated" in table["c_cut.bin"]["note"] and "not a flight log" in table["d_junk.ulg"]["note"]
    assert float(table["a.bin"]["duration_s"]) == pytest.approx(3.0, abs=0.1)
    assert int(table["a.bin"]["samples"]) == 1200 and float(table["a.bin"]["yaw_rms_deg"]) < MAX_ERR_DEG
    for name in ("a", "b", "c_cut"):
        assert errors_deg(read_rows(out / f"{name}.csv")[10:]).max() < MAX_ERR_DEG
    assert len(read_rows(out / "c_cut.csv")) == pytest.approx(75, abs=5)  # the first half
    assert (out / "a.png").read_bytes()[:4] == b"\x89PNG"
    assert not (out / "d_junk.csv").exists()


def test_a_directory_with_a_dataflash_text_log_and_another_program_s_log(tmp_path, capsys):
    """A .log is a DataFlash text log (Mission Planner's conversion) or any program's log: the one is replayed as
    its .bin is, the other left alone."""
    logs = tmp_path / "logs"
    logs.mkdir()
    binary = write_dataflash(tmp_path / "f.bin", static_log(3.0, yaw_rate_dps=YAW_RATE_DPS))
    write_text_log(binary, logs / "f.log")
    (logs / "mavproxy.log").write_text("Connect udpin:0.0.0.0:14550 source_system=255\n")
    out = tmp_path / "out"
    assert main(["replay", str(logs), "-o", str(out), "--no-plot", *REF]) == 0
    assert list(summary(out / "summary.csv")) == ["f.log"]
    as_text, as_binary = read_rows(out / "f.csv"), tmp_path / "f_bin.csv"
    assert main(["replay", str(binary), "-o", str(as_binary), "--no-plot", *REF]) == 0
    # the same flight: the text's float32 fields to 7 significant digits change the attitude by ~1e-7 rad
    assert np.degrees(angle_between(as_text[:, 1:5], read_rows(as_binary)[:, 1:5])).max() < 1e-4


def test_logs_of_one_name_in_two_folders_keep_their_own_results_and_a_log_named_twice_is_replayed_once(tmp_path):
    """a/f.bin and b/f.bin both wrote out/f.csv, the second over the first; a/f.bin named and inside the folder
    a also named was replayed twice."""
    for folder, yaw_rate_dps in (("a", YAW_RATE_DPS), ("b", 0.0)):
        (tmp_path / folder).mkdir()
        write_dataflash(tmp_path / folder / "f.bin", static_log(3.0, yaw_rate_dps=yaw_rate_dps))
    out = tmp_path / "out"
    logs = [str(tmp_path / "a" / "f.bin"), str(tmp_path / "b" / "f.bin"), str(tmp_path / "a")]
    assert main(["replay", *logs, "-o", str(out), "--no-plot", *REF]) == 0
    assert sorted(p.name for p in out.iterdir()) == ["a_f.bin.csv", "b_f.bin.csv", "summary.csv"]
    assert errors_deg(read_rows(out / "a_f.bin.csv")[10:]).max() < MAX_ERR_DEG  # a's yaw turns, b's does not
    assert errors_deg(read_rows(out / "b_f.bin.csv")[10:]).max() > 10 * MAX_ERR_DEG
    with (out / "summary.csv").open(encoding="utf-8") as f:
        assert len(list(csv.DictReader(f))) == 2


def test_a_log_name_that_does_not_exist_is_said_before_anything_is_replayed_or_made(tmp_path, capsys):
    good = str(write_dataflash(tmp_path / "a.bin", static_log(1.0)))
    assert main(["replay", good, str(tmp_path / "b.bni"), "-o", str(tmp_path / "out"), *REF]) == 2
    assert capsys.readouterr().err.strip().endswith(f"{tmp_path / 'b.bni'}: no such file or directory")
    assert not (tmp_path / "out").exists()


def test_several_logs_given_a_csv_for_output_are_refused_before_a_directory_of_that_name_is_made(tmp_path, capsys):
    logs = [str(write_dataflash(tmp_path / f"{name}.bin", static_log(1.0))) for name in "ab"]
    assert main(["replay", *logs, "-o", str(tmp_path / "out.csv"), *REF]) == 2
    assert "2 logs write a CSV each and a summary: give a directory" in capsys.readouterr().err
    assert not (tmp_path / "out.csv").exists()


@pytest.mark.parametrize("layout", ["4.1", "3.0"])  # an I column, or IMU, IMU2 records
def test_an_imu_instance_the_log_lacks_is_refused_naming_those_it_has(tmp_path, capsys, layout):
    log = str(write_dataflash(tmp_path / "two.bin", static_log(1.0), layout=layout, instances=2))
    assert main(["replay", log, "--imu", "2", "-o", str(tmp_path / "out.csv"), *REF]) == 2
    assert capsys.readouterr().err.strip().endswith("records; the log has IMU instance 0, 1: --imu 0")


def test_a_truncated_log_alone_is_replayed_then_one_line_and_exit_2(tmp_path):
    data = write_dataflash(tmp_path / "x.bin", static_log(3.0)).read_bytes()
    cut = tmp_path / "cut.bin"
    cut.write_bytes(data[: len(data) // 3])
    out = tmp_path / "cut.csv"
    done = run_cli(["--log-level", "WARNING", "replay", str(cut), "-o", str(out), *REF])
    assert done.returncode == 2
    (line,) = done.stderr.strip().splitlines()
    assert (
        line.startswith(f"mavattitude replay: error: {cut}: truncated: the ") and "samples before it replayed" in line
    )
    assert len(read_rows(out)) > 40  # what came before the cut


def test_a_log_whose_imu_time_stands_still_is_replayed_with_a_warning_that_says_why(tmp_path):
    """An IMU clock stuck after its first second: a few attitudes, then every sample a duplicate."""
    log = static_log(10.0)
    log.imu_t_s = np.minimum(log.imu_t_s, 2.0)
    path = write_dataflash(tmp_path / "stuck.bin", log)
    done = run_cli(["--log-level", "WARNING", "replay", str(path), "-o", str(tmp_path / "stuck.csv"), *REF])
    assert done.returncode == 0 and 0 < len(read_rows(tmp_path / "stuck.csv")) < 60  # the first second's
    (line,) = done.stderr.strip().splitlines()
    assert re.search(r"most input samples were refused \(3599 of 4000\): refused: duplicate 3599 \(its IMU time", line)


def test_a_telemetry_log_with_a_damaged_record_is_replayed_around_it_then_exit_2(tmp_path, capsys):
    from tests.commands.test_replay import write_tlog

    path = write_tlog(tmp_path / "x.tlog", seconds=3.0, second_vehicle=False, attitude=False)
    data = bytearray(path.read_bytes())
    data[len(data) // 2] ^= 0xFF  # one record's CRC fails: the log goes on after it
    path.write_bytes(bytes(data))
    out = tmp_path / "x.csv"
    assert main(["replay", str(path), "-o", str(out), *REF]) == 2
    line = capsys.readouterr().err.strip().splitlines()[-1]
    assert ": damaged: the record at byte " in line and "does not decode (CRC): skipped; the other 298 samples" in line
    assert len(read_rows(out)) == pytest.approx(150, abs=2)  # the whole log, but for one sample


def test_the_shared_sitl_flight_ign_and_fused(tmp_path):
    flight = shared_path("data", "ardupilot-sitl", "flightA.BIN")
    figures = {}
    for method in ("ign", "fused"):
        out = tmp_path / method
        main(["replay", str(flight), "-o", str(out), "--method", method, "--no-plot"])
        figures[method] = summary(out / "summary.csv")["flightA.BIN"]
        assert figures[method]["status"] == "damaged"  # the file ends in the first bytes of an IMU record
    ign, fused = figures["ign"], figures["fused"]
    # The targets for the fused filter against the autopilot's ATT: roll / pitch ≤ 0.6° RMS and ≤ 2° p99, yaw
    # ≤ 1.5° RMS. Measured on this commit, the GPS velocity's acceleration removed: 0.18 / 0.23° RMS, 0.62 /
    # 0.77° p99, yaw 1.16° (without it 0.36 / 0.59°, 1.30 / 1.94°, 1.04°; docs/fused.md): the bounds are the
    # targets themselves.
    assert float(fused["roll_rms_deg"]) <= 0.6 and float(fused["pitch_rms_deg"]) <= 0.6
    assert float(fused["roll_p99_deg"]) <= 2.0 and float(fused["pitch_p99_deg"]) <= 2.0
    assert float(fused["yaw_rms_deg"]) <= 1.5
    # IGN alone (../shared/data/ardupilot-sitl/README.md: 6.6 / 8.7° RMS roll / pitch): it reads the
    # accelerations' specific force as gravity; the bounds are that physics, not a tuning.
    assert 5.5 < float(ign["roll_rms_deg"]) < 7.5 and 7.5 < float(ign["pitch_rms_deg"]) < 9.5
    assert int(fused["fused.updates"]) > 1000 and "fused.updates" not in ign  # the filter's counters, fused only
    # the receiver's 5 Hz velocity (GPS Spd/GCrs/VZ) is differenced from its first fixes: nearly every update
    assert int(fused["fused.gps_updates"]) > 0.95 * int(fused["fused.updates"]) and fused["fused.gps_refused"] == "0"
    assert float(fused["heading_from_compass"]) == 1.0 and "heading_from_compass" not in ign  # SITL's clean compass


@pytest.mark.parametrize("name", ["sample.ulg", "sample_log_small.ulg"])
def test_the_shared_px4_logs(tmp_path, name):
    out = tmp_path / "px4.csv"
    # PX4's attitude_estimator_q ran with declination 0 (../shared/data/README.md): magnetic north
    assert (
        main(
            [
                "replay",
                str(shared_path("data", "px4", name)),
                "-o",
                str(out),
                "--declination",
                "0",
                "--inclination",
                "60",
                "--no-plot",
                "--method",
                "fused",
            ]
        )
        == 0
    )
    assert len(read_rows(out)) > 100


@pytest.mark.parametrize("method", ["ign", "fused"])
@pytest.mark.parametrize("reference", [{"reference.magnetic": {"declination_deg": 0, "inclination_deg": 63.5}}, {}])
def test_a_log_at_once_gives_the_outputs_of_its_items_one_by_one(tmp_path, method, reference):
    from mavattitude.config import load_config
    from mavattitude.link.logs import open_log
    from mavattitude.replay import replay

    log = static_log(20.0, yaw_rate_dps=YAW_RATE_DPS)
    rng = np.random.default_rng(5)
    log.acc_mps2 = log.acc_mps2 + rng.normal(0.0, 0.5, log.acc_mps2.shape)  # vibration: ACC_NORM flags too
    log.mag_uT = log.mag_uT + rng.normal(0.0, 0.5, log.mag_uT.shape)
    path = write_dataflash(tmp_path / "n.bin", log)
    config = load_config(None, {**reference, "estimator.method": method}, env={})
    at_once = replay(open_log(path, config), config)
    one_by_one = replay(open_log(path, config), config, at_once=False)
    a, b = at_once.output_array(), one_by_one.output_array()
    assert len(a) > 900 and np.array_equal(a[:, 0], b[:, 0])  # the same ticks; auto: from the first position on
    # the vectorised front end equals the streaming one to rounding (~1e-12 on the filtered vectors)
    assert np.max(angle_between(a[:, 1:], b[:, 1:])) < 1e-9
    assert at_once.pipeline.counters.frontend.flagged == one_by_one.pipeline.counters.frontend.flagged
    assert at_once.counters.received == one_by_one.counters.received == len(log.imu_t_s)


@pytest.mark.parametrize("method", ["ign", "fused"])
def test_a_telemetry_log_at_once_gives_its_outputs_one_by_one(tmp_path, method):
    from mavattitude.config import load_config
    from mavattitude.link.logs import open_log
    from mavattitude.replay import replay
    from tests.commands.test_replay import write_tlog

    path = write_tlog(tmp_path / "two.tlog", seconds=4.0, position=True)  # two vehicles, a ground station
    config = load_config(None, {"estimator.method": method}, env={})  # auto: the WMM at the logged position
    at_once = replay(open_log(path, config), config)
    one_by_one = replay(open_log(path, config), config, at_once=False)
    a, b = at_once.output_array(), one_by_one.output_array()
    assert len(a) > 150 and np.array_equal(a[:, 0], b[:, 0])
    assert np.max(angle_between(a[:, 1:], b[:, 1:])) < 1e-9  # the front ends agree to rounding
    assert at_once.counters.ignored == one_by_one.counters.ignored > 0  # vehicle 2 and the ground station
    assert len(at_once.autopilot) == len(one_by_one.autopilot) > 30


def test_a_telemetry_log_of_an_imu_the_autopilot_lacks_is_refused_saying_why(tmp_path):
    """ArduPilot sends SCALED_IMU3 with a zero accelerometer and gyroscope when it has no third IMU (the compass in
    it may be real): replaying that message fails, and the error says what the refusals mean."""
    log = static_log(3.0)
    log.acc_mps2, log.gyr_radps = np.zeros_like(log.acc_mps2), np.zeros_like(log.gyr_radps)
    path = write_tlog(tmp_path / "third.tlog", log, message="SCALED_IMU3")
    done = run_cli(["replay", str(path), "-o", str(tmp_path / "out"), "--message", "SCALED_IMU3", *REF])
    assert done.returncode == 2  # a log not replayed
    n = len(log.imu_t_s)
    assert re.search(
        rf"no attitude could be computed \(refused: dead_acc {n} \(its accelerometer reads under 5% of g: .*"
        r"an IMU the autopilot lacks\)\)\n",  # and no other IMU message to name: it sent none
        done.stderr,
    ), done.stderr


@pytest.mark.parametrize(
    ("folder", "name", "message"),
    [("ardupilot-sitl", "lowrate.tlog", "SCALED_IMU3"), ("real", "ardusub41_2023-04-18.tlog", "SCALED_IMU2")],
)
def test_a_zero_imu_message_of_a_shared_log_is_refused_naming_the_one_to_replay(tmp_path, folder, name, message):
    """The SITL log at ground-station rates (two IMUs) carries SCALED_IMU3, the real ArduSub dive (one IMU)
    SCALED_IMU2: each with a zero accelerometer and gyroscope and a real compass. Replayed as asked, each fails
    naming RAW_IMU, which it sent; the dive has no GPS and no field could be measured either, but what stopped it
    is the refusals, and they are said."""
    log = shared_path("data", folder, name)
    done = run_cli(["replay", str(log), "-o", str(tmp_path / "out"), "--message", message, "--no-plot"])
    assert done.returncode == 2  # a log not replayed
    assert re.search(r"refused: dead_acc \d+ \(.*\)\); it sent RAW_IMU too: --message RAW_IMU$", done.stderr.strip())


def test_a_shared_log_read_with_another_sensors_profile_is_said_to_be_in_the_wrong_units(tmp_path):
    """The real ArduSub dive read with --profile adis16405 (3.33 mg per count for ArduPilot's 1 mg): the
    accelerometer reads 3.33 g. The dive has no GPS and, never still, no field measured: the error leads with the
    units, the warning gives the profile's scale to check."""
    log = shared_path("data", "real", "ardusub41_2023-04-18.tlog")
    done = run_cli(["replay", str(log), "-o", str(tmp_path / "out.csv"), "--profile", "adis16405", "--no-plot"])
    assert done.returncode == 2
    assert (
        "accelerometer: its median |f| over the first 5 s is 3.33 g, where a vehicle's is about 1 g: wrong units: "
        "check --profile adis16405's scale, 0.03266 m/s² per unit of RAW_IMU's accelerometer"
    ) in done.stderr
    assert "wrong units, so the vehicle never read as still: fix them (the warning above), or give" in done.stderr
