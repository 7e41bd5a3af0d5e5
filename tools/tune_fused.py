"""Score the gyro-aided ("fused") filter on the BROAD training set, beside its two peers, and tune it.

Usage::

    .venv/bin/python tools/tune_fused.py [--trials 04 08 ...] [--set name=value ...]   # one configuration
    .venv/bin/python tools/tune_fused.py --loco [--tune name ...] [--set ...]          # leave one category out
    .venv/bin/python tools/tune_fused.py --loro [--tune name ...] [--set ...]          # leave one motion out
    .venv/bin/python tools/tune_fused.py --references [--set ...]                       # reference variants
    .venv/bin/python tools/tune_fused.py --sim [--set ...]                              # the maneuvering flight

Training set: the 17 BROAD trials in ``../shared/data/broad`` (01 03 04 06 08 10 12 15 21 24 26 28 29 31 33
34 36). Other BROAD trials are kept back for scoring: never tune on them. One configuration for every
trial; ``--set`` overrides a ``FusedSettings`` field (the ``estimator.fused`` config keys).

For each trial the filter runs on the raw samples and is scored at every input sample with BROAD's
metric (RMS total error over the movement phase, degrees), against causal VQF (defaults) and imufusion
(gain 0.1 with its gyro ``Bias`` estimator), both on the same samples. The peers' figures are cached in
``out/tune_fused/`` (they do not depend on our settings). The summary line: geometric mean and worst of
fused/VQF, trials where fused loses to imufusion.

``--loco``: for every movement category (slow/fast rotation, translation, combined, tapping, vibration,
stationary magnet, attached magnet), tune the ``--tune`` parameters by coordinate descent (each parameter
in turn ×/÷ a step, kept while the geometric mean of fused/VQF over the *other* categories improves) and
score the held-out category with the result. A category that only scores well when it is trained on is
what the held-back trials would expose. Without ``--tune`` the tuned set is the accelerometer and
magnetometer weights. Long: run it under ``nice -n 10``; ``--jobs 2`` scores a configuration's trials in
two processes (the scores are shared between the folds either way).

``--loro``: the same with the training set split by recording rather than by category: every recording of a
motion (BROAD's file name less its number and its letter A/B/C/D: 01 and 03 are both "undisturbed slow rotation",
10 and 12 "undisturbed slow translation", 28, 29 and 31 "disturbed stationary magnet") is held out together, so a
fold never tunes on a sibling of what it is scored on (13 folds).

``--references``: the table with the magnetic reference taken as the validation takes it (the opening rest), from
the last rest window instead, with its dip off by ±3° and its strength off by ±8 %; then a row per variant:
geometric mean and worst of fused/VQF, losses to imufusion, the geometric mean against the first row's.

``--motion-field``: the same with the field where the body moves 5 % stronger and 5 % weaker than at the rest spot,
its direction kept (the magnetometer scaled from the first movement sample on; VQF and imufusion re-run on the same
data): a field off in strength but not in heading, which the strength-based weight takes for one off in heading.

``--field``: per trial, the measured field turned into NED by the true attitude over the movement phase against
the reference: its heading (mean, RMS; the white part, one 50 Hz update to the next; the slow part, its 20 s running
mean), strength ratio and dip difference, beside the gyro's own heading drift over 5 and 20 s and the
filter's heading error (RMS, mean, correlation with the field's slow part): ground-truth analysis of why heading
differs from recording to recording, and of what a weight on the field's consistency with the gyro could see.

``--misoriented`` runs each trial with its magnetometer's axes flipped or turned by 90° and prints the RMS
roll/pitch difference from the good-compass run (the target: ≤ 1°: the field sets heading only).

``--solve`` scores the same trials through ``mavattitude solve --method fused`` (a subprocess per trial: the
CSV in, the service pipeline's 50 Hz ticks out, the reference field from the opening rest as
``--mag-ref-ned``, ``--set`` as an ``estimator.fused`` config) against the ground truth at the ticks: the
figures the issue's targets are stated in. The default table scores the filter itself at every input
sample; the two agree to ~0.02°.

``--sim`` flies the fake vehicle's maneuvering flight (:func:`mavattitude.sim.scenarios.maneuver`,
consumer sensors at 200 Hz, seeded) through the service pipeline with ``estimator.method`` ``ign`` and
``fused`` and prints both errors and their ratio (the target: fused ≤ 1/5 of IGN-only).

Data: D. Laidig, M. Caruso, A. Cereatti, T. Seel, "BROAD — A Benchmark for Robust Inertial Orientation
Estimation", Data 6(7):72, 2021, doi:10.3390/data6070072 (CC BY 4.0), read from ``../shared/data/broad``.
"""

