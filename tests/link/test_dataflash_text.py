"""DataFlash logs as text (.log, Mission Planner's conversion of a .bin): read as their binary is, known by name
or by content, damaged lines left out and said."""

from __future__ import annotations

import numpy as np
import pytest
from pymavlink import DFReader

from mavattitude.errors import DataFileError
from mavattitude.link.dataflash import read_dataflash, read_dataflash_text
from mavattitude.link.logs import detect_format, found_in_folder, open_log
from mavattitude.sim.logwriter import LAYOUTS, static_log, write_dataflash
from tests.link.dataflash_text import write_text_log
from tests.link.test_tlog import HEARTBEAT, _raw, write_tlog
from tests.test_service import make_config

# The text holds a float32 field to 7 significant digits: within half a unit of the 7th, 5e-7 of the value.
FLOAT_TEXT_REL = 5e-7


def _pair(tmp_path, layout: str = "4.1", instances: int = 2):
    log = static_log(2.0, imu_rate_hz=50.0, yaw_rate_dps=10.0)
    parameters = {"COMPASS_USE2": 0.0}
    binary = write_dataflash(tmp_path / "f.bin", log, layout=layout, instances=instances, parameters=parameters)
    return binary, write_text_log(binary, tmp_path / "f.log")


@pytest.mark.parametrize("layout", LAYOUTS)
def test_a_text_log_reads_as_the_binary_it_was_written_from(tmp_path, layout):
    binary, text = _pair(tmp_path, layout)
    b, t = read_dataflash(binary, 1), read_dataflash_text(text, 1)
    assert np.array_equal(t.imu_t_s, b.imu_t_s) and t.time_wrap_s == b.time_wrap_s  # integer times, as logged
    assert t.acc_mps2 == pytest.approx(b.acc_mps2, rel=FLOAT_TEXT_REL, abs=1e-12)
    assert np.array_equal(t.mag_t_s, b.mag_t_s) and np.array_equal(t.mag_uT, b.mag_uT)  # int16 fields
    assert t.attitude_q == pytest.approx(b.attitude_q, abs=1e-6)  # from float32 (or centidegree) angles
    assert np.array_equal(t.position, b.position) and t.date == b.date  # lat/lon at every digit: 1e-7 °
    # a GPS record without a time of its own (3.0) takes the IMU record's before it: by line as by byte
    assert np.array_equal(t.position_t_s, b.position_t_s)
    assert sorted(t.compasses.readings) == sorted(b.compasses.readings) and t.compasses.why == b.compasses.why
    assert t.damage is None
    # the fixture is a text log as pymavlink knows one: its text reader counts the records its binary reader does
    df = DFReader.DFReader_binary(str(binary))
    assert DFReader.DFReader_text(str(text)).counts == {df.formats[k].name: n for k, n in enumerate(df.counts) if n}


def test_text_logs_are_known_by_their_name_or_their_content(tmp_path):
    _, text = _pair(tmp_path)
    assert detect_format(text).name == "dataflash text"
    renamed = tmp_path / "f.txt"
    renamed.write_bytes(text.read_bytes())
    assert (
        detect_format(renamed).name == "dataflash text" and len(open_log(renamed, make_config()).streams.imu_t_s) == 100
    )
    service_log = tmp_path / "mavattitude.log"  # a .log that is not a flight log: one error, naming it
    service_log.write_text("2026-11-29 11:42:18,136 INFO mavattitude: started\n")
    with pytest.raises(DataFileError, match=r"mavattitude\.log: not a DataFlash log: no format \(FMT\) line"):
        open_log(service_log, make_config())
    assert found_in_folder(text) and not found_in_folder(service_log)  # replay DIR takes the one, not the other
    unreadable = tmp_path / "unreadable.log"  # a file whose read fails, even as root: not taken, not an error
    unreadable.symlink_to("/proc/self/mem")
    assert not found_in_folder(unreadable)
    # a name that says one format and records that say the other: the records
    write_tlog(tmp_path / "telemetry.log", [(1, "HEARTBEAT", HEARTBEAT), (1, "RAW_IMU", _raw(0))])
    assert detect_format(tmp_path / "telemetry.log").name == "tlog"
    (tmp_path / "text.tlog").write_bytes(text.read_bytes())
    assert detect_format(tmp_path / "text.tlog").name == "dataflash text"


def test_damaged_lines_are_left_out_and_said(tmp_path):
    """A number that is not one, a value lost (the last) and the last line cut in half: those three IMU
    records are not read, every other is; an FMT that lost a column name loses its records; all said."""
    binary, text = _pair(tmp_path, instances=1)
    lines = text.read_bytes().decode().split("\r\n")[:-1]
    imu = [k for k, line in enumerate(lines) if line.startswith("IMU,")]
    lines[imu[10]] = lines[imu[10]].replace(", ", ", x", 3)
    lines[imu[20]] = lines[imu[20]].rsplit(", ", 1)[0]
    att_format = next(k for k, line in enumerate(lines) if line.startswith("FMT, ") and ", ATT, " in line)
    lines[att_format] = lines[att_format].replace(",Roll,", ",", 1)
    lines = lines[: imu[-1] + 1]
    lines[-1] = lines[-1][: len(lines[-1]) // 2]
    text.write_bytes("\r\n".join(lines).encode())
    s, whole = read_dataflash_text(text), read_dataflash(binary)
    assert len(s.imu_t_s) == len(whole.imu_t_s) - 3
    assert np.array_equal(s.imu_t_s, np.delete(whole.imu_t_s, [10, 20, len(whole.imu_t_s) - 1]))
    assert len(s.attitude_t_s) == 0 and len(whole.attitude_t_s) > 0
    assert s.damage == "3 IMU line(s) damaged: not read; the format (FMT) of ATT is damaged: its records are not read"
