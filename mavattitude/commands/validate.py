"""`mavattitude validate`: score the estimators on real recordings (BROAD trials, a PX4 log).

Each recording goes through the service's streaming pipeline (screen, low-pass, 50 Hz resampling,
solve) and through ``solve_batch`` on the raw samples, for each method; a table per recording is
printed, and optionally written into a Markdown document with figures. See docs/validation.md.
"""

from __future__ import annotations

import argparse
import json
import logging
import sys
from collections.abc import Sequence
from pathlib import Path

import yaml

from mavattitude.commands._offline import Progress
from mavattitude.config import load_config
from mavattitude.errors import ConfigError
from mavattitude.estimation import METHODS, SNAPSHOT_METHODS
from mavattitude.files import refuse_overwriting
from mavattitude.validation import find_recordings, load_recording
from mavattitude.validation.report import markdown_table, text_table, write_markdown
from mavattitude.validation.runner import (
    PATHS,
    Evaluation,
    estimate_batch,
    estimate_stream,
    evaluate,
    validation_config,
)

NAME = "validate"
HELP = "score the estimators on real recordings with ground truth (BROAD) or an autopilot's attitude (PX4)"

log = logging.getLogger(__name__)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "paths",
        nargs="*",
        type=Path,
        default=[Path("../shared/data")],
        metavar="PATH",
        help="recording files (.csv / .csv.gz) or directories searched for them (default: ../shared/data)",
    )
    parser.add_argument(
        "--method",
        dest="methods",
        action="append",
        choices=METHODS,
        help="estimator to run; repeat for several (default: all of " + ", ".join(METHODS) + ")",
    )
    parser.add_argument(
        "--path",
        dest="paths_run",
        action="append",
        choices=PATHS,
        help="stream: the service's pipeline (filter, 50 Hz); batch: solve_batch on the raw samples "
        "(no fused). Repeat for both (default: both)",
    )
    parser.add_argument("--start", type=float, metavar="S", help="first second to use, from the file's start")
    parser.add_argument("--stop", type=float, metavar="S", help="second to stop at, from the file's start")
    parser.add_argument(
        "--config",
        type=Path,
        metavar="FILE",
        help="YAML config for the pipeline (filter, estimator, ...); its magnetic reference and sensor noise "
        "are replaced by those measured at the recording's opening rest (unless given with --set)",
    )
    parser.add_argument(
        "--set",
        dest="settings",
        action="append",
        default=[],
        metavar="KEY=VALUE",
        help="override one config key, YAML value, e.g. --set filter.cutoff_hz=5 (repeatable); applied last, "
        "so it also replaces the measured noise or magnetic reference",
    )
    parser.add_argument(
        "--peers",
        action="store_true",
        help="also run the peer filters VQF (causal) and imufusion on the raw samples (pip install .[test])",
    )
    parser.add_argument("--report", type=Path, metavar="MD", help="write the tables into this Markdown document")
    parser.add_argument("--figures", type=Path, metavar="DIR", help="save validation-*.png figures here (matplotlib)")
    parser.add_argument("--json", type=Path, metavar="FILE", help="write every score as JSON (for tuning scripts)")


def _settings(items: Sequence[str]) -> dict[str, object]:
    out = {}
    for item in items:
        key, sep, value = item.partition("=")
        if not sep or not key:
            raise ConfigError(f"--set {item!r}: expected KEY=VALUE, e.g. filter.cutoff_hz=5")
        out[key.strip()] = yaml.safe_load(value)
    return out


def _peer_estimates(recording):  # type: ignore[no-untyped-def]
    from mavattitude.validation.peers import PEERS, estimate_peer

    for name in PEERS:
        try:
            yield estimate_peer(recording, name)
        except ImportError as exc:
            raise ConfigError(f"--peers needs {name} (pip install .[test]): {exc}") from exc


