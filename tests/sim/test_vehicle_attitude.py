"""The fake vehicle's own ATTITUDE (an autopilot's estimate): a log recorded from it replays with the
comparison, and a simulated autopilot error comes out of that comparison."""

from __future__ import annotations

import struct
import time
from pathlib import Path

import pytest
from pymavlink.dialects.v20 import ardupilotmega as mavlink2

from mavattitude.cli import main
from mavattitude.sim import scenarios
from mavattitude.sim.vehicle import FakeVehicle, VehicleConfig
from tests.link.peer import UdpPeer

RECORD_S = 3.0  # 600 RAW_IMU and 30 ATTITUDE: plenty for the comparison's means


def record_tlog(vehicle: FakeVehicle, path: Path, seconds: float) -> None:
    """What a ground station on the vehicle's link records: each datagram after its µs receive time."""
    station = UdpPeer(system=255, component=190)
    station.target = ("127.0.0.1", vehicle.port)
    station.send(station.heartbeat(mavlink2.MAV_AUTOPILOT_INVALID))  # a datagram makes us the vehicle's client
    station.sock.settimeout(0.1)
    end = time.monotonic() + seconds
    with path.open("wb") as f:
        while time.monotonic() < end:
            try:
                data, _ = station.sock.recvfrom(65535)
            except TimeoutError:
                continue
            f.write(struct.pack(">Q", int(time.time() * 1e6)) + data)
    station.close()


def test_a_flight_recorded_from_the_fake_vehicle_replays_against_its_autopilot(tmp_path: Path, capsys) -> None:
    tlog = tmp_path / "flight.tlog"
    config = VehicleConfig("udpin:127.0.0.1:0", stream_on_start=True, attitude_error_deg=(0.0, 2.0, -5.0))
    with FakeVehicle(scenarios.static(60.0), scenarios.paper_sensors(200.0), config) as vehicle:
        record_tlog(vehicle, tlog, RECORD_S)
    field = [str(v) for v in scenarios.DEFAULT_MAG_NED_UT]
    out = tmp_path / "ours.csv"
    assert main(["replay", str(tlog), "-o", str(out), "--mag-ref-ned", *field]) == 0
    table = {line.split()[0]: line.split()[1:] for line in capsys.readouterr().out.splitlines() if line.strip()}
    # ours − autopilot = truth − (truth + error) = −error; paper noise at rest: ours within ~0.3° of the truth.
    assert float(table["roll"][0]) == pytest.approx(0.0, abs=0.3)
    assert float(table["pitch"][0]) == pytest.approx(-2.0, abs=0.3)
    assert float(table["yaw"][0]) == pytest.approx(5.0, abs=0.5)
    assert out.with_suffix(".png").exists()  # the comparison plot


def test_attitude_streams_from_boot_and_stops_when_asked() -> None:
    config = VehicleConfig("udpin:127.0.0.1:0", attitude_rate_hz=20.0, fly_when_asked=True)
    with FakeVehicle(scenarios.static(60.0), scenarios.paper_sensors(200.0), config) as vehicle:
        station = UdpPeer(system=255, component=190)
        station.target = ("127.0.0.1", vehicle.port)
        station.send(station.heartbeat(mavlink2.MAV_AUTOPILOT_INVALID))
        first = station.wait_for("ATTITUDE")
        assert (first.roll, first.pitch, first.yaw) == pytest.approx((0.0, 0.0, 0.0), abs=1e-6)  # static: level, north
        station.send(
            mavlink2.MAVLink_command_long_message(1, 1, 511, 0, mavlink2.MAVLINK_MSG_ID_ATTITUDE, -1, 0, 0, 0, 0, 0)
        )
        station.wait_for("COMMAND_ACK")
        station.received.clear()
        station.poll(0.3)
        station.poll(0.3)
        assert not any(m.get_type() == "ATTITUDE" for m in station.received)
        assert not vehicle.flying  # asking about ATTITUDE does not start the script (only the IMU stream does)
        station.close()
