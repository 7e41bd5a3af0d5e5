#!/usr/bin/env python3
"""Validate on real data: every recording in ../shared/data through the stream and batch paths.

``mavattitude validate`` with this repository's defaults. A full default run (no file, slice, method
or path chosen) also writes ``docs/validation.md`` and ``docs/figures/validation-*.png``; a partial
run, e.g. for tuning, only prints (unless --report/--figures are given):

    tools/validate_real.py --method fused --path stream ../shared/data/broad/08_*.csv.gz --stop 60
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from mavattitude.commands import EXIT_USER_ERROR, configure_logging, validate
from mavattitude.errors import MavAttitudeError

ROOT = Path(__file__).resolve().parents[1]
DATA = ROOT / ".." / "shared" / "data"


def main() -> int:
    parser = argparse.ArgumentParser(prog="validate_real.py", description=__doc__.split("\n\n")[0])
    validate.add_arguments(parser)
    parser.set_defaults(paths=[DATA])
    args = parser.parse_args()
    full_run = args.paths == [DATA] and args.start is None and args.stop is None
    if full_run and args.methods is None and args.paths_run is None:
        args.report = args.report or ROOT / "docs" / "validation.md"
        args.figures = args.figures or ROOT / "docs" / "figures"
    configure_logging("INFO")
    try:
        return validate.run(args)
    except MavAttitudeError as exc:
        print(f"validate_real.py: error: {exc}", file=sys.stderr)
        return EXIT_USER_ERROR


if __name__ == "__main__":
    sys.exit(main())
