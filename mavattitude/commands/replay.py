"""`mavattitude replay LOG... -o OUT`: the service's pipeline, offline, over flight logs.

Each log (a telemetry log .tlog, an ArduPilot DataFlash .bin or its text form .log, a PX4 ULog .ulg: the
format is read from the file's content) goes through the service's own dispatcher and pipeline
(mavattitude.replay), as fast as the CPU goes. From a .tlog the IMU messages are input.message decoded with
input.profile (without --message, a log whose autopilot sent none is replayed with the first other IMU message
of the profile it sent, and said: a PX4's HIGHRES_IMU), and replay follows one autopilot as the service does
(--system-id or link.vehicle_system_id, else the first autopilot HEARTBEAT; the others the log holds are
named); a .bin, .log or .ulg is the autopilot's own log (IMU and MAG instances chosen with --imu / --mag).
With reference.magnetic auto, the World Magnetic Model is evaluated at the log's positions, on the log's
date; a log without a position is replayed with the dip and |B| its compass shows while the vehicle is still
(reference.position_wait_s after its start, as the live service does), heading from magnetic north, or from
true north by the autopilot's declination where its parameters give it (ArduPilot's COMPASS_DEC, PX4's
EKF2_MAG_DECL).

One log and OUT ending in .csv (or .csv.gz): the attitude is written there. Several logs, or a
directory of them: OUT is a directory, with one CSV per log (the columns of `mavattitude solve`), and
summary.csv, the table also printed, per log: log, status (ok, damaged: read up to the damage, failed), its
duration_s, samples, outputs, ours-minus-autopilot roll_rms_deg, pitch_rms_deg, yaw_rms_deg and roll_p99_deg,
pitch_p99_deg, yaw_p99_deg (degrees; at each of the autopilot's attitudes, ours interpolated to its time, as
the service's cross-check pairs them; differences wrapped to ±180°), how many of the autopilot's attitudes
inside our output span were compared (compared, compared_pct) and why the others were not (not_compared: gap,
reset, late, overflow), rejects (inputs and ticks refused), rate_handling (an IMU at 20 Hz or slower, below
about twice the low-pass cutoff, gives one unfiltered attitude per sample; --method fused then solves them with
IGN: too slow to integrate), heading, its source (a log without a magnetometer, or one reading zero, gives roll
and pitch with the yaw NaN), reference, the magnetic one used (WMM release, place and date; the field measured
from the compass; or the one given), units (a sensor whose first seconds' magnitude says its units are wrong:
"accelerometer reads 3.33 g"), trim_deg (the autopilot's level trim applied, roll and pitch: ArduPilot's
AHRS_TRIM_X/Y from the log's parameters, with mounting.autopilot_trim), the estimator's own counters named by
its method (ign.noise_rest_s, the still time seen, and ign.noise_measured, 1 where the σ measured at rest were
used; the fused filter's fused.*, among them fused.noise_rest_s, fused.noise_measured and fused.bias_from_rest,
the filters started from the gyro bias measured at rest, and heading_from_compass), the compass monitor's
compass_dip_deg (the first minute's mean), compass_dip_expected_deg, compass_field_ratio and compass_warnings,
with crosscheck.enabled the cross-check's xc_pairs, xc_unjudged (of them not judged: a snapshot method's while
the vehicle moved), xc_rms_deg and xc_warnings, and a note on what was wrong with the file.
Every magnetometer a log holds (a .bin's MAG instances; a .tlog's RAW_IMU, SCALED_IMU2, SCALED_IMU3) is
judged by the compass monitor against the same IMU: the summary's compasses column ("0 ok; 1 turns unlike
the gyro: turned?"), and compass, the one replayed and why: --mag, else the one the autopilot used where
the log says (COMPASS_USE / COMPASS_USE2 / COMPASS_PRIMARY in PARM or PARAM_VALUE), else the most consistent;
one the autopilot did not use (its COMPASS_USE 0: the only one logged, or --mag's) is said (a warning, and
"unused by the autopilot" in compass), and so is each other one it does not use (COMPASS_USE2 0, PX4's
CAL_MAGn_EN 0) in its verdict and warning.
-j N replays N logs at a time in worker processes. Where a log holds the autopilot's own attitude, a
PNG comparison plot is written beside its CSV (needs matplotlib: pip install mavattitude[plot]), shaded where
the compass was judged off and where the cross-check warned.

The snapshot methods (ign, the default) see only the accelerometer and magnetometer: during
accelerations they take specific force for gravity, so their roll and pitch differ from a gyro-aided
autopilot's by degrees there; --method fused integrates the gyro and follows it closely.

A log that cannot be read is one line naming the file and what is wrong; one cut short or damaged is
read up to the damage, its outputs written and the damage named. Either way the exit code is 2, and
with several logs the others are replayed all the same (the summary marks the bad ones).
"""

