"""When the input datagram that completes the next output tick can arrive, at the earliest: what lets the live
loop sleep through the samples between two ticks instead of waking for each.

The pipeline emits an output for the tick ``t_k`` when the first sample at or after it arrives (the front end's
ticks ``k / output_rate_hz``, the fused filter's from its start: :mod:`mavattitude.sensors.frontend`,
:mod:`mavattitude.estimation.fused.filter`); the next tick is the newest output's plus the shortest interval
between outputs seen lately. Its sample is stamped no earlier than ``t_k``, nor than the newest sample ``t_n``
plus the shortest interval between samples seen lately, ``Δ₀``. A sample stamped ``t`` on the
vehicle's clock arrives at ``t + delay`` on ours (``time.monotonic()``), and the delay has a floor ``d₀``: the
sender's stamping-to-sending time plus the link's transit, never less, measured as the smallest ``t_rx − t``
seen lately. So the sample completing the next tick arrives no earlier than

    t_arrival ≥ max(t_k, t_n + Δ₀) + d₀ − MARGIN_S,

``MARGIN_S`` covering the floor's own uncertainty (the two clocks drift by parts per million; a path faster than
any seen lately is possible but rare). ``Δ₀``, ``d₀`` and the output interval are minima over the last one to
two ``WINDOW_S`` (two half-windows, the older dropped as a new one starts), so they follow drift and a change
of rate and forget a reboot's clock.

A sample earlier than its forecast is not lost: it waits in the socket, and the loop counts its latency from when
it began to sleep (:meth:`~mavattitude.link.connection.MavlinkLink.recv_items`). What waited through a sleep is
known to have arrived only after the sleep began: the floor learns from it only when it is a sample that came
earlier than forecast, and then from that lower bound, so a forecast too late corrects itself (learning only from
what came after a sleep would see the late arrivals alone, and the floor would creep up).
"""

from __future__ import annotations

import math

WINDOW_S = 2.0
MARGIN_S = 0.001  # the floor's uncertainty: clock drift over a window is ~0.1 ms, the sleep's own lateness less


class TickArrivals:
    """The earliest arrival (``time.monotonic()``) of the sample completing the next output tick."""

    def __init__(self) -> None:
        self.forget()

    def forget(self) -> None:
        """The stream stopped or restarted: nothing is forecast until samples flow again."""
        self._t_newest = -math.inf  # the newest sample's vehicle time
        self._last_output_s = -math.inf  # the newest output's tick
        self._next_output_s = -math.inf  # ... plus the shortest interval between outputs lately
        self._floors = [math.inf, math.inf]  # smallest delay t_rx − t: this half-window, the one before
        self._intervals = [math.inf, math.inf]  # smallest interval between samples, likewise
        self._output_intervals = [math.inf, math.inf]  # smallest interval between output ticks, likewise
        self._window_end = -math.inf

    def add(self, t_vehicle_s: float, t_rx: float, backlog: bool = False) -> None:
        """A sample stamped ``t_vehicle_s`` that arrived at ``t_rx``; with ``backlog``, at ``t_rx`` or later (it
        waited through a sleep that began then, and says something of the floor only if it came early)."""
        if t_rx >= self._window_end:
            self._floors = [math.inf, self._floors[0]]
            self._intervals = [math.inf, self._intervals[0]]
            self._output_intervals = [math.inf, self._output_intervals[0]]
            self._window_end = t_rx + WINDOW_S / 2.0
        interval = t_vehicle_s - self._t_newest
        if 0.0 < interval < self._intervals[0]:
            self._intervals[0] = interval
        if not backlog or t_vehicle_s >= self._tick_sample_s():
            self._floors[0] = min(self._floors[0], t_rx - t_vehicle_s)
        self._t_newest = t_vehicle_s

    def output(self, tick_s: float) -> None:
        """An output at ``tick_s`` (vehicle clock): the next is no sooner than the shortest interval lately."""
        interval = tick_s - self._last_output_s
        if 0.0 < interval < self._output_intervals[0]:
            self._output_intervals[0] = interval
        self._last_output_s = tick_s
        self._next_output_s = tick_s + min(self._output_intervals)

    def earliest(self) -> float:
        """When the next tick's sample may arrive, at the earliest; -inf before anything is known."""
        floor = min(self._floors)
        if not math.isfinite(floor + self._t_newest):
            return -math.inf
        return self._tick_sample_s() + floor - MARGIN_S

    def _tick_sample_s(self) -> float:
        """The earliest vehicle time of the sample completing the next output tick: the next sample's, or the
        tick's when it is later. A tick that does not follow the newest sample within one output interval (a
        reboot's or a wrap's clock, ticks skipped) is not trusted: the next sample may complete one."""
        interval = min(self._intervals)
        after = self._t_newest + (interval if interval < math.inf else 0.0)
        tick_s, period = self._next_output_s, min(self._output_intervals)
        if period < math.inf and after < tick_s <= self._t_newest + period:
            return tick_s
        return after
