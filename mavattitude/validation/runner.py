"""Run a recording through the estimators, the way the service does and the way offline work does.

- **stream**: every sample, in order, through :class:`~mavattitude.pipeline.AttitudePipeline` — the
  service's own front end (screen, low-pass, 50 Hz resampling) and solver; scored at its output ticks
  against the reference interpolated to those instants.
- **batch**: :func:`~mavattitude.estimation.solve_batch` on the raw samples (no filter), scored per
  sample — the per-sample baseline (with ``triad``, the data README's reference figures).

Both take the recording's own references (:class:`~mavattitude.validation.frames.RestReference`): the
magnetic field measured at the opening rest and the per-axis sensor noise measured there.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from mavattitude.config import REPLACE_WHOLE, Config, load_config
from mavattitude.errors import ConfigError
from mavattitude.estimation import METHODS, NoiseModel, solve_batch
from mavattitude.estimation.conventions import Array
from mavattitude.pipeline import AttitudePipeline
from mavattitude.sensors.units import ImuSample
from mavattitude.validation.loaders import Recording, truth_at
from mavattitude.validation.metrics import BroadScore, Px4Score, broad_errors, euler_differences

PATHS = ("stream", "batch")  # batch: solve_batch, per sample (SNAPSHOT_METHODS); the fused filter is only a stream

Progress = Callable[[int, int], None]


@dataclass(frozen=True)
class Estimate:
    """What one path and method produced on one recording."""

    path: str
    method: str
    time_s: Array  # (M,) instants of the estimates (input samples for batch, 50 Hz ticks for stream)
    q: Array  # (M, 4) body → NED
    expected: int  # how many estimates a gap-free run would have produced
    elapsed_s: float  # processing time (time.monotonic)
    counters: Mapping[str, int] = field(default_factory=dict)

    @property
    def coverage(self) -> float:
        return len(self.time_s) / self.expected if self.expected else float("nan")


@dataclass(frozen=True)
class Evaluation:
    """An estimate scored against the recording's reference, with the per-instant errors for plots."""

    estimate: Estimate
    score: BroadScore | Px4Score
    errors_rad: Array  # (M, 3): BROAD total/heading/inclination, or PX4 roll/pitch/yaw differences
    truth_q: Array  # (M, 4) the reference at the estimate's instants
    movement: Array  # (M,) bool


def validation_config(recording: Recording, method: str, base: Config | None = None, **overrides: Any) -> Config:
    """``base`` (or the defaults) with the recording's measured references and ``method``, then
    ``overrides`` (dotted keys, e.g. ``**{"filter.cutoff_hz": 5}``), which win over both."""
    ref = recording.reference
    layer: dict[str, Any] = {
        "estimator.method": method,
        "reference.magnetic": {"field_ned_uT": [float(v) for v in ref.field_ned_uT]},
    }
    if METHODS[method].sensor_noise:  # the fused filter's σ are its own (estimator.fused), not the sensor noise
        layer |= {
            "noise.accel_std_mps2": [float(v) for v in ref.acc_std_mps2],
            "noise.mag_std_uT": [float(v) for v in ref.mag_std_uT],
        }
    layer |= overrides
    merged = {} if base is None else base.to_dict()
    return load_config(None, overrides=_flatten(merged) | layer, env={})


def _flatten(data: Mapping[str, Any], prefix: str = "") -> dict[str, Any]:
    out: dict[str, Any] = {}
    for key, value in data.items():
        if isinstance(value, Mapping) and f"{prefix}{key}" not in REPLACE_WHOLE:
            out |= _flatten(value, f"{prefix}{key}.")
        else:
            out[f"{prefix}{key}"] = value
    return out


def samples(recording: Recording) -> list[ImuSample]:
    """The recording as the link would deliver it: a magnetometer value only when it is new."""
    rows = zip(
        recording.time_s.tolist(),
        recording.acc_mps2.tolist(),
        recording.gyr_radps.tolist(),
        recording.mag_uT.tolist(),
        recording.mag_new.tolist(),
        strict=True,
    )
    return [
        ImuSample(
            time_s=t,
            acc_mps2=tuple(acc),
            gyr_radps=tuple(gyr),
            mag_uT=tuple(mag) if new else None,
        )
        for t, acc, gyr, mag, new in rows
    ]


