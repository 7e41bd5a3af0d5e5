"""The misoriented-compass table: every axis flip and 90° turn of the magnetometer, on every shared recording.

Usage::

    nice -n 10 .venv/bin/python tools/compass_table.py [--recordings 06 08 sitl ...] [--methods ign fused]
    nice -n 10 .venv/bin/python tools/compass_table.py --flights [--methods ign fused]

For each recording (the 17 BROAD training trials in ``../shared/data/broad``, the ArduCopter SITL flight
``../shared/data/ardupilot-sitl/flightA.BIN`` and the PX4 log's sensors in ``../shared/data/px4``) the
service's pipeline runs with a good compass and with its magnetometer's axes turned by each of
:data:`~mavattitude.validation.frames.MISORIENTATIONS` (the field turned in the body frame before the
front end). Printed, as Markdown tables (docs/vehicle.md):

- **IGN**: RMS tilt difference (the angle between the two "down" directions, degrees) from the
  accelerometer-only tilt (TRIAD with the accelerometer primary, good compass), and the time of the
  first compass warning after the first output (``-``: none); each row names when the recording first
  moves (BROAD's first movement phase, the SITL flight's first turn), after the first output;
- **fused**: RMS tilt difference from the good-compass fused run, and the first warning's time;
- **good compass**: the warnings (time, s after the first output) with a good compass, IGN and fused;
  when the compass was vouched for (from then on IGN is the paper's; docs/vehicle.md); for BROAD, IGN's
  movement-phase RMS total error against the optical truth.

Every misorientation of :data:`TURNS`: the axis flips, the 90° turns, and a 45° turn about z.
``--flights`` prints instead the good-compass warnings of every SITL flight in ``../shared/data/ardupilot-sitl``
(.BIN and .tlog, each method, with ``configs/ardupilot.yaml`` and with the simulator's true field given), and of
simulated hard flights at the same rates with a good compass and one turned 45° (the warnings it should give).

The target: every cell ≤ 1° and warned within 10 s (of the first turn,
for a compass turned about the vertical or mirrored in a vertical plane: only a turn shows those);
no warning with a good compass except in BROAD's disturbed phases.
BROAD runs take each trial's own references (``validation_config``: the field and noise at its opening
rest, as does the PX4 log); the SITL flight the default configuration (WMM at the logged position and
date). Slow: about 15 runs per recording; run it under ``nice -n 10``.
"""

from __future__ import annotations

import argparse
import dataclasses
import functools
import math
import tempfile
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from mavattitude.config import load_config
from mavattitude.errors import MavAttitudeError
from mavattitude.link.dataflash import read_dataflash
from mavattitude.link.logs import open_log
from mavattitude.link.logstreams import LogStreams, StreamSource
from mavattitude.pipeline import AttitudePipeline
from mavattitude.replay import replay
from mavattitude.sim.logwriter import manoeuvring_log, write_dataflash, write_tlog
from mavattitude.sim.scoring import tilt_error
from mavattitude.validation.frames import MISORIENTATIONS
from mavattitude.validation.loaders import Recording, load_recording
from mavattitude.validation.runner import Estimate, evaluate, validation_config

ROOT = Path(__file__).resolve().parents[1]
BROAD_DIR = ROOT / ".." / "shared" / "data" / "broad"
SITL_DIR = ROOT / ".." / "shared" / "data" / "ardupilot-sitl"
SITL_BIN = SITL_DIR / "flightA.BIN"
PX4_CSV = ROOT / ".." / "shared" / "data" / "px4" / "px4_sample_sensors.csv.gz"
SITL_FIRST_TURN_S = 59.0  # vehicle time of the SITL flight's first turn (its README: a 360° yaw at 60°/s)
#: the misorientations of the table: every axis flip and 90° turn, and ArduPilot's ROTATION_YAW_45 (no axis-aligned
#: mounting explains it: only the turn mismatch finds it; the second compass of the SITL flight ``twocompass``)
_C45 = 0.5**0.5
TURNS = {**MISORIENTATIONS, "yaw-45": np.array([[_C45, -_C45, 0.0], [_C45, _C45, 0.0], [0.0, 0.0, 1.0]])}
SITL_FLIGHTS = ("flightA", "nogps", "lowrate", "twocompass")
SIM_SEEDS, SIM_SECONDS = (0, 1, 2), 120.0  # the simulated flights of --flights
TRUE_FIELD = {"declination_deg": 12.8, "inclination_deg": -65.77}  # the SITL's at CMAC (its README)
BROAD = ("01", "03", "04", "06", "08", "10", "12", "15", "21", "24", "26", "28", "29", "31", "33", "34", "36")


