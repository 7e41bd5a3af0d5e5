"""Whose attitude was off when the cross-check warned: ours and the autopilot's, held against the simulator's truth.

    .venv/bin/python tools/sitl_truth.py LOG.BIN|LOG.tlog... [--config FILE] [--method M]

An ArduPilot SITL DataFlash log records the simulated vehicle's true attitude (``SIM``: its quaternion, at 10 Hz,
and its position), and its telemetry log too (``SIMSTATE``, at the stream's rate, on the ground station's
receipt time, put on the vehicle's clock by ATTITUDE's: good to tens of ms, so in a fast turn by a degree or
more). Each log is replayed as ``mavattitude replay`` replays it (the same config, the same
cross-check), and at every truth record ours and the autopilot's ``ATT`` (each interpolated to its time) are
held against the truth, in the north both estimators head by: true north from the log's first 3D GPS fix (the
autopilot's ``COMPASS_AUTODEC``, our WMM field), before it magnetic north turned by ``COMPASS_DEC``, the truth
turned from true to that by the WMM's declination at the simulated position (the simulator's field is the
WMM's, to about 0.4°). Printed per log: both angles from the truth over the flight and where the cross-check
judged, and for each cross-check warning both over the hold that raised it: whose error it was. A telemetry log
begins at the autopilot's boot: its figures hold its start-up too (its yaw before its EKF aligned, up to 120°
off).
"""

from __future__ import annotations

import argparse
import datetime as dt
import math
import sys
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from pymavlink import DFReader, mavutil

from mavattitude.config import Config, load_config
from mavattitude.estimation.conventions import angle_between, quat_from_euler, quat_multiply
from mavattitude.estimation.crosscheck import interpolate
from mavattitude.link.logs import open_log
from mavattitude.replay import Replayed, replay
from mavattitude.sensors.magref import clamp_to_model, wmm_field_ned_uT

GPS_3D_FIX = 3  # DataFlash GPS Status: 3 is a 3D fix
TRUTH_FRAME_ERROR_DEG = 0.4  # the simulator's field against the WMM's declination, measured on the shared logs


@dataclass(frozen=True)
class Truth:
    t_s: np.ndarray  # the truth's times, the vehicle's clock
    q: np.ndarray  # body → NED, turned to the north both estimators head by
    north: str


@dataclass
class _Read:
    """What a log says of the truth: rows ``t_s, qw, qx, qy, qz`` (true north), and what sets the heading's north."""

    rows: list[tuple[float, ...]] = field(default_factory=list)
    fixes: list[tuple[float, bool]] = field(default_factory=list)  # each GPS record's time, and whether a 3D fix
    declination_deg: float = 0.0
    position: tuple[float, float, float] | None = None


def _read_dataflash(path: Path) -> _Read:
    """SIM records (their quaternion, at 10 Hz), GPS Status, PARM COMPASS_DEC."""
    log, read = DFReader.DFReader_binary(str(path)), _Read()
    while (m := log.recv_match(type=["SIM", "GPS", "PARM"])) is not None:
        kind = m.get_type()
        if kind == "SIM":
            read.rows.append((m.TimeUS * 1e-6, m.Q1, m.Q2, m.Q3, m.Q4))
            read.position = read.position or (m.Lat, m.Lng, m.Alt)
        elif kind == "GPS":
            read.fixes.append((m.TimeUS * 1e-6, m.Status >= GPS_3D_FIX))
        elif m.Name == "COMPASS_DEC":
            read.declination_deg = math.degrees(m.Value)
    return read


