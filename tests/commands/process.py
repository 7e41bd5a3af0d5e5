"""The command line as a user runs it: ``python -m mavattitude`` in a process of its own."""

from __future__ import annotations

import os
import subprocess
import sys
import threading
from collections.abc import Iterator, Sequence
from contextlib import contextmanager

from mavattitude.config import ENV_VAR

CLI = [sys.executable, "-m", "mavattitude"]
# Without the overlay config a developer's shell may name: the commands read only what the test gives them.
ENV_WITHOUT_OVERLAY = {k: v for k, v in os.environ.items() if k != ENV_VAR}


def run_cli(args: Sequence[str], timeout_s: float = 60.0) -> subprocess.CompletedProcess[str]:
    """``mavattitude ARGS`` to its end: exit code, stdout and stderr as text."""
    return subprocess.run([*CLI, *args], capture_output=True, text=True, timeout=timeout_s, env=ENV_WITHOUT_OVERLAY)


@contextmanager
def cli_process(*args: str, timeout_s: float) -> Iterator[subprocess.Popen[str]]:
    """``mavattitude ARGS`` running, for the test to read and interrupt: its stdout and stderr piped as text;
    killed after ``timeout_s`` (which bounds the test's reads of its pipes) and on leaving, whatever failed."""
    proc = subprocess.Popen(
        [*CLI, *args], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=ENV_WITHOUT_OVERLAY
    )
    deadline = threading.Timer(timeout_s, proc.kill)
    deadline.start()
    try:
        yield proc
    finally:
        deadline.cancel()
        if proc.poll() is None:
            proc.kill()
            proc.wait()
