"""Frames the link handles without pymavlink's message objects: the input message decoded straight from its
frame (the same items, senders and counters as pymavlink's path, over real UDP on 127.0.0.1, a real TCP socket
and a real tty, and every other frame handled as before), and the attitude it sends packed byte for byte as
pymavlink packs it.

Each reception case sends the same bytes twice, once read with the input message's :class:`DirectFrame` and
once without (pymavlink decodes every frame), and compares what came out.
"""

from __future__ import annotations

import dataclasses
import os
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager

import numpy as np
import pytest
from pymavlink.dialects.v10 import ardupilotmega as mavlink1
from pymavlink.dialects.v20 import ardupilotmega as mavlink2

from mavattitude.link import MavlinkLink
from mavattitude.link.connection import MAX_MESSAGES_PER_RECV
from mavattitude.link.mavlink2 import mavlink2 as link_dialect
from mavattitude.link.memory import MemoryLink
from mavattitude.link.source import MavlinkDecoder, Undecodable
from mavattitude.sensors import units
from tests.link.peer import UdpPeer
from tests.link.test_connection import WAIT_S, _listener
from tests.link.test_signing import KEY, OTHER_KEY

SEED = 20250611


def _drain(
    link: MavlinkLink, decoder: MavlinkDecoder, direct: bool, count: int, reads: frozenset[int] | None = None
) -> list[tuple]:
    """``(arrival, sender, item)`` of everything the link hands over until ``count`` frames are accounted for."""
    got: list[tuple] = []
    deadline = time.monotonic() + WAIT_S
    c = link.counters
    while time.monotonic() < deadline and c.received + c.bad_data + c.signature_rejected + c.skipped < count:
        got += link.recv_items(0.05, decoder, decoder.direct if direct else None, reads=reads)
    return got


def _comparable(item: object) -> object:
    """An item as a value: an Undecodable by its reason (exceptions compare by identity)."""
    return ("undecodable", str(item.error)) if isinstance(item, Undecodable) else item


def _both_ways(datagrams: list[bytes], decoder: MavlinkDecoder, **link_kwargs: object) -> list[tuple]:
    """The same datagrams through a fresh link read directly and one read by pymavlink: (items, counters) each."""
    results = []
    for direct in (True, False):
        got, counters = _received("udp", datagrams, decoder, None, direct, **link_kwargs)
        results.append(([(s, _comparable(i)) for _, s, i in got], counters))
    return results


def _random_samples(rng: np.random.Generator, n: int) -> list[units.ImuSample]:
    """Plausible readings, one without a compass and one far too strong (the unit check refuses it)."""
    samples = []
    for i in range(n):
        mag = tuple(rng.normal(0.0, 30.0, 3))
        samples.append(
            units.ImuSample(10.0 + 0.005 * i, tuple(rng.normal(0.0, 6.0, 3)), tuple(rng.normal(0, 1, 3)), mag)
        )
    samples[3] = dataclasses.replace(samples[3], mag_uT=None)
    samples[5] = dataclasses.replace(samples[5], mag_uT=(2500.0, 0.0, 0.0))
    return samples


@pytest.mark.parametrize(
    ("message", "profile", "refused"),
    # 2 500 µT is 50 000 ADIS16405 counts: clipped to 14 bits, 410 µT, plausible
    [
        ("RAW_IMU", "ardupilot", 1),
        ("SCALED_IMU2", "ardupilot", 1),
        ("HIGHRES_IMU", "px4", 1),
        ("RAW_IMU", "adis16405", 0),
    ],
)
def test_direct_items_equal_pymavlinks_and_skip_its_decoder(message, profile, refused, monkeypatch):
    rng = np.random.default_rng(SEED)
    decoder = MavlinkDecoder(message, units.PROFILES[profile])
    peer = mavlink2.MAVLink(None, srcSystem=3, srcComponent=1)
    cls = getattr(mavlink2, f"MAVLink_{message.lower()}_message")
    datagrams = [
        bytes(cls(**units.encode(s, units.PROFILES[profile], message)).pack(peer)) for s in _random_samples(rng, 12)
    ]
    assert any(len(d) < 12 + cls.unpacker.size for d in datagrams)  # MAVLink 2 trims trailing zeros: padded back
    decoded = []
    real_decode = link_dialect.MAVLink.decode
    monkeypatch.setattr(link_dialect.MAVLink, "decode", lambda mav, buf: decoded.append(1) or real_decode(mav, buf))
    (direct, direct_counters), (by_pymavlink, counters) = _both_ways(datagrams, decoder)
    assert len(decoded) == len(datagrams)  # only the run without the direct path called pymavlink's decoder
    assert direct == by_pymavlink and direct_counters == counters
    assert len(direct) == 12 and {s for s, _ in direct} == {(3, 1)}
    assert sum(isinstance(i, tuple) and i[0] == "undecodable" for _, i in direct) == refused


