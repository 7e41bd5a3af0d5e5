"""The daemon loop of ``mavattitude run``: MAVLink link ↔ attitude pipeline.

One thread, one loop: wait (bounded) for input on the link, handle every message that arrived, then
run whatever periodic work is due (heartbeat, rate requests, input watchdog, counters, sd_notify). The
input message goes decode → pipeline → ATTITUDE_QUATERNION in the same pass that received it, so the
latency from arrival to send is the processing time alone; nothing waits for a timer. Between two output
ticks the loop sleeps until the sample completing the next one can arrive at the earliest
(:mod:`mavattitude.link.arrivals`) and reads what came meanwhile in one pass, rather than wake for each sample;
what waited through a sleep counts its latency from the sleep's start, so the latency is never understated.

What it reads comes from the live link, decoded (:mod:`mavattitude.link.source`'s decoder), through
the dispatcher (:mod:`mavattitude.dispatch`) that ``replay`` uses too: it locks onto the autopilot
(``link.vehicle_system_id``, or with 0 the first autopilot HEARTBEAT; every other sender is ignored and
counted, and another autopilot heard is said once: in automatic mode the companion may follow the wrong
vehicle) and routes the IMU samples into the pipeline and the positions to its magnetic reference. The
service is the dispatcher's listener. What it does on the link:
- sends its own HEARTBEAT at 1 Hz as the vehicle's system id (an onboard controller, component
  ``link.component_id``). Until it has locked on in automatic mode it has no id to use and sends as
  system 1 (never 255), so that a ``udpout`` peer learns where we are and starts talking;
- asks for the input (and the position and SYSTEM_TIME's GPS date, with ``reference.magnetic: auto``;
  GPS_RAW_INT, the receiver's velocity, with the fused filter) with MAV_CMD_SET_MESSAGE_INTERVAL on locking,
  every ``request_repeat_s``, and as soon as the link (re)opens
  (unless ``request_messages`` is off); each COMMAND_ACK is matched to the request it answers
  (:mod:`mavattitude.link.requests`), and each stream's answer (or its absence) is said once;
- asks for ArduPilot's parameters (PARAM_REQUEST_READ, until answered or asked three times): its level trim
  (``AHRS_TRIM_X/Y``, with ``mounting.autopilot_trim``), which the pipeline turns the readings by, so the
  attitude is of the vehicle's frame, as the autopilot's (docs/frames.md); whether it uses each compass
  (``COMPASS_USE…``: the one input.message carries set aside is said once, with the one it uses); and with
  ``reference.magnetic: auto`` its declination (``COMPASS_DEC``; PX4's ``EKF2_MAG_DECL`` with input.profile
  px4), which turns a field measured without a position to its north;
- cross-checks the autopilot (``crosscheck:``): asks for its ATTITUDE, pairs it with our output by vehicle
  time (:mod:`mavattitude.estimation.crosscheck`), publishes the difference as NAMED_VALUE_FLOAT
  (``xc_roll``, ``xc_pitch``, ``xc_yaw``, ``xc_total``, degrees) at ``publish_rate_hz``, and says once (log +
  STATUSTEXT) when the total stays above ``threshold_deg`` for ``hold_s``, and when it clears; an attitude that
  may read the vehicle's acceleration as tilt (a snapshot solve, or the fused filter's without GPS velocity, while
  the vehicle moves), or that turns unlike the gyro, is published, not judged
  (:class:`~mavattitude.pipeline.CrossCheckGate`);
  attitudes that can never be paired with ours (another clock than the input's) are said once;
- measures the input rate it receives, and says once (log + STATUSTEXT) when it stays below the requested
  rate (a slow serial link, a busy autopilot), with the measured rate and what to do, and when it recovers;
- emits ATTITUDE_QUATERNION per pipeline output, stamped with the vehicle time of the sample, and (unless
  ``output.covariance`` is off) ATTITUDE_QUATERNION_COV with its 3×3 error covariance (rad², body frame);
- input silent for longer than ``input_timeout_s``: says so once (log + STATUSTEXT); the output
  stops by itself, since outputs only come from input, and resumes with the next good sample;
- input that arrives but is all refused for as long (a frozen IMU time, values out of range): says so once,
  with the refusals since the last attitude (log + STATUSTEXT, :attr:`Waiting.ATTITUDES`), and when
  attitudes go out again;
- STATUSTEXT on start (once locked on) and, rate-limited, on degenerate geometry;
- the input's accelerometer or magnetometer in the wrong units (:mod:`mavattitude.sensors.unitcheck`: its first
  seconds' magnitude far from g, or from any Earth field): said once (log warning with the profile's scale to
  check, and a STATUSTEXT), and in the wait for a position, which it keeps from ending;
- the compass judged inconsistent (:mod:`mavattitude.estimation.compass`): said once (log warning with the
  measured and expected dip, and a STATUSTEXT) until it clears; its figures go into the counters line;
- another program sending HEARTBEATs under our system and component id (a second mavattitude, the systemd service
  beside a run by hand; not our own echoed back): said (log warning and STATUSTEXT), and when it has been gone
  ``SAME_ID_GONE_S``;
- the autopilot's HEARTBEAT missed for ``HEARTBEAT_LOST_S`` is said (a restart, the link down), nothing asked of it
  meanwhile, and its streams asked for at once when it is back (a restarted autopilot has forgotten them);
- while it waits (for the autopilot's HEARTBEAT, the IMU stream, a GPS position, the first attitude:
  :class:`Waiting`, read as :attr:`AttitudeService.waiting`) it says what for and the likely cause, first
  after ``WAIT_REPORT_FIRST_S`` and then at a slowing rate, so a wrong wiring does not look like a hang;
- every ``stats_interval_s`` one ``counters:`` log line of the ``key=value`` numbers that changed since the
  last one (all of them at DEBUG); the whole line when it stops;
- systemd (sd_notify): READY as soon as the loop runs, STATUS = what it waits for (on every change of
  :class:`Waiting`), the counters line once attitudes flow; WATCHDOG from the loop. In a container the
  loop refreshes an alive file instead, which the image's HEALTHCHECK reads, and exits when it hangs
  (:mod:`mavattitude.alive`).
"""

