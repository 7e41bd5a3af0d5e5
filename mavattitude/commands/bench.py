"""`mavattitude bench`: every performance figure the issues ask for, in one table (also `tools/bench.py`).

Each section measures one part through its public API. A part that is not installed or not built yet
is reported as ``not available: <reason>``, never as a number; a part that fails while measured is
reported as ``failed: <error>`` and makes the command exit 1. Times are the best of several repeats
(the least disturbed by other processes on a shared machine) divided by the samples per repeat.
"""

from __future__ import annotations

import argparse
import datetime
import os
import platform
import sys
import time
from collections.abc import Callable
from dataclasses import dataclass
from importlib import metadata
from pathlib import Path

import numpy as np

from mavattitude.errors import ConfigError

NAME = "bench"
HELP = "measure solver, front end, service and filter performance; print one table (and write it as Markdown)"

SEED = 20140401


@dataclass(frozen=True)
class Row:
    """One figure: what was measured, the value (or why there is none), and the issue's target."""

    section: str
    figure: str
    measured: str
    target: str = ""
    verdict: str = ""  # "yes" / "no" against the target, "" when there is no target or no value


@dataclass(frozen=True)
class Settings:
    quick: bool

    def pick(self, quick: int, full: int) -> int:
        return quick if self.quick else full


class NotAvailable(Exception):
    """The part a section measures is not there (not installed, not built yet): say why, measure nothing."""


def _fmt(value: float, unit: str, digits: int = 3) -> str:
    return f"{value:.{digits}g} {unit}"


def _row(section: str, figure: str, value: float, unit: str, target: float | None = None, higher_is_better=False):
    """A measured row; the verdict compares against the target in the direction that is better."""
    if target is None:
        return Row(section, figure, _fmt(value, unit))
    ok = value >= target if higher_is_better else value <= target
    sign = "≥" if higher_is_better else "≤"
    return Row(section, figure, _fmt(value, unit), f"{sign} {_fmt(target, unit)}", "yes" if ok else "no")


def best_time_s(call: Callable[[], object], repeats: int) -> float:
    """Seconds for one call (a whole batch, a whole pass): the fastest of `repeats`."""
    best = float("inf")
    for _ in range(repeats):
        start = time.perf_counter()
        call()
        best = min(best, time.perf_counter() - start)
    return best


# --- the sections -----------------------------------------------------------------------------------------

Section = Callable[[Settings], list[Row]]
SECTIONS: dict[str, Section] = {}


def section(name: str) -> Callable[[Section], Section]:
    def register(func: Section) -> Section:
        SECTIONS[name] = func
        return func

    return register


def _require(module: str, why: str):
    """Import a module a section needs, or say it is not available and why."""
    try:
        return __import__(module, fromlist=["_"])
    except ImportError as exc:
        raise NotAvailable(f"{why} ({exc})") from None


# The rows each section reports, so that a section that is not available still shows what it would measure.
EXPECTED_ROWS: dict[str, list[str]] = {}


def run_section(name: str, settings: Settings) -> tuple[list[Row], bool]:
    """The section's rows and whether it failed (a bug or a broken part, not a missing one)."""
    try:
        return SECTIONS[name](settings), False
    except NotAvailable as exc:
        first, *rest = EXPECTED_ROWS[name]
        return [Row(name, first, f"not available: {exc}")] + [
            Row(name, f, "not available (as above)") for f in rest
        ], False
    except Exception as exc:  # reported in the table and in the exit code, never hidden
        return [Row(name, "(section)", f"failed: {type(exc).__name__}: {exc}")], True


# Scenario for the solver and filter figures: a mid-latitude field (inclination ~65°), MEMS-grade noise.
GRAVITY_MPS2 = 9.80665
MAG_REF_NED_UT = (19.0, 1.5, 45.0)
ACC_STD_MPS2 = 0.05
MAG_STD_UT = 0.5


