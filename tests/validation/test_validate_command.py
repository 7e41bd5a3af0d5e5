"""`mavattitude validate` end to end on a slice of the PX4 log, its errors, its running RMS, --set."""

from __future__ import annotations

import json

import numpy as np
import pytest

from mavattitude.cli import EXIT_USER_ERROR, main
from mavattitude.validation.plots import running_rms
from mavattitude.validation.runner import estimate_batch, evaluate, validation_config


def test_validate_writes_table_report_and_json(tmp_path, capsys, px4_csv) -> None:
    report, scores = tmp_path / "validation.md", tmp_path / "scores.json"
    argv = ["validate", str(px4_csv), "--stop", "10", "--method", "ign", "--method", "triad", "--path", "batch"]
    assert main([*argv, "--report", str(report), "--json", str(scores)]) == 0
    captured = capsys.readouterr()
    printed = captured.out
    assert "px4_sample_sensors" in printed and "roll rms" in printed
    assert "\r" not in captured.err and "px4_sample_sensors batch ign: done in" in captured.err  # not a terminal
    assert "| batch | triad |" in report.read_text()
    data = json.loads(scores.read_text())["px4_sample_sensors"]
    assert [(row["path"], row["method"]) for row in data] == [("batch", "ign"), ("batch", "triad")]
    assert all(0.0 < row["roll rms"] < 5.0 and row["coverage"] == 1.0 for row in data)


def test_validate_user_errors_exit_2(tmp_path, capsys, px4_csv) -> None:
    assert main(["validate", str(tmp_path)]) == EXIT_USER_ERROR
    assert "no .csv or .csv.gz recordings" in capsys.readouterr().err
    assert main(["validate", str(px4_csv), "--set", "filter.cutoff_hz"]) == EXIT_USER_ERROR
    assert "expected KEY=VALUE" in capsys.readouterr().err
    assert main(["validate", str(px4_csv), "--set", "filter.cutof_hz=5"]) == EXIT_USER_ERROR
    assert "did you mean cutoff_hz" in capsys.readouterr().err
    assert main(["validate", str(px4_csv), "--method", "fused", "--path", "batch"]) == EXIT_USER_ERROR
    assert "no batch path" in capsys.readouterr().err


def test_running_rms_over_a_trailing_window() -> None:
    t = np.arange(0.0, 2.0, 0.1)
    x = np.where(t < 1.0, 1.0, 3.0)
    x[3] = np.nan  # ignored, not propagated
    rms = running_rms(t, x, 0.45)  # windows of 5 samples (t − 0.45, t]
    assert rms[4] == 1.0 and rms[-1] == 3.0
    np.testing.assert_allclose(rms[12], np.sqrt((3 * 9 + 2 * 1) / 5))


def test_set_wins_over_the_measured_references(recordings) -> None:
    rec = recordings["px4"]
    config = validation_config(rec, "ign", **{"noise.mag_std_uT": 2.0, "filter.cutoff_hz": 5})
    assert config.noise.mag_std_uT == (2.0, 2.0, 2.0) and config.filter.cutoff_hz == 5.0
    assert config.noise.accel_std_mps2 == tuple(rec.reference.acc_std_mps2)  # the rest stays measured
    # The batch path uses the config's reference, so a --set reference reaches it: a field 10° east of
    # north turns every heading 10° east of the autopilot's magnetic one (whose own offset is −0.2°).
    east = validation_config(
        rec.slice(10, 20), "triad", **{"reference.magnetic": {"declination_deg": 10.0, "inclination_deg": 63.5}}
    )
    score = evaluate(rec.slice(10, 20), estimate_batch(rec.slice(10, 20), east)).score  # at rest: ±0.1°
    assert score.heading_mean_deg == pytest.approx(10.0 - 0.2, abs=0.5)
