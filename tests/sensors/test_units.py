"""Unit profiles: decode against the senders' documented units, encode as its exact inverse (through real
pymavlink packing), timestamps, saturation and the refusal of ArduPilot's HIGHRES_IMU magnetometer."""

from __future__ import annotations

import math
from types import SimpleNamespace

import numpy as np
import pytest
from hypothesis import example, given, settings
from hypothesis import strategies as st
from pymavlink.dialects.v20 import common as mavlink2

from mavattitude.errors import SensorError
from mavattitude.sensors import units
from mavattitude.sensors.units import ImuSample, decode, decode_position, encode, get_profile


def _packed(kind: str, fields: dict) -> object:
    """Encode with pymavlink, pack to bytes and parse back: what arrives over a real link."""
    mav = mavlink2.MAVLink(None, srcSystem=1, srcComponent=1)
    msg = getattr(mav, f"{kind.lower()}_encode")(**fields)
    return mav.parse_char(msg.pack(mav))


def _msg(kind: str, **fields: float) -> SimpleNamespace:
    return SimpleNamespace(get_type=lambda: kind, **fields)


IMU_ZERO = dict.fromkeys(("xacc", "yacc", "zacc", "xgyro", "ygyro", "zgyro", "xmag", "ymag", "zmag"), 0)


def test_ardupilot_raw_imu_units_are_milli_g_milliradian_and_milligauss() -> None:
    fields = {**IMU_ZERO, "xacc": 1000, "zacc": -1000, "xgyro": 500, "xmag": 1000, "zmag": -250}
    s = decode(_packed("RAW_IMU", {"time_usec": 1_500_000, **fields}), get_profile("ardupilot"))
    assert s.time_s == 1.5
    assert s.acc_mps2 == pytest.approx((9.80665, 0.0, -9.80665), abs=1e-12)  # 1000 mG = 1 g
    assert s.gyr_radps == pytest.approx((0.5, 0.0, 0.0), abs=1e-12)  # mrad/s
    assert s.mag_uT == pytest.approx((100.0, 0.0, -25.0), abs=1e-12)  # 1 gauss = 100 µT
    assert s.time_wrap_s is None and s.saturated == frozenset()  # a uint64 of µs: never wraps
    assert s.mag_repeats  # the newest compass reading in every message: a repeat is no new reading


def test_scaled_imu_time_is_time_boot_ms() -> None:
    s = decode(_packed("SCALED_IMU2", {"time_boot_ms": 123_456, **IMU_ZERO, "xmag": 1}), get_profile("px4"))
    assert s.time_s == pytest.approx(123.456, abs=1e-12)
    assert s.time_wrap_s == 2**32 * 1e-3  # a uint32 of ms: the front end's clock unwraps it
    assert s.mag_repeats


def test_px4_highres_imu_is_si_with_gauss_and_fields_updated() -> None:
    fields = {**IMU_ZERO, "xacc": 1.5, "zacc": -9.75, "zgyro": 0.25, "xmag": 0.2, "ymag": -0.05, "zmag": 0.45}
    extra = {"abs_pressure": 0, "diff_pressure": 0, "pressure_alt": 0, "temperature": 0}
    with_mag = decode(
        _packed("HIGHRES_IMU", {"time_usec": 7, **fields, **extra, "fields_updated": 0x1FF}), get_profile("px4")
    )
    assert with_mag.acc_mps2 == pytest.approx((1.5, 0.0, -9.75))
    assert with_mag.gyr_radps == pytest.approx((0.0, 0.0, 0.25))
    assert with_mag.mag_uT == pytest.approx((20.0, -5.0, 45.0), rel=1e-6)  # float32 on the wire
    assert not with_mag.mag_repeats  # fields_updated says it is new, whatever its value
    without = decode(
        _packed("HIGHRES_IMU", {"time_usec": 8, **fields, **extra, "fields_updated": 0x3F}), get_profile("px4")
    )
    assert without.mag_uT is None


def test_ardupilot_highres_imu_magnetometer_is_refused() -> None:
    # ArduPilot's HIGHRES_IMU magnetometer is 10⁶ too large: an Earth field of 0.45 gauss arrives as 4.5e5
    msg = _msg("HIGHRES_IMU", time_usec=1, xacc=0, yacc=0, zacc=-9.8, xgyro=0, ygyro=0, zgyro=0,
               xmag=2.0e5, ymag=0.0, zmag=4.0e5, fields_updated=0x1FF)  # fmt: skip
    with pytest.raises(SensorError, match=r"HIGHRES_IMU magnetometer .* implausible.*RAW_IMU or SCALED_IMU"):
        decode(msg, get_profile("ardupilot"))


