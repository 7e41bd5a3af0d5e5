"""One module per `mavattitude` sub-command, found by the CLI at start-up.

A command module defines ``NAME`` (the sub-command), ``HELP`` (one line for ``mavattitude --help``),
``add_arguments(parser)`` and ``run(args) -> int`` (the exit code). Adding a command is adding a module:
no central list to edit. How a command ends (the exit codes) and where it logs are here, for the CLI and the
commands alike.
"""

from __future__ import annotations

import logging
import os
import sys

EXIT_USER_ERROR = 2
EXIT_INTERRUPTED = 130  # 128 + SIGINT, as a shell reports a command stopped by Ctrl-C


def configure_logging(level: str) -> None:
    """Log to stderr; under systemd (JOURNAL_STREAM set) journald adds the timestamps, so we do not."""
    fmt = "%(levelname)s %(name)s: %(message)s"
    if "JOURNAL_STREAM" not in os.environ:
        fmt = "%(asctime)s " + fmt
    logging.basicConfig(level=level, format=fmt, stream=sys.stderr, force=True)