from __future__ import annotations

import argparse
import concurrent.futures
import csv
import dataclasses
import logging
import math
import multiprocessing
import sys
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from mavattitude import collector
from mavattitude.commands import about
from mavattitude.commands._offline import (
    Progress,
    add_config_arguments,
    config_from_args,
    summarise,
    write_outputs,
)
from mavattitude.config import DEFAULTS, Config
from mavattitude.errors import DataFileError, MavAttitudeError
from mavattitude.estimation import METHODS
from mavattitude.estimation.conventions import euler_from_quat
from mavattitude.files import refuse_overwriting
from mavattitude.link.logstreams import TILT_ONLY
from mavattitude.reports import arriving_twice, compass_unused_warning, heading_lost, profile_units, rate_handling
from mavattitude.sensors.frontend import SampleFlag
from mavattitude.sensors.units import MESSAGES, PROFILE_NAMES, get_profile

NAME = "replay"
HELP = (
    "the service's pipeline over flight logs (.tlog, DataFlash .bin/.log, ULog .ulg): attitude CSVs, vs the autopilot's"
)

log = logging.getLogger(__name__)

SNAPSHOT_NOTE = (
    "{method} uses the accelerometer and magnetometer only: in accelerations it reads specific force as gravity, "
    "so its roll/pitch (and, through the field's dip, its yaw) differ from the gyro-aided autopilot's there "
    "(--method fused follows it); the cross-check judges it only while the vehicle is still (xc_unjudged)"
)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.formatter_class = argparse.RawDescriptionHelpFormatter
    parser.description = __doc__.split("\n", 2)[2]
    parser.add_argument(
        "logs",
        nargs="+",
        metavar="LOG",
        help="flight logs, or directories of them: telemetry (.tlog), DataFlash (.bin), ULog (.ulg)",
    )
    parser.add_argument(
        "-o", "--output", required=True, help="one log: output CSV (.csv/.csv.gz) or directory; several: directory"
    )
    parser.add_argument(
        "-j", "--jobs", type=_positive, default=1, metavar="N", help="logs replayed at once (default 1)"
    )
    parser.add_argument("--imu", type=int, default=0, metavar="I", help="IMU instance of a .bin/.ulg (default 0)")
    parser.add_argument(
        "--mag",
        type=int,
        default=None,
        metavar="I",
        help="magnetometer instance (a .tlog: 0 RAW_IMU's, 1 SCALED_IMU2's, 2 SCALED_IMU3's); default: the one "
        "the autopilot used where the log says (ArduPilot COMPASS_USE/_PRIMARY), else the most consistent; one the "
        "log lacks is refused, naming those it has",
    )
    parser.add_argument(
        "--message",
        choices=MESSAGES,
        type=str.upper,
        help=f"IMU message of a .tlog (config default: {DEFAULTS.input.message})",
    )
    parser.add_argument(
        "--profile", choices=PROFILE_NAMES, help=f"unit profile of a .tlog (config default: {DEFAULTS.input.profile})"
    )
    parser.add_argument(
        "--system-id",
        type=int,
        metavar="ID",
        help="the autopilot of a .tlog to follow, by MAVLink system id, where it holds several (a swarm, a ground "
        "station's log of two vehicles); default: the first whose HEARTBEAT it holds",
    )
    parser.add_argument(
        "--plot", metavar="PNG", help="plot file of a single log (default: the output's name with .png)"
    )
    parser.add_argument("--no-plot", action="store_true", help="write no plot")
    add_config_arguments(parser)


def _positive(text: str) -> int:
    value = int(text)
    if value < 1:
        raise argparse.ArgumentTypeError(f"{text}: expected a whole number of at least 1")
    return value


@dataclass
class LogResult:
    """One log's line of the summary. ``columns`` holds what other parts add (compass health, cross-checks,
    filter counters): name → value, shown after the fixed columns."""

    log: str
    status: str = "ok"  # ok | damaged (read up to the damage) | failed (nothing usable)
    note: str = ""
    duration_s: float = math.nan
    samples: int = 0
    outputs: int = 0
    rms_deg: tuple[float, float, float] = (math.nan, math.nan, math.nan)  # roll, pitch, yaw: ours − autopilot
    p99_deg: tuple[float, float, float] = (math.nan, math.nan, math.nan)
    rejects: int = 0
    columns: dict[str, Any] = field(default_factory=dict)

    def row(self) -> dict[str, Any]:
        fixed = {
            "log": self.log,
            "status": self.status,
            "duration_s": round(self.duration_s, 1),
            "samples": self.samples,
            "outputs": self.outputs,
            **{f"{a}_rms_deg": round(v, 2) for a, v in zip(("roll", "pitch", "yaw"), self.rms_deg, strict=True)},
            **{f"{a}_p99_deg": round(v, 2) for a, v in zip(("roll", "pitch", "yaw"), self.p99_deg, strict=True)},
            "rejects": self.rejects,
        }
        return {**fixed, **self.columns, "note": self.note}


