"""The `mavattitude` command line: sub-commands are the modules of :mod:`mavattitude.commands`.

User mistakes (a :class:`~mavattitude.errors.MavAttitudeError`) print one clear line and exit 2, with
no traceback; anything else is a bug and keeps its traceback. A mistyped flag, choice or command gets
argparse's usage and exit 2 with a "did you mean"; the global flags (``--log-level``) go before or after
the command's name; an interrupted command (Ctrl-C) exits 130.
"""

from __future__ import annotations

import argparse
import difflib
import importlib
import pkgutil
import re
import sys
from collections.abc import Sequence
from types import ModuleType
from typing import Any, NoReturn

from mavattitude import __version__, commands
from mavattitude.commands import EXIT_INTERRUPTED, EXIT_USER_ERROR, configure_logging
from mavattitude.config import LOG_LEVELS
from mavattitude.errors import MavAttitudeError

__all__ = ["EXIT_INTERRUPTED", "EXIT_USER_ERROR", "build_parser", "configure_logging", "main"]


def _command_modules() -> list[ModuleType]:
    names = sorted(m.name for m in pkgutil.iter_modules(commands.__path__) if not m.name.startswith("_"))
    return [importlib.import_module(f"{commands.__name__}.{name}") for name in names]


class _Parser(argparse.ArgumentParser):
    """argparse that suggests what was probably meant: a mistyped choice or sub-command, an unknown flag."""

    commands: dict[str, argparse.ArgumentParser]

    def error(self, message: str) -> NoReturn:
        bad = re.search(r"invalid choice: '([^']*)' \(choose from (.*)\)", message)
        if bad:
            message += _did_you_mean(bad.group(1), re.findall(r"'([^']*)'", bad.group(2)))
        super().error(message)

    def parse_args(self, args: Sequence[str] | None = None, namespace: Any = None) -> Any:  # type: ignore[override]
        parsed, extras = self.parse_known_args(args, namespace)
        if extras:  # told by the sub-command's parser, with its usage and its flags to suggest from
            parser = getattr(self, "commands", {}).get(getattr(parsed, "command", None), self)
            flags = [s for action in parser._actions for s in action.option_strings]
            unknown = next((e.split("=", 1)[0] for e in extras if e.startswith("-")), None)
            if unknown is None:
                parser.error(f"unrecognized arguments: {' '.join(extras)}")
            parser.error(f"unrecognized argument {unknown}{_did_you_mean(unknown, flags)}")
        return parsed


def _did_you_mean(word: str, candidates: Sequence[str]) -> str:
    close = difflib.get_close_matches(word, candidates, n=1, cutoff=0.6)
    return f"; did you mean {close[0]}?" if close else ""


def _global_flags(default: Any) -> argparse.ArgumentParser:
    """The flags every command accepts before or after its name (after it, not given: ``SUPPRESS`` keeps
    what was given before it)."""
    flags = argparse.ArgumentParser(add_help=False)
    flags.add_argument(
        "--log-level",
        type=str.upper,
        choices=LOG_LEVELS,
        default=default,
        help="how much to log (default INFO; for `run`, the config's logging.level)",
    )
    return flags


def build_parser() -> argparse.ArgumentParser:
    parser = _Parser(
        prog="mavattitude",
        description="Independent accelerometer + magnetometer attitude (IGN) for a MAVLink vehicle. "
        "Run `mavattitude COMMAND --help` for each command.",
        parents=[_global_flags(None)],
    )
    parser.add_argument("--version", action="version", version=f"mavattitude {__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", required=True)
    parser.commands = {}
    for module in _command_modules():
        command = sub.add_parser(
            module.NAME, help=module.HELP, description=module.HELP, parents=[_global_flags(argparse.SUPPRESS)]
        )
        module.add_arguments(command)
        command.set_defaults(handler=module.run)
        parser.commands[module.NAME] = command
    return parser


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
        return EXIT_INTERRUPTED