def _read_tlog(path: Path) -> _Read:
    """SIMSTATE messages (Euler angles; no time of their own: the ground station's receipt time, put on the vehicle's
    clock by the median offset of ATTITUDE's, sent in the same stream: tens of ms), GPS_RAW_INT's fix,
    PARAM_VALUE COMPASS_DEC."""
    # SIMSTATE is ArduPilot's: its dialect named, whatever another caller left as pymavlink's process-wide one
    log, read = mavutil.mavlink_connection(str(path), dialect="ardupilotmega"), _Read()
    received, offsets, fixes = [], [], []  # on the ground station's clock
    while (m := log.recv_match(type=["SIMSTATE", "ATTITUDE", "GPS_RAW_INT", "PARAM_VALUE"])) is not None:
        kind = m.get_type()
        if kind == "SIMSTATE":
            received.append((m._timestamp, *quat_from_euler(m.roll, m.pitch, m.yaw)))
            read.position = read.position or (m.lat * 1e-7, m.lng * 1e-7, 0.0)
        elif kind == "ATTITUDE":
            offsets.append(m._timestamp - m.time_boot_ms * 1e-3)
        elif kind == "GPS_RAW_INT":
            fixes.append((m._timestamp, m.fix_type >= GPS_3D_FIX))
        elif m.param_id == "COMPASS_DEC":
            read.declination_deg = math.degrees(m.param_value)
    offset_s = float(np.median(offsets)) if offsets else 0.0
    read.rows = [(t - offset_s, *q) for t, *q in received]
    read.fixes = [(t - offset_s, fix) for t, fix in fixes]
    return read


def _first_fix_s(fixes: list[tuple[float, bool]]) -> float:
    """When both estimators start heading by true north: the first GPS record with a 3D fix (-inf when the log's
    first has one: the log began after it, as a DataFlash log begins at arming; inf without one)."""
    if fixes and fixes[0][1]:
        return -math.inf
    return next((t for t, fix in fixes if fix), math.inf)


def read_truth(path: Path) -> Truth:
    """The log's true attitudes turned to the north the autopilot and we head by (the module docstring)."""
    read = _read_tlog(path) if path.suffix.lower() == ".tlog" else _read_dataflash(path)
    if not read.rows:
        raise SystemExit(f"{path}: no SIM records or SIMSTATE messages: not an ArduPilot SITL log")
    table = np.array(read.rows)
    t_s, q = table[:, 0], table[:, 1:5]
    fix_s = _first_fix_s(read.fixes)
    before = t_s < fix_s
    north_uT, east_uT, _ = wmm_field_ned_uT(*read.position, clamp_to_model(dt.date.today()))
    wmm_deg = math.degrees(math.atan2(east_uT, north_uT))
    magnetic = f"magnetic north + COMPASS_DEC {read.declination_deg:.1f}° (the WMM's declination {wmm_deg:.2f}° there)"
    north = "true north (a GPS fix from the start)" if not before.any() else magnetic
    if before.any() and not before.all():
        north = f"{magnetic} until the first GPS fix at {fix_s:.1f} s, true north after"
    turn = quat_from_euler(0.0, 0.0, -math.radians(wmm_deg - read.declination_deg))  # true north → the heading's
    if before.any():
        q[before] = [quat_multiply(turn, row) for row in q[before]]
    return Truth(t_s, q, north)


def at_times(t_s: np.ndarray, q: np.ndarray, times_s: np.ndarray) -> np.ndarray:
    """Attitudes ``q`` at ``t_s`` interpolated to ``times_s`` (NaN rows outside their span or across a gap of more
    than a second)."""
    out = np.full((len(times_s), 4), np.nan)
    after = np.searchsorted(t_s, times_s)
    for i, (t, j) in enumerate(zip(times_s.tolist(), after.tolist(), strict=True)):
        if 0 < j < len(t_s) and t_s[j] - t_s[j - 1] <= 1.0:
            out[i] = interpolate(t_s[j - 1], tuple(q[j - 1]), t_s[j], tuple(q[j]), t)
    return out


def errors_deg(q: np.ndarray, truth: np.ndarray) -> np.ndarray:
    """Angle from the truth per row, degrees (NaN where either is unknown)."""
    known = ~np.isnan(q[:, 0]) & ~np.isnan(truth[:, 0])
    out = np.full(len(q), np.nan)
    out[known] = np.degrees(angle_between(q[known], truth[known]))
    return out


@dataclass(frozen=True)
class Warned:
    """One cross-check warning: its hold (``hold_s`` before it was raised) to its end, and both errors over it."""

    start_s: float
    raised_s: float
    end_s: float
    ours_deg: float  # mean angle from the truth over the hold
    autopilot_deg: float

    @property
    def whose(self) -> str:
        return "the autopilot's error" if self.autopilot_deg > self.ours_deg else "our error"


