"""The vehicle's clock as seen through its IMU messages: wrap, reboot, duplicates and reordering.

Message times come from the autopilot (``time_usec``, ``time_boot_ms``), never from our own clock. The
clock keeps them increasing: a uint32 millisecond field that wraps (after ≈ 49.7 days) is unwrapped; a
time that goes back by more than ``reorder_window_s`` is a reboot (the caller resets what depends on
time); a repeated time is a duplicate and a time slightly behind the newest is a reordered datagram, both
dropped, as is a time that is no finite number. Gaps are the front end's business (it knows the input time-out).
"""

from __future__ import annotations

import enum
import math

import numpy as np
from numpy.typing import ArrayLike


class ClockEvent(enum.Enum):
    OK = "ok"
    WRAP = "wrap"  # time field wrapped; the unwrapped time is returned
    REBOOT = "reboot"  # time restarted; the returned time starts a new epoch
    DUPLICATE = "duplicate"  # same time as the newest sample: dropped
    OUT_OF_ORDER = "out_of_order"  # slightly behind the newest sample: dropped
    NO_TIME = "no_time"  # not a finite number (a CSV's nan or inf): dropped, the clock unchanged


class VehicleClock:
    """Unwraps and checks message times; one per input stream."""

    def __init__(self, reorder_window_s: float = 1.0) -> None:
        self.reorder_window_s = reorder_window_s
        self._offset_s = 0.0
        self._last_raw_s: float | None = None

    def update(self, raw_time_s: float, wrap_period_s: float | None) -> tuple[float | None, ClockEvent]:
        """The message time on the unwrapped vehicle clock, or ``None`` when the sample must be dropped."""
        if not -math.inf < raw_time_s < math.inf:  # NaN too: taken, it would make every later time a reboot
            return None, ClockEvent.NO_TIME
        last = self._last_raw_s
        if last is None or raw_time_s > last:
            self._last_raw_s = raw_time_s
            return raw_time_s + self._offset_s, ClockEvent.OK
        if raw_time_s == last:
            return None, ClockEvent.DUPLICATE
        back_s = last - raw_time_s
        if wrap_period_s is not None and back_s > 0.5 * wrap_period_s:
            self._offset_s += wrap_period_s
            self._last_raw_s = raw_time_s
            return raw_time_s + self._offset_s, ClockEvent.WRAP
        if back_s <= self.reorder_window_s:
            return None, ClockEvent.OUT_OF_ORDER
        self._offset_s = 0.0
        self._last_raw_s = raw_time_s
        return raw_time_s, ClockEvent.REBOOT


def first_repeats(time_s: ArrayLike) -> int:
    """How many samples, in arrival order, repeat the time of the one before while that one did not repeat its own:
    one per copy of a stream that arrives twice (every sample followed by its copy), one per run of a clock that
    stands still (however long the run)."""
    t = np.asarray(time_s, dtype=float)
    same = t[1:] == t[:-1]
    return int(np.count_nonzero(same[1:] & ~same[:-1]) + (same[0] if len(same) else 0))
