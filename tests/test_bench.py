"""The benchmark tool: `tools/bench.py --quick` runs in seconds and prints the one table with every figure.

It measures, it does not judge: whether a figure meets its target is reported in the table, never
asserted here (speed targets are not timed tests). What is asserted is that every expected row is
there with a number or an honest reason, and that a broken part fails the run.
"""

from __future__ import annotations

import argparse
import importlib.util
import re
import subprocess
import sys
from pathlib import Path

import pytest

from mavattitude.commands import bench
from mavattitude.errors import ConfigError

ROOT = Path(__file__).resolve().parents[1]
QUICK_TIMEOUT_S = 120  # the quick run takes seconds; this only bounds a hung one
# A number with its unit (possibly followed by detail: "0 of 3995", "2000 Hz (tried 2000 Hz)"), or "none (...)".
MEASURED = re.compile(r"^(-?[0-9.]+(e[-+]?\d+)?( \S+|,)|none \()")


def _table_rows(text: str) -> dict[tuple[str, str], str]:
    rows = {}
    for line in text.splitlines():
        cells = [c.strip() for c in line.strip().strip("|").split(" | ")]
        if line.startswith("| ") and len(cells) == 5 and cells[0] != "section":
            rows[(cells[0], cells[1])] = cells[2]
    return rows


def test_quick_run_prints_every_figure_as_a_number_or_a_reason(tmp_path):
    out = tmp_path / "bench.md"
    result = subprocess.run(
        [sys.executable, str(ROOT / "tools" / "bench.py"), "--quick", "--output", str(out)],
        capture_output=True,
        text=True,
        timeout=QUICK_TIMEOUT_S,
        stdin=subprocess.DEVNULL,
        cwd=tmp_path,
    )
    assert result.returncode == 0, result.stdout + result.stderr
    rows = _table_rows(result.stdout)
    expected = {(name, figure) for name, figures in bench.EXPECTED_ROWS.items() for figure in figures}
    assert set(rows) == expected
    for key, measured in rows.items():
        assert MEASURED.match(measured) or measured.startswith("not available"), (key, measured)
    report = out.read_text()
    assert "## Machine" in report and "- Python:" in report
    assert _table_rows(report) == rows


def test_a_missing_part_is_not_available_with_its_reason(monkeypatch):
    def missing(settings):
        bench._require("mavattitude_no_such_module", "the part under test")

    monkeypatch.setitem(bench.SECTIONS, "solver", missing)
    rows, failed = bench.run_section("solver", bench.Settings(quick=True))
    assert not failed
    assert [r.figure for r in rows] == bench.EXPECTED_ROWS["solver"]
    assert rows[0].measured.startswith("not available: the part under test")
    assert all(r.measured.startswith("not available") for r in rows)


def test_a_broken_part_fails_the_run(monkeypatch, capsys):
    def broken(settings):
        raise RuntimeError("solver exploded")

    monkeypatch.setitem(bench.SECTIONS, "solver", broken)
    args = bench_args(["solver", "--quick"])
    assert bench.run(args) == 1
    assert "failed: RuntimeError: solver exploded" in capsys.readouterr().out


def test_unknown_section_is_a_user_error():
    with pytest.raises(ConfigError, match="unknown bench section nope"):
        bench.run(bench_args(["nope"]))


def test_verdict_follows_the_direction_of_the_target():
    assert bench._row("s", "f", 12.0, "µs", 20.0).verdict == "yes"
    assert bench._row("s", "f", 25.0, "µs", 20.0).verdict == "no"
    assert bench._row("s", "f", 4e5, "samples/s", 5e5, higher_is_better=True).verdict == "no"
    assert bench._row("s", "f", 1.0, "µs").target == ""


def bench_args(argv: list[str]) -> argparse.Namespace:
    parser = argparse.ArgumentParser()
    bench.add_arguments(parser)
    return parser.parse_args(argv)


def test_tools_bench_writes_the_record_only_on_a_full_run_of_every_section():
    spec = importlib.util.spec_from_file_location("tools_bench", ROOT / "tools" / "bench.py")
    assert spec is not None and spec.loader is not None
    tool = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(tool)
    assert tool.bench_argv([]) == ["bench", "--output", str(ROOT / "docs" / "benchmarks.md")]
    assert tool.bench_argv(["--quick"]) == ["bench", "--quick"]  # a smoke run never overwrites the record
    assert tool.bench_argv(["soak"]) == ["bench", "soak"]  # nor does one section
    assert tool.bench_argv(["-o", "x.md"]) == ["bench", "-o", "x.md"]