@dataclass(frozen=True)
class Verdict:
    log: str
    north: str
    records: int
    t_s: np.ndarray  # the truth's times
    ours_deg: np.ndarray  # per truth record
    autopilot_deg: np.ndarray
    judged: np.ndarray  # the cross-check judged the pair nearest the record
    warnings: list[Warned]


def judge(path: Path, config: Config) -> Verdict:
    """Replay ``path`` and hold both attitudes against its truth (the module docstring)."""
    replayed: Replayed = replay(open_log(path, config), config)
    truth = read_truth(path)
    ours, autopilot = replayed.output_array(), replayed.autopilot_array()
    ours_deg = errors_deg(at_times(ours[:, 0], ours[:, 1:5], truth.t_s), truth.q)
    autopilot_deg = errors_deg(at_times(autopilot[:, 0], autopilot[:, 1:5], truth.t_s), truth.q)
    _, pairs, events = replayed.cross_check()
    pair_t = np.array([d.time_s for d in pairs])
    nearest = np.clip(np.searchsorted(pair_t, truth.t_s), 0, max(len(pairs) - 1, 0))
    judged = np.array([pairs[i].judged for i in nearest.tolist()]) if pairs else np.zeros(len(truth.t_s), bool)
    hold_s = config.crosscheck.hold_s
    raised = [e.time_s for e in events if e.disagree]
    cleared = [e.time_s for e in events if not e.disagree]
    warnings = []
    for t in raised:
        end = next((c for c in cleared if c > t), float(truth.t_s[-1]))
        spell = (truth.t_s >= t - hold_s) & (truth.t_s <= t)
        warnings.append(
            Warned(t - hold_s, t, end, float(np.nanmean(ours_deg[spell])), float(np.nanmean(autopilot_deg[spell])))
        )
    return Verdict(path.name, truth.north, len(truth.t_s), truth.t_s, ours_deg, autopilot_deg, judged, warnings)


def _rms_p99(x: np.ndarray) -> str:
    x = x[~np.isnan(x)]
    if not len(x):
        return "-"
    return f"{math.sqrt(float(np.mean(x**2))):.2f} ({float(np.percentile(x, 99)):.2f})"


def render(v: Verdict) -> str:
    lines = [
        f"{v.log}: the truth in {v.north}, good to about {TRUTH_FRAME_ERROR_DEG}°",
        f"  {'angle from the truth, RMS (p99), degrees':<48}{'ours':<18}autopilot",
        f"  {f'whole flight ({v.records} SIM records)':<48}{_rms_p99(v.ours_deg):<18}{_rms_p99(v.autopilot_deg)}",
    ]
    share = f"where the cross-check judged ({100.0 * np.mean(v.judged):.0f} %)"
    lines.append(f"  {share:<48}{_rms_p99(v.ours_deg[v.judged]):<18}{_rms_p99(v.autopilot_deg[v.judged])}")
    for w in v.warnings:
        lines.append(
            f"  cross-check warning at {w.raised_s:.1f} s (until {w.end_s:.1f} s): over its hold from {w.start_s:.1f} s"
            f" ours {w.ours_deg:.2f}°, the autopilot's {w.autopilot_deg:.2f}° from the truth: {w.whose}"
        )
    if not v.warnings:
        lines.append("  no cross-check warning")
    return "\n".join(lines)


def parse_args(argv: Sequence[str] | None) -> argparse.Namespace:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("logs", nargs="+", type=Path, metavar="LOG", help="ArduPilot SITL logs: .BIN or .tlog")
    parser.add_argument("--config", type=Path, help="a mavattitude config (default: the defaults, as replay's)")
    parser.add_argument("--method", help="estimator.method (default: the config's)")
    return parser.parse_args(argv)


def main(argv: Sequence[str] | None = None) -> int:
    args = parse_args(argv)
    overrides = {"estimator.method": args.method} if args.method else {}
    config = load_config(args.config, overrides, env={})
    for path in args.logs:
        print(render(judge(path, config)), flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
