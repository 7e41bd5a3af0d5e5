"""Settings fields that carry their own check: the config reads each field's range and description from
its metadata, so a key is checked once, by the same rule, in a file and where the settings live."""

from __future__ import annotations

import dataclasses
from typing import Any


def ranged(default: float | None, doc: str, lo: float = 0.0, hi: float = 1e6, *, lo_open: bool = False) -> Any:
    """A number in ``[lo, hi]`` (``(lo, hi]`` with ``lo_open``) with its one-line description."""
    return dataclasses.field(default=default, metadata={"doc": doc, "range": (lo, hi, lo_open)})


def described(default: Any, doc: str) -> Any:
    """A field the config checks by its type (a bool, a vector), with its one-line description."""
    return dataclasses.field(default=default, metadata={"doc": doc})
