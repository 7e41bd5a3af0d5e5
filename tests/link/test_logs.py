"""Log sources: DataFlash written here byte for byte as ArduPilot does, the shared real logs, and bad files."""

from __future__ import annotations

import dataclasses
import datetime as dt
import gzip
import struct

import numpy as np
import pytest

from mavattitude.errors import DataFileError
from mavattitude.files import LOG_SUFFIXES
from mavattitude.link.dataflash import read_dataflash
from mavattitude.link.logs import FORMATS, detect_format, open_log
from mavattitude.link.logstreams import LOG_VEHICLE, StreamSource
from mavattitude.link.source import AutopilotAttitude, PositionFix
from mavattitude.link.ulog import cut_at, read_ulog
from mavattitude.sensors.units import ImuSample
from mavattitude.sim.logwriter import LAYOUTS, static_log, write_dataflash
from tests.link.test_tlog import HEARTBEAT, _raw, write_tlog
from tests.shared import shared_path
from tests.test_service import make_config


@pytest.mark.parametrize("layout", LAYOUTS)
@pytest.mark.parametrize("instance", [0, 1])
def test_dataflash_every_layout_and_instance_read_back(tmp_path, layout, instance):
    log = static_log(2.0, yaw_rate_dps=10.0)
    path = write_dataflash(tmp_path / "x.bin", log, layout=layout, instances=2)
    s = read_dataflash(path, instance, instance)
    gain = 1.0 + instance / 100.0  # the writer's mark of each instance
    new = layout >= "3.3"
    tick_s = 1e-6 if new else 1e-3  # TimeUS or TimeMS
    assert s.imu_t_s == pytest.approx(log.imu_t_s, abs=0.501 * tick_s)  # rounded to the tick (+ float error)
    assert s.acc_mps2 == pytest.approx(log.acc_mps2 * gain, rel=1e-6)  # float32 fields
    assert s.mag_uT == pytest.approx(log.mag_uT * gain, abs=0.05)  # int16 milligauss: 0.05 µT rounding
    assert s.time_wrap_s == (None if new else 2**32 / 1000)
    assert len(s.attitude_t_s) == 20 and s.position[0].tolist() == pytest.approx([47.4, 8.5, 450.0], abs=1e-6)
    assert s.damage is None


@pytest.mark.parametrize("layout", LAYOUTS)
def test_positions_times_and_the_date_of_every_layout(tmp_path, layout):
    """POS where the layout has it, else the GPS records with a 3D fix (GPS and GPS2, or instances), each at
    its time since boot (TimeUS, an old GPS's T, or before 3.1 the log's order: the IMU record before it), and
    the date from the GPS week (GWk/GMS, or Week/TimeMS)."""
    log = static_log(4.0, imu_rate_hz=50.0)
    day = dt.date(2014, 8, 20)  # 00:00 UTC is GPS week 1806 + 3 days, plus the 16 leap seconds of 2014
    log.gps_time_s = (day - dt.date(1980, 1, 6)).days * 86_400.0 + 16.0
    s = read_dataflash(write_dataflash(tmp_path / "g.bin", log, layout=layout, instances=2))
    receivers = 1 if layout in ("4.1", "3.0") else 2  # 4.1: POS; 3.0: no GPS2
    assert len(s.position_t_s) == receivers * len(log.position_t_s)
    assert np.abs(s.position - [47.4, 8.5, 450.0]).max() < 1e-6  # 1e-7 ° and 1 cm are the logged resolutions
    # the old GPS logged no time since boot: the IMU record before it (50 Hz: at most 20 ms before)
    bound_s = 0.0201 if layout == "3.0" else 0.0011
    assert np.repeat(log.position_t_s, receivers) - s.position_t_s == pytest.approx(0.0, abs=bound_s)
    assert s.date == day
    attitude = read_dataflash(write_dataflash(tmp_path / "a.bin", log, layout=layout)).attitude_t_s
    assert attitude == pytest.approx(log.attitude_t_s, abs=0.0011)  # to the ms of TimeMS


def test_gps_records_without_a_fix_are_no_position(tmp_path):
    log = static_log(2.0, imu_rate_hz=50.0)
    path = write_dataflash(tmp_path / "n.bin", log, layout="3.2")
    data = bytearray(path.read_bytes())
    status = 3  # the GPS record's first field, right after its 3-byte header (type 130 in the 3.2 layout)
    for at in [i for i in range(len(data) - 3) if data[i : i + 3] == b"\xa3\x95\x82"]:
        data[at + status] = 1  # no fix
    path.write_bytes(bytes(data))
    s = read_dataflash(path)
    assert len(s.position_t_s) == 0 and s.date is None