@dataclass(frozen=True)
class Job:
    """One log to replay and where its results go (picklable: it crosses to a worker process)."""

    log: Path
    csv: Path
    plot: Path | None
    config: Config
    imu: int
    mag: int | None
    table: bool  # print the comparison table (one log only)
    message_given: bool = False  # --message: a telemetry log without it fails, not replayed with another


def run(args: argparse.Namespace) -> int:
    overrides = {"input.message": args.message, "input.profile": args.profile, "link.vehicle_system_id": args.system_id}
    config = config_from_args(args, {k: v for k, v in overrides.items() if v is not None})
    jobs = _jobs(args, config)
    if len(jobs) == 1 and jobs[0].table:
        result = replay_log(jobs[0])
        if result.status != "ok":
            raise DataFileError(result.note)
        return 0
    results = replay_all(jobs, args.jobs)
    summary = Path(args.output) / "summary.csv"
    _write_summary(summary, results)
    sys.stdout.write(summary_table(results, config.estimator.method) + "\n")
    bad = [r for r in results if r.status != "ok"]
    if bad:
        raise DataFileError(f"{len(bad)} of {len(results)} logs not fully replayed ({summary}): {bad[0].note}")
    return 0


def _find_logs(names: Iterable[str]) -> list[Path]:
    """The logs named and those in the directories named, each once (a file also inside a directory given)."""
    from mavattitude.link.logs import found_in_folder

    found: dict[Path, Path] = {}
    for name in names:
        path = Path(name)
        if path.is_dir():
            inside = sorted(filter(found_in_folder, path.iterdir()))
            if not inside:
                raise DataFileError(f"{path}: a directory with no .tlog, .bin, .ulg or DataFlash text .log in it")
        elif not path.exists():  # a slip in one name: said before any log is replayed or any output made
            raise DataFileError(f"{path}: no such file or directory")
        else:
            inside = [path]
        for p in inside:
            found.setdefault(p.resolve(), p)
    return list(found.values())


def _output_names(logs: list[Path]) -> list[str]:
    """Each log's name in the output directory: its stem; its whole name where stems repeat (f.bin, f.tlog); and
    the folders above it, as many as it takes, where names repeat too (a/f.tlog, b/f.tlog: a_f.tlog, b_f.tlog),
    so that no log's results overwrite another's."""
    names = [p.stem for p in logs]
    if len(set(names)) < len(names):
        names = [p.name for p in logs]
    folders = [p.resolve().parent.parts for p in logs]
    depth = 0
    while len(set(names)) < len(names):
        depth += 1
        names = [
            "_".join((*parts[max(len(parts) - depth, 0) :], p.name)) for p, parts in zip(logs, folders, strict=True)
        ]
    return names


def _jobs(args: argparse.Namespace, config: Config) -> list[Job]:
    logs = _find_logs(args.logs)
    out = Path(args.output)
    plot = not args.no_plot
    if len(logs) == 1 and out.name.endswith((".csv", ".csv.gz")):
        png = Path(args.plot) if args.plot else Path(str(out).removesuffix(".gz")).with_suffix(".png")
        refuse_overwriting(logs, out, png if plot else None)
        return [Job(logs[0], out, png if plot else None, config, args.imu, args.mag, True, args.message is not None)]
    if out.name.endswith((".csv", ".csv.gz")) and not out.is_dir():
        raise DataFileError(f"-o {out}: {len(logs)} logs write a CSV each and a summary: give a directory")
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise DataFileError(f"{out}: cannot make the output directory: {exc.strerror or exc}") from exc
    return [
        Job(
            p,
            out / f"{name}.csv",
            out / f"{name}.png" if plot else None,
            config,
            args.imu,
            args.mag,
            False,
            args.message is not None,
        )
        for p, name in zip(logs, _output_names(logs), strict=True)
    ]


#: How -j's worker processes start, the same on every Python (the default on Linux is fork up to 3.13,
#: forkserver from 3.14): each from a server process that holds no thread, not a copy of this process, which
#: runs numpy's OpenBLAS thread (a fork copies the locks other threads hold; CPython 3.12+ warns of it) and
#: whatever state the caller left. A worker imports the package itself (~0.35 s of CPU) and logs as the
#: caller does (its level, the command line's format).
WORKER_START_METHOD = "forkserver"


