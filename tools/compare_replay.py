"""What a change did to the answers: the same logs replayed by an earlier commit and by this checkout, compared.

    .venv/bin/python tools/compare_replay.py BASE LOG... [--method fused] [-j 2]

BASE is any commit git knows (``HEAD~3``, a hash). It is checked out in a temporary git worktree and replayed
*from that directory*: ``python -m`` puts the current directory first on ``sys.path``, so a baseline started
from the checkout (``PYTHONPATH=worktree python -m mavattitude``) would run the checkout's code and compare it
with itself. Each side's ``mavattitude`` is checked to be the one meant before its replay. Every CSV is then
compared byte for byte, and where one differs, by the largest angle between the two attitudes of a row; the
summaries are compared but for the output directory they name. Exit 0: identical; 1: a difference; 2: an
error (a commit git does not know, a replay that failed).
"""

from __future__ import annotations

import argparse
import csv
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

from mavattitude.estimation.conventions import angle_between

ROOT = Path(__file__).resolve().parent.parent
QUATERNION = ("qw", "qx", "qy", "qz")


class Failed(Exception):
    """A side could not be replayed as meant."""


def _package_dir(cwd: Path) -> Path:
    """The mavattitude package a ``python -m mavattitude`` started in ``cwd`` imports."""
    done = subprocess.run(
        [sys.executable, "-c", "import mavattitude; print(mavattitude.__file__)"],
        cwd=cwd,
        capture_output=True,
        text=True,
        check=True,
    )
    return Path(done.stdout.strip()).parent


def _replay(cwd: Path, logs: list[Path], out: Path, options: list[str]) -> None:
    if _package_dir(cwd) != cwd / "mavattitude":
        raise Failed(f"python -m mavattitude in {cwd} does not import {cwd / 'mavattitude'}")
    cmd = [sys.executable, "-m", "mavattitude", "--log-level", "WARNING", "replay", *map(str, logs)]
    done = subprocess.run([*cmd, "-o", str(out), "--no-plot", *options], cwd=cwd, capture_output=True, text=True)
    if not (out / "summary.csv").exists():  # a log that is damaged still has its row; no summary is a failure
        raise Failed(f"the replay in {cwd} failed:\n{done.stderr[-2000:]}")


def _largest_angle_rad(a: Path, b: Path) -> float:
    """The largest angle between the two files' attitudes, row by row (inf when the rows differ in number)."""
    qa, qb = (np.genfromtxt(p, delimiter=",", names=True) for p in (a, b))
    if len(qa) != len(qb):
        return float("inf")
    q = [np.column_stack([rows[c] for c in QUATERNION]) for rows in (qa, qb)]
    return float(np.max(angle_between(*q), initial=0.0))


def _summary_rows(path: Path) -> list[dict[str, str]]:
    """The summary's rows, the output directory each names taken out."""
    with path.open(encoding="utf-8") as f:
        return [{k: v.replace(str(path.parent), "OUT") for k, v in row.items()} for row in csv.DictReader(f)]


def compare(base_out: Path, new_out: Path) -> list[str]:
    """A line per difference between the two replays' outputs (none: identical)."""
    found = []
    names = sorted({p.name for p in (*base_out.glob("*.csv"), *new_out.glob("*.csv"))} - {"summary.csv"})
    for name in names:
        a, b = base_out / name, new_out / name
        if not (a.exists() and b.exists()):
            found.append(f"{name}: written by {'this checkout' if b.exists() else 'the base'} only")
        elif a.read_bytes() != b.read_bytes():
            found.append(f"{name}: differs, by {_largest_angle_rad(a, b):.3g} rad at most")
    if _summary_rows(base_out / "summary.csv") != _summary_rows(new_out / "summary.csv"):
        found.append("summary.csv: differs")
    return found


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("base", help="the commit to compare with (HEAD~1, a hash)")
    parser.add_argument("logs", nargs="+", type=Path, help="logs or directories of logs, as replay takes them")
    parser.add_argument("--method", help="replay's --method, on both sides")
    parser.add_argument("-j", "--jobs", default="1", help="replay's -j, on both sides")
    args = parser.parse_args(argv)
    options = ["-j", args.jobs, *(["--method", args.method] if args.method else [])]
    logs = [p.resolve() for p in args.logs]
    with tempfile.TemporaryDirectory(prefix="compare-replay-") as tmp:
        worktree = Path(tmp) / "base"
        added = subprocess.run(
            ["git", "-C", str(ROOT), "worktree", "add", "--detach", str(worktree), args.base],
            capture_output=True,
            text=True,
        )
        if added.returncode != 0:
            print(f"compare_replay: {added.stderr.strip()}", file=sys.stderr)
            return 2
        try:
            _replay(worktree, logs, Path(tmp) / "base-out", options)
            _replay(ROOT, logs, Path(tmp) / "new-out", options)
        except Failed as exc:
            print(f"compare_replay: {exc}", file=sys.stderr)
            return 2
        finally:
            subprocess.run(["git", "-C", str(ROOT), "worktree", "remove", "--force", str(worktree)], check=False)
        found = compare(Path(tmp) / "base-out", Path(tmp) / "new-out")
    for line in found:
        print(line)
    print(f"{args.base} and this checkout: " + (f"{len(found)} difference(s)" if found else "identical"))
    return 1 if found else 0


if __name__ == "__main__":
    sys.exit(main())
