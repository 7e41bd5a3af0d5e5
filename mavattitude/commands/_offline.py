"""What the offline commands (`solve`, `replay`) share: the config flags, the output CSV and progress."""

from __future__ import annotations

import argparse
import logging
import sys
import time
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any, TextIO

import numpy as np

from mavattitude.config import DEFAULTS, Config, load_config
from mavattitude.errors import ConfigError, DataFileError, MavAttitudeError
from mavattitude.estimation import METHODS
from mavattitude.files import open_text

if TYPE_CHECKING:
    from mavattitude.estimation.compass import CompassEvent
    from mavattitude.pipeline import AttitudeOutput, AttitudePipeline

COVARIANCE_COLUMNS = ("cov_xx_rad2", "cov_xy_rad2", "cov_xz_rad2", "cov_yy_rad2", "cov_yz_rad2", "cov_zz_rad2")
OUTPUT_COLUMNS = (
    "t_s",
    "qw",
    "qx",
    "qy",
    "qz",
    "roll_deg",
    "pitch_deg",
    "yaw_deg",
    "iterations",
    "converged",
    *COVARIANCE_COLUMNS,
)
_UPPER = np.triu_indices(3)  # xx, xy, xz, yy, yz, zz: the order of COVARIANCE_COLUMNS
# Inputs at least this long show progress on stderr unless --no-progress.
PROGRESS_MIN_SAMPLES = 50_000
MOSTLY_REFUSED = 0.5  # more of the input samples refused than this share: said (a log's refusals are ~1 %)


def add_config_arguments(parser: argparse.ArgumentParser) -> None:
    """The flags that override the config (they take precedence over --config and $MAVATTITUDE_CONFIG)."""
    parser.add_argument("--config", metavar="FILE", help="YAML config (see configs/); flags below override it")
    parser.add_argument("--method", choices=METHODS, help=f"estimator (config default: {DEFAULTS.estimator.method})")
    ref = parser.add_mutually_exclusive_group()
    ref.add_argument(
        "--declination",
        type=float,
        metavar="DEG",
        help="magnetic declination, degrees east of true north (with --inclination)",
    )
    ref.add_argument("--mag-ref-ned", type=float, nargs=3, metavar=("N", "E", "D"), help="magnetic field in NED, µT")
    parser.add_argument("--inclination", type=float, metavar="DEG", help="magnetic inclination (dip), degrees down")
    noise = DEFAULTS.noise
    for flag, sensor, unit, std in (
        ("--accel-std", "accelerometer", "m/s²", noise.accel_std_mps2),
        ("--mag-std", "magnetometer", "µT", noise.mag_std_uT),
    ):
        parser.add_argument(
            flag,
            type=_std,
            metavar="S",
            help=f"{sensor} noise σ, {unit}: one value or three comma-separated (config default: {_sigmas(std)})",
        )
    parser.add_argument(
        "--filter",
        action=argparse.BooleanOptionalAction,
        default=None,
        help=f"low-pass and resample to the output rate ({DEFAULTS.filter.output_rate_hz:g} Hz by default) as the "
        "service does; --no-filter solves every input sample "
        f"(default: --{'' if DEFAULTS.filter.enabled else 'no-'}filter)",
    )


def _sigmas(std: tuple[float, ...]) -> str:
    """A per-axis σ as the flags take it: one value when the three are equal."""
    return f"{std[0]:g}" if len(set(std)) == 1 else ",".join(f"{s:g}" for s in std)


def _std(text: str) -> float | list[float]:
    try:
        values = [float(v) for v in text.split(",")]
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r}: expected one number or three comma-separated") from None
    if len(values) not in (1, 3):
        raise argparse.ArgumentTypeError(f"{text!r}: expected one number or three comma-separated")
    return values[0] if len(values) == 1 else values


