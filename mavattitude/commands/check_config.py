"""`mavattitude check-config [FILE]`: validate a config and print the effective values as YAML.

The effective config is the defaults, overlaid by FILE, overlaid by the file named in
``$MAVATTITUDE_CONFIG``; each value set by a layer is listed with the layer it came from. The config is
also handed to the pipeline, so settings that only the front end can check (a mounting name) are checked.
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Mapping
from typing import Any

from mavattitude.config import ENV_VAR, REPLACE_WHOLE, layers, merge_layers

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
    sys.stdout.write(
        "# values set by a layer (all others are defaults):\n" if origin else "# every value is a default\n"
    )
    for key, source in origin.items():
        sys.stdout.write(f"#   {key}: {source}\n")
    return 0
