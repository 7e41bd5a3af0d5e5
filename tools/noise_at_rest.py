"""IGN at rest with the noise it measures itself, against the noise handed in: error and claimed covariance.

Usage::

    .venv/bin/python tools/noise_at_rest.py [--trials 01 04 ...] [--no-sim]

Three runs of the service pipeline (``estimator.method: ign``, its front end's 10 Hz low-pass and 50 Hz ticks)
per recording: ``config`` (the default ``noise:`` and ``noise.rest_s: 0``: what a user who sets nothing had),
``true`` (``noise:`` the sensors' own σ, ``rest_s: 0``), ``measured`` (the default ``noise:`` as the prior,
``rest_s: 10``: the σ the pipeline measures on its ticks at rest, :mod:`mavattitude.estimation.restnoise`).
Each is scored on the rest ticks after the measured σ came into use: the RMS of the total angle error against
the truth, and, per body axis, the σ the covariance claims (the root of its mean diagonal) over the error's
RMS about each rest segment's own mean (an offset that differs between attitudes, calibration residue or BROAD's
marker-to-sensor alignment, is not noise): 1.0 is a covariance that tells the truth, the target is within 10 %.

Recordings: the fake vehicle at rest (60 s, consumer sensors at 200 Hz, seeded; true σ the sensor model's), and
the rest segments (≥ 1 s from motion) of the 17 BROAD training trials (true σ and the reference field: the
validation's, from the opening rest window, :class:`mavattitude.validation.frames.RestReference`).
D. Laidig et al., "BROAD", Data 6(7):72, 2021, doi:10.3390/data6070072 (CC BY 4.0).
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

from mavattitude import pipeline
from mavattitude.config import from_dict
from mavattitude.estimation.conventions import quat_conjugate, quat_multiply, rotvec_from_quat
from mavattitude.validation.loaders import load_recording

BROAD = Path(__file__).resolve().parents[1].parent / "shared" / "data" / "broad"
TRAINING = ("01", "03", "04", "06", "08", "10", "12", "15", "21", "24", "26", "28", "29", "31", "33", "34", "36")
REST_S = 10.0
DEFAULT_NOISE = {"accel_std_mps2": 0.05, "mag_std_uT": 0.5}  # the config's defaults


def _run(rows: tuple, reference: list[float], noise: dict, rest_s: float) -> tuple:
    """The pipeline over the rows at once: ticks' times, q, covariances, and when the measured σ came in."""
    t, acc, gyr, mag = rows
    config = from_dict({"reference": {"magnetic": {"field_ned_uT": reference}}, "noise": {**noise, "rest_s": rest_s}})
    p = pipeline.AttitudePipeline(config)
    outputs = p.push_batch(t, acc, gyr, mag, np.ones(len(t), dtype=bool)).outputs
    times = np.array([o.time_s for o in outputs])
    rest = p.estimator.rest_noise
    return times, np.array([o.q for o in outputs]), pipeline.output_covariances(outputs), rest


def _score(times, q, cov, q_true, keep) -> tuple[float, np.ndarray]:
    err = rotvec_from_quat(quat_multiply(quat_conjugate(q_true[keep]), q[keep]))  # body-frame error angles
    total = np.degrees(np.linalg.norm(err, axis=1))
    claimed = np.sqrt(np.mean(np.diagonal(cov[keep], axis1=1, axis2=2), axis=0))
    # the scatter about each rest segment's own mean: an offset that differs between attitudes (calibration
    # residue, the markers' alignment) is no noise, and no covariance of a single tick claims it
    segment = np.cumsum(np.r_[True, np.diff(times[keep]) > 0.1])
    means = np.array([err[segment == k].mean(axis=0) for k in range(1, segment[-1] + 1)])
    scatter = np.sqrt(np.mean((err - means[segment - 1]) ** 2, axis=0))
    return float(np.sqrt(np.mean(total**2))), claimed / scatter