def _frame_with_payload(peer: mavlink2.MAVLink, msg: object, extra: bytes) -> bytes:
    """``msg`` packed with ``extra`` bytes after its payload (a newer dialect's extension fields), CRC redone."""
    frame = bytearray(msg.pack(peer))  # type: ignore[attr-defined]
    frame[1] += len(extra)
    frame[-2:-2] = extra
    crc = mavlink2.x25crc(bytes(frame[1:-2]))
    crc.accumulate(bytes([msg.crc_extra]))  # type: ignore[attr-defined]
    frame[-2:] = crc.crc.to_bytes(2, "little")
    return bytes(frame)


def _as_decoded(decoder: MavlinkDecoder, frame: bytes) -> object:
    """What pymavlink and the decoder make of one frame, alone."""
    return decoder(mavlink2.MAVLink(None).decode(bytearray(frame)))


def test_bad_crc_truncated_foreign_and_other_frames_handled_as_before():
    decoder = MavlinkDecoder("RAW_IMU", units.PROFILES["ardupilot"])
    vehicle = mavlink2.MAVLink(None, srcSystem=1, srcComponent=1)
    stranger = mavlink2.MAVLink(None, srcSystem=9, srcComponent=1)
    v1 = mavlink1.MAVLink(None, srcSystem=1, srcComponent=1)
    sample = units.ImuSample(5.0, (0.1, 0.2, -9.8), (0.01, 0.0, 0.0), (20.0, 1.0, 40.0))
    fields = units.encode(sample, units.PROFILES["ardupilot"], "RAW_IMU")
    v1_fields = {k: v for k, v in fields.items() if k in mavlink1.MAVLink_raw_imu_message.fieldnames}
    good = bytes(mavlink2.MAVLink_raw_imu_message(**fields).pack(vehicle))
    sample = _as_decoded(decoder, good)  # as sent, in the message's integer units
    bad_crc = good[:-1] + bytes([good[-1] ^ 0xFF])
    datagrams = [
        good,
        bad_crc,
        good[:20],  # truncated: dropped (and counted) when the next datagram arrives
        good,
        bytes(mavlink2.MAVLink_raw_imu_message(**fields).pack(stranger)),  # another sender: handed on as its own
        bytes(mavlink2.MAVLink_heartbeat_message(2, 3, 0, 0, 4, 3).pack(vehicle)),
        bytes(mavlink1.MAVLink_raw_imu_message(**v1_fields).pack(v1)),  # MAVLink 1: pymavlink's
        good + good,  # two frames in one datagram: pymavlink's
        _frame_with_payload(vehicle, mavlink2.MAVLink_raw_imu_message(**fields), b"\x07\x07"),  # longer payload: cut
    ]
    (direct, direct_counters), (by_pymavlink, counters) = _both_ways(datagrams, decoder)
    assert direct == by_pymavlink and direct_counters == counters
    assert counters["bad_data"] == 2 and counters["received"] == 8
    assert [s for s, _ in direct] == [(1, 1), (1, 1), (9, 1), (1, 1), (1, 1), (1, 1), (1, 1), (1, 1)]
    assert sum(i == sample for _, i in direct) == 7  # every RAW_IMU, however it came, decodes to the sample sent


def test_signed_input_checked_by_pymavlink_and_unsigned_refused_when_signing_is_required():
    decoder = MavlinkDecoder("RAW_IMU", units.PROFILES["ardupilot"])
    sample = units.ImuSample(5.0, (0.1, 0.2, -9.8), (0.01, 0.0, 0.0), (20.0, 1.0, 40.0))
    msg = mavlink2.MAVLink_raw_imu_message(**units.encode(sample, units.PROFILES["ardupilot"], "RAW_IMU"))
    sample = _as_decoded(decoder, bytes(msg.pack(mavlink2.MAVLink(None))))
    unsigned, honest, forger = UdpPeer(), UdpPeer(key=KEY), UdpPeer(key=OTHER_KEY)
    datagrams = [unsigned.pack(msg), forger.pack(msg), honest.pack(msg), unsigned.pack(msg)]
    for peer in (unsigned, honest, forger):
        peer.close()
    required = _both_ways(datagrams, decoder, signing_key=KEY, require_signing=True)
    assert required[0] == required[1]
    (items, counters) = required[0]
    assert items == [((1, 1), sample)] and counters["signature_rejected"] == 3
    allowed = _both_ways(datagrams, decoder, signing_key=KEY, require_signing=False)
    assert allowed[0] == allowed[1]
    # unsigned input allowed: a bad signature is no worse than none (pymavlink's rule, kept)
    assert allowed[0][0] == [((1, 1), sample)] * 4 and allowed[0][1]["signature_rejected"] == 0


