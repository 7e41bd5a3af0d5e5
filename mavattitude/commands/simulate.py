"""`mavattitude simulate`: run the scripted fake vehicle on a MAVLink connection.

The vehicle flies a truth script, streams IMU messages of a unit profile once asked (or at once with
``--stream-on-start``), logs each STATUSTEXT it receives (what a ground station would show the pilot), and at
the end prints how the ATTITUDE_QUATERNION it received compares with the truth. Point a running
`mavattitude run` (or a router) at it; with ``--serial`` it is on a pseudo-terminal instead, a serial device
whose path it logs (:mod:`mavattitude.sim.relay`), to try a service's serial wiring without the hardware.
"""

from __future__ import annotations

import argparse
import logging
import time
from collections.abc import Callable
from contextlib import nullcontext

from mavattitude.commands import EXIT_INTERRUPTED
from mavattitude.config import DEFAULTS
from mavattitude.errors import MavAttitudeError
from mavattitude.sensors.units import MESSAGES, PROFILES
from mavattitude.service import WaitReports
from mavattitude.sim import scenarios
from mavattitude.sim.relay import serial_relay
from mavattitude.sim.scoring import Score
from mavattitude.sim.sensors import DEFAULT_RATE_HZ
from mavattitude.sim.vehicle import FakeVehicle, VehicleConfig

NAME = "simulate"
HELP = "run the scripted fake vehicle (a MAVLink 2 autopilot peer) on a connection and score what it hears"

log = logging.getLogger(__name__)


def add_vehicle_arguments(parser: argparse.ArgumentParser, default_duration_s: float) -> None:
    """The options that describe the fake vehicle (shared with `mavattitude demo`)."""
    for flag, presets, default, what in (
        ("--script", scenarios.SCRIPTS, "tour", "truth trajectory"),
        ("--sensors", scenarios.SENSORS, "consumer", "sensor error preset"),
    ):
        about = (presets[default].__doc__ or "").split("\n")[0].rstrip(".")  # the preset's own description
        parser.add_argument(flag, default=default, choices=sorted(presets), help=f"{what} (default {default}: {about})")
    parser.add_argument(
        "--duration",
        type=float,
        default=default_duration_s,
        metavar="S",
        help=f"how long to fly, vehicle seconds from the first IMU request (default {default_duration_s:g})",
    )
    parser.add_argument(
        "--profile",
        default=DEFAULTS.input.profile,
        choices=sorted(PROFILES),
        help=f"unit profile (default {DEFAULTS.input.profile})",
    )
    parser.add_argument(
        "--message",
        type=str.upper,
        choices=MESSAGES,
        help="IMU message (default: the profile's own, "
        + ", ".join(f"{p.default_message} for {name}" for name, p in PROFILES.items())
        + ")",
    )
    parser.add_argument(
        "--rate", type=float, default=DEFAULT_RATE_HZ, metavar="HZ", help=f"IMU rate, Hz (default {DEFAULT_RATE_HZ:g})"
    )
    parser.add_argument(
        "--link-max-hz",
        type=float,
        metavar="HZ",
        help="the most IMU messages a second the link carries, whatever rate is asked: a telemetry radio (a "
        "57600-baud one carries about 140 RAW_IMU a second), a ground station's stream rates (2-10); default: no "
        "limit",
    )
    parser.add_argument("--seed", type=int, default=0, help="noise seed (default 0)")
    parser.add_argument(
        "--autopilot-error",
        type=float,
        nargs=3,
        default=(0.0, 0.0, 0.0),
        metavar=("ROLL", "PITCH", "YAW"),
        help="the error of the autopilot's own ATTITUDE (10 Hz, the truth otherwise), degrees (default 0 0 0)",
    )


