"""`mavattitude calibrate mag INPUT -o OUT.yaml`: hard- and soft-iron calibration by ellipsoid fit.

INPUT is a CSV (``.csv`` or ``.csv.gz`` with columns ``mag_x_uT, mag_y_uT, mag_z_uT``; rows with a
``mag_new`` column of 0 are repeats and skipped), a flight log (``.tlog``, DataFlash ``.bin`` or text ``.log``,
ULog ``.ulg``: the autopilot's samples, read as replay reads them), or a pymavlink connection
string (``udpin:0.0.0.0:14551``, ``tcp:HOST:PORT``, ``/dev/ttyACM0``) to collect live while the vehicle is
turned by hand: the autopilot is asked for the IMU message as the service asks for it, and while the
vehicle rests the progress line says to turn it. Coverage counts the orientations the readings show, none
before the vehicle has turned. The result is the ``calibration: mag:`` block of the config.

ArduPilot's RAW_IMU and SCALED_IMU magnetometer is already corrected by the autopilot's own compass
calibration: a fit on it finds what that calibration left.
"""

from __future__ import annotations

import argparse
import logging
import sys
import time
from collections.abc import Callable, Iterable, Iterator
from pathlib import Path
from typing import TYPE_CHECKING, Any, TextIO

import numpy as np
import yaml

from mavattitude.commands._offline import Progress
from mavattitude.config import DEFAULTS
from mavattitude.errors import CalibrationError
from mavattitude.files import LOG_SUFFIXES, MAG_COLUMNS, read_columns, refuse_overwriting
from mavattitude.link.requests import StreamRequest
from mavattitude.link.session import LinkSession
from mavattitude.sensors import magfit, units
from mavattitude.sensors.calibration import mag_block

if TYPE_CHECKING:
    from mavattitude.dispatch import Dispatcher
    from mavattitude.estimation.conventions import Vec3
    from mavattitude.link.connection import MavlinkLink
    from mavattitude.link.source import MessageSource

NAME = "calibrate"
HELP = "fit the magnetometer's hard- and soft-iron calibration (ellipsoid fit) and write its YAML block"

log = logging.getLogger(__name__)

REFUSED_HINT = "--message asks for another IMU message"  # a refused stream, in this command's words
LIVE_MIN_SAMPLES = 500  # live collection stops once coverage is met with at least this many samples
LIVE_RATE_HZ = 50.0  # the IMU rate asked of the autopilot while collecting
LIVE_WAIT_S = 0.1  # the longest a live read waits for input before the periodic work
REQUEST_REPEAT_S = 5.0  # asked again this often (a ground station may change rates; a reboot forgets)
#: Live, the command speaks as a second onboard computer (MAV_COMP_ID_ONBOARD_COMPUTER2), not as the service's 191:
#: run beside the service (both behind one router) it would otherwise take the service's id, draw its replies and
#: be said by the service to be another program under its id
LIVE_COMPONENT_ID = 192
REST_RATE_RADPS = 0.05  # a batch turning slower than 3°/s throughout is a vehicle at rest
PROGRESS_EVERY = 100


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("sensor", choices=["mag"], help="the sensor to calibrate (mag: magnetometer)")
    parser.add_argument(
        "input",
        metavar="INPUT",
        help="a CSV (.csv/.csv.gz, columns mag_x_uT, mag_y_uT, mag_z_uT in µT, sensor frame), a .tlog/.bin/.log/.ulg, "
        "or a connection string (udpin:0.0.0.0:14551, tcp:HOST:PORT, /dev/ttyACM0) to collect live",
    )
    parser.add_argument("-o", "--output", required=True, metavar="OUT.yaml", help="YAML file to write")
    parser.add_argument(
        "--profile",
        default=DEFAULTS.input.profile,
        choices=sorted(units.PROFILES),
        help=f"unit profile of the IMU messages in a .tlog or on the link (default {DEFAULTS.input.profile})",
    )
    parser.add_argument(
        "--message",
        choices=units.MESSAGES,
        help="IMU message to read from a .tlog or the link (default: the first one the profile reads that the "
        "autopilot followed sent in the log; live, the one its sender streams by default, e.g. RAW_IMU for ardupilot)",
    )
    parser.add_argument(
        "--system-id", type=int, help="read only this MAVLink system (default: the first autopilot heard)"
    )
    parser.add_argument(
        "--field-uT",
        type=float,
        metavar="B",
        help="the local field magnitude in µT: the calibrated |B| is scaled to it "
        "(default: keep the sensor's scale, determinant of the soft-iron matrix 1)",
    )
    parser.add_argument(
        "--min-coverage",
        type=float,
        default=magfit.MIN_COVERAGE,
        metavar="F",
        help=f"fraction of the 26 orientation cells the data must cover (default {magfit.MIN_COVERAGE})",
    )
    parser.add_argument(
        "--duration",
        type=float,
        default=180.0,
        metavar="S",
        help="live: give up after this many seconds (default 180); collection ends earlier once coverage "
        f"is met with at least {LIVE_MIN_SAMPLES} samples",
    )


