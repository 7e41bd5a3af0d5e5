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
import logging
import sys
from pathlib import Path
from typing import Any

import numpy as np

from mavattitude.commands._offline import add_config_arguments, config_from_args, output_row, summarise, write_outputs
from mavattitude.errors import DataFileError
from mavattitude.sensors.units import MESSAGES, PROFILE_NAMES

NAME = "replay"
HELP = "the service's pipeline over a flight log (.tlog, DataFlash .bin, ULog .ulg): attitude CSV, vs the autopilot's"

log = logging.getLogger(__name__)

# Autopilot attitudes further apart than this are not interpolated between.
MAX_ATTITUDE_GAP_S = 0.5


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.formatter_class = argparse.RawDescriptionHelpFormatter
    parser.description = __doc__.split("\n", 2)[2]
    parser.add_argument(
        "log",
        help="flight log: telemetry (.tlog), ArduPilot DataFlash (.bin) or PX4 ULog (.ulg); format from its content",
    )
    parser.add_argument("-o", "--output", required=True, help="output CSV (gzip-compressed if it ends in .gz)")
    parser.add_argument(
        "--message", choices=MESSAGES, type=str.upper, help="IMU message to read (config default: RAW_IMU)"
    )
    parser.add_argument("--profile", choices=PROFILE_NAMES, help="unit profile (config default: ardupilot)")
    parser.add_argument(
        "--plot", metavar="PNG", help="comparison plot file (default: the output's name with .png); --no-plot: none"
    )
    parser.add_argument("--no-plot", action="store_true", help="write no plot")
    add_config_arguments(parser)


def run(args: argparse.Namespace) -> int:
    from mavattitude.link.logs import open_log
    from mavattitude.replay import replay

    overrides = {"input.message": args.message, "input.profile": args.profile}
    config = config_from_args(args, {k: v for k, v in overrides.items() if v is not None})
    source = open_log(args.log, config)
    result = replay(source, config)
    _check_found(args.log, config.input.message, result)
    summarise(result.pipeline, result.counters.received, args.log)
    ours = result.output_array()
    write_outputs(args.output, (output_row(o.time_s, o.q, o.iterations, o.converged) for o in result.outputs))
    log.info("wrote %d attitudes to %s", len(ours), args.output)
    if result.autopilot:
        _compare(ours, result.autopilot_array(), args)
    else:
        log.info("%s holds no ATTITUDE from the autopilot: no comparison", args.log)
    return 0


def _check_found(path: str, message: str, result: Any) -> None:
    if result.counters.ignored:
        log.info(
            "%s: ignored %d message(s) not from the autopilot (other system or component, or before its HEARTBEAT)",
            path,
            result.counters.ignored,
        )
    if result.vehicle is None:
        raise DataFileError(f"{path}: no autopilot HEARTBEAT (from link.vehicle_system_id, if set)")
    if result.counters.received == 0:
        raise DataFileError(f"{path}: no {message} from the autopilot (set input.message, or --message)")
    if result.pipeline.waiting_for_reference:
        raise DataFileError(
            f"{path}: reference.magnetic is auto but the log holds no position with a fix: give --declination "
            "DEG --inclination DEG or --mag-ref-ned N E D"
        )


def compare(ours: np.ndarray, autopilot: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Ours (rows ``t_s, qw, qx, qy, qz``) against the autopilot's attitude (rows ``t_s, qw, qx, qy, qz``).

    Returns the times compared, the autopilot's quaternions there, and our-minus-theirs differences in
    degrees ``(roll, pitch, yaw wrapped to ±180, total angle)``, at our output times that fall between two
    autopilot attitudes at most ``MAX_ATTITUDE_GAP_S`` apart.
    """
    from mavattitude.estimation.conventions import angle_between, euler_from_quat

    t_ap = autopilot[:, 0]
    q_ap = autopilot[:, 1:5]
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
    """Roll, pitch, yaw of ours (rows ``t_s, qw, qx, qy, qz``) and the autopilot's, and the angle between."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from mavattitude.estimation.conventions import euler_from_quat

    ref_deg = np.degrees(euler_from_quat(q_ref))
    ours_deg = np.degrees(euler_from_quat(ours[:, 1:5]))
    fig, axes = plt.subplots(4, 1, sharex=True, figsize=(10, 9))
    for i, name in enumerate(("roll", "pitch", "yaw")):
        axes[i].plot(ours[:, 0], ours_deg[:, i], lw=0.8, label="mavattitude")
        axes[i].plot(t, ref_deg[:, i], lw=0.8, label="autopilot ATTITUDE")
        axes[i].set_ylabel(f"{name} (deg)")
    axes[0].legend(loc="upper right")
    axes[3].plot(t, diff[:, 3], lw=0.8, color="k")
    axes[3].set_ylabel("difference (deg)")
    axes[3].set_xlabel("vehicle time (s)")
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)