def replay_all(jobs: list[Job], workers: int) -> list[LogResult]:
    progress = Progress("replayed logs", len(jobs) > 1 and sys.stderr.isatty())
    if workers == 1 or len(jobs) == 1:
        results = []
        for job in jobs:
            results.append(replay_log(job))
            progress(len(results), len(jobs))
        return results
    from mavattitude.commands import configure_logging

    level = logging.getLevelName(logging.getLogger().getEffectiveLevel())
    with concurrent.futures.ProcessPoolExecutor(
        max_workers=min(workers, len(jobs)),
        mp_context=multiprocessing.get_context(WORKER_START_METHOD),
        initializer=configure_logging,
        initargs=(level,),
    ) as pool:
        futures = [pool.submit(replay_log, job) for job in jobs]
        for done, _ in enumerate(concurrent.futures.as_completed(futures), start=1):
            progress(done, len(jobs))
        return [f.result() for f in futures]


def replay_log(job: Job) -> LogResult:
    """Replay one log to its CSV (and plot); what went wrong is the result's status and note, not an exception.

    The collector is paused until the log's outputs are written and freed (:mod:`mavattitude.collector`); every
    line logged meanwhile names the log."""
    with collector.paused(), about(str(job.log)):
        return _replay_log(job)


def _replay_log(job: Job) -> LogResult:
    from mavattitude.link.logs import open_log
    from mavattitude.replay import replay

    result = LogResult(str(job.log))
    source = replayed = None
    try:
        progress = Progress(job.log.name) if job.table and sys.stderr.isatty() else None
        source = open_log(job.log, job.config, job.imu, job.mag)
        replayed = replay(source, job.config, progress)
        if replayed.counters.received == 0:
            source, replayed = _with_the_message_it_sent(job, source, replayed, progress)
        telemetry = _telemetry_message(source)
        units_from = _units_from(job.config, telemetry)
        _check_found(str(job.log), telemetry or job.config.input.message, replayed, units_from)
    except MavAttitudeError as exc:
        return dataclasses.replace(result, status="failed", note=str(exc) + _dead_imu_hint(job, source, replayed))
    message = _telemetry_message(source)
    _fill(result, replayed, message or "IMU")
    log.info("%s", result.columns["rate_handling"])
    if message and not replayed.pipeline.compass_seen:  # a .bin's or .ulg's reader said it as it read the log
        log.warning("%s carries no magnetometer reading: %s", message, TILT_ONLY)
    write_outputs(job.csv, replayed.outputs, replayed.covariances)
    log.info("wrote %d attitudes to %s", result.outputs, job.csv)
    damage = getattr(source, "damage", None)
    if damage:
        result.status = "damaged"
        read = "skipped; the other" if damage.startswith("damaged") else "the"  # read past it, or up to it
        where = "" if damage.startswith("damaged") else " before it"
        result.note = f"{job.log}: {damage}: {read} {result.samples} samples{where} replayed, written to {job.csv}"
    if job.config.compass.enabled:
        _compass_columns(replayed.pipeline.compass.figures(), result)
        _compasses_columns(replayed, job, result)
    if replayed.autopilot:
        _compare(replayed, job, result)
    else:
        log.info("no attitude from the autopilot in the log: no comparison")
    return result


def _telemetry_message(source: Any) -> str | None:
    """A telemetry log's IMU message (None: the autopilot's own log, whose IMU records are called IMU)."""
    from mavattitude.link.tlog import TlogSource

    return source.decoder.message if isinstance(source, TlogSource) else None


def _with_the_message_it_sent(job: Job, source: Any, replayed: Any, progress: Any) -> tuple[Any, Any]:
    """A telemetry log whose autopilot sent no ``input.message`` (a PX4's HIGHRES_IMU, a log of SCALED_IMU2
    only): replayed with the first other IMU message of ``input.profile`` it sent, and said; refused naming it
    when ``--message`` asked for the one it lacks. As it was if it sent none of them, or for the autopilot's own
    log."""
    from mavattitude.replay import replay

    wanted = job.config.input.message
    if _telemetry_message(source) is None:
        return source, replayed
    other = _other_imu_source(job, wanted)
    found = _telemetry_message(other)
    if found == wanted:
        return source, replayed
    if job.message_given:
        raise DataFileError(f"{job.log}: no {wanted} from the autopilot; it sent {found}: --message {found}")
    log.info("the autopilot sent no %s: replaying %s, the first IMU message it sent (--message chooses)", wanted, found)
    return other, replay(other, job.config, progress)


