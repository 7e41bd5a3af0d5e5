"""One module per `mavattitude` sub-command, found by the CLI at start-up.

A command module defines ``NAME`` (the sub-command), ``HELP`` (one line for ``mavattitude --help``),
``add_arguments(parser)`` and ``run(args) -> int`` (the exit code). Adding a command is adding a module:
no central list to edit. How a command ends (the exit codes) and where it logs are here, for the CLI and the
commands alike.
"""

from __future__ import annotations

import contextlib
import contextvars
import logging
import os
import sys
from collections.abc import Iterator

EXIT_USER_ERROR = 2
EXIT_INTERRUPTED = 130  # 128 + SIGINT, as a shell reports a command stopped by Ctrl-C


#: The input the records logged now are about (a replayed log, a solved file), named before each message: the
#: library below a command (the log readers, the pipeline, the magnetic reference) does not know which file it
#: reads, and ``replay -j`` interleaves several files' lines.
_SUBJECT: contextvars.ContextVar[str] = contextvars.ContextVar("subject", default="")


@contextlib.contextmanager
def about(subject: str) -> Iterator[None]:
    """Every record logged inside the block starts ``subject: ``."""
    token = _SUBJECT.set(subject)
    try:
        yield
    finally:
        _SUBJECT.reset(token)


def _name_subject(record: logging.LogRecord) -> bool:
    subject = _SUBJECT.get()
    record.subject = f"{subject}: " if subject else ""
    return True


def configure_logging(level: str) -> None:
    """Log to stderr, each record of an input's work named by it (:func:`about`); under systemd
    (JOURNAL_STREAM set) journald adds the timestamps, so we do not."""
    fmt = "%(levelname)s %(name)s: %(subject)s%(message)s"
    if "JOURNAL_STREAM" not in os.environ:
        fmt = "%(asctime)s " + fmt
    handler = logging.StreamHandler(sys.stderr)
    handler.setFormatter(logging.Formatter(fmt))
    handler.addFilter(_name_subject)
    logging.basicConfig(level=level, handlers=[handler], force=True)
