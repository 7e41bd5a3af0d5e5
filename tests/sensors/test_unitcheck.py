"""The units check: the accelerometer's and magnetometer's median magnitudes over the first seconds, judged once."""

from __future__ import annotations

import numpy as np
import pytest

from mavattitude.estimation.conventions import STANDARD_GRAVITY_MPS2
from mavattitude.sensors.magfit import EARTH_FIELD_UT, UNITS_MARGIN
from mavattitude.sensors.unitcheck import GRAVITY_BAND, MIN_SAMPLES, WINDOW_S, UnitsCheck, unlike_gravity

RATE_HZ = 50.0
FIELD_UT = 48.0  # a mid-latitude field, inside the Earth's 22–67 µT


def _stream(seconds: float, g: float = 1.0, field_uT: float = FIELD_UT, seed: int = 7):
    """A vehicle turning at random, its specific force ``g`` (in g) and field ``field_uT`` in magnitude, with 2 %
    noise on each (a consumer IMU's scatter is well under that)."""
    rng = np.random.default_rng(seed)
    n = round(seconds * RATE_HZ)
    t = 100.0 + np.arange(n) / RATE_HZ

    def vectors(norm: float) -> np.ndarray:
        d = rng.normal(size=(n, 3))
        return d / np.linalg.norm(d, axis=1, keepdims=True) * norm * (1 + 0.02 * rng.normal(size=(n, 1)))

    return t, vectors(g * STANDARD_GRAVITY_MPS2), vectors(field_uT)


def test_a_vehicle_in_si_units_is_no_finding():
    check = UnitsCheck()
    assert check.add(*_stream(WINDOW_S + 1.0)) == []
    assert not check.open and check.findings == []


@pytest.mark.parametrize(
    ("g", "words"),
    [
        (3.33, "its median |f| over the first 5 s is 3.33 g, where a vehicle's is about 1 g: wrong units"),
        (1 / STANDARD_GRAVITY_MPS2, "is 0.102 g, where a vehicle's is about 1 g (readings in g taken for m/s²?)"),
    ],
)
def test_an_accelerometer_far_from_g_is_a_finding_with_its_figure(g, words):
    """An ADIS16405's 3.33 mg per count read as ArduPilot's mg; a CSV in g read as m/s² (the slip named)."""
    check = UnitsCheck()
    (finding,) = check.add(*_stream(WINDOW_S + 1.0, g=g))
    assert finding.sensor == "accelerometer" and words in finding.text
    assert finding.short == f"accel reads {g:.3g} g: check units, profile" and len(finding.short) <= 50
    assert finding.reads == f"{g:.3g} g"
    assert finding.time_s == pytest.approx(100.0 + WINDOW_S)  # judged with the first sample WINDOW_S on


@pytest.mark.parametrize("factor", [10.0, 0.01])
def test_a_magnetometer_far_from_any_earth_field_is_a_finding(factor):
    """Milligauss read as µT (10×), gauss read as µT (0.01×)."""
    (finding,) = UnitsCheck().add(*_stream(WINDOW_S + 1.0, field_uT=FIELD_UT * factor))
    assert finding.sensor == "magnetometer" and finding.reads == f"{FIELD_UT * factor:.3g} µT"
    assert (
        finding.short == f"compass reads {FIELD_UT * factor:.3g} uT: check units, profile" and finding.short.isascii()
    )
    assert f"its median |B| over the first 5 s is {FIELD_UT * factor:.3g} µT, where the Earth's is 22-67 µT" in (
        finding.text
    )


def test_the_bands_edges():
    """``GRAVITY_BAND`` and the Earth's field widened by ``UNITS_MARGIN`` (the rule ``calibrate`` judges by)."""
    low, high = GRAVITY_BAND
    g = STANDARD_GRAVITY_MPS2
    assert unlike_gravity(0.99 * low * g) and unlike_gravity(1.01 * high * g)
    assert unlike_gravity(1.01 * low * g) is None and unlike_gravity(0.99 * high * g) is None
    weakest, strongest = EARTH_FIELD_UT[0] / UNITS_MARGIN, EARTH_FIELD_UT[1] * UNITS_MARGIN
    for field_uT, found in [(0.99 * weakest, True), (1.01 * weakest, False), (1.01 * strongest, True)]:
        check = UnitsCheck()
        assert bool(check.add(*_stream(WINDOW_S + 1.0, field_uT=field_uT, seed=1))) is found, field_uT


def test_zero_readings_are_no_sensor_not_wrong_units():
    """An IMU the autopilot lacks sends zeros (refused as dead by the front end, with words of its own); a
    message without a compass reading is NaN: neither is judged."""
    t, acc, mag = _stream(WINDOW_S + 1.0)
    acc[::2] = 0.0
    mag[:] = np.nan
    assert UnitsCheck().add(t, acc, mag) == []
    t, acc, mag = _stream(WINDOW_S + 1.0, g=3.33)
    acc[:] = 0.0
    assert UnitsCheck().add(t, acc, mag) == []


def test_the_window_ends_after_its_seconds_and_its_fewest_samples():
    """Judged at the first sample ``WINDOW_S`` on, once ``MIN_SAMPLES`` are in: a 2 Hz stream's 11th sample;
    a stream that stops within the window is never judged; the samples after the window do not count."""
    t, acc, mag = _stream(20.0, g=3.33)
    slow = UnitsCheck()
    every = round(RATE_HZ / 2.0)  # 2 Hz
    for i in range(0, len(t), every):
        found = slow.add(t[i : i + 1], acc[i : i + 1], mag[i : i + 1])
        if found:
            break
    assert i // every + 1 == MIN_SAMPLES + 1 and t[i] - t[0] == pytest.approx(WINDOW_S)
    short, within = UnitsCheck(), round(RATE_HZ * WINDOW_S)  # the samples before the one WINDOW_S on
    assert short.add(t[:within], acc[:within], mag[:within]) == [] and short.open
    acc[within + 1 :] /= 3.33  # in SI after the window (three quarters of the stream): not counted
    assert len(UnitsCheck().add(t, acc, mag)) == 1


def test_one_by_one_as_all_at_once():
    """:meth:`UnitsCheck.add_sample` is ``add`` of one row: the same findings, at the same sample."""
    t, acc, mag = _stream(WINDOW_S + 2.0, g=0.2, field_uT=FIELD_UT * 10)
    mag[1::2] = np.nan  # a compass at half the IMU's rate
    batch = UnitsCheck().add(t, acc, mag)
    check, one_by_one = UnitsCheck(), []
    for i in range(len(t)):
        one_by_one += check.add_sample(float(t[i]), tuple(acc[i]), None if np.isnan(mag[i, 0]) else tuple(mag[i]))
    assert one_by_one == batch and [f.sensor for f in batch] == ["accelerometer", "magnetometer"]
