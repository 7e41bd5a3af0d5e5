"""What the service and the commands say, written once: the counters line and the compass's and the
cross-check's words.

- :class:`ServiceCounters` and :func:`counters_line`: the ``key=value`` line the service logs every
  ``stats_interval_s`` (and at the end), which the e2e tests and an operator read; :func:`pipeline_summary`:
  the pipeline's part of it, the line ``solve`` and ``replay`` log for each input;
- :func:`compass_event_words`, :func:`compass_warning`, :func:`compass_statustext`: a change of the compass
  monitor's verdict in the log and in STATUSTEXT's 50 characters, live and in an offline summary alike;
  :func:`compass_summary`: its figures over a log as one line;
- :func:`rate_handling`: how the input was processed at its rate (the service's log, replay's summary);
- :func:`heading_lost`: the fused filter's compass that gave no heading (almost) all along, live and offline.
"""

from __future__ import annotations

import logging
import math
from collections import Counter
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

from mavattitude.config import Config
from mavattitude.dispatch import DISPATCH_REJECTS, DispatchCounters
from mavattitude.estimation import METHODS
from mavattitude.estimation.compass import CompassEvent, CompassFigures
from mavattitude.estimation.crosscheck import CrossCheck
from mavattitude.link.connection import STATUSTEXT_LEN
from mavattitude.link.session import RequestCounters
from mavattitude.pipeline import SLOW_INPUT_METHOD
from mavattitude.sensors.clock import first_repeats
from mavattitude.sensors.frontend import SLOW_PACE, FrontEndSettings
from mavattitude.sensors.units import PROFILES, get_profile


@dataclass
class ServiceCounters(DispatchCounters, RequestCounters):
    """What the service has seen and done since it started (the dispatcher's counters and its own).

    ``mean_iterations`` and the latencies are refreshed at each counters line (latency: over the window
    since the previous line); ``rejected`` holds the service's own reasons, and the line adds the
    pipeline's (input samples the front end dropped, ticks the solver could not use) by name.
    """

    emitted: int = 0  # ATTITUDE_QUATERNION sent
    rejected: dict[str, int] = field(default_factory=lambda: dict.fromkeys(DISPATCH_REJECTS, 0))
    input_lost: int = 0  # times the input went silent for longer than input_timeout_s
    autopilot_silent: int = 0  # times nothing came from the autopilot (HEARTBEAT, input) for HEARTBEAT_LOST_S
    input_rate_hz: float = float("nan")  # received, over the service's last rate window
    rate_warnings: int = 0  # times the input stayed below the requested rate
    mean_iterations: float = float("nan")
    latency_p50_ms: float = float("nan")  # input read from the socket -> ATTITUDE_QUATERNION handed to the OS
    latency_p99_ms: float = float("nan")


#: The fused filter's heading is the gyro's alone (the compass rejected, absent or degenerate) for at least this
#: share of its updates, or for this long without a break: said, not left to drift in silence.
HEADING_LOST_FRACTION = 0.5
HEADING_LOST_S = 60.0


def heading_lost(counters: dict[str, float]) -> str | None:
    """The words for a fused filter whose compass gave (almost) no heading, from its counters; ``None`` when it
    gave one. A compass off for a while is the filter's to coast over; one that never comes back is a finding.
    Where no heading update was ever taken after a start with the heading unknown (the first reading's field
    already off: ``start_heading_unknown``), there is no heading for the gyro to carry: the yaw is meaningless."""
    updates, tilt_only = counters.get("updates", 0), counters.get("tilt_only_updates", 0)
    gap_s = counters.get("heading_gap_s", 0.0)
    if not updates or (tilt_only < HEADING_LOST_FRACTION * updates and gap_s < HEADING_LOST_S):
        return None
    share = 100.0 * tilt_only / updates
    if tilt_only == updates and counters.get("start_heading_unknown", 0):
        what = "the heading was never known (the field already off at the start): the yaw means nothing"
    else:
        what = f"none for the last {gap_s:.0f} s: the heading is the gyro's alone and drifts"
    return (
        f"the compass gave no heading for {tilt_only:.0f} of {updates:.0f} updates ({share:.0f} %), {what}; check "
        "the compass (a disturbance that never ends, a field off the reference, no magnetometer)"
    )


