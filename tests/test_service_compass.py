"""The service reports an inconsistent compass once, as a log warning, a STATUSTEXT and counters."""

from __future__ import annotations

import logging

import numpy as np
import pytest

from mavattitude.estimation.conventions import rotate_ned_to_body
from mavattitude.link.mavlink2 import mavlink2
from mavattitude.link.memory import MemoryLink
from mavattitude.pipeline import AttitudePipeline
from mavattitude.reports import compass_statustext
from mavattitude.sensors import units
from mavattitude.service import AttitudeService
from mavattitude.systemd_notify import SystemdNotifier
from tests.test_dispatch import Peer, memory_service, sent, serve  # noqa: F401 (memory_service: a fixture)
from tests.test_service import (
    DECLINATION_DEG,
    G_NED_MPS2,
    GYRO_RADPS,
    INCLINATION_DEG,
    Q_TRUE,
    mag_ned_uT,
    make_config,
)

ACC = rotate_ned_to_body(Q_TRUE, G_NED_MPS2)
UPSIDE_DOWN = rotate_ned_to_body(Q_TRUE, mag_ned_uT()) * np.array([1.0, 1.0, -1.0])


def test_a_compass_upside_down_is_said_once_in_the_log_and_as_a_statustext(memory_service, caplog):  # noqa: F811
    service, link = memory_service
    caplog.set_level(logging.INFO, logger="mavattitude.service")
    vehicle = Peer()
    link.deliver(vehicle.heartbeat(), *vehicle.stream(1000, mag_uT=UPSIDE_DOWN))  # 5 s at 200 Hz
    serve(service, link)
    warnings = [r.getMessage() for r in caplog.records if "compass dip" in r.getMessage()]
    assert len(warnings) == 1 and warnings[0].endswith("check the compass orientation and calibration")
    texts = [m.text for m in sent(link, "STATUSTEXT") if "compass" in m.text]
    figures = service.pipeline.compass.figures()
    assert texts == [compass_statustext(figures)] and len(texts[0]) <= 50
    assert texts[0].startswith(f"compass dip {figures.dip_deg:+.0f} (expected +60)")
    service._log_counters(final=True)
    line = [r.getMessage() for r in caplog.records if r.getMessage().startswith("counters (final):")][-1]
    pairs = dict(item.split("=") for item in line.removeprefix("counters (final): ").split())
    assert pairs["compass_warnings"] == "1" and pairs["compass_dip_expected_deg"] == "60.000"
    # the tilt is kept from the accelerometer: every output after the first tick took heading only
    assert service.counters.emitted > 0


def test_a_good_compass_is_not_reported(memory_service, caplog):  # noqa: F811
    service, link = memory_service
    caplog.set_level(logging.INFO, logger="mavattitude.service")
    vehicle = Peer()
    link.deliver(vehicle.heartbeat(), *vehicle.stream(1000))
    serve(service, link)
    assert not any("compass dip" in r.getMessage() for r in caplog.records)
    assert not any("compass" in m.text for m in sent(link, "STATUSTEXT"))
    # RAW_IMU quantisation (1 mgauss of 500, 1 mG of 1000) moves the dip by < 0.2°
    assert service.pipeline.compass.figures().dip_deg == pytest.approx(60.0, abs=0.5)


def _scaled_imu2(vehicle: Peer, mag_uT: np.ndarray) -> bytes:
    """A SCALED_IMU2 carrying the vehicle's second compass (the IMU fields as RAW_IMU's, at the last sample's time)."""
    sample = units.ImuSample(vehicle.time_s, tuple(ACC), GYRO_RADPS, tuple(mag_uT))
    fields = units.encode(sample, units.PROFILES["ardupilot"], "SCALED_IMU2")
    return vehicle.pack(mavlink2.MAVLink_scaled_imu2_message(**fields))


def test_a_second_compass_upside_down_is_named_and_the_first_one_is_not(memory_service, caplog):  # noqa: F811
    # RAW_IMU carries compass 1 (good), SCALED_IMU2 compass 2 (upside down): each judged on the same IMU samples
    service, link = memory_service
    caplog.set_level(logging.INFO, logger="mavattitude.service")
    vehicle = Peer()
    messages = [vehicle.heartbeat()]
    for _ in range(1000):  # 5 s at 200 Hz
        messages += [vehicle.raw_imu(), _scaled_imu2(vehicle, UPSIDE_DOWN)]
    link.deliver(*messages)
    serve(service, link)
    warnings = [r.getMessage() for r in caplog.records if r.levelno == logging.WARNING and "compass" in r.getMessage()]
    assert len(warnings) == 1 and warnings[0].startswith("compass 2: compass dip")
    texts = [m.text for m in sent(link, "STATUSTEXT") if "compass" in m.text]
    assert len(texts) == 1 and texts[0].startswith("compass 2 dip") and len(texts[0]) <= 50
    assert service.pipeline.compass.warnings == 0  # compass 1, the one replayed, is not warned about
    assert service.other_compasses.judges[1].compass.warnings == 1


def test_the_calibration_fitted_to_our_compass_is_not_applied_to_the_others(caplog):
    """calibration.mag is fitted to input.message's compass (RAW_IMU's: 30 µT of hard iron here); compass 2 comes
    calibrated by the autopilot. Its judge takes it as it comes: with our hard iron it read |B| 30 µT off."""
    caplog.set_level(logging.WARNING, logger="mavattitude.service")
    hard_iron = np.array([30.0, 0.0, 0.0])
    field = {"declination_deg": DECLINATION_DEG, "inclination_deg": INCLINATION_DEG}
    field["intensity_uT"] = float(np.linalg.norm(mag_ned_uT()))  # known: the thresholds are the noise's, not 96°
    config = make_config(**{"calibration.mag.hard_iron_uT": hard_iron.tolist(), "reference.magnetic": field})
    link = MemoryLink()
    service = AttitudeService(config, link, AttitudePipeline(config), SystemdNotifier(environ={}))
    vehicle = Peer()
    truth = rotate_ned_to_body(Q_TRUE, mag_ned_uT())
    messages = [vehicle.heartbeat()]
    for _ in range(1000):  # 5 s at 200 Hz
        messages += [vehicle.raw_imu(mag_uT=truth + hard_iron), _scaled_imu2(vehicle, truth)]
    link.deliver(*messages)
    serve(service, link)
    assert service.other_compasses.judges[1].compass.samples > 25  # judged, and
    assert not [r.getMessage() for r in caplog.records if "compass" in r.getMessage()]  # neither is off
    assert service.pipeline.compass.warnings == 0 and service.other_compasses.judges[1].compass.warnings == 0
