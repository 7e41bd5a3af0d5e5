"""A file whose modification time the main loop refreshes: what Docker's HEALTHCHECK reads.

Under systemd the loop pings the watchdog over sd_notify (:mod:`mavattitude.systemd_notify`); a
container has no such supervisor socket, so the loop touches ``$MAVATTITUDE_ALIVE_FILE`` every
:data:`PERIOD_S` instead, and the image's HEALTHCHECK fails once the file is older than its limit: a
frozen loop shows as ``unhealthy``. With the variable unset nothing is written.

A failed touch is logged and counted, never raised, like a failed sd_notify: the health check is what
notices a loop that stops refreshing the file.
"""

from __future__ import annotations

import logging
import os
from collections.abc import Mapping
from pathlib import Path

log = logging.getLogger(__name__)

ENV = "MAVATTITUDE_ALIVE_FILE"
PERIOD_S = 1.0  # the image's HEALTHCHECK allows a few of these (its limit is in the Dockerfile)


class AliveFile:
    """``touch()`` refreshes the file named by ``$MAVATTITUDE_ALIVE_FILE``; a no-op when it is unset."""

    def __init__(self, environ: Mapping[str, str] | None = None) -> None:
        env = os.environ if environ is None else environ
        name = env.get(ENV, "")
        self.path = Path(name) if name else None
        self.errors = 0

    def touch(self) -> bool:
        """Create or refresh the file; True if it was written."""
        if self.path is None:
            return False
        try:
            self.path.touch()
        except OSError as exc:
            self.errors += 1
            log.warning("cannot refresh the alive file %s (%d failures so far): %s", self.path, self.errors, exc)
            return False
        return True
