"""The autopilot cross-check: our attitude against the autopilot's, paired by vehicle time. No I/O.

The autopilot's attitude (ATTITUDE, ~10 Hz) is sparser than ours (50 Hz), so each of its attitudes is
paired with ours *interpolated to its time* (normalised linear interpolation between the two outputs
around it, no further apart than a gap of our stream: ``max_gap_s``, or more when our outputs are slower,
:func:`~.conventions.gap_limit_s` of their usual interval): no extrapolation, and an autopilot attitude that
arrives before our output for its time waits until that output is there. The difference is ours minus the
autopilot's: roll, pitch and yaw (ZYX Euler angles, each difference wrapped to ±180°: ours at −179° and the
autopilot's at +179° differ by 2°) and the total rotation angle between the two, degrees.

Every autopilot attitude is either paired or counted in :attr:`CrossCheck.unpaired` by why it was not:
``outside`` our output span (before our first output, or still waiting after our last), ``gap`` (our outputs
around it are further apart than a gap), ``reset`` (before our first output since our clock went back, or
waiting when the autopilot's did: a reboot), ``late`` (ours around it already forgotten, ``KEEP_S`` behind the
newest), ``overflow`` (more than ``MAX_WAITING`` waiting for our outputs) or ``invalid`` (not an attitude: a
quaternion not finite or shorter than ``MIN_NORM``; any other is normalised). All but ``outside`` are misses inside
our span (:attr:`CrossCheck.share`). The live service runs it on every output and autopilot attitude, so it works
on plain floats (numpy's per-call overhead on four-element arrays was most of its cost).

The verdict: *disagreeing* once the total stays above ``threshold_deg`` for ``hold_s`` of vehicle time,
*agreeing* again once it stays below ``CLEAR_FRACTION · threshold_deg`` for ``hold_s`` (hysteresis, so a
difference hovering at the threshold is said once, not at every crossing).

A snapshot solve (one accelerometer and magnetometer solve per tick, no gyro: a snapshot method's, or any
method's on an input too slow to integrate) reads the specific force as gravity: while the vehicle accelerates
its tilt is off, and through the field's dip its heading more (a copter's 20° dash reads level), and in a fast
turn its heading trails. The gyro-aided filter without the GPS receiver's acceleration leans too, less and for
longer (it comes back over seconds). The difference is then ours being wrong, which the pilot cannot act on, so
such a pair is published and counted but not judged (:attr:`CrossCheck.unjudged`) when ours around it may read
acceleration as tilt while the vehicle moved (``moving``: turning faster than 10°/s, the specific force off g by
3 %, or ours turning unlike the gyro, :class:`GyroDrift`; :class:`mavattitude.pipeline.CrossCheckGate`) or within
``settle_s`` after (an acceleration a turn began lasts past it), and it restarts the hold: the verdict's
``hold_s`` is of judged pairs in a row. What the vehicle's own sensors cannot show stays: a steady acceleration
at a gentle tilt that ours had already settled into before it was judged (docs/vehicle.md).
"""

from __future__ import annotations

import bisect
import math
from collections import Counter, deque
from collections.abc import Iterable
from dataclasses import dataclass
from typing import ClassVar

import numpy as np

from mavattitude.fields import described, ranged

from .conventions import (
    Quat,
    angle_between_parts,
    euler_from_quat_parts,
    gap_limit_s,
    quat_from_euler_parts,
    quat_from_rotvec_parts,
    quat_multiply_parts,
    wrap_deg,
)

