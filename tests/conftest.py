"""Suite-wide fixtures."""

from __future__ import annotations

import logging
from collections.abc import Iterator

import pytest


@pytest.fixture(autouse=True)
def _restore_root_logging() -> Iterator[None]:
    """Undo what an in-process ``cli.main()`` does to the root logger.

    ``cli.configure_logging`` (``basicConfig(force=True)``) binds a handler to the ``sys.stderr`` of the
    moment, which inside a test is pytest's capture stream; it is closed when that test ends, and a later
    test's log records would then fail with "I/O operation on closed file".
    """
    root = logging.getLogger()
    handlers, level = root.handlers[:], root.level
    yield
    root.handlers[:] = handlers
    root.setLevel(level)