def random_samples(n: int, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Uniformly random attitudes and the noisy body-frame specific force and field they give."""
    from mavattitude.estimation import conventions as cv

    q_true = cv.quat_normalize(rng.normal(size=(n, 4)))
    acc = cv.rotate_ned_to_body(q_true, (0.0, 0.0, -GRAVITY_MPS2)) + rng.normal(0.0, ACC_STD_MPS2, (n, 3))
    mag = cv.rotate_ned_to_body(q_true, MAG_REF_NED_UT) + rng.normal(0.0, MAG_STD_UT, (n, 3))
    return q_true, acc, mag


EXPECTED_ROWS["solver"] = [
    "solve(method='ign') per sample, from TRIAD",
    "solve(method='ign') per sample, warm start",
    "ahrs QUEST per sample (peer)",
    "scipy Rotation.align_vectors per sample (peer)",
    "QUEST time / IGN time",
    "align_vectors time / IGN time",
    "IGN vs weighted align_vectors optimum, worst angle",
    "IGN iterations from TRIAD: worst, converged share",
    "solve_batch(method='ign') throughput",
]


@section("solver")
def bench_solver(settings: Settings) -> list[Row]:
    est = _require("mavattitude.estimation", "the estimation core (issue 2)")
    noise_mod = _require("mavattitude.estimation.noise", "the estimation core's noise model (issue 2)")
    if not all(hasattr(est, name) for name in ("solve", "solve_batch", "NoiseModel")):
        raise NotAvailable("mavattitude.estimation does not export solve, solve_batch and NoiseModel yet")
    ahrs_filters = _require("ahrs.filters", "the ahrs package, a test extra: pip install 'mavattitude[test]'")
    rotation = _require("scipy.spatial.transform", "scipy, a test extra: pip install 'mavattitude[test]'").Rotation
    rng = np.random.default_rng(SEED)
    n = settings.pick(300, 3000)
    repeats = settings.pick(2, 5)
    _, acc, mag = random_samples(n, rng)
    noise = est.NoiseModel(accel_std=ACC_STD_MPS2, mag_std=MAG_STD_UT)
    acc_rows, mag_rows = list(acc), list(mag)  # one (3,) array per sample, as the pipeline hands them over

    results = [est.solve(acc_rows[i], mag_rows[i], MAG_REF_NED_UT, noise) for i in range(n)]
    q_ign = np.array([r.q for r in results])
    cold_s = _per_sample(lambda i: est.solve(acc_rows[i], mag_rows[i], MAG_REF_NED_UT, noise), n, repeats)
    warm_s = _per_sample(lambda i: est.solve(acc_rows[i], mag_rows[i], MAG_REF_NED_UT, noise, q0=q_ign[i]), n, repeats)
    quest = ahrs_filters.QUEST(magnetic_dip=None)
    # QUEST's references: gravity up in its own frame; only the timing is compared, so its frames do not matter.
    quest_s = _per_sample(lambda i: quest.estimate(acc_rows[i], mag_rows[i]), n, repeats)

    # scipy's closed-form optimum with the same (paper's) weights: a ≈ R b, a in NED, b in the body.
    w_acc = noise_mod.paper_weight(acc, noise.accel_var)
    w_mag = noise_mod.paper_weight(mag, noise.mag_var)
    refs = np.array([(0.0, 0.0, -1.0), np.asarray(MAG_REF_NED_UT) / np.linalg.norm(MAG_REF_NED_UT)])

    def align(i: int) -> object:
        body = np.array([acc[i] / np.linalg.norm(acc[i]), mag[i] / np.linalg.norm(mag[i])])
        return rotation.align_vectors(refs, body, weights=[w_acc[i], w_mag[i]])[0]

    align_s = _per_sample(align, n, repeats)
    from mavattitude.estimation import conventions as cv

    q_opt = cv.quat_normalize(np.array([align(i).as_quat(scalar_first=True) for i in range(n)]))
    worst_rad = float(np.max(cv.angle_between(q_ign, q_opt)))
    iterations = np.array([r.iterations for r in results])
    converged = np.mean([r.converged for r in results])

    n_batch = settings.pick(20_000, 200_000)
    _, acc_b, mag_b = random_samples(n_batch, rng)
    batch_s = best_time_s(lambda: est.solve_batch(acc_b, mag_b, MAG_REF_NED_UT, noise), repeats)
    sec = "solver"
    return [
        _row(sec, EXPECTED_ROWS[sec][0], cold_s * 1e6, "µs", 20.0),
        _row(sec, EXPECTED_ROWS[sec][1], warm_s * 1e6, "µs", 20.0),
        _row(sec, EXPECTED_ROWS[sec][2], quest_s * 1e6, "µs"),
        _row(sec, EXPECTED_ROWS[sec][3], align_s * 1e6, "µs"),
        _row(sec, EXPECTED_ROWS[sec][4], quest_s / cold_s, "×"),
        _row(sec, EXPECTED_ROWS[sec][5], align_s / cold_s, "×"),
        _row(sec, EXPECTED_ROWS[sec][6], worst_rad, "rad", 1e-9),
        Row(
            sec,
            EXPECTED_ROWS[sec][7],
            f"{iterations.max()}, {converged:.1%} of {n}",
            "≤ 3, 100%",
            "yes" if iterations.max() <= 3 and converged == 1.0 else "no",
        ),
        _row(sec, EXPECTED_ROWS[sec][8], n_batch / batch_s, "samples/s", 500_000, higher_is_better=True),
    ]


def _per_sample(func: Callable[[int], object], n: int, repeats: int) -> float:
    """Seconds per call of ``func(i)`` over samples ``0 .. n−1``, best of ``repeats`` passes."""

    def one_pass() -> None:
        for i in range(n):
            func(i)

    return best_time_s(one_pass, repeats) / n


EXPECTED_ROWS["fused"] = ["FusedFilter.push per 200 Hz input sample (gyro-aided filter)"]


@section("fused")
def bench_fused(settings: Settings) -> list[Row]:
    fused = _require("mavattitude.estimation.fused", "the gyro-aided filter (mavattitude/estimation/fused.py)")
    from mavattitude.estimation import conventions as cv

    rng = np.random.default_rng(SEED)
    n = settings.pick(2_000, 20_000)
    rate_hz = 200.0
    # A slow constant turn: the filter propagates every sample and updates at its own 50 Hz.
    rate_radps = np.array([0.1, -0.05, 0.2])
    t = np.arange(n) / rate_hz
    q_true = cv.quat_from_rotvec(t[:, None] * rate_radps)
    acc = cv.rotate_ned_to_body(q_true, (0.0, 0.0, -GRAVITY_MPS2)) + rng.normal(0.0, ACC_STD_MPS2, (n, 3))
    mag = cv.rotate_ned_to_body(q_true, MAG_REF_NED_UT) + rng.normal(0.0, MAG_STD_UT, (n, 3))
    gyr = rate_radps + rng.normal(0.0, 0.003, (n, 3))
    samples = [(float(t[i]), tuple(gyr[i]), tuple(acc[i]), tuple(mag[i])) for i in range(n)]

    def one_pass() -> None:
        filt = fused.FusedFilter(fused.FusedSettings(), MAG_REF_NED_UT)
        for sample in samples:
            filt.push(*sample)

    per_sample_s = best_time_s(one_pass, settings.pick(2, 3)) / n
    return [_row("fused", EXPECTED_ROWS["fused"][0], per_sample_s * 1e6, "µs")]


# --- the table and the machine ----------------------------------------------------------------------------


def render_table(rows: list[Row]) -> str:
    header = ["section", "figure", "measured", "target", "meets"]
    cells = [[r.section, r.figure, r.measured, r.target, r.verdict] for r in rows]
    lines = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    lines += ["| " + " | ".join(c.replace("|", "\\|") for c in row) + " |" for row in cells]
    return "\n".join(lines)


def _version(dist: str) -> str:
    try:
        return metadata.version(dist)
    except metadata.PackageNotFoundError:
        return "not installed"


def machine_description() -> list[str]:
    cpu = platform.processor() or platform.machine()
    cpuinfo = Path("/proc/cpuinfo")
    if cpuinfo.exists():
        names = [ln.split(":", 1)[1].strip() for ln in cpuinfo.read_text().splitlines() if ln.startswith("model name")]
        cpu = names[0] if names else cpu
    load = os.getloadavg() if hasattr(os, "getloadavg") else (float("nan"),) * 3
    libs = ", ".join(f"{d} {_version(d)}" for d in ("numpy", "scipy", "pymavlink", "ahrs"))
    return [
        f"- CPU: {cpu}, {os.cpu_count()} logical cores available to this process: {len(os.sched_getaffinity(0))}"
        if hasattr(os, "sched_getaffinity")
        else f"- CPU: {cpu}, {os.cpu_count()} logical cores",
        f"- OS: {platform.system()} {platform.release()} ({platform.machine()})",
        f"- Python: {platform.python_implementation()} {platform.python_version()}; {libs}",
        f"- Load average at start (1/5/15 min): {load[0]:.2f} / {load[1]:.2f} / {load[2]:.2f}",
        f"- Date (UTC): {datetime.datetime.now(datetime.timezone.utc):%Y-%m-%d %H:%M}",
    ]


def markdown_report(rows: list[Row], settings: Settings, argv: list[str]) -> str:
    mode = "quick (CI smoke run: small samples, noisy figures)" if settings.quick else "full"
    return "\n".join(
        [
            "# Benchmarks",
            "",
            f"Written by `tools/bench.py` ({mode}); regenerate with `python tools/bench.py` from the repository root.",
            "Times are the best of several repeats on a machine shared with other work; the target column is",
            "the figure the issues ask for. A row that says *not available* names the part that is missing.",
            "",
            "## Machine",
            "",
            *machine_description(),
            f"- Command: `mavattitude bench {' '.join(argv)}`".rstrip() + "",
            "",
            "## Results",
            "",
            render_table(rows),
            "",
        ]
    )


# --- the command ------------------------------------------------------------------------------------------


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "sections",
        nargs="*",
        metavar="SECTION",
        help=f"sections to run, any of: {', '.join(SECTIONS)} (default: all)",
    )
    parser.add_argument(
        "--quick",
        action="store_true",
        help="a smoke run in seconds (small sample counts, short link runs) for CI; figures are rough",
    )
    parser.add_argument(
        "-o",
        "--output",
        type=Path,
        default=None,
        help="also write the table and the machine's description as Markdown to this file (default: print only)",
    )


def run(args: argparse.Namespace) -> int:
    unknown = [s for s in args.sections if s not in SECTIONS]
    if unknown:
        raise ConfigError(f"unknown bench section {', '.join(unknown)}; choose from {', '.join(SECTIONS)}")
    settings = Settings(quick=args.quick)
    rows: list[Row] = []
    failed = False
    for name in args.sections or list(SECTIONS):
        section_rows, section_failed = run_section(name, settings)
        rows += section_rows
        failed |= section_failed
        print(f"bench: {name} done", file=sys.stderr, flush=True)
    print(render_table(rows))
    if args.output is not None:
        args.output.parent.mkdir(parents=True, exist_ok=True)
        argv = [*args.sections, *(["--quick"] if args.quick else [])]
        args.output.write_text(markdown_report(rows, settings, argv))
        print(f"written to {args.output}", file=sys.stderr)
    return 1 if failed else 0