def run(args: argparse.Namespace) -> int:
    source = args.input
    refuse_overwriting([source], args.output)
    is_csv = source.endswith((".csv", ".csv.gz"))
    if is_csv:
        mag = read_csv_mag(Path(source))
    elif source.lower().endswith(LOG_SUFFIXES) or Path(source).is_file():  # a serial port is no regular file
        mag = _collect(_log_samples(Path(source), args), args, sys.stderr, live=False)
    else:
        from mavattitude.link.connection import MavlinkLink

        with MavlinkLink(source, source_system=args.system_id or 1, source_component=LIVE_COMPONENT_ID) as link:
            live = _live(link, args)
            try:
                mag = _collect(_live_samples(link, args, live), args, sys.stderr, live=True)
            except CalibrationError as exc:
                raise CalibrationError(f"{exc}: {live.why_none()}") from None
    try:
        fit = magfit.fit_ellipsoid(mag, field_uT=args.field_uT, min_coverage=args.min_coverage)
    except CalibrationError as exc:
        raise CalibrationError(f"{source}: {exc}") from None
    unlike = None if args.field_uT is not None else magfit.unlike_earth(fit.radius_uT)
    if unlike is not None:  # written all the same: a sensor whose scale is off is calibrated, --field-uT fixes it
        units_from = "the CSV's units (µT)" if is_csv else "--profile"
        log.warning(
            "%s: %s: readings in gauss (100 µT) or milligauss (0.1 µT)? Check %s; if right, the sensor's scale is "
            "off: give the local field with --field-uT",
            source,
            unlike,
            units_from,
        )
    Path(args.output).write_text(
        "# magnetometer calibration written by `mavattitude calibrate mag`: mag = soft_iron (raw − hard_iron_uT)\n"
        + yaml.safe_dump(mag_block(fit.hard_iron_uT, fit.soft_iron), sort_keys=False)
    )
    print(report(fit, args.output))
    return 0


def report(fit: magfit.MagFit, output: str) -> str:
    lines = [
        f"{fit.samples} samples, orientation coverage {fit.coverage:.0%}, {fit.iterations} refinement iterations",
        f"|B| spread (std / mean): before {fit.spread_before:.2%}, after {fit.spread_after:.2%}",
        f"fit residual rms {fit.residual_rms_uT:.3f} µT on |B| = {fit.radius_uT:.2f} µT",
        "hard iron (µT): " + ", ".join(f"{v:.3f}" for v in fit.hard_iron_uT),
        "soft iron: " + "; ".join(", ".join(f"{v:.5f}" for v in row) for row in fit.soft_iron),
        f"written to {output}",
    ]
    return "\n".join(lines)


def read_csv_mag(path: Path) -> np.ndarray:
    """The magnetometer columns of a CSV (µT), skipping rows marked ``mag_new == 0``."""
    data = read_columns(path, MAG_COLUMNS, ["mag_new"])
    mag = np.column_stack([data[c] for c in MAG_COLUMNS])
    return mag[data["mag_new"] != 0.0] if "mag_new" in data else mag


class _Readings:
    """The dispatcher's sink in calibrate: the vehicle's samples are kept, not estimated."""

    mag_ref_ned_uT = None

    def __init__(self) -> None:
        self.samples: list[units.ImuSample] = []

    def push(self, sample: units.ImuSample) -> list[Any]:
        self.samples.append(sample)
        return []

    def set_position(self, lat_deg: float, lon_deg: float, alt_m: float, when: Any = None) -> bool:
        return False

    def set_velocity(self, velocity: units.GpsVelocity) -> None:
        """Nothing is estimated here."""

    def set_autopilot_parameter(self, name: str, value: float) -> bool:
        """A calibration is of the sensors' own frame: the autopilot's level trim does not enter it."""
        return False


class _Skipped:
    """The dispatcher's listener in calibrate: says what it skipped, nothing else."""

    def on_reject(self, reason: str, exc: BaseException) -> None:
        log.warning("skipped a sample (%s): %s", reason, exc)

    def on_lock(self, vehicle: tuple[int, int]) -> None:
        log.info("reading the autopilot at system %d, component %d", *vehicle)

    def on_input(self, sample: units.ImuSample, t_rx: float) -> None:
        """Kept by the sink."""

    def on_outputs(self, pushed: Any, t_rx: float) -> None:
        """Nothing is estimated here."""

    def on_autopilot_attitude(self, attitude: Any, t_rx: float) -> None:
        """Not needed for a calibration."""

    def on_parameter(self, parameter: Any) -> None:
        """Not needed for a calibration."""

    def on_message(self, msg: Any, t_rx: float) -> None:
        """Not needed for a calibration."""


