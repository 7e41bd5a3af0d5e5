"""A container's watchdog: a file the main loop refreshes, and an exit when the loop hangs.

Under systemd the loop pings the watchdog over sd_notify (:mod:`mavattitude.systemd_notify`) and systemd
kills and restarts a loop that stops pinging. A container has no such supervisor, so with
``$MAVATTITUDE_ALIVE_FILE`` set (the image sets it) the loop does both halves itself:

- it touches the file every :data:`PERIOD_S`, and the image's HEALTHCHECK fails once the file is older
  than its limit, so a frozen loop shows as ``unhealthy``;
- each touch re-arms :func:`faulthandler.dump_traceback_later`: a loop that has not touched for
  :data:`HANG_EXIT_S` gets every thread's traceback written to stderr (the container's log) and the
  process ends with exit code 1, which the restart policy (``--restart=unless-stopped``) restarts. It is
  a C thread, so it fires even while a hung loop holds the GIL.

With the variable unset nothing is written or armed. A failed touch is logged and counted, never raised,
like a failed sd_notify: the health check is what notices a loop that stops refreshing the file.
"""

from __future__ import annotations

import faulthandler
import logging
import os
from collections.abc import Mapping
from pathlib import Path

log = logging.getLogger(__name__)

ENV = "MAVATTITUDE_ALIVE_FILE"
PERIOD_S = 1.0  # the image's HEALTHCHECK allows a few of these (its limit, 5 s, is in the Dockerfile)
HANG_EXIT_S = 10.0  # twice systemd's WatchdogSec: past the health check's verdict, so both are seen


class AliveFile:
    """``touch()`` refreshes the file named by ``$MAVATTITUDE_ALIVE_FILE`` and re-arms the hang exit;
    ``close()`` disarms it (a stopping service may take longer than a loop period). No-ops when unset."""

    def __init__(self, environ: Mapping[str, str] | None = None, hang_exit_s: float = HANG_EXIT_S) -> None:
        env = os.environ if environ is None else environ
        name = env.get(ENV, "")
        self.path = Path(name) if name else None
        self.hang_exit_s = hang_exit_s
        self.errors = 0

    def touch(self) -> bool:
        """Create or refresh the file and re-arm the hang exit; True if the file was written."""
        if self.path is None:
            return False
        faulthandler.dump_traceback_later(self.hang_exit_s, exit=True)
        try:
            self.path.touch()
        except OSError as exc:
            self.errors += 1
            log.warning("cannot refresh the alive file %s (%d failures so far): %s", self.path, self.errors, exc)
            return False
        return True

    def close(self) -> None:
        if self.path is not None:
            faulthandler.cancel_dump_traceback_later()
