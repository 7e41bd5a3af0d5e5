"""`mavattitude replay LOG.tlog -o OUT.csv`: the service's pipeline, offline, over a telemetry log.

The log's IMU messages (input.message, decoded with input.profile) go through the same pipeline as the
service; the attitude is written as CSV (the columns of `mavattitude solve`). Like the service, replay
follows one autopilot: link.vehicle_system_id, or (0) the first autopilot HEARTBEAT in the log; messages
from other systems or components are skipped. With reference.magnetic auto, the World Magnetic Model is
evaluated at the log's GLOBAL_POSITION_INT / GPS_RAW_INT positions, on the log's date.

Where the log holds the autopilot's own ATTITUDE, a comparison table (ours minus the autopilot's: roll,
pitch, yaw and total angle, degrees) is printed, and a PNG plot written (needs matplotlib:
pip install mavattitude[plot]; without it the plot is skipped with a warning).
"""

from __future__ import annotations

import argparse
import datetime as dt
import logging
import sys
from collections import Counter
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from mavattitude.commands._offline import add_config_arguments, config_from_args, output_row, summarise, write_outputs
from mavattitude.config import MESSAGES, PROFILES
from mavattitude.errors import DataFileError, SensorError
from mavattitude.link.connection import MavlinkLink

NAME = "replay"
HELP = "the service's pipeline over a telemetry log (.tlog): attitude CSV, compared with the autopilot's"

log = logging.getLogger(__name__)

POSITION_MESSAGES = ("GLOBAL_POSITION_INT", "GPS_RAW_INT")
# Autopilot attitudes further apart than this are not interpolated between.
MAX_ATTITUDE_GAP_S = 0.5


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.formatter_class = argparse.RawDescriptionHelpFormatter
    parser.description = __doc__.split("\n", 2)[2]
    parser.add_argument("log", help="telemetry log (.tlog), as MAVProxy or a ground station records it")
    parser.add_argument("-o", "--output", required=True, help="output CSV (gzip-compressed if it ends in .gz)")
    parser.add_argument(
        "--message", choices=MESSAGES, type=str.upper, help="IMU message to read (config default: RAW_IMU)"
    )
    parser.add_argument("--profile", choices=PROFILES, help="unit profile (config default: ardupilot)")
    parser.add_argument(
        "--plot", metavar="PNG", help="comparison plot file (default: the output's name with .png); --no-plot: none"
    )
    parser.add_argument("--no-plot", action="store_true", help="write no plot")
    add_config_arguments(parser)


@dataclass
class LogContents:
    """What replay gathered from the log besides the outputs."""

    attitude: list[tuple[float, float, float, float]] = field(default_factory=list)  # t_s, roll, pitch, yaw (rad)
    skipped: Counter[str] = field(default_factory=Counter)
    imu_messages: int = 0
    autopilot: tuple[int, int] | None = None


def run(args: argparse.Namespace) -> int:
    from mavattitude.link.tlog import read_messages
    from mavattitude.pipeline import AttitudePipeline
    from mavattitude.sensors.units import decode, decode_position, get_profile

    overrides = {"input.message": args.message, "input.profile": args.profile}
    config = config_from_args(args, {k: v for k, v in overrides.items() if v is not None})
    profile = get_profile(config.input.profile, config.input.custom)
    pipeline = AttitudePipeline(config)
    message = config.input.message
    contents = LogContents()
    rows: list[list[str]] = []
    wanted = {message, "HEARTBEAT", "ATTITUDE", *POSITION_MESSAGES}
    for msg in read_messages(args.log, wanted):
        kind = msg.get_type()
        if not _from_autopilot(msg, contents, config.link.vehicle_system_id):
            continue
        if kind == message:
            contents.imu_messages += 1
            try:
                sample = decode(msg, profile)
            except SensorError as exc:
                contents.skipped[f"undecodable {kind}"] += 1
                log.debug("%s", exc)
                continue
            rows += [output_row(o.time_s, o.q, o.iterations, o.converged) for o in pipeline.push(sample)]
        elif kind == "ATTITUDE":
            contents.attitude.append((msg.time_boot_ms * 1e-3, msg.roll, msg.pitch, msg.yaw))
        elif kind in POSITION_MESSAGES and config.reference.magnetic.mode == "auto":
            position = decode_position(msg)
            if position is not None:
                when = dt.datetime.fromtimestamp(msg._timestamp, dt.timezone.utc).date()
                pipeline.set_position(position.lat_deg, position.lon_deg, position.alt_m, when)
    _check_found(args.log, message, contents, pipeline)
    summarise(pipeline, contents.imu_messages, args.log)
    write_outputs(args.output, rows)
    log.info("wrote %d attitudes to %s", len(rows), args.output)
    if contents.attitude:
        _compare(np.array([[float(v) for v in r] for r in rows]), np.array(contents.attitude), args)
    else:
        log.info("%s holds no ATTITUDE from the autopilot: no comparison", args.log)
    return 0


def _from_autopilot(msg: Any, contents: LogContents, system_id: int) -> bool:
    """Lock onto the autopilot as the service does; True for a message from it."""
    source = (msg.get_srcSystem(), msg.get_srcComponent())
    if contents.autopilot is None:
        if MavlinkLink.is_autopilot_heartbeat(msg) and system_id in (0, source[0]):
            contents.autopilot = source
            log.info("following the autopilot at system %d, component %d", *source)
        elif msg.get_type() != "HEARTBEAT":
            contents.skipped["before the autopilot's HEARTBEAT"] += 1
        return False
    if source != contents.autopilot:
        contents.skipped["other system or component"] += 1
        return False
    return True