from __future__ import annotations

import argparse
import dataclasses
import functools
import math
import multiprocessing
import re
import time
from collections.abc import Callable, Iterable, Sequence
from pathlib import Path

import numpy as np

from mavattitude.estimation.fused import FusedFilter, FusedSettings
from mavattitude.sensors.units import STANDARD_GRAVITY_MPS2
from mavattitude.validation.frames import MISORIENTATIONS, ned_from_enu
from mavattitude.validation.loaders import Recording, load_recording
from mavattitude.validation.metrics import score_broad
from mavattitude.validation.peers import estimate_peer

ROOT = Path(__file__).resolve().parents[1]
DATA_DIR = ROOT / ".." / "shared" / "data" / "broad"
CACHE_DIR = ROOT / "out" / "tune_fused"
TRAINING = ("01", "03", "04", "06", "08", "10", "12", "15", "21", "24", "26", "28", "29", "31", "33", "34", "36")
#: BROAD's movement categories, from the trial names (the filter never sees them: only the tuning does).
CATEGORIES = {
    "slow rotation": ("01", "03", "04"),
    "fast rotation": ("06", "08"),
    "translation": ("10", "12", "15"),
    "combined": ("21",),
    "tapping": ("24",),
    "vibration": ("26",),
    "stationary magnet": ("28", "29", "31"),
    "attached magnet": ("33", "34", "36"),
}
DEFAULT_TUNED = ("accel_lowpass_s", "accel_lag_gain", "accel_norm_gain", "mag_std_uT", "gyro_scale_fraction")


#: The reference field's variants the figures must survive: as the validation takes it (the opening rest), from
#: the last rest window instead, the dip off by ±3°, the strength off by ±8 %.
REFERENCES = ("first rest", "last rest", "inclination +3°", "inclination -3°", "strength +8%", "strength -8%")
#: The field where the body moves, stronger or weaker than at the rest spot with its direction kept (the magnetometer
#: scaled from the first movement sample on): what the strength-based weight takes for a field off in heading.
MOTION_FIELDS = ("motion field +5%", "motion field -5%")


@functools.cache
def recording(trial: str, reference: str = REFERENCES[0]) -> Recording:
    """The trial, its magnetic reference one of :data:`REFERENCES`, or its field in motion one of
    :data:`MOTION_FIELDS`."""
    (path,) = DATA_DIR.glob(f"{trial}_*.csv.gz")
    rec = load_recording(path)
    if reference == REFERENCES[0]:
        return rec
    if reference in MOTION_FIELDS:
        mag = rec.mag_uT.copy()
        mag[np.argmax(rec.movement) :] *= 1.0 + float(reference.rpartition(" ")[2].rstrip("%")) / 100.0
        return dataclasses.replace(rec, mag_uT=mag)
    field = _last_rest_field(rec) if reference == "last rest" else rec.reference.field_ned_uT
    strength, dip = float(np.linalg.norm(field)), math.atan2(field[2], field[0])
    kind, _, amount = reference.partition(" ")
    if kind == "inclination":
        dip += math.radians(float(amount.rstrip("°")))
    elif kind == "strength":
        strength *= 1.0 + float(amount.rstrip("%")) / 100.0
    changed = strength * np.array([math.cos(dip), 0.0, math.sin(dip)])
    return dataclasses.replace(rec, reference=dataclasses.replace(rec.reference, field_ned_uT=changed))