def compass_event_words(event: CompassEvent) -> tuple[int, str]:
    """The log level and words of a change of the compass verdict (said once each way)."""
    if event.inconsistent:
        return logging.WARNING, compass_warning(event.figures)
    return logging.INFO, f"compass consistent again: {event.figures.describe()}"


def compass_warning(figures: CompassFigures) -> str:
    """The log's words for an inconsistent compass."""
    return f"{figures.describe()}: check the compass orientation and calibration"


def compass_statustext(figures: CompassFigures) -> str:
    """The same in STATUSTEXT's 50 ASCII characters: the figure that is off, and what to check."""
    if figures.turn_off:
        return "compass turns unlike the gyro: check mount, cal"
    word = "start" if figures.reference_measured else "expected"  # a field measured at the start: a change since
    if abs(figures.dip_deg - figures.expected_dip_deg) > figures.threshold_dip_deg:
        return f"compass dip {figures.dip_deg:+.0f} ({word} {figures.expected_dip_deg:+.0f}): check mount, cal"
    return f"compass |B| {100.0 * figures.field_ratio:.0f}% of {word}: check calibration"


def compass_pairs(figures: CompassFigures) -> list[tuple[str, float]]:
    """The compass figures of the counters line (degrees, and |B| as a fraction of the reference's)."""
    return [
        ("compass_dip_deg", figures.dip_deg),
        ("compass_dip_expected_deg", figures.expected_dip_deg),
        ("compass_dip_std_deg", figures.dip_std_deg),
        ("compass_dip_1min_deg", figures.first_dip_deg),
        ("compass_field_ratio", figures.field_ratio),
        ("compass_turn_mismatch", figures.turn_mismatch),
        ("compass_warnings", figures.warnings),
    ]


def crosscheck_pairs(xcheck: CrossCheck) -> list[tuple[str, float]]:
    """The cross-check figures of the counters line: pairs compared and of them not judged (the vehicle moving), those
    missed inside our output span and why, the last and RMS total difference (deg)."""
    last = xcheck.last.total_deg if xcheck.last is not None else math.nan
    return [
        ("xc_pairs", xcheck.pairs),
        ("xc_unjudged", xcheck.unjudged),  # compared, not judged: ours a snapshot method's while the vehicle moved
        ("xc_missed", xcheck.missed),  # inside our output span, not paired: xc_unpaired.REASON says why
        *((f"xc_unpaired.{k}", v) for k, v in sorted(xcheck.unpaired.items())),
        ("xc_total_deg", last),
        ("xc_rms_deg", xcheck.rms_total_deg),
        ("xc_warnings", xcheck.warnings),
    ]


