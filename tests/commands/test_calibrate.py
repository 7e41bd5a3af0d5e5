"""`mavattitude calibrate mag`: from a CSV, a .tlog and live over real UDP; the YAML it writes; refusals."""

from __future__ import annotations

import argparse
import gzip
import io
import itertools
import logging
import socket
import threading
import time
import warnings
from pathlib import Path

import numpy as np
import pytest
import yaml
from pymavlink import mavutil

from mavattitude.cli import main
from mavattitude.commands.calibrate import _collect, _live, _live_samples
from mavattitude.config import from_dict
from mavattitude.link.mavlink2 import mavlink2
from mavattitude.sensors.calibration import Calibration
from mavattitude.sensors.units import ImuSample, encode, get_profile
from mavattitude.sim import logwriter, scenarios
from mavattitude.sim.logwriter import SensorLog, write_dataflash
from mavattitude.sim.vehicle import FakeVehicle, VehicleConfig
from tests.link.test_tlog import HEARTBEAT, write_tlog

OFFSET = np.array([18.0, -25.0, 9.0])
DISTORTION = np.array([[1.15, 0.03, 0.0], [0.03, 0.9, 0.02], [0.0, 0.02, 1.05]])


def _distorted(n: int, seed: int = 0) -> np.ndarray:
    rng = np.random.default_rng(seed)
    u = rng.normal(size=(n, 3))
    field = 48.0 * u / np.linalg.norm(u, axis=1, keepdims=True) + rng.normal(0.0, 0.2, (n, 3))
    return field @ DISTORTION.T + OFFSET


def _check_yaml(path: Path) -> Calibration:
    data = yaml.safe_load(path.read_text())
    assert set(data) == {"calibration"} and set(data["calibration"]) == {"mag"}
    assert set(data["calibration"]["mag"]) == {"hard_iron_uT", "soft_iron"}
    cal = from_dict(data).calibration
    corrected = (_distorted(500, seed=9) - cal.mag.hard_iron_uT) @ np.asarray(cal.mag.soft_iron).T
    norms = np.linalg.norm(corrected, axis=1)
    assert np.std(norms) / np.mean(norms) < 0.01  # 0.2 µT noise on 48 µT and the integer rounding: ~0.5 %
    return cal


