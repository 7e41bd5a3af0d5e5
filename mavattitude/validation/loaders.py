"""Loaders for the real recordings in ``../shared/data`` (BROAD trials and a PX4 log), gzip CSV.

Each file becomes a :class:`Recording`: SI sensor arrays in the body frame the estimators see, the
reference attitude as body → NED (BROAD's sensor → ENU ground truth converted, see
:mod:`mavattitude.validation.frames`; PX4's own estimate), the scoring masks, and the references measured
on the *whole* file's opening rest, so that a slice is scored against the same references as the file.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from mavattitude.errors import DataFileError
from mavattitude.estimation.conventions import Array, quat_normalize
from mavattitude.files import ACC_COLUMNS, GYR_COLUMNS, MAG_COLUMNS, TIME_COLUMN, load_numbers, open_text, reading
from mavattitude.validation.frames import RestReference, ned_from_enu, rest_reference

_SENSORS = (*ACC_COLUMNS, *GYR_COLUMNS, *MAG_COLUMNS)
BROAD_COLUMNS = (TIME_COLUMN, *_SENSORS, "gt_qw", "gt_qx", "gt_qy", "gt_qz", "movement")
PX4_COLUMNS = (TIME_COLUMN, *_SENSORS, "mag_new", "att_qw", "att_qx", "att_qy", "att_qz")

# BROAD scores rest samples at least this far from any movement sample (Laidig et al. 2021).
REST_DISTANCE_S = 1.0


@dataclass(frozen=True)
class Recording:
    """One real recording, as the validation sees it (N samples)."""

    name: str
    kind: str  # "broad" (optical ground truth) or "px4" (the autopilot's attitude)
    time_s: Array  # (N,) the recorder's clock
    acc_mps2: Array  # (N, 3) specific force, body frame
    gyr_radps: Array  # (N, 3)
    mag_uT: Array  # (N, 3)
    mag_new: Array  # (N,) bool: this row carries a new magnetometer reading (PX4 holds ~87 Hz values)
    truth_q: Array  # (N, 4) reference attitude body → NED; NaN rows where BROAD's markers were lost
    movement: Array  # (N,) bool, BROAD's movement phases (all False for PX4)
    rest: Array  # (N,) bool, rest samples ≥ REST_DISTANCE_S from movement (all False for PX4)
    reference: RestReference

    def __len__(self) -> int:
        return len(self.time_s)

    def slice(self, start_s: float | None = None, stop_s: float | None = None) -> Recording:
        """The samples from ``start_s`` to ``stop_s`` (seconds from the file's first sample)."""
        t = self.time_s - self.time_s[0]
        keep = (t >= (start_s if start_s is not None else -np.inf)) & (t < (stop_s if stop_s is not None else np.inf))
        if keep.sum() < 2:
            span = f"{start_s or 0:g} s to {'the end' if stop_s is None else f'{stop_s:g} s'}"
            raise DataFileError(f"{self.name}: {span} holds fewer than 2 samples (the recording is {t[-1]:.1f} s long)")
        arrays = {
            k: getattr(self, k)[keep]
            for k in ("time_s", "acc_mps2", "gyr_radps", "mag_uT", "mag_new", "truth_q", "movement", "rest")
        }
        return replace(self, **arrays)


def _read_csv(path: Path) -> dict[str, Array]:
    with reading(path), open_text(path, "r") as f:
        header = f.readline().strip().split(",")
        data = load_numbers(f, path, range(len(header)))
    if data.shape[1] != len(header) or len(data) < 2:
        raise DataFileError(f"{path}: {len(header)} columns in the header, rows of {data.shape[1]}, {len(data)} rows")
    return {name: data[:, i] for i, name in enumerate(header)}


def _stack(columns: dict[str, Array], names: list[str] | tuple[str, ...]) -> Array:
    return np.stack([columns[n] for n in names], axis=1)


def rest_mask(time_s: Array, movement: Array, distance_s: float = REST_DISTANCE_S) -> Array:
    """Rest samples at least ``distance_s`` from the nearest movement sample."""
    if not movement.any():
        return np.ones_like(movement, dtype=bool)
    t_move = time_s[movement]
    i = np.searchsorted(t_move, time_s)
    before = t_move[np.maximum(i - 1, 0)]
    after = t_move[np.minimum(i, len(t_move) - 1)]
    nearest = np.minimum(np.abs(time_s - before), np.abs(after - time_s))
    return ~movement & (nearest >= distance_s)


def load_recording(path: str | Path) -> Recording:
    """Read a BROAD trial or the PX4 log (told apart by their columns)."""
    path = Path(path)
    columns = _read_csv(path)
    name = path.name.removesuffix(".gz").removesuffix(".csv")
    if all(c in columns for c in BROAD_COLUMNS):
        kind = "broad"
        truth = ned_from_enu(_stack(columns, ("gt_qw", "gt_qx", "gt_qy", "gt_qz")))
        movement = columns["movement"] == 1
        rest = rest_mask(columns["t_s"], movement)
        mag_new = np.ones(len(movement), dtype=bool)
    elif all(c in columns for c in PX4_COLUMNS):
        kind = "px4"
        truth = _stack(columns, ("att_qw", "att_qx", "att_qy", "att_qz"))
        movement = rest = np.zeros(len(columns["t_s"]), dtype=bool)
        mag_new = columns["mag_new"] == 1
    else:
        raise DataFileError(f"{path}: neither a BROAD trial nor the PX4 log (columns: {', '.join(columns)})")
    time_s = columns["t_s"]
    if not np.all(np.diff(time_s) > 0):
        raise DataFileError(f"{path}: t_s is not strictly increasing")
    acc, gyr, mag = (_stack(columns, _SENSORS[i : i + 3]) for i in (0, 3, 6))
    return Recording(
        name=name,
        kind=kind,
        time_s=time_s,
        acc_mps2=acc,
        gyr_radps=gyr,
        mag_uT=mag,
        mag_new=mag_new,
        truth_q=quat_normalize(truth),
        movement=movement,
        rest=rest,
        reference=rest_reference(time_s, acc, gyr, mag),
    )


def find_recordings(root: str | Path) -> list[Path]:
    """Every ``*.csv.gz`` / ``*.csv`` under ``root`` (or ``root`` itself if it is a file), sorted."""
    root = Path(root)
    if root.is_file():
        return [root]
    files = sorted(p for p in root.rglob("*") if p.name.endswith((".csv.gz", ".csv")))
    if not files:
        raise DataFileError(f"{root}: no .csv or .csv.gz recordings found")
    return files


def truth_at(recording: Recording, time_s: Array) -> tuple[Array, Array, Array]:
    """Reference attitude, movement and rest flags at arbitrary instants (e.g. the pipeline's 50 Hz ticks).

    The attitude is the normalised linear interpolation of the two neighbouring samples (at BROAD's
    3.5 ms spacing it differs from slerp by < 1e-6 rad even at 770 °/s); NaN outside the recording or
    next to a sample without ground truth. The flags are the nearest sample's.
    """
    t = recording.time_s
    i = np.clip(np.searchsorted(t, time_s, side="right"), 1, len(t) - 1)
    frac = ((time_s - t[i - 1]) / (t[i] - t[i - 1]))[:, None]
    q0, q1 = recording.truth_q[i - 1], recording.truth_q[i]
    q1 = np.where((q0 * q1).sum(axis=1, keepdims=True) < 0.0, -q1, q1)  # same hemisphere before blending
    q = quat_normalize((1.0 - frac) * q0 + frac * q1)
    q[(time_s < t[0]) | (time_s > t[-1])] = np.nan
    nearest = np.where(frac[:, 0] < 0.5, i - 1, i)
    return q, recording.movement[nearest], recording.rest[nearest]
