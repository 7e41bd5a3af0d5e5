"""Our side of the MAVLink conversation with the autopilot, kept by one object the loop ticks.

:class:`LinkSession` sends our HEARTBEAT every ``HEARTBEAT_PERIOD_S`` (at once on locking on, under the
vehicle's system id), asks for the streams with MAV_CMD_SET_MESSAGE_INTERVAL on their schedule (on locking,
every ``repeat_s``, at once after a reconnect or when told: a rebooted autopilot has forgotten them; nothing
while told to ``hold``: a silent autopilot would not answer), and
matches each COMMAND_ACK to the request it answers (:class:`~.requests.PendingRequests`), saying each
stream's answer, or its absence, once. It reads the autopilot's ``parameters`` the service needs (its level
trim, whether it uses the compass the input carries) with PARAM_REQUEST_READ, on locking and with every stream
request after, until each is answered or has been asked ``PARAMETER_TRIES`` times (an autopilot without it, a
PX4, never answers: said once). ``tick(now)`` does what is due; the service and live ``calibrate`` keep one each.
"""

from __future__ import annotations

import logging
import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

from mavattitude.link.connection import MavlinkLink
from mavattitude.link.requests import PendingRequests, RequestSchedule, StreamRequest
from mavattitude.link.source import Sender
from mavattitude.periodic import Every

log = logging.getLogger(__name__)

HEARTBEAT_PERIOD_S = 1.0
ACK_TIMEOUT_S = 2.0
ACK_FORGET_S = 10.0  # an unanswered request still matches a late ACK for this long
PARAMETER_TRIES = 3
REFUSED_HINT = "if it streams the message by itself, set link.request_messages: false"  # the service's config words


@dataclass
class RequestCounters:
    """What was asked and answered (the service's counters extend these)."""

    interval_requests: int = 0
    parameter_requests: int = 0  # PARAM_REQUEST_READ sent
    acks: dict[str, int] = field(default_factory=dict)  # SET_MESSAGE_INTERVAL results by name (of our requests)
    ack_timeouts: int = 0
    requests_unheard: int = 0  # unanswered, sent to a vehicle silent since (not timeouts: it did not hear them)
    acks_unmatched: int = 0  # ACKs of SET_MESSAGE_INTERVAL addressed to us with no request of ours waiting


