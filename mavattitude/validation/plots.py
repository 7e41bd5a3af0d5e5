"""Figures of the validation (matplotlib is the optional ``plot`` extra, imported only here, on use)."""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from mavattitude.estimation.conventions import euler_from_quat
from mavattitude.validation.loaders import Recording

if TYPE_CHECKING:  # only for annotations: runner imports the pipeline
    from mavattitude.validation.runner import Evaluation


def _pyplot():  # type: ignore[no-untyped-def]
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def _shade_movement(ax, recording: Recording) -> None:  # type: ignore[no-untyped-def]
    t = recording.time_s - recording.time_s[0]
    edges = np.flatnonzero(np.diff(np.r_[0, recording.movement.astype(int), 0]))
    for start, stop in zip(edges[::2], edges[1::2], strict=True):
        ax.axvspan(t[start], t[stop - 1], color="0.88", lw=0)


def broad_figure(recording: Recording, evaluations: Sequence[Evaluation], path: Path) -> None:
    """Total and heading/inclination error over time, movement phases shaded."""
    plt = _pyplot()
    fig, axes = plt.subplots(3, 1, figsize=(11, 8), sharex=True)
    for i, (ax, label) in enumerate(zip(axes, ("total", "heading", "inclination"), strict=True)):
        _shade_movement(ax, recording)
        for ev in evaluations:
            t = ev.estimate.time_s - recording.time_s[0]
            ax.plot(t, np.degrees(ev.errors_rad[:, i]), lw=0.6, label=f"{ev.estimate.path} {ev.estimate.method}")
        ax.set_ylabel(f"{label} error, °")
        ax.set_yscale("log")
        ax.set_ylim(0.01, 180)
    axes[0].set_title(f"{recording.name}: error against the optical ground truth (grey: movement phases)")
    axes[0].legend(loc="upper right", fontsize=8, ncol=3)
    axes[-1].set_xlabel("time from the start of the trial, s")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def px4_figure(recording: Recording, evaluations: Sequence[Evaluation], path: Path) -> None:
    """Roll, pitch and yaw of our estimates over the autopilot's."""
    plt = _pyplot()
    fig, axes = plt.subplots(3, 1, figsize=(11, 8), sharex=True)
    t0 = recording.time_s[0]
    truth = np.degrees(euler_from_quat(recording.truth_q))
    for i, (ax, label) in enumerate(zip(axes, ("roll", "pitch", "yaw"), strict=True)):
        ax.plot(recording.time_s - t0, truth[:, i], color="k", lw=1.6, label="PX4 attitude_estimator_q")
        for ev in evaluations:
            ours = np.degrees(euler_from_quat(ev.estimate.q))
            ax.plot(ev.estimate.time_s - t0, ours[:, i], lw=0.7, label=f"{ev.estimate.path} {ev.estimate.method}")
        ax.set_ylabel(f"{label}, °")
    axes[0].set_title(f"{recording.name}: our attitude over the autopilot's (yaw: magnetic north)")
    axes[0].legend(loc="upper right", fontsize=8, ncol=3)
    axes[-1].set_xlabel("time from the start of the log, s")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
