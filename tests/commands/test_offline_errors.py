"""Every offline command against random bytes, truncated and wrong-format files: exit 2 and one line.

A user who hands a command the wrong file must read one line naming it (and where there is one, the line),
never a traceback or a numpy warning. The commands and the files they read are tables below, so a new
command or input format is one more row.
"""

from __future__ import annotations

import gzip
import io
import struct
import tempfile
import warnings
from collections.abc import Callable
from pathlib import Path

import pytest
import yaml
from hypothesis import HealthCheck, assume, example, given, settings
from hypothesis import strategies as st
from pymavlink.dialects.v20 import ardupilotmega as mavlink2

from mavattitude.cli import EXIT_USER_ERROR, main
from mavattitude.sim.logwriter import static_log, write_dataflash

REF = ["--declination", "0", "--inclination", "60"]
# command → argv for an input file (and an output path); the suffixes it is handed.
COMMANDS: dict[str, tuple[Callable[[Path, Path], list[str]], tuple[str, ...]]] = {
    "solve": (lambda p, o: ["solve", str(p), "-o", str(o), *REF], (".csv", ".csv.gz", ".tlog")),
    "replay": (lambda p, o: ["replay", str(p), "-o", str(o), *REF], (".tlog", ".bin")),
    "calibrate": (lambda p, o: ["calibrate", "mag", str(p), "-o", str(o)], (".csv", ".csv.gz", ".tlog")),
    "validate": (lambda p, o: ["validate", str(p), "--report", str(o)], (".csv", ".csv.gz")),
    "check-config": (lambda p, o: ["check-config", str(p)], (".yaml",)),
    "solve --config": (lambda p, o: ["solve", str(p), "-o", str(o), "--config", str(p)], (".yaml",)),
}
CASES = [(name, suffix) for name, (_, suffixes) in COMMANDS.items() for suffix in suffixes]
SETTINGS = settings(max_examples=25, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])


def good_csv(rows: int = 400) -> bytes:
    lines = ["t_s,acc_x_mps2,acc_y_mps2,acc_z_mps2,mag_x_uT,mag_y_uT,mag_z_uT"]
    lines += [f"{0.01 * i:.2f},0.1,0.2,-9.8,{20 + i % 7},{i % 5},{40 - i % 3}" for i in range(rows)]
    return ("\n".join(lines) + "\n").encode()


def good_tlog(n: int = 200) -> bytes:
    out = io.BytesIO()
    mav = mavlink2.MAVLink(None, srcSystem=1, srcComponent=1)
    for i in range(n):
        msg = (
            mav.heartbeat_encode(2, 3, 0, 0, 4)
            if i % 50 == 0
            else mav.raw_imu_encode(5000 * i, 0, 0, -1000, 0, 0, 0, 200, 0, 400)
        )
        out.write(struct.pack(">Q", 1_700_000_000_000_000 + 5000 * i) + msg.pack(mav))
    return out.getvalue()


def good_bytes(suffix: str) -> bytes:
    if suffix == ".csv":
        return good_csv()
    if suffix == ".csv.gz":
        return gzip.compress(good_csv(), mtime=0)
    if suffix == ".tlog":
        return good_tlog()
    if suffix == ".bin":
        return write_dataflash(Path(tempfile.mkdtemp()) / "good.bin", static_log(2.0)).read_bytes()
    return b"filter:\n  cutoff_hz: 5\n"


def run_on(tmp_path: Path, command: str, suffix: str, content: bytes) -> tuple[int, list[str], list[str]]:
    """Exit code, stderr lines and warnings of ``command`` on a file holding ``content``."""
    path = tmp_path / f"input{suffix}"
    path.write_bytes(content)
    argv, _ = COMMANDS[command]
    return run_on_argv(argv(path, tmp_path / "out.csv"))


def run_on_argv(argv: list[str]) -> tuple[int, list[str], list[str]]:
    """Exit code, stderr lines and warnings of the command line ``argv``."""
    capture = io.StringIO()
    with warnings.catch_warnings(record=True) as caught, pytest.MonkeyPatch.context() as mp:
        warnings.simplefilter("always")
        warnings.simplefilter("ignore", ResourceWarning)  # never shown to a user (and pymavlink leaks on garbage)
        mp.setattr("sys.stderr", capture)
        mp.setattr("sys.stdout", io.StringIO())
        code = main(argv)
    return code, capture.getvalue().splitlines(), [str(w.message) for w in caught]


