#!/usr/bin/env python3
"""Every performance figure of the project in one table: `python tools/bench.py [SECTION ...] [--quick]`.

The same as `mavattitude bench` (mavattitude/commands/bench.py holds the measurements), except that a
full run of every section also writes the table and the machine's description to docs/benchmarks.md,
the figures the README quotes. `--quick` is the CI smoke run (seconds); `-o FILE` writes anywhere.
"""

from __future__ import annotations

import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))  # the checkout's package, installed or not

from mavattitude.cli import main  # noqa: E402  (after the path set-up above)

RECORD = ROOT / "docs" / "benchmarks.md"


def bench_argv(argv: list[str]) -> list[str]:
    """`mavattitude bench` arguments; the full run of all sections writes the record unless told where."""
    writes = any(a in ("-o", "--output") or a.startswith("--output=") for a in argv)
    sections = [a for a in argv if not a.startswith("-")]
    if not writes and not sections and "--quick" not in argv and not {"-h", "--help"} & set(argv):
        argv = [*argv, "--output", str(RECORD)]
    return ["bench", *argv]


if __name__ == "__main__":
    sys.exit(main(bench_argv(sys.argv[1:])))