def _last_rest_field(rec: Recording) -> np.ndarray:
    """The field as the opening rest gives it (strength, dip against the measured down; declination 0), from the
    recording's last rest window instead (:func:`mavattitude.validation.frames.rest_reference`'s rule)."""
    edges = np.flatnonzero(np.diff(np.r_[0, rec.rest.astype(int), 0]))
    start, stop = edges[-2], edges[-1]
    down, field = -rec.acc_mps2[start:stop].mean(axis=0), rec.mag_uT[start:stop].mean(axis=0)
    strength = float(np.linalg.norm(field))
    dip = math.asin(float(field @ down) / (strength * float(np.linalg.norm(down))))
    return strength * np.array([math.cos(dip), 0.0, math.sin(dip)])


def recording_groups(trials: Iterable[str]) -> dict[str, tuple[str, ...]]:
    """The trials by motion, from BROAD's file names: a name less its number and its recording letter (A, B, C,
    D) is the motion, so every sibling recording of a motion is kept out together (01 and 03, 10 and 12, …)."""
    groups: dict[str, list[str]] = {}
    for trial in trials:
        (path,) = DATA_DIR.glob(f"{trial}_*.csv.gz")
        motion = re.sub(r"_[A-D]$", "", path.name.removesuffix(".csv.gz").split("_", 1)[1])
        groups.setdefault(motion.replace("_", " "), []).append(trial)
    return {motion: tuple(members) for motion, members in groups.items()}


def imufusion_with_bias(rec: Recording, gain: float = 0.1) -> np.ndarray:
    """Fusion AHRS (gain 0.1) on gyro samples corrected by its own ``Bias`` estimator; body → NED."""
    import imufusion

    rate_hz = 1.0 / float(np.median(np.diff(rec.time_s)))
    ahrs, bias = imufusion.Ahrs(), imufusion.Bias()
    settings = imufusion.AhrsSettings()
    settings.convention, settings.sample_rate, settings.gain = imufusion.CONVENTION_ENU, rate_hz, gain
    ahrs.set_settings(settings)
    bias_settings = imufusion.BiasSettings()
    bias_settings.sample_rate = rate_hz
    bias.set_settings(bias_settings)
    gyr_dps, acc_g = np.degrees(rec.gyr_radps), rec.acc_mps2 / STANDARD_GRAVITY_MPS2
    q = np.empty((len(rec), 4))
    for i in range(len(rec)):
        ahrs.update(bias.update(gyr_dps[i]), acc_g[i], rec.mag_uT[i])
        q[i] = ahrs.get_quaternion()
    return ned_from_enu(q)


def peer_scores(trial: str, reference: str = REFERENCES[0]) -> dict[str, float]:
    """Movement-phase RMS total (degrees) of VQF and imufusion on a trial, cached on disk; on its field in motion
    changed (:data:`MOTION_FIELDS`) they run on the same changed data (their reference is their own)."""
    motion = reference in MOTION_FIELDS
    path = CACHE_DIR / (f"{trial} {reference}.npz" if motion else f"{trial}.npz")
    if path.exists():
        return {k: float(v) for k, v in np.load(path).items()}
    rec = recording(trial, reference if motion else REFERENCES[0])
    q = {"vqf": estimate_peer(rec, "vqf").q, "imufusion": imufusion_with_bias(rec)}
    scores = {k: score_broad(v, rec.truth_q, rec.movement, rec.rest).movement.total_deg for k, v in q.items()}
    CACHE_DIR.mkdir(parents=True, exist_ok=True)
    np.savez(path, **scores)
    return scores