def assert_one_line_error(result: tuple[int, list[str], list[str]], command: str, path_part: str) -> None:
    code, lines, caught = result
    assert code == EXIT_USER_ERROR, lines
    assert not caught, caught
    errors = [line for line in lines if ": error: " in line]
    assert len(errors) == 1 and lines[-1] == errors[0], lines
    assert errors[0].startswith(f"mavattitude {command.split()[0]}: error: ") and path_part in errors[0], lines
    assert not any("Traceback" in line or "Warning" in line for line in lines), lines


def _not_a_valid_config(content: bytes) -> bool:
    try:
        return yaml.safe_load(content) not in (None, {})  # an empty file is the defaults: valid
    except yaml.YAMLError:
        return True


@pytest.mark.parametrize(("command", "suffix"), CASES)
@SETTINGS
@given(content=st.binary(max_size=400))
@example(content=b"\n\x00")  # an empty header line, then a row that is no number: its column had no name
def test_random_bytes(tmp_path: Path, command: str, suffix: str, content: bytes) -> None:
    assume(suffix != ".yaml" or _not_a_valid_config(content))
    assert_one_line_error(run_on(tmp_path, command, suffix, content), command, "input")


@pytest.mark.parametrize(("command", "suffix"), CASES)
@SETTINGS
@given(fraction=st.floats(0.0, 0.95))
def test_truncated_files(tmp_path: Path, command: str, suffix: str, fraction: float) -> None:
    good = good_bytes(suffix)
    cut = good[: int(fraction * len(good))]
    assume(suffix != ".yaml" or _not_a_valid_config(cut))
    result = run_on(tmp_path, command, suffix, cut)
    if result[0] == 0:  # a file cut at a row boundary (or a log read up to the cut) is a good, shorter one
        assert not result[2], result
    else:
        assert_one_line_error(result, command, "input")


FORMATS = (".csv", ".csv.gz", ".tlog", ".bin", ".yaml")  # .ulg: no writer yet, only the shared real logs
LOG_FORMATS = {".tlog", ".bin", ".ulg"}
# Every (command, file name, content) where the content is not what the name says; replay tells the log
# formats apart by their content, so a log under another log's name is no error there.
MISNAMED = [
    (command, suffix, content)
    for command, suffix in CASES
    for content in FORMATS
    if content != suffix and not (command == "replay" and {content, suffix} <= LOG_FORMATS)
]
UNREAD = [(command, suffix) for command in COMMANDS for suffix in FORMATS if suffix not in COMMANDS[command][1]]


@pytest.mark.parametrize(("command", "suffix", "content"), MISNAMED)
def test_a_file_whose_content_is_not_what_its_name_says(
    tmp_path: Path, command: str, suffix: str, content: str
) -> None:
    assert_one_line_error(run_on(tmp_path, command, suffix, good_bytes(content)), command, "input")


@pytest.mark.parametrize(("command", "suffix"), UNREAD)
def test_a_format_the_command_does_not_read(tmp_path: Path, command: str, suffix: str) -> None:
    assert_one_line_error(run_on(tmp_path, command, suffix, good_bytes(suffix)), command, "input")


@pytest.mark.parametrize(
    ("command", "name", "content"),
    [
        ("solve", "in.csv", ".csv"),
        ("calibrate", "in.csv", ".csv"),
        ("replay", "flight.csv", ".tlog"),
        ("validate", "trial.csv", ".csv"),
    ],
)
def test_an_output_that_is_the_input_is_refused_and_the_input_kept(
    tmp_path: Path, command: str, name: str, content: str
) -> None:
    """``-o`` naming the input itself (here by another spelling, ``DIR/./NAME``) wrote the results over the
    recording they came from; replay knows a log by its content, so a telemetry log may be called .csv."""
    recording = good_bytes(content)
    path = tmp_path / name
    path.write_bytes(recording)
    argv, _ = COMMANDS[command]
    result = run_on_argv(argv(path, tmp_path / "." / name))
    assert_one_line_error(result, command, "that is the input")
    assert path.read_bytes() == recording
