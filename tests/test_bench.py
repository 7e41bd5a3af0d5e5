"""The benchmark tool: `tools/bench.py --quick` runs in seconds and prints the one table with every figure.

It measures, it does not judge: whether a figure meets its target is reported in the table and in the
exit code, never asserted here (speed targets are not timed tests). What is asserted is that every
expected row is there with a number, that the exit code agrees with the table, and that a broken part
fails the run. The tool imports the project's modules directly, so a broken import fails loading it here.
"""

from __future__ import annotations

import re
import subprocess
import sys
from pathlib import Path

import pytest

from tests.shared import shared_path
from tests.tools import ROOT, load_tool

QUICK_TIMEOUT_S = 120  # the quick run takes seconds; this only bounds a hung one
# A number with its unit (possibly followed by detail: "0 of 3995", "2000 Hz (tried 2000 Hz)"), or "none (...)".
MEASURED = re.compile(r"^(-?[0-9.]+(e[-+]?\d+)?( \S+|,)|none \()")


bench = load_tool("bench")


def _table_rows(text: str) -> dict[tuple[str, str], tuple[str, str]]:
    """(section, figure) -> (measured, meets) of every row of the table in ``text``."""
    rows = {}
    for line in text.splitlines():
        cells = [c.strip() for c in line.strip().strip("|").split(" | ")]
        if line.startswith("| ") and len(cells) == 5 and cells[0] != "section":
            rows[(cells[0], cells[1])] = (cells[2], cells[4])
    return rows


def test_quick_run_prints_every_figure_as_a_number_and_exits_by_its_verdicts(tmp_path):
    shared_path("data", "px4", "sample.ulg")  # the replay section times pyulog on this real log
    out = tmp_path / "bench.md"
    result = subprocess.run(
        [sys.executable, str(ROOT / "tools" / "bench.py"), "--quick", "--output", str(out)],
        capture_output=True,
        text=True,
        timeout=QUICK_TIMEOUT_S,
        stdin=subprocess.DEVNULL,
        cwd=tmp_path,
    )
    rows = _table_rows(result.stdout)
    expected = {(name, figure) for name, figures in bench.EXPECTED_ROWS.items() for figure in figures}
    assert set(rows) == expected, result.stdout + result.stderr
    for key, (measured, _) in rows.items():
        assert MEASURED.match(measured), (key, measured)
    # A loaded machine may miss a speed target (exit 3, the misses named); anything else must be 0.
    missed = [key for key, (_, meets) in rows.items() if meets == "no"]
    assert result.returncode == (bench.EXIT_TARGET_MISSED if missed else 0), result.stdout + result.stderr
    assert all(f"target missed: {section}: {figure}:" in result.stderr for section, figure in missed)
    report = out.read_text()
    assert "## Machine" in report and "- Python:" in report
    assert "- Command: `python tools/bench.py --quick`" in report
    assert _table_rows(report) == rows


def _meeting(settings):
    return [bench._row("solver", "f", 12.0, "µs", 20.0)]


def _missing(settings):
    return [bench._row("solver", "f", 25.0, "µs", 20.0), bench._row("solver", "g", 1.0, "µs")]


def _broken(settings):
    raise RuntimeError("solver exploded")


@pytest.mark.parametrize(
    ("section", "code"),
    [(_meeting, 0), (_missing, bench.EXIT_TARGET_MISSED), (_broken, bench.EXIT_FAILED)],
)
def test_the_exit_code_says_whether_every_section_ran_and_met_its_targets(monkeypatch, capsys, section, code):
    monkeypatch.setitem(bench.SECTIONS, "solver", section)
    assert bench.main(["solver", "--quick"]) == code
    out, err = capsys.readouterr()
    assert ("target missed: solver: f: 25 µs (target ≤ 20 µs)" in err) == (code == bench.EXIT_TARGET_MISSED)
    assert ("failed: RuntimeError: solver exploded" in out) == (code == bench.EXIT_FAILED)


def test_unknown_section_is_a_usage_error(capsys):
    with pytest.raises(SystemExit, match="2"):
        bench.parse_args(["nope"])
    assert "unknown bench section nope; choose from solver, " in capsys.readouterr().err


def test_verdict_follows_the_direction_of_the_target():
    assert bench._row("s", "f", 12.0, "µs", 20.0).verdict == "yes"
    assert bench._row("s", "f", 25.0, "µs", 20.0).verdict == "no"
    assert bench._row("s", "f", 4e5, "samples/s", 5e5, higher_is_better=True).verdict == "no"
    assert bench._row("s", "f", 1.0, "µs").target == ""


def test_the_record_is_written_only_on_a_full_run_of_every_section():
    assert bench.parse_args([]).output == ROOT / "docs" / "benchmarks.md"
    assert bench.parse_args(["--quick"]).output is None  # a smoke run never overwrites the record
    assert bench.parse_args(["soak"]).output is None  # nor does one section
    assert bench.parse_args(["-o", "x.md"]).output == Path("x.md")
