"""Figures of the validation (matplotlib is the optional ``plot`` extra, imported only here, on use).

Only the curves that tell the story are drawn, when present: the per-sample TRIAD baseline (batch
triad), the service's pipeline (stream ign), the gyro-aided filter (stream fused) and the state of the
art (peer vqf); the tables carry every method.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from mavattitude.estimation.conventions import Array, euler_from_quat
from mavattitude.validation.loaders import Recording

if TYPE_CHECKING:  # only for annotations: runner imports the pipeline
    from mavattitude.validation.runner import Evaluation

SHOWN = (("batch", "triad", "0.6"), ("stream", "ign", "C0"), ("stream", "fused", "C3"), ("peer", "vqf", "C2"))
RMS_WINDOW_S = 0.5
PX4_ZOOM_S = (1.5, 7.5)  # the hand movement in the bench log


def _pyplot():  # type: ignore[no-untyped-def]
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def _shown(evaluations: Sequence[Evaluation]):  # type: ignore[no-untyped-def]
    by_key = {(ev.estimate.path, ev.estimate.method): ev for ev in evaluations}
    return [(by_key[(p, m)], color) for p, m, color in SHOWN if (p, m) in by_key]


def running_rms(time_s: Array, x: Array, window_s: float) -> Array:
    """RMS of ``x`` over the trailing ``window_s`` at each sample (NaN samples ignored)."""
    ok = ~np.isnan(x)
    sq = np.concatenate([[0.0], np.cumsum(np.where(ok, x, 0.0) ** 2)])
    n = np.concatenate([[0], np.cumsum(ok)])
    start = np.searchsorted(time_s, time_s - window_s, side="left")
    end = np.arange(1, len(x) + 1)
    count = n[end] - n[start]
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.sqrt((sq[end] - sq[start]) / count)


def _shade_movement(ax, recording: Recording) -> None:  # type: ignore[no-untyped-def]
    t = recording.time_s - recording.time_s[0]
    edges = np.flatnonzero(np.diff(np.r_[0, recording.movement.astype(int), 0]))
    for start, stop in zip(edges[::2], edges[1::2], strict=True):
        ax.axvspan(t[start], t[stop - 1], color="0.9", lw=0)


def broad_figure(recording: Recording, evaluations: Sequence[Evaluation], path: Path) -> None:
    """Total, heading and inclination error over time (0.5 s running RMS), movement phases shaded."""
    plt = _pyplot()
    fig, axes = plt.subplots(3, 1, figsize=(11, 8), sharex=True)
    for i, (ax, label) in enumerate(zip(axes, ("total", "heading", "inclination"), strict=True)):
        _shade_movement(ax, recording)
        for ev, color in _shown(evaluations):
            t = ev.estimate.time_s
            rms = running_rms(t, ev.errors_rad[:, i], RMS_WINDOW_S)
            ax.plot(t - recording.time_s[0], np.degrees(rms), lw=0.9, color=color, label=_label(ev))
        ax.set_ylabel(f"{label} error, °")
        ax.set_yscale("log")
        ax.set_ylim(0.05, 180)
        ax.grid(True, which="major", lw=0.3)
    axes[0].set_title(
        f"{recording.name}: error vs optical ground truth, {RMS_WINDOW_S} s running RMS (grey: movement phases)",
        fontsize=10,
    )
    axes[0].legend(loc="upper right", fontsize=8, ncol=4)
    axes[-1].set_xlabel("time from the start of the trial, s")
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)


def _label(ev: Evaluation) -> str:
    return f"{ev.estimate.path} {ev.estimate.method}"


def px4_figure(recording: Recording, evaluations: Sequence[Evaluation], path: Path) -> None:
    """Roll, pitch and yaw of our estimates over the autopilot's: the whole log, and the movement zoomed."""
    plt = _pyplot()
    fig, axes = plt.subplots(3, 2, figsize=(12, 8), sharex="col", gridspec_kw={"width_ratios": [2, 1]})
    t0 = recording.time_s[0]
    truth = np.degrees(euler_from_quat(recording.truth_q))
    shown = [(ev, color, np.degrees(euler_from_quat(ev.estimate.q))) for ev, color in _shown(evaluations)]
    for i, label in enumerate(("roll", "pitch", "yaw")):
        for ax in axes[i]:
            for ev, color, ours in shown:
                ax.plot(ev.estimate.time_s - t0, ours[:, i], lw=0.7, color=color, label=_label(ev))
            ax.plot(recording.time_s - t0, truth[:, i], color="k", lw=1.0, ls="--", label="PX4 attitude_estimator_q")
            ax.grid(True, lw=0.3)
        axes[i, 0].set_ylabel(f"{label}, °")
        axes[i, 1].set_xlim(*PX4_ZOOM_S)
        zoom = (recording.time_s - t0 >= PX4_ZOOM_S[0]) & (recording.time_s - t0 <= PX4_ZOOM_S[1])
        lo, hi = truth[zoom, i].min(), truth[zoom, i].max()
        axes[i, 1].set_ylim(lo - 5, hi + 5)
        axes[i, 0].set_ylim(lo - 10, hi + 10)
    axes[0, 0].set_title(f"{recording.name}: ours over the autopilot's (yaw from magnetic north)", fontsize=10)
    axes[0, 1].set_title("the hand movement", fontsize=10)
    axes[0, 0].legend(loc="upper right", fontsize=7, ncol=2)
    for ax in axes[-1]:
        ax.set_xlabel("time from the start of the log, s")
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)
