"""The soak: the service as a real subprocess fed by the fake vehicle for a long (accelerated) run.

``run_soak(duration_s=3600, rate_hz=200, speed=20)`` flies ``duration_s`` of vehicle time (a level
yaw spin, one turn per window, with consumer-grade sensor errors) at ``speed`` × real time, with the IMU
at ``rate_hz`` on the vehicle's clock. Every ``window_s`` of vehicle time it records the service's
resident memory, the error statistics and the output rate of that window. The report says whether
memory grew (beyond the first window, which includes start-up allocations), whether the error
statistics drifted, and whether the output rate held: the targets are checked by the
caller (``tools/bench.py soak``, and a short version in the tests).
"""

from __future__ import annotations

import time
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from mavattitude.config import merge
from mavattitude.errors import MavAttitudeError
from mavattitude.sim import scenarios
from mavattitude.sim.daemon import START_TIMEOUT_S, ServiceProcess, service_config
from mavattitude.sim.scoring import Score
from mavattitude.sim.sensors import DEFAULT_RATE_HZ
from mavattitude.sim.trajectory import Rotate, Script
from mavattitude.sim.vehicle import FakeVehicle, VehicleConfig

DRAIN_TIMEOUT_S = 2.0  # ample for a receive thread to read a socket buffer's worth of datagrams


@dataclass(frozen=True)
class SoakWindow:
    end_s: float  # vehicle time at the end of the window
    rss_kib: int
    score: Score


@dataclass
class SoakReport:
    duration_s: float
    rate_hz: float
    speed: float
    wall_s: float
    windows: list[SoakWindow] = field(default_factory=list)
    imu_sent: int = 0
    outputs: int = 0
    exit_code: int | None = None
    final_counters: dict[str, float] = field(default_factory=dict)

    @property
    def rss_growth_mb(self) -> float:
        """Resident memory growth (MB) from the end of the first window to the end of the run."""
        if len(self.windows) < 2:
            return float("nan")
        return (self.windows[-1].rss_kib - self.windows[0].rss_kib) / 1024.0

    @property
    def error_drift_deg(self) -> float:
        """Largest minus smallest per-window RMS angle error (degrees)."""
        rms = [w.score.angle_rms_deg for w in self.windows]
        return float(np.max(rms) - np.min(rms)) if rms else float("nan")

    @property
    def output_rates_hz(self) -> tuple[float, float]:
        rates = [w.score.output_rate_hz for w in self.windows]
        return (float(np.min(rates)), float(np.max(rates))) if rates else (float("nan"), float("nan"))

    @property
    def broken(self) -> int:
        return sum(w.score.broken for w in self.windows)

    def summary(self) -> str:
        lo, hi = self.output_rates_hz
        return (
            f"soak: {self.duration_s:.0f} s at {self.rate_hz:g} Hz ×{self.speed:g} in {self.wall_s:.1f} s wall, "
            f"{self.imu_sent} IMU sent, {self.outputs} outputs ({self.broken} broken), "
            f"RSS growth {self.rss_growth_mb:.2f} MB, error drift {self.error_drift_deg:.3f}°, "
            f"output rate {lo:.2f}–{hi:.2f} Hz, exit {self.exit_code}"
        )


def run_soak(
    duration_s: float = 3600.0,
    rate_hz: float = DEFAULT_RATE_HZ,
    speed: float = 20.0,
    window_s: float = 300.0,
    seed: int = 0,
    service_overrides: Mapping[str, Any] | None = None,
    progress: Callable[[SoakWindow], None] | None = None,
) -> SoakReport:
    """Run the soak; raises :class:`MavAttitudeError` if the service never starts answering."""
    if not (duration_s > 0 and rate_hz > 0 and speed > 0 and 0 < window_s <= duration_s):
        raise MavAttitudeError("soak: duration, rate, speed must be positive and 0 < window ≤ duration")
    # A level yaw spin, one turn per window: every window sees the same attitudes, so with steady errors
    # (consumer sensors: noise plus small residual biases) the per-window statistics must not move.
    spin = Rotate(duration_s + 2 * window_s, (0.0, 0.0, 2 * np.pi / window_s))
    script = Script([spin], scenarios.DEFAULT_MAG_NED_UT)
    vehicle_cfg = VehicleConfig("udpin:127.0.0.1:0", speed=speed, seed=seed, fly_when_asked=True)
    report = SoakReport(duration_s, rate_hz, speed, 0.0)
    with FakeVehicle(script, scenarios.consumer_sensors(rate_hz), vehicle_cfg) as vehicle:
        overrides = merge(
            {
                "link": {"request_rate_hz": rate_hz},
                "reference": {"magnetic": {"field_ned_uT": list(scenarios.DEFAULT_MAG_NED_UT)}},
                # The real-time input timeout still applies; accelerated input only makes gaps shorter.
                "output": {"stats_interval_s": max(1.0, window_s / speed)},
            },
            service_overrides or {},
        )
        with ServiceProcess(service_config(vehicle.port, **overrides)) as service:
            wall0 = time.monotonic()
            if not vehicle.wait_for_outputs(1, START_TIMEOUT_S):
                raise MavAttitudeError("soak: the service sent no attitude:\n" + service.log_tail())
            first_index = 0
            end_s = 0.0  # windows on the script clock, which starts with the IMU stream
            while end_s < duration_s and service.running:
                end_s = min(duration_s, end_s + window_s)
                _sleep_until(vehicle, end_s)
                index = len(vehicle.attitude_log)
                window = SoakWindow(end_s, service.rss_kib(), vehicle.score(first_index))
                first_index = index
                report.windows.append(window)
                if progress is not None:
                    progress(window)
            report.exit_code = service.stop()
            report.final_counters = service.final_counters() if service.counters else {}
            # The service's last datagrams may still wait in the vehicle's socket when it exits: let the vehicle
            # read what was sent before counting (what never arrives still shows as a shortfall).
            vehicle.wait_for_outputs(int(report.final_counters.get("emitted", 0)), DRAIN_TIMEOUT_S)
            report.wall_s = time.monotonic() - wall0
        report.imu_sent = vehicle.imu_sent
        report.outputs = len(vehicle.attitude_log)
    return report


def _sleep_until(vehicle: FakeVehicle, script_s: float) -> None:
    """Pace the soak on the vehicle's clock (this is pacing, not synchronisation)."""
    while (remaining := (script_s - vehicle.script_time()) / vehicle.config.speed) > 0:
        time.sleep(min(remaining, 0.5))