def run_fused(rec: Recording, settings: FusedSettings) -> tuple[np.ndarray, FusedFilter, float]:
    """Attitude (body → NED) at every input sample, the filter at the end, and µs per input sample."""
    t, gyr, acc, mag = (a.tolist() for a in (rec.time_s, rec.gyr_radps, rec.acc_mps2, rec.mag_uT))
    f = FusedFilter(settings, rec.reference.field_ned_uT)
    q = np.empty((len(t), 4))
    start = time.process_time()
    for i in range(len(t)):
        f.push(t[i], gyr[i], acc[i], mag[i])
        q[i] = f.q
    return q, f, (time.process_time() - start) / len(t) * 1e6


def score(
    trial: str, settings: FusedSettings, reference: str = REFERENCES[0]
) -> tuple[float, float, float, FusedFilter, float]:
    """``(total, heading, inclination)`` movement RMS (degrees), the filter, µs per sample."""
    rec = recording(trial, reference)
    q, f, cost_us = run_fused(rec, settings)
    m = score_broad(q, rec.truth_q, rec.movement, rec.rest).movement
    return m.total_deg, m.heading_deg, m.inclination_deg, f, cost_us


_TOTALS: dict[tuple[str, FusedSettings], float] = {}
JOBS = 1  # processes that score a configuration's trials (--jobs)


def total_deg(trial: str, settings: FusedSettings) -> float:
    """Movement RMS total of one trial, remembered: the searches (and the folds) ask for the same
    configurations again."""
    key = (trial, settings)
    if key not in _TOTALS:
        _TOTALS[key] = score(trial, settings)[0]
    return _TOTALS[key]


def _scored(key: tuple[str, FusedSettings]) -> float:
    return score(*key)[0]


def ratios(trials: Iterable[str], settings: FusedSettings, peer: str = "vqf") -> dict[str, float]:
    trials = list(trials)
    todo = [(t, settings) for t in trials if (t, settings) not in _TOTALS]
    if JOBS > 1 and len(todo) > 1:  # the missing trials at once, in JOBS processes
        with multiprocessing.Pool(JOBS) as pool:
            _TOTALS.update(zip(todo, pool.map(_scored, todo), strict=True))
    return {t: total_deg(t, settings) / peer_scores(t)[peer] for t in trials}


def geomean(values: Iterable[float]) -> float:
    v = list(values)
    return math.exp(sum(math.log(x) for x in v) / len(v))


Row = Callable[[str], tuple[float, float, float, str]]


def filter_row(settings: FusedSettings, reference: str = REFERENCES[0]) -> Row:
    """A table row from the filter itself, scored at every input sample: the figures and its counters."""

    def row(trial: str) -> tuple[float, float, float, str]:
        total, heading, incl, f, cost_us = score(trial, settings, reference)
        counters = " ".join(f"{k}={v}" for k, v in f.counters.items() if v)
        return total, heading, incl, f"{cost_us:.1f}µs {counters}"

    return row


def table(
    trials: Sequence[str], row: Row, note: str = "counters", reference: str = REFERENCES[0]
) -> tuple[float, float, int]:
    """The per-trial table (``row(trial)``: total, heading, inclination, a note) and the summary line; the
    summary's figures: geometric mean and worst of fused/VQF, trials worse than imufusion (the peers on the
    ``reference`` variant's data)."""
    print(f"{'trial':6}{'fused':>7}{'head':>7}{'incl':>7}{'VQF':>7}{'imuf':>7}{'f/VQF':>7}{'f/imuf':>7}  {note}")
    r_vqf, losses = [], []
    for trial in trials:
        total, heading, incl, text = row(trial)
        peers = peer_scores(trial, reference)
        r_vqf.append(total / peers["vqf"])
        if total > peers["imufusion"]:
            losses.append(trial)
        print(
            f"{trial:6}{total:7.2f}{heading:7.2f}{incl:7.2f}{peers['vqf']:7.2f}{peers['imufusion']:7.2f}"
            f"{r_vqf[-1]:7.2f}{total / peers['imufusion']:7.2f}  {text}",
            flush=True,
        )
    print(
        f"fused/VQF geometric mean {geomean(r_vqf):.3f} (target ≤ 0.95), worst {max(r_vqf):.2f} (≤ 1.25); "
        f"worse than imufusion on {len(losses)} of {len(trials)} {' '.join(losses)}"
    )
    return geomean(r_vqf), max(r_vqf), len(losses)