def _read(
    source: MessageSource, system_id: int, listener: Any, going: Callable[[Dispatcher], bool]
) -> Iterator[units.ImuSample]:
    """The autopilot's IMU samples from ``source``, through the service's dispatcher (lock-on to the
    autopilot, ``system_id`` or the first; its IMU messages only), while ``going(dispatcher)`` (the
    periodic work of a live link) says so and the source has more."""
    from mavattitude.dispatch import Dispatcher

    readings = _Readings()
    dispatcher = Dispatcher(readings, listener, system_id=system_id, vehicle=source.vehicle)
    while not source.finished and going(dispatcher):
        for received in source.recv(LIVE_WAIT_S):
            dispatcher.handle(received)
        yield from readings.samples
        readings.samples.clear()


def _log_samples(path: Path, args: argparse.Namespace) -> Iterator[units.ImuSample]:
    """The autopilot's IMU samples of a .tlog, .bin, .log or .ulg, through the service's source and dispatcher;
    from a .tlog without ``--message``, the first of the profile's messages that the autopilot followed (the one
    the dispatcher locks onto, as replay's) sent in the log."""
    from mavattitude.config import load_config
    from mavattitude.link.logs import open_log

    profile = units.get_profile(args.profile)
    overrides = {"input.profile": args.profile, "input.message": args.message or profile.default_message}
    config = load_config(None, overrides, env={})
    first_of = () if args.message else tuple(profile.messages)
    source = open_log(path, config, first_of=first_of, system_id=args.system_id)
    return _read(source, args.system_id or 0, _Skipped(), lambda _: True)


class _Live(_Skipped):
    """The live link's upkeep while collecting, the service's :class:`LinkSession`: our HEARTBEAT (as an
    onboard computer, under the autopilot's system id once locked on), the IMU message requested with
    SET_MESSAGE_INTERVAL (at once on locking on, then every ``REQUEST_REPEAT_S``) and its answer said; until
    ``duration_s`` is over."""

    def __init__(self, link: MavlinkLink, request: StreamRequest, duration_s: float) -> None:
        now = time.monotonic()
        self.request = request
        self.session = LinkSession(link, [request], REQUEST_REPEAT_S, now, refused_hint=REFUSED_HINT)
        self.deadline = now + duration_s
        self.dispatcher: Dispatcher | None = None  # the one reading the link, once it has run

    def on_lock(self, vehicle: tuple[int, int]) -> None:
        self.session.lock(vehicle, time.monotonic())
        log.info("locked onto the autopilot at system %d, component %d; asking for %s", *vehicle, self.request.name)
        if self._firmware_lacks() is not None:
            self.deadline = time.monotonic()  # it never sends it: said at once, not after --duration

    def on_message(self, msg: Any, t_rx: float) -> None:
        self.session.on_message(msg, time.monotonic())

    def __call__(self, dispatcher: Dispatcher) -> bool:
        self.dispatcher = dispatcher
        now = time.monotonic()
        self.session.tick(now)
        return now < self.deadline

    def _firmware_lacks(self) -> str | None:
        """That the autopilot's firmware has no stream of the message asked for, and the --profile that reads what
        it has; None when it has one (or its firmware is unknown)."""
        from mavattitude.reports import firmware_without

        profile = None if self.dispatcher is None else self.dispatcher.vehicle_profile
        return firmware_without(profile, self.request.name, "--profile {profile} reads its {message}")

    def why_none(self) -> str:
        """Why the link gave no magnetometer reading, as far as the link shows (the words after a colon)."""
        dispatcher, name = self.dispatcher, self.request.name
        if dispatcher is None or dispatcher.vehicle is None:
            return "no autopilot HEARTBEAT heard"
        lacks = self._firmware_lacks()
        if lacks is not None:
            return lacks
        if dispatcher.counters.received:
            return f"its {dispatcher.counters.received} {name} messages carry none (all zero)"
        answer = self.session.answers.get(name)
        return f"no {name} from the autopilot" + (f" (it answered the request with {answer})" if answer else "")


def _live(link: MavlinkLink, args: argparse.Namespace) -> _Live:
    """The upkeep of a live collection: ``--message`` (or the profile's own) asked for as the service asks."""
    from mavattitude.link.mavlink2 import message_id

    message = args.message or units.get_profile(args.profile).default_message
    return _Live(link, StreamRequest(message, message_id(message), LIVE_RATE_HZ), args.duration)