def test_attitude_frames_are_pymavlinks_bytes():
    """Trailing zero bytes cut as pymavlink cuts them (a zero rate, an all-zero covariance tail, NaN "unknown"),
    the sequence shared with what pymavlink sends (the HEARTBEAT between), the one datagram per attitude."""
    rng = np.random.default_rng(SEED)
    link = MemoryLink(source_system=5)
    reference = mavlink2.MAVLink(None, srcSystem=5, srcComponent=mavlink2.MAV_COMP_ID_ONBOARD_COMPUTER)
    cases = [(12.0, [1.0, 0.0, 0.0, 0.0], [0.0, 0.0, 0.0], [0.0] * 9), (0.0, [0.0] * 4, [0.0] * 3, None)]
    cases.append(((2**64 - 1) * 1e-6, [1.0, 0.0, 0.0, 0.0], [0.0] * 3, [0.0] * 9))  # the latest an IMU time can be
    for _ in range(20):
        q = rng.normal(size=4)
        cov = [float("nan")] + [0.0] * 8 if rng.random() < 0.3 else rng.normal(0, 1e-3, 9).tolist()
        cases.append((float(rng.uniform(0, 5e6)), (q / np.linalg.norm(q)).tolist(), rng.normal(size=3).tolist(), cov))
    for time_s, q, rates, cov in cases:
        assert link.send_attitude(time_s, q, rates, cov)
        expected = reference.attitude_quaternion_encode(units.time_boot_ms(time_s), *q, *rates, [0.0] * 4).pack(
            reference
        )
        reference.seq += 1
        if cov is not None:
            expected += reference.attitude_quaternion_cov_encode(units.time_usec(time_s), q, *rates, cov).pack(
                reference
            )
            reference.seq += 1
        assert link.sent_bytes[-1] == expected
        link.send_heartbeat()
        reference.seq += 1
    assert link.counters.sent == 3 * len(cases) - 1 and link.counters.send_failed == 0


@contextmanager
def _stream_link(kind: str) -> Iterator[tuple[MavlinkLink, Callable[[bytes], None]]]:
    """A link on a byte stream, and what writes to its far end: a TCP client with a listener in the test, or a
    serial device on a pseudo-terminal's slave end (pyserial), the test on its master."""
    if kind == "tcp":
        server = _listener()
        link = MavlinkLink(f"tcp:127.0.0.1:{server.getsockname()[1]}", source_system=1)
        conn, _ = server.accept()
        try:
            yield link, conn.sendall
        finally:
            link.close()
            conn.close()
            server.close()
    else:
        master, slave = os.openpty()
        link = MavlinkLink(f"{os.ttyname(slave)},921600", source_system=1)
        try:
            yield link, lambda data: os.write(master, data)
        finally:
            link.close()
            os.close(master)
            os.close(slave)


def _stream_bytes(rng: np.random.Generator) -> tuple[list[bytes], int, int, int]:
    """Frames as a stream carries them, and noise between: (the pieces, the RAW_IMU frames the direct path may
    take, the other frames, which pymavlink decodes, the noise's bytes)."""
    vehicle = mavlink2.MAVLink(None, srcSystem=1, srcComponent=1)
    stranger = mavlink2.MAVLink(None, srcSystem=9, srcComponent=1)
    v1 = mavlink1.MAVLink(None, srcSystem=1, srcComponent=1)
    pieces, direct, other, noise = [], 0, 0, 0
    for sample in _random_samples(rng, 60):
        fields = units.encode(sample, units.PROFILES["ardupilot"], "RAW_IMU")
        kind = rng.choice(["imu", "imu", "imu", "stranger", "heartbeat", "v1", "bad_crc", "noise"])
        if kind in ("imu", "stranger", "bad_crc"):
            frame = bytes(mavlink2.MAVLink_raw_imu_message(**fields).pack(stranger if kind == "stranger" else vehicle))
            pieces.append(frame[:-1] + bytes([frame[-1] ^ 0xFF]) if kind == "bad_crc" else frame)
            direct += kind != "bad_crc"
        elif kind == "heartbeat":
            pieces.append(bytes(mavlink2.MAVLink_heartbeat_message(2, 3, 0, 0, 4, 3).pack(vehicle)))
        elif kind == "v1":
            v1_fields = {k: v for k, v in fields.items() if k in mavlink1.MAVLink_raw_imu_message.fieldnames}
            pieces.append(bytes(mavlink1.MAVLink_raw_imu_message(**v1_fields).pack(v1)))
        else:  # line noise: no byte that starts a frame (pymavlink reports a run as BAD_DATA, never decodes it)
            pieces.append(bytes(rng.choice([b for b in range(256) if b not in (0xFD, 0xFE)], rng.integers(1, 30))))
            noise += len(pieces[-1])
        other += kind in ("heartbeat", "v1", "bad_crc")
    return pieces, direct, other, noise


