"""MAVLink 2 message signing: the key file, the wall-clock timestamp, and a verify-first signature check.

- Key file: exactly 32 bytes is a raw key; anything else is a passphrase (one line of ASCII text, the
  trailing newline ignored) turned into the key by SHA-256, as MAVProxy's ``signing setup`` does. A key
  file that other users can read is refused (:class:`SigningError`): the key authenticates the vehicle.
- Timestamp: 10 µs units since 2015-01-01 00:00 UTC (MAVLink's signing epoch). pymavlink advances it by
  one tick per packet sent, so on its own it falls behind the wall clock; :func:`signing_timestamp_now`
  is what the link raises it to periodically, so that a receiver's one-minute window for a new stream
  accepts us.
- :func:`verify_signature` replaces pymavlink's ``MAVLink.check_signature``, which records a stream's
  timestamp *before* it checks the signature: a forger could then send one badly signed packet with a
  timestamp far in the future and make every genuine packet of that stream look like a replay. Here
  the signature is checked first and only a valid packet moves the stream's timestamp.
"""

from __future__ import annotations

import hashlib
import hmac
import os
import stat
import time
from pathlib import Path
from typing import Any

from mavattitude.errors import SigningError

KEY_LENGTH = 32
SIGNING_EPOCH_UNIX_S = 1_420_070_400  # 2015-01-01T00:00:00Z
TICKS_PER_S = 100_000  # the signing timestamp counts 10 µs
NEW_STREAM_WINDOW_TICKS = 60 * TICKS_PER_S  # a new stream may lag our clock by one minute (MAVLink spec)
SIGNATURE_BLOCK_LEN = 13  # link id (1) + timestamp (6) + signature (6)


def passphrase_to_key(passphrase: str) -> bytes:
    """MAVProxy's key derivation: SHA-256 of the ASCII passphrase."""
    try:
        encoded = passphrase.encode("ascii")
    except UnicodeEncodeError as exc:
        raise SigningError("a signing passphrase must be ASCII text (MAVProxy encodes it so)") from exc
    return hashlib.sha256(encoded).digest()


def load_signing_key(path: str | os.PathLike[str]) -> bytes:
    """Read a signing key file (32 raw bytes, or a passphrase line); refuse one that is world-readable."""
    key_path = Path(path)
    try:
        mode = key_path.stat().st_mode
        data = key_path.read_bytes()
    except OSError as exc:
        raise SigningError(f"cannot read signing key file {key_path}: {exc.strerror or exc}") from exc
    if mode & stat.S_IROTH:
        raise SigningError(
            f"signing key file {key_path} is world-readable (mode {stat.S_IMODE(mode):04o}); "
            f"run `chmod 600 {key_path}` and start again"
        )
    if len(data) == KEY_LENGTH:
        return data
    try:
        passphrase = data.decode("ascii").rstrip("\r\n")
    except UnicodeDecodeError as exc:
        raise SigningError(
            f"signing key file {key_path} holds {len(data)} bytes: neither a raw {KEY_LENGTH}-byte key "
            "nor an ASCII passphrase"
        ) from exc
    if not passphrase.strip():
        raise SigningError(f"signing key file {key_path} is empty")
    return passphrase_to_key(passphrase)


def signing_timestamp_now(unix_time_s: float | None = None) -> int:
    """The signing timestamp of a wall-clock time (now by default), in 10 µs ticks since 2015."""
    now = time.time() if unix_time_s is None else unix_time_s
    return int((max(now, SIGNING_EPOCH_UNIX_S) - SIGNING_EPOCH_UNIX_S) * TICKS_PER_S)


def verify_signature(signing: Any, msgbuf: bytes | bytearray, src_system: int, src_component: int) -> bool:
    """Check a signed packet against ``signing`` (pymavlink's ``MAVLinkSigning`` state) and update it.

    True only for a correct signature whose timestamp is newer than the last one of its stream
    (link id, system, component) or, for a new stream, no more than a minute older than our clock.
    """
    expected = hashlib.sha256(signing.secret_key + bytes(msgbuf[:-6])).digest()[:6]
    if not hmac.compare_digest(expected, bytes(msgbuf[-6:])):
        return False
    link_id = msgbuf[-SIGNATURE_BLOCK_LEN]
    timestamp = int.from_bytes(msgbuf[-12:-6], "little")
    stream = (link_id, src_system, src_component)
    last = signing.stream_timestamps.get(stream)
    if last is None:
        if timestamp + NEW_STREAM_WINDOW_TICKS < signing.timestamp:
            return False
    elif timestamp <= last:
        return False  # a replay, or a packet older than one already accepted
    signing.stream_timestamps[stream] = timestamp
    signing.timestamp = max(signing.timestamp, timestamp)
    return True
