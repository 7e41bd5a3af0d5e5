"""sd_notify: tell systemd READY, STATUS, WATCHDOG and STOPPING over ``$NOTIFY_SOCKET``.

The protocol is one ``AF_UNIX`` datagram of ``KEY=value`` lines to the socket named in ``$NOTIFY_SOCKET``
(a path, or ``@name`` for the abstract namespace); see sd_notify(3). It is a few lines of standard
library, so we write it rather than depend on the ``sdnotify`` package, which has not had a release since
2017 and hides send errors unless told otherwise. Outside systemd (``$NOTIFY_SOCKET`` unset) every call
is a no-op, so the service runs the same from a terminal, a container or a test.

A failed send is logged and counted, never raised: systemd's watchdog is what notices a service that
stops reporting, and taking the attitude service down because its supervisor's socket hiccupped would
be the worse failure.

Use a :class:`SystemdNotifier` (``notifier.ready()``, ``.status(text)``, ``.watchdog()``, ``.stopping()``,
``.watchdog_interval_s``), or the module-level functions of the same names, which share one notifier.
"""

from __future__ import annotations

import logging
import os
import socket
from collections.abc import Mapping

log = logging.getLogger(__name__)


class SystemdNotifier:
    """A sender of sd_notify messages; a no-op when the process was not started by systemd with Type=notify."""

    def __init__(self, environ: Mapping[str, str] | None = None) -> None:
        env = os.environ if environ is None else environ
        self.address = _socket_address(env.get("NOTIFY_SOCKET", ""))
        self.watchdog_interval_s = _watchdog_interval_s(env)
        self.send_errors = 0
        self._sock: socket.socket | None = None
        if self.address is not None:
            self._sock = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM | socket.SOCK_CLOEXEC)

    @property
    def enabled(self) -> bool:
        """True when messages actually go to systemd."""
        return self._sock is not None

    def notify(self, **fields: str) -> bool:
        """Send ``KEY=value`` lines (keys upper-cased); True if the datagram was sent."""
        if self._sock is None:
            return False
        payload = "\n".join(f"{key.upper()}={value}" for key, value in fields.items())
        try:
            self._sock.sendto(payload.encode("utf-8"), self.address)
        except OSError as exc:
            self.send_errors += 1
            log.warning("sd_notify to %r failed (%d so far): %s", self.address, self.send_errors, exc)
            return False
        return True

    def ready(self, status: str | None = None) -> bool:
        """The service has its link and its first solution (Type=notify start-up is complete)."""
        return self.notify(ready="1", **({"status": status} if status is not None else {}))

    def status(self, text: str) -> bool:
        """One line shown by ``systemctl status`` (the service's counters)."""
        return self.notify(status=text.replace("\n", " "))

    def watchdog(self) -> bool:
        """The main loop is alive: call at least every ``watchdog_interval_s / 2``."""
        return self.notify(watchdog="1")

    def stopping(self) -> bool:
        """The service is shutting down on purpose."""
        return self.notify(stopping="1")

    def close(self) -> None:
        if self._sock is not None:
            self._sock.close()
            self._sock = None

    def __enter__(self) -> SystemdNotifier:
        return self

    def __exit__(self, *exc_info: object) -> None:
        self.close()


_default: SystemdNotifier | None = None


def default_notifier() -> SystemdNotifier:
    """The process-wide notifier, built from the environment on first use."""
    global _default
    if _default is None:
        _default = SystemdNotifier()
    return _default


def ready(status: str | None = None) -> bool:
    return default_notifier().ready(status)


def status(text: str) -> bool:
    return default_notifier().status(text)


def watchdog() -> bool:
    return default_notifier().watchdog()


def stopping() -> bool:
    return default_notifier().stopping()


def watchdog_interval_s() -> float | None:
    """systemd's watchdog period in seconds, or None when no watchdog is set for this process."""
    return default_notifier().watchdog_interval_s


def _socket_address(notify_socket: str) -> str | bytes | None:
    """``$NOTIFY_SOCKET`` as a socket address: a path, or ``@name`` -> the abstract name ``\\0name``."""
    if not notify_socket:
        return None
    if notify_socket.startswith("@"):
        return b"\0" + notify_socket[1:].encode()
    if notify_socket.startswith("/"):
        return notify_socket
    log.warning("ignoring NOTIFY_SOCKET=%r: neither an absolute path nor an @abstract name", notify_socket)
    return None


def _watchdog_interval_s(env: Mapping[str, str]) -> float | None:
    """systemd's watchdog period (``WATCHDOG_USEC``) if it is meant for this process, else None.

    ``WATCHDOG_PID``, when set, names the process the watchdog is for: a child that inherited the
    environment must not ping on its parent's behalf.
    """
    usec = env.get("WATCHDOG_USEC", "")
    pid = env.get("WATCHDOG_PID", "")
    if not usec.isdigit() or int(usec) == 0:
        return None
    if pid and (not pid.isdigit() or int(pid) != os.getpid()):
        return None
    return int(usec) / 1e6