def test_adis16405_counts_are_14_bit_twos_complement_with_datasheet_scales() -> None:
    # 0x3FFF is −1 in 14 bits; bit 15 (ND, new data) and bit 14 (EA, error/alarm) are register flags
    counts = {"xacc": 300, "yacc": 0x3FFF, "zacc": 0x8000 | 0x2000, "xgyro": 20, "ygyro": -20,
              "zgyro": 0, "xmag": 1000, "ymag": 0, "zmag": -1000}  # fmt: skip
    msg = _msg("RAW_IMU", time_usec=10, **counts)
    s = decode(msg, get_profile("adis16405"))
    mg = 9.80665e-3
    assert s.acc_mps2 == pytest.approx((300 * 3.33 * mg, -3.33 * mg, -8192 * 3.33 * mg))
    assert s.gyr_radps == pytest.approx((math.radians(1.0), -math.radians(1.0), 0.0))  # 0.05 °/s/LSB
    assert s.mag_uT == pytest.approx((50.0, 0.0, -50.0))  # 0.5 mgauss/LSB = 0.05 µT
    assert s.saturated == frozenset({"acc"})  # −8192 is the 14-bit limit


def test_int16_limit_marks_the_sensor_saturated() -> None:
    s = decode(_packed("RAW_IMU", {"time_usec": 1, **IMU_ZERO, "zacc": -32768, "xmag": 5}), get_profile("ardupilot"))
    assert s.saturated == frozenset({"acc"})


def test_all_zero_magnetometer_means_no_compass() -> None:
    s = decode(_packed("SCALED_IMU", {"time_boot_ms": 5, **IMU_ZERO, "zacc": -1000}), get_profile("ardupilot"))
    assert s.mag_uT is None


def test_custom_profile_scales_each_sensor() -> None:
    scales = units.CustomScales(accel_mps2_per_lsb=0.01, gyro_radps_per_lsb=0.001, mag_uT_per_lsb=0.1)
    s = decode(_msg("RAW_IMU", time_usec=0, **{**IMU_ZERO, "xacc": 100, "ygyro": 10, "zmag": 400}),
               get_profile("custom", scales))  # fmt: skip
    assert s.acc_mps2 == pytest.approx((1.0, 0, 0)) and s.gyr_radps == pytest.approx((0, 0.01, 0))
    assert s.mag_uT == pytest.approx((0, 0, 40.0))
    with pytest.raises(SensorError, match="positive"):
        units.custom_profile(0.0, 1.0, 1.0)


def test_unknown_profile_and_unread_message_are_errors() -> None:
    with pytest.raises(SensorError, match="unknown unit profile"):
        get_profile("betaflight")
    with pytest.raises(SensorError, match="does not read SCALED_IMU"):
        decode(_msg("SCALED_IMU", time_boot_ms=0, **IMU_ZERO), get_profile("adis16405"))


vec = st.tuples(*[st.floats(-50, 50)] * 3)


@settings(max_examples=60, deadline=None)
@given(
    profile=st.sampled_from(["ardupilot", "px4", "adis16405"]),
    t=st.floats(0, 4e6),
    acc=vec,
    gyr=st.tuples(*[st.floats(-5, 5)] * 3),
    mag=st.one_of(st.none(), vec),
)
@example(profile="ardupilot", t=1048576.3125, acc=(0, 0, 0), gyr=(0, 0, 0), mag=None)  # a half-ms tie at 2²⁰ s
def test_encode_is_the_inverse_of_decode_through_pymavlink(profile, t, acc, gyr, mag) -> None:
    p = get_profile(profile)
    for kind in p.messages:
        sample = ImuSample(t, acc, gyr, mag)
        back = decode(_packed(kind, encode(sample, p, kind)), p)
        scale = p.messages[kind]
        layout = units.LAYOUTS[kind]
        integer = layout.integer
        # integer fields: half a unit of rounding; float32 fields: 1e-7 relative of the largest component
        tol = [0.5 * scale.acc_mps2, 0.5 * scale.gyr_radps, 0.5 * scale.mag_uT] if integer else [1e-5, 1e-6, 1e-5]
        assert back.acc_mps2 == pytest.approx(acc, abs=tol[0] * 1.0001)
        assert back.gyr_radps == pytest.approx(gyr, abs=tol[1] * 1.0001)
        rounds_to_zero = mag is not None and integer and max(abs(v) for v in mag) < 0.5 * scale.mag_uT
        if mag is None or rounds_to_zero:
            assert back.mag_uT is None
        else:
            assert back.mag_uT == pytest.approx(mag, abs=tol[2] * 1.0001)
        wrap = layout.time_wrap_s
        expected_t = t % wrap if wrap else t
        # half a tick of the time field, plus the float rounding of ticks × unit (the unit itself inexact): 2 ulp
        assert back.time_s == pytest.approx(expected_t, abs=0.5 * layout.time_unit_s + 2 * math.ulp(expected_t))


def test_time_boot_ms_wraps_at_2_to_the_32() -> None:
    assert units.time_boot_ms(2**32 / 1000 + 1.5) == 1500
    assert units.time_boot_ms(12.3456) == 12346


def test_time_usec_stays_within_a_uint64() -> None:
    """The latest RAW_IMU time_usec, 2⁶⁴ − 1 µs, rounds to 2⁶⁴ as a float: sent back as it came, not past it."""
    assert units.time_usec((2**64 - 1) * 1e-6) == 2**64 - 1
    assert units.time_usec(-1.0) == 0 and units.time_usec(1.5) == 1_500_000


