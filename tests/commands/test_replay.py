"""`mavattitude replay`: a .tlog written here with pymavlink, through the service's pipeline."""

from __future__ import annotations

import csv
import datetime as dt
import struct
from pathlib import Path

import numpy as np
import pytest
import yaml
from pymavlink.dialects.v20 import ardupilotmega as mavlink

from mavattitude.cli import main
from mavattitude.estimation.conventions import angle_between, quat_from_euler, rotate_ned_to_body
from mavattitude.sensors.magref import field_from_angles, wmm_field_ned_uT
from mavattitude.sensors.units import PROFILES, ImuSample, encode
from tests.commands.process import run_cli

G = 9.80665
T0_UNIX = dt.datetime(2026, 3, 1, 12, 0, tzinfo=dt.timezone.utc).timestamp()
DECL, INCL, F_UT = -1.5, 62.0, 49.0
REF = ["--declination", str(DECL), "--inclination", str(INCL)]
LAT, LON, ALT = 47.4, 8.5, 450.0
AUTOPILOT_YAW_OFFSET_DEG = 2.0  # the logged ATTITUDE differs from the truth by this much yaw
YAW_RATE_DEG_S = 1.5  # a slow turn on the ground: under the 2°/s about the vertical that may be a turn's lean


def truth_euler_rad(t_s: np.ndarray, sysid: int) -> np.ndarray:
    """Vehicle 1 yaws slowly at a small roll and pitch; vehicle 2 sits still, rolled 40°."""
    t = np.asarray(t_s, dtype=float)
    if sysid == 2:
        return np.radians(np.stack([40.0 + 0 * t, 0 * t, 90.0 + 0 * t], -1))
    return np.radians(np.stack([8.0 + 0 * t, -4.0 + 0 * t, 20.0 + YAW_RATE_DEG_S * t], -1))