def estimate_stream(recording: Recording, config: Config, progress: Progress | None = None) -> Estimate:
    """Push every sample through the service's pipeline and collect its outputs."""
    pipeline = AttitudePipeline(config)
    feed = samples(recording)
    times, quats = [], []
    start = time.monotonic()
    for i, sample in enumerate(feed):
        for out in pipeline.push(sample).outputs:
            times.append(out.time_s)
            quats.append(out.q)
        if progress is not None and i % 5000 == 0:
            progress(i, len(feed))
    elapsed = time.monotonic() - start
    return Estimate(
        path="stream",
        method=config.estimator.method,
        time_s=np.asarray(times, dtype=float),
        q=np.asarray(quats, dtype=float).reshape(-1, 4),
        expected=_ticks_within(recording.time_s[0], recording.time_s[-1], config.filter.output_rate_hz),
        elapsed_s=elapsed,
        counters=_stream_counters(pipeline),
    )


def _ticks_within(start_s: float, stop_s: float, rate_hz: float) -> int:
    """How many output ticks ``k / rate_hz`` of the vehicle clock fall in ``[start_s, stop_s]``."""
    return int(np.floor(stop_s * rate_hz) - np.ceil(start_s * rate_hz)) + 1


def estimate_batch(recording: Recording, config: Config) -> Estimate:
    """``solve_batch`` on the raw samples with the config's noise, references and method."""
    noise = NoiseModel(accel_std=config.noise.accel_std_mps2, mag_std=config.noise.mag_std_uT)
    field_ned_uT = config.reference.magnetic.fixed_field().field_ned_uT
    if field_ned_uT is None:
        raise ConfigError("the batch path needs a fixed magnetic reference, not auto (no position in a recording)")
    start = time.monotonic()
    # The samples the per-sample path would refuse one by one (near-collinear acc and mag, a vector buried
    # in its noise) are left out, and show as lost coverage.
    result = solve_batch(
        recording.acc_mps2,
        recording.mag_uT,
        field_ned_uT,
        noise,
        method=config.estimator.method,
        max_iterations=config.estimator.max_iterations,
        tolerance=config.estimator.tolerance,
        min_angle_deg=config.estimator.min_angle_deg,
        full_output=True,  # a sample that hits max_iterations is counted, not fatal
        skip_unusable=True,
    )
    usable = result.usable
    return Estimate(
        path="batch",
        method=config.estimator.method,
        time_s=recording.time_s[usable],
        q=result.q[usable],
        expected=len(recording),
        elapsed_s=time.monotonic() - start,
        counters={"unusable": int((~usable).sum()), "not converged": int((usable & ~result.converged).sum())},
    )


def evaluate(recording: Recording, estimate: Estimate) -> Evaluation:
    """Score an estimate with the recording's metric (BROAD's, or agreement with the autopilot)."""
    truth, movement, rest = truth_at(recording, estimate.time_s)
    if recording.kind == "broad":
        errors = broad_errors(estimate.q, truth)
        score: BroadScore | Px4Score = BroadScore.of(errors, movement, rest)
    else:
        errors = euler_differences(estimate.q, truth)
        score = Px4Score.of(errors)
    return Evaluation(estimate=estimate, score=score, errors_rad=errors, truth_q=truth, movement=movement)


def _stream_counters(pipeline: AttitudePipeline) -> dict[str, int]:
    """The pipeline's counters worth a column: rejects by reason, flags, not converged."""
    c = pipeline.counters
    out = {f"rejected {k}": v for k, v in c.rejected.items()}
    out |= {f"input rejected {k}": v for k, v in c.frontend.rejected.items()}
    out |= {f"flagged {k}": v for k, v in c.frontend.flagged.items()}
    out["not converged"] = c.not_converged
    return out