def _dead_imu_hint(job: Job, source: Any, replayed: Any) -> str:
    """A telemetry log whose IMU message was refused as an IMU the vehicle lacks (``reports.refused_as_dead_imu``):
    the first other IMU message of ``input.profile`` its autopilot sent, to replay instead, as the service names
    them live; empty otherwise."""
    from mavattitude.reports import refused_as_dead_imu

    message = _telemetry_message(source) if source is not None else None
    if message is None or replayed is None or not refused_as_dead_imu(replayed.pipeline.frontend.counters.rejected):
        return ""
    found = _telemetry_message(_other_imu_source(job, message))
    return f"; it sent {found} too: --message {found}" if found != message else ""


def _other_imu_source(job: Job, message: str) -> Any:
    """The telemetry log opened on the first IMU message of ``input.profile`` other than ``message`` that its
    autopilot sent (on ``message`` itself when it sent none of them)."""
    from mavattitude.link.logs import open_log

    others = [m for m in get_profile(job.config.input.profile).messages if m != message]
    return open_log(job.log, job.config, job.imu, job.mag, first_of=others)


def _heading(outputs: list[Any]) -> str:
    """Where the outputs' heading came from: the magnetometer, or nowhere (roll and pitch only) for some or all."""
    unknown = sum(bool(o.flags & SampleFlag.NO_HEADING) for o in outputs)
    if not unknown:
        return "magnetometer"
    if unknown == len(outputs):
        return "unknown: no magnetometer"
    return f"unknown in {unknown} of {len(outputs)} outputs (no magnetometer reading)"


def _fill(result: LogResult, replayed: Any, imu_name: str) -> None:
    pipeline = replayed.pipeline.counters
    frontend = pipeline.frontend
    result.columns["heading"] = _heading(replayed.outputs)
    result.columns["rate_handling"] = rate_handling(
        replayed.pipeline.config, imu_name, replayed.input_rate_hz, frontend.per_sample, frontend.accepted
    )
    result.samples = replayed.counters.received
    result.outputs = len(replayed.outputs)
    result.duration_s = replayed.last_sample_s - replayed.first_sample_s
    result.columns["reference"] = replayed.pipeline.magref.describe()  # the magnetic reference(s), in order
    result.columns["units"] = "; ".join(f"{f.sensor} reads {f.reads}" for f in replayed.pipeline.units.findings)
    trim = replayed.pipeline.frontend.settings.trim_rad
    result.columns["trim_deg"] = ", ".join(f"{math.degrees(a):.2f}" for a in trim) if any(trim) else ""
    result.rejects = (
        sum(replayed.counters.rejected.values())
        + sum(pipeline.frontend.rejected.values())
        + sum(pipeline.rejected.values())
    )
    twice = arriving_twice(replayed.sample_times_s, imu_name)
    if twice is not None:  # recorded so: the ground station heard the vehicle by two routes
        log.warning("%s", twice)
    # The estimator's own counters: the fused filter's and its learnt offset, a snapshot's noise measured at rest.
    own, prefix = pipeline.estimator(), pipeline.estimator_prefix
    result.columns |= {f"{prefix}.{k}": round(v, 2) if isinstance(v, float) else v for k, v in own.items()}
    if "tilt_only_updates" in own:  # the fused filter's compass
        updates = own["updates"]
        result.columns["heading_from_compass"] = round(1.0 - own["tilt_only_updates"] / updates, 3) if updates else ""
        lost = heading_lost(own)
        if lost:
            log.warning("%s", lost)


def _compass_columns(figures: Any, result: LogResult) -> None:
    """The compass monitor's figures in the summary (docs/vehicle.md)."""
    result.columns |= {
        "compass_dip_deg": round(figures.first_dip_deg, 1),  # the first minute's mean
        "compass_dip_expected_deg": round(figures.expected_dip_deg, 1),
        "compass_field_ratio": round(figures.first_field_ratio, 3),
        "compass_warnings": figures.warnings,
    }


def _compasses_columns(replayed: Any, job: Job, result: LogResult) -> None:
    """Which magnetometer was replayed and why, and every one's verdict (docs/vehicle.md); each one found off is
    said once in the log."""
    result.columns["compass"] = replayed.compass_used
    if replayed.unused_compass is not None:
        instance, name, value = replayed.unused_compass
        result.columns["compass"] += f"; unused by the autopilot ({name} {value:g})"
        log.warning("%s", compass_unused_warning(instance, name, value, "--mag I replays another the log holds"))
    if not replayed.compasses:
        return
    unused = {k: f" (unused by the autopilot: {why})" for k, why in replayed.unused_compasses.items()}
    result.columns["compasses"] = "; ".join(
        f"{j.instance} {j.verdict()}{unused.get(j.instance, '')}" for j in replayed.compasses
    )
    for judged in replayed.compasses:
        warned = next((e for e in judged.events if e.inconsistent), None)
        if warned is not None:
            figures = warned.figures.describe() + unused.get(judged.instance, "")
            log.warning("magnetometer %d: t=%.1f s: %s", judged.instance, warned.time_s, figures)