from __future__ import annotations

import enum
import logging
import math
import threading
import time
from collections import Counter
from collections.abc import Callable
from typing import Any

import numpy as np

from mavattitude import __version__, alive
from mavattitude.compasses import OtherCompasses
from mavattitude.config import Config
from mavattitude.dispatch import Dispatcher
from mavattitude.errors import DegenerateGeometryError
from mavattitude.estimation import METHODS
from mavattitude.estimation.compass import CompassEvent
from mavattitude.estimation.crosscheck import CrossCheck
from mavattitude.link import MavlinkLink, load_signing_key, message_id
from mavattitude.link.arrivals import TickArrivals
from mavattitude.link.logstreams import TILT_ONLY, compass_use_parameter
from mavattitude.link.requests import LOW_FRACTION, RateMonitor, StreamRequest
from mavattitude.link.session import LinkSession
from mavattitude.link.source import AutopilotAttitude, AutopilotParameter, MavlinkDecoder, Sender
from mavattitude.periodic import Every
from mavattitude.pipeline import AttitudeOutput, AttitudePipeline, CrossCheckGate, Pushed, comparable_heading
from mavattitude.reports import (
    CLOCKS_APART_STATUSTEXT,
    DEGENERATE_STATUSTEXT,
    FIRMWARE_NAMES,
    ServiceCounters,
    arriving_twice,
    compass_event_words,
    compass_statustext,
    compass_unused_statustext,
    compass_unused_warning,
    counters_line,
    firmware_without,
    heading_lost,
    input_lost_statustext,
    profile_units,
    rate_handling,
    refusals,
    refusals_text,
    refused_as_dead_imu,
    refused_statustext,
    start_statustext,
)
from mavattitude.sensors import units
from mavattitude.sensors.frontend import SampleFlag
from mavattitude.sensors.magref import declination_parameter
from mavattitude.sensors.mounting import TRIM_PARAMETERS
from mavattitude.sensors.unitcheck import UnitsFinding
from mavattitude.sensors.units import ImuSample
from mavattitude.systemd_notify import SystemdNotifier, default_notifier

log = logging.getLogger(__name__)

TICK_S = 0.05  # periodic work runs at least this often; also the longest wait on the link
ATTITUDE_FRESH_S = 2.0  # the autopilot's attitudes still come: one within this long (its stream at 0.5 Hz or more)
UNLOCKED_SYSTEM_ID = 1  # our system id before locking onto an autopilot in automatic mode
RATE_WINDOW_S = 5.0  # the input rate is measured over windows this long
HEARTBEAT_LOST_S = 5.0  # nothing from the autopilot this long (its 1 Hz HEARTBEAT missed): the link or it is down
SAME_ID_GONE_S = 10.0  # another program's 1 Hz HEARTBEAT under our id unheard this long: it has gone
DEGENERATE = DegenerateGeometryError.__name__  # the pipeline's reject reason for collinear acc and mag
POSITION_MESSAGE = "GLOBAL_POSITION_INT"
POSITION_RATE_HZ = 1.0
TIME_MESSAGE = "SYSTEM_TIME"
# The fused filter's GPS velocity: the receiver's own, at the 5 Hz most receivers give (a faster stream repeats fixes)
GPS_VELOCITY_MESSAGE = "GPS_RAW_INT"
GPS_VELOCITY_RATE_HZ = 5.0
TIME_RATE_HZ = 0.2
ATTITUDE_MESSAGE = "ATTITUDE"
CROSSCHECK_NAMES = ("xc_roll", "xc_pitch", "xc_yaw", "xc_total")  # NAMED_VALUE_FLOAT: ≤ 10 characters
MAX_LATENCY_SAMPLES = 100_000  # per counters window: bounds memory if stats_interval_s is long
WAIT_REPORT_FIRST_S = 3.0  # a normal start (autopilot up, link wired) passes every wait well within this
WAIT_REPORT_MAX_S = 300.0  # the interval between "waiting for" lines doubles up to this
LINK_HINTS = {  # the likely cause when no HEARTBEAT comes, by connection kind
    "udpin": "is the autopilot sending to this port?",
    "udpout": "is the autopilot listening on that port?",
    "tcp": "is the autopilot listening on that port?",
    "tcpin": "is the autopilot connecting to this port?",
    "serial": "is the autopilot sending MAVLink 2 on this port, at this baud rate?",
}
GARBAGE_HINTS = {  # the likely cause when bytes come but no MAVLink frame is in them
    "serial": "a baud rate other than the autopilot's, or another protocol on its port: its SERIALn_BAUD and "
    "SERIALn_PROTOCOL 2",
    "udpin": "another program sending to this port",
}


class WaitReports:
    """When to say that something is still awaited: ``WAIT_REPORT_FIRST_S`` after the state began (a wiring
    mistake shows within seconds), then at doubling intervals up to ``WAIT_REPORT_MAX_S`` (a long, expected
    wait — no GPS fix indoors — does not flood the log)."""

    def __init__(self, state: object, now: float) -> None:
        self.state, self.since, self._next = state, now, now + WAIT_REPORT_FIRST_S

    def changed(self, state: object, now: float) -> bool:
        """True, and the clock restarted, when ``state`` differs from the last one."""
        if state == self.state:
            return False
        self.state, self.since, self._next = state, now, now + WAIT_REPORT_FIRST_S
        return True

    def due(self, now: float) -> float | None:
        """The seconds waited in the current state when a report is due at ``now``, else None."""
        if now < self._next:
            return None
        waited_s = now - self.since
        self._next = now + min(max(waited_s, WAIT_REPORT_FIRST_S), WAIT_REPORT_MAX_S)
        return waited_s


