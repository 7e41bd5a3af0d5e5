"""The .tlog reader: real files written in MAVProxy's format (8-byte µs timestamp + MAVLink packet)."""

from __future__ import annotations

import datetime as dt
import struct
from pathlib import Path

import numpy as np
import pytest
from pymavlink.dialects.v20 import ardupilotmega as mavlink2

from mavattitude.dispatch import Dispatcher
from mavattitude.errors import DataFileError
from mavattitude.estimation.conventions import angle_between
from mavattitude.link.source import PositionFix
from mavattitude.link.tlog import TlogSource, x25_crc


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


def pymavlink_messages(path: Path, types: list[str] | frozenset[str]) -> list:
    """The messages of ``types`` in log order as pymavlink decodes the file: what the array reader must match."""
    from pymavlink import mavutil

    log = mavutil.mavlink_connection(str(path), dialect="ardupilotmega", robust_parsing=True, notimestamps=False)
    try:
        return list(iter(lambda: log.recv_match(type=sorted(types)), None))
    finally:
        log.close()


def test_missing_file_is_a_data_file_error(tmp_path: Path) -> None:
    with pytest.raises(DataFileError, match="no such telemetry log"):
        _source(tmp_path / "nope.tlog", _config())


def test_first_of_reads_the_first_imu_message_the_followed_autopilot_sent(tmp_path: Path) -> None:
    """The log read once: the decoder given ``first_of`` reads the first of them that the autopilot a
    dispatcher locks onto sent after its HEARTBEAT; another system's earlier message does not choose it."""
    from mavattitude.link.source import MavlinkDecoder

    path = tmp_path / "scaled.tlog"
    scaled = dict(time_boot_ms=5, xacc=0, yacc=0, zacc=-1000, xgyro=0, ygyro=0, zgyro=0, xmag=200, ymag=0, zmag=400)
    write_tlog(
        path,
        [(2, "RAW_IMU", _raw(0)), (1, "HEARTBEAT", HEARTBEAT), (1, "SCALED_IMU2", scaled), (1, "RAW_IMU", _raw(1))],
    )
    decoder = MavlinkDecoder.from_config(_config())
    imus = ("RAW_IMU", "SCALED_IMU2", "HIGHRES_IMU")
    assert TlogSource(path, decoder, imus, system_id=1).decoder.message == "SCALED_IMU2"
    source = TlogSource(path, decoder, imus)  # locked onto system 1, the first autopilot HEARTBEAT
    # its HEARTBEAT and SCALED_IMU2, and the RAW_IMU records: each carries a compass, judged beside the IMU's own
    assert source.decoder.message == "SCALED_IMU2" and source.count == 4
    assert TlogSource(path, decoder, imus, system_id=2).decoder.message == "RAW_IMU"  # no lock: its own
    assert TlogSource(path, decoder, ("HIGHRES_IMU",)).decoder.message == "RAW_IMU"  # none: its own


# --- the array reader: every frame kind a ground station records, against pymavlink's decode of the file ---

SIGNING_KEY = bytes(range(32))
UNIX_2027_03_01_US = 1_803_902_400_000_000