@pytest.mark.parametrize("kind", ["tcp", "serial"])
def test_a_stream_in_any_pieces_gives_pymavlinks_items_with_the_input_decoded_directly(kind, monkeypatch):
    """The stream's bytes cut at random (frames split across reads, several in one), read after each piece. A run
    of noise is one BAD_DATA to pymavlink's parser when it reads it whole, one per read it spans otherwise."""
    rng = np.random.default_rng(SEED)
    pieces, n_direct, n_other, noise_bytes = _stream_bytes(rng)
    data = b"".join(pieces)
    cuts = np.sort(rng.choice(np.arange(1, len(data)), 120, replace=False))
    chunks = [data[a:b] for a, b in zip([0, *cuts], [*cuts, len(data)], strict=True)]
    reference = mavlink2.MAVLink(None)
    reference.robust_parsing = True
    expected_msgs = reference.parse_buffer(data)
    decoder = MavlinkDecoder("RAW_IMU", units.PROFILES["ardupilot"])
    expected = [
        ((m.get_srcSystem(), m.get_srcComponent()), _comparable(decoder(m)))
        for m in expected_msgs
        if m.get_type() != "BAD_DATA"
    ]
    n_bad = sum(m.get_type() == "BAD_DATA" for m in expected_msgs)
    decoded = []
    real_decode = link_dialect.MAVLink.decode
    monkeypatch.setattr(link_dialect.MAVLink, "decode", lambda mav, buf: decoded.append(1) or real_decode(mav, buf))
    for direct in (True, False):
        decoded.clear()
        with _stream_link(kind) as (link, write):
            got = []
            for chunk in chunks:
                write(chunk)
                got += link.recv_items(0.0, decoder, decoder.direct if direct else None)
            deadline = time.monotonic() + WAIT_S  # the last pieces may still be on their way
            while link.counters.received < len(expected) and time.monotonic() < deadline:
                got += link.recv_items(0.05, decoder, decoder.direct if direct else None)
            assert [(s, _comparable(i)) for _, s, i in got] == expected
            assert link.counters.received == len(expected)
            assert n_bad <= link.counters.bad_data <= n_bad + noise_bytes
        # every frame but the direct path's went through pymavlink's decoder
        assert len(decoded) == n_other + (0 if direct else n_direct)


def test_frames_left_over_from_one_read_come_without_waiting_for_more_input():
    """More frames arrive in one read than one receive hands over: the rest are handed over at once by the next,
    not when the device next has something to read (nothing more comes here)."""
    packer = mavlink2.MAVLink(None, srcSystem=1, srcComponent=1)
    burst = b"".join(bytes(mavlink2.MAVLink_heartbeat_message(2, 3, 0, 0, 4, 3).pack(packer)) for _ in range(80))
    with _stream_link("tcp") as (link, write):
        write(burst)
        first = link.recv(WAIT_S)
        rest = link.recv(WAIT_S)
        assert (len(first), len(rest)) == (MAX_MESSAGES_PER_RECV, 80 - MAX_MESSAGES_PER_RECV)