def test_from_csv_writes_the_mag_block_and_reports(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    src = tmp_path / "turns.csv.gz"
    with gzip.open(src, "wt") as f:
        f.write("t_s,mag_x_uT,mag_y_uT,mag_z_uT,mag_new\n")
        for i, row in enumerate(_distorted(1200)):
            f.write(f"{i * 0.01},{row[0]},{row[1]},{row[2]},1\n")
            f.write(f"{i * 0.01 + 0.005},{row[0] + 99},{row[1]},{row[2]},0\n")  # a repeat, skipped
    out = tmp_path / "mag.yaml"
    assert main(["calibrate", "mag", str(src), "-o", str(out), "--field-uT", "48"]) == 0
    cal = _check_yaml(out)
    assert np.asarray(cal.mag.hard_iron_uT) == pytest.approx(OFFSET, abs=0.2)
    text = capsys.readouterr().out
    assert "1200 samples" in text and "|B| spread" in text and "before" in text and "residual" in text


@pytest.mark.parametrize(
    ("message", "name"), [("RAW_IMU", "turns.tlog"), ("SCALED_IMU2", "turns.tlog"), ("RAW_IMU", "turns.mavlink")]
)
def test_from_a_tlog(tmp_path: Path, message: str, name: str) -> None:
    """Without --message, the first of the profile's IMU messages that the autopilot's log holds; a telemetry log
    under another name is known by its frames, not opened as a serial port."""
    profile = get_profile("ardupilot")
    packets = [(2, message, encode(ImuSample(0.0, (0.0, 0.0, -9.8), (0.0,) * 3, (99.0,) * 3), profile, message))]
    packets += [(1, "HEARTBEAT", HEARTBEAT)]  # the autopilot, locked onto as the service does: not system 2
    packets += [
        (1, message, encode(ImuSample(i * 0.01, (0.0, 0.0, -9.8), (0.0, 0.0, 0.0), tuple(m)), profile, message))
        for i, m in enumerate(_distorted(1000))
    ]
    log = tmp_path / name
    write_tlog(log, packets)
    out = tmp_path / "mag.yaml"
    assert main(["calibrate", "mag", str(log), "-o", str(out), "--profile", "ardupilot"]) == 0
    _check_yaml(out)


def test_from_a_tlog_of_two_vehicles_the_followed_one_names_the_imu_message(tmp_path: Path) -> None:
    # The ground station heard vehicle 1 first (its HEARTBEAT is the one locked onto, as replay and the service
    # lock), then vehicle 2's SCALED_IMU2 half a second before vehicle 1's first RAW_IMU. The IMU message was
    # the log's first of any system: SCALED_IMU2, which vehicle 1 never sent, so no reading was found.
    mags = _distorted(1000)
    t = 1.0 + np.arange(len(mags)) * 0.01
    level = np.tile([0.0, 0.0, -9.8], (len(t), 1))
    ours = SensorLog(t, level, np.zeros((len(t), 3)), t, mags)
    other = SensorLog(t - 0.5, level, np.zeros((len(t), 3)), t - 0.5, np.tile([20.0, 0.0, 40.0], (len(t), 1)))
    log = logwriter.write_tlog(tmp_path / "two.tlog", ours, system=1, others=[(other, 2, "SCALED_IMU2")])
    out = tmp_path / "mag.yaml"
    assert main(["calibrate", "mag", str(log), "-o", str(out)]) == 0
    cal = _check_yaml(out)
    assert np.asarray(cal.mag.hard_iron_uT) == pytest.approx(OFFSET, abs=0.3)  # RAW_IMU's milligauss: 0.1 µT steps


def test_from_a_dataflash_log(tmp_path: Path) -> None:
    mags = _distorted(1000)
    t = np.arange(len(mags)) * 0.01
    flight = SensorLog(t, np.tile([0.0, 0.0, -9.8], (len(t), 1)), np.zeros((len(t), 3)), t, mags)
    out = tmp_path / "mag.yaml"
    assert main(["calibrate", "mag", str(write_dataflash(tmp_path / "turns.bin", flight)), "-o", str(out)]) == 0
    cal = _check_yaml(out)
    assert np.asarray(cal.mag.hard_iron_uT) == pytest.approx(OFFSET, abs=0.3)  # int16 milligauss: 0.05 µT steps


def test_poor_coverage_is_refused_with_exit_2(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    src = tmp_path / "bench.csv"
    rows = _distorted(3000)
    rows = rows[rows[:, 2] > OFFSET[2] + 35]  # one attitude only
    src.write_text("mag_x_uT,mag_y_uT,mag_z_uT\n" + "\n".join(",".join(map(str, r)) for r in rows))
    assert main(["calibrate", "mag", str(src), "-o", str(tmp_path / "x.yaml")]) == 2
    assert "cover" in capsys.readouterr().err and not (tmp_path / "x.yaml").exists()


@pytest.mark.parametrize(("scale", "field", "warned"), [(0.01, None, True), (0.01, "48", False), (1.0, None, False)])
def test_readings_whose_field_is_not_the_earths_in_uT_are_warned_about(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], scale: float, field: str | None, warned: bool
) -> None:
    """A CSV in gauss fits |B| ≈ 0.5, far below the Earth's 22-67 µT: said, with the units to check, and still
    written (a sensor whose scale is off is calibrated too); not with --field-uT, which scales it to µT."""
    src = tmp_path / "turns.csv"
    src.write_text("mag_x_uT,mag_y_uT,mag_z_uT\n" + "\n".join(",".join(map(str, r)) for r in scale * _distorted(1000)))
    out = tmp_path / "mag.yaml"
    assert main(["calibrate", "mag", str(src), "-o", str(out), *(["--field-uT", field] if field else [])]) == 0
    assert out.exists() and ("gauss (100 µT)" in capsys.readouterr().err) == warned


def test_missing_columns_are_a_user_error(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    src = tmp_path / "bad.csv"
    src.write_text("t_s,mx,my,mz\n0,1,2,3\n")
    assert main(["calibrate", "mag", str(src), "-o", str(tmp_path / "x.yaml")]) == 2
    assert "missing column(s) mag_x_uT" in capsys.readouterr().err


def test_live_over_udp_asks_for_the_stream_and_shows_coverage(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    stop = threading.Event()
    requests: list[object] = []
    profile = get_profile("ardupilot")

    def vehicle() -> None:
        """An autopilot that, as ArduPilot Copter, streams RAW_IMU only once asked."""
        conn = mavutil.mavlink_connection(f"udpout:127.0.0.1:{port}", source_system=1, dialect="common")
        conn.mav.WIRE_PROTOCOL_VERSION = "2.0"
        mags = _distorted(4000, seed=3)
        i = 0
        while not stop.is_set():
            if i % 400 == 0:
                conn.mav.heartbeat_send(mavlink2.MAV_TYPE_QUADROTOR, mavlink2.MAV_AUTOPILOT_ARDUPILOTMEGA, 0, 0, 0)
            msg = conn.recv_msg()
            if msg is not None and msg.get_type() == "COMMAND_LONG":
                requests.append(msg)
            if requests:  # turning at 1 rad/s: not at rest
                sample = ImuSample(i * 0.005, (0.0, 0.0, -9.8), (0.0, 0.0, 1.0), tuple(mags[i % 4000]))
                conn.mav.raw_imu_send(**encode(sample, profile, "RAW_IMU"))
            i += 1
            stop.wait(0.0005)  # pacing the sender, about 2 kHz
        conn.close()

    sender = threading.Thread(target=vehicle, daemon=True)
    sender.start()
    out = tmp_path / "live.yaml"
    try:
        code = main(["calibrate", "mag", f"udpin:127.0.0.1:{port}", "-o", str(out), "--duration", "30"])
    finally:
        stop.set()
        sender.join(5.0)
    assert code == 0
    _check_yaml(out)
    assert requests and requests[0].command == mavlink2.MAV_CMD_SET_MESSAGE_INTERVAL
    assert requests[0].param1 == mavlink2.MAVLINK_MSG_ID_RAW_IMU and requests[0].param2 == 1e6 / 50.0
    # as a second onboard computer: run beside the service, it does not take the service's 191
    assert requests[0].get_srcComponent() == mavlink2.MAV_COMP_ID_ONBOARD_COMPUTER2
    err = capsys.readouterr().err
    assert "coverage [" in err and "at rest" not in err


def test_live_on_a_px4_asked_for_raw_imu_ends_at_once_saying_why(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """A PX4 has no RAW_IMU, the default profile's message: the collection ends on locking on, not after
    --duration's 180 s of nothing, and the error says what to give instead."""
    config = VehicleConfig("udpin:127.0.0.1:0", profile="px4", message="HIGHRES_IMU")
    with FakeVehicle(scenarios.paper_static(60.0), scenarios.paper_sensors(100.0), config) as vehicle:
        start = time.monotonic()
        code = main(["calibrate", "mag", f"udpout:127.0.0.1:{vehicle.port}", "-o", str(tmp_path / "x.yaml")])
        took_s = time.monotonic() - start
    assert code == 2
    assert capsys.readouterr().err.endswith(
        "no magnetometer readings found: the autopilot is a PX4 (its HEARTBEAT), which has no RAW_IMU stream: "
        "--profile px4 reads its HIGHRES_IMU\n"
    )
    assert took_s < 30.0  # its first HEARTBEAT within a second or two of ours; the default --duration is 180 s


def test_live_a_refused_stream_is_said_in_the_commands_words(caplog: pytest.LogCaptureFixture) -> None:
    """The autopilot refusing the IMU message: the fix said is the command's flag, not the service's config key."""
    from mavattitude.link.memory import MemoryLink

    link = MemoryLink()
    live = _live(link, argparse.Namespace(message="SCALED_IMU3", profile="ardupilot", duration=30.0))
    now = time.monotonic()
    live.session.lock((1, 1), now)
    live.session.tick(now)
    autopilot = mavlink2.MAVLink(None, srcSystem=1, srcComponent=1)
    result = mavlink2.MAV_RESULT_DENIED
    denied = autopilot.command_ack_encode(mavlink2.MAV_CMD_SET_MESSAGE_INTERVAL, result, 0, 0, 1, 191)
    denied.pack(autopilot)
    with caplog.at_level(logging.WARNING, logger="mavattitude.link.session"):
        live.session.on_message(denied, now)
    assert [r.getMessage() for r in caplog.records] == [
        "autopilot answered SET_MESSAGE_INTERVAL(SCALED_IMU3 at 50 Hz) with DENIED; --message asks for another IMU "
        "message"
    ]


def test_live_reads_the_chosen_autopilot_as_the_service_does() -> None:
    """Live, through the service's message source and dispatcher: a ground station, a second autopilot and
    an undecodable message are not read; only the chosen system is locked onto, asked and read."""
    from mavattitude.link.memory import MemoryLink

    links = {s: mavlink2.MAVLink(None, srcSystem=s, srcComponent=1) for s in (1, 2, 255)}
    link = MemoryLink()
    link.deliver(links[255].heartbeat_encode(6, mavlink2.MAV_AUTOPILOT_INVALID, 0, 0, 0).pack(links[255]))
    for system in (1, 2):
        link.deliver(
            links[system].heartbeat_encode(2, mavlink2.MAV_AUTOPILOT_ARDUPILOTMEGA, 0, 0, 4).pack(links[system])
        )
    link.deliver(links[2].raw_imu_encode(0, 0, 0, -1000, 0, 0, 0, 30000, 30000, 30000).pack(links[2]))  # 5196 µT

    def imu(first: int) -> None:
        for i in range(first, first + 10):
            for system in (1, 2):
                fields = dict(time_usec=1000 * i, xacc=system, yacc=0, zacc=-1000, xgyro=0, ygyro=0, zgyro=0)
                link.deliver(links[system].raw_imu_encode(**fields, xmag=200 + i, ymag=0, zmag=400).pack(links[system]))

    args = argparse.Namespace(message=None, profile="ardupilot", system_id=2, duration=30.0)
    samples = _live_samples(link, args, _live(link, args))
    imu(0)
    first = list(itertools.islice(samples, 10))
    imu(10)  # read after the next periodic work: the request goes out on locking
    both = first + list(itertools.islice(samples, 10))
    assert [s.acc_mps2[0] for s in both] == [2 * 9.80665e-3] * 20  # system 2's, each once
    assert [s.mag_uT[0] for s in both] == pytest.approx([(200 + i) * 0.1 for i in range(20)])
    asked = [m for m in link.sent() if m.get_type() == "COMMAND_LONG"]
    assert asked and {(m.target_system, m.target_component) for m in asked} == {(2, 1)}
    assert asked[0].param1 == mavlink2.MAVLINK_MSG_ID_RAW_IMU


def test_a_vehicle_at_rest_covers_nothing_and_is_told_to_turn() -> None:
    rest = np.array([20.0, 5.0, 40.0]) + np.random.default_rng(2).normal(0.0, 0.3, (1000, 3))
    samples = [ImuSample(i * 0.01, (0.0, 0.0, -9.8), (0.001, 0.0, 0.0), tuple(m)) for i, m in enumerate(rest)]
    out = io.StringIO()
    args = argparse.Namespace(input="live", min_coverage=0.6)
    _collect(samples, args, out, live=True)
    lines = out.getvalue().splitlines()
    # noise around the midpoint points every way: before, that read as 100 % of orientations
    assert lines and all(" 0% of orientations" in line for line in lines)
    assert all(line.endswith("the vehicle is at rest, turn it through every orientation") for line in lines)


def test_a_reading_its_messages_repeat_is_taken_once() -> None:
    readings = _distorted(300, seed=3)
    # five RAW_IMU messages per compass reading, as ArduPilot streams a 10 Hz compass in a 50 Hz RAW_IMU
    samples = [
        ImuSample(0.02 * i, (0.0, 0.0, -9.8), (0.0, 0.0, 0.1), tuple(readings[i // 5]), mag_repeats=True)
        for i in range(5 * len(readings))
    ]
    args = argparse.Namespace(min_coverage=0.6, input="x")
    assert np.array_equal(_collect(samples, args, io.StringIO(), live=False), readings)
    # a message that does not repeat (HIGHRES_IMU says when it has a new reading) keeps every one
    plain = [ImuSample(s.time_s, s.acc_mps2, s.gyr_radps, s.mag_uT) for s in samples]
    assert len(_collect(plain, args, io.StringIO(), live=False)) == len(samples)


def test_the_written_block_is_a_config_the_front_end_applies(tmp_path: Path) -> None:
    from mavattitude.config import load_config
    from mavattitude.pipeline import frontend_settings
    from mavattitude.sensors.frontend import FrontEnd

    src = tmp_path / "turns.csv"
    src.write_text("mag_x_uT,mag_y_uT,mag_z_uT\n" + "\n".join(",".join(map(str, r)) for r in _distorted(800)))
    out = tmp_path / "mag.yaml"
    assert main(["calibrate", "mag", str(src), "-o", str(out), "--field-uT", "48"]) == 0
    config = load_config(out, env={})
    fe = FrontEnd(frontend_settings(config, filter_enabled=False))
    raw = _distorted(1, seed=5)[0]
    (tick,) = fe.push(ImuSample(1.0, (0.0, 0.0, -9.8), (0.0, 0.0, 0.0), tuple(raw)))
    assert np.linalg.norm(tick.mag_uT) == pytest.approx(48.0, abs=0.5)  # 0.2 µT noise, the fit's residual


def test_a_vehicle_left_at_rest_is_told_to_turn_not_diagnosed(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    src = tmp_path / "static.csv"
    rows = np.array([20.0, 5.0, 40.0]) + np.random.default_rng(1).normal(0.0, 0.3, (2000, 3))  # at rest: noise only
    src.write_text("mag_x_uT,mag_y_uT,mag_z_uT\n" + "\n".join(",".join(map(str, r)) for r in rows))
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # no numpy warning on the way (a negative determinant's cube root was one)
        assert main(["calibrate", "mag", str(src), "-o", str(tmp_path / "x.yaml")]) == 2
    err = capsys.readouterr().err.splitlines()
    assert err[-1].startswith(f"mavattitude calibrate: error: {src}: the vehicle was not turned: the readings span")
    assert "soft-iron" not in err[-1]


class _Terminal(io.StringIO):
    def isatty(self) -> bool:
        return True


@pytest.mark.parametrize("stream", [io.StringIO, _Terminal])
def test_progress_is_redrawn_on_a_terminal_and_plain_lines_elsewhere(stream: type[io.StringIO]) -> None:
    out = stream()
    samples = [
        ImuSample(0.005 * i, (0.0, 0.0, -9.8), (0.0, 0.0, 0.0), tuple(m)) for i, m in enumerate(_distorted(1000))
    ]
    args = argparse.Namespace(min_coverage=0.6, input="x")
    _collect(samples, args, out, live=False)
    text = out.getvalue()
    assert "coverage [" in text
    if stream is _Terminal:
        assert text.count("\r") == 10 and text.endswith("\n")  # one redraw per 100 samples
    else:
        lines = text.splitlines()
        assert "\r" not in text and 1 <= len(lines) < 10  # a line when the coverage changes, not per 100 samples
        assert all(line.startswith("coverage [") for line in lines)


def test_the_running_coverage_counts_as_a_count_over_all_readings_would() -> None:
    from mavattitude.commands.calibrate import _Coverage
    from mavattitude.sensors import magfit

    readings = _distorted(3000, seed=4)
    running = _Coverage()
    for end in range(100, len(readings) + 1, 100):
        seen = readings[:end]
        expected = magfit.coverage(seen - (seen.max(axis=0) + seen.min(axis=0)) / 2.0)[1]
        assert np.array_equal(running.add(readings[end - 100 : end]), expected)
