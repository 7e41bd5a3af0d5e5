"""Score the gyro-aided ("fused") filter on BROAD beside its two peers, in one run on the same samples.

Usage: ``.venv/bin/python tools/tune_fused.py [--trials 04 08 28] [--set name=value ...] [--no-peers] [--sim]``

Runs our :class:`~mavattitude.estimation.fused.FusedFilter` directly on the raw samples (one configuration
for every trial; ``--set`` overrides a ``FusedSettings`` field while tuning), the xioTechnologies Fusion
AHRS (``imufusion``) and causal VQF through the validation package's peers, and prints BROAD's metric:
RMS total / heading / inclination error (degrees) over the movement phase, and the total at rest (≥ 1 s
from motion). The filter is scored at every input sample (BROAD's metric), the cost per input sample is
timed on a separate pass that only pushes samples. ``mavattitude validate --method fused`` scores the
same filter through the service pipeline at its 50 Hz ticks.

``--sim`` instead flies the fake vehicle's maneuvering flight (:func:`mavattitude.sim.scenarios.maneuver`,
consumer sensors at 200 Hz, seeded) through the service pipeline with ``estimator.method`` ``ign`` and
``fused`` and prints both errors and their ratio (the target: fused ≤ 1/5 of IGN-only).

Data: D. Laidig, M. Caruso, A. Cereatti, T. Seel, "BROAD — A Benchmark for Robust Inertial Orientation
Estimation", Data 6(7):72, 2021, doi:10.3390/data6070072 (CC BY 4.0), read from ``../shared/data/broad``.
"""

from __future__ import annotations

import argparse
import dataclasses
import time
from pathlib import Path

import numpy as np

from mavattitude.estimation.fused import FusedFilter, FusedSettings
from mavattitude.validation.loaders import Recording, load_recording
from mavattitude.validation.metrics import score_broad
from mavattitude.validation.peers import estimate_peer

DATA_DIR = Path(__file__).resolve().parents[1] / ".." / "shared" / "data" / "broad"


def run_fused(rec: Recording, settings: FusedSettings) -> tuple[np.ndarray, float]:
    """Attitude (body → NED) at every input sample, and the cost in µs per input sample."""
    t, gyr, acc, mag = (a.tolist() for a in (rec.time_s, rec.gyr_radps, rec.acc_mps2, rec.mag_uT))
    f = FusedFilter(settings, rec.reference.field_ned_uT)
    start = time.perf_counter()
    for i in range(len(t)):
        f.push(t[i], gyr[i], acc[i], mag[i])
    cost_us = (time.perf_counter() - start) / len(t) * 1e6
    f = FusedFilter(settings, rec.reference.field_ned_uT)
    q = np.empty((len(t), 4))
    for i in range(len(t)):
        f.push(t[i], gyr[i], acc[i], mag[i])
        q[i] = f.q
    return q, cost_us


def run_sim(overrides: dict[str, float], seed: int = 0) -> None:
    """The maneuvering flight through the pipeline, IGN-only against fused (``overrides`` go to the filter)."""
    from mavattitude import pipeline
    from mavattitude.config import from_dict
    from mavattitude.estimation.conventions import angle_between
    from mavattitude.sensors.units import ImuSample
    from mavattitude.sim import scenarios
    from mavattitude.sim.scoring import heading_error, tilt_error

    script, sensors = scenarios.maneuver(), scenarios.consumer_sensors(200.0)
    rng = np.random.default_rng(seed)
    t = sensors.sample_times(0.0, script.duration_s, rng)
    acc, gyr, mag = sensors.measure(script, t, rng)
    samples = [ImuSample(t[i], tuple(acc[i]), tuple(gyr[i]), tuple(mag[i])) for i in range(len(t))]
    reference = {"magnetic": {"field_ned_uT": list(scenarios.DEFAULT_MAG_NED_UT)}}
    noise = {"accel_std_mps2": [0.03, 0.03, 0.04], "mag_std_uT": [0.4, 0.4, 0.5]}  # the preset's σ
    rms = {}
    for method in ("ign", "fused"):
        p = pipeline.AttitudePipeline(
            from_dict({"reference": reference, "noise": noise, "estimator": {"method": method}})
        )
        if method == "fused":
            p.estimator.settings = dataclasses.replace(p.estimator.settings, **overrides)
        out = [o for s in samples for o in p.push(s)]
        q, q_true = np.array([o.q for o in out]), script.attitude(np.array([o.time_s for o in out]))
        errs = [np.degrees(e(q, q_true)) for e in (angle_between, tilt_error, heading_error)]
        rms[method] = [float(np.sqrt(np.mean(e**2))) for e in errs]
        print(
            f"sim maneuver  {method:6} RMS total {rms[method][0]:6.2f}  tilt {rms[method][1]:6.2f}  "
            f"heading {rms[method][2]:6.2f} deg  ({len(out)} ticks)"
        )
    print(f"fused / ign = {rms['fused'][0] / rms['ign'][0]:.3f} (target ≤ 0.2)")


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--trials", nargs="+", default=["04", "08", "28"], help="BROAD trial numbers")
    parser.add_argument("--set", nargs="*", default=[], metavar="NAME=VALUE", help="FusedSettings overrides")
    parser.add_argument("--no-peers", action="store_true", help="skip imufusion and VQF")
    parser.add_argument("--sim", action="store_true", help="the fake vehicle's maneuvering flight, not BROAD")
    args = parser.parse_args()
    overrides = {k: float(v) for k, v in (s.split("=", 1) for s in args.set)}
    if args.sim:
        run_sim(overrides)
        return 0
    settings = dataclasses.replace(FusedSettings(), **overrides)
    print(f"{'trial':6}{'method':11}{'total':>7}{'heading':>9}{'incl':>7}{'rest':>7}  (deg RMS; rest = total at rest)")
    for trial in args.trials:
        (path,) = DATA_DIR.glob(f"{trial}_*.csv.gz")
        rec = load_recording(path)
        q, cost_us = run_fused(rec, settings)
        runs = {"fused": (q, f"  {cost_us:.1f} µs/sample")}
        if not args.no_peers:
            runs |= {name: (estimate_peer(rec, name).q, "") for name in ("imufusion", "vqf")}
        for name, (q_ned, note) in runs.items():
            s = score_broad(q_ned, rec.truth_q, rec.movement, rec.rest)
            m = s.movement
            print(
                f"{trial:6}{name:11}{m.total_deg:7.2f}{m.heading_deg:9.2f}{m.inclination_deg:7.2f}"
                f"{s.rest.total_deg:7.2f}{note}"
            )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
