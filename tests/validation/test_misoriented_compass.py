"""A misoriented compass on BROAD's fast-rotation trials: the IGN tilt stays the accelerometer's.

Every axis flip and 90° turn of the magnetometer (:data:`~mavattitude.validation.frames.MISORIENTATIONS`),
on the first minute of trials 06 and 08 (a rest, then fast rotation: the first movement at 37.6 s and
28.5 s). The target (docs/vehicle.md): roll/pitch within 1° RMS of the accelerometer-only tilt, the
warning within 10 s; the whole-file figures are tools/compass_table.py's.
Data: Laidig et al., BROAD, Data 6(7):72, 2021, doi:10.3390/data6070072 (CC BY 4.0).
"""

from __future__ import annotations

import numpy as np
import pytest

from mavattitude.pipeline import AttitudePipeline, Pushed
from mavattitude.sensors.frontend import SampleFlag
from mavattitude.sim.scoring import tilt_error
from mavattitude.validation.frames import MISORIENTATIONS
from mavattitude.validation.loaders import Recording
from mavattitude.validation.runner import validation_config

FIRST_MINUTE_S = 60.0


def _run(rec: Recording, method: str, mag_uT: np.ndarray) -> tuple[np.ndarray, np.ndarray, Pushed]:
    pipeline = AttitudePipeline(validation_config(rec, method))
    pushed = pipeline.push_batch(rec.time_s, rec.acc_mps2, rec.gyr_radps, mag_uT, rec.mag_new)
    out = pushed.outputs
    return np.array([o.time_s for o in out]), np.array([o.q for o in out]), pushed


@pytest.fixture(scope="module")
def accelerometer_tilt(recordings) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """TRIAD with the accelerometer primary: its tilt is the accelerometer's exactly."""
    out = {}
    for trial in ("06", "08"):
        rec = recordings[trial].slice(0.0, FIRST_MINUTE_S)
        out[trial] = _run(rec, "triad", rec.mag_uT)[:2]
    return out


@pytest.mark.parametrize("trial", ["06", "08"])
@pytest.mark.parametrize("name", list(MISORIENTATIONS))
def test_a_misoriented_compass_leaves_the_ign_tilt_to_the_accelerometer(recordings, accelerometer_tilt, trial, name):
    rec = recordings[trial].slice(0.0, FIRST_MINUTE_S)
    t, q, pushed = _run(rec, "ign", rec.mag_uT @ MISORIENTATIONS[name].T)
    t_acc, q_acc = accelerometer_tilt[trial]
    # a tick whose field lies along gravity is not solved (the geometry is degenerate): a few more of them
    common, i, j = np.intersect1d(t, t_acc, return_indices=True)
    assert len(common) > 0.95 * len(t_acc)
    rms_deg = np.sqrt(np.mean(np.degrees(tilt_error(q[i], q_acc[j])) ** 2))
    assert rms_deg < 1.0  # the target; measured ≤ 0.2° (tools/compass_table.py, first minute and whole file)
    warnings = [e.time_s for e in pushed.compass if e.inconsistent]
    first_movement_s = rec.time_s[np.argmax(rec.movement)]
    # the target: within 10 s; a compass turned about the vertical or mirrored shows only once it turns
    assert warnings and warnings[0] - max(first_movement_s if _turn_only(name) else t[0], t[0]) < 10.0


def _turn_only(name: str) -> bool:
    """Whether only a turn shows this misorientation (it keeps the dip while the sensor lies as at rest)."""
    return name in ("x-flip", "y-flip", "yaw-90")


@pytest.mark.parametrize(("trial", "name"), [("01", "y-flip"), ("04", "x-flip"), ("12", "yaw-90")])
def test_a_slow_turn_mostly_about_the_misorientations_axis_is_warned_about_within_10_s(recordings, trial, name):
    # 01 and 04 start by turning mostly about the mirror's own axis, 12 (slow translation) turns little: the
    # mismatch ratio warned 28, 12.6 and 12 s after the first movement; the mounting comparison at the first
    # judgement of the turn (measured 3.2, 2.5 and 6.2 s). The good compass of the same minute: no warning.
    rec = recordings[trial].slice(0.0, FIRST_MINUTE_S)
    first_movement_s = rec.time_s[np.argmax(rec.movement)]
    *_, bad = _run(rec, "ign", rec.mag_uT @ MISORIENTATIONS[name].T)
    warnings = [e.time_s for e in bad.compass if e.inconsistent]
    assert warnings and 0.0 < warnings[0] - first_movement_s < 10.0  # the target
    *_, good = _run(rec, "ign", rec.mag_uT)
    assert good.compass == []


def test_a_good_compass_is_vouched_for_at_the_first_turns_and_trusted_from_then(recordings):
    rec = recordings["08"].slice(0.0, FIRST_MINUTE_S)
    pipeline = AttitudePipeline(validation_config(rec, "ign"))
    first_movement_s = rec.time_s[np.argmax(rec.movement)]
    before = rec.time_s < first_movement_s + 5.0
    first = pipeline.push_batch(
        *(a[before] for a in (rec.time_s, rec.acc_mps2, rec.gyr_radps, rec.mag_uT, rec.mag_new))
    )
    assert pipeline.compass.confirmed  # measured: 1.5 s after the first movement
    after = pipeline.push_batch(
        *(a[~before] for a in (rec.time_s, rec.acc_mps2, rec.gyr_radps, rec.mag_uT, rec.mag_new))
    )
    assert first.compass == [] and after.compass == []
    assert not any(SampleFlag.MAG_HEADING_ONLY in o.flags for o in after.outputs if SampleFlag.MAG_NORM not in o.flags)