def _live_samples(link: MavlinkLink, args: argparse.Namespace, live: _Live) -> Iterator[units.ImuSample]:
    """The IMU samples of the autopilot on a live link, read as the service reads them (the link as a message
    source, the service's dispatcher) and asked for by ``live``."""
    from mavattitude.link.source import MavlinkDecoder, MavlinkSource

    source = MavlinkSource(link, MavlinkDecoder(live.request.name, units.get_profile(args.profile)))
    return _read(source, args.system_id or 0, live, live)


class _Coverage:
    """Cell counts of the orientations the readings show, fed a batch at a time.

    A reading shows an orientation by its direction from the midpoint of the readings' range (a cheap
    hard-iron estimate), and only once the vehicle has been turned: the range must span
    ``magfit.MIN_TURN_SPAN`` of |B| (a vehicle at rest has visited one orientation, and its noise around
    the midpoint points everywhere), and the reading must lie at least half the range's radius from the
    midpoint. While the range holds, only the new batch is counted; a new extreme moves the midpoint and
    all readings are counted again (rare once the vehicle has turned: a long log costs linear time).
    """

    def __init__(self) -> None:
        self._batches: list[np.ndarray] = []
        self._lo, self._hi = np.full(3, np.inf), np.full(3, -np.inf)
        self._counts = np.zeros(len(magfit.CELL_DIRECTIONS), dtype=np.int64)
        self._field_uT = 0.0

    def add(self, batch: np.ndarray) -> np.ndarray:
        self._batches.append(batch)
        lo, hi = np.minimum(self._lo, batch.min(axis=0)), np.maximum(self._hi, batch.max(axis=0))
        if np.array_equal(lo, self._lo) and np.array_equal(hi, self._hi):
            self._counts = self._counts + self._visited(batch)
        else:
            self._lo, self._hi = lo, hi
            self._batches = [np.concatenate(self._batches)]
            self._field_uT = float(np.median(np.linalg.norm(self._batches[0], axis=1)))
            self._counts = self._visited(self._batches[0])
        return self._counts

    def _visited(self, readings: np.ndarray) -> np.ndarray:
        span = self._hi - self._lo
        if float(span.max()) < magfit.MIN_TURN_SPAN * self._field_uT:
            return np.zeros(len(magfit.CELL_DIRECTIONS), dtype=np.int64)  # not turned yet
        offsets = readings - (self._hi + self._lo) / 2.0
        far = np.linalg.norm(offsets, axis=1) >= 0.25 * float(span.max())  # half the radius
        return magfit.cell_counts(offsets[far])


def _collect(samples: Iterable[units.ImuSample], args: argparse.Namespace, out: TextIO, *, live: bool) -> np.ndarray:
    """Magnetometer readings from a sample stream, with a coverage progress line on ``out``; a ``live``
    collection ends once coverage is met with enough samples, a log is read to its end.

    Coverage is judged around the midpoint of the readings' range on each axis (a cheap hard-iron
    estimate: the offset is not fitted yet); the fit judges it again around the fitted centre.
    """
    rows: list[Vec3] = []
    frac = 0.0
    progress = Progress(stream=out)  # a line per change of coverage in a log or a pipe; every batch on a terminal
    seen = _Coverage()
    fastest_radps = 0.0  # the fastest rotation in the current batch: a batch without turning is at rest
    for sample in samples:
        fastest_radps = max(fastest_radps, float(np.linalg.norm(sample.gyr_radps)))
        # a message that repeats the newest reading (RAW_IMU between 10 Hz compass updates) would weigh
        # it once per message in the fit: each reading is taken once
        if sample.mag_uT is None or (sample.mag_repeats and rows and sample.mag_uT == rows[-1]):
            continue
        rows.append(sample.mag_uT)
        if len(rows) % PROGRESS_EVERY == 0:
            counts = seen.add(np.array(rows[-PROGRESS_EVERY:], dtype=float))
            frac = magfit.covered(counts)
            at_rest = live and fastest_radps < REST_RATE_RADPS
            fastest_radps = 0.0
            bar = "".join("#" if c >= magfit.MIN_PER_CELL else "." for c in counts)
            line = f"coverage [{bar}] {frac:.0%} of orientations, {len(rows)} samples"
            if at_rest:
                line += ": the vehicle is at rest, turn it through every orientation"
            progress.show(line, line if progress.tty else (frac, at_rest))
            if live and frac >= args.min_coverage and len(rows) >= LIVE_MIN_SAMPLES:
                break
    progress.end()
    if not rows:
        raise CalibrationError(f"{args.input}: no magnetometer readings found")
    return np.array(rows, dtype=float)
