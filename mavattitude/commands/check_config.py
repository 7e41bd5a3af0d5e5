"""`mavattitude check-config [FILE]`: validate a config and print the effective values as YAML.

The effective config is the defaults, overlaid by FILE, overlaid by the file named in
``$MAVATTITUDE_CONFIG``; each layer is listed with how many values it sets and which are not the defaults. The config is
also handed to the pipeline, so settings that only the front end can check (a mounting name) are checked.
"""

from __future__ import annotations

import argparse
import sys
import textwrap
from collections.abc import Mapping
from typing import Any

from mavattitude.config import ENV_VAR, REPLACE_WHOLE, describe, layers, merge_layers

NAME = "check-config"
HELP = "validate a YAML config file and print the effective configuration"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "file",
        nargs="?",
        help=f"config file (optional: without it, the defaults overlaid by ${ENV_VAR} if set)",
    )


def _leaves(data: Mapping[str, Any], prefix: str = "") -> list[str]:
    """Dotted keys a raw layer sets (a polymorphic value counts as one key)."""
    out = []
    for key, value in data.items():
        path = f"{prefix}{key}"
        if isinstance(value, Mapping) and path not in REPLACE_WHOLE:
            out += _leaves(value, f"{path}.")
        else:
            out.append(path)
    return out


def run(args: argparse.Namespace) -> int:
    from mavattitude.pipeline import AttitudePipeline  # imports numpy and the front end: only when needed

    found = layers(args.file)  # each file read and parsed once
    config = merge_layers(found)
    AttitudePipeline(config)
    origin: dict[str, str] = {}
    for source, data in found:
        origin.update(dict.fromkeys(_leaves(data), source))
    sys.stdout.write(f"# effective configuration: valid\n{config.to_yaml()}")
    if not origin:
        sys.stdout.write("# every value is a default\n")
        return 0
    sys.stdout.write("# values set by a layer (all others are defaults):\n")
    defaults = {key: default for key, default, _ in describe()}
    effective = config.to_dict()
    for source, _ in found:
        keys = [key for key, where in origin.items() if where == source]
        if not keys:  # every value it set, a later layer set again
            continue
        changed = [key for key in keys if _value(effective, key) != defaults.get(key)]
        sys.stdout.write(_source_line(source, len(keys), changed))
    return 0


def _value(data: Mapping[str, Any], dotted: str) -> Any:
    for part in dotted.split("."):
        data = data[part]
    return data


def _source_line(source: str, count: int, changed: list[str]) -> str:
    """One entry per layer: how many values it sets and which of them are not the defaults."""
    text = f"{source}: {count} value{'s' if count != 1 else ''}"
    if len(changed) < count:
        text += f", {count - len(changed)} of them the defaults"
    if changed:
        text += f"; not the defaults: {', '.join(changed)}"
    return "\n".join(textwrap.wrap(text, 116, initial_indent="#   ", subsequent_indent="#     ")) + "\n"
