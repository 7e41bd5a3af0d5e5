"""Fixtures of the deployment tests: the machine's verdict, the fake vehicle, the README's blocks.

The deployment tests need root, Docker, debootstrap and systemd-nspawn (``.ci/prepare`` installs them
with apt-get) and a reachable Debian mirror and PyPI; without them they skip, and the reason is printed
in pytest's summary. One deployment run at a time per machine: they share the cache and Docker's data root.
"""

from __future__ import annotations

import datetime as dt
import re
from collections.abc import Iterator
from pathlib import Path

import pytest

from mavattitude.sensors.magref import wmm_field_ned_uT
from mavattitude.sim import scenarios
from mavattitude.sim.trajectory import Hold, Script
from mavattitude.sim.vehicle import FakeVehicle, VehicleConfig

from . import machine

ROOT = Path(__file__).resolve().parents[2]
EXAMPLE_CONFIG = ROOT / "configs" / "ardupilot.yaml"  # what both README sections install
OUTPUT_TIMEOUT_S = 30.0  # first attitude from a service just started in a container or a booted machine
MAX_ANGLE_RMS_DEG = 1.0  # static hold, paper-grade sensors: the e2e tests' bound (tests/e2e/test_profiles.py)


@pytest.fixture(scope="module")
def deploy_host() -> Iterator[None]:
    """The machine's go-ahead and the lock, for one module: held to its end, not the session's, so another
    suite's deployment tests wait only for these, not for everything that runs after them here."""
    reason = machine.why_not()
    if reason is not None:
        pytest.skip(f"deployment tests cannot run here: {reason}")
    with machine.cache_lock():
        yield


def readme_block(heading: str, index: int = 0) -> list[str]:
    """The lines of the ``index``-th ```sh block under the README heading ``heading`` (continuations joined)."""
    text = (ROOT / "README.md").read_text()
    start = text.index(heading)
    end = text.find("\n#", start + len(heading))
    blocks = re.findall(r"```sh\n(.*?)```", text[start : end if end != -1 else None], re.S)
    assert len(blocks) > index, f"README: no ```sh block {index} under {heading!r}"
    joined = blocks[index].replace("\\\n", " ")
    return [line.strip() for line in joined.splitlines() if line.strip()]


def vehicle(connect: str, signing_key: bytes | None = None) -> FakeVehicle:
    """The fake vehicle at rest at its home, in the World Magnetic Model's field there: the example
    config's ``reference: auto`` takes the field from its GPS position, so both agree."""
    home = VehicleConfig(connect, fly_when_asked=True, signing_key=signing_key)
    field = wmm_field_ned_uT(home.home_lat_deg, home.home_lon_deg, home.home_alt_m, dt.date.today())
    return FakeVehicle(Script([Hold(600.0)], tuple(field)), scenarios.paper_sensors(200.0), home)


def assert_attitudes_scored(v: FakeVehicle, count: int = 100) -> None:
    """``count`` ATTITUDE_QUATERNION arrive and all are right (the first output is waited for separately)."""
    start = len(v.attitude_log)
    assert v.wait_for_outputs(start + count, OUTPUT_TIMEOUT_S), f"only {len(v.attitude_log) - start} outputs"
    score = v.score(start)
    assert score.broken == 0 and score.angle_rms_deg < MAX_ANGLE_RMS_DEG, score