@dataclasses.dataclass(frozen=True)
class Run:
    """One pipeline run: its outputs and the compass warnings' vehicle times."""

    time_s: np.ndarray
    q: np.ndarray
    warnings_s: list[float]
    vouched_s: float  # vehicle time the compass was vouched for (NaN: never)

    def first_warning_s(self) -> float:
        """Seconds from the first output to the first warning (NaN: none)."""
        return self.warnings_s[0] - self.time_s[0] if self.warnings_s else math.nan


def _run(pipeline: AttitudePipeline, outputs: list, events: list) -> Run:
    warnings = [e.time_s for e in events if e.inconsistent]
    t = np.array([o.time_s for o in outputs], dtype=float)
    q = np.array([o.q for o in outputs], dtype=float).reshape(-1, 4)
    return Run(t, q, warnings, pipeline.compass.confirmed_at_s)


def run_broad(rec: Recording, method: str, mag_uT: np.ndarray) -> Run:
    """A BROAD trial through the pipeline (its samples at once, as replay feeds a log)."""
    pipeline = AttitudePipeline(validation_config(rec, method))
    pushed = pipeline.push_batch(rec.time_s, rec.acc_mps2, rec.gyr_radps, mag_uT, rec.mag_new)
    return _run(pipeline, pushed.outputs, pushed.compass)


def run_sitl(streams: LogStreams, method: str, mag_uT: np.ndarray) -> Run:
    """The SITL DataFlash log through replay, its magnetometer replaced by ``mag_uT``."""
    source = StreamSource("flightA.BIN", dataclasses.replace(streams, mag_uT=mag_uT, compasses=None))
    result = replay(source, load_config(None, {"estimator.method": method}, env={}))
    return _run(result.pipeline, result.outputs, result.compass)


def tilt_rms_deg(run: Run, reference: Run) -> float:
    """RMS tilt difference at the instants both runs output, degrees."""
    common, i, j = np.intersect1d(np.round(run.time_s, 6), np.round(reference.time_s, 6), return_indices=True)
    if len(common) < 0.9 * len(reference.time_s):
        return math.nan  # too few common instants to compare: shown, not hidden
    return float(np.sqrt(np.mean(np.degrees(tilt_error(run.q[i], reference.q[j])) ** 2)))


def _cell(rms: float, warned_s: float) -> str:
    warned = "-" if warned_s != warned_s else f"{warned_s:.1f} s"
    return f"{rms:.2f}° / {warned}"


def _label(name: str, rec: Recording | None, first_output_s: float) -> str:
    """The row's name with its first movement (BROAD) or first turn (SITL), s after the first output."""
    if rec is not None and not rec.movement.any():
        return name  # the PX4 log: no movement phases marked
    moves_s = SITL_FIRST_TURN_S if rec is None else rec.time_s[np.argmax(rec.movement)]
    return f"{name} (moves {moves_s - first_output_s:.1f} s)"


def recording_rows(name: str, methods: Sequence[str]) -> dict[str, str]:
    """One row per table (``ign``, ``fused``, ``good``) for one recording."""
    if name == "sitl":
        streams = read_dataflash(SITL_BIN)
        mag, runner, rec = streams.mag_uT, functools.partial(run_sitl, streams), None
    else:
        rec = load_recording(PX4_CSV if name == "px4" else next(BROAD_DIR.glob(f"{name}_*.csv.gz")))
        mag, runner = rec.mag_uT, functools.partial(run_broad, rec)
    rows: dict[str, str] = {}
    good_notes = []
    accel_only = runner("triad", mag)
    label = _label(name, rec, accel_only.time_s[0])
    for method in methods:
        good = runner(method, mag)
        reference = accel_only if method != "fused" else good
        cells = []
        for m in TURNS.values():
            bad = runner(method, mag @ m.T)
            cells.append(_cell(tilt_rms_deg(bad, reference), bad.first_warning_s()))
        rows[method] = f"| {label} | " + " | ".join(cells) + " |"
        warned = ", ".join(f"{t - good.time_s[0]:.1f}" for t in good.warnings_s) or "none"
        good_notes.append(f"{method}: {warned}")
        if method != "fused":
            good_notes.append(f"vouched for at {good.vouched_s - good.time_s[0]:.1f} s")
        if rec is not None and rec.kind == "broad" and method != "fused":
            score = evaluate(rec, Estimate("stream", method, good.time_s, good.q, len(good.time_s), 0.0)).score
            good_notes.append(f"{method} move total {score.movement.total_deg:.2f}°")
    rows["good"] = f"| {label} | " + "; ".join(good_notes) + " |"
    return rows


