"""The streaming pipeline and the batch solver, fed the same samples, give the same attitudes (1e-6 rad).

Both solve the same weighted Wahba problem to the solver's tolerance (1e-12); what separates them is
the stream's warm start from the previous tick and rounding, far below the 1e-6 rad asked for.
Samples the front end flagged (|a| or |B| off: σ scaled up) are left out, since ``solve_batch`` takes
one noise model for all samples, and so are those too close to collinear to solve, and those the compass
gate set heading only (``MAG_INCONSISTENT``: before the compass is vouched for, a tick whose dip is off by
more than the noise is TRIAD with the accelerometer primary, flagged ``MAG_HEADING_ONLY``; docs/vehicle.md).
"""

from __future__ import annotations

import numpy as np

from mavattitude.estimation import NoiseModel, solve_batch
from mavattitude.estimation.conventions import angle_between
from mavattitude.pipeline import AttitudePipeline, frontend_settings
from mavattitude.sensors.frontend import SampleFlag, batch_inputs, process_batch
from mavattitude.validation.runner import estimate_batch, samples, validation_config

AGREEMENT_RAD = 1e-6
SCREEN_FLAGS = SampleFlag.ACC_NORM | SampleFlag.MAG_NORM | SampleFlag.MAG_HELD | SampleFlag.MAG_INCONSISTENT


def _stream(recording, config):
    """Stream outputs not flagged by the screening, as (times, quaternions)."""
    pipeline = AttitudePipeline(config)
    outs = [o for s in samples(recording) for o in pipeline.push(s).outputs if not (o.flags & SCREEN_FLAGS)]
    return np.array([o.time_s for o in outs]), np.array([o.q for o in outs])


def test_unfiltered_stream_equals_the_batch_path_on_the_raw_samples(recordings) -> None:
    rec = recordings["04"].slice(25, 40)  # rest, then slow rotation
    config = validation_config(rec, "ign", **{"filter.enabled": False})
    t, q_stream = _stream(rec, config)
    batch = estimate_batch(rec, config)
    common, i_stream, i_batch = np.intersect1d(t, batch.time_s, return_indices=True)
    assert len(common) > 0.8 * len(rec)  # not vacuous: 84% of this slice passes the screening and the gate unflagged
    assert angle_between(q_stream[i_stream], batch.q[i_batch]).max() < AGREEMENT_RAD


def test_filtered_stream_equals_solve_batch_on_the_front_ends_batch_output(recordings) -> None:
    rec = recordings["08"].slice(25, 40)  # rest, then fast rotation
    config = validation_config(rec, "ign")
    t, q_stream = _stream(rec, config)
    ticks = process_batch(
        frontend_settings(config),
        **batch_inputs(samples(rec)),
        expected_field_uT=float(np.linalg.norm(rec.reference.field_ned_uT)),
    )
    clean = (ticks.acc_std_scale == 1.0) & (ticks.mag_std_scale == 1.0) & ~np.isnan(ticks.mag_uT).any(axis=1)
    noise = NoiseModel(accel_std=config.noise.accel_std_mps2, mag_std=config.noise.mag_std_uT)
    batch = solve_batch(
        ticks.acc_mps2[clean],
        ticks.mag_uT[clean],
        rec.reference.field_ned_uT,
        noise,
        full_output=True,
        skip_unusable=True,
    )
    q_batch = batch.q[batch.usable]  # near-collinear ticks: refused here as by the stream's solver
    common, i_stream, i_batch = np.intersect1d(t, ticks.time_s[clean][batch.usable], return_indices=True)
    assert len(common) > 0.5 * len(t)
    assert angle_between(q_stream[i_stream], q_batch[i_batch]).max() < AGREEMENT_RAD
