"""Logs damaged byte by byte, as a failing SD card or a cut transfer leaves them: bytes changed, cut out or put in,
the file cut short, more often in its first kilobytes where the formats and definitions are. Each is replayed
to its end or refused with one DataFileError naming the file; never another exception, never a hang (an alarm
ends a read still running after 20 s: a read of these takes well under a second). What is replayed is sound:
finite times, unit quaternions.
"""

from __future__ import annotations

import signal
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from mavattitude.errors import DataFileError
from mavattitude.link.logs import open_log
from mavattitude.replay import replay
from mavattitude.sim.logwriter import static_log, write_dataflash
from tests.shared import shared_path
from tests.test_service import make_config

READ_LIMIT_S = 20


def _dataflash(tmp_path: Path) -> bytes:
    return write_dataflash(tmp_path / "whole.bin", static_log(2.0)).read_bytes()


def _shared(*parts: str, size: int) -> Callable[[Path], bytes]:
    return lambda _: shared_path(*parts).read_bytes()[:size]


# Every log format, small enough to replay in a fraction of a second: ours (2 s, every record replay reads), a
# SITL telemetry log's first 150 kB, a PX4 log's definitions (61 kB) and its first data.
LOGS = {
    ".bin": _dataflash,
    ".tlog": _shared("data", "ardupilot-sitl", "flightA.tlog", size=150_000),
    ".ulg": _shared("data", "px4", "sample_log_small.ulg", size=100_000),
}
HEAD_BYTES = 65_536  # where formats and definitions are

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
    """Out of reach of any ``except Exception`` inside a reader, so a hang fails the test."""


def _endless(*_: object) -> None:
    raise _Endless(f"still reading after {READ_LIMIT_S} s")


@pytest.mark.parametrize("suffix", LOGS)
def test_a_damaged_log_is_replayed_or_refused_in_one_error(tmp_path, suffix):
    whole = LOGS[suffix](tmp_path)
    config = make_config(**{"crosscheck.enabled": True, "reference.magnetic": "auto"})

    @settings(max_examples=20, deadline=None, database=None, derandomize=True)
    @given(damage=DAMAGE)
    def replayed_or_refused(damage: list[tuple[str, bool, float, bytes]]) -> None:
        path = tmp_path / f"damaged{suffix}"
        path.write_bytes(damaged(whole, damage))
        previous = signal.signal(signal.SIGALRM, _endless)
        signal.alarm(READ_LIMIT_S)
        try:
            out = replay(open_log(path, config), config).output_array()
        except DataFileError as exc:
            assert str(exc).startswith(str(path))
            return
        finally:
            signal.alarm(0)
            signal.signal(signal.SIGALRM, previous)
        assert np.all(np.isfinite(out[:, 0]))
        assert np.allclose(np.linalg.norm(out[:, 1:5], axis=1), 1.0, atol=1e-9)

    replayed_or_refused()
