"""Logs damaged byte by byte, as a failing SD card or a cut transfer leaves them: bytes changed, cut out or put in,
the file cut short, more often in its first kilobytes where the formats and definitions are. Each is replayed
to its end or refused with one DataFileError naming the file; never another exception, never a hang (an alarm
ends a read still running after 20 s: a read of these takes well under a second). What is replayed is sound:
finite times, unit quaternions.
"""

from __future__ import annotations

import contextlib
import signal
import struct
from collections.abc import Callable, Iterator
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from mavattitude.errors import DataFileError
from mavattitude.link.logs import open_log
from mavattitude.link.ulog import data_section_at, read_ulog
from mavattitude.replay import replay
from mavattitude.sim.logwriter import static_log, write_dataflash
from tests.link.dataflash_text import write_text_log
from tests.link.test_logs import ulog_bytes
from tests.shared import shared_path
from tests.test_service import make_config

READ_LIMIT_S = 20


def _dataflash(tmp_path: Path) -> bytes:
    return write_dataflash(tmp_path / "whole.bin", static_log(2.0)).read_bytes()


def _dataflash_text(tmp_path: Path) -> bytes:
    write_dataflash(tmp_path / "whole.bin", static_log(2.0))
    return write_text_log(tmp_path / "whole.bin", tmp_path / "whole.log").read_bytes()


def _shared(*parts: str, size: int) -> Callable[[Path], bytes]:
    return lambda _: shared_path(*parts).read_bytes()[:size]


# Every log format, small enough to replay in a fraction of a second: ours (2 s, every record replay reads; and as
# text), a SITL telemetry log's first 150 kB, a PX4 log's definitions (61 kB) and its first data.
LOGS = {
    ".bin": _dataflash,
    ".log": _dataflash_text,
    ".tlog": _shared("data", "ardupilot-sitl", "flightA.tlog", size=150_000),
    ".ulg": _shared("data", "px4", "sample_log_small.ulg", size=100_000),
}
HEAD_BYTES = 65_536  # where formats and definitions are
EXAMPLES = {".bin": 60, ".log": 30, ".tlog": 15, ".ulg": 60}  # a damaged .tlog replays in ~0.2 s, .log ~0.05 s

DAMAGE = st.lists(
    st.tuples(
        st.sampled_from(["change", "cut out", "put in", "end"]),
        st.booleans(),  # in the head
        st.floats(0.0, 1.0, exclude_max=True),  # where, as a fraction of the head or the file
        st.binary(min_size=1, max_size=64),  # the bytes put in or written over
    ),
    min_size=1,
    max_size=6,
)


def damaged(data: bytes, damage: list[tuple[str, bool, float, bytes]]) -> bytes:
    out = bytearray(data)
    for kind, in_head, where, chunk in damage:
        at = int(where * (min(len(out), HEAD_BYTES) if in_head else len(out)))
        if kind == "change":
            out[at : at + len(chunk)] = chunk[: len(out) - at]
        elif kind == "cut out":
            del out[at : at + len(chunk)]
        elif kind == "put in":
            out[at:at] = chunk
        else:
            del out[max(at, 1) :]
    return bytes(out)


class _Endless(BaseException):
    """Raised by the alarm: out of reach of any ``except Exception`` inside a reader, so a hang fails the test."""


@contextlib.contextmanager
def within(seconds: int) -> Iterator[None]:
    """A read that must end within ``seconds`` (an alarm)."""

    def endless(*_: object) -> None:
        raise _Endless(f"still reading after {seconds} s")

    previous = signal.signal(signal.SIGALRM, endless)
    signal.alarm(seconds)
    try:
        yield
    finally:
        signal.alarm(0)
        signal.signal(signal.SIGALRM, previous)


@pytest.mark.parametrize("suffix", LOGS)
def test_a_damaged_log_is_replayed_or_refused_in_one_error(tmp_path, suffix):
    whole = LOGS[suffix](tmp_path)
    config = make_config(**{"crosscheck.enabled": True, "reference.magnetic": "auto"})

    @settings(max_examples=EXAMPLES[suffix], deadline=None, database=None, derandomize=True)
    @given(damage=DAMAGE)
    def replayed_or_refused(damage: list[tuple[str, bool, float, bytes]]) -> None:
        path = tmp_path / f"damaged{suffix}"
        path.write_bytes(damaged(whole, damage))
        try:
            with within(READ_LIMIT_S):
                out = replay(open_log(path, config), config).output_array()
        except DataFileError as exc:
            assert str(exc).startswith(str(path))
            return
        assert np.all(np.isfinite(out[:, 0]))
        assert np.allclose(np.linalg.norm(out[:, 1:5], axis=1), 1.0, atol=1e-9)

    replayed_or_refused()


def test_a_ulog_whose_definitions_run_to_its_end_is_refused_not_read_forever(tmp_path):
    """A log cut in its definitions with a header that cannot be one running past the end (type 0, 512 bytes):
    pyulog 1.3 seeks back before it, steps over the zeros before it a byte at a time and meets it again, for
    ever. Such a file has no data; it is refused at once (a read takes milliseconds; 10 s only bounds a hang)."""
    key = b"char[600] sys_name"
    info = bytes([len(key)]) + key + bytes(600)
    path = tmp_path / "endless.ulg"
    path.write_bytes(
        ulog_bytes() + struct.pack("<HB", len(info), ord("I")) + info + struct.pack("<HB", 512, 0) + bytes(10)
    )
    with within(10), pytest.raises(DataFileError, match=r"endless\.ulg: .* ends inside its definitions, before any"):
        read_ulog(path)
    data = shared_path("data", "px4", "sample.ulg").read_bytes()
    path.write_bytes(data[: data_section_at(data) - 100])  # a real log cut in its parameters
    with pytest.raises(DataFileError, match=r"ends inside its definitions, before any data"):
        read_ulog(path)