def counters_line(
    counters: ServiceCounters,
    link_counters: Any,
    pipeline_counters: Any,
    compass: CompassFigures | None = None,
    xcheck: CrossCheck | None = None,
) -> str:
    """``key=value`` numbers, one line: what the e2e tests and an operator read.

    ``rejected.REASON`` sums the service's reasons, the front end's dropped input samples and the
    solver's refused ticks; ``mag_rejected.REASON`` counts magnetometer readings the front end dropped;
    ``compass_*`` are the compass monitor's figures (:func:`compass_pairs`), when it is on.
    """
    c = counters
    frontend = pipeline_counters.frontend
    rejected = Counter(c.rejected) + Counter(frontend.rejected) + Counter(pipeline_counters.rejected)
    pairs: list[tuple[str, float]] = [
        ("received", c.received),
        ("emitted", c.emitted),
        ("ignored", c.ignored),
        ("skipped", link_counters.skipped),  # telemetry of no use here, not decoded
        *((f"rejected.{k}", rejected[k]) for k in sorted({*c.rejected, *rejected})),
        *((f"mag_rejected.{k}", v) for k, v in sorted(frontend.mag_rejected.items())),
        ("gap_resets", frontend.gap_resets),
        ("per_sample", frontend.per_sample),  # ticks that are one input sample each: the input too slow to filter
        ("reboots", frontend.reboots),
        ("not_converged", pipeline_counters.not_converged),
        ("mean_iterations", c.mean_iterations),
        ("latency_p50_ms", c.latency_p50_ms),
        ("latency_p99_ms", c.latency_p99_ms),
        ("input_lost", c.input_lost),
        ("autopilot_silent", c.autopilot_silent),
        ("positions", c.positions),
        ("interval_requests", c.interval_requests),
        ("parameter_requests", c.parameter_requests),
        *((f"acks.{k.lower()}", v) for k, v in sorted(c.acks.items())),
        ("ack_timeouts", c.ack_timeouts),
        ("requests_unheard", c.requests_unheard),
        ("acks_unmatched", c.acks_unmatched),
        ("input_rate_hz", c.input_rate_hz),
        ("rate_warnings", c.rate_warnings),
        ("bad_data", link_counters.bad_data),
        ("signature_rejected", link_counters.signature_rejected),
        ("sent", link_counters.sent),
        ("send_failed", link_counters.send_failed),
        ("reconnects", link_counters.reconnects),
        ("same_id", link_counters.same_id),  # another program's HEARTBEATs under our id
        *(compass_pairs(compass) if compass is not None else ()),
        *(crosscheck_pairs(xcheck) if xcheck is not None else ()),
        *((f"{pipeline_counters.estimator_prefix}.{k}", v) for k, v in pipeline_counters.estimator().items()),
    ]
    return " ".join(f"{k}={v:.3f}" if isinstance(v, float) else f"{k}={v}" for k, v in pairs)


def compass_summary(f: CompassFigures) -> str:
    """The compass monitor's figures over a log as one line; what was not measured is said so, not ``nan``."""
    if f.samples == 0:
        return "compass: no quiet sample (the vehicle never rested): dip and |B| not judged"
    field = (
        f"|B| {f.field_ratio:.2f} of the {f.expected} ({_spread(f.field_std, '.2f', '')}, "
        f"first minute {f.first_field_ratio:.2f})"
        if f.field_ratio == f.field_ratio
        else "|B| not compared (the magnetic reference gives no field strength: reference.magnetic.intensity_uT "
        "or a position for the World Magnetic Model)"
    )
    return (
        f"compass: dip {f.dip_deg:.1f}° ({_spread(f.dip_std_deg, '.1f', '°')}, first minute {f.first_dip_deg:.1f}°) vs "
        f"{f.expected} {f.expected_dip_deg:.1f}°, {field}, {f.samples} quiet samples, judged inconsistent "
        f"{f.warnings} time(s)"
    )


def _spread(std: float, spec: str, unit: str) -> str:
    """A window's spread, or why there is none (one quiet sample in the window: a slow input)."""
    return f"spread {std:{spec}}{unit}" if std == std else "one sample in the window, no spread"


#: A share of slow samples said as "all", and its complement said as none: a stream's first sample comes
#: before its pace is known (a slow one's is not slow yet; a log's first interval may be long, 0.16 s before a
#: 200 Hz stream, which makes its second sample alone "slow")
MOSTLY = 0.99