def config_from_args(args: argparse.Namespace, extra: dict[str, Any] | None = None) -> Config:
    """The effective config: the flags (and ``extra`` dotted keys from a command's own flags) over
    $MAVATTITUDE_CONFIG over --config over the defaults."""
    overrides: dict[str, Any] = dict(extra or {})
    if (args.declination is None) != (args.inclination is None):
        raise ConfigError("--declination and --inclination go together")
    if args.declination is not None:
        overrides["reference.magnetic"] = {"declination_deg": args.declination, "inclination_deg": args.inclination}
    if args.mag_ref_ned is not None:
        overrides["reference.magnetic"] = {"field_ned_uT": list(args.mag_ref_ned)}
    for flag, key in (
        ("method", "estimator.method"),
        ("accel_std", "noise.accel_std_mps2"),
        ("mag_std", "noise.mag_std_uT"),
        ("filter", "filter.enabled"),
    ):
        if getattr(args, flag) is not None:
            overrides[key] = getattr(args, flag)
    return load_config(args.config, overrides)


#: printf formats of ``OUTPUT_COLUMNS``: time to the µs, quaternion to 1e-9, angles to 1e-4°, covariance.
ROW_FORMAT = ["%.6f", *["%.9f"] * 4, *["%.4f"] * 3, "%d", "%d", *["%.6e"] * 6]


def write_outputs(path: str | Path, outputs: Sequence[AttitudeOutput], covariances: np.ndarray | None = None) -> int:
    """Write the attitude CSV (``OUTPUT_COLUMNS``), Euler angles computed for all rows at once; returns the
    number of rows. The covariance is of the body-frame error angles, rad² (NaN: none; ``covariances``: the
    outputs' already computed, ``(N, 3, 3)``); the yaw of an attitude without a heading (``NO_HEADING``: its
    quaternion holds yaw 0) is NaN."""
    from mavattitude.estimation.conventions import euler_from_quat
    from mavattitude.pipeline import output_covariances
    from mavattitude.sensors.frontend import SampleFlag

    n = len(outputs)
    q = np.array([o.q for o in outputs], dtype=float).reshape(n, 4)
    euler_deg = np.degrees(euler_from_quat(q)).reshape(n, 3)
    euler_deg[[bool(o.flags & SampleFlag.NO_HEADING) for o in outputs], 2] = np.nan  # no magnetometer: yaw 0 held
    cov = output_covariances(list(outputs)) if covariances is None else covariances
    table = np.column_stack(
        [
            np.array([o.time_s for o in outputs], dtype=float),
            q,
            euler_deg,
            np.array([o.iterations for o in outputs], dtype=float),
            np.array([o.converged for o in outputs], dtype=float),
            cov[:, _UPPER[0], _UPPER[1]].reshape(n, 6),
        ]
    )
    with open_text(path, "w") as f:
        f.write(",".join(OUTPUT_COLUMNS) + "\n")
        if n:
            np.savetxt(f, table, fmt=ROW_FORMAT, delimiter=",")
    return n


def summarise_compass(pipeline: AttitudePipeline, events: list[CompassEvent], logger: logging.Logger) -> None:
    """The compass verdict's changes (vehicle time) and its figures, as the service reports them live."""
    from mavattitude.reports import compass_event_words, compass_summary

    for event in events:
        level, words = compass_event_words(event)
        logger.log(level, "t=%.1f s: %s", event.time_s, words)
    if pipeline.compass_seen:
        logger.info("%s", compass_summary(pipeline.compass.figures()))
    else:
        logger.info("compass: no magnetometer reading: nothing to judge")