CLEAR_FRACTION = 0.8
KEEP_S = 5.0  # our outputs kept for pairing, s of vehicle time
MAX_WAITING = 100  # autopilot attitudes waiting for our output (10 s at 10 Hz)
#: An autopilot attitude this far behind the newest waiting one is its clock started again (a reboot), as the
#: front end's clock takes an IMU time (``FrontEndSettings.reorder_window_s``); less is a datagram reordered
REBOOT_BACK_S = 1.0
MIN_NORM = 0.5  # an autopilot quaternion shorter than this is not a rotation gone slightly off unit length
#: Ours turning unlike the gyro: the rate of ours against the gyro's rotation, fitted over windows this long (the
#: mean of each half-window's residual; a snapshot's noise of about 0.6° an output on a real board, sample.ulg,
#: averages to 0.3°/s at 50 Hz), judged above this rate; outputs no further apart than the step (a slower output is
#: one unfiltered snapshot a sample: its rates are not integrable).
DRIFT_WINDOW_S = 1.0
DRIFT_LIMIT_DPS = 2.0
DRIFT_MAX_STEP_S = 0.1
#: The fitted rate's slow mean, taken out: a gyro's bias (a raw one's reaches degrees a second), which the vehicle
#: does not turn by, reads as ours turning steadily unlike the gyro. Started from the first window within the cap,
#: then learnt over this long from windows within the cap of it only (a manoeuvre's snapshot errors, tens of
#: degrees a second, would carry it off).
DRIFT_BIAS_S = 5.0
DRIFT_BIAS_CAP_DPS = 6.0


class GyroDrift:
    """Whether our attitude turns unlike the gyro: over each ``DRIFT_WINDOW_S``, ours against the window's first
    attitude carried by the body rates (a small rotation, body frame, per output), its second half's mean less its
    first half's over half a window, faster than ``DRIFT_LIMIT_DPS``. A snapshot solve under a steady acceleration
    at a gentle tilt (a copter's dash at 15°: |a| within 3 % of g, no turn, so not ``MOVING``) reads the tilt as
    level and comes round to it only as the speed settles, seconds later: its attitude moves while the gyro says
    the vehicle does not. A fault that keeps ours steadily off (a mounting, the autopilot's own drift) turns with
    the gyro and stays judged; a compass turned on its mount turns unlike it, and is the compass monitor's to say.
    The fitted rate is taken against its own slow mean (``DRIFT_BIAS_S``, from the first window within
    ``DRIFT_BIAS_CAP_DPS``), so a gyro's bias is not ours turning."""

    def __init__(self) -> None:
        self._last_s = -math.inf
        self._anchor: tuple[float, Quat] = (-math.inf, (1.0, 0.0, 0.0, 0.0))  # the window's first time, ours then
        self._carried: Quat = (1.0, 0.0, 0.0, 0.0)  # the body rates' rotation since
        self._halves = [[0.0, 0.0, 0.0, 0], [0.0, 0.0, 0.0, 0]]  # each half-window's residual sum and count
        self._bias: tuple[float, ...] | None = None  # the fitted rate's slow mean, rad/s, body frame
        self.drifting = False

    def update(self, time_s: float, q: Iterable[float], rates_radps: Iterable[float]) -> bool:
        """Take one of our outputs (``rates_radps``: body rates over the interval that ends at it); whether ours
        turned unlike the gyro over the last whole window."""
        ours = _quat(q)
        dt, self._last_s = time_s - self._last_s, time_s
        if not 0.0 < dt <= DRIFT_MAX_STEP_S:  # the first, a gap, a slow input, a clock gone back: start again
            self._start(time_s, ours)
            self.drifting = False
            return False
        wx, wy, wz = (float(w) * dt for w in rates_radps)
        self._carried = quat_multiply_parts(self._carried, quat_from_rotvec_parts(wx, wy, wz))
        since_s = time_s - self._anchor[0]
        w0, x0, y0, z0 = quat_multiply_parts(self._anchor[1], self._carried)
        # ours against the gyro's: (anchor ⊗ carried)⁻¹ ⊗ ours, small, as twice its vector part
        w, x, y, z = quat_multiply_parts((w0, -x0, -y0, -z0), ours)
        sign = 2.0 if w >= 0.0 else -2.0
        half = self._halves[since_s >= 0.5 * DRIFT_WINDOW_S]
        half[0] += sign * x
        half[1] += sign * y
        half[2] += sign * z
        half[3] += 1
        if since_s >= DRIFT_WINDOW_S:
            (a0, a1, a2, na), (b0, b1, b2, nb) = self._halves
            if na and nb:
                self.drifting = self._judge(((b0 / nb - a0 / na), (b1 / nb - a1 / na), (b2 / nb - a2 / na)), since_s)
            self._start(time_s, ours)
        return self.drifting

    def _judge(self, moved: tuple[float, float, float], since_s: float) -> bool:
        """Whether ``moved`` (the second half-window's mean residual less the first's, rad) is turning unlike the
        gyro beyond its slow mean; the mean then follows it."""
        rate = tuple(m / (0.5 * since_s) for m in moved)
        bias = self._bias
        off = math.degrees(math.dist(rate, (0.0, 0.0, 0.0) if bias is None else bias))
        if off > DRIFT_BIAS_CAP_DPS:
            return True
        if bias is None:  # the first window within the cap: its rate is the bias to start from
            self._bias = rate
            return False
        k = min(1.0, since_s / DRIFT_BIAS_S)
        self._bias = tuple(b + k * (r - b) for r, b in zip(rate, bias, strict=True))
        return off > DRIFT_LIMIT_DPS

    def _start(self, time_s: float, ours: Quat) -> None:
        self._anchor, self._carried = (time_s, ours), (1.0, 0.0, 0.0, 0.0)
        self._halves = [[0.0, 0.0, 0.0, 0], [0.0, 0.0, 0.0, 0]]