def run(args: argparse.Namespace) -> int:
    settings = _settings(args.settings)
    base = load_config(args.config, overrides=settings)  # checked here, before any data is read
    runs = [
        (method, path)
        for method in args.methods or METHODS
        for path in args.paths_run or PATHS
        if path == "stream" or method in SNAPSHOT_METHODS  # the fused filter exists only as a stream
    ]
    if not runs:
        raise ConfigError("nothing to run: the fused method has no batch path (use --path stream)")
    files = [f for p in args.paths for f in find_recordings(p)]
    refuse_overwriting(files, args.report, args.json)
    results: dict[str, list[Evaluation]] = {}
    recordings = {}
    for file in files:
        recording = load_recording(file).slice(args.start, args.stop)
        recordings[recording.name] = recording
        evaluations = results.setdefault(recording.name, [])
        for method, path in runs:
            config = validation_config(recording, method, base, **settings)
            label = f"{recording.name} {path} {method}"
            if path == "stream":
                estimate = estimate_stream(recording, config, Progress(label, sys.stderr.isatty()))
            else:
                estimate = estimate_batch(recording, config)
            redraw = "\r" if sys.stderr.isatty() else ""  # over the terminal's percent line; a log gets lines
            print(f"{redraw}{label}: done in {estimate.elapsed_s:.1f} s", file=sys.stderr, flush=True)
            evaluations.append(evaluate(recording, estimate))
        if args.peers:
            for estimate in _peer_estimates(recording):
                print(f"{recording.name} peer {estimate.method}: done in {estimate.elapsed_s:.1f} s", file=sys.stderr)
                evaluations.append(evaluate(recording, estimate))
        print(text_table(f"\n{recording.name}  (degrees)", evaluations))
    if args.json:
        _write_json(args.json, results)
    if args.figures:
        _figures(args.figures, recordings, results)
    if args.report:
        write_markdown(args.report, _markdown(recordings, results, args))
    return 0


def _markdown(recordings, results, args: argparse.Namespace) -> str:  # type: ignore[no-untyped-def]
    span = ""
    if args.start is not None or args.stop is not None:
        span = f" (slice {args.start or 0}–{args.stop or 'end'} s)"
    parts = [f"Generated by `tools/validate_real.py`{span}. Degrees; coverage = outputs / expected outputs."]
    for name, evaluations in results.items():
        ref = recordings[name].reference
        parts.append(
            f"### {name}\n\nMagnetic reference (NED, µT, measured at the opening rest "
            f"{ref.window_s[0]:.1f}–{ref.window_s[1]:.1f} s): "
            f"({ref.field_ned_uT[0]:.2f}, 0, {ref.field_ned_uT[2]:.2f}).\n\n{markdown_table(evaluations)}"
        )
        if args.figures:
            parts.append(f"![{name}](figures/validation-{_figure_key(name)}.png)")
    return "\n\n".join(parts)


def _figure_key(name: str) -> str:
    return name.split("_")[0]


def _figures(directory: Path, recordings, results) -> None:  # type: ignore[no-untyped-def]
    from mavattitude.validation.plots import broad_figure, px4_figure

    directory.mkdir(parents=True, exist_ok=True)
    for name, evaluations in results.items():
        recording = recordings[name]
        draw = broad_figure if recording.kind == "broad" else px4_figure
        draw(recording, evaluations, directory / f"validation-{_figure_key(name)}.png")


def _write_json(path: Path, results) -> None:  # type: ignore[no-untyped-def]
    data = {
        name: [
            {
                "path": ev.estimate.path,
                "method": ev.estimate.method,
                "coverage": ev.estimate.coverage,
                "elapsed_s": ev.estimate.elapsed_s,
                "counters": dict(ev.estimate.counters),
                **ev.score.columns(),
            }
            for ev in evaluations
        ]
        for name, evaluations in results.items()
    }
    path.write_text(json.dumps(data, indent=2), encoding="utf-8")
