"""The `mavattitude` command line: sub-commands are the modules of :mod:`mavattitude.commands`.

User mistakes (a :class:`~mavattitude.errors.MavAttitudeError`) print one clear line and exit 2, with
no traceback; anything else is a bug and keeps its traceback.
"""

from __future__ import annotations

import argparse
import importlib
import logging
import os
import pkgutil
import sys
from collections.abc import Sequence
from types import ModuleType

from mavattitude import __version__, commands
from mavattitude.config import LOG_LEVELS
from mavattitude.errors import MavAttitudeError

EXIT_USER_ERROR = 2


def _command_modules() -> list[ModuleType]:
    names = sorted(m.name for m in pkgutil.iter_modules(commands.__path__) if not m.name.startswith("_"))
    return [importlib.import_module(f"{commands.__name__}.{name}") for name in names]


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="mavattitude",
        description="Independent accelerometer + magnetometer attitude (IGN) for a MAVLink vehicle. "
        "Run `mavattitude COMMAND --help` for each command.",
    )
    parser.add_argument("--version", action="version", version=f"mavattitude {__version__}")
    parser.add_argument(
        "--log-level",
        type=str.upper,
        choices=LOG_LEVELS,
        help="how much to log (default INFO; for `run`, the config's logging.level)",
    )
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", required=True)
    for module in _command_modules():
        command = sub.add_parser(module.NAME, help=module.HELP, description=module.HELP)
        module.add_arguments(command)
        command.set_defaults(handler=module.run)
    return parser


def configure_logging(level: str) -> None:
    """Log to stderr; under systemd (JOURNAL_STREAM set) journald adds the timestamps, so we do not."""
    fmt = "%(levelname)s %(name)s: %(message)s"
    if "JOURNAL_STREAM" not in os.environ:
        fmt = "%(asctime)s " + fmt
    logging.basicConfig(level=level, format=fmt, stream=sys.stderr, force=True)


def one_line(text: str) -> str:
    """``text`` with what would break or garble a line (newlines, control bytes a file held) escaped."""
    return "".join(c if c.isprintable() else repr(c)[1:-1] for c in text)


def main(argv: Sequence[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    configure_logging(args.log_level or "INFO")
    try:
        return int(args.handler(args))
    except MavAttitudeError as exc:
        print(f"mavattitude {args.command}: error: {one_line(str(exc))}", file=sys.stderr)
        return EXIT_USER_ERROR
    except KeyboardInterrupt:
        return 130