class Waiting(enum.Enum):
    """What the service waits for, in the order it needs them; ``RUNNING`` once an attitude went out."""

    AUTOPILOT = "autopilot"  # its HEARTBEAT (the first, or ``link.vehicle_system_id``'s)
    AUTOPILOT_BACK = "autopilot back"  # its HEARTBEAT again, silent for HEARTBEAT_LOST_S with no input
    IMU_STREAM = "IMU stream"  # the input message, at start or after input_timeout_s of silence
    POSITION = "GPS position"  # ``reference.magnetic: auto``: the position, or the field measured without one
    FIRST_ATTITUDE = "first attitude"  # input flows, the filter and solver have not produced one yet
    ATTITUDES = "attitudes"  # input flows, attitudes went out, but none for longer than a gap: all refused
    RUNNING = "running"


class _RateLimiter:
    """Allows one event per key every ``interval_s``; counts what it held back."""

    def __init__(self, interval_s: float, clock: Callable[[], float]) -> None:
        self.interval_s = interval_s
        self._clock = clock
        self._last: dict[str, float] = {}
        self.suppressed: dict[str, int] = {}

    def allow(self, key: str) -> bool:
        now = self._clock()
        last = self._last.get(key)
        if last is not None and now - last < self.interval_s:
            self.suppressed[key] = self.suppressed.get(key, 0) + 1
            return False
        self._last[key] = now
        return True

    def take_suppressed(self, key: str) -> int:
        return self.suppressed.pop(key, 0)


def log_banner(config: Config) -> None:
    """The start-up line, logged before the link opens (so before anything the link says)."""
    log.info(
        "mavattitude %s: link %s, input %s (%s profile), vehicle %s",
        __version__,
        config.link.connect,
        config.input.message,
        config.input.profile,
        config.link.vehicle_system_id or "auto (first autopilot heartbeat)",
    )


def open_link(config: Config) -> MavlinkLink:
    """The link the config describes (signing key read and checked here)."""
    signing = config.link.signing
    return MavlinkLink(
        config.link.connect,
        source_system=config.link.vehicle_system_id or UNLOCKED_SYSTEM_ID,
        source_component=config.link.component_id,
        signing_key=load_signing_key(signing.key_file) if signing.key_file else None,
        require_signing=signing.require_signing,
    )


