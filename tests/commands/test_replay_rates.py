"""`replay` at whatever rates a log has: every autopilot attitude inside our output span compared, or why not."""

from __future__ import annotations

import csv
from pathlib import Path

from mavattitude.cli import main
from tests.shared import shared_path

CONFIG = Path(__file__).resolve().parents[2] / "configs" / "ardupilot.yaml"
MIN_SHARE_PCT = 95.0  # the target: the autopilot's attitudes inside our output span that are compared


def summary_row(out: Path) -> dict[str, str]:
    with (out / "summary.csv").open(encoding="utf-8") as f:
        (row,) = csv.DictReader(f)
    return row


def replay_dir(tmp_path: Path, log: Path, *args: str) -> dict[str, str]:
    """One log replayed into a directory (its summary row: the columns this file checks)."""
    out = tmp_path / "out"
    main(["replay", str(log), "-o", str(out), "--config", str(CONFIG), "--no-plot", *args])
    return summary_row(out)


def test_ours_starting_at_the_first_gps_fix_still_pair_every_later_autopilot_attitude(tmp_path):
    """twocompass.tlog: ATTITUDE at 50 Hz from the start, ours from the GPS position on; only 250 were compared
    when the replay's pairing ran one output ahead per autopilot attitude before our first."""
    row = replay_dir(tmp_path, shared_path("data", "ardupilot-sitl", "twocompass.tlog"))
    assert float(row["compared_pct"]) >= MIN_SHARE_PCT and int(row["compared"]) > 10_000