@dataclass(frozen=True)
class CrossCheckSettings:
    """The config's ``crosscheck`` section: whether and how often to compare, and the verdict's rule."""

    enabled: bool = described(True, "compare with the autopilot's ATTITUDE and publish the difference")
    attitude_rate_hz: float = ranged(10.0, "ATTITUDE rate asked of the autopilot, Hz", 0.0, 100.0, lo_open=True)
    publish_rate_hz: float = ranged(2.0, "NAMED_VALUE_FLOAT rate of the difference, Hz", 0.0, 50.0, lo_open=True)
    threshold_deg: float = ranged(5.0, "warn when the total difference stays above", 0.0, 180.0, lo_open=True)
    hold_s: float = ranged(3.0, "... for this long (and clear after as long below), s", 0.0, 600.0)
    settle_s: float = ranged(
        1.0,
        "with a snapshot method (or fused without GPS velocity), judge only this long after the vehicle last turned or"
        " accelerated, s",
        0.0,
        60.0,
    )
    max_gap_s: ClassVar[float] = 0.5  # our outputs further apart (and slower than 2.5 × their rhythm): not bridged


@dataclass(frozen=True)
class Difference:
    """Ours minus the autopilot's at the autopilot's ``time_s`` (vehicle clock), degrees."""

    time_s: float
    roll_deg: float
    pitch_deg: float
    yaw_deg: float
    total_deg: float
    judged: bool = True  # false: published, not judged (ours a snapshot solve while the vehicle moved)


@dataclass(frozen=True)
class CrossCheckEvent:
    """The verdict changed at ``time_s``: ``disagree`` (the total stayed above the threshold) or agree again."""

    time_s: float
    disagree: bool
    total_deg: float


def difference(time_s: float, ours: Quat, theirs: Quat, heading: bool = True, judged: bool = True) -> Difference:
    """Ours minus theirs (quaternions ``[w, x, y, z]`` body → NED) in degrees. ``heading`` false: ours has none
    (no magnetometer, yaw held at 0): the yaw difference is NaN and the total the tilt's alone (ours turned to
    their yaw). ``judged``: whether the verdict takes it (the module docstring)."""
    (r1, p1, y1), (r2, p2, y2) = euler_from_quat_parts(ours), euler_from_quat_parts(theirs)
    if not heading:
        ours, y1 = quat_from_euler_parts(r1, p1, y2), math.nan
    total = math.degrees(angle_between_parts(ours, theirs))
    roll, pitch, yaw = (wrap_deg(math.degrees(a - b)) for a, b in ((r1, r2), (p1, p2), (y1, y2)))
    return Difference(time_s, roll, pitch, yaw, total, judged)