def write_tlog(
    path: Path,
    seconds: float = 3.0,
    field_ned_uT: np.ndarray | None = None,
    attitude: bool = True,
    position: bool = False,
    position_from_s: float = 0.5,
    second_vehicle: bool = True,
    gimbal_first: bool = False,
    mag_every: int = 1,
    heartbeats: bool = True,
    imu_clock_offset_s: float = 0.0,
    imu_copies: int = 1,
) -> Path:
    """A ground station's recording: its own heartbeat, the autopilot(s') heartbeats, RAW_IMU at 100 Hz
    (ArduPilot units, seeded noise; each compass reading repeated in ``mag_every`` messages, as ArduPilot
    sends a slower compass; stamped ``imu_clock_offset_s`` from the other messages; each recorded ``imu_copies``
    times, as a station that hears the vehicle by two routes records it), ATTITUDE at 10 Hz, optionally
    GLOBAL_POSITION_INT at 5 Hz from ``position_from_s``; without ``heartbeats``, the station's alone."""
    field = field_from_angles(DECL, INCL, F_UT) if field_ned_uT is None else field_ned_uT
    rng = np.random.default_rng(3)
    profile = PROFILES["ardupilot"]
    links = {s: mavlink.MAVLink(None, srcSystem=s, srcComponent=1) for s in (1, 2, 3, 255)}
    records: list[tuple[float, bytes]] = []

    def add(t_s: float, sysid: int, msg: mavlink.MAVLink_message) -> None:
        records.append((t_s, msg.pack(links[sysid])))

    vehicles = (1, 2) if second_vehicle else (1,)
    if gimbal_first:  # a gimbal that fills in an autopilot type, as some do: not a flight controller
        gimbal = links[3].heartbeat_encode(mavlink.MAV_TYPE_GIMBAL, mavlink.MAV_AUTOPILOT_GENERIC, 0, 0, 4)
        add(0.0005, 3, gimbal)
    for k in range(int(seconds) + 1):
        add(k + 0.001, 255, links[255].heartbeat_encode(6, mavlink.MAV_AUTOPILOT_INVALID, 0, 0, 0))
        for s in vehicles if heartbeats else ():
            add(k + 0.002, s, links[s].heartbeat_encode(2, mavlink.MAV_AUTOPILOT_ARDUPILOTMEGA, 0, 0, 4))
    t = np.arange(1, int(seconds * 100)) / 100.0
    for s in vehicles:
        rpy = truth_euler_rad(t, s)
        q = quat_from_euler(rpy[:, 0], rpy[:, 1], rpy[:, 2])
        acc = rotate_ned_to_body(q, [0.0, 0.0, -G]) + rng.normal(0, 0.03, (len(t), 3))
        mag = rotate_ned_to_body(q, field) + rng.normal(0, 0.3, (len(t), 3))
        mag = mag[np.arange(len(t)) // mag_every * mag_every]  # the newest reading of a slower compass
        gyr = np.tile([0.0, 0.0, np.radians(YAW_RATE_DEG_S) if s == 1 else 0.0], (len(t), 1))
        for i, ti in enumerate(t):
            sample = ImuSample(float(ti) + imu_clock_offset_s, tuple(acc[i]), tuple(gyr[i]), tuple(mag[i]))
            for _ in range(imu_copies):
                add(ti, s, links[s].raw_imu_encode(**encode(sample, profile, "RAW_IMU")))
            if attitude and i % 10 == 5:
                r, p, y = rpy[i] + [0.0, 0.0, np.radians(AUTOPILOT_YAW_OFFSET_DEG)]
                add(ti, s, links[s].attitude_encode(round(ti * 1e3), r, p, y, 0.0, 0.0, 0.0))
    for s in vehicles if position else ():
        for ti in np.arange(position_from_s, seconds, 0.2):
            add(ti, s, links[s].global_position_int_encode(round(ti * 1e3), 474000000, 85000000, 450000, 0, 0, 0, 0, 0))
    records.sort(key=lambda r: r[0])
    with path.open("wb") as f:
        for t_s, buf in records:
            f.write(struct.pack(">Q", round((T0_UNIX + t_s) * 1e6)) + buf)
    return path


def read_rows(path: Path) -> np.ndarray:
    return np.loadtxt(path, delimiter=",", skiprows=1, ndmin=2)


def errors_deg(rows: np.ndarray, sysid: int = 1) -> np.ndarray:
    rpy = truth_euler_rad(rows[:, 0], sysid)
    return np.degrees(angle_between(rows[:, 1:5], quat_from_euler(rpy[:, 0], rpy[:, 1], rpy[:, 2])))


# Per-sample heading σ: magnetometer 0.3 µT / (49 µT cos 62°) = 0.75°, and the tilt error (0.03 / 9.81 rad =
# 0.18°) × tan 62° = 0.33°: 0.82° together. The 10 Hz Butterworth passes 11.1 Hz of the 50 Hz input band:
# σ × 0.47 ≈ 0.39°. The filter's 22 ms group delay at 1.5°/s adds 0.03°. Bound: 4σ + lag (at 5°/s, 0.11°).
MAX_ERR_DEG = 1.7


def test_replay_writes_the_attitude_and_compares_with_the_autopilot(tmp_path, capsys):
    log = write_tlog(tmp_path / "flight.tlog")
    out = tmp_path / "flight.csv"
    assert main(["replay", str(log), "-o", str(out), *REF]) == 0
    rows = read_rows(out)
    assert len(rows) == pytest.approx(150, abs=2)  # 3 s at 50 Hz
    assert errors_deg(rows[10:]).max() < MAX_ERR_DEG  # vehicle 1, not vehicle 2 (rolled 40°)
    captured = capsys.readouterr()
    table = captured.out
    yaw = next(line for line in table.splitlines() if line.startswith("yaw"))
    mean_yaw = float(yaw.split()[1])
    # Ours is the truth, the autopilot's is the truth + 2°: −2° within the error bound.
    assert abs(mean_yaw + AUTOPILOT_YAW_OFFSET_DEG) < MAX_ERR_DEG / 2
    assert "autopilot attitudes compared with ours (interpolated to their times)" in table
    compared = next(line for line in table.splitlines() if "compared with ours" in line).split()[0]
    # turning at 1.5°/s on the ground: every pair judged (a snapshot is judged below 10°/s, 2°/s about the vertical),
    # the 2° never warned of
    assert f"\ncross-check: {compared} judged, 0 warning(s)\n" in table
    png = out.with_suffix(".png")
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert "other system or component" in captured.err  # vehicle 2 and the ground station were skipped


def test_the_compass_line_says_when_the_field_strength_is_not_known(tmp_path, capsys):
    """Declination and inclination give no intensity: |B| is not compared, and the line says so (not ``nan``);
    with a full field vector it is compared."""
    log = write_tlog(tmp_path / "flight.tlog", seconds=2.0, second_vehicle=False, attitude=False)
    assert main(["replay", str(log), "-o", str(tmp_path / "a.csv"), *REF]) == 0
    line = next(x for x in capsys.readouterr().err.splitlines() if ": compass: dip" in x)
    assert "|B| not compared (the magnetic reference gives no field strength" in line and "nan" not in line
    field = field_from_angles(DECL, INCL, F_UT)
    assert main(["replay", str(log), "-o", str(tmp_path / "b.csv"), "--mag-ref-ned", *map(str, field)]) == 0
    line = next(x for x in capsys.readouterr().err.splitlines() if ": compass: dip" in x)
    ratio = float(line.split("|B| ")[1].split()[0])
    assert ratio == pytest.approx(1.0, abs=0.05)  # the written field, 0.3 µT noise on 49 µT


@pytest.mark.parametrize("chosen_by", ["config", "flag"])
def test_the_configured_system_id_selects_the_vehicle(tmp_path, capsys, chosen_by):
    log = write_tlog(tmp_path / "two.tlog", attitude=False)
    config = tmp_path / "c.yaml"
    config.write_text(yaml.safe_dump({"link": {"vehicle_system_id": 2}}))
    out = tmp_path / "v2.csv"
    choice = ["--config", str(config)] if chosen_by == "config" else ["--system-id", "2"]
    assert main(["replay", str(log), "-o", str(out), *REF, *choice]) == 0
    assert errors_deg(read_rows(out)[10:], sysid=2).max() < MAX_ERR_DEG
    captured = capsys.readouterr()
    assert captured.out == ""  # no ATTITUDE in the log: no table
    assert not out.with_suffix(".png").exists()
    assert (
        "the log holds other autopilots than system 2, component 1, the one replayed: system 1, component 1 "
        "(--system-id 1 replays it)"
    ) in captured.err


def test_the_other_autopilots_a_log_holds_are_named_with_the_flag_that_replays_them(tmp_path, capsys):
    """A ground station's log of two vehicles: the first autopilot heard is followed, the other named (a ground
    station's and a gimbal's HEARTBEAT are no autopilot's)."""
    log = write_tlog(tmp_path / "two.tlog", attitude=False, gimbal_first=True)
    assert main(["replay", str(log), "-o", str(tmp_path / "v1.csv"), *REF]) == 0
    assert (
        "the log holds other autopilots than system 1, component 1, the one replayed: system 2, component 1 "
        "(--system-id 2 replays it)"
    ) in capsys.readouterr().err
    one = write_tlog(tmp_path / "one.tlog", attitude=False, second_vehicle=False, gimbal_first=True)
    assert main(["replay", str(one), "-o", str(tmp_path / "one.csv"), *REF]) == 0
    assert "other autopilots" not in capsys.readouterr().err


def test_a_gimbal_heartbeat_is_not_taken_for_the_autopilot(tmp_path, capsys):
    # The same lock-on rule as the service (MavlinkLink.is_autopilot_heartbeat): the first HEARTBEAT in the
    # log is a gimbal's, and replay must still follow vehicle 1.
    log = write_tlog(tmp_path / "gimbal.tlog", attitude=False, second_vehicle=False, gimbal_first=True)
    out = tmp_path / "g.csv"
    assert main(["replay", str(log), "-o", str(out), *REF]) == 0
    assert errors_deg(read_rows(out)[10:]).max() < MAX_ERR_DEG
    assert "following the autopilot at system 1, component 1" in capsys.readouterr().err


def test_a_log_without_an_autopilot_heartbeat_follows_nobody_and_says_so(tmp_path, capsys):
    log = write_tlog(tmp_path / "station.tlog", seconds=1.0, second_vehicle=False, heartbeats=False)
    assert main(["replay", str(log), "-o", str(tmp_path / "s.csv"), *REF]) == 2
    err = capsys.readouterr().err
    # the station's 2 HEARTBEATs, 99 RAW_IMU and 10 ATTITUDE of vehicle 1
    assert "no autopilot HEARTBEAT (from link.vehicle_system_id, if set) among its 111 MAVLink messages" in err
    assert "following" not in err


def test_an_empty_log_is_said_to_hold_no_message(tmp_path, capsys):
    log = tmp_path / "empty.tlog"
    log.write_bytes(b"")
    assert main(["replay", str(log), "-o", str(tmp_path / "e.csv"), *REF]) == 2
    assert f"{log}: not one MAVLink message could be read from it" in capsys.readouterr().err


def test_replayed_one_by_one_the_vehicle_followed_is_the_one_locked_on(tmp_path, capsys):
    """A reference that changes mid-log is replayed sample by sample (as live), from the rows of the autopilot
    the log's reading locked on: vehicle 2 here, said once."""
    config = tmp_path / "c.yaml"
    config.write_text(yaml.safe_dump({"link": {"vehicle_system_id": 2}}))
    log = write_tlog(tmp_path / "two.tlog", 10.0, position=True, position_from_s=7.5, attitude=False)
    out = tmp_path / "two.csv"
    assert main(["replay", str(log), "-o", str(out), "--config", str(config)]) == 0
    err = capsys.readouterr().err
    assert err.count("following the autopilot") == 1 and "following the autopilot at system 2, component 1" in err
    assert "magnetic reference from WMM2025" in err  # the position came after the measured field: one by one
    rows = read_rows(out)
    assert len(rows) > 100
    tilt = np.degrees(np.arccos(np.clip(np.cos(np.radians(rows[:, 5])) * np.cos(np.radians(rows[:, 6])), -1, 1)))
    assert np.abs(tilt - 40.0).max() < MAX_ERR_DEG  # vehicle 2 sits rolled 40°; vehicle 1 at 8° and -4°


def test_auto_reference_from_the_logged_position_and_date(tmp_path):
    when = dt.datetime.fromtimestamp(T0_UNIX, dt.timezone.utc).date()
    wmm = np.array(wmm_field_ned_uT(LAT, LON, ALT, when))
    log = write_tlog(tmp_path / "gps.tlog", field_ned_uT=wmm, position=True, second_vehicle=False)
    out = tmp_path / "gps.csv"
    assert main(["replay", str(log), "-o", str(out), "--no-plot"]) == 0
    rows = read_rows(out)
    assert rows[0, 0] >= 0.5  # nothing before the first position
    assert errors_deg(rows[10:]).max() < MAX_ERR_DEG


@pytest.mark.parametrize(
    ("kwargs", "args", "message"),
    [
        ({}, ["--message", "SCALED_IMU"], "no SCALED_IMU from the autopilot"),
        ({"position": False}, [], "holds no position with a fix, and no field was measured from its compass (5 s"),
    ],
)
def test_what_the_log_lacks_is_named(tmp_path, capsys, kwargs, args, message):
    log = write_tlog(tmp_path / "x.tlog", seconds=1.0, second_vehicle=False, **kwargs)
    assert main(["replay", str(log), "-o", str(tmp_path / "x.csv"), *args, *([] if "position" in kwargs else REF)]) == 2
    assert message in capsys.readouterr().err


def yaw_error_deg(rows: np.ndarray) -> np.ndarray:
    """Our yaw minus the truth's, degrees (±180°)."""
    truth = np.degrees(truth_euler_rad(rows[:, 0], 1)[:, 2])
    return (rows[:, 7] - truth + 180.0) % 360.0 - 180.0


def test_without_a_position_the_field_is_measured_from_the_compass(tmp_path, capsys):
    """No position in the log: after the wait (reference.position_wait_s, vehicle time), magnetic north and the
    dip and |B| the compass shows; said in one line and in the summary's reference column."""
    log = write_tlog(tmp_path / "nogps.tlog", seconds=8.0, second_vehicle=False)
    given = write_tlog(tmp_path / "given.tlog", seconds=6.0, second_vehicle=False)
    out = tmp_path / "out"
    config = tmp_path / "given.yaml"  # the summary says which reference each log had: one given for both
    assert main(["replay", str(log), "-o", str(out), "--no-plot"]) == 0
    err = capsys.readouterr().err
    line = next(x for x in err.splitlines() if "no GPS position" in x)
    # the written field: 62.0° dip, 49 µT, with 0.3 µT noise per axis over hundreds of quiet ticks
    assert "heading is magnetic north, field measured from the compass: dip 62.0°, 49.0 µT" in line
    rows = read_rows(out / "nogps.csv")
    assert 5.0 <= rows[0, 0] < 5.1  # the default wait from the first tick (0.01 s)
    # magnetic heading = true heading − declination (here −1.5°): within the bound of the given-field tests
    assert np.abs(yaw_error_deg(rows[10:]) + DECL).max() < MAX_ERR_DEG
    assert main(["replay", str(log), str(given), "-o", str(out), "--no-plot"]) == 0
    with (out / "summary.csv").open() as f:
        assert [r["reference"] for r in csv.DictReader(f)] == ["measured: dip 62.0°, 49.0 µT, magnetic north"] * 2
    config.write_text(yaml.safe_dump({"reference": {"magnetic": {"declination_deg": DECL, "inclination_deg": INCL}}}))
    assert main(["replay", str(log), str(given), "-o", str(out), "--no-plot", "--config", str(config)]) == 0
    with (out / "summary.csv").open() as f:
        assert [r["reference"] for r in csv.DictReader(f)] == ["given: declination -1.5°, inclination 62°"] * 2


def test_a_position_after_the_wait_replaces_the_measured_field(tmp_path, capsys):
    """Measured first, then the WMM at the first position (replayed one by one, as live)."""
    when = dt.datetime.fromtimestamp(T0_UNIX, dt.timezone.utc).date()
    wmm = np.array(wmm_field_ned_uT(LAT, LON, ALT, when))
    declination = np.degrees(np.arctan2(wmm[1], wmm[0]))
    log = write_tlog(tmp_path / "late.tlog", 10.0, wmm, position=True, position_from_s=7.5, second_vehicle=False)
    out = tmp_path / "late.csv"
    assert main(["replay", str(log), "-o", str(out), "--no-plot"]) == 0
    said = [x for x in capsys.readouterr().err.splitlines() if "magnetic" in x]
    assert "field measured from the compass" in said[0] and "magnetic reference from WMM2025 at 47.4000°" in said[1]
    rows = read_rows(out)
    before, after = rows[(rows[:, 0] > 5.2) & (rows[:, 0] < 7.5)], rows[rows[:, 0] > 7.6]
    assert np.abs(yaw_error_deg(before) + declination).max() < MAX_ERR_DEG  # magnetic north
    assert np.abs(yaw_error_deg(after)).max() < MAX_ERR_DEG  # true north


def test_replay_as_a_subprocess(tmp_path):
    log = write_tlog(tmp_path / "sub.tlog", seconds=1.0, second_vehicle=False)
    out = tmp_path / "sub.csv.gz"
    done = run_cli(["replay", str(log), "-o", str(out), *REF, "--no-plot"])
    assert done.returncode == 0, done.stderr
    assert "total angle" in done.stdout
    assert out.stat().st_size > 0 and not (tmp_path / "sub.png").exists()
    # The differences are ours minus the autopilot's, as the table says: yaw ≈ −2°.
    yaw = next(line for line in done.stdout.splitlines() if line.startswith("yaw"))
    assert float(yaw.split()[1]) == pytest.approx(-AUTOPILOT_YAW_OFFSET_DEG, abs=MAX_ERR_DEG / 2)


def test_help_names_every_summary_column(tmp_path):
    """replay --help lists what summary.csv holds: every column a replay writes is named there."""
    from mavattitude.commands import replay

    logs = [write_tlog(tmp_path / f"{n}.tlog", seconds=6.0, second_vehicle=False) for n in ("a", "b")]
    out = tmp_path / "out"
    assert main(["replay", *map(str, logs), "-o", str(out), "--no-plot"]) == 0
    with (out / "summary.csv").open() as f:
        columns = next(csv.reader(f))
    help_text = " ".join(replay.__doc__.split())
    assert [c for c in columns if c not in help_text] == []


def test_the_summary_names_a_sensor_read_in_the_wrong_units(tmp_path, capsys):
    """ArduPilot's RAW_IMU read with --profile adis16405 (3.33 mg per count for 1 mg): with a reference given the
    attitude is solved (each vector normalised), and the summary's units column says what the accelerometer read;
    with the right profile the column is empty."""
    logs = [write_tlog(tmp_path / f"{n}.tlog", seconds=6.0, second_vehicle=False) for n in ("a", "b")]
    out = tmp_path / "out"
    for profile, said in (("adis16405", "accelerometer reads 3.33 g"), ("ardupilot", "")):
        assert main(["replay", *map(str, logs), "-o", str(out), *REF, "--no-plot", "--profile", profile]) == 0
        with (out / "summary.csv").open(encoding="utf-8") as f:
            assert [r["units"] for r in csv.DictReader(f)] == [said] * 2
    assert capsys.readouterr().err.count("--profile adis16405's scale, 0.03266 m/s² per unit") == 2


def test_a_telemetry_log_without_the_configured_message_is_replayed_with_the_one_its_autopilot_sent(tmp_path, capsys):
    """A PX4's telemetry log holds HIGHRES_IMU, not the default RAW_IMU: replayed with it (and said), as a
    directory of logs from several vehicles is; with --message RAW_IMU asked for, refused naming what it sent."""
    from mavattitude.sim.logwriter import static_log
    from mavattitude.sim.logwriter import write_tlog as write_vehicle_tlog

    log = write_vehicle_tlog(tmp_path / "px4.tlog", static_log(10.0, imu_rate_hz=50.0), message="HIGHRES_IMU")
    out = tmp_path / "out"
    assert main(["replay", str(log), "-o", str(out), "--no-plot"]) == 0
    err = capsys.readouterr().err
    assert "the autopilot sent no RAW_IMU: replaying HIGHRES_IMU, the first IMU message it sent" in err
    with (out / "summary.csv").open(encoding="utf-8") as f:
        (row,) = list(csv.DictReader(f))
    assert row["status"] == "ok" and row["rate_handling"].startswith("HIGHRES_IMU at 50.0 Hz")
    # level and still, noise-free but for float32 rounding (its yaw is off by the WMM's declination there, 3.6°:
    # the written field has none)
    assert float(row["roll_rms_deg"]) < 0.1 and float(row["pitch_rms_deg"]) < 0.1 and int(row["compared"]) > 90
    assert main(["replay", str(log), "-o", str(tmp_path / "asked"), "--message", "RAW_IMU"]) == 2
    assert "no RAW_IMU from the autopilot; it sent HIGHRES_IMU: --message HIGHRES_IMU" in capsys.readouterr().err


def test_an_imu_stamped_on_another_clock_than_the_autopilots_attitude_is_said(tmp_path, capsys):
    """RAW_IMU stamped with Unix time (a bridge's, an old firmware's), ATTITUDE with time since boot: nothing can
    be compared, and the refusal to compare says why, as the service does live."""
    log = write_tlog(tmp_path / "unix.tlog", second_vehicle=False, imu_clock_offset_s=1.7e9)
    assert main(["replay", str(log), "-o", str(tmp_path / "unix.csv"), "--no-plot", *REF]) == 0
    said = [line for line in capsys.readouterr().err.splitlines() if "no comparison" in line]
    assert len(said) == 1 and said[0].endswith(" s from our IMU's: stamped with Unix time?)")
    offset_s = float(said[0].split("(its clock ")[1].split(" s from")[0])
    assert offset_s == pytest.approx(-1.7e9, abs=5.0)  # the newest of each, within the log's 3 s


def test_a_log_recorded_twice_over_is_said_and_replays_as_once(tmp_path: Path, capsys: pytest.CaptureFixture[str]):
    """A ground station that heard the vehicle by two routes recorded every RAW_IMU twice: said (the service's words
    for a stream arriving twice), the copies dropped, the attitudes those of the log recorded once."""
    once, twice = write_tlog(tmp_path / "once.tlog"), write_tlog(tmp_path / "twice.tlog", imu_copies=2)
    for log in (once, twice):
        assert main(["replay", str(log), "-o", str(tmp_path / f"{log.stem}.csv"), "--no-plot", *REF]) == 0
    said = [line for line in capsys.readouterr().err.splitlines() if "arrives twice" in line]
    assert len(said) == 1 and f"{twice}: 50 % of the last " in said[0]
    np.testing.assert_array_equal(read_rows(tmp_path / "once.csv"), read_rows(tmp_path / "twice.csv"))
