"""The service as a real subprocess (``python -m mavattitude run``), for the end-to-end tests, the demo
and the soak.

:class:`ServiceProcess` writes a YAML config, starts the daemon, reads its log (stderr) on a thread and
turns its periodic counters lines into dictionaries, and stops it with SIGTERM (its exit code and its
final counters line are what the tests assert on). Waiting is on events with bounded time-outs.
"""

from __future__ import annotations

import logging
import os
import re
import signal
import subprocess
import sys
import tempfile
import threading
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import Any

import yaml

from mavattitude.config import merge
from mavattitude.errors import MavAttitudeError
from mavattitude.estimation import METHODS
from mavattitude.estimation.solve import DEFAULT_METHOD
from mavattitude.sim.vehicle import FakeVehicle

log = logging.getLogger(__name__)

# The service's counters line: "counters: received=123 rejected.nan=0 ... latency_p99_ms=1.2".
_COUNTERS_MARK = "counters"
START_TIMEOUT_S = 20.0  # a cold daemon start to its first attitude on a loaded 2-core CI machine (≈ 1 s idle)
_PAIR = re.compile(r"([A-Za-z_][\w.\-]*)=([-+0-9.eE]+|nan|inf)")


def parse_counters(line: str) -> dict[str, float] | None:
    """The ``key=value`` numbers of a counters log line, or None for any other line."""
    if _COUNTERS_MARK not in line:
        return None
    pairs = {k: float(v) for k, v in _PAIR.findall(line.split(_COUNTERS_MARK, 1)[1])}
    return pairs or None


class ServiceProcess:
    """``with ServiceProcess(config) as svc:`` — the daemon running on ``config`` (a YAML-able mapping)."""

    def __init__(self, config: Mapping[str, Any], workdir: Path | None = None, log_level: str = "INFO") -> None:
        self._tmp = None if workdir is not None else tempfile.TemporaryDirectory(prefix="mavattitude-")
        self.workdir = Path(workdir if workdir is not None else self._tmp.name)  # type: ignore[union-attr]
        self.config_path = self.workdir / "service.yaml"
        self.config_path.write_text(yaml.safe_dump(dict(config), sort_keys=False))
        self.log_level = log_level
        self.lines: list[str] = []
        self.counters: list[dict[str, float]] = []
        self._cond = threading.Condition()
        self.proc: subprocess.Popen[str] | None = None
        self._reader: threading.Thread | None = None
        self.returncode: int | None = None

    @property
    def pid(self) -> int:
        if self.proc is None:
            raise MavAttitudeError("the service is not running")
        return self.proc.pid

    def start(self) -> ServiceProcess:
        env = {**os.environ, "PYTHONUNBUFFERED": "1"}
        env.pop("MAVATTITUDE_CONFIG", None)  # the test's config only, not the developer's overlay
        cmd = [sys.executable, "-m", "mavattitude", "--log-level", self.log_level, "run", "--config"]
        self.proc = subprocess.Popen(
            [*cmd, str(self.config_path)],
            stdin=subprocess.DEVNULL,
            stdout=subprocess.PIPE,
            stderr=subprocess.STDOUT,
            text=True,
            env=env,
            # Its own process group: a terminal's Ctrl-C reaches the caller (the demo, a test), which
            # then stops the service with one SIGTERM, instead of the service seeing two signals.
            start_new_session=True,
        )
        self._reader = threading.Thread(target=self._read, name="service-log", daemon=True)
        self._reader.start()
        return self

    def _read(self) -> None:
        assert self.proc is not None and self.proc.stdout is not None
        for raw in self.proc.stdout:
            line = raw.rstrip("\n")
            counters = parse_counters(line)
            with self._cond:
                self.lines.append(line)
                if counters is not None:  # a periodic line holds what changed: merged onto the last
                    self.counters.append({**(self.counters[-1] if self.counters else {}), **counters})
                self._cond.notify_all()
        with self._cond:
            self._cond.notify_all()

    def wait_for_line(self, pattern: str, timeout_s: float, start: int = 0) -> str | None:
        """The first log line from index ``start`` on matching ``pattern`` (regex), waiting up to ``timeout_s``."""
        regex = re.compile(pattern)

        def found() -> str | None:
            return next((ln for ln in self.lines[start:] if regex.search(ln)), None)

        with self._cond:
            self._cond.wait_for(lambda: found() is not None or not self.running, timeout=timeout_s)
            return found()

    def wait_until(self, predicate: Callable[[], bool], timeout_s: float) -> bool:
        with self._cond:
            return self._cond.wait_for(predicate, timeout=timeout_s)

    @property
    def running(self) -> bool:
        return self.proc is not None and self.proc.poll() is None

    def stop(self, timeout_s: float = 5.0) -> int:
        """SIGTERM, wait for the exit (the service promises one within 1 s) and its last log lines."""
        if self.proc is None:
            raise MavAttitudeError("the service was never started")
        if self.proc.poll() is None:
            self.proc.send_signal(signal.SIGTERM)
        try:
            self.returncode = self.proc.wait(timeout=timeout_s)
        except subprocess.TimeoutExpired:
            self.proc.kill()
            self.returncode = self.proc.wait(timeout=timeout_s)
            raise MavAttitudeError(f"the service did not exit within {timeout_s} s of SIGTERM") from None
        finally:
            if self._reader is not None:
                self._reader.join(timeout=timeout_s)
        return self.returncode

    def latest_counters(self) -> dict[str, float]:
        """The last counters line logged so far (empty before the first)."""
        with self._cond:
            return dict(self.counters[-1]) if self.counters else {}

    def final_counters(self) -> dict[str, float]:
        with self._cond:
            if not self.counters:
                raise MavAttitudeError("the service logged no counters line:\n" + "\n".join(self.lines[-20:]))
            return self.counters[-1]

    def rss_kib(self) -> int:
        """Resident memory of the running service (``VmRSS``, KiB)."""
        status = Path(f"/proc/{self.pid}/status").read_text()
        match = re.search(r"^VmRSS:\s+(\d+)\s+kB", status, re.MULTILINE)
        if match is None:
            raise MavAttitudeError("no VmRSS in /proc status")
        return int(match.group(1))

    def __enter__(self) -> ServiceProcess:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        if self.running:
            try:
                self.stop()
            except MavAttitudeError as err:
                log.warning("%s", err)
        if self._tmp is not None:
            self._tmp.cleanup()

    def log_tail(self, n: int = 30) -> str:
        with self._cond:
            return "\n".join(self.lines[-n:])