def rate_handling(config: Config, message: str, rate_hz: float, per_sample: int, samples: int) -> str:
    """How the input was processed at its rate, one line (the service's log, replay's ``rate_handling``):
    ``per_sample`` of the accepted ``samples`` gave one attitude each, unfiltered (the input slower than about
    twice the low-pass cutoff; :func:`~mavattitude.sensors.frontend.pace_intervals_s`)."""
    head = f"{message} at {rate_hz:.1f} Hz" if math.isfinite(rate_hz) else f"{message} at a rate unknown (one sample)"
    integrates = METHODS[config.estimator.method].needs_gyro
    if per_sample > (1.0 - MOSTLY) * samples:
        what = "one attitude per sample, no filtering"
        if integrates:
            what = f"too slow to integrate the gyro: one {SLOW_INPUT_METHOD.upper()} attitude per sample, no filtering"
        below = f"below {SLOW_PACE * config.filter.cutoff_hz:g} Hz"
        share = "" if per_sample >= MOSTLY * samples else f" ({per_sample} of {samples} samples, {below})"
        return f"{head}: {what}{share}"
    if integrates:
        return f"{head}: every sample into the gyro-aided filter"
    if not config.filter.enabled:
        return f"{head}: one attitude per sample (filter.enabled is false)"
    return f"{head}: {config.filter.cutoff_hz:g} Hz low-pass, {config.filter.output_rate_hz:g} Hz output"


def profile_units(config: Config, message: str, sensor: str, named: str = "input.profile") -> str:
    """What to check for a units finding (:mod:`~mavattitude.sensors.unitcheck`) on a MAVLink input: the scale
    ``named`` (the config key, or a command's flag) reads ``message``'s ``sensor`` with."""
    scale = get_profile(config.input.profile, config.input.custom).scale(message)
    per_unit, unit = (scale.acc_mps2, "m/s²") if sensor == "accelerometer" else (scale.mag_uT, "µT")
    return (
        f"{named} {config.input.profile}'s scale, {per_unit:.4g} {unit} per unit of {message}'s {sensor}: the "
        "autopilot's? (profile custom with input.custom gives any other)"
    )


def pipeline_summary(counters: Any) -> str:
    """The pipeline's counters as one line (an offline run's): samples in and out, refusals by reason."""
    return (
        f"received={counters.frontend.received} emitted={counters.emitted} "
        f"rejected={{{_by_reason(counters.rejected)}}} input_rejected={{{_by_reason(counters.frontend.rejected)}}} "
        f"mean_iterations={counters.mean_iterations:.2f} not_converged={counters.not_converged}"
        + "".join(f" {k}={v:.3g}" if isinstance(v, float) else f" {k}={v}" for k, v in counters.estimator().items())
    )


#: What a refusal's reason means for the vehicle, where its counter's name does not say it.
REFUSAL_HINTS = {
    "duplicate": "its IMU time does not advance",
    "out_of_order": "its IMU time goes back",
    "decode": "not readable in the input.profile's units",
    "nonfinite": "its accelerometer or gyroscope reads no number",
    "saturated_acc": "its accelerometer at an integer limit or its full scale",
    "saturated_gyr": "its gyroscope at an integer limit or its full scale",
    "dead_acc": f"its accelerometer reads under {FrontEndSettings.dead_fraction:.0%} of g: a bus glitch, free fall, "
    "or an IMU the autopilot lacks",
}


#: What the service says to the ground station, each within STATUSTEXT's 50 characters for every input message
#: (its log line says more).
DEGENERATE_STATUSTEXT = "mavattitude: acc and mag collinear, no attitude"
CLOCKS_APART_STATUSTEXT = "mavattitude: no cross-check: clocks apart"


FIRMWARE_NAMES = {"ardupilot": "an ArduPilot", "px4": "a PX4"}  # by unit profile (link.source.FIRMWARE_PROFILES)


