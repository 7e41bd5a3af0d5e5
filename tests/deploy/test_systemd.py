"""The unit booted under systemd for real: a Debian 12 tree (debootstrap, cached) in systemd-nspawn,
installed by the README's systemd section line by line, then driven with the fake vehicle.

The machine shares the host's network: the service reaches the fake vehicle in this process on
127.0.0.1. Its link is pointed at the vehicle's ephemeral port (``udpout:``) before ``enable --now``,
the one edit the test makes to what the README says; the vehicle stays silent until a test starts it.
"""

from __future__ import annotations

import re
import secrets
import shutil
import time
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path

import pytest

from mavattitude.sim.vehicle import FakeVehicle

from . import machine
from .conftest import OUTPUT_TIMEOUT_S, ROOT, assert_attitudes_scored, readme_block, vehicle

HEADING = "### 1. As a systemd service"
CHECKOUT = "/root/mavattitude"  # where the README's commands run: a checkout of the repository
CONFIG = "/etc/mavattitude/config.yaml"
UNIT = "mavattitude.service"
READY_LIMIT_S = 5.0
RESTART_TIMEOUT_S = 30.0  # watchdog 5 s, then SIGABRT, the core dump, RestartSec=1s, and a new start
MAX_EXPOSURE = 2.0
DYNAMIC_UIDS = range(61184, 65520)  # systemd's DynamicUser= range
COPY_IGNORE = shutil.ignore_patterns(".venv", ".git", "*cache*", "*.egg-info", "build")

pytestmark = pytest.mark.deploy


@dataclass
class Installed:
    machine: machine.NspawnMachine
    enable_s: float  # how long `systemctl enable --now` took, with no vehicle talking
    status_at_start: str  # the unit's STATUS right after it

    def sh(self, script: str, check: bool = True) -> str:
        return self.machine.sh(script, check=check).stdout.strip()

    def show(self, prop: str) -> str:
        return self.sh(f"systemctl show -p {prop} --value {UNIT}")

    def connect(self) -> str:
        """The installed config's ``link.connect``."""
        path = self.machine.root / CONFIG.lstrip("/")
        found = re.search(r'(?m)^\s*connect: "([^"]*)"', path.read_text())
        assert found is not None, "no link.connect in the installed config"
        return found[1]

    def set_link(self, connect: str, key_file: str | None = None) -> None:
        """Edit the installed config (as a user does) and restart the service."""
        path = self.machine.root / CONFIG.lstrip("/")
        text = re.sub(r'(?m)^(\s*connect: )"[^"]*"', rf'\g<1>"{connect}"', path.read_text(), count=1)
        text = re.sub(r"(?m)^(\s*key_file: )\S+", rf"\g<1>{key_file or 'null'}", text, count=1)
        path.write_text(text)
        self.sh(f"systemctl restart {UNIT}")


@pytest.fixture(scope="module")
def installed(deploy_host: None, tmp_path_factory: pytest.TempPathFactory) -> Iterator[Installed]:
    tree = machine.cached_tree(machine.TREE)
    workdir = tmp_path_factory.mktemp("nspawn")
    with machine.NspawnMachine(tree, workdir) as m:
        shutil.copytree(ROOT, m.root / CHECKOUT.lstrip("/"), ignore=COPY_IGNORE)
        silent = vehicle("udpin:127.0.0.1:0")  # bound, not started: no HEARTBEAT until a test starts one
        lines = readme_block(HEADING)
        enable = lines.index("sudo systemctl daemon-reload && sudo systemctl enable --now mavattitude")
        for line in lines[:enable]:
            m.sh(f"cd {CHECKOUT} && {line}", timeout_s=600)
        path = m.root / CONFIG.lstrip("/")
        path.write_text(path.read_text().replace('"udpin:0.0.0.0:14551"', f'"udpout:127.0.0.1:{silent.port}"', 1))
        start = time.monotonic()
        m.sh(f"cd {CHECKOUT} && {lines[enable]}")
        enable_s = time.monotonic() - start
        status = m.sh(f"systemctl show -p StatusText --value {UNIT}").stdout.strip()
        for line in lines[enable + 1 :]:
            if not line.split("#")[0].rstrip().endswith(" -f"):  # `journalctl -f` follows for ever
                m.sh(f"cd {CHECKOUT} && {line}")
        silent.stop()
        yield Installed(m, enable_s, status)


def test_ready_within_5s_with_no_vehicle_and_status_says_what_it_waits_for(installed: Installed) -> None:
    assert installed.enable_s < READY_LIMIT_S, f"systemctl enable --now took {installed.enable_s:.1f} s"
    assert installed.status_at_start.startswith("waiting for a HEARTBEAT on udpout:127.0.0.1:"), (
        installed.status_at_start
    )
    assert installed.show("ActiveState") == "active"
    assert installed.show("UnitFileState") == "enabled"


