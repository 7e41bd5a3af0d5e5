"""The short soak: the service under the accelerated fake vehicle for a few simulated minutes.

The full one (one simulated hour at 200 Hz) runs from ``tools/bench.py soak`` with the same function.
"""

from __future__ import annotations

import pytest

from mavattitude.sim.soak import run_soak

pytestmark = pytest.mark.e2e


def test_short_soak_is_steady() -> None:
    # One simulated minute at 200 Hz, ×10 real time (2 000 messages/s into the service): 6 s of wall time.
    report = run_soak(duration_s=60.0, rate_hz=200.0, speed=10.0, window_s=15.0)
    assert report.exit_code == 0
    assert len(report.windows) == 4
    assert report.broken == 0
    lo, hi = report.output_rates_hz
    # 50 Hz ticks of the vehicle clock; a window may lose a tick or two to its edges.
    assert 49.5 < lo <= hi < 50.5, report.summary()
    # Consumer sensors, a yaw spin: the error RMS is ≈ 1° (residual biases) and must not drift.
    assert max(w.score.angle_rms_deg for w in report.windows) < 3.0, report.summary()
    assert report.error_drift_deg < 0.5, report.summary()
    # Memory: a minute cannot show a leak of 5 MB/hour, but anything growing per message would show.
    assert report.rss_growth_mb < 5.0, report.summary()
    # Counters agree with the wire: every output the service counted reached the vehicle.
    assert report.final_counters["emitted"] == report.outputs