def _check_found(path: str, message: str, contents: LogContents, pipeline: Any) -> None:
    for reason, count in sorted(contents.skipped.items()):
        log.info("%s: skipped %d message(s): %s", path, count, reason)
    if contents.autopilot is None:
        raise DataFileError(f"{path}: no autopilot HEARTBEAT (from link.vehicle_system_id, if set)")
    if contents.imu_messages == 0:
        raise DataFileError(f"{path}: no {message} from the autopilot (set input.message, or --message)")
    if pipeline.waiting_for_reference:
        raise DataFileError(
            f"{path}: reference.magnetic is auto but the log holds no position with a fix: give --declination "
            "DEG --inclination DEG or --mag-ref-ned N E D"
        )


def compare(ours: np.ndarray, autopilot: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Ours (rows ``t_s, qw, qx, qy, qz, …``) against the autopilot's ATTITUDE (``t_s, roll, pitch, yaw``, rad).

    Returns the times compared, the autopilot's quaternions there, and our-minus-theirs differences in
    degrees ``(roll, pitch, yaw wrapped to ±180, total angle)``, at our output times that fall between two
    autopilot attitudes at most ``MAX_ATTITUDE_GAP_S`` apart.
    """
    from mavattitude.estimation.conventions import angle_between, euler_from_quat, quat_from_euler

    t_ap = autopilot[:, 0]
    q_ap = quat_from_euler(autopilot[:, 1], autopilot[:, 2], autopilot[:, 3])
    t = ours[:, 0]
    after = np.searchsorted(t_ap, t)
    inside = (after > 0) & (after < len(t_ap))
    after = np.clip(after, 1, len(t_ap) - 1)
    inside &= (t_ap[after] - t_ap[after - 1]) <= MAX_ATTITUDE_GAP_S
    t, q, after = t[inside], ours[inside, 1:5], after[inside]
    q0, q1 = q_ap[after - 1], q_ap[after]
    q1 = np.where(np.sum(q0 * q1, axis=1, keepdims=True) < 0, -q1, q1)  # the shorter way round
    frac = ((t - t_ap[after - 1]) / (t_ap[after] - t_ap[after - 1]))[:, None]
    q_ref = q0 + (q1 - q0) * frac
    q_ref /= np.linalg.norm(q_ref, axis=1, keepdims=True)
    diff = np.degrees(euler_from_quat(q) - euler_from_quat(q_ref))
    diff[:, 2] = (diff[:, 2] + 180.0) % 360.0 - 180.0
    total = np.degrees(angle_between(q, q_ref))
    return t, q_ref, np.column_stack([diff, total])


def comparison_table(diff_deg: np.ndarray) -> str:
    lines = [f"{'ours − autopilot (deg)':<24}{'mean':>9}{'rms':>9}{'p95 |.|':>9}{'max |.|':>9}"]
    for name, d in zip(("roll", "pitch", "yaw", "total angle"), diff_deg.T, strict=True):
        a = np.abs(d)
        lines.append(f"{name:<24}{d.mean():9.3f}{np.sqrt(np.mean(d**2)):9.3f}{np.percentile(a, 95):9.3f}{a.max():9.3f}")
    lines.append(f"{len(diff_deg)} output samples compared with the autopilot's ATTITUDE")
    return "\n".join(lines)


def _compare(ours: np.ndarray, autopilot: np.ndarray, args: argparse.Namespace) -> None:
    t, q_ref, diff = compare(ours, autopilot) if len(ours) else (np.empty(0), np.empty((0, 4)), np.empty((0, 4)))
    if len(t) == 0:
        log.warning("no output sample falls within the autopilot's ATTITUDE times: no comparison")
        return
    sys.stdout.write(comparison_table(diff) + "\n")
    if args.no_plot:
        return
    plot = Path(args.plot) if args.plot else Path(args.output.removesuffix(".gz")).with_suffix(".png")
    try:
        _plot(plot, ours, t, q_ref, diff)
    except ImportError:
        log.warning("matplotlib is not installed (pip install mavattitude[plot]): no plot written")
        return
    log.info("wrote the comparison plot %s", plot)


def _plot(path: Path, ours: np.ndarray, t: np.ndarray, q_ref: np.ndarray, diff: np.ndarray) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from mavattitude.estimation.conventions import euler_from_quat

    ref_deg = np.degrees(euler_from_quat(q_ref))
    fig, axes = plt.subplots(4, 1, sharex=True, figsize=(10, 9))
    for i, name in enumerate(("roll", "pitch", "yaw")):
        axes[i].plot(ours[:, 0], ours[:, 5 + i], lw=0.8, label="mavattitude")
        axes[i].plot(t, ref_deg[:, i], lw=0.8, label="autopilot ATTITUDE")
        axes[i].set_ylabel(f"{name} (deg)")
    axes[0].legend(loc="upper right")
    axes[3].plot(t, diff[:, 3], lw=0.8, color="k")
    axes[3].set_ylabel("difference (deg)")
    axes[3].set_xlabel("vehicle time (s)")
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)