def service_config(vehicle_port: int, **sections: Mapping[str, Any]) -> dict[str, Any]:
    """A service config reaching a ``udpin`` fake vehicle on ``vehicle_port``; ``sections`` override."""
    base: dict[str, Any] = {
        "link": {"connect": f"udpout:127.0.0.1:{vehicle_port}", "vehicle_system_id": 0},
        "output": {"stats_interval_s": 1.0},
    }
    return merge(base, sections)


def config_for(vehicle: FakeVehicle, **sections: Mapping[str, Any]) -> dict[str, Any]:
    """A service config that matches ``vehicle``: its port, message, profile, rate, field and noise.

    The noise σ given to the service are the sensor model's (floored at the encoding's quantisation σ,
    LSB/√12, so an ideal sensor still gets a positive σ); not with ``estimator.method: fused``, whose σ are
    its own effective values (``estimator.fused``) and which refuses a ``noise`` section.
    """
    cfg = vehicle.config
    sensors = vehicle.sensors
    matched: dict[str, Any] = {
        "link": {"request_rate_hz": sensors.rate_hz},
        "input": {"message": cfg.message, "profile": cfg.profile},
        "reference": {"magnetic": {"field_ned_uT": [float(v) for v in vehicle.script.mag_ned_uT]}},
    }
    if METHODS[sections.get("estimator", {}).get("method", DEFAULT_METHOD)].sensor_noise:
        matched["noise"] = {
            "accel_std_mps2": [max(float(s), 0.003) for s in sensors.accel.noise_std],
            "mag_std_uT": [max(float(s), 0.03) for s in sensors.mag.noise_std],
        }
    return service_config(vehicle.port, **merge(matched, sections))