class LinkSession:
    """Heartbeat, stream requests and ACK matching on ``link`` (see the module docstring)."""

    def __init__(
        self,
        link: MavlinkLink,
        streams: list[StreamRequest],
        repeat_s: float,
        now: float,
        counters: RequestCounters | None = None,
        parameters: Sequence[str] = (),
        refused_hint: str = REFUSED_HINT,
    ) -> None:
        self.link = link
        self._refused_hint = refused_hint  # what to do when a stream is refused, in the caller's words
        self.counters = counters if counters is not None else RequestCounters()
        self.vehicle: Sender | None = None
        self._heartbeat = Every(HEARTBEAT_PERIOD_S, now)
        self._requests = RequestSchedule(streams, repeat_s)
        self._pending = PendingRequests(ACK_TIMEOUT_S, ACK_FORGET_S)
        self._answers_said: set[tuple[str, str]] = set()  # (stream, result) logged once each
        self.answers: dict[str, str] = {}  # each stream's latest answer: ACCEPTED, DENIED, …, TIMEOUT
        self._reconnects_seen = 0
        self._parameter_tries = dict.fromkeys(parameters, 0)  # of those not answered yet
        self._parameters_next_s = math.inf  # asked first on locking
        self._held = False  # nothing asked (hold) until ask_now

    def lock(self, vehicle: Sender, now: float) -> None:
        """Locked onto ``vehicle``: speak as its system, announce ourselves and ask for the streams at once."""
        self.vehicle = vehicle
        self.link.set_source_system(vehicle[0])
        self._heartbeat.at_once(now)
        self._requests.ask_now(now)
        self._parameters_next_s = now

    def ask_now(self, now: float) -> None:
        """Ask for the streams at the next tick (a rebooted autopilot has forgotten them)."""
        if self.vehicle is not None:
            self._held = False
            self._requests.ask_now(now)

    def hold(self) -> None:
        """Ask nothing until :meth:`ask_now` (the autopilot is silent: a request would only time out)."""
        self._held = True

    def tick(self, now: float, heard_s: float = math.inf) -> None:
        """What is due at ``now``; ``heard_s``: when the vehicle was last heard, its HEARTBEAT or its input (a request
        it has not been heard from since is not said unanswered: :meth:`~.requests.PendingRequests.timed_out`)."""
        if self._heartbeat.due(now):
            self.link.send_heartbeat()
        if self.link.counters.reconnects != self._reconnects_seen:
            self._reconnects_seen = self.link.counters.reconnects
            self.ask_now(now)  # a new connection: the autopilot may have lost our requests
        vehicle = None if self._held else self.vehicle
        for stream in self._requests.due(now) if vehicle is not None else ():
            if self.link.request_message_interval(vehicle, stream.message_id, stream.rate_hz):
                self.counters.interval_requests += 1
                self._pending.sent(stream, now)
        unanswered, unheard = self._pending.timed_out(now, heard_s)
        self.counters.requests_unheard += unheard
        for request in unanswered:
            self.counters.ack_timeouts += 1
            self._say_answer(request, "TIMEOUT")
        if vehicle is not None and now >= self._parameters_next_s:
            self._ask_parameters(vehicle, now)

    def _ask_parameters(self, vehicle: Sender, now: float) -> None:
        self._parameters_next_s = now + self._requests.repeat_s
        tries = self._parameter_tries
        unanswered = [n for n, k in tries.items() if k == PARAMETER_TRIES]
        if unanswered:  # one line for all: a PX4 answers none of ArduPilot's
            log.info(
                "the autopilot did not answer for %s in %d requests: going without",
                ", ".join(unanswered),
                PARAMETER_TRIES,
            )
        for name in unanswered:
            del tries[name]
        for name in tries:
            if self.link.request_parameter(vehicle, name):
                self.counters.parameter_requests += 1
                tries[name] += 1

    def parameter_received(self, name: str) -> None:
        """The autopilot said one of its parameters: it is not asked for again."""
        self._parameter_tries.pop(name, None)

    def on_message(self, msg: Any, now: float) -> None:
        """A message from the vehicle: a COMMAND_ACK of SET_MESSAGE_INTERVAL addressed to us is matched."""
        if msg.get_type() != "COMMAND_ACK":
            return
        result = self.link.interval_ack_result(msg)
        if result is None or not self.link.addressed_to_us(msg):
            return
        request = self._pending.answered(now)
        if request is None:
            self.counters.acks_unmatched += 1
            return
        self.counters.acks[result] = self.counters.acks.get(result, 0) + 1
        self._say_answer(request, result)

    def _say_answer(self, request: StreamRequest, result: str) -> None:
        """Keep the autopilot's answer to a stream request, and log it once per stream and answer (no flip-flop)."""
        self.answers[request.name] = result
        if (request.name, result) in self._answers_said:
            return
        self._answers_said.add((request.name, result))
        if result == "ACCEPTED":
            log.info("autopilot accepted %s", request.describe())
        elif request.optional:
            log.info("autopilot answered SET_MESSAGE_INTERVAL(%s) with %s: going without", request.describe(), result)
        elif result == "TIMEOUT":
            log.warning("no COMMAND_ACK for SET_MESSAGE_INTERVAL(%s) within %.0f s", request.describe(), ACK_TIMEOUT_S)
        else:
            hint = self._refused_hint
            log.warning("autopilot answered SET_MESSAGE_INTERVAL(%s) with %s; %s", request.describe(), result, hint)