class AttitudeService:
    """The loop: ``AttitudeService(config, link, pipeline).run(stop_event)`` returns the final counters.

    ``link`` is what the service reads and sends on; it reads with the config's input message and unit profile
    (:class:`~mavattitude.link.source.MavlinkDecoder`, the input message decoded by the link from its frame).
    """

    def __init__(
        self,
        config: Config,
        link: MavlinkLink,
        pipeline: AttitudePipeline,
        notifier: SystemdNotifier | None = None,
        alive_file: alive.AliveFile | None = None,
    ) -> None:
        self.config = config
        self.link = link
        self.decoder = MavlinkDecoder.from_config(config)
        # what is read: the decoder's messages, the ACKs to our requests, and every IMU message (the other
        # compasses', and what the vehicle sends besides input.message); the rest of its telemetry is skipped
        self._reads = frozenset(message_id(m) for m in {*self.decoder.types, "COMMAND_ACK", *units.MESSAGES})
        self.pipeline = pipeline
        self.notifier = notifier if notifier is not None else default_notifier()
        self.alive_file = alive_file if alive_file is not None else alive.AliveFile()
        self.counters = ServiceCounters()
        self._input_name = config.input.message
        self._limiter = _RateLimiter(config.output.statustext_interval_s, time.monotonic)
        self._latencies_s: list[float] = []
        self._arrivals = TickArrivals()
        self._sample_wait_s = config.output.wait_ms / 1000.0
        self._last_input: float | None = None
        self._input_lost = False
        self._autopilot_silent_since: float | None = None  # its last HEARTBEAT's arrival, while it is silent
        self._output_since = -math.inf  # the last attitude sent (or the input's return), time.monotonic()
        self._stalled = False  # input arrives but every sample is refused: said (_watch_output)
        self._refused: Counter[str] = Counter()  # the refusals up to the last attitude
        self._per_sample = False  # the input too slow to filter, as last said (_say_rate_handling)
        self._no_heading = SampleFlag.NONE  # our attitudes have no heading, as last said (_say_tilt_only)
        self._others_said: set[Sender] = set()  # the other autopilots heard, as said (_say_other_autopilots)
        self._attitude_sent = False
        self._rate = RateMonitor(config.link.request_rate_hz, RATE_WINDOW_S) if config.link.request_messages else None
        self._xcheck = CrossCheck(config.crosscheck) if config.crosscheck.enabled else None
        self._gate = CrossCheckGate()
        self.other_compasses = OtherCompasses(config)
        self.other_imu_messages: set[str] = set()  # IMU messages the vehicle sent other than input.message
        self._published_s: float | None = None  # vehicle time of the last difference published
        self._autopilot_heard = -math.inf  # the last autopilot attitude's arrival, time.monotonic()
        self._unpairable_said = False  # its attitudes can never be paired with ours (said once)
        now = time.monotonic()
        trim = TRIM_PARAMETERS if config.mounting.autopilot_trim else ()
        own = self.other_compasses.own  # the compass input.message carries (None: HIGHRES_IMU, PX4's, says none)
        self._others = units.other_compasses(config.input.message)  # the rest, each with its message
        # whether the autopilot uses each compass: input.message's asked last, so that the others' answers (in the
        # order asked, as ArduPilot answers) are in when its own is judged, and the pilot is told which it uses
        compasses = [] if own is None else [*self._others, own]
        self._compass_use = tuple(compass_use_parameter(k) for k in compasses)
        self._compass_uses: dict[str, float] = {}  # their answers
        self._compass_unused = False  # the autopilot said it does not use input.message's compass (said once)
        # its declination turns a field measured from the compass (no position) to true north
        auto = config.reference.magnetic.mode == "auto"
        declination = (declination_parameter(config.input.profile),) if auto else ()
        self.session = LinkSession(
            link,
            self._stream_requests(config),
            config.link.request_repeat_s,
            now,
            self.counters,
            trim + self._compass_use + declination,
        )
        self._tick = Every(TICK_S, now)
        self._publish = Every(1.0 / config.crosscheck.publish_rate_hz, now)
        self._stats = Every(config.output.stats_interval_s, now, first_s=config.output.stats_interval_s)
        self._heading_lost = False  # the fused filter's compass gave no heading (said once)
        watchdog_s = self.notifier.watchdog_interval_s
        self._watchdog = Every(watchdog_s / 4 if watchdog_s else math.inf, now)
        self._alive = Every(alive.PERIOD_S, now)
        self._twice = Every(RATE_WINDOW_S, now, first_s=RATE_WINDOW_S)  # the input arriving twice (_watch_twice)
        self._twice_times: list[float] = []  # the window's input sample times, in arrival order
        self._twice_said = False
        self._same_id_said = False  # another program under our id, said until it has gone
        self._wait_reports = WaitReports(Waiting.AUTOPILOT, now)
        self._last_counters: dict[str, str] = {}  # the last periodic line's key=value, to log what changed
        self.dispatcher = Dispatcher(
            pipeline,
            self,
            system_id=config.link.vehicle_system_id,
            counters=self.counters,
            wants_position=config.reference.magnetic.mode == "auto",
        )

    @property
    def vehicle(self) -> Sender | None:
        """The autopilot locked onto (``None`` until then)."""
        return self.dispatcher.vehicle

    # -- the loop -------------------------------------------------------------------------------------

    def run(self, stop: threading.Event) -> ServiceCounters:
        """Serve until ``stop`` is set (within ``TICK_S``); return the counters."""
        # READY means running and listening: the link is open. What it still waits for is the STATUS, not
        # a reason to hold start-up: a companion computer usually boots before its autopilot talks.
        self.notifier.ready(status=self.waiting_text())
        try:
            while not stop.is_set():
                self.step(self._tick.wait_s(time.monotonic()))
        finally:
            self.notifier.stopping()
            self.alive_file.close()
            self._log_counters(final=True)
        return self.counters

    def step(self, wait_s: float) -> None:
        """One pass of the loop: wait up to ``wait_s`` for input, handle all of it, then the periodic work due."""
        handle, decoder = self.dispatcher.handle, self.decoder
        quiet_until = self._quiet_until()
        # periodic work due before the next tick's sample can come waits for it (within a TICK_S): no wake of its own
        wait_s = max(wait_s, min(quiet_until - time.monotonic(), TICK_S))
        for received in self.link.recv_items(wait_s, decoder, decoder.direct, quiet_until, self._reads):
            handle(received)
        now = time.monotonic()
        if self._tick.due(now):
            self._periodic(now)

    def _quiet_until(self) -> float:
        """Until when the link may sleep: no input can complete an output tick before the forecast
        (:class:`TickArrivals`), and where the OS stamps arrivals the one that does may wait ``output.wait_ms``
        (its latency still counted from its arrival). Never while each sample is a tick (an input too slow to
        filter) or the input is silent."""
        if self.pipeline.frontend.per_sample or self._input_lost:
            return -math.inf
        return self._arrivals.earliest() + (self._sample_wait_s if self.link.stamps_arrivals else 0.0)

    def _periodic(self, now: float) -> None:
        """The work due every ``TICK_S`` at most: the link's upkeep, the watches, what is said and touched."""
        heard = self._vehicle_heard_s()
        if heard is not None:
            self._watch_autopilot(heard, now)
        self.session.tick(now, math.inf if heard is None else heard)
        if self.pipeline.frontend.per_sample != self._per_sample:
            self._say_rate_handling()
        if self._same_id_said != (now - self.link.same_id_heard_s < SAME_ID_GONE_S):
            self._say_same_id()
        if self.vehicle is not None and self.counters.other_autopilots - self._others_said:
            self._say_other_autopilots(self.vehicle)
        if self._rate is not None:
            self._check_rate(self._rate, now)
        if self._twice.due(now):
            self._watch_twice()
        if self._xcheck is not None and self._publish.due(now):
            self._publish_difference(self._xcheck)
            self._watch_pairing(self._xcheck, now)
        if not self._input_lost and self._last_input is not None:
            silent_s = now - self._last_input
            if silent_s > self.pipeline.frontend.gap_limit_s:  # input_timeout_s, or longer for a slow input
                self._on_input_lost(silent_s)
        if self._attitude_sent and not self._input_lost:
            self._watch_output(now)
        self._report_waiting(now)
        if self._stats.due(now):
            self._log_counters()
        if self._watchdog.due(now):
            self.notifier.watchdog()
        if self._alive.due(now):
            self.alive_file.touch()

    # -- what it waits for -----------------------------------------------------------------------------

    @property
    def waiting(self) -> Waiting:
        """The first thing still missing for attitudes to go out (``RUNNING`` when nothing is)."""
        if self.vehicle is None:
            return Waiting.AUTOPILOT
        if self._last_input is None or self._input_lost:
            return Waiting.IMU_STREAM if self._autopilot_silent_since is None else Waiting.AUTOPILOT_BACK
        if self.pipeline.waiting_for_reference and self.pipeline.frontend.counters.accepted:
            return Waiting.POSITION  # (with every sample refused, the refusals are what to say, not the position)
        if not self._attitude_sent:
            return Waiting.FIRST_ATTITUDE
        if self._stalled:
            return Waiting.ATTITUDES
        return Waiting.RUNNING

    def waiting_text(self, waiting: Waiting | None = None) -> str:
        """``waiting`` (default: the current state) in words, with what to check."""
        waiting = self.waiting if waiting is None else waiting
        link = self.config.link
        others = self._other_autopilots_text()
        if waiting is Waiting.AUTOPILOT:
            which = f" from system {link.vehicle_system_id}" if link.vehicle_system_id else ""
            if others:  # the id configured is not the vehicle's, or the vehicle is not on this link
                return f"waiting for a HEARTBEAT{which} on {link.connect}: heard only {others}"
            heard = self.link.counters
            if heard.bad_data and not heard.received:  # something talks, but not MAVLink
                garbage = GARBAGE_HINTS.get(self.link.endpoint.kind, GARBAGE_HINTS["udpin"])
                return f"waiting for a HEARTBEAT{which} on {link.connect}: data, but no MAVLink frame in it ({garbage})"
            return f"waiting for a HEARTBEAT{which} on {link.connect} ({LINK_HINTS[self.link.endpoint.kind]})"
        if waiting is Waiting.AUTOPILOT_BACK:
            assert self.vehicle is not None and self._autopilot_silent_since is not None
            silent_s = time.monotonic() - self._autopilot_silent_since
            # another autopilot heard: the link is up (a vehicle back under a new system id is one)
            heard = f"; {others} heard: link.vehicle_system_id chooses" if others else ""
            return (
                f"waiting for the autopilot: no HEARTBEAT from system {self.vehicle[0]}, component {self.vehicle[1]} "
                f"for {silent_s:.0f} s (the link or the autopilot is down; a restarting autopilot is back in "
                f"seconds){heard}"
            )
        if waiting is Waiting.IMU_STREAM:
            assert self.vehicle is not None
            source = f"{self._input_name} from system {self.vehicle[0]}, component {self.vehicle[1]}"
            # a PX4 sends HIGHRES_IMU, not the default RAW_IMU: what it does send is the likely fix
            instead = self._other_imu_text() + "".join(f"; {text}" for text in [self._firmware_text()] if text)
            if link.request_messages:
                answer = self.session.answers.get(self._input_name, "ACCEPTED")
                refused = {"ACCEPTED": "", "TIMEOUT": " (no answer)"}.get(answer, f" (answered {answer})")
                asked = f"asked for at {link.request_rate_hz:g} Hz{refused}"
                return f"waiting for the IMU stream: {source}, {asked}{instead}"
            return (
                f"waiting for the IMU stream: {source} (link.request_messages is off: is the autopilot streaming "
                f"it?){instead}"
            )
        if waiting is Waiting.POSITION:
            # an accelerometer in the wrong units never reads as still: no field is measured until they are fixed
            wrong = "".join(f" ({f.text})" for f in self.pipeline.units.findings if f.sensor == "accelerometer")
            return (
                "waiting for a GPS position (reference: auto): GLOBAL_POSITION_INT, or GPS_RAW_INT with a 3D fix; "
                f"without one, after {self.config.reference.position_wait_s:g} s of the IMU stream, the field is "
                f"measured from the compass while the vehicle is still{wrong}"
            )
        refused = refusals(self.counters, self.pipeline.counters)
        if waiting is Waiting.FIRST_ATTITUDE:
            return f"waiting for the first attitude ({refusals_text(refused)}){self._dead_imu_hint(refused)}"
        if waiting is Waiting.ATTITUDES:
            since = refused - self._refused
            hint = self._dead_imu_hint(since)
            return f"{self._input_name} arrives but no attitude goes out ({refusals_text(since)}){hint}"
        return "running"

    def _other_autopilots_text(self) -> str:
        """The other autopilots heard on the link, as "autopilot system 2" (empty: none)."""
        heard = sorted({system for system, _ in self.counters.other_autopilots})
        kind = "systems" if len(heard) > 1 else "system"
        return f"autopilot {kind} {', '.join(map(str, heard))}" if heard else ""

    def _other_imu_text(self) -> str:
        """The IMU messages the vehicle sends besides ``input.message``, as the fix to try (empty: none)."""
        sends = ", ".join(sorted(self.other_imu_messages))
        return f"; it sends {sends}: set input.message (and input.profile) to read one" if sends else ""

    def _firmware_text(self) -> str:
        """That the autopilot's firmware sends no ``input.message``, and what to read instead (empty: it does)."""
        remedy = "set input.message: {message} and input.profile: {profile}"
        return firmware_without(self.dispatcher.vehicle_profile, self._input_name, remedy) or ""

    def _dead_imu_hint(self, refused: Counter[str]) -> str:
        """:meth:`_other_imu_text` when the input is refused as an IMU the vehicle lacks (``refused_as_dead_imu``)."""
        return self._other_imu_text() if refused_as_dead_imu(refused) else ""

    def _report_waiting(self, now: float) -> None:
        """Say what it waits for (:class:`WaitReports`), and tell systemd on every change."""
        waiting = self.waiting
        if self._wait_reports.changed(waiting, now):
            self.notifier.status(self.waiting_text(waiting))
            return
        waited_s = self._wait_reports.due(now)
        if waiting is not Waiting.RUNNING and waited_s is not None:
            log.info("%s (%.0f s so far)", self.waiting_text(waiting), waited_s)

    # -- the autopilot --------------------------------------------------------------------------------

    def on_lock(self, vehicle: Sender) -> None:
        self.session.lock(vehicle, time.monotonic())
        log.info("locked onto the autopilot: system %d, component %d", *vehicle)
        self._statustext("start", start_statustext(__version__, self._input_name), "info")
        profile, firmware = self.dispatcher.vehicle_profile, self._firmware_text()
        if profile is not None and firmware:
            log.warning("%s", firmware)
            text = f"mavattitude: {FIRMWARE_NAMES[profile]} sends no {self._input_name}"
            self._statustext("firmware", text, "warning", log_it=False)

    @staticmethod
    def _stream_requests(config: Config) -> list[StreamRequest]:
        """What to ask the autopilot to stream: the input, the position for the WMM and the GPS velocity for the
        fused filter (when asked to ask)."""
        if not config.link.request_messages:
            return []
        streams = [StreamRequest(config.input.message, message_id(config.input.message), config.link.request_rate_hz)]
        if config.reference.magnetic.mode == "auto":
            streams.append(StreamRequest(POSITION_MESSAGE, message_id(POSITION_MESSAGE), POSITION_RATE_HZ))
            # the GPS date for the magnetic model (the companion's clock may be wrong until NTP)
            streams.append(StreamRequest(TIME_MESSAGE, message_id(TIME_MESSAGE), TIME_RATE_HZ, optional=True))
        if METHODS[config.estimator.method].uses_gps_velocity and config.estimator.fused.gps_max_accel_mps2 > 0.0:
            rate_hz = GPS_VELOCITY_RATE_HZ  # optional: a vehicle without GPS flies without it
            streams.append(
                StreamRequest(GPS_VELOCITY_MESSAGE, message_id(GPS_VELOCITY_MESSAGE), rate_hz, optional=True)
            )
        if config.crosscheck.enabled:
            rate_hz = config.crosscheck.attitude_rate_hz
            streams.append(StreamRequest(ATTITUDE_MESSAGE, message_id(ATTITUDE_MESSAGE), rate_hz, optional=True))
        if config.compass.enabled and config.compass.others_rate_hz > 0.0:
            # the vehicle's other compasses, each judged beside ours (optional: a vehicle has one, two or three)
            rate_hz = config.compass.others_rate_hz
            others = units.other_compasses(config.input.message).values()
            streams += [StreamRequest(m, message_id(m), rate_hz, optional=True) for m in others]
        return streams

    def on_parameter(self, parameter: AutopilotParameter) -> None:
        self.session.parameter_received(parameter.name)
        if parameter.name in self._compass_use:
            self._compass_uses[parameter.name] = parameter.value
            if parameter.name == self._compass_use[-1]:
                self._say_compass_use(parameter.name, parameter.value)

    def _say_compass_use(self, name: str, value: float) -> None:
        """Whether the autopilot uses the compass our heading comes from: said when it does not (it may have set
        it aside for a reason the pilot knows), with which it uses instead; and when it uses it again."""
        unused = value == 0.0
        if unused == self._compass_unused:
            return
        self._compass_unused, own = unused, self.other_compasses.own
        assert own is not None  # asked only for a compass input.message carries
        if not unused:
            log.info("the autopilot uses compass %d again (%s %g)", own + 1, name, value)
            return
        log.warning("%s", compass_unused_warning(own, name, value, self._compass_remedy()))
        self._statustext("compass_unused", compass_unused_statustext(own), "warning", log_it=False)

    def _compass_remedy(self) -> str:
        """Which compass the autopilot uses instead, as far as it said, and the input message that carries it."""
        messages = self._others
        uses = {k: self._compass_uses.get(compass_use_parameter(k)) for k in messages}  # None: not answered
        used = [k for k, use in uses.items() if use is not None and use != 0.0]
        if used:
            k = min(used)
            return f"it uses compass {k + 1}: input.message {messages[k]} carries it"
        if all(use is not None for use in uses.values()):
            return "it uses none of its compasses (its heading comes from elsewhere: a GPS, or nowhere)"
        return "input.message " + " or ".join(f"{m} carries compass {k + 1}" for k, m in messages.items())

    def on_message(self, msg: Any, t_rx: float) -> None:
        self.session.on_message(msg, time.monotonic())
        self.other_compasses.reading(msg)
        if msg.get_type() in units.MESSAGES:
            self.other_imu_messages.add(msg.get_type())

    def on_autopilot_attitude(self, attitude: AutopilotAttitude, t_rx: float) -> None:
        self._autopilot_heard = t_rx
        if self._xcheck is not None:
            self._xcheck.add_autopilot(attitude.time_s, attitude.q)
            self._cross_check(self._xcheck)

    def _cross_check(self, xcheck: CrossCheck) -> None:
        for event in xcheck.update()[1]:
            t = self.config.crosscheck
            if event.disagree:
                d = xcheck.last
                assert d is not None
                log.warning(
                    "our attitude and the autopilot's differ by %.1f° (roll %+.1f°, pitch %+.1f°, yaw %+.1f°) for "
                    "%g s: one of them is wrong; see docs/vehicle.md (the autopilot cross-check) for what to check",
                    event.total_deg,
                    d.roll_deg,
                    d.pitch_deg,
                    d.yaw_deg,
                    t.hold_s,
                )
                text = f"mavattitude: {event.total_deg:.0f} deg off the autopilot's attitude"
                self._statustext("crosscheck", text, "warning", log_it=False)
            else:
                log.info("our attitude agrees with the autopilot's again (%.1f°)", event.total_deg)
                self._statustext("crosscheck_clear", "mavattitude: agrees with the autopilot again", "info")

    def _watch_pairing(self, xcheck: CrossCheck, now: float) -> None:
        """Said once: the autopilot's attitudes keep coming but none can ever be paired with ours (its clock and
        our input's are apart), so the cross-check, on as configured, checks nothing."""
        if self._unpairable_said or not now - self._autopilot_heard < ATTITUDE_FRESH_S:
            return
        offset_s = xcheck.unpairable_offset_s()
        if offset_s is None:
            return
        self._unpairable_said = True
        log.warning(
            "the autopilot's ATTITUDE is stamped %+.0f s from our %s time: none can be paired with ours, so there "
            "is no cross-check (is %s stamped with Unix time, or from another clock than the attitude?)",
            offset_s,
            self._input_name,
            self._input_name,
        )
        self._statustext("crosscheck_clock", CLOCKS_APART_STATUSTEXT, "warning", log_it=False)

    def _publish_difference(self, xcheck: CrossCheck) -> None:
        """The latest difference as NAMED_VALUE_FLOAT, stamped with its vehicle time; nothing new, nothing sent."""
        d = xcheck.last
        if d is None or d.time_s == self._published_s:
            return
        self._published_s = d.time_s
        stamp = units.time_boot_ms(d.time_s)
        for name, value in zip(CROSSCHECK_NAMES, (d.roll_deg, d.pitch_deg, d.yaw_deg, d.total_deg), strict=True):
            self.link.send_named_value_float(stamp, name, value)

    def _check_rate(self, rate: RateMonitor, now: float) -> None:
        turned = rate.update(now)
        self.counters.input_rate_hz = rate.rate_hz
        if turned is None:
            return
        if turned:
            self.counters.rate_warnings += 1
            log.warning(
                "%s arrives at %.0f Hz, below the %g Hz asked for (a slow link or a busy autopilot): lower "
                "link.request_rate_hz to about %.0f Hz, or use a faster link",
                self._input_name,
                rate.rate_hz,
                rate.requested_hz,
                math.floor(LOW_FRACTION * rate.rate_hz),
            )
            text = f"mavattitude: {self._input_name} {rate.rate_hz:.0f} Hz < {rate.requested_hz:g} asked"
            self._statustext("input_rate", text, "warning", log_it=False)
        else:
            log.info("%s arrives at %.0f Hz again", self._input_name, rate.rate_hz)

    def _watch_twice(self) -> None:
        """The input arriving twice over the last window (:func:`~mavattitude.reports.arriving_twice`): said once.
        The copies are dropped as duplicates and the attitude is right, at twice the cost."""
        times, self._twice_times = self._twice_times, []
        words = arriving_twice(times, self._input_name)
        if words is None or self._twice_said:
            return
        self._twice_said = True
        log.warning("%s", words)
        self._statustext("twice", f"mavattitude: {self._input_name} arrives twice", "warning", log_it=False)

    # -- input and output -----------------------------------------------------------------------------

    def on_input(self, sample: ImuSample, t_rx: float) -> None:
        self._last_input = t_rx
        if not self._twice_said:
            self._twice_times.append(sample.time_s)
        self._arrivals.add(sample.time_s, t_rx, self.link.backlog)
        for instance, event in self.other_compasses.push(sample, self.pipeline):
            self._on_compass(event, instance)
        if self._rate is not None:
            self._rate.count(t_rx)
        if self._input_lost:
            self._input_lost = False
            self._output_since = t_rx  # the output's watch starts again with the input
            log.info("input %s is back", self._input_name)

    def on_outputs(self, pushed: Pushed, t_rx: float) -> None:
        if pushed.rejected and DEGENERATE in pushed.rejected:
            self._statustext("degenerate", DEGENERATE_STATUSTEXT, "warning")
        for event in pushed.compass:
            self._on_compass(event)
        for finding in pushed.units:
            self._say_units(finding)
        outputs = pushed.outputs
        if outputs and (outputs[-1].flags & SampleFlag.NO_HEADING) != self._no_heading:
            self._say_tilt_only(bool(outputs[-1].flags & SampleFlag.NO_HEADING))
        for out in outputs:
            self._emit(out, t_rx)
        if self._xcheck is not None and outputs:
            for out in outputs:
                moving = self._gate.moving(out)
                flags = int(out.flags)
                judged = bool(comparable_heading(out.q, out.covariance_or_nan(), flags))
                self._xcheck.add_ours(out.time_s, out.q, not flags & SampleFlag.NO_HEADING, moving, judged)
            self._cross_check(self._xcheck)

    def _say_units(self, finding: UnitsFinding) -> None:
        """A sensor whose magnitude says its units are wrong (judged once, at the start): with the scale to check."""
        log.warning("%s: check %s", finding.text, profile_units(self.config, self._input_name, finding.sensor))
        self._statustext(f"units:{finding.sensor}", finding.short, "warning", log_it=False)

    def _vehicle_heard_s(self) -> float | None:
        """When the autopilot was last heard (its HEARTBEAT or its input's arrival); None before locking on."""
        heartbeat, sample = self.dispatcher.vehicle_heard_s, self._last_input
        return heartbeat if sample is None or heartbeat is None else max(heartbeat, sample)

    def _watch_autopilot(self, heard: float, now: float) -> None:
        """Nothing from the autopilot for ``HEARTBEAT_LOST_S`` (a restart, the link down) is said, and so is its
        return, when the streams are asked for at once: a restarted autopilot has forgotten them, and the next
        ``link.request_repeat_s`` may be seconds away. Nothing is asked while it is silent."""
        assert self.vehicle is not None
        since = self._autopilot_silent_since
        if since is None and now - heard > HEARTBEAT_LOST_S:
            self._autopilot_silent_since = heard
            self.counters.autopilot_silent += 1
            self.session.hold()
            log.warning(
                "no HEARTBEAT from the autopilot (system %d, component %d) for %.0f s: the link or the autopilot is "
                "down",
                *self.vehicle,
                now - heard,
            )
        elif since is not None and heard > since:
            self._autopilot_silent_since = None
            self.session.ask_now(now)
            log.info("the autopilot's HEARTBEAT again after %.1f s: its streams asked for at once", heard - since)

    def _say_other_autopilots(self, vehicle: Sender) -> None:
        """Another autopilot on the link (a swarm on one radio, a second vehicle): said once each. Locked on in
        automatic mode, the first heard was taken, and the companion may be following the wrong vehicle."""
        chosen = self.config.link.vehicle_system_id != 0
        for system, component in sorted(self.counters.other_autopilots - self._others_said):
            following = f"following system {vehicle[0]}, component {vehicle[1]}"
            if chosen:
                log.info("another autopilot on the link: system %d, component %d (%s)", system, component, following)
            else:
                log.warning(
                    "another autopilot on the link: system %d, component %d (%s, the first heard): if this companion "
                    "is on the other vehicle, set link.vehicle_system_id: %d",
                    system,
                    component,
                    following,
                    system,
                )
                text = f"mavattitude: autopilot sys {system} also heard"
                self._statustext(f"autopilot{system}", text, "warning", log_it=False)
        self._others_said = set(self.counters.other_autopilots)

    def _say_same_id(self) -> None:
        """Another program sending HEARTBEATs as us (:attr:`~mavattitude.link.connection.LinkCounters.same_id`): the
        autopilot's answers to our requests reach it too, and a ground station cannot tell its messages from ours
        (two attitudes under one id). Said when heard, and when it has been gone ``SAME_ID_GONE_S``."""
        self._same_id_said = not self._same_id_said
        system, component = self.link.source
        if not self._same_id_said:
            log.info("no other program heard as system %d, component %d for %.0f s", system, component, SAME_ID_GONE_S)
            return
        log.warning(
            "another program sends HEARTBEATs as system %d, component %d, our id (a second mavattitude, the systemd "
            "service beside a run by hand, another onboard program): a ground station cannot tell its messages from "
            "ours; stop it, or give one of them another link.component_id",
            system,
            component,
        )
        self._statustext("same_id", f"mavattitude: comp {component} also used by another", "warning", log_it=False)

    def _say_tilt_only(self, unknown: bool) -> None:
        """Our attitudes lost or found their heading (no magnetometer reading at all): said once each way."""
        self._no_heading = SampleFlag.NO_HEADING if unknown else SampleFlag.NONE
        if unknown:
            log.warning("no %s magnetometer reading: %s", self._input_name, TILT_ONLY)
        else:
            log.info("%s magnetometer readings: heading from the compass again", self._input_name)

    def _say_rate_handling(self) -> None:
        """The input crossed the rate below which it is too slow to filter: how it is processed now, once."""
        frontend = self.pipeline.frontend
        self._per_sample = frontend.per_sample
        slow = int(frontend.per_sample)
        log.info("%s", rate_handling(self.config, self._input_name, frontend.rate_hz, slow, slow))

    def _on_compass(self, event: CompassEvent, instance: int | None = None) -> None:
        """The compass verdict changed: said once each way (the monitor's hysteresis keeps it from flapping).
        ``instance``: another of the vehicle's magnetometers than ``input.message``'s, named from 1 as the
        autopilot numbers them (``compass 2 turns unlike the gyro: check mount, cal``)."""
        level, words = compass_event_words(event)
        text = compass_statustext(event.figures)
        if instance is not None:
            words, text = f"compass {instance + 1}: {words}", f"compass {instance + 1}{text.removeprefix('compass')}"
        log.log(level, "%s", words)
        if event.inconsistent:
            self._statustext("compass" if instance is None else f"compass{instance}", text, "warning", log_it=False)

    def on_reject(self, reason: str, exc: BaseException) -> None:
        if reason != "internal_error":
            self._reject(reason, exc, counted=True)
        elif self._limiter.allow("log:internal_error"):  # a bug below us: the traceback goes to the log
            log.error("internal error; the message or sample is dropped (please report this)", exc_info=exc)

    def _emit(self, out: AttitudeOutput, t_rx: float) -> None:
        q, rates_radps = out.q.tolist(), out.rates_radps.tolist()  # floats once for both messages' fields
        # NaN first: "unknown", as MAVLink says
        covariance = out.covariance_or_nan().ravel().tolist() if self.config.output.covariance else None
        if not self.link.send_attitude(out.time_s, q, rates_radps, covariance):
            return
        self._arrivals.output(out.time_s)
        latency_s = self.link.last_send_s - t_rx
        self.counters.emitted += 1
        if len(self._latencies_s) < MAX_LATENCY_SAMPLES:
            self._latencies_s.append(latency_s)
        self._attitude_sent = True
        self._output_since = self.link.last_send_s
        if self._stalled:
            self._stalled = False
            log.info("attitudes go out again")

    def _watch_output(self, now: float) -> None:
        """Input arrives, attitudes went out, and none has for longer than a gap (what counts the input lost): every
        sample or tick refused since (a frozen IMU time, values out of range, degenerate geometry). Said once, with
        the refusals since the last attitude, and once when attitudes go out again (:meth:`_emit`)."""
        refused = refusals(self.counters, self.pipeline.counters)
        quiet_s = now - self._output_since
        if quiet_s <= self.pipeline.frontend.gap_limit_s:
            self._refused = refused  # attitudes flow: what is refused from here on is why they would stop
            return
        if self._stalled:
            return
        self._stalled = True
        why = refusals_text(refused - self._refused)
        log.warning("%s arrives but no attitude has gone out for %.1f s: %s", self._input_name, quiet_s, why)
        text = refused_statustext(self._input_name, refused - self._refused)
        self._statustext("output_stopped", text, "warning", log_it=False)

    def _on_input_lost(self, silent_s: float) -> None:
        self._input_lost = True
        self.counters.input_lost += 1
        log.warning("no %s for %.1f s, output stopped", self._input_name, silent_s)
        self._statustext("input_lost", input_lost_statustext(self._input_name, silent_s), "warning", log_it=False)
        if self._rate is not None:
            self._rate.restart()
        self._arrivals.forget()
        self.session.ask_now(time.monotonic())  # a rebooted autopilot has forgotten our request: ask now

    def _reject(self, reason: str, exc: BaseException, counted: bool = False) -> None:
        if not counted:
            self.counters.rejected[reason] = self.counters.rejected.get(reason, 0) + 1
        if self._limiter.allow(f"log:{reason}"):
            held = self._limiter.take_suppressed(f"log:{reason}")
            log.warning("rejected (%s): %s%s", reason, exc, f" (+{held} more since the last report)" if held else "")

    def _statustext(self, key: str, text: str, severity: str, log_it: bool = True) -> None:
        if log_it:
            log.info("%s", text)
        if self.config.output.statustext and self._limiter.allow(f"statustext:{key}"):
            self.link.send_statustext(text, severity)

    # -- counters -------------------------------------------------------------------------------------

    def _say_heading(self, lost: str | None) -> None:
        """The fused filter's compass that gives no heading (:func:`heading_lost`): said once, and when it is back."""
        if (lost is not None) == self._heading_lost:
            return
        self._heading_lost = lost is not None
        if lost is not None:
            log.warning("%s", lost)
            self._statustext("heading", "compass: no heading, gyro only: check compass", "warning", log_it=False)
        else:
            log.info("the compass gives a heading again")

    def _log_counters(self, final: bool = False) -> None:
        """The counters: a periodic INFO line with what changed since the last one (the whole line at
        DEBUG; nothing at INFO when nothing changed), the whole line at the end and in systemd's STATUS."""
        if self._latencies_s:
            p50, p99 = np.percentile(np.asarray(self._latencies_s), [50.0, 99.0]) * 1e3
            self.counters.latency_p50_ms, self.counters.latency_p99_ms = float(p50), float(p99)
            self._latencies_s.clear()
        self.counters.mean_iterations = self.pipeline.counters.mean_iterations
        compass = self.pipeline.compass.figures() if self.config.compass.enabled else None
        line = counters_line(self.counters, self.link.counters, self.pipeline.counters, compass, self._xcheck)
        self._say_heading(heading_lost(self.pipeline.counters.estimator()))
        if final:
            log.info("counters (final): %s", line)
        else:
            pairs = dict(item.split("=", 1) for item in line.split())
            changed = " ".join(f"{k}={v}" for k, v in pairs.items() if self._last_counters.get(k) != v)
            self._last_counters = pairs
            log.debug("counters (all): %s", line)
            if changed:
                log.info("counters: %s", changed)
        waiting = self.waiting
        self.notifier.status(line if waiting is Waiting.RUNNING else self.waiting_text(waiting))
