"""`mavattitude demo` and `mavattitude simulate` as a user runs them: real processes, real UDP."""

from __future__ import annotations

import os
import re
import signal
import subprocess
import sys
from pathlib import Path

import pytest

from mavattitude.sim.daemon import ServiceProcess, service_config
from mavattitude.sim.scenarios import DEFAULT_MAG_NED_UT

from .conftest import FAST_SERVICE, free_udp_port, merged

pytestmark = pytest.mark.e2e

CLI = [sys.executable, "-m", "mavattitude"]
ROW = re.compile(r"^\s*(\d+)\s+([\d.]+)\s+([\d.]+)\s+([\d.]+)\s+([\d.]+)\s+([\d.]+)\s+([\d.]+)")
TIMED_ROW = re.compile(r"^\s*\d+\.\d\s+\d+\s+[\d.]+")  # a live row: "  3.0     50    0.248 ..."
TIMEOUT_S = 60.0


def _last_row(text: str) -> list[float]:
    rows = [m.groups() for line in text.splitlines() if (m := ROW.match(line))]
    assert rows, text
    return [float(x) for x in rows[-1]]


def test_demo_runs_finite_and_prints_the_error_table() -> None:
    done = subprocess.run(
        [*CLI, "demo", "--duration", "3", "--script", "static", "--sensors", "paper"],
        capture_output=True,
        text=True,
        timeout=TIMEOUT_S,
    )
    assert done.returncode == 0, done.stderr
    assert "service exit code 0" in done.stdout
    count, err_rms, *_ = _last_row(done.stdout)
    # About 3 s at 50 Hz: how many are scored before the demo stops the vehicle depends on the machine's
    # load, not on the service, so only "some"; paper noise static: ≈ 0.3° RMS (see test_profiles).
    assert count > 0 and err_rms < 1.0, done.stdout


def test_demo_shows_what_the_service_tells_the_ground_station() -> None:
    """An autopilot whose attitude is 10° off in roll: the cross-check's STATUSTEXT under the table, as a ground
    station would show it (the hold is 3 s of judged pairs at rest: well within 8 s)."""
    done = subprocess.run(
        [
            *CLI,
            "demo",
            "--duration",
            "8",
            "--script",
            "static",
            "--sensors",
            "paper",
            "--autopilot-error",
            "10",
            "0",
            "0",
        ],
        capture_output=True,
        text=True,
        timeout=TIMEOUT_S,
    )
    assert done.returncode == 0, done.stderr
    said = [line.split("STATUSTEXT ", 1)[1] for line in done.stdout.splitlines() if "STATUSTEXT " in line]
    assert said[0].startswith("mavattitude ") and said[0].endswith(": attitude from RAW_IMU"), done.stdout
    assert "mavattitude: 10 deg off the autopilot's attitude" in said, done.stdout


def test_demo_is_ctrl_c_safe() -> None:
    proc = subprocess.Popen(
        [*CLI, "demo", "--duration", "600", "--script", "static", "--sensors", "paper"],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        start_new_session=True,  # its own process group, as a terminal's foreground job
    )
    assert proc.stdout is not None
    first = proc.stdout.readline()
    service_pid = int(re.search(r"service pid (\d+)", first).group(1))  # type: ignore[union-attr]
    table = [proc.stdout.readline() for _ in range(4)]  # header (2 lines), first rows: it is running
    assert any(TIMED_ROW.match(line) for line in table), table
    os.killpg(proc.pid, signal.SIGINT)  # Ctrl-C reaches the whole foreground group
    out, err = proc.communicate(timeout=TIMEOUT_S)
    assert proc.returncode == 130, err  # interrupted, as a shell reports Ctrl-C; the service stopped cleanly
    assert "interrupted" in out and "service exit code 0" in out
    assert not Path(f"/proc/{service_pid}").exists(), "the service outlived the demo"


def test_simulate_serves_a_running_service() -> None:
    port = free_udp_port()
    sim = subprocess.Popen(
        [*CLI, "simulate", "--connect", f"udpin:127.0.0.1:{port}", "--duration", "4", "--script", "static"],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    config = service_config(
        port, **merged(FAST_SERVICE, {"reference": {"magnetic": {"field_ned_uT": list(DEFAULT_MAG_NED_UT)}}})
    )
    with ServiceProcess(config) as svc:
        out, err = sim.communicate(timeout=TIMEOUT_S)
        assert svc.stop() == 0
    assert sim.returncode == 0, err
    count, err_rms, *_ = _last_row(out)
    # About 4 s at 50 Hz, how many depends on the load; consumer sensors by default: ≈ 1° RMS from their
    # residual biases.
    assert count > 0 and err_rms < 3.0, out
    assert f"ATTITUDE_QUATERNION received: {int(count)}" in out
    # what the service told the vehicle, as a ground station shows it: its start, first of all
    assert re.search(r"STATUSTEXT from the service: mavattitude \S+: attitude from RAW_IMU", err), err


def test_demo_on_a_slow_link_is_told_so_and_scores_each_sample() -> None:
    """--link-max-hz 4: a telemetry-rate link whatever the service asks. The service outputs one attitude per
    sample (too slow to filter), says the rate (two 5 s windows under 90 % of the 200 Hz asked), and the table's
    latency is each output's own sample's (it read -249 ms: the output's millisecond rounded past its sample)."""
    done = subprocess.run(
        [*CLI, "demo", "--duration", "14", "--script", "static", "--sensors", "paper", "--link-max-hz", "4"],
        capture_output=True,
        text=True,
        timeout=TIMEOUT_S,
    )
    assert done.returncode == 0, done.stderr
    assert "STATUSTEXT mavattitude: RAW_IMU 4 Hz < 200 asked" in done.stdout, done.stdout
    *_, rate_hz, lat_p50, lat_p99 = map(float, done.stdout.strip().splitlines()[-1].split())  # the whole run's
    assert rate_hz == pytest.approx(4.0, abs=0.1) and 0.0 < lat_p50 <= lat_p99 < 50.0, done.stdout


@pytest.mark.parametrize("flag", ["--link-max-hz", "--rate"])
def test_a_rate_that_is_not_positive_is_refused(flag: str) -> None:
    done = subprocess.run([*CLI, "simulate", flag, "0"], capture_output=True, text=True, timeout=TIMEOUT_S)
    assert done.returncode == 2 and f"{flag} must be positive, got 0.0" in done.stderr, done.stderr