def reference_robustness(trials: Sequence[str], settings: FusedSettings, variants: Sequence[str] = REFERENCES) -> None:
    """The table under each reference variant (:data:`REFERENCES`, or the unchanged data and
    :data:`MOTION_FIELDS`), then one summary row per variant."""
    rows = []
    for reference in variants:
        print(f"- reference: {reference}", flush=True)
        rows.append((reference, *table(trials, filter_row(settings, reference), reference=reference)))
    first = rows[0][1]
    print(f"{'reference':18}{'geomean':>9}{'worst':>7}{'losses':>8}{'vs first':>10}")
    for reference, mean, worst, losses in rows:
        print(f"{reference:18}{mean:9.3f}{worst:7.2f}{losses:8d}{mean / first - 1.0:+10.1%}")


def cost(trials: Sequence[str], settings: FusedSettings) -> float:
    """The tuning objective, from the targets: geometric mean of fused/VQF, plus the worst ratio's excess over
    1.25, plus every trial's excess of fused/imufusion over 1."""
    r = ratios(trials, settings).values()
    losses = sum(max(0.0, x - 1.0) for x in ratios(trials, settings, "imufusion").values())
    return geomean(r) + max(0.0, max(r) - 1.25) + losses


def coordinate_descent(
    trials: Sequence[str], base: FusedSettings, names: Sequence[str], step: float = 1.5, rounds: int = 1
) -> FusedSettings:
    """Each parameter in turn ×/÷ ``step`` while :func:`cost` on ``trials`` improves."""
    best = base
    best_cost = cost(trials, best)
    for _ in range(rounds):
        improved = False
        for name in names:
            for factor in (step, 1.0 / step):
                value = getattr(best, name) * factor
                trial_settings = dataclasses.replace(best, **{name: value})
                c = cost(trials, trial_settings)
                if c < best_cost:
                    best, best_cost, improved = trial_settings, c, True
                    print(f"    {name} = {value:.4g}: {c:.3f}", flush=True)
                    break
        if not improved:
            break
    return best


def leave_groups_out(groups: dict[str, tuple[str, ...]], base: FusedSettings, names: Sequence[str]) -> None:
    """Tune without each group (a category, or every recording of a motion), score on it."""
    print(f"tuned parameters: {' '.join(names)}; start: the given configuration")
    held_out: dict[str, float] = {}
    for category, trials in groups.items():
        train = [t for t in TRAINING if t not in trials]
        print(f"- without {category}:", flush=True)
        tuned = coordinate_descent(train, base, names)
        held = ratios(trials, tuned)
        at_base = ratios(trials, base)
        held_out |= held
        print(
            f"  {category}: fused/VQF held out {geomean(held.values()):.3f} (with the start configuration "
            f"{geomean(at_base.values()):.3f}); tuned: " + " ".join(f"{n}={getattr(tuned, n):.4g}" for n in names),
            flush=True,
        )
    print(f"held out: geometric mean {geomean(held_out.values()):.3f}, worst {max(held_out.values()):.2f}")
    print("  " + " ".join(f"{t} {r:.2f}" for t, r in sorted(held_out.items())))