def scores(rows: tuple, reference: list[float], true_noise: dict, q_true_at, rest_at) -> tuple[dict, object] | str:
    """Per run (``config``, ``true``, ``measured``): the rest RMS (deg), the claimed σ / scatter per axis, and the
    rest-noise measurement; or why there is nothing to score."""
    runs = {
        "config": _run(rows, reference, DEFAULT_NOISE, 0.0),
        "true": _run(rows, reference, true_noise, 0.0),
        "measured": _run(rows, reference, DEFAULT_NOISE, REST_S),
    }
    rest = runs["measured"][3]
    if rest.measured is None:
        return f"rest {rest.still_s:5.1f} s: too little to measure"
    out = {}
    for label, (t, q, cov, _) in runs.items():
        keep = rest_at(t) & (t >= rest.since_s)  # the ticks after the switch to the measured σ
        if keep.sum() < 50:
            return "fewer than 50 rest ticks after the switch"
        out[label] = _score(t, q, cov, q_true_at(t), keep)
    return out, rest


def compare(name: str, *recording) -> list[str]:
    result = scores(*recording)
    if isinstance(result, str):
        return [f"{name:28} {result}"]
    runs, rest = result
    lines = [
        f"{name:28} {label:9} rest RMS {rms:6.3f} deg   claimed σ / scatter x y z {_fmt(ratio)}"
        for label, (rms, ratio) in runs.items()
    ]
    m = rest.measured
    lines.append(f"{'':28} measured σ acc {_fmt(m.accel_std)} m/s², mag {_fmt(m.mag_std)} µT over {rest.still_s:.0f} s")
    return lines


def _fmt(values) -> str:
    return " ".join(f"{v:6.3f}" for v in values)


def sim_recording(seed: int = 0, duration_s: float = 60.0) -> tuple:
    """The fake vehicle at rest (consumer sensors at 200 Hz, seeded), as :func:`scores` takes a recording."""
    from mavattitude.sim import scenarios

    script, sensors = scenarios.static(duration_s), scenarios.consumer_sensors(200.0)
    rng = np.random.default_rng(seed)
    t = sensors.sample_times(0.0, script.duration_s, rng)
    acc, gyr, mag = sensors.measure(script, t, rng)
    true = {"accel_std_mps2": list(sensors.accel.noise_std), "mag_std_uT": list(sensors.mag.noise_std)}
    everywhere = lambda ticks: np.ones(len(ticks), dtype=bool)  # noqa: E731
    return (t, acc, gyr, mag), list(scenarios.DEFAULT_MAG_NED_UT), true, script.attitude, everywhere


def sim() -> list[str]:
    return compare("fake vehicle at rest", *sim_recording())


def broad(trial: str) -> list[str]:
    path = next(BROAD.glob(f"{trial}_*.csv.gz"))
    r = load_recording(path)
    rest = r.rest & np.all(np.isfinite(r.truth_q), axis=1)
    true = {"accel_std_mps2": r.reference.acc_std_mps2.tolist(), "mag_std_uT": r.reference.mag_std_uT.tolist()}
    t0 = r.time_s

    def at(ticks: np.ndarray) -> np.ndarray:
        return np.clip(np.searchsorted(t0, ticks), 0, len(t0) - 1)

    return compare(
        r.name,
        (r.time_s, r.acc_mps2, r.gyr_radps, r.mag_uT),
        r.reference.field_ned_uT.tolist(),
        true,
        lambda ticks: r.truth_q[at(ticks)],
        lambda ticks: rest[at(ticks)],
    )


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--trials", nargs="*", default=list(TRAINING), help="BROAD training trials")
    parser.add_argument("--no-sim", action="store_true", help="leave out the fake vehicle")
    args = parser.parse_args()
    lines = [] if args.no_sim else sim()
    for trial in args.trials:
        lines += broad(trial)
    print("\n".join(lines))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