def test_a_slower_magnetometer_is_carried_once_by_the_first_sample_at_or_after_it(tmp_path):
    log = static_log(2.0, imu_rate_hz=400.0, mag_rate_hz=10.0)
    log.mag_t_s = log.mag_t_s + 0.0013  # between two IMU samples
    source = StreamSource("x", read_dataflash(write_dataflash(tmp_path / "m.bin", log)))
    items = []
    while not source.finished:
        items += source.recv()
    samples = [item for _, sender, item in items if isinstance(item, ImuSample)]
    assert {sender for _, sender, _ in items} == {LOG_VEHICLE}
    with_mag = [s for s in samples if s.mag_uT is not None]
    assert len(with_mag) == len(log.mag_t_s)  # each reading once; the front end holds it in between
    for sample, t_mag in zip(with_mag, log.mag_t_s, strict=True):
        assert 0.0 <= sample.time_s - t_mag < 1 / 400.0  # never before the reading: no look into the future
    assert sum(isinstance(i, AutopilotAttitude) for _, _, i in items) == 20
    assert sum(isinstance(i, PositionFix) for _, _, i in items) == 10
    times = [t for t, _, _ in items]
    assert times == sorted(times)


def test_a_truncated_log_is_read_up_to_the_cut_and_says_where(tmp_path):
    path = write_dataflash(tmp_path / "t.bin", static_log(2.0))
    data = path.read_bytes()
    cut = len(data) * 2 // 3 + 5
    path.write_bytes(data[:cut])
    s = read_dataflash(path)
    assert s.damage is not None and s.damage.startswith("truncated: the ")
    at = int(s.damage.split("at byte ")[1].split()[0])
    assert cut - 60 < at < cut  # the last record, which began before the cut
    assert 0.6 * 800 < len(s.imu_t_s) < 0.7 * 800  # two thirds of the samples


def test_what_pyulog_prints_of_a_damaged_log_goes_to_the_log_not_to_stdout(tmp_path, capsys, caplog):
    """33 bytes missing from the middle of sample.ulg: pyulog prints a warning on stdout, where `replay` writes
    its table; it is logged at debug level instead, and the damage is the log's."""
    data = shared_path("data", "px4", "sample.ulg").read_bytes()
    damaged = tmp_path / "damaged.ulg"
    damaged.write_bytes(data[:2_648_952] + data[2_648_952 + 33 :])
    caplog.set_level("DEBUG", logger="mavattitude.link.ulog")
    s = read_ulog(damaged)
    assert capsys.readouterr().out == ""
    assert s.damage == "damaged: pyulog skipped what it could not read"
    assert any(r.getMessage().startswith("pyulog: Warning: no subscription found") for r in caplog.records)


