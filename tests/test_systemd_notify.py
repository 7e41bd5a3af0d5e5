"""The sd_notify protocol for real: the notifier sends to a unix datagram socket the test listens on."""

from __future__ import annotations

import os
import socket
import uuid
from collections.abc import Iterator
from pathlib import Path

import pytest

from mavattitude import systemd_notify
from mavattitude.systemd_notify import SystemdNotifier

RECV_TIMEOUT_S = 2.0  # a local datagram arrives in microseconds; this only bounds a failing test


@pytest.fixture
def listener(tmp_path: Path) -> Iterator[tuple[socket.socket, str]]:
    """A datagram socket bound at a path, as systemd's own notify socket is."""
    sock = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
    path = str(tmp_path / "notify.sock")
    sock.bind(path)
    sock.settimeout(RECV_TIMEOUT_S)
    yield sock, path
    sock.close()


def _lines(sock: socket.socket) -> list[str]:
    return sock.recv(4096).decode().split("\n")


def test_each_message_arrives_as_one_datagram_of_key_value_lines(listener):
    sock, path = listener
    with SystemdNotifier({"NOTIFY_SOCKET": path}) as notifier:
        assert notifier.enabled
        assert notifier.ready(status="link up, first solution")
        assert _lines(sock) == ["READY=1", "STATUS=link up, first solution"]
        assert notifier.status("rx 200\nemitted 50")
        assert _lines(sock) == ["STATUS=rx 200 emitted 50"]  # STATUS is one line: newlines would split it
        assert notifier.watchdog()
        assert _lines(sock) == ["WATCHDOG=1"]
        assert notifier.stopping()
        assert _lines(sock) == ["STOPPING=1"]
        assert notifier.send_errors == 0


def test_abstract_namespace_socket():
    name = f"mavattitude-test-{uuid.uuid4().hex}"
    with socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM) as sock:
        sock.bind(b"\0" + name.encode())
        sock.settimeout(RECV_TIMEOUT_S)
        with SystemdNotifier({"NOTIFY_SOCKET": "@" + name}) as notifier:
            assert notifier.watchdog()
        assert _lines(sock) == ["WATCHDOG=1"]


def test_no_socket_means_no_op():
    notifier = SystemdNotifier({})
    assert not notifier.enabled
    assert not notifier.ready()
    assert not notifier.watchdog()
    assert notifier.watchdog_interval_s is None


def test_relative_path_is_refused_not_guessed(caplog):
    notifier = SystemdNotifier({"NOTIFY_SOCKET": "relative.sock"})
    assert not notifier.enabled
    assert "neither an absolute path" in caplog.text


def test_send_failure_is_counted_and_logged_not_raised(tmp_path, caplog):
    with SystemdNotifier({"NOTIFY_SOCKET": str(tmp_path / "nobody-listens.sock")}) as notifier:
        assert not notifier.ready()
        assert not notifier.watchdog()
        assert notifier.send_errors == 2
    assert "sd_notify" in caplog.text


@pytest.mark.parametrize(
    ("env", "expected_s"),
    [
        ({"WATCHDOG_USEC": "5000000"}, 5.0),
        ({"WATCHDOG_USEC": "2500000", "WATCHDOG_PID": str(os.getpid())}, 2.5),
        ({"WATCHDOG_USEC": "5000000", "WATCHDOG_PID": str(os.getpid() + 1)}, None),  # another process's
        ({"WATCHDOG_USEC": "0"}, None),
        ({"WATCHDOG_USEC": "soon"}, None),
        ({}, None),
    ],
)
def test_watchdog_interval(env, expected_s):
    assert SystemdNotifier(env).watchdog_interval_s == expected_s


def test_module_functions_share_one_notifier_from_the_environment(listener, monkeypatch):
    sock, path = listener
    monkeypatch.setenv("NOTIFY_SOCKET", path)
    monkeypatch.setenv("WATCHDOG_USEC", "3000000")
    monkeypatch.setattr(systemd_notify, "_default", None)
    assert systemd_notify.ready()
    assert _lines(sock) == ["READY=1"]
    assert systemd_notify.status("ok")
    assert _lines(sock) == ["STATUS=ok"]
    assert systemd_notify.watchdog()
    assert _lines(sock) == ["WATCHDOG=1"]
    assert systemd_notify.stopping()
    assert _lines(sock) == ["STOPPING=1"]
    assert systemd_notify.watchdog_interval_s() == 3.0
    assert systemd_notify.default_notifier() is systemd_notify.default_notifier()
    systemd_notify.default_notifier().close()