def _telemetry_frames() -> tuple[list[bytes], int]:
    """A vehicle's RAW_IMU and HEARTBEAT among telemetry an attitude service does not read (VFR_HUD, SYS_STATUS,
    one with a bad CRC, one in MAVLink 1), and how many of those are MAVLink 2 frames."""
    vehicle = mavlink2.MAVLink(None, srcSystem=1, srcComponent=1)
    v1 = mavlink1.MAVLink(None, srcSystem=1, srcComponent=1)
    sample = units.ImuSample(5.0, (0.1, 0.2, -9.8), (0.01, 0.0, 0.0), (20.0, 1.0, 40.0))
    imu = mavlink2.MAVLink_raw_imu_message(**units.encode(sample, units.PROFILES["ardupilot"], "RAW_IMU"))
    hud = mavlink2.MAVLink_vfr_hud_message(1.0, 2.0, 90, 50, 10.0, 0.5)
    status = mavlink2.MAVLink_sys_status_message(1, 1, 1, 500, 12000, 30, 80, 0, 0, 0, 0, 0, 0)
    bad_hud = bytes(hud.pack(vehicle))
    frames = [
        bytes(mavlink2.MAVLink_heartbeat_message(2, 3, 0, 0, 4, 3).pack(vehicle)),
        bytes(imu.pack(vehicle)),
        bytes(hud.pack(vehicle)),
        bytes(status.pack(vehicle)),
        bytes(imu.pack(vehicle)),
        bad_hud[:-1] + bytes([bad_hud[-1] ^ 0xFF]),
        bytes(mavlink1.MAVLink_vfr_hud_message(1.0, 2.0, 90, 50, 10.0, 0.5).pack(v1)),
        bytes(imu.pack(vehicle)),
    ]
    return frames, 3


READS = frozenset({mavlink2.MAVLINK_MSG_ID_RAW_IMU, mavlink2.MAVLINK_MSG_ID_HEARTBEAT})


def _kinds(items: list[tuple]) -> list[str]:
    return [type(i).__name__ if not hasattr(i, "get_type") else i.get_type() for _, _, i in items]


@pytest.mark.parametrize("kind", ["udp", "tcp", "serial"])
def test_messages_the_caller_does_not_read_are_skipped_undecoded(kind, monkeypatch):
    """``reads``: a MAVLink 2 frame of another message is counted ``skipped`` and never reaches pymavlink's
    decoder (its CRC unchecked: a bad one is skipped too); MAVLink 1 is still pymavlink's; what is read comes as
    without ``reads``."""
    frames, unread_v2 = _telemetry_frames()
    decoder = MavlinkDecoder("RAW_IMU", units.PROFILES["ardupilot"])
    decoded = []
    real_decode = link_dialect.MAVLink.decode
    monkeypatch.setattr(link_dialect.MAVLink, "decode", lambda mav, buf: decoded.append(1) or real_decode(mav, buf))
    got = _received(kind, frames, decoder, READS)
    assert _kinds(got[0]) == ["Heartbeat", "ImuSample", "ImuSample", "VFR_HUD", "ImuSample"]
    assert got[1]["skipped"] == unread_v2 and got[1]["bad_data"] == 0
    assert len(decoded) == 2  # the HEARTBEAT and the MAVLink 1 frame
    everything = _received(kind, frames, decoder, None)
    assert _kinds(everything[0]) == [
        "Heartbeat",
        "ImuSample",
        "VFR_HUD",
        "SYS_STATUS",
        "ImuSample",
        "VFR_HUD",
        "ImuSample",
    ]
    assert everything[1]["skipped"] == 0 and everything[1]["bad_data"] == 1


def test_nothing_is_skipped_while_signing_is_required():
    """With signing required every frame is pymavlink's to check: none is skipped unchecked (these, unsigned, are
    all refused: by their signature, the one with a bad CRC by that)."""
    frames, _ = _telemetry_frames()
    decoder = MavlinkDecoder("RAW_IMU", units.PROFILES["ardupilot"])
    items, counters = _received("udp", frames, decoder, READS, signing_key=KEY, require_signing=True)
    assert items == [] and counters["skipped"] == 0
    assert (counters["signature_rejected"], counters["bad_data"]) == (len(frames) - 1, 1)


def _received(
    kind: str,
    frames: list[bytes],
    decoder: MavlinkDecoder,
    reads: frozenset[int] | None,
    direct: bool = True,
    **link_kwargs: object,
) -> tuple[list[tuple], dict[str, int]]:
    """``frames`` through a fresh link of ``kind`` (one datagram each, or one stream) read with ``reads``: what
    it handed over and its counters once every frame is accounted for."""
    if kind != "udp":
        with _stream_link(kind) as (link, write):
            write(b"".join(frames))
            return _drain(link, decoder, direct, len(frames), reads), dataclasses.asdict(link.counters)
    link = MavlinkLink("udpin:127.0.0.1:0", source_system=1, **link_kwargs)
    peer = UdpPeer()
    peer.target = link.local_address
    try:
        for data in frames:
            peer.send_raw(data)
        return _drain(link, decoder, direct, len(frames), reads), dataclasses.asdict(link.counters)
    finally:
        link.close()
        peer.close()
