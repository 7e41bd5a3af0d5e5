"""The `mavattitude` command line."""

from __future__ import annotations

import argparse
from collections.abc import Sequence

from mavattitude import __version__


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="mavattitude",
        description="Independent accelerometer + magnetometer attitude for a MAVLink vehicle.",
    )
    parser.add_argument("--version", action="version", version=f"mavattitude {__version__}")
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    build_parser().parse_args(argv)
    return 0