def test_a_log_cut_inside_a_record_replay_does_not_read_is_said_truncated(tmp_path):
    """A cut inside the last record whatever its type (here a RATE record: no table replay reads), not only inside
    the IMU, MAG, ATT, GPS or PARM records."""
    from pymavlink import DFReader

    whole = shared_path("data", "ardupilot-sitl", "lowrate.BIN")
    index = DFReader.DFReader_binary(str(whole), zero_time_base=False)
    offsets = index.offsets[index.name_to_id["RATE"]]
    at = int(offsets[len(offsets) // 2])
    cut = tmp_path / "cut.bin"
    cut.write_bytes(whole.read_bytes()[: at + 5])
    s = read_dataflash(cut)
    assert s.damage == f"truncated: the RATE record at byte {at} is incomplete"
    assert read_dataflash(whole).damage is None


def test_damaged_bytes_are_skipped_and_said(tmp_path):
    path = write_dataflash(tmp_path / "d.bin", static_log(2.0))
    data = bytearray(path.read_bytes())
    middle = data.index(b"\xa3\x95\x81", len(data) // 2)  # from an IMU record's first byte on
    data[middle : middle + 40] = b"\xff" * 40  # no record header left in there: DFReader skips to the next one
    path.write_bytes(bytes(data))
    s = read_dataflash(path)
    assert s.damage is not None and s.damage.startswith("damaged: ")
    assert s.damage.endswith(f"the first at byte {middle}")
    assert len(s.imu_t_s) >= 790  # one or two records lost, not the rest of the file


def test_a_record_of_an_undeclared_type_ends_the_readable_part(tmp_path):
    path = write_dataflash(tmp_path / "u.bin", static_log(2.0))
    data = bytearray(path.read_bytes())
    at = data.index(b"\xa3\x95\x81", len(data) // 2)  # an IMU record's header
    data[at + 2] = 0x10  # a type no FMT declares: DFReader reads no further
    path.write_bytes(bytes(data))
    s = read_dataflash(path)
    assert s.damage == f"unreadable from byte {at} ({len(data) - at} bytes are not records DFReader could read)"
    assert 350 < len(s.imu_t_s) < 450  # what came before


def _with_format(path, name: bytes, field: slice, value: bytes) -> None:
    """The FMT record declaring ``name`` with one of its fields rewritten (zero-padded): ``LAYOUT`` (16 bytes) or
    ``COLUMNS`` (64), its header, type, length and name kept."""
    data = bytearray(path.read_bytes())
    at = next(i for i in range(0, len(data), 89) if data[i : i + 3] == b"\xa3\x95\x80" and data[i + 5 : i + 9] == name)
    data[at + field.start : at + field.stop] = value.ljust(field.stop - field.start, b"\0")
    path.write_bytes(bytes(data))


LAYOUT, COLUMNS = slice(9, 25), slice(25, 89)  # an FMT record's Format and Columns fields


def test_a_damaged_format_record_loses_its_records_and_says_so(tmp_path):
    """An FMT record whose layout no longer matches its column names (a byte of the GPS layout damaged): the GPS
    records are not read (no GPS velocity; positions from POS), the rest is, and the damage is said. A column
    name empty is the same; one replay reads damaged, or a layout char DFReader does not know, is one error naming
    the file. Before, all four were tracebacks."""
    log = static_log(2.0)
    path = write_dataflash(tmp_path / "f.bin", log)
    _with_format(path, b"GPS\0", LAYOUT, b"QBBIHBcLLeffffBB")
    s = read_dataflash(path)
    assert s.damage == "the format (FMT) of GPS is damaged: its records are not read"
    assert len(s.imu_t_s) == len(log.imu_t_s) and len(s.gps_t_s) == 0 and len(s.position_t_s) > 0
    _with_format(path, b"MAG\0", COLUMNS, b"TimeUS,I,,MagY,MagZ")  # numpy would name the empty one f2
    s = read_dataflash(path)
    assert "the format (FMT) of MAG is damaged: its records are not read" in s.damage and len(s.mag_t_s) == 0
    _with_format(path, b"MAG\0", COLUMNS, b"TimeUS,I,MagQ,MagY,MagZ")
    with pytest.raises(DataFileError, match=r"f\.bin: a record lacks a field replay reads: 'MagX'"):
        read_dataflash(path)
    _with_format(path, b"IMU\0", LAYOUT, b"QBffffff?")
    with pytest.raises(DataFileError, match=r"f\.bin: not a readable DataFlash log: Unsupported format char: '\?'"):
        read_dataflash(path)


def test_what_a_log_lacks_is_one_error_naming_the_file(tmp_path):
    log = static_log(1.0)
    with pytest.raises(DataFileError, match=r"IMU\[I=3\]"):
        read_dataflash(write_dataflash(tmp_path / "one.bin", log), imu_instance=3)


@pytest.mark.parametrize(
    ("where", "imu", "refusal"),
    [
        (("px4", "sample.ulg"), 3, r"no sensor_combined\[3\] records; the log has sensor_combined instance 0: --imu 0"),
        (
            ("ardupilot-sitl", "twocompass.tlog"),
            1,
            r"IMU is its message, not an instance \(--imu 1\): --message SCALED_IMU2",
        ),
    ],
)
def test_an_imu_instance_a_log_cannot_give_is_refused_with_what_it_can(where, imu, refusal):
    """Not replayed with another IMU than asked: a ULog's other sensor_combined, a telemetry log's IMU message."""
    with pytest.raises(DataFileError, match=refusal):
        open_log(shared_path("data", *where), make_config(), imu_instance=imu)


def test_a_log_without_a_magnetometer_is_read_and_said_in_one_line(tmp_path, caplog):
    """No MAG records, or MAG reading zero in all: the IMU is there (roll and pitch), the compass is not."""
    log = static_log(1.0)
    no_mag = write_dataflash(
        tmp_path / "nomag.bin", dataclasses.replace(log, mag_t_s=np.empty(0), mag_uT=np.empty((0, 3)))
    )
    zero = write_dataflash(tmp_path / "zero.bin", dataclasses.replace(log, mag_uT=np.zeros_like(log.mag_uT)))
    for path in (no_mag, zero):
        s = read_dataflash(path)
        assert len(s.imu_t_s) == len(log.imu_t_s) and len(s.mag_t_s) == 0 and (s.carried_mag() == -1).all()
    said = [r.getMessage() for r in caplog.records if r.levelname == "WARNING"]
    assert [m.split(": ", 1)[0] for m in said] == [str(no_mag), str(zero)]
    assert "no MAG[I=0] records: no magnetometer: roll and pitch" in said[0]
    assert "MAG[I=0] reads zero in all 10 records: no magnetometer" in said[1]


def test_unknown_formats_are_named_with_their_first_bytes(tmp_path):
    junk = tmp_path / "junk.bin"
    junk.write_bytes(b"\x01\x02\x03\x04 not a log")
    with pytest.raises(DataFileError, match=r"junk\.bin: not a flight log this reads \(byte 0: 01 02 03 04\)"):
        detect_format(junk)
    empty = tmp_path / "empty.ulg"
    empty.write_bytes(b"")
    with pytest.raises(DataFileError, match="empty file"):
        open_log(empty, make_config())
    samples = tmp_path / "samples.csv"
    samples.write_text("t_s,acc_x_mps2\n")
    with pytest.raises(DataFileError, match=r"\(a CSV of samples is for `mavattitude solve`\)$"):
        detect_format(samples)
    shared = tmp_path / "flight.tlog.gz"  # a log as it is often shared: compressed
    shared.write_bytes(gzip.compress(b"\x00" * 100))
    with pytest.raises(DataFileError, match=r"1f 8b .*\(a gzip file: take the log out of it and give that\)$"):
        detect_format(shared)


def test_a_telemetry_log_under_another_name_is_known_by_its_frames(tmp_path):
    """A .tlog has no magic: saved as .mavlink, or with no suffix, its first records (framed from byte 0, CRCs
    right) say what it is; the same bytes with one byte flipped, or random bytes, are refused as before."""
    tlog = tmp_path / "flight.tlog"
    write_tlog(tlog, [(1, "HEARTBEAT", HEARTBEAT), *((1, "RAW_IMU", _raw(i)) for i in range(30))])
    data = tlog.read_bytes()
    for name in ("flight.mavlink", "flight"):
        (tmp_path / name).write_bytes(data)
        assert detect_format(tmp_path / name).name == "tlog"
        assert open_log(tmp_path / name, make_config()).count == 31
    broken = bytearray(data)
    broken[len(data) // 2] ^= 0xFF  # a CRC or the framing fails
    (tmp_path / "broken.mavlink").write_bytes(bytes(broken))
    noise = np.random.default_rng(3).integers(0, 256, 4096, dtype=np.uint8).tobytes()
    (tmp_path / "noise.dat").write_bytes(noise)
    for name in ("broken.mavlink", "noise.dat"):
        with pytest.raises(DataFileError, match="not a flight log this reads"):
            detect_format(tmp_path / name)


def test_the_shared_sitl_flight_as_dataflash():
    s = read_dataflash(shared_path("data", "ardupilot-sitl", "flightA.BIN"))
    duration_s = s.imu_t_s[-1] - s.imu_t_s[0]
    assert 138 < duration_s < 140  # TimeUS 44.9-184.0 s (README)
    assert len(s.imu_t_s) / duration_s == pytest.approx(25.0, rel=0.01)  # IMU logged at 25 Hz
    assert len(s.mag_t_s) / duration_s == pytest.approx(10.0, rel=0.02)
    # 58.0 µT at home (README: WMM); the calibrated compass within a few per cent
    assert np.median(np.linalg.norm(s.mag_uT, axis=1)) == pytest.approx(58.0, rel=0.03)
    assert np.median(np.linalg.norm(s.acc_mps2, axis=1)) == pytest.approx(9.81, rel=0.02)
    assert s.position[0].tolist() == pytest.approx([-35.363261, 149.165230, 584.0], abs=1.0)


@pytest.mark.parametrize(("name", "mag"), [("sample.ulg", 87.0), ("sample_log_small.ulg", 49.0)])
def test_both_ulog_generations(name, mag):
    s = read_ulog(shared_path("data", "px4", name))
    duration_s = s.imu_t_s[-1] - s.imu_t_s[0]
    assert len(s.mag_t_s) / duration_s == pytest.approx(mag, rel=0.1)  # README: ~87 Hz old, 49 Hz new
    assert np.median(np.linalg.norm(s.acc_mps2, axis=1)) == pytest.approx(9.81, rel=0.02)
    assert 20.0 < np.median(np.linalg.norm(s.mag_uT, axis=1)) < 70.0  # gauss × 100: an Earth field
    assert np.allclose(np.linalg.norm(s.attitude_q, axis=1), 1.0, atol=1e-5)
    assert s.damage is None  # both end on a message's end


def ulog_bytes(*payload_sizes: int) -> bytes:
    """A file header and messages of these payload sizes (type 'D', zero payloads): the framing alone."""
    return b"ULog\x01\x125\x01" + bytes(8) + b"".join(struct.pack("<HB", n, ord("D")) + bytes(n) for n in payload_sizes)


def test_a_ulog_cut_inside_its_last_message_is_found_by_walking_the_message_sizes():
    whole = ulog_bytes(40, 7, 300, 12)
    assert cut_at(whole) is None
    last = 16 + (3 + 40) + (3 + 7) + (3 + 300)  # where the 12-byte message starts
    assert cut_at(whole[:-5]) == f"truncated: the message at byte {last} is incomplete (10 bytes)"
    assert cut_at(whole[: last + 2]) == f"truncated: the message at byte {last} is incomplete (2 bytes)"  # its header
    assert cut_at(whole[:16]) is None  # a header alone: no message begun


def test_a_cut_off_px4_log_is_replayed_up_to_the_cut_and_said_damaged(tmp_path):
    data = shared_path("data", "px4", "sample.ulg").read_bytes()
    cut = tmp_path / "cut.ulg"
    cut.write_bytes(data[: len(data) * 3 // 4])  # as a pulled battery leaves it: mid-message
    s = read_ulog(cut)
    assert s.damage is not None and s.damage.startswith("truncated: the message at byte ")
    whole = read_ulog(shared_path("data", "px4", "sample.ulg"))
    assert 0.6 < len(s.imu_t_s) / len(whole.imu_t_s) < 0.9  # what came before the cut is there
    assert np.array_equal(s.imu_t_s, whole.imu_t_s[: len(s.imu_t_s)])


def test_a_telemetry_log_record_that_fails_its_crc_is_skipped_and_said(tmp_path):
    from mavattitude.sim.logwriter import write_tlog

    path = write_tlog(tmp_path / "c.tlog", static_log(1.0))
    data = bytearray(path.read_bytes())
    at = len(data) // 2
    data[at] ^= 0xFF  # one byte of one record: its CRC no longer matches
    path.write_bytes(bytes(data))
    source = open_log(path, make_config())
    items = []
    while not source.finished:
        items += source.recv(0.0)
    samples = [i for _, _, i in items if isinstance(i, ImuSample)]
    assert source.bad_records == 1 and source.damage.startswith("damaged: the record at byte ")
    assert at - 60 < int(source.damage.split("byte ")[1].split()[0]) <= at
    assert len(samples) == 399  # the others are read


def test_the_format_table_has_a_row_for_each_log_suffix_the_commands_look_for():
    assert sorted(f.suffix for f in FORMATS) == sorted(LOG_SUFFIXES)  # replay DIR lists files by these
    # the formats without magic, told by their name or their first records
    assert [f.name for f in FORMATS if f.magic is None] == ["tlog", "dataflash text"]


def test_a_gps_message_of_another_layout_is_no_position(tmp_path):
    """A GPS message without ArduPilot's Status/Lat/Lng/Alt (PX4's old DataFlash: Fix, Lat, Lon) is read past."""
    log = static_log(1.0, imu_rate_hz=50.0)
    path = write_dataflash(tmp_path / "p.bin", log, layout="3.2")
    data = path.read_bytes()
    # the 3.2 GPS FMT record's columns renamed as PX4 named them: Status → Fix1.., Lng → Lon
    renamed = data.replace(b"Status,TimeMS,Week,NSats,HDop,Lat,Lng,", b"Fix123,TimeMS,Week,NSats,HDop,Lat,Lon,", 1)
    assert renamed != data
    path.write_bytes(renamed)
    s = read_dataflash(path)
    assert len(s.position_t_s) == 0 and s.date is None and len(s.imu_t_s) == len(log.imu_t_s)