def test_positions_need_a_3d_fix_and_are_degrees_and_metres() -> None:
    gpi = _packed("GLOBAL_POSITION_INT", dict(time_boot_ms=1, lat=473_977_420, lon=85_455_940, alt=488_000,
                                              relative_alt=0, vx=0, vy=0, vz=0, hdg=0))  # fmt: skip
    assert decode_position(gpi) == units.Position(pytest.approx(47.397742), pytest.approx(8.545594), 488.0)
    no_position = _msg("GLOBAL_POSITION_INT", lat=0, lon=0, alt=0)
    assert decode_position(no_position) is None
    gps = dict(time_usec=1, lat=10_000_000, lon=20_000_000, alt=5000, eph=0, epv=0, vel=0, cog=0, satellites_visible=9)
    assert decode_position(_packed("GPS_RAW_INT", {**gps, "fix_type": 2})) is None  # 2D fix
    assert decode_position(_packed("GPS_RAW_INT", {**gps, "fix_type": 3})) == units.Position(1.0, 2.0, 5.0)


def test_a_position_off_the_globe_is_none_as_one_message_and_as_columns() -> None:
    """A garbled latitude of 2³¹ − 1 × 10⁻⁷ = 214.7°, a longitude of 190°, or an altitude of −2³¹ mm (2147 km
    down, outside the magnetic model's −1 to 850 km) is no place: the model would give a field for it all the
    same (174 µT at that depth)."""
    lat = np.array([473_977_420, 2**31 - 1, 0, 473_977_420, 473_977_420])
    lon = np.array([85_455_940, 85_455_940, 0, 1_900_000_000, 85_455_940])
    alt = np.array([488_000, 488_000, 0, 488_000, -(2**31)])
    valid, _ = units.decode_position_columns("GLOBAL_POSITION_INT", {"lat": lat, "lon": lon, "alt": alt})
    assert valid.tolist() == [True, False, False, False, False]
    one_by_one = [
        decode_position(_msg("GLOBAL_POSITION_INT", lat=int(a), lon=int(b), alt=int(h))) is not None
        for a, b, h in zip(lat, lon, alt, strict=True)
    ]
    assert one_by_one == valid.tolist()


@pytest.mark.parametrize(
    ("profile", "message"),
    [(name, m) for name, p in units.PROFILES.items() for m in p.messages],
)
def test_the_columns_decode_each_message_as_decode_does(profile: str, message: str) -> None:
    """decode_columns (a log read as arrays) gives every row what decode gives the message: the same floats,
    the same missing or saturated sensors, the same refusals (seeded values over each field's whole range)."""
    import numpy as np

    rng = np.random.default_rng(11)
    cls = getattr(mavlink2, f"MAVLink_{message.lower()}_message")
    types = dict(zip(cls.fieldnames, cls.fieldtypes, strict=True))
    n = 400
    fields: dict[str, np.ndarray] = {}
    for name, kind in types.items():
        if kind == "float":
            fields[name] = rng.normal(0.0, 5.0, n).astype(np.float32)
        else:
            info = np.iinfo(kind.removesuffix("_t"))
            fields[name] = rng.integers(info.min, int(info.max) + 1, n, dtype=kind.removesuffix("_t"))
    for name in ("xmag", "ymag", "zmag"):
        fields[name][::7] = 0  # rows without a magnetometer
    if "fields_updated" in fields:
        fields["fields_updated"][::3] = units.HIGHRES_ACC_GYRO_UPDATED  # no new magnetometer
    else:  # at the integer limits: saturated
        fields["xacc"][5], fields["zgyro"][6], fields["ymag"][8] = 32767, -32768, 32767
    columns = units.decode_columns(message, fields, units.PROFILES[profile])
    assert columns.has_mag.sum() < n and (columns.saturated.any() or message == "HIGHRES_IMU")
    for i, sample in enumerate(columns.samples()):
        msg = SimpleNamespace(get_type=lambda: message, **{k: v[i].item() for k, v in fields.items()})
        try:
            expected = decode(msg, units.PROFILES[profile])
        except SensorError as exc:
            assert sample is None and str(columns.error(i)) == str(exc)
            continue
        assert sample == expected


def test_encode_position_is_decode_positions_inverse() -> None:
    fields = units.encode_position(units.Position(47.397742, -8.545594, 488.25))
    assert fields == (473_977_420, -85_455_940, 488_250)  # degrees × 10⁷, millimetres
    gpi = _msg("GLOBAL_POSITION_INT", lat=fields[0], lon=fields[1], alt=fields[2])
    # one unit of the encoding apart at most: 1e-7°, 1 mm
    assert decode_position(gpi) == units.Position(
        pytest.approx(47.397742, abs=1e-7), pytest.approx(-8.545594, abs=1e-7), pytest.approx(488.25, abs=1e-3)
    )