def field_in_motion(trials: Sequence[str], settings: FusedSettings) -> None:
    """Why heading differs between recordings: the measured field turned into NED by the *true* attitude over
    the movement phase, against the reference (from the opening rest): its heading error (mean and RMS about the
    reference's north; its change from one 50 Hz update to the next over √2, the white part; the RMS of its 20 s
    running mean, the slow part), strength and dip; the gyro's heading drift over 5 and 20 s; the filter's heading
    error (RMS, mean) and its correlation with the field's 20 s mean (negative: the filter follows the field,
    ``ψ − ψ_true = −δ``). Analysis of the ground truth only, never inside the filter."""
    from mavattitude.estimation.conventions import quat_conjugate, quat_multiply, rotate_body_to_ned

    print(
        f"{'trial':6}{'field heading':>14}{'rms':>6}{'white':>7}{'20 s':>6}{'gyro 5 s':>10}{'20 s':>6}"
        f"{'|B| ratio':>10}{'dip diff':>9}{'fused heading':>15}{'mean':>7}{'corr':>7}"
    )
    for trial in trials:
        rec = recording(trial)
        keep = rec.movement & np.all(np.isfinite(rec.truth_q), axis=1)
        field = rotate_body_to_ned(np.nan_to_num(rec.truth_q, nan=1.0), rec.mag_uT)
        ref = rec.reference.field_ned_uT
        heading = _wrapped_deg(np.arctan2(field[:, 1], field[:, 0]) - math.atan2(ref[1], ref[0]))
        strength = np.linalg.norm(field, axis=1)[keep]
        dip = np.degrees(np.arcsin(field[keep, 2] / strength)) - math.degrees(math.asin(ref[2] / np.linalg.norm(ref)))
        rate_hz = 1.0 / float(np.median(np.diff(rec.time_s)))
        slow = np.convolve(heading, np.ones(round(20.0 * rate_hz)) / round(20.0 * rate_hz), mode="same")
        n1 = round(0.02 * rate_hz)  # one 50 Hz update apart: BROAD's magnetometer repeats within a few samples
        white = _wrapped_deg(np.radians(heading[n1:] - heading[:-n1]))[keep[n1:] & keep[:-n1]] / math.sqrt(2.0)
        q = run_fused(rec, settings)[0]
        err = quat_multiply(q, quat_conjugate(rec.truth_q))  # the earth-frame error
        fused = np.degrees(2.0 * np.arctan2(err[:, 3] * np.sign(err[:, 0]), np.abs(err[:, 0])))[keep]
        gyro = _gyro_drift_deg(rec, 5.0), _gyro_drift_deg(rec, 20.0)
        print(
            f"{trial:6}{heading[keep].mean():14.2f}{_rms(heading[keep]):6.2f}{_rms(white):7.2f}{_rms(slow[keep]):6.2f}"
            f"{gyro[0]:10.2f}{gyro[1]:6.2f}{strength.mean() / np.linalg.norm(ref):10.3f}"
            f"{dip.mean():9.2f}{_rms(fused):15.2f}{fused.mean():7.2f}{np.corrcoef(fused, slow[keep])[0, 1]:7.2f}",
            flush=True,
        )


def _rms(x: np.ndarray) -> float:
    return float(np.sqrt(np.mean(x**2)))


def _wrapped_deg(angle_rad: np.ndarray) -> np.ndarray:
    return np.degrees(np.angle(np.exp(1j * angle_rad)))


def _gyro_drift_deg(rec: Recording, window_s: float) -> float:
    """RMS heading error (degrees) of the gyro alone over ``window_s``: integrated from the true attitude at the
    start of each window of the movement phase, its bias the opening rest's mean rate."""
    from mavattitude.estimation.conventions import quat_conjugate, quat_from_rotvec_parts, quat_multiply_parts

    bias = rec.gyr_radps[: np.argmax(rec.movement)].mean(axis=0)
    steps = (rec.gyr_radps[1:] - bias) * np.diff(rec.time_s)[:, None]
    finite = np.all(np.isfinite(rec.truth_q), axis=1)
    drift, start = [], int(np.argmax(rec.movement))
    n = round(window_s / float(np.median(np.diff(rec.time_s))))
    while start + n < len(rec):
        end = start + n
        if rec.movement[start] and rec.movement[end] and finite[start] and finite[end]:
            q = tuple(rec.truth_q[start])
            for step in steps[start:end].tolist():
                q = quat_multiply_parts(q, quat_from_rotvec_parts(*step))
            w, _, _, z = quat_multiply_parts(q, tuple(quat_conjugate(rec.truth_q[end])))
            drift.append(2.0 * math.atan2(z * math.copysign(1.0, w), abs(w)))
        start = end
    return math.degrees(_rms(np.array(drift))) if drift else math.nan