def firmware_without(vehicle_profile: str | None, message: str, remedy: str) -> str | None:
    """That the autopilot's firmware (the unit profile its HEARTBEAT names) has no ``message`` stream, as a PX4 has
    no RAW_IMU, and the ``remedy`` in the caller's words, given the profile that reads the firmware (``{profile}``)
    and that profile's own message (``{message}``); None when it has one, or when the firmware is not one with a
    profile."""
    if vehicle_profile is None or message in PROFILES[vehicle_profile].messages:
        return None
    own = PROFILES[vehicle_profile].default_message
    lacks = f"the autopilot is {FIRMWARE_NAMES[vehicle_profile]} (its HEARTBEAT), which has no {message} stream"
    return f"{lacks}: {remedy.format(profile=vehicle_profile, message=own)}"


#: Of an input, this share repeating the time of the sample before, one copy each (a clock that stands still repeats
#: in runs: one each): the stream arrives twice, or more.
TWICE_SHARE = 0.25


def arriving_twice(time_s: Sequence[float], message: str) -> str | None:
    """The words for an input that arrives twice, every sample followed by a copy (by two routes), from its samples'
    times in arrival order (:func:`~mavattitude.sensors.clock.first_repeats`); None when it does not."""
    received = len(time_s)
    share = first_repeats(time_s) / received if received else 0.0
    if share < TWICE_SHARE:
        return None
    return (
        f"{100.0 * share:.0f} % of the last {received} {message} repeated the time of the one before, one copy each: "
        "the stream arrives twice, by two routes (a router beside a direct link, or a routing loop); the copies are "
        "dropped, at their cost"
    )


def start_statustext(version: str, message: str) -> str:
    return f"mavattitude {version}: attitude from {message}"


def input_lost_statustext(message: str, silent_s: float) -> str:
    return f"mavattitude: no {message} {silent_s:.1f} s, output stopped"


def refused_statustext(message: str, refused: Counter[str]) -> str:
    """The input arrives but is all refused: the commonest reason, when it fits."""
    top = refused.most_common(1)
    text = f"mavattitude: {message} {top[0][0] if top else 'refused'}: no attitude"
    return text if len(text) <= STATUSTEXT_LEN else f"mavattitude: {message} refused: no attitude"


def compass_unused_warning(instance: int, parameter: str, value: float, remedy: str) -> str:
    """The compass our heading comes from is one the autopilot does not use (``instance`` 0-based; the autopilot
    numbers them from 1): it set it aside, perhaps for a reason the pilot knows (interference, a bad mount)."""
    return (
        f"the autopilot does not use compass {instance + 1} ({parameter} {value:g}), the one our heading comes "
        f"from: it may have set it aside for a reason (interference, its mounting); {remedy}"
    )


def compass_unused_statustext(instance: int) -> str:
    return f"mavattitude: compass {instance + 1} unused by autopilot"


def refusals(dispatch: DispatchCounters, pipeline: Any) -> Counter[str]:
    """Every input sample and tick refused so far, by reason: undecodable (the dispatcher), refused by the front
    end (its clock, the screening), not emitted by the pipeline (degenerate geometry, no magnetometer, …)."""
    return Counter(dispatch.rejected) + pipeline.frontend.rejected + pipeline.rejected


def refused_as_dead_imu(refused: Counter[str]) -> bool:
    """Whether the input is refused mostly as a dead accelerometer: ArduPilot sends SCALED_IMU2/3 for an IMU it
    lacks with a zero accelerometer and gyroscope (the compass in it may be real), so another IMU message of the
    vehicle's is the likely fix."""
    top = refused.most_common(1)
    return bool(top) and top[0][0] == "dead_acc"


def refusals_text(refused: Counter[str]) -> str:
    """Refusals as words, the most frequent first: ``duplicate 2400 (its IMU time does not advance)``."""
    refused = +refused  # (a count of 0 is nothing refused)
    if not refused:
        return "nothing refused"
    words = [f"{k} {n}" + (f" ({REFUSAL_HINTS[k]})" if k in REFUSAL_HINTS else "") for k, n in refused.most_common()]
    return "refused: " + ", ".join(words)


def _by_reason(counter: Mapping[str, int]) -> str:
    return ", ".join(f"{k}: {v}" for k, v in sorted(counter.items()))
