"""CPython's cyclic garbage collector paused over work that keeps many objects and makes no reference cycles.

A replay keeps every output (each with its solution, for the lazy covariance) until it is written: hundreds of
thousands of container objects that the collector, triggered by the allocations, would traverse again and again
(a generation's pass over all of them each time it fills) to find nothing. Paused, they cost nothing to it, and
freed (by their reference counts) before it resumes, they are never traversed at all. Any cycle made meanwhile
is collected as usual after the block.
"""

from __future__ import annotations

import contextlib
import gc
from collections.abc import Iterator


@contextlib.contextmanager
def paused() -> Iterator[None]:
    """The collector paused for the block, its state (enabled or not) restored after: blocks may nest."""
    enabled = gc.isenabled()
    gc.disable()
    try:
        yield
    finally:
        if enabled:
            gc.enable()