def vehicle_from_args(args: argparse.Namespace, connect: str, stream_on_start: bool) -> FakeVehicle:
    if not args.duration > 0:
        raise MavAttitudeError(f"--duration must be positive, got {args.duration}")
    for flag, value in (("--rate", args.rate), ("--link-max-hz", args.link_max_hz)):
        if value is not None and not value > 0:
            raise MavAttitudeError(f"{flag} must be positive, got {value}")
    script = scenarios.script_named(args.script, args.duration)
    if args.script == "paper_static" and args.sensors == "consumer":
        log.info("paper_static flies with the paper's noise; use --sensors to choose another")
    config = VehicleConfig(
        connect,
        profile=args.profile,
        message=args.message or PROFILES[args.profile].default_message,
        stream_on_start=stream_on_start,
        fly_when_asked=True,  # the script (and --duration) starts when the IMU is first asked for
        seed=args.seed,
        attitude_error_deg=tuple(args.autopilot_error),
        link_max_imu_hz=args.link_max_hz,
    )
    return FakeVehicle(script, scenarios.sensors_named(args.sensors, args.rate), config)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    where = parser.add_mutually_exclusive_group()
    where.add_argument(
        "--connect",
        default="udpout:127.0.0.1:14551",
        help="pymavlink connection string of the vehicle (default udpout:127.0.0.1:14551: it sends to the "
        "service's port, as a router on the companion computer does, so `mavattitude run --config "
        "configs/ardupilot.yaml` hears it)",
    )
    where.add_argument(
        "--serial",
        action="store_true",
        help="be on a serial device instead: a pseudo-terminal, whose path (/dev/pts/N) it logs; a service with "
        "that as its link.connect tries a serial wiring without the hardware",
    )
    parser.add_argument(
        "--stream-on-start",
        action="store_true",
        help="stream the IMU message at once (default: silent until SET_MESSAGE_INTERVAL, like ArduPilot Copter)",
    )
    add_vehicle_arguments(parser, default_duration_s=60.0)


def run(args: argparse.Namespace) -> int:
    connect = "udpin:127.0.0.1:0" if args.serial else args.connect  # the relay's far end when on a pty
    vehicle = vehicle_from_args(args, connect, args.stream_on_start)
    with vehicle, serial_relay(vehicle.port) if args.serial else nullcontext() as device:
        where = device or (connect.removesuffix(":0") + f":{vehicle.port}" if connect.endswith(":0") else connect)
        interrupted = False
        try:
            _fly(vehicle, args, where)
        except KeyboardInterrupt:  # the summary is still printed
            log.info("interrupted")
            interrupted = True
    print(f"IMU messages sent: {vehicle.imu_sent}, ATTITUDE_QUATERNION received: {len(vehicle.attitude_log)}")
    if vehicle.attitude_log:
        print(Score.header())
        print(vehicle.score().row())
    return EXIT_INTERRUPTED if interrupted else 0


def say_statustexts(vehicle: FakeVehicle, said: int, say: Callable[[str], None]) -> int:
    """Each STATUSTEXT the vehicle received after its first ``said`` to ``say`` (what a ground station shows the
    pilot); how many it has now."""
    texts = vehicle.statustexts[said:]
    for text in texts:
        say(text)
    return said + len(texts)


def _fly(vehicle: FakeVehicle, args: argparse.Namespace, where: str) -> None:
    """Until the script's end; while nobody asks for the IMU stream on ``where``, say so now and then."""
    log.info("fake vehicle on %s: %s for %.0f s once asked for IMU", where, args.script, args.duration)
    reports, said = WaitReports(False, time.monotonic()), 0
    while vehicle.script_time() < args.duration:
        time.sleep(0.1)  # pacing the end of the run, not a synchronisation
        said = say_statustexts(vehicle, said, lambda text: log.info("STATUSTEXT from the service: %s", text))
        now = time.monotonic()
        if not reports.changed(vehicle.flying, now) and not vehicle.flying and (waited_s := reports.due(now)):
            log.info(
                "waiting for a service to ask for the IMU stream on %s (is its link.connect pointed here?) "
                "(%.0f s so far)",
                where,
                waited_s,
            )