def flight_warnings(path: Path, method: str, true_field: bool) -> str:
    """The good-compass warnings of one SITL log replayed with the example config (``--config
    configs/ardupilot.yaml``), or with the simulator's true field given: count, and the first's time and text."""
    overrides: dict = {"estimator.method": method} | ({"reference.magnetic": TRUE_FIELD} if true_field else {})
    config = load_config(ROOT / "configs" / "ardupilot.yaml", overrides, env={})
    try:
        result = replay(open_log(path, config), config)
    except MavAttitudeError as exc:
        return f"- | {exc}"
    if not result.outputs:
        return "- | no output (no reference: the log has no position)"
    warned = [e for e in result.compass if e.inconsistent]
    first = f"{warned[0].time_s:.1f} s: {warned[0].figures.describe()}" if warned else ""
    return f"{len(warned)} | {first}"


def flights_table(methods: Sequence[str]) -> None:
    """The good-compass warnings on every shared SITL flight (.BIN and .tlog), each method, config and true field."""
    print("| flight | method | reference | warnings | first |")
    print("|---|---|---|---|---|")
    for flight in SITL_FLIGHTS:
        for ext in ("BIN", "tlog"):
            for method in methods:
                for true_field in (False, True):
                    cells = flight_warnings(SITL_DIR / f"{flight}.{ext}", method, true_field)
                    reference = "true field" if true_field else "example config"
                    print(f"| {flight}.{ext} | {method} | {reference} | {cells} |", flush=True)
    with tempfile.TemporaryDirectory() as tmp:
        for seed in SIM_SEEDS:
            for turn in ("none", "yaw-45"):
                for ext, path in _simulated(Path(tmp), seed, TURNS.get(turn)):
                    for method in methods:
                        name = f"simulated {seed}, compass turned {turn}, .{ext}"
                        print(f"| {name} | {method} | the WMM | {flight_warnings(path, method, False)} |", flush=True)


def _simulated(folder: Path, seed: int, turn: np.ndarray | None) -> list[tuple[str, Path]]:
    """A simulated hard flight (mavattitude.sim.logwriter.manoeuvring_log: 200°/s yaw swings, tilts to 30°) as
    a .BIN (25 Hz IMU, 10 Hz averaged compass) and a .tlog (50 Hz RAW_IMU repeating it)."""
    bin_log = write_dataflash(folder / "sim.bin", manoeuvring_log(SIM_SECONDS, mag_turn=turn, seed=seed))
    tlog = write_tlog(folder / "sim.tlog", manoeuvring_log(SIM_SECONDS, imu_rate_hz=50.0, mag_turn=turn, seed=seed))
    return [("BIN", bin_log), ("tlog", tlog)]


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--recordings", nargs="+", default=[*BROAD, "sitl", "px4"], help="BROAD trials, sitl, px4")
    parser.add_argument("--methods", nargs="+", default=["ign", "fused"], choices=["ign", "fused", "cgn", "ml"])
    parser.add_argument("--flights", action="store_true", help="only the warnings of the SITL and simulated flights")
    args = parser.parse_args()
    if args.flights:
        flights_table(args.methods)
        return 0
    rows = {}
    for name in args.recordings:
        rows[name] = recording_rows(name, args.methods)
        print(name, end=" ", flush=True)
    print()
    for table in [*args.methods, "good"]:
        print(f"\n{table}: RMS tilt difference / first warning" if table != "good" else "\ngood compass: warnings (s)")
        columns = list(TURNS) if table != "good" else ["notes"]
        print("| recording | " + " | ".join(columns) + " |")
        print("|---" * (len(columns) + 1) + "|")
        for name in args.recordings:
            print(rows[name][table])
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
