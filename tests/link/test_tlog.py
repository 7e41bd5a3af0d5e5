"""The .tlog reader: real files written in MAVProxy's format (8-byte µs timestamp + MAVLink packet)."""

from __future__ import annotations

import struct
from pathlib import Path

import pytest
from pymavlink.dialects.v20 import ardupilotmega as mavlink2

from mavattitude.errors import DataFileError
from mavattitude.link.tlog import read_messages


def write_tlog(path: Path, packets: list[tuple[int, str, dict]]) -> None:
    """``packets``: (system id, message name, fields) in order."""
    with path.open("wb") as f:
        for i, (system, name, fields) in enumerate(packets):
            mav = mavlink2.MAVLink(None, srcSystem=system, srcComponent=1)
            msg = getattr(mav, f"{name.lower()}_encode")(**fields)
            f.write(struct.pack(">Q", 1_700_000_000_000_000 + 5000 * i) + msg.pack(mav))


HEARTBEAT = dict(type=2, autopilot=3, base_mode=0, custom_mode=0, system_status=4)


def _raw(i: int) -> dict:
    return dict(time_usec=1000 * i, xacc=i, yacc=0, zacc=-1000, xgyro=0, ygyro=0, zgyro=0, xmag=200, ymag=0, zmag=400)


def test_reads_the_requested_types_in_order_and_filters_the_system(tmp_path: Path) -> None:
    path = tmp_path / "flight.tlog"
    packets = [(1, "HEARTBEAT", HEARTBEAT)]
    packets += [(1 if i % 4 else 2, "RAW_IMU", _raw(i)) for i in range(20)]
    write_tlog(path, packets)
    got = list(read_messages(path, {"RAW_IMU"}))
    assert [m.xacc for m in got] == list(range(20))
    ones = list(read_messages(path, ["RAW_IMU", "HEARTBEAT"], system_id=1))
    assert ones[0].get_type() == "HEARTBEAT"
    assert [m.xacc for m in ones[1:]] == [i for i in range(20) if i % 4]


def test_missing_file_is_a_data_file_error(tmp_path: Path) -> None:
    with pytest.raises(DataFileError, match="no such telemetry log"):
        list(read_messages(tmp_path / "nope.tlog", {"RAW_IMU"}))
