"""`mavattitude demo`: the service and the fake vehicle on loopback, with a live error table.

Starts the fake vehicle on an ephemeral UDP port of 127.0.0.1, then `mavattitude run` as a subprocess
connected to it (exactly as it runs on a companion computer), and prints once a second how far the
ATTITUDE_QUATERNION the service sends is from the truth, and under it every STATUSTEXT the service sent the
vehicle since (what a ground station shows the pilot: its start, a cross-check that disagrees with
``--autopilot-error``, a compass judged off). Finite (``--duration``) and Ctrl-C safe: both processes are
stopped and the whole run is scored at the end.
"""

from __future__ import annotations

import argparse
import logging
import signal
import time

from mavattitude.commands import EXIT_INTERRUPTED
from mavattitude.commands.simulate import add_vehicle_arguments, say_statustexts, vehicle_from_args
from mavattitude.config import DEFAULTS
from mavattitude.errors import MavAttitudeError
from mavattitude.estimation import METHODS
from mavattitude.sim.daemon import START_TIMEOUT_S, ServiceProcess, config_for
from mavattitude.sim.scoring import Score
from mavattitude.sim.vehicle import FakeVehicle

NAME = "demo"
HELP = "run the service against the fake vehicle on loopback and print a live attitude error table"

log = logging.getLogger(__name__)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    add_vehicle_arguments(parser, default_duration_s=20.0)
    parser.add_argument(
        "--method",
        default=DEFAULTS.estimator.method,
        choices=METHODS,
        help=f"the service's estimator (default {DEFAULTS.estimator.method})",
    )
    parser.add_argument("--interval", type=float, default=1.0, metavar="S", help="table row period, s (default 1)")


def _interrupt(signum: int, frame: object) -> None:
    raise KeyboardInterrupt  # SIGTERM ends the demo as Ctrl-C does: both processes stopped, a summary


def run(args: argparse.Namespace) -> int:
    if not args.interval > 0:
        raise MavAttitudeError(f"--interval must be positive, got {args.interval}")
    previous = signal.signal(signal.SIGTERM, _interrupt)
    try:
        return _demo(args)
    finally:
        signal.signal(signal.SIGTERM, previous)


def _demo(args: argparse.Namespace) -> int:
    with vehicle_from_args(args, "udpin:127.0.0.1:0", stream_on_start=False) as vehicle:
        config = config_for(vehicle, estimator={"method": args.method})
        with ServiceProcess(config, log_level="WARNING") as service:
            print(
                f"fake vehicle on udp 127.0.0.1:{vehicle.port}, service pid {service.pid}, script {args.script}",
                flush=True,
            )
            interrupted = False
            try:
                _table(vehicle, service, args.duration, args.interval)
            except KeyboardInterrupt:  # both processes still stopped, and the summary still printed
                print("interrupted")
                interrupted = True
            code = service.stop()
    print(f"service exit code {code}; whole run:")
    print(Score.header())
    print(vehicle.score().row())
    return EXIT_INTERRUPTED if interrupted else 0


def _table(vehicle: FakeVehicle, service: ServiceProcess, duration_s: float, interval_s: float) -> None:
    if not vehicle.wait_for_outputs(1, START_TIMEOUT_S):
        raise MavAttitudeError("the service sent no attitude in time; its log:\n" + service.log_tail())
    print("     t " + Score.header().replace("\n", "\n       "))
    start, said = len(vehicle.attitude_log), 0
    while vehicle.script_time() < duration_s:
        if not service.running:
            raise MavAttitudeError("the service stopped; its log:\n" + service.log_tail())
        time.sleep(interval_s)  # the table's pace, not a synchronisation
        index = len(vehicle.attitude_log)
        if index > start:
            print(f"{vehicle.script_time():6.1f} {vehicle.score(start).row()}", flush=True)
        start = index
        said = say_statustexts(vehicle, said, lambda text: print(f"{'':6} STATUSTEXT {text}", flush=True))