def interpolate(t0: float, q0: Quat, t1: float, q1: Quat, t: float) -> Quat:
    """Normalised linear interpolation between two attitudes, the shorter way round."""
    if q0[0] * q1[0] + q0[1] * q1[1] + q0[2] * q1[2] + q0[3] * q1[3] < 0.0:
        q1 = (-q1[0], -q1[1], -q1[2], -q1[3])
    f = (t - t0) / (t1 - t0)
    w, x, y, z = (a + (b - a) * f for a, b in zip(q0, q1, strict=True))
    n = math.sqrt(w * w + x * x + y * y + z * z)
    return (w / n, x / n, y / n, z / n)


def _quat(q: Iterable[float]) -> Quat:
    """A quaternion as plain floats (an array row, a tuple from a message)."""
    w, x, y, z = map(float, q)
    return (w, x, y, z)


class CrossCheck:
    """Pairs the autopilot's attitudes with ours and judges the difference (see the module docstring)."""

    def __init__(self, settings: CrossCheckSettings) -> None:
        self.settings = settings
        self._times: deque[float] = deque()
        self._quats: deque[Quat] = deque()
        # for each of ours: 2 a heading judged, 1 one not judged (too uncertain), 0 none (no magnetometer)
        self._headings: deque[int] = deque()
        self._moved: deque[float] = deque()  # for each of ours, the time of the last moving one up to it
        # autopilot attitudes ahead of our outputs (bounded: while we output nothing, the oldest go)
        self._waiting: deque[tuple[float, Quat]] = deque()
        self._newest_autopilot_s = math.nan
        self._first_s = math.inf  # our first output since the start or our last reset
        self._dropped_s = -math.inf  # the newest of ours forgotten (KEEP_S behind the newest)
        self._resets = 0
        self.last: Difference | None = None
        self.pairs = 0
        self.unjudged = 0  # pairs not judged: ours reading acceleration as tilt while moving (or settle_s after)
        self.unpaired: Counter[str] = Counter()  # autopilot attitudes not paired, by why (module docstring)
        self.disagree = False
        self.warnings = 0
        self._sum_total2 = 0.0
        self._since: float | None = None  # when the total crossed to the other side of the verdict

    @property
    def rms_total_deg(self) -> float:
        return math.sqrt(self._sum_total2 / self.pairs) if self.pairs else math.nan

    @property
    def missed(self) -> int:
        """Autopilot attitudes inside our output span that were not paired."""
        return sum(n for reason, n in self.unpaired.items() if reason != "outside")

    @property
    def share(self) -> float:
        """The fraction of the autopilot's attitudes inside our output span that were paired (NaN: none)."""
        inside = self.pairs + self.missed
        return self.pairs / inside if inside else math.nan

    def add_ours(
        self, time_s: float, q: Iterable[float], heading: bool = True, moving: bool = False, judged_heading: bool = True
    ) -> None:
        """One of our attitudes; ``heading`` false: it has none (roll and pitch only); ``moving``: a snapshot
        solve while the vehicle turned or accelerated (the module docstring); ``judged_heading`` false: its heading
        is too uncertain to judge the autopilot's by (the difference keeps its yaw, the verdict takes the tilt's)."""
        if self._times and time_s <= self._times[-1]:  # our clock went back (a reboot): start over
            self._times.clear()
            self._quats.clear()
            self._headings.clear()
            self._moved.clear()
            self._resets += 1
            self._first_s, self._dropped_s = time_s, -math.inf
            self._since = None  # a verdict's hold is timed on one clock
        if not self._times:
            self._first_s = min(self._first_s, time_s)
        self._moved.append(time_s if moving else self._moved[-1] if self._moved else -math.inf)
        self._times.append(time_s)
        self._quats.append(_quat(q))
        self._headings.append(2 if heading and judged_heading else int(heading))
        while self._times[0] < time_s - KEEP_S:
            self._dropped_s = self._times.popleft()
            self._quats.popleft()
            self._headings.popleft()
            self._moved.popleft()

    def unpairable_offset_s(self) -> float | None:
        """How far the autopilot's clock is from ours (its newest attitude's time less our newest output's, s) when
        none of its attitudes was ever paired though both came, more than we keep apart (``KEEP_S``): its
        attitudes can never be paired (an IMU message stamped with Unix time, the attitude from another clock);
        else None."""
        if self.pairs or not self._times or self._newest_autopilot_s != self._newest_autopilot_s:
            return None
        offset_s = self._newest_autopilot_s - self._times[-1]
        return offset_s if abs(offset_s) > KEEP_S else None

    def add_autopilot(self, time_s: float, q: Iterable[float]) -> None:
        self._newest_autopilot_s = time_s
        w, x, y, z = map(float, q)
        norm = math.sqrt(w * w + x * x + y * y + z * z)
        if not MIN_NORM < norm < math.inf:  # NaN too
            self.unpaired["invalid"] += 1
            return
        waiting = self._waiting
        if waiting and time_s < waiting[-1][0] - REBOOT_BACK_S:  # its clock started again: those wait for nothing
            self.unpaired["reset"] += len(waiting)
            waiting.clear()
        if len(waiting) == MAX_WAITING:  # the oldest goes
            dropped_s = waiting.popleft()[0]
            self.unpaired["outside" if dropped_s < self._first_s else "overflow"] += 1
        waiting.append((time_s, (w / norm, x / norm, y / norm, z / norm)))

    def finish(self) -> None:
        """The end of the stream (a log's): what still waits for our outputs lies after our last one."""
        if self._waiting:
            self.unpaired["outside"] += len(self._waiting)
            self._waiting.clear()

    def update(self) -> tuple[list[Difference], list[CrossCheckEvent]]:
        """Pair every waiting autopilot attitude that our outputs now reach; the differences and verdicts."""
        diffs: list[Difference] = []
        events: list[CrossCheckEvent] = []
        while self._waiting and self._times and self._waiting[0][0] <= self._times[-1]:
            t, theirs = self._waiting.popleft()
            ours = self._ours_at(t)
            if isinstance(ours, str):
                self.unpaired[ours] += 1
                continue
            q, heading, moved_s = ours
            judged = t - moved_s > self.settings.settle_s  # (settle_s 0: a moving one itself is not judged)
            d = difference(t, q, theirs, heading > 0, judged)
            diffs.append(d)
            self.last = d
            self.pairs += 1
            self._sum_total2 += d.total_deg * d.total_deg
            if not judged:
                self.unjudged += 1
                self._since = None  # the hold is of judged pairs in a row
                continue
            total_deg = d.total_deg if heading != 1 else difference(t, q, theirs, False).total_deg
            event = self._judge(t, total_deg)
            if event is not None:
                events.append(event)
        return diffs, events

    def _ours_at(self, t: float) -> tuple[Quat, int, float] | str:
        """Ours at ``t`` (within our newest output's time), its heading (as kept: 2 judged, 1 not, 0 none) and when
        the vehicle last moved up to it, or why there is none."""
        times, headings, moved = self._times, self._headings, self._moved
        i = bisect.bisect_left(times, t)
        if times[i] == t:
            return self._quats[i], headings[i], moved[i]
        if i == 0:
            if t < self._first_s:
                return "reset" if self._resets else "outside"
            if t < self._dropped_s or not self._gap(self._dropped_s, times[0]):
                return "late"  # ours around it were there, but forgotten before it came
            return "gap"
        if self._gap(times[i - 1], times[i]):
            return "gap"
        q = interpolate(times[i - 1], self._quats[i - 1], times[i], self._quats[i], t)
        return q, min(headings[i - 1], headings[i]), moved[i]

    def _gap(self, before_s: float, after_s: float) -> bool:
        """Whether two of ours are too far apart to interpolate between."""
        dt = after_s - before_s
        return dt > self.settings.max_gap_s and dt > self._gap_limit_s()

    def _gap_limit_s(self) -> float:
        """The longest interval between our outputs that is bridged: their usual interval decides (a 2 Hz stream)."""
        times = self._times
        intervals = sorted(b - a for a, b in zip(times, list(times)[1:], strict=False))
        return gap_limit_s(self.settings.max_gap_s, intervals[len(intervals) // 2] if intervals else math.nan)

    def _judge(self, time_s: float, total_deg: float) -> CrossCheckEvent | None:
        s = self.settings
        beyond = total_deg > s.threshold_deg if not self.disagree else total_deg >= CLEAR_FRACTION * s.threshold_deg
        if beyond == self.disagree:  # on the side of the current verdict
            self._since = None
            return None
        if self._since is None:
            self._since = time_s
        if time_s - self._since < s.hold_s:
            return None
        self.disagree = not self.disagree
        self.warnings += self.disagree
        self._since = None
        return CrossCheckEvent(time_s, self.disagree, total_deg)


def cross_check_log(
    ours_t_s: np.ndarray,
    ours_q: np.ndarray,
    theirs_t_s: np.ndarray,
    theirs_q: np.ndarray,
    settings: CrossCheckSettings,
    ours_heading: np.ndarray | None = None,
    ours_moving: np.ndarray | None = None,
    ours_judged_heading: np.ndarray | None = None,
) -> tuple[CrossCheck, list[Difference], list[CrossCheckEvent]]:
    """The live cross-check over a whole log: both attitude series, each in the log's order, fed in vehicle-time
    order, as they arrive (``ours_heading``: which of ours have a heading, default all; ``ours_moving``: which
    are snapshot solves while the vehicle moved, default none; ``ours_judged_heading``: whose heading the verdict
    may judge by, default all). Where the vehicle
    rebooted both clocks go back: each series' k-th boot (its times going back as :meth:`CrossCheck.add_ours`
    and :meth:`CrossCheck.add_autopilot` tell a reboot) is merged with the other's k-th."""
    check = CrossCheck(settings)
    heading = [True] * len(ours_t_s) if ours_heading is None else ours_heading.tolist()
    moving = [False] * len(ours_t_s) if ours_moving is None else ours_moving.tolist()
    judged = [True] * len(ours_t_s) if ours_judged_heading is None else ours_judged_heading.tolist()
    diffs: list[Difference] = []
    events: list[CrossCheckEvent] = []
    j = 0
    ours, theirs = ours_t_s.tolist(), theirs_t_s.tolist()
    ours_boot, theirs_boot = _boots(ours_t_s, 0.0), _boots(theirs_t_s, REBOOT_BACK_S)
    for t, boot, q in zip(theirs, theirs_boot, theirs_q, strict=True):
        # ours of earlier boots, then of its boot up to the first at or past its time, as live: an attitude is
        # paired once ours reach past it
        while j < len(ours) and (
            ours_boot[j] < boot or (ours_boot[j] == boot and (j == 0 or ours_boot[j - 1] < boot or ours[j - 1] < t))
        ):
            check.add_ours(ours[j], ours_q[j], heading[j], moving[j], judged[j])
            j += 1
        check.add_autopilot(t, q)
        d, e = check.update()
        diffs += d
        events += e
    check.finish()
    return check, diffs, events


def _boots(t_s: np.ndarray, back_s: float) -> list[int]:
    """Each time's boot: how often the clock went back by more than ``back_s`` up to it."""
    return np.concatenate([[0], np.cumsum(np.diff(t_s) < -back_s)])[: len(t_s)].tolist()
