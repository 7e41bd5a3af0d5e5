"""MAVLink 2 signing: key files, outgoing signatures, rejection of unsigned, forged and replayed input."""

from __future__ import annotations

import hashlib
import os
import time

import pytest
from MAVProxy.modules.mavproxy_signing import SigningModule

from mavattitude.errors import SigningError
from mavattitude.link import MavlinkLink, load_signing_key
from mavattitude.link.signing import passphrase_to_key, signing_timestamp_now, verify_signature
from tests.link.peer import UdpPeer
from tests.link.test_connection import WAIT_S, recv_n

KEY = bytes(range(32))
OTHER_KEY = bytes(range(1, 33))
SIGNED_FLAG = 0x01


def _drain(link: MavlinkLink, timeout_s: float = 0.2) -> list:
    """Everything the link hands over until it has been quiet for ``timeout_s``."""
    got, batch = [], link.recv(timeout_s)
    while batch:
        got += batch
        batch = link.recv(timeout_s)
    return [m for _, m in got]


@pytest.fixture
def signed_link():
    link = MavlinkLink("udpin:127.0.0.1:0", source_system=1, signing_key=KEY, require_signing=True)
    yield link
    link.close()


def _peer(link: MavlinkLink, key: bytes | None, **kwargs) -> UdpPeer:
    peer = UdpPeer(system=1, key=key, **kwargs)
    peer.target = link.local_address
    return peer


def test_signed_input_accepted_and_output_signed_near_wall_clock(signed_link):
    peer = _peer(signed_link, KEY)
    peer.send(peer.heartbeat())
    recv_n(signed_link, "HEARTBEAT", 1)
    signed_link.send_heartbeat()
    peer.wait_for("HEARTBEAT")  # the peer's parser has the key: it verified our signature
    frame = peer.raw[-1]
    assert frame[2] & SIGNED_FLAG
    sent_ticks = int.from_bytes(frame[-12:-6], "little")
    # 10 µs ticks: within 2 s of the wall clock (one packet advances it by one tick)
    assert abs(sent_ticks - signing_timestamp_now()) < 2 * 100_000
    assert peer.mav.signing.goodsig_count >= 1 and peer.mav.signing.badsig_count == 0
    peer.close()


def test_unsigned_and_wrongly_signed_input_rejected_and_counted(signed_link):
    honest = _peer(signed_link, KEY)
    unsigned = _peer(signed_link, None)
    forger = _peer(signed_link, OTHER_KEY)
    for _ in range(3):
        unsigned.send(unsigned.heartbeat())
        forger.send(forger.heartbeat())
    honest.send(honest.heartbeat())
    got = []
    deadline = time.monotonic() + WAIT_S
    while time.monotonic() < deadline and signed_link.counters.signature_rejected < 6:
        got += _drain(signed_link, 0.05)
    assert signed_link.counters.signature_rejected == 6
    assert len(got) == 1 and got[0].get_signed()
    for peer in (honest, unsigned, forger):
        peer.close()


def test_forged_future_timestamp_does_not_lock_out_the_vehicle(signed_link):
    """pymavlink's own check records a stream's timestamp before checking the signature; ours does not."""
    honest = _peer(signed_link, KEY)
    far_future = signing_timestamp_now() + 10**12
    forger = _peer(signed_link, OTHER_KEY)
    forger.set_key(OTHER_KEY, link_id=0, timestamp=far_future)  # same stream id (link 0, system 1, comp 1)
    honest.send(honest.heartbeat())
    recv_n(signed_link, "HEARTBEAT", 1)
    forger.send(forger.heartbeat())
    honest.send(honest.heartbeat())
    recv_n(signed_link, "HEARTBEAT", 1)
    assert signed_link.counters.signature_rejected == 1
    honest.close()
    forger.close()


def test_replayed_frame_rejected(signed_link):
    honest = _peer(signed_link, KEY)
    frame = honest.send(honest.heartbeat())
    recv_n(signed_link, "HEARTBEAT", 1)
    honest.send_raw(frame)
    deadline = time.monotonic() + WAIT_S
    while signed_link.counters.signature_rejected == 0 and time.monotonic() < deadline:
        assert _drain(signed_link, 0.05) == []
    assert signed_link.counters.signature_rejected == 1
    honest.close()


def test_signing_not_required_accepts_unsigned_but_still_signs():
    with MavlinkLink("udpin:127.0.0.1:0", source_system=1, signing_key=KEY) as link:
        peer = _peer(link, None)
        peer.send(peer.heartbeat())
        recv_n(link, "HEARTBEAT", 1)
        link.send_heartbeat()
        peer.wait_for("HEARTBEAT")
        assert peer.raw[-1][2] & SIGNED_FLAG
        peer.close()


def test_verify_signature_checks_the_new_stream_window():
    peer = UdpPeer(system=4, key=KEY)
    now = signing_timestamp_now()
    peer.set_key(KEY, timestamp=now - 2 * 60 * 100_000)  # two minutes behind our clock

    class State:
        secret_key = KEY
        timestamp = now
        stream_timestamps: dict = {}  # noqa: RUF012  (a stand-in for pymavlink's MAVLinkSigning)

    stale = peer.pack(peer.heartbeat())
    assert not verify_signature(State, stale, 4, 1)
    assert State.stream_timestamps == {}
    peer.set_key(KEY, timestamp=now - 30 * 100_000)  # 30 s behind: a new stream within the minute
    fresh = peer.pack(peer.heartbeat())
    assert verify_signature(State, fresh, 4, 1)
    assert not verify_signature(State, fresh, 4, 1)  # the same timestamp again is a replay
    peer.close()


def test_key_file_raw_bytes(tmp_path):
    path = tmp_path / "key.bin"
    path.write_bytes(KEY)
    path.chmod(0o600)
    assert load_signing_key(path) == KEY


def test_key_file_passphrase_hashed_as_mavproxy_does(tmp_path):
    path = tmp_path / "passphrase"
    path.write_text("correct horse battery staple\n")
    path.chmod(0o640)  # group-readable is allowed; world-readable is not
    expected = SigningModule.passphrase_to_key(None, "correct horse battery staple")
    assert load_signing_key(path) == expected == hashlib.sha256(b"correct horse battery staple").digest()


def test_world_readable_key_file_refused(tmp_path):
    path = tmp_path / "key.bin"
    path.write_bytes(KEY)
    path.chmod(0o644)
    with pytest.raises(SigningError, match=r"world-readable \(mode 0644\).*chmod 600"):
        load_signing_key(path)


@pytest.mark.parametrize(("content", "match"), [(b"", "is empty"), (b"\n", "is empty"), (b"\xff\xfe\x00", "ASCII")])
def test_unusable_key_files_refused(tmp_path, content, match):
    path = tmp_path / "key"
    path.write_bytes(content)
    os.chmod(path, 0o600)
    with pytest.raises(SigningError, match=match):
        load_signing_key(path)


def test_missing_key_file_and_bad_setups_refused(tmp_path):
    with pytest.raises(SigningError, match="cannot read signing key file"):
        load_signing_key(tmp_path / "absent")
    with pytest.raises(SigningError, match="ASCII"):
        passphrase_to_key("clé")
    with pytest.raises(SigningError, match="32 bytes, not 16"):
        MavlinkLink("udpin:127.0.0.1:0", source_system=1, signing_key=bytes(16))
    with pytest.raises(SigningError, match="no signing key"):
        MavlinkLink("udpin:127.0.0.1:0", source_system=1, require_signing=True)