def _mixed_log(path: Path) -> list[tuple]:
    """MAVLink 1 and 2 frames, signed and unsigned, payloads shortened by their trailing zeros, from two
    autopilots and a ground station; returns (system, message, byte offset) of each record."""
    from pymavlink.dialects.v10 import ardupilotmega as mavlink1

    v2 = {s: mavlink2.MAVLink(None, srcSystem=s, srcComponent=1) for s in (1, 2, 255)}
    v1 = mavlink1.MAVLink(None, srcSystem=1, srcComponent=1)
    signed = mavlink2.MAVLink(None, srcSystem=1, srcComponent=1)
    signed.signing.secret_key, signed.signing.sign_outgoing, signed.signing.timestamp = SIGNING_KEY, True, 1
    written: list[tuple] = []
    records = []

    def add(mav, system: int, name: str, **fields) -> None:
        if mav is v1:  # MAVLink 1 has no extension fields: read back as zero
            fields = {k: v for k, v in fields.items() if k not in ("id", "temperature")}
        msg = getattr(mav, f"{name.lower()}_encode")(**fields)
        records.append(msg.pack(mav))
        written.append((system, name))

    add(v2[255], 255, "HEARTBEAT", **{**HEARTBEAT, "autopilot": 8, "type": 6})
    add(v2[2], 2, "HEARTBEAT", **HEARTBEAT)
    add(v2[1], 1, "HEARTBEAT", **HEARTBEAT)
    for i in range(60):
        fields = _raw(i) | {"zmag": 0 if i % 3 == 0 else 400, "temperature": 0 if i % 2 else 2500}
        mav = (v2[1], v1, signed)[i % 3]
        add(mav, 1, "RAW_IMU", **fields)
        add(v2[2], 2, "RAW_IMU", **_raw(1000 + i))
        if i % 10 == 0:
            add(v1 if i % 20 else signed, 1, "ATTITUDE", time_boot_ms=10 * i, roll=0.1, pitch=-0.2 * i, yaw=3.0,
                rollspeed=0.0, pitchspeed=0.0, yawspeed=0.0)  # fmt: skip
            add(v2[1], 1, "GLOBAL_POSITION_INT", time_boot_ms=10 * i, lat=474000000 + i, lon=85000000, alt=450000,
                relative_alt=0, vx=0, vy=0, vz=0, hdg=0)  # fmt: skip
        if i == 25:  # the vehicle's GPS date from here on (the log's own day before); a boot-stamped GPS_RAW_INT
            add(v2[1], 1, "SYSTEM_TIME", time_unix_usec=UNIX_2027_03_01_US, time_boot_ms=250)
            add(v2[1], 1, "GPS_RAW_INT", time_usec=62_173_000, fix_type=3, lat=474000000, lon=85000000, alt=450000,
                eph=0, epv=0, vel=0, cog=0, satellites_visible=9)  # fmt: skip
    offset = 0
    with path.open("wb") as f:
        for i, buf in enumerate(records):
            f.write(struct.pack(">Q", 1_700_000_000_000_000 + 5000 * i) + buf)
            written[i] += (offset,)
            offset += 8 + len(buf)
    return written


def _config(**settings):
    from mavattitude.config import load_config

    return load_config(
        None, {"reference.magnetic": {"declination_deg": 0.0, "inclination_deg": 60.0}, **settings}, env={}
    )


def _source(path: Path, config) -> TlogSource:
    from mavattitude.link.source import MavlinkDecoder

    return TlogSource(path, MavlinkDecoder.from_config(config))


def test_the_columns_are_pymavlinks_decode_of_every_frame_kind(tmp_path: Path) -> None:
    path = tmp_path / "mixed.tlog"
    written = _mixed_log(path)
    source = _source(path, _config())
    assert source.count == len(written) and source.bad_records == 0 and source.damage is None
    names = ["HEARTBEAT", "RAW_IMU", "ATTITUDE", "GLOBAL_POSITION_INT", "SYSTEM_TIME", "GPS_RAW_INT"]
    theirs = pymavlink_messages(path, names)
    assert len(theirs) == len(written)
    for name in names:
        table = source.tables[name]
        msgs = [m for m in theirs if m.get_type() == name]
        assert [(m.get_srcSystem(), m.get_srcComponent()) for m in msgs] == [(c >> 8, c & 0xFF) for c in table.sender]
        for field in msgs[0].get_fieldnames():
            assert table.fields[field].tolist() == [getattr(m, field) for m in msgs], (name, field)  # exact