class Progress:
    """The one progress line of the commands, on stderr (or ``stream``): redrawn in place on a terminal, a line
    per change elsewhere (a log, a pipe).

    ``progress(done, total)`` draws a bar, every 1 % on a terminal and 10 % elsewhere: the signature the
    library's loops report through (replay, the validation); :meth:`show` draws any other line (calibrate's
    coverage). ``enabled`` None: only for totals of ``PROGRESS_MIN_SAMPLES`` or more.
    """

    def __init__(self, label: str = "", enabled: bool | None = True, stream: TextIO | None = None) -> None:
        self.label = label
        self.enabled = enabled
        self.stream = stream or sys.stderr
        self.tty = self.stream.isatty()
        self._key: object = None
        self._width = 0  # of the line drawn in place: a shorter one is padded over it
        self._start = time.monotonic()

    def __call__(self, done: int, total: int) -> None:
        if not (total >= PROGRESS_MIN_SAMPLES if self.enabled is None else self.enabled):
            return
        percent = 100 * done // max(total, 1)
        elapsed = time.monotonic() - self._start
        line = f"{self.label}: [{'#' * (percent // 5):<20}] {percent:3d}% {done}/{total} {elapsed:.1f} s"
        self.show(line, percent if self.tty else percent // 10)
        if done >= total:
            self.end()

    def show(self, line: str, key: object) -> None:
        """``line`` drawn, unless ``key`` is the drawn line's (say what changed, not every call)."""
        if key == self._key:
            return
        self._key = key
        self.stream.write("\r" + line.ljust(self._width) if self.tty else line + "\n")
        self.stream.flush()
        self._width = max(self._width, len(line)) if self.tty else 0

    def end(self) -> None:
        """The line drawn in place on a terminal finished (the next output starts on a new one)."""
        if self._width:
            self.stream.write("\n")
            self.stream.flush()
        self._width, self._key = 0, None


def summarise(
    pipeline: AttitudePipeline,
    n_in: int,
    source: str,
    compass: list[CompassEvent],
    units_from: Callable[[str], str],
) -> None:
    """Log the counters, a units finding with ``units_from(sensor)``, where its units were given, the compass
    verdict's changes (``compass``) and its figures (the caller names ``source`` in the log:
    :func:`mavattitude.commands.about`); nothing solved at all is a failure, not an empty success."""
    from mavattitude.reports import pipeline_summary, refusals_text
    from mavattitude.sensors.magref import MIN_MEASURED_TICKS

    counters = pipeline.counters
    logger = logging.getLogger("mavattitude")
    logger.info("%d samples in; %s", n_in, pipeline_summary(counters))
    for finding in pipeline.units.findings:
        logger.warning("t=%.1f s: %s: check %s", finding.time_s, finding.text, units_from(finding.sensor))
    if pipeline.config.compass.enabled:
        summarise_compass(pipeline, compass, logger)
    # (without a compass no field is needed; with every sample refused, the refusals are what stopped it)
    if counters.emitted == 0 and pipeline.waiting_for_reference and counters.frontend.accepted:
        # an accelerometer in the wrong units never reads as still, so no field is measured: the cause, said first
        wrong = [
            f"{f.text}, so the vehicle never read as still: fix them (the warning above), or "
            for f in pipeline.units.findings
            if f.sensor == "accelerometer"
        ]
        raise DataFileError(
            f"{source}: reference.magnetic is auto, the input holds no position with a fix, and no field was "
            f"measured from its compass ({pipeline.magref.position_wait_s:g} s of reference.position_wait_s from its "
            f"start, then {MIN_MEASURED_TICKS} magnetometer ticks with the vehicle still): "
            f"{''.join(wrong)}give --declination DEG --inclination DEG or --mag-ref-ned N E D"
        )
    refused, received = counters.frontend.rejected, counters.frontend.received
    if counters.emitted == 0:
        reasons = dict(counters.rejected) or (refusals_text(refused) if +refused else "no output tick")
        raise MavAttitudeError(f"{source}: no attitude could be computed ({reasons})")
    if sum(refused.values()) > received * MOSTLY_REFUSED:  # attitudes, but from a few samples: said, as live
        logger.warning(
            "most input samples were refused (%d of %d): %s", sum(refused.values()), received, refusals_text(refused)
        )
