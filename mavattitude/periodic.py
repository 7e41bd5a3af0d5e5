"""Periodic work on the monotonic clock: one small timer instead of a ``_next_*`` attribute per task."""

from __future__ import annotations

import math


class Every:
    """Due every ``period_s`` (``math.inf``: never): first ``first_s`` after ``now`` (at once by default)."""

    __slots__ = ("_next", "period_s")

    def __init__(self, period_s: float, now: float, first_s: float = 0.0) -> None:
        self.period_s = period_s
        self._next = now + first_s if period_s < math.inf else math.inf

    def due(self, now: float) -> bool:
        """True, and the next time set a period on, when ``now`` has reached it."""
        if now < self._next:
            return False
        self._next = now + self.period_s
        return True

    def at_once(self, now: float) -> None:
        """Due at the next check, then every period from there."""
        if self.period_s < math.inf:
            self._next = now

    def wait_s(self, now: float) -> float:
        """Seconds until due (0 when it is)."""
        return max(self._next - now, 0.0)