def misoriented(trials: Sequence[str], settings: FusedSettings) -> None:
    """Roll/pitch with a misoriented magnetometer against the good-compass run, RMS over the whole trial."""
    from mavattitude.sim.scoring import tilt_error

    print(f"{'trial':6}" + "".join(f"{name:>10}" for name in MISORIENTATIONS) + "  (deg RMS tilt difference)")
    worst = 0.0
    for trial in trials:
        rec = recording(trial)
        good, _, _ = run_fused(rec, settings)
        diffs = []
        for m in MISORIENTATIONS.values():
            bad, _, _ = run_fused(dataclasses.replace(rec, mag_uT=rec.mag_uT @ m.T), settings)
            diffs.append(float(np.sqrt(np.mean(np.degrees(tilt_error(bad, good)) ** 2))))
        worst = max(worst, *diffs)
        print(f"{trial:6}" + "".join(f"{d:10.2f}" for d in diffs), flush=True)
    print(f"worst {worst:.2f}° (target ≤ 1°)")


def solve_row(trial: str, overrides: dict[str, float]) -> tuple[float, float, float, str]:
    """Movement RMS total, heading, inclination (degrees) of ``mavattitude solve --method fused``."""
    import subprocess
    import sys
    import tempfile

    import yaml

    from mavattitude.validation.loaders import truth_at
    from mavattitude.validation.metrics import ErrorRms, broad_errors

    rec = recording(trial)
    (path,) = DATA_DIR.glob(f"{trial}_*.csv.gz")
    with tempfile.TemporaryDirectory() as tmp:
        out, config = Path(tmp) / "out.csv", Path(tmp) / "config.yaml"
        config.write_text(yaml.safe_dump({"estimator": {"method": "fused", "fused": overrides}}))
        field = [f"{v:.6f}" for v in rec.reference.field_ned_uT]
        command = [sys.executable, "-m", "mavattitude", "solve", str(path), "-o", str(out), "--config", str(config)]
        subprocess.run([*command, "--mag-ref-ned", *field, "--no-progress"], check=True, capture_output=True)
        ticks = np.loadtxt(out, delimiter=",", skiprows=1, usecols=range(5), ndmin=2)
    truth, movement, _ = truth_at(rec, ticks[:, 0])
    m = ErrorRms.of(broad_errors(ticks[:, 1:], truth)[movement])
    return m.total_deg, m.heading_deg, m.inclination_deg, f"{len(ticks)} ticks"