def test_each_record_is_the_live_decoders_item(tmp_path: Path) -> None:
    """recv() hands out what the live link's decoder makes of pymavlink's messages, with the same senders."""
    from mavattitude.link.source import MavlinkDecoder

    path = tmp_path / "mixed.tlog"
    _mixed_log(path)
    config = _config()
    source = _source(path, config)
    ours = []
    while not source.finished:
        ours += source.recv(0.0)
    decode = MavlinkDecoder.from_config(
        config, lambda m: dt.datetime.fromtimestamp(m._timestamp, dt.timezone.utc).date()
    )
    theirs = pymavlink_messages(path, decode.types)
    assert [s for _, s, _ in ours] == [(m.get_srcSystem(), m.get_srcComponent()) for m in theirs]
    assert [item for _, _, item in ours] == [decode(m) for m in theirs]
    dates = [item.date for _, _, item in ours if isinstance(item, PositionFix)]
    assert [str(d) for d in dates] == ["2023-11-14"] * 3 + ["2027-03-01"] * 4  # from SYSTEM_TIME on
    streams = source.streams_for(Dispatcher(None, _Locked(), system_id=1))
    assert streams.date == dates[0] and len(streams.position_t_s) == 7


def test_a_log_clock_that_is_no_date_leaves_the_positions_undated(tmp_path: Path) -> None:
    """Records stamped past any date (a garbled or uninitialised recorder clock) and no GPS time: the positions
    carry no date (the companion's clock decides, as live before a GPS time), one by one and as arrays."""
    path = tmp_path / "garbled-clock.tlog"
    mav = mavlink2.MAVLink(None, srcSystem=1, srcComponent=1)
    position = mav.global_position_int_encode(0, 474000000, 85000000, 450000, 0, 0, 0, 0, 0)
    records = [mav.heartbeat_encode(**HEARTBEAT), position, *(mav.raw_imu_encode(**_raw(i)) for i in range(20))]
    path.write_bytes(b"".join(struct.pack(">Q", 2**63) + r.pack(mav) for r in records))
    config = _config(**{"reference.magnetic": "auto"})
    source = _source(path, config)
    fixes = [item for _, _, item in source.recv(0.0) if isinstance(item, PositionFix)]
    assert len(fixes) == 1 and fixes[0].date is None
    assert _source(path, config).streams_for(Dispatcher(None, _Locked(), system_id=1)).date is None


def test_across_a_reboot_a_position_takes_its_place_by_the_logs_order_at_once_as_one_by_one(tmp_path: Path) -> None:
    """The autopilot rebooted (its clock from 100 s back to 1 s) and found its position after: live, the
    attitudes start at that position; the samples before the reboot, though later in time, have none. Replay
    at once gives what one by one gives (it reads such a log in its own order), with the compass RAW_IMU
    carries replayed, as live, and the second one (SCALED_IMU2's) judged beside it."""
    from mavattitude.estimation.conventions import rotate_ned_to_body
    from mavattitude.replay import replay
    from mavattitude.sensors import units
    from tests.test_dispatch import Peer
    from tests.test_service import G_NED_MPS2, GYRO_RADPS, Q_TRUE, mag_ned_uT

    vehicle, profile = Peer(), units.get_profile("ardupilot")
    messages = {"RAW_IMU": mavlink2.MAVLink_raw_imu_message, "SCALED_IMU2": mavlink2.MAVLink_scaled_imu2_message}
    acc, mag = (tuple(rotate_ned_to_body(Q_TRUE, v)) for v in (G_NED_MPS2, mag_ned_uT()))

    def stream(n: int) -> list[bytes]:  # 200 Hz of RAW_IMU, each followed by SCALED_IMU2 (compass 2) alike
        out = []
        for _ in range(n):
            sample = units.ImuSample(vehicle.time_s, acc, GYRO_RADPS, mag)
            out += [vehicle.pack(message(**units.encode(sample, profile, name))) for name, message in messages.items()]
            vehicle.time_s += 0.005
        return out

    datagrams = [vehicle.heartbeat(), *stream(100)]  # 100 s to 100.5 s
    vehicle.time_s = 1.0
    datagrams += stream(20)
    position = mavlink2.MAVLink_global_position_int_message(0, 474000000, 85000000, 450000, 0, 0, 0, 0, 0)
    datagrams += [vehicle.pack(position), *stream(200)]  # from 1.1 s to 2.1 s
    path = tmp_path / "reboot.tlog"
    path.write_bytes(b"".join(struct.pack(">Q", 1_700_000_000_000_000 + 5000 * i) + d for i, d in enumerate(datagrams)))
    config = _config(**{"reference.magnetic": "auto"})
    at_once, one_by_one = (replay(_source(path, config), config, at_once=a) for a in (True, False))
    outputs = at_once.output_array()
    assert outputs[0, 0] == pytest.approx(1.1) and len(outputs) == 50  # 1.1 s to 2.08 s at 50 Hz
    np.testing.assert_array_equal(outputs, one_by_one.output_array())
    assert at_once.compass_used == "0: RAW_IMU's own, as live"
    assert [j.instance for j in at_once.compasses] == [0, 1]


