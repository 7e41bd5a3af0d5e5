"""Fuzz of the decode path the service runs on every datagram: MAVLink parse → units.decode → pipeline.

Two generators, both with a bounded budget (hypothesis, derandomised so CI is repeatable):
- frames: valid packets of the fake vehicle with random byte flips, truncations and junk around them;
- fields: streams of IMU messages whose every field is arbitrary (any float incl. NaN/inf/huge/tiny in
  HIGHRES_IMU, any int16 in RAW_IMU, times going anywhere).
The contract: the parser raises only its own MAVError for bad bytes; decode raises only SensorError;
the pipeline raises only MavAttitudeError, and every quaternion it returns is finite and unit.
"""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from mavattitude.config import load_config
from mavattitude.errors import MavAttitudeError, SensorError
from mavattitude.link.mavlink2 import mavlink2
from mavattitude.pipeline import AttitudePipeline
from mavattitude.sensors.units import ImuSample, decode, encode, get_profile
from mavattitude.sim import scenarios

BUDGET = settings(max_examples=100, deadline=None, derandomize=True, suppress_health_check=[HealthCheck.too_slow])
PROFILES = {"RAW_IMU": "ardupilot", "HIGHRES_IMU": "px4"}


def _pipeline(message: str) -> AttitudePipeline:
    overrides = {
        "input": {"message": message, "profile": PROFILES[message]},
        "reference": {"magnetic": {"field_ned_uT": list(scenarios.DEFAULT_MAG_NED_UT)}},
    }
    return AttitudePipeline(load_config(None, overrides=overrides, env={}))


def _check(pipeline: AttitudePipeline, msg: object, profile: str) -> None:
    try:
        sample = decode(msg, get_profile(profile))
    except SensorError:
        return
    try:
        outputs = pipeline.push(sample).outputs
    except MavAttitudeError:
        return
    for out in outputs:
        q = np.asarray(out.q, float)
        assert np.all(np.isfinite(q)) and abs(np.linalg.norm(q) - 1.0) < 1e-6


def _good_packets(message: str, n: int) -> list[bytes]:
    mav = mavlink2.MAVLink(None, srcSystem=1, srcComponent=1)
    truth = scenarios.static(10.0).sample(np.arange(n) / 200.0)
    packets = []
    for i in range(n):
        sample = ImuSample(
            float(truth.t_s[i]),
            tuple(truth.specific_force_mps2[i]),
            tuple(truth.gyr_radps[i]),
            tuple(truth.mag_uT[i]),
        )
        fields = encode(sample, get_profile(PROFILES[message]), message)
        packets.append(bytes(getattr(mavlink2, f"MAVLink_{message.lower()}_message")(**fields).pack(mav)))
    return packets


@pytest.mark.parametrize("message", list(PROFILES))
@BUDGET
@given(data=st.data())
def test_mutated_frames(message: str, data: st.DataObject) -> None:
    pipeline = _pipeline(message)
    parser = mavlink2.MAVLink(None)
    parser.robust_parsing = True
    for packet in _good_packets(message, 30):
        buf = bytearray(packet)
        action = data.draw(st.sampled_from(["keep", "flip", "truncate", "junk"]))
        if action == "flip":
            i = data.draw(st.integers(0, len(buf) - 1))
            buf[i] ^= data.draw(st.integers(1, 255))
        elif action == "truncate":
            buf = buf[: data.draw(st.integers(0, len(buf) - 1))]
        elif action == "junk":
            buf = bytearray(data.draw(st.binary(max_size=64))) + buf
        try:
            msgs = parser.parse_buffer(bytes(buf)) or []
        except mavlink2.MAVError:
            continue
        for msg in msgs:
            if msg.get_type() == message:
                _check(pipeline, msg, PROFILES[message])


_any_float = st.floats(allow_nan=True, allow_infinity=True, width=32)
_int16 = st.integers(-32768, 32767)


class _Fields:
    """A test double with MAVLink field attributes and get_type(), as decode accepts."""

    def __init__(self, kind: str, **fields: float) -> None:
        self._kind = kind
        self.__dict__.update(fields)

    def get_type(self) -> str:
        return self._kind


_AXES = ("xacc", "yacc", "zacc", "xgyro", "ygyro", "zgyro", "xmag", "ymag", "zmag")


# Mostly the nominal 5 ms step (so the front end produces ticks for the solver), sometimes anything.
_time_step_us = st.one_of(st.just(5000), st.just(5000), st.just(5000), st.integers(-(10**7), 10**7))
# Level and still in the default field, in HIGHRES_IMU units (m/s², rad/s, gauss) and RAW_IMU units
# (mG, mrad/s, mgauss).
_LEVEL_SI = (0.0, 0.0, -9.80665, 0.0, 0.0, 0.0, *(b / 100.0 for b in scenarios.DEFAULT_MAG_NED_UT))
_LEVEL_RAW = (0, 0, -1000, 0, 0, 0, *(round(b * 10.0) for b in scenarios.DEFAULT_MAG_NED_UT))


def _times(steps: list[int]) -> list[int]:
    times, t = [], 10**9
    for step in steps:
        t = max(0, t + step)
        times.append(t)
    return times


@BUDGET
@given(
    stream=st.lists(
        st.tuples(
            _time_step_us,
            st.lists(st.one_of(st.none(), _any_float), min_size=9, max_size=9),
            st.sampled_from([0x1FF, 0x3F, 0, 0xFFFF]),
        ),
        min_size=1,
        max_size=80,
    )
)
def test_arbitrary_highres_fields(stream: list[tuple[int, list[float | None], int]]) -> None:
    """Each field is the level truth (None) or any float32."""
    pipeline = _pipeline("HIGHRES_IMU")
    for t, (_, values, updated) in zip(_times([s[0] for s in stream]), stream, strict=True):
        fields = {a: (lv if v is None else v) for a, v, lv in zip(_AXES, values, _LEVEL_SI, strict=True)}
        _check(pipeline, _Fields("HIGHRES_IMU", time_usec=t, fields_updated=updated, **fields), "px4")


@BUDGET
@given(
    stream=st.lists(
        st.tuples(_time_step_us, st.lists(st.one_of(st.none(), _int16), min_size=9, max_size=9)),
        min_size=1,
        max_size=80,
    )
)
def test_arbitrary_raw_imu_fields(stream: list[tuple[int, list[int | None]]]) -> None:
    """Each field is the level truth (None) or any int16."""
    pipeline = _pipeline("RAW_IMU")
    for t, (_, values) in zip(_times([s[0] for s in stream]), stream, strict=True):
        fields = {a: (lv if v is None else v) for a, v, lv in zip(_AXES, values, _LEVEL_RAW, strict=True)}
        _check(pipeline, _Fields("RAW_IMU", time_usec=t, **fields), "ardupilot")
