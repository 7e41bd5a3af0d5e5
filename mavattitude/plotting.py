"""Time series drawn so they can be read: decimated keeping their extremes, angle wraps broken.

matplotlib is the optional ``plot`` extra; nothing here imports it, so these are plain numpy and tested
without it. A line through 250 000 points is a solid band, and one through a yaw going from +180° to
−180° draws a vertical stroke across the panel that is not in the data: :func:`envelope` and
:func:`break_wraps` prepare the arrays the plotting code then draws.
"""

from __future__ import annotations

import itertools

import numpy as np
from numpy.typing import ArrayLike

from mavattitude.estimation.conventions import Array

MAX_POINTS = 4000  # per line: more than a figure's pixels across


def envelope(t: ArrayLike, y: ArrayLike, max_points: int = MAX_POINTS) -> tuple[Array, Array]:
    """``(t, y)`` with at most ``max_points`` points: each bin of consecutive samples becomes its minimum and
    its maximum (in time order), so spikes stay visible where plain striding would skip them."""
    t, y = np.asarray(t, dtype=float), np.asarray(y, dtype=float)
    bins = max(max_points // 2, 1)
    if len(t) <= max_points:
        return t, y
    edges = np.linspace(0, len(t), bins + 1).astype(int)
    t_out, y_out = [], []
    for lo, hi in itertools.pairwise(edges):
        seg = y[lo:hi]
        if np.all(np.isnan(seg)):
            t_out += [t[lo]]
            y_out += [np.nan]
            continue
        i, j = sorted((lo + int(np.nanargmin(seg)), lo + int(np.nanargmax(seg))))
        t_out += [t[i], t[j]]
        y_out += [y[i], y[j]]
    return np.array(t_out), np.array(y_out)


def break_wraps(t: ArrayLike, angle_deg: ArrayLike, period_deg: float = 360.0) -> tuple[Array, Array]:
    """``(t, angle)`` with a NaN between two samples that wrap (jump by more than half a period), so a line
    through them stops at one edge of the panel and starts again at the other."""
    t, a = np.asarray(t, dtype=float), np.asarray(angle_deg, dtype=float)
    jumps = np.flatnonzero(np.abs(np.diff(a)) > period_deg / 2) + 1
    return np.insert(t, jumps, np.nan), np.insert(a, jumps, np.nan)


def angle_series(t: ArrayLike, angle_deg: ArrayLike, max_points: int = MAX_POINTS) -> tuple[Array, Array]:
    """An angle ready to draw: enveloped, then its wraps broken."""
    return break_wraps(*envelope(t, angle_deg, max_points))


def spans(changes: list[tuple[float, bool]], end_s: float) -> list[tuple[float, float]]:
    """The intervals a verdict held, from its changes ``(time_s, on)`` in time order: from each turn on to the
    next turn off, or to ``end_s`` when it never turned off."""
    out: list[tuple[float, float]] = []
    since: float | None = None
    for time_s, on in changes:
        if on and since is None:
            since = time_s
        elif not on and since is not None:
            out.append((since, time_s))
            since = None
    if since is not None:
        out.append((since, end_s))
    return out