def run_sim(overrides: dict[str, float], seed: int = 0) -> None:
    """The maneuvering flight through the pipeline, IGN-only against fused (``overrides`` go to the filter)."""
    from mavattitude import pipeline
    from mavattitude.config import from_dict
    from mavattitude.estimation.conventions import angle_between
    from mavattitude.sensors.units import ImuSample
    from mavattitude.sim import scenarios
    from mavattitude.sim.scoring import heading_error, tilt_error

    script, sensors = scenarios.maneuver(), scenarios.consumer_sensors(200.0)
    rng = np.random.default_rng(seed)
    t = sensors.sample_times(0.0, script.duration_s, rng)
    acc, gyr, mag = sensors.measure(script, t, rng)
    samples = [ImuSample(t[i], tuple(acc[i]), tuple(gyr[i]), tuple(mag[i])) for i in range(len(t))]
    reference = {"magnetic": {"field_ned_uT": list(scenarios.DEFAULT_MAG_NED_UT)}}
    rms = {}
    for method in ("ign", "fused"):
        estimator: dict[str, object] = {"method": method}
        config: dict[str, object] = {"reference": reference, "estimator": estimator}
        if method == "fused":
            estimator["fused"] = overrides
        else:
            config["noise"] = {"accel_std_mps2": [0.03, 0.03, 0.04], "mag_std_uT": [0.4, 0.4, 0.5]}  # the preset's σ
        p = pipeline.AttitudePipeline(from_dict(config))
        out = [o for s in samples for o in p.push(s).outputs]
        q, q_true = np.array([o.q for o in out]), script.attitude(np.array([o.time_s for o in out]))
        errs = [np.degrees(e(q, q_true)) for e in (angle_between, tilt_error, heading_error)]
        rms[method] = [float(np.sqrt(np.mean(e**2))) for e in errs]
        print(
            f"sim maneuver  {method:6} RMS total {rms[method][0]:6.2f}  tilt {rms[method][1]:6.2f}  "
            f"heading {rms[method][2]:6.2f} deg  ({len(out)} ticks)"
        )
    print(f"fused / ign = {rms['fused'][0] / rms['ign'][0]:.3f} (target ≤ 0.2)")


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--trials", nargs="+", default=list(TRAINING), help="BROAD trial numbers (training set)")
    parser.add_argument("--set", nargs="*", default=[], metavar="NAME=VALUE", help="FusedSettings overrides")
    parser.add_argument("--loco", action="store_true", help="leave-one-category-out tuning and scores")
    parser.add_argument(
        "--loro", action="store_true", help="leave-one-motion-out: every recording (A, B, C, D) of a motion held out"
    )
    parser.add_argument(
        "--references", action="store_true", help="the table under each reference-field variant, and their summary"
    )
    parser.add_argument(
        "--motion-field", action="store_true", help="the table with the field in motion ±5 %% stronger, and a summary"
    )
    parser.add_argument(
        "--field", action="store_true", help="the field in the motion volume (by the truth) against the reference"
    )
    parser.add_argument("--descend", action="store_true", help="coordinate descent of --tune on --trials")
    parser.add_argument("--jobs", type=int, default=1, help="processes for --loco and --descend (nice them)")
    parser.add_argument("--tune", nargs="+", default=list(DEFAULT_TUNED), help="parameters --loco tunes")
    parser.add_argument("--solve", action="store_true", help="score through `mavattitude solve --method fused`")
    parser.add_argument("--sim", action="store_true", help="the fake vehicle's maneuvering flight, not BROAD")
    parser.add_argument(
        "--misoriented", action="store_true", help="roll/pitch with a flipped or turned magnetometer vs a good one"
    )
    args = parser.parse_args()
    global JOBS
    JOBS = max(1, args.jobs)
    overrides = {k: float(v) for k, v in (s.split("=", 1) for s in args.set)}
    if args.sim:
        run_sim(overrides)
        return 0
    settings = dataclasses.replace(FusedSettings(), **overrides)
    unknown = [t for t in args.trials if t not in TRAINING]
    if unknown:
        parser.error(f"not in the training set: {' '.join(unknown)} (the others are kept back for scoring)")
    if args.loco:
        leave_groups_out(CATEGORIES, settings, args.tune)
    elif args.loro:
        leave_groups_out(recording_groups(TRAINING), settings, args.tune)
    elif args.references:
        reference_robustness(args.trials, settings)
    elif args.motion_field:
        reference_robustness(args.trials, settings, (REFERENCES[0], *MOTION_FIELDS))
    elif args.field:
        field_in_motion(args.trials, settings)
    elif args.descend:
        tuned = coordinate_descent(args.trials, settings, args.tune)
        print("tuned: " + " ".join(f"{n}={getattr(tuned, n):.4g}" for n in args.tune))
        table(args.trials, filter_row(tuned))
    elif args.misoriented:
        misoriented(args.trials, settings)
    elif args.solve:
        table(args.trials, functools.partial(solve_row, overrides=overrides), "mavattitude solve")
    else:
        table(args.trials, filter_row(settings))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
