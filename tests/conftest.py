"""Suite-wide fixtures, and ``--shuffle SEED``: the test files in a seeded random order, each file's tests too.

Shuffling within files keeps a file's module-scoped fixtures (the e2e daemons) set up once; a failure
names its seed, so the order is reproduced with the same ``--shuffle``. (Ten lines here rather than a
plugin dependency: pytest-random-order's default bucket does the same.)
"""

from __future__ import annotations

import compileall
import logging
import random
import signal
from collections.abc import Iterator
from pathlib import Path

import pytest

import mavattitude


def pytest_configure(config: pytest.Config) -> None:
    """Commands started by a test get SIGINT as from a terminal, however the suite itself was started.

    A suite started in the background by a script (``cmd &``, nohup) inherits SIGINT ignored, and an
    ignored signal stays ignored across exec: every command a test then interrupts would run on until its
    time-out. A handler here (not SIG_IGN) is reset to the default in each child.
    """
    if signal.getsignal(signal.SIGINT) is signal.SIG_IGN:
        signal.signal(signal.SIGINT, signal.default_int_handler)


def pytest_sessionstart(session: pytest.Session) -> None:
    """The package byte-compiled once, for the few hundred Python processes the suite starts (daemons, commands,
    fake vehicles): with PYTHONDONTWRITEBYTECODE set, as on the CI machines, an editable install is otherwise
    compiled again by each (~0.15 s apiece). The caches go where Python's own would (``__pycache__``, ignored
    by git, Docker and the deployment tests' copy)."""
    compileall.compile_dir(Path(mavattitude.__file__).parent, quiet=1)


def pytest_addoption(parser: pytest.Parser) -> None:
    parser.addoption("--shuffle", type=int, metavar="SEED", help="run files and tests in a random order (seeded)")


def pytest_collection_modifyitems(config: pytest.Config, items: list[pytest.Item]) -> None:
    seed = config.getoption("shuffle")
    if seed is None:
        return
    rng = random.Random(seed)
    files: dict[str, list[pytest.Item]] = {}
    for item in items:
        files.setdefault(str(item.path), []).append(item)
    order = list(files.values())
    rng.shuffle(order)
    for tests in order:
        rng.shuffle(tests)
    items[:] = [item for tests in order for item in tests]


def pytest_report_header(config: pytest.Config) -> str | None:
    seed = config.getoption("shuffle")
    return None if seed is None else f"shuffled: --shuffle {seed}"


@pytest.fixture(autouse=True)
def _restore_root_logging() -> Iterator[None]:
    """Undo what an in-process ``cli.main()`` does to the root logger.

    ``commands.configure_logging`` (``basicConfig(force=True)``) binds a handler to the ``sys.stderr`` of the
    moment, which inside a test is pytest's capture stream; it is closed when that test ends, and a later
    test's log records would then fail with "I/O operation on closed file".
    """
    root = logging.getLogger()
    handlers, level = root.handlers[:], root.level
    yield
    root.handlers[:] = handlers
    root.setLevel(level)