def _report_cross_check(check: Any, events: list[Any], job: Job, result: LogResult) -> None:
    """The service's cross-check over the log: its warnings (vehicle time) and figures, as live."""
    for event in events:
        if event.disagree:
            log.warning(
                "t=%.1f s: our attitude and the autopilot's differ by %.1f° for %g s",
                event.time_s,
                event.total_deg,
                job.config.crosscheck.hold_s,
            )
        else:
            log.info("t=%.1f s: our attitude agrees with the autopilot's again", event.time_s)
    rms_deg = round(check.rms_total_deg, 2)
    result.columns |= {
        "xc_pairs": check.pairs,
        "xc_unjudged": check.unjudged,
        "xc_rms_deg": rms_deg,
        "xc_warnings": check.warnings,
    }


def _units_from(config: Config, telemetry: str | None) -> Callable[[str], str]:
    """What to check for a units finding (:mod:`mavattitude.sensors.unitcheck`): the scales a telemetry log's IMU
    message is read with (``--profile``); an autopilot's own log records its units itself."""
    if telemetry is None:
        return lambda sensor: "the log: its format records its units, so a reader misread them (please report it)"
    return lambda sensor: profile_units(config, telemetry, sensor, "--profile")


def _check_found(path: str, message: str, result: Any, units_from: Callable[[str], str]) -> None:
    if result.counters.ignored:
        log.info(
            "ignored %d message(s) not from the autopilot (other system or component, or before its HEARTBEAT)",
            result.counters.ignored,
        )
    others = sorted(result.counters.other_autopilots)
    if others and result.vehicle is not None:
        log.info(
            "the log holds other autopilots than system %d, component %d, the one replayed: %s (--system-id %d "
            "replays %s)",
            *result.vehicle,
            ", ".join(f"system {s}, component {c}" for s, c in others),
            others[0][0],
            "it" if len(others) == 1 else "the first",
        )
    if result.vehicle is None:
        if not result.counters.ignored:
            raise DataFileError(f"{path}: not one MAVLink message could be read from it")
        raise DataFileError(
            f"{path}: no autopilot HEARTBEAT (from link.vehicle_system_id, if set) among its "
            f"{result.counters.ignored} MAVLink messages: none of them is taken to be the vehicle's"
        )
    if result.counters.received == 0:
        raise DataFileError(f"{path}: no {message} from the autopilot (set input.message, or --message)")
    summarise(result.pipeline, result.counters.received, path, result.compass, units_from)


def summary_table(results: list[LogResult], method: str) -> str:
    """The summary as aligned text: one line per log, then the note on snapshot methods."""
    names, rows = _summary_rows(results)
    text = [[str(row.get(n, "")) for n in names] for row in rows]
    widths = [max(len(n), *(len(t[i]) for t in text)) for i, n in enumerate(names)]
    lines = ["  ".join(n.ljust(w) for n, w in zip(names, widths, strict=True)).rstrip()]
    lines += ["  ".join(v.ljust(w) for v, w in zip(t, widths, strict=True)).rstrip() for t in text]
    if METHODS[method].snapshot:
        lines.append(SNAPSHOT_NOTE.format(method=method))
    return "\n".join(lines)


def _summary_rows(results: list[LogResult]) -> tuple[list[str], list[dict[str, Any]]]:
    """Every column any log has (a failed log has no compass or cross-check columns), and the rows."""
    rows = [r.row() for r in results]
    return list(dict.fromkeys(k for row in rows for k in row)), rows


def _write_summary(path: Path, results: list[LogResult]) -> None:
    names, rows = _summary_rows(results)
    with path.open("w", encoding="utf-8", newline="") as f:
        writer = csv.DictWriter(f, names, lineterminator="\n")
        writer.writeheader()
        writer.writerows(rows)