@contextmanager
def _flying(installed: Installed, key: bytes | None = None, key_file: str | None = None) -> Iterator[FakeVehicle]:
    """A fake vehicle talking, the service pointed at it and restarted, its first attitude received."""
    v = vehicle("udpin:127.0.0.1:0", signing_key=key)
    installed.set_link(f"udpout:127.0.0.1:{v.port}", key_file)
    with v:
        if not v.wait_for_outputs(1, OUTPUT_TIMEOUT_S):
            log = installed.sh(f"journalctl -u {UNIT} --no-pager -n 30")
            pytest.fail(f"no ATTITUDE_QUATERNION from the unit; journal:\n{log}")
        yield v


def test_attitude_once_the_vehicle_talks_and_the_watchdog_restarts_a_frozen_loop(installed: Installed) -> None:
    with _flying(installed) as v:
        assert_attitudes_scored(v)
        status = installed.show("StatusText")
        assert status == "running" or status.startswith("received="), status
        restarts = int(installed.show("NRestarts"))
        frozen = installed.show("MainPID")
        installed.sh(f"kill -STOP {frozen}")
        deadline = time.monotonic() + RESTART_TIMEOUT_S
        while installed.show("NRestarts") == str(restarts) and time.monotonic() < deadline:
            time.sleep(0.5)  # polling systemd: nothing in the machine can signal this process
        assert int(installed.show("NRestarts")) == restarts + 1
        assert installed.show("MainPID") != frozen
        journal = installed.sh(f"journalctl -u {UNIT} --no-pager -n 50")
        assert "Watchdog timeout" in journal, journal
        assert_attitudes_scored(v)  # the restarted service talks to the vehicle again


def test_systemctl_stop_is_clean(installed: Installed) -> None:
    installed.sh(f"systemctl start {UNIT}")
    start = time.monotonic()
    installed.sh(f"systemctl stop {UNIT}")
    stop_s = time.monotonic() - start
    try:
        assert installed.show("ActiveState") == "inactive"
        assert installed.show("Result") == "success"
        assert installed.show("ExecMainStatus") == "0"
        assert stop_s < 2.0, f"systemctl stop took {stop_s:.1f} s (the service promises 1 s)"
    finally:
        installed.sh(f"systemctl start {UNIT}")


def test_installed_unit_verifies_and_its_security_exposure_is_low(installed: Installed) -> None:
    # What the README says: verify passes once ExecStart= exists, i.e. after the install.
    verify = installed.machine.sh(f"systemd-analyze verify /etc/systemd/system/{UNIT}", check=False)
    assert verify.returncode == 0 and verify.stderr.strip() == "", verify.stderr
    report = installed.sh(f"systemd-analyze security --no-pager {UNIT}")
    exposure = re.search(r"Overall exposure level for mavattitude\.service: ([0-9.]+)", report)
    assert exposure is not None and float(exposure[1]) <= MAX_EXPOSURE, report[-1500:]


def test_the_dynamic_user_reads_the_root_owned_config(installed: Installed) -> None:
    installed.sh(f"systemctl restart {UNIT}")
    pid = installed.show("MainPID")
    uid = int(installed.sh(f"stat -c %u /proc/{pid}"))
    assert uid in DYNAMIC_UIDS
    assert installed.sh(f"stat -c '%U %a' {CONFIG}") == "root 644"
    # It started on that config: its banner names the link the config sets now (whichever case ran
    # before this one: the signing case leaves it on udpin), and it is running.
    connect = installed.connect()
    journal = installed.sh(f"journalctl -u {UNIT} --no-pager -n 20 _PID={pid}")
    assert connect.startswith("udp") and f"link {connect}," in journal, journal
    assert installed.show("ActiveState") == "active"


def test_signing_key_through_load_credential_signs_every_frame(installed: Installed, tmp_path: Path) -> None:
    key = secrets.token_bytes(32)
    key_path = installed.machine.root / CHECKOUT.lstrip("/") / "signing.key"
    key_path.write_bytes(key)
    block = readme_block(HEADING, index=1)  # install the key, uncomment LoadCredential=
    for line in block:
        installed.sh(f"cd {CHECKOUT} && {line.split('  #')[0]}")
    installed.sh("systemctl daemon-reload")
    credential = "/run/credentials/mavattitude.service/signing.key"
    with _flying(installed, key=key, key_file=credential) as v:
        assert_attitudes_scored(v)
        signing = v.conn.mav.signing
        assert signing.badsig_count == 0
        assert signing.goodsig_count >= len(v.attitude_log)  # every frame it sent was signed with the key
    assert installed.sh("stat -c '%U %a' /etc/mavattitude/signing.key") == "root 600"
    installed.set_link("udpin:127.0.0.1:0")  # back to no key for the other tests
