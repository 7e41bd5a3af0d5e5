"""The command line as a user runs it: ``python -m mavattitude`` in a process of its own."""

from __future__ import annotations

import os
import subprocess
import sys
from collections.abc import Sequence

from mavattitude.config import ENV_VAR

# Without the overlay config a developer's shell may name: the commands read only what the test gives them.
ENV_WITHOUT_OVERLAY = {k: v for k, v in os.environ.items() if k != ENV_VAR}


def run_cli(args: Sequence[str], timeout_s: float = 60.0) -> subprocess.CompletedProcess[str]:
    """``mavattitude ARGS`` to its end: exit code, stdout and stderr as text."""
    return subprocess.run(
        [sys.executable, "-m", "mavattitude", *args],
        capture_output=True,
        text=True,
        timeout=timeout_s,
        env=ENV_WITHOUT_OVERLAY,
    )
