"""Readable plots: long series enveloped (extremes kept), angle wraps broken, and the replay figure built
from them with a title and both lines visible."""

from __future__ import annotations

import numpy as np
import pytest

from mavattitude.estimation.conventions import quat_from_euler
from mavattitude.plotting import MAX_POINTS, angle_series, break_wraps, envelope, spans


def _wrapping_yaw(n: int) -> tuple[np.ndarray, np.ndarray]:
    t = np.arange(n) * 0.004  # 250 000 samples: 1000 s at 250 Hz, a long log
    yaw = (t * 7.0 + 180.0) % 360.0 - 180.0  # turning 7°/s: wraps every ~51 s
    return t, yaw


def test_a_long_series_is_enveloped_and_keeps_its_spikes() -> None:
    t = np.arange(250_000) * 0.004
    y = np.sin(t)
    y[123_457] = 40.0  # one spike that plain striding would skip
    te, ye = envelope(t, y)
    assert len(te) <= MAX_POINTS and np.all(np.diff(te) >= 0)
    assert ye.max() == 40.0 and ye.min() == pytest.approx(-1.0, abs=1e-3)
    short = np.arange(10.0)
    assert np.array_equal(envelope(short, short)[1], short)  # a short series is drawn as it is


def test_a_wrap_is_a_gap_not_a_vertical_stroke() -> None:
    t, a = break_wraps([0.0, 1.0, 2.0, 3.0], [170.0, 179.0, -179.0, -170.0])
    assert np.isnan(a[2]) and np.isnan(t[2]) and list(a[[0, 1, 3, 4]]) == [170.0, 179.0, -179.0, -170.0]
    t, yaw = _wrapping_yaw(250_000)
    _, drawn = angle_series(t, yaw)
    finite_steps = np.abs(np.diff(drawn))
    assert np.nanmax(finite_steps) < 180.0  # no segment crosses the panel
    assert np.isnan(drawn).sum() == np.count_nonzero(np.abs(np.diff(yaw)) > 180.0)  # one gap per wrap


def test_the_replay_figure_is_titled_decimated_and_shows_both_attitudes() -> None:
    pytest.importorskip("matplotlib")
    import matplotlib.pyplot as plt

    from mavattitude.commands.replay import comparison_figure

    t, yaw = _wrapping_yaw(250_000)
    q = quat_from_euler(np.zeros_like(t), np.zeros_like(t), np.radians(yaw))
    ours_deg = np.column_stack([np.zeros_like(t), np.zeros_like(t), yaw])
    diff = np.zeros((len(t), 4))
    fig = comparison_figure("flight.tlog: mavattitude (ign) vs the autopilot's attitude", t, ours_deg, t, q, diff)
    try:
        axes = fig.axes
        assert axes[0].get_title().startswith("flight.tlog: mavattitude (ign)")
        for ax in axes:
            for line in ax.get_lines():
                assert len(line.get_xdata()) <= MAX_POINTS + 100  # + one gap per wrap
        ours_line, autopilot_line = axes[2].get_lines()
        assert ours_line.get_linewidth() > 2 * autopilot_line.get_linewidth()  # wide and pale under thin
        assert np.nanmax(np.abs(np.diff(autopilot_line.get_ydata()))) < 180.0
    finally:
        plt.close(fig)


def test_a_verdict_is_shaded_from_its_warning_to_its_clearing_or_the_end() -> None:
    changes = [(10.0, True), (14.0, False), (30.0, True)]
    assert spans(changes, 60.0) == [(10.0, 14.0), (30.0, 60.0)]
    assert spans([(5.0, False)], 60.0) == [] and spans([], 60.0) == []


def test_the_replay_figure_bars_where_the_cross_check_did_not_judge() -> None:
    pytest.importorskip("matplotlib")
    import matplotlib.pyplot as plt

    from mavattitude.commands.replay import Verdicts, comparison_figure

    t = np.arange(0.0, 60.0, 0.1)
    q = quat_from_euler(np.zeros_like(t), np.zeros_like(t), np.zeros_like(t))
    # pairs at 5, 6, 8, 9, 50 s: the first two not judged, then judged, the last not judged to the end
    unjudged = [(5.0, True), (6.0, True), (8.0, False), (9.0, False), (50.0, True)]
    verdicts = Verdicts(unjudged=unjudged)
    fig = comparison_figure("f.tlog", t, np.zeros((len(t), 3)), t, q, np.zeros((len(t), 4)), verdicts)
    try:
        bars = [(p.get_x(), p.get_x() + p.get_width()) for p in fig.axes[3].patches]
        assert bars == [(5.0, 8.0), (50.0, pytest.approx(t[-1]))]
        assert "cross-check warned 0× (40 % judged)" in fig.axes[0].get_title()
    finally:
        plt.close(fig)


def test_the_replay_figure_marks_the_compass_and_cross_check_verdicts() -> None:
    pytest.importorskip("matplotlib")
    import matplotlib.pyplot as plt

    from mavattitude.commands.replay import Verdicts, comparison_figure

    t = np.arange(0.0, 60.0, 0.1)
    q = quat_from_euler(np.zeros_like(t), np.zeros_like(t), np.zeros_like(t))
    ours_deg = np.zeros((len(t), 3))
    diff = np.zeros((len(t), 4))
    verdicts = Verdicts(compass=[(20.0, True), (25.0, False)], crosscheck=[(40.0, True)], threshold_deg=5.0)
    fig = comparison_figure("f.tlog", t, ours_deg, t, q, diff, verdicts)
    try:
        axes = fig.axes
        labels = {text.get_text() for ax in axes if ax.get_legend() for text in ax.get_legend().get_texts()}
        assert {"compass judged off", "cross-check warned", "cross-check threshold"} <= labels
        shaded = [(p.get_x(), p.get_x() + p.get_width()) for p in axes[3].patches]
        assert shaded == [(20.0, 25.0), (40.0, pytest.approx(t[-1]))]  # the warning never cleared: to the end
        assert all(len(ax.patches) >= 1 for ax in axes[:3])  # the compass verdict on every panel
        assert axes[0].get_title().endswith("compass judged off 1×, cross-check warned 1×")  # all judged: not said
    finally:
        plt.close(fig)
