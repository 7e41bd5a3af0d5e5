"""What the service asks the autopilot for, and how it knows what was answered: no I/O here.

- :class:`RequestSchedule`: when the streams are asked for (at once on locking on, again every few
  seconds), for the service and live ``calibrate`` alike.
- :class:`PendingRequests`: the SET_MESSAGE_INTERVAL commands sent and not yet answered. A COMMAND_ACK
  names only the command it answers, not its parameters, so several requests of one command (the IMU
  stream, the position, the autopilot's ATTITUDE) are told apart by order: an autopilot answers the
  COMMAND_LONGs of one sender in the order they came, so an ACK answers the *oldest* request of its
  command still waiting. A request unanswered for ``timeout_s`` is reported once as timed out but kept
  (a slow link answers late: that late ACK must not be taken for the next request's) until
  ``forget_s``; an ACK addressed to another system or component (a ground station's request, through a
  router) is not ours.
- :class:`RateMonitor`: the input rate actually received over windows of ``window_s``; it turns *low*
  once the rate stays under ``LOW_FRACTION`` of the requested rate for ``LOW_WINDOWS`` windows in a row,
  and clears above ``CLEAR_FRACTION`` (hysteresis: one warning, no flip-flop).
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass

LOW_FRACTION = 0.9  # below this fraction of the requested rate the stream is "low" ...
CLEAR_FRACTION = 0.97  # ... until it is back above this fraction
LOW_WINDOWS = 2  # consecutive low windows before saying so


@dataclass(frozen=True)
class StreamRequest:
    """One message the service asks the autopilot to stream: ``name`` at ``rate_hz``."""

    name: str
    message_id: int
    rate_hz: float
    optional: bool = False  # useful, not needed: an autopilot that refuses it is no reason for a warning

    def describe(self) -> str:
        return f"{self.name} at {self.rate_hz:g} Hz"


class RequestSchedule:
    """When to ask the autopilot for its streams: at once when told (locking on, a new connection, a rebooted
    autopilot), then every ``repeat_s`` (a ground station may change rates; a reboot forgets them)."""

    def __init__(self, streams: list[StreamRequest], repeat_s: float) -> None:
        self.streams = streams
        self.repeat_s = repeat_s
        self._next_s = math.inf  # nothing is asked before the first ask_now

    def ask_now(self, now_s: float) -> None:
        if self.streams:
            self._next_s = now_s

    def due(self, now_s: float) -> list[StreamRequest]:
        """The streams to request now (every one, when due), else none."""
        if now_s < self._next_s:
            return []
        self._next_s = now_s + self.repeat_s
        return self.streams


@dataclass
class _Pending:
    request: StreamRequest
    sent_s: float
    timed_out: bool = False


class PendingRequests:
    """SET_MESSAGE_INTERVAL requests waiting for their COMMAND_ACK (see the module docstring)."""

    def __init__(self, timeout_s: float, forget_s: float) -> None:
        self.timeout_s = timeout_s
        self.forget_s = forget_s
        self._pending: deque[_Pending] = deque()

    def __len__(self) -> int:
        return len(self._pending)

    def sent(self, request: StreamRequest, now_s: float) -> None:
        self._pending.append(_Pending(request, now_s))

    def answered(self, now_s: float) -> StreamRequest | None:
        """The request an ACK of SET_MESSAGE_INTERVAL addressed to us answers (None: none was waiting)."""
        self._forget(now_s)
        return self._pending.popleft().request if self._pending else None

    def timed_out(self, now_s: float, heard_s: float = math.inf) -> tuple[list[StreamRequest], int]:
        """Requests unanswered for ``timeout_s``, each reported once (they still match a late ACK), and how many
        more were dropped unreported: sent to a vehicle not heard from since (``heard_s``: when it last was, its
        HEARTBEAT or its input), whose silence (a restart, the link down) is no refusal, and which will not answer
        them."""
        self._forget(now_s)
        out, unheard = [], [p for p in self._pending if heard_s < p.sent_s and now_s - p.sent_s >= self.timeout_s]
        for p in unheard:
            self._pending.remove(p)
        for p in self._pending:
            if not p.timed_out and now_s - p.sent_s >= self.timeout_s:
                p.timed_out = True
                out.append(p.request)
        return out, len(unheard)

    def _forget(self, now_s: float) -> None:
        while self._pending and now_s - self._pending[0].sent_s >= self.forget_s:
            self._pending.popleft()


class RateMonitor:
    """The received rate of a stream over fixed windows, and whether it stays below the requested rate."""

    def __init__(self, requested_hz: float, window_s: float) -> None:
        self.requested_hz = requested_hz
        self.window_s = window_s
        self.rate_hz = math.nan  # over the last complete window
        self.low = False
        self.warnings = 0
        self._start_s: float | None = None
        self._count = 0
        self._low_windows = 0

    def count(self, now_s: float) -> None:
        """One sample received at ``now_s`` (time.monotonic)."""
        if self._start_s is None:
            self._start_s = now_s
            return  # the window starts at the first sample: a rate is intervals, not samples
        self._count += 1

    def restart(self) -> None:
        """The stream stopped (input lost): the next window starts with its next sample."""
        self._start_s = None
        self._count = 0

    def update(self, now_s: float) -> bool | None:
        """At a window's end: True when the stream just turned low, False when it just cleared, else None."""
        if self._start_s is None or now_s - self._start_s < self.window_s:
            return None
        self.rate_hz = self._count / (now_s - self._start_s)
        self._start_s, self._count = now_s, 0
        if self.rate_hz < LOW_FRACTION * self.requested_hz:
            self._low_windows += 1
            if not self.low and self._low_windows >= LOW_WINDOWS:
                self.low = True
                self.warnings += 1
                return True
        else:
            self._low_windows = 0
            if self.low and self.rate_hz >= CLEAR_FRACTION * self.requested_hz:
                self.low = False
                return False
        return None
