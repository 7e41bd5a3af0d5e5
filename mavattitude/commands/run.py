"""`mavattitude run`: the companion-computer daemon (MAVLink in, ATTITUDE_QUATERNION out).

Configuration precedence (highest first): the flags below > the file named by ``$MAVATTITUDE_CONFIG``
> ``--config FILE`` > built-in defaults. SIGTERM or SIGINT stops it within a second with exit code 0
and a final counters line.
"""

from __future__ import annotations

import argparse
import gc
import logging
import signal
import threading
from typing import Any

from mavattitude.commands import EXIT_INTERRUPTED
from mavattitude.config import DEFAULTS, ENV_VAR, load_config
from mavattitude.sensors.units import MESSAGES, PROFILE_NAMES

NAME = "run"
HELP = "run the attitude service on a MAVLink link (the daemon)"

log = logging.getLogger(__name__)

# flag destination -> dotted config key
_OVERRIDES = {
    "connect": "link.connect",
    "vehicle_system_id": "link.vehicle_system_id",
    "component_id": "link.component_id",
    "rate": "link.request_rate_hz",
    "request_messages": "link.request_messages",
    "signing_key": "link.signing.key_file",
    "require_signing": "link.signing.require_signing",
    "message": "input.message",
    "profile": "input.profile",
    "input_timeout": "input.input_timeout_s",
    "stats_interval": "output.stats_interval_s",
}


def add_arguments(parser: argparse.ArgumentParser) -> None:
    d = DEFAULTS  # the defaults quoted below are the config's own
    parser.description = (
        f"{HELP}. Precedence: flags > ${ENV_VAR} file > --config FILE > defaults. "
        "Stops cleanly on SIGTERM/SIGINT with a final counters line."
    )
    parser.add_argument("--config", metavar="FILE", help="YAML config (see configs/*.yaml)")
    parser.add_argument(
        "--connect",
        metavar="STR",
        help="pymavlink connection string: udpin:HOST:PORT, udpout:HOST:PORT, tcp:HOST:PORT, tcpin:HOST:PORT "
        f"or a serial device /dev/ttyACM0[,BAUD] (default {d.link.connect})",
    )
    parser.add_argument(
        "--vehicle-system-id",
        type=int,
        metavar="ID",
        help=f"autopilot system id 1-254; 0 = the first autopilot heartbeat (default {d.link.vehicle_system_id})",
    )
    parser.add_argument(
        "--component-id",
        type=int,
        metavar="ID",
        help=f"our MAVLink component id 2-255, not the autopilot's 1 (default {d.link.component_id}, an onboard "
        "computer's)",
    )
    parser.add_argument(
        "--rate",
        type=float,
        metavar="HZ",
        help=f"input rate requested with SET_MESSAGE_INTERVAL, Hz (default {d.link.request_rate_hz:g})",
    )
    parser.add_argument(
        "--no-request",
        dest="request_messages",
        action="store_const",
        const=False,
        help="ask for no stream with SET_MESSAGE_INTERVAL (the input, the position, SYSTEM_TIME, GPS_RAW_INT, "
        "ATTITUDE: none of them; the autopilot already streams what is needed)",
    )
    parser.add_argument(
        "--signing-key",
        metavar="FILE",
        help="MAVLink 2 signing key: 32 raw bytes, or a passphrase line hashed with SHA-256 as MAVProxy does; "
        "must not be world-readable",
    )
    parser.add_argument(
        "--require-signing",
        action="store_const",
        const=True,
        help="drop unsigned or badly signed input (needs a signing key)",
    )
    parser.add_argument("--message", choices=MESSAGES, help=f"IMU message to read (default {d.input.message})")
    parser.add_argument(
        "--profile", choices=PROFILE_NAMES, help=f"unit profile of that message (default {d.input.profile})"
    )
    parser.add_argument(
        "--input-timeout",
        type=float,
        metavar="S",
        help=f"input gap that stops the output, s (default {d.input.input_timeout_s:g})",
    )
    parser.add_argument(
        "--stats-interval",
        type=float,
        metavar="S",
        help=f"period of the counters log line, s (default {d.output.stats_interval_s:g})",
    )


def overrides_from_args(args: argparse.Namespace) -> dict[str, Any]:
    """The dotted config keys the flags set (flags left out set nothing)."""
    return {key: getattr(args, dest) for dest, key in _OVERRIDES.items() if getattr(args, dest, None) is not None}


def run(args: argparse.Namespace) -> int:
    from mavattitude.pipeline import AttitudePipeline  # numpy, pymavlink and the solvers: only when serving
    from mavattitude.service import AttitudeService, log_banner, open_link

    config = load_config(args.config, overrides_from_args(args))
    if getattr(args, "log_level", None) is None:  # no --log-level flag: the config's level applies
        logging.getLogger().setLevel(config.logging.level)
    stop = threading.Event()
    stopped_by: list[int] = []

    def on_signal(signum: int, _frame: object) -> None:
        stopped_by.append(signum)
        stop.set()

    previous = {sig: signal.signal(sig, on_signal) for sig in (signal.SIGTERM, signal.SIGINT)}
    try:
        pipeline = AttitudePipeline(config)
        log_banner(config)
        with open_link(config) as link:
            service = AttitudeService(config, link, pipeline)
            # Everything allocated so far (pymavlink's dialect alone is ~40 000 objects) lives as long as the
            # process: keep it out of the collector, whose full passes over it took ~9 ms, the latency budget.
            gc.collect()
            gc.freeze()
            service.run(stop)
    finally:
        for sig, handler in previous.items():
            signal.signal(sig, handler)
    # SIGTERM is how systemd and Docker stop a service: a clean stop. Ctrl-C is an interruption.
    return EXIT_INTERRUPTED if signal.SIGINT in stopped_by[:1] else 0