def comparison_table(diff_deg: np.ndarray, check: Any, judged: bool = True) -> str:
    """The differences' statistics, how many were compared, and with ``judged`` (the cross-check on) what it
    judged and warned of."""
    lines = [f"{'ours − autopilot (deg)':<24}{'mean':>9}{'rms':>9}{'p95 |.|':>9}{'max |.|':>9}"]
    for name, d in zip(("roll", "pitch", "yaw", "total angle"), diff_deg.T, strict=True):
        d = d[np.isfinite(d)]  # yaw: none where ours has no heading
        if not len(d):
            lines.append(f"{name:<24}{'(ours has no heading: no magnetometer)':>36}")
            continue
        a = np.abs(d)
        lines.append(f"{name:<24}{d.mean():9.3f}{np.sqrt(np.mean(d**2)):9.3f}{np.percentile(a, 95):9.3f}{a.max():9.3f}")
    compared = f"{len(diff_deg)} autopilot attitudes compared with ours (interpolated to their times)"
    lines.append(f"{compared}: {_pairing(check)}")
    if judged:
        moving = f" ({check.unjudged} not: ours a snapshot while the vehicle moved)" if check.unjudged else ""
        lines.append(f"cross-check: {check.pairs - check.unjudged} judged{moving}, {check.warnings} warning(s)")
    return "\n".join(lines)


def _rms_p99(diff_deg: np.ndarray) -> tuple[float, float]:
    """RMS and 99th percentile of |d| over the finite values (NaN when none: a yaw without a heading)."""
    d = diff_deg[np.isfinite(diff_deg)]
    if not len(d):
        return math.nan, math.nan
    return float(np.sqrt(np.mean(d**2))), float(np.percentile(np.abs(d), 99.0))


def _pairing(check: Any) -> str:
    """How many of the autopilot's attitudes inside our output span were compared, and why the others were not."""
    inside = check.pairs + check.missed
    text = f"{check.pairs} of the {inside} inside our output span ({100.0 * check.share:.1f} %)"
    return text + (f"; not compared: {_reasons(check.unpaired)}" if check.missed else "")


def _reasons(unpaired: Any) -> str:
    """The cross-check's misses by reason, ``gap 3, reset 1`` (``outside`` our span is no miss)."""
    return ", ".join(f"{k} {v}" for k, v in sorted(unpaired.items()) if k != "outside" and v)


def _compare(replayed: Any, job: Job, result: LogResult) -> None:
    """Ours against the autopilot's attitude, paired as the service's cross-check pairs them
    (:mod:`mavattitude.estimation.crosscheck`): at each autopilot attitude's time, ours interpolated between the
    two outputs around it. The summary's RMS and p99 of ours minus theirs (yaw where ours has a heading), the
    table, the plot with the compass's and the cross-check's verdicts, and the cross-check's own figures and
    warnings when it is enabled."""
    check, pairs, events = replayed.cross_check()
    if job.config.crosscheck.enabled:
        _report_cross_check(check, events, job, result)
    result.columns |= {
        "compared": check.pairs,
        "compared_pct": round(100.0 * check.share, 1),
        "not_compared": _reasons(check.unpaired),
    }
    if check.missed:
        log.info("%s", _pairing(check))
    if not pairs:
        offset_s = check.unpairable_offset_s()  # as the service says it: its clock another than our input's
        apart = "" if offset_s is None else f" (its clock {offset_s:+.0f} s from our IMU's: stamped with Unix time?)"
        log.warning("no autopilot attitude falls within our output times: no comparison%s", apart)
        return
    t = np.array([d.time_s for d in pairs])
    diff = np.array([(d.roll_deg, d.pitch_deg, d.yaw_deg, d.total_deg) for d in pairs])
    stats = [_rms_p99(diff[:, i]) for i in range(3)]
    result.rms_deg = tuple(rms for rms, _ in stats)  # type: ignore[assignment]
    result.p99_deg = tuple(p99 for _, p99 in stats)  # type: ignore[assignment]
    if job.table:
        method = job.config.estimator.method
        note = SNAPSHOT_NOTE.format(method=method) + "\n" if METHODS[method].snapshot else ""
        sys.stdout.write(comparison_table(diff, check, job.config.crosscheck.enabled) + "\n" + note)
    if job.plot is None:
        return
    verdicts = Verdicts(
        compass=[(e.time_s, e.inconsistent) for e in replayed.compass],
        crosscheck=[(e.time_s, e.disagree) for e in events],
        unjudged=[(d.time_s, not d.judged) for d in pairs],
        threshold_deg=job.config.crosscheck.threshold_deg if job.config.crosscheck.enabled else None,
    )
    ours, autopilot = replayed.output_array(), replayed.autopilot_array()  # the plot's own
    q_ref = autopilot[np.searchsorted(autopilot[:, 0], t), 1:5]
    ours_deg = np.degrees(euler_from_quat(ours[:, 1:5]))
    ours_deg[~replayed.heading(), 2] = np.nan  # no heading: no yaw drawn
    try:
        title = f"{job.log.name}: mavattitude ({job.config.estimator.method}) vs the autopilot's attitude"
        _save(comparison_figure(title, ours[:, 0], ours_deg, t, q_ref, diff, verdicts), job.plot)
    except ImportError:
        log.warning("matplotlib is not installed (pip install mavattitude[plot]): no plot written")
        return
    log.info("wrote the comparison plot %s", job.plot)


