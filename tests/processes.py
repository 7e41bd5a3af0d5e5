"""A command of the CLI run as a process the test reads and interrupts, and never leaves running."""

from __future__ import annotations

import subprocess
import sys
import threading
from collections.abc import Iterator
from contextlib import contextmanager

CLI = [sys.executable, "-m", "mavattitude"]


@contextmanager
def cli_process(*args: str, timeout_s: float) -> Iterator[subprocess.Popen[str]]:
    """``mavattitude ARGS``, its stdout and stderr piped as text; killed after ``timeout_s`` (which bounds the
    test's reads of its pipes) and on leaving, whatever failed."""
    proc = subprocess.Popen([*CLI, *args], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    deadline = threading.Timer(timeout_s, proc.kill)
    deadline.start()
    try:
        yield proc
    finally:
        deadline.cancel()
        if proc.poll() is None:
            proc.kill()
            proc.wait()
