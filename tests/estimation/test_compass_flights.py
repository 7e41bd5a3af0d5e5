"""The compass monitor on whole flights: no warning on a good compass in hard flying, at the rates logs have
(25 Hz IMU and a 10 Hz averaged compass in a .BIN, 50 Hz RAW_IMU snapshots repeating it in a .tlog), on
flights the simulator writes and on the shared ArduCopter SITL flights; a compass turned 45° still named."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from mavattitude.config import load_config
from mavattitude.link.logs import open_log
from mavattitude.replay import Replayed, replay
from mavattitude.sim.logwriter import manoeuvring_log, write_dataflash, write_tlog
from tests.shared import shared_path

TURNED_45_Z = np.array([[math.sqrt(0.5), math.sqrt(0.5), 0.0], [-math.sqrt(0.5), math.sqrt(0.5), 0.0], [0.0, 0.0, 1.0]])
TRUE_FIELD = {"reference.magnetic": {"declination_deg": 12.8, "inclination_deg": -65.77}}  # the SITL's (its README)


def _replayed(path: Path, method: str, **overrides: object) -> Replayed:
    config = load_config(None, {"estimator.method": method, **overrides}, env={})
    return replay(open_log(path, config), config)


def _warnings(result: Replayed) -> list[str]:
    return [f"{e.time_s:.1f} s: {e.figures.describe()}" for e in result.compass if e.inconsistent]


def _log(tmp_path: Path, kind: str, turn: np.ndarray | None = None) -> Path:
    # seed 1: yaw swings at 200°/s, roll and pitch ±30° at 0.2-0.8 Hz; the turn test without the readings'
    # times and lag warned about this flight's good compass twice in 60 s (mismatch 21-38 %)
    if kind == "bin":
        return write_dataflash(tmp_path / "hard.bin", manoeuvring_log(60.0, mag_turn=turn, seed=1))
    return write_tlog(tmp_path / "hard.tlog", manoeuvring_log(60.0, imu_rate_hz=50.0, mag_turn=turn, seed=1))


@pytest.mark.parametrize("method", ["ign", "fused"])
@pytest.mark.parametrize("kind", ["bin", "tlog"])
def test_a_good_compass_in_hard_flying_is_not_warned_about(tmp_path, kind, method):
    result = _replayed(_log(tmp_path, kind), method)
    figures = result.pipeline.compass.figures()
    assert _warnings(result) == []
    # the readings' timing taken out, a good compass's turn is its noise alone (exact data: a few %)
    assert figures.turn_mismatch < 0.05
    assert 0.0 < result.pipeline.compass._turn.lag_s() < 0.1  # the mean over a 10 Hz interval lags by ~0.05 s


@pytest.mark.parametrize("method", ["ign", "fused"])
@pytest.mark.parametrize("kind", ["bin", "tlog"])
def test_a_compass_turned_45_degrees_is_named_within_seconds(tmp_path, kind, method):
    result = _replayed(_log(tmp_path, kind, TURNED_45_Z), method)
    warned = [e for e in result.compass if e.inconsistent]
    assert warned and "turns unlike the gyroscope" in warned[0].figures.describe()
    # tilted from the start: the first judgement (25 steps) and PERSIST_S after it, well within the 10 s target
    assert warned[0].time_s - result.outputs[0].time_s < 5.0


@pytest.mark.parametrize(
    ("name", "method"),
    [
        ("nogps.BIN", "fused"),
        ("nogps.tlog", "ign"),
        ("nogps.tlog", "fused"),
        ("twocompass.BIN", "fused"),
        ("twocompass.tlog", "ign"),
        ("twocompass.tlog", "fused"),
    ],
)
def test_the_sitl_flights_good_compass_is_not_warned_about(name, method):
    # where the turn test warned 1-5 times in manoeuvres (true field given: nogps has no position)
    result = _replayed(shared_path("data", "ardupilot-sitl", name), method, **TRUE_FIELD)
    assert _warnings(result) == []