@dataclass(frozen=True)
class Verdicts:
    """What a comparison plot marks: the compass monitor's and the cross-check's verdict changes, ``(time_s,
    off)`` each in time order (off: the compass judged off, the cross-check warning), where the cross-check did
    not judge (``(time_s, True)`` from a pair it did not, ``(time_s, False)`` from one it did), and the
    cross-check's threshold (None: the cross-check is off)."""

    compass: list[tuple[float, bool]] = field(default_factory=list)
    crosscheck: list[tuple[float, bool]] = field(default_factory=list)
    unjudged: list[tuple[float, bool]] = field(default_factory=list)
    threshold_deg: float | None = None


def _save(fig: Any, path: Path) -> None:
    import matplotlib.pyplot as plt

    fig.savefig(path, dpi=100)
    plt.close(fig)


def comparison_figure(
    title: str,
    ours_t: np.ndarray,
    ours_deg: np.ndarray,
    t: np.ndarray,
    q_ref: np.ndarray,
    diff: np.ndarray,
    verdicts: Verdicts | None = None,
) -> Any:
    """Roll, pitch, yaw of ours (``ours_deg`` at ``ours_t``; a yaw NaN where there is no heading) and the
    autopilot's (``q_ref`` at ``t``), the angle between (``diff[:, 3]``), and the verdicts: shaded where the
    compass was judged off (every panel) and where the cross-check warned (with its threshold on the last panel),
    and a bar along the last panel's foot where it did not judge.

    Each line is enveloped to a few thousand points (a long log's 250 000 were a solid band) with its yaw
    wraps broken; ours is drawn wide and pale under the autopilot's thin line, so both show where they agree.
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from mavattitude.plotting import angle_series, envelope, spans

    verdicts = verdicts or Verdicts()
    ref_deg = np.degrees(euler_from_quat(q_ref))
    fig, axes = plt.subplots(4, 1, sharex=True, figsize=(11, 9))
    for i, name in enumerate(("roll", "pitch", "yaw")):
        axes[i].plot(*angle_series(ours_t, ours_deg[:, i]), lw=2.5, alpha=0.45, color="C0", label="mavattitude")
        axes[i].plot(*angle_series(t, ref_deg[:, i]), lw=0.7, color="k", label="autopilot ATTITUDE")
        axes[i].set_ylabel(f"{name} (deg)")
    axes[3].plot(*envelope(t, diff[:, 3]), lw=0.7, color="C3", label="angle between")
    axes[3].set_ylabel("angle between (deg)")
    axes[3].set_xlabel("vehicle time (s)")
    end_s = float(max(ours_t[-1], t[-1]))
    compass, warned = spans(verdicts.compass, end_s), spans(verdicts.crosscheck, end_s)
    for ax in axes:
        ax.grid(True, lw=0.3)
        for k, (a, b) in enumerate(compass):
            ax.axvspan(a, b, color="C1", alpha=0.2, lw=0, label="compass judged off" if k == 0 else None)
    for k, (a, b) in enumerate(warned):
        axes[3].axvspan(a, b, color="C3", alpha=0.15, lw=0, label="cross-check warned" if k == 0 else None)
    for k, (a, b) in enumerate(spans(verdicts.unjudged, end_s)):
        label = "not judged: vehicle moving" if k == 0 else None
        axes[3].axvspan(a, b, ymin=0.0, ymax=0.04, color="0.4", lw=0, label=label)
    if verdicts.threshold_deg is not None:
        axes[3].axhline(verdicts.threshold_deg, color="C3", lw=0.8, ls="--", label="cross-check threshold")
    axes[0].legend(loc="upper right", fontsize=8)
    axes[3].legend(loc="upper right", fontsize=8)
    rms = np.sqrt(np.mean(diff[:, 3] ** 2))
    said = f"compass judged off {len(compass)}×, cross-check warned {len(warned)}×"
    unjudged = sum(on for _, on in verdicts.unjudged)
    if unjudged:
        said += f" ({100.0 * (1.0 - unjudged / len(verdicts.unjudged)):.0f} % judged)"
    axes[0].set_title(f"{title}\nangle between: {rms:.2f}° RMS over {len(t)} comparisons; {said}", fontsize=10)
    # fixed margins for the fixed size: what tight_layout finds for these labels, without the extra draw it
    # takes to find them (~0.4 s of a short log's replay)
    fig.subplots_adjust(left=0.075, right=0.985, bottom=0.06, top=0.93, hspace=0.1)
    return fig