class _Locked:
    def on_lock(self, vehicle: tuple[int, int]) -> None:
        """Only the lock-on is heard."""


def test_the_vehicle_is_chosen_by_the_dispatchers_rules(tmp_path: Path) -> None:
    """At once, as one by one: the first autopilot heartbeat (not the ground station's), or the configured
    system; every other record counted ignored."""
    from mavattitude.replay import replay

    path = tmp_path / "mixed.tlog"
    written = _mixed_log(path)
    for system in (0, 1):
        config = _config(**{"link.vehicle_system_id": system})
        at_once = replay(_source(path, config), config)
        one_by_one = replay(_source(path, config), config, at_once=False)
        vehicle = system or 2  # system 2's heartbeat comes first
        mine = [n for s, n, _ in written if s == vehicle and n == "RAW_IMU"]
        assert at_once.vehicle == one_by_one.vehicle == (vehicle, 1)
        assert at_once.counters.received == one_by_one.counters.received == len(mine)
        lock = next(i for i, (s, n, _) in enumerate(written) if s == vehicle and n == "HEARTBEAT")
        taken = sum(1 for s, _, _ in written[lock + 1 :] if s == vehicle)
        assert at_once.counters.ignored == one_by_one.counters.ignored == len(written) - taken - 1  # - the lock
        a, b = at_once.output_array(), one_by_one.output_array()
        assert len(a) >= 3 and np.array_equal(a[:, 0], b[:, 0])  # 60 samples 1 ms apart: 50 Hz output
        assert np.max(angle_between(a[:, 1:], b[:, 1:])) < 1e-9  # the vectorised front end: equal to rounding


def test_a_frame_that_fails_its_crc_is_counted_and_skipped(tmp_path: Path) -> None:
    path = tmp_path / "mixed.tlog"
    written = _mixed_log(path)
    imu = [ofs for s, n, ofs in written if s == 1 and n == "RAW_IMU"]
    data = bytearray(path.read_bytes())
    for ofs in imu[4:6]:  # a MAVLink 1 and a signed MAVLink 2 frame: one payload byte each
        data[ofs + 8 + 12] ^= 0x40
    path.write_bytes(bytes(data))
    source = _source(path, _config())
    assert source.bad_records == 2
    assert source.damage == f"damaged: the record at byte {imu[4]} does not decode (CRC)"
    assert len(source.tables["RAW_IMU"].index) == 60 + 60 - 2  # the others read


def test_a_truncated_last_record_ends_the_log_and_is_said(tmp_path: Path) -> None:
    path = tmp_path / "mixed.tlog"
    written = _mixed_log(path)
    last = written[-1][2]
    path.write_bytes(path.read_bytes()[: last + 15])
    source = _source(path, _config())
    assert source.damage is not None and source.damage.startswith(f"truncated: the record at byte {last} is incomplete")
    assert source.count == len(written) - 1 and source.bad_records == 0


def test_bytes_that_start_no_record_are_skipped_to_the_next_frame(tmp_path: Path) -> None:
    path = tmp_path / "mixed.tlog"
    written = _mixed_log(path)
    cut = written[10][2]
    data = path.read_bytes()
    path.write_bytes(data[:cut] + b"\x00" * 7 + data[cut:])
    source = _source(path, _config())
    assert source.damage == f"damaged: 7 byte(s) skipped, the first at byte {cut}"
    assert source.count == len(written)


def test_bytes_inserted_inside_records_cost_those_records_alone(tmp_path: Path) -> None:
    """A radio's or a disk's damage: runs of bytes inserted inside records (some holding a MAVLink magic). Each
    costs the record it lands in, never the ones after: framing resumes at the next receive time in step with the
    log's. (Resuming at the next magic alone took a payload's 0xFD for a record and framed on out of step.)"""
    path = tmp_path / "imu.tlog"
    n = 2000
    write_tlog(path, [(1, "HEARTBEAT", HEARTBEAT)] + [(1, "RAW_IMU", _raw(i) | {"xacc": i % 256}) for i in range(n)])
    data = bytearray(path.read_bytes())
    rng = np.random.default_rng(11)
    record = len(data) // (n + 1)  # every RAW_IMU record is the same length here (and the HEARTBEAT near it)
    hit = sorted(rng.choice(np.arange(10, n - 10), 12, replace=False).tolist(), reverse=True)
    for k in hit:  # from the end, so the offsets before stay right
        junk = rng.integers(0, 256, 37, dtype=np.uint8)
        junk[rng.integers(0, 37, 3)] = 0xFD
        at = int(k * record + rng.integers(0, record))
        data[at:at] = junk.tobytes()
    path.write_bytes(bytes(data))
    source = _source(path, _config())
    kept = len(source.tables["RAW_IMU"].index)
    assert n - len(hit) <= kept < n and source.damage is not None
    t_us = source.tables["RAW_IMU"].fields["time_usec"]
    assert np.diff(t_us).max() <= 2000  # no gap longer than the one record lost (1 ms apart)


@pytest.mark.parametrize("length", [0, 1, 30, 31])
def test_the_crc_is_mavlinks_x25(length: int) -> None:
    from pymavlink.mavutil import x25crc

    rng = np.random.default_rng(7)
    strings = rng.integers(0, 256, size=(50, length), dtype=np.uint8)
    extra = rng.integers(0, 256, size=50, dtype=np.uint8)
    ours = x25_crc(strings, extra)
    assert ours.tolist() == [x25crc(bytes(s) + bytes([e])).crc for s, e in zip(strings, extra, strict=True)]


@pytest.mark.parametrize("damage", ["none", "truncated", "skipped", "crc", "receive_time_zero"])
def test_framing_the_whole_log_at_once_is_framing_it_record_by_record(tmp_path: Path, damage: str) -> None:
    from mavattitude.link.tlog import _frame, _frame_by_record, _frame_whole

    written = _mixed_log(tmp_path / "mixed.tlog")
    data = bytearray((tmp_path / "mixed.tlog").read_bytes())
    cut = written[10][2]
    if damage == "truncated":
        data = data[: written[-1][2] + 15]
    elif damage == "skipped":
        data[cut:cut] = b"\x00" * 7
    elif damage == "crc":
        data[cut + 8 + 12] ^= 0x40
    elif damage == "receive_time_zero":  # every record's time zero: its top bytes are no record's mark
        for _, _, ofs in written:
            data[ofs : ofs + 8] = bytes(8)
    starts, *rest = _frame(bytes(data))
    one_by_one, *rest_by_record = _frame_by_record(bytes(data))
    assert starts.tolist() == one_by_one and rest == rest_by_record
    # at once where nothing is skipped (a CRC is framing's business no more than a cut-short end)
    assert (_frame_whole(bytes(data)) is not None) == (damage != "skipped")
