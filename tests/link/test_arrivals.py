"""The forecast of when the sample completing the next output tick can arrive (:class:`TickArrivals`), and the
link's sleep until then (:meth:`MavlinkLink.recv_items` with ``quiet_until``) over real UDP on 127.0.0.1."""

from __future__ import annotations

import math
import time

import numpy as np
import pytest
from pymavlink.dialects.v20 import ardupilotmega as mavlink2

from mavattitude.link import MavlinkLink
from mavattitude.link.arrivals import MARGIN_S, TickArrivals
from mavattitude.link.connection import MAX_MESSAGES_PER_RECV
from mavattitude.link.source import MavlinkDecoder
from mavattitude.sensors import units
from tests.link.peer import UdpPeer

SEED = 4242
RATE_HZ, OUTPUT_HZ = 200.0, 50.0
FLOOR_S = 0.003  # the link's delay floor in the simulated streams


def _stream(rng: np.random.Generator, n: int, jitter_s: float) -> tuple[np.ndarray, np.ndarray]:
    """Vehicle times (200 Hz, stamps jittered by ±0.5 ms) and arrival times (floor + exponential jitter)."""
    t = 10.0 + np.arange(n) / RATE_HZ + rng.uniform(-5e-4, 5e-4, n)
    return t, 500.0 + t + FLOOR_S + rng.exponential(jitter_s, n)


def _tick_samples(t: np.ndarray) -> np.ndarray:
    """Which samples complete a tick: the first at or after each k / OUTPUT_HZ."""
    k = np.floor(t * OUTPUT_HZ)
    return np.concatenate([[False], k[1:] > k[:-1]]) | np.concatenate([[False], np.isclose(t[1:] * OUTPUT_HZ, k[1:])])


def test_forecast_never_after_the_tick_sample_and_sleeps_through_most_others():
    rng = np.random.default_rng(SEED)
    t, t_rx = _stream(rng, 4000, jitter_s=0.0005)
    arrivals = TickArrivals(OUTPUT_HZ)
    ticks = _tick_samples(t)
    late, quiet = 0, 0
    last_tick = int(np.flatnonzero(ticks)[-1])
    for i in range(last_tick):
        arrivals.add(t[i], t_rx[i])
        earliest = arrivals.earliest()
        nxt = i + 1 + int(np.argmax(ticks[i + 1 :]))  # the next tick's sample
        late += earliest > t_rx[nxt]
        quiet += earliest > t_rx[i + 1]  # the very next sample arrives while the loop sleeps
    assert late == 0
    assert quiet > 0.5 * last_tick  # three samples of four arrive in the sleep before the tick's


def test_a_tick_sample_that_came_early_lowers_the_floor():
    arrivals = TickArrivals(OUTPUT_HZ)
    delay_s = 100.0 + FLOOR_S  # the two clocks' offset and the floor
    for i in range(40):
        arrivals.add(1.0 + i / RATE_HZ, 1.0 + i / RATE_HZ + delay_s)
    t_tick = 1.0 + 40 / RATE_HZ
    forecast = arrivals.earliest()
    assert forecast == pytest.approx(t_tick + delay_s - MARGIN_S, abs=1e-9)  # float rounding of the sums
    # the path got 2 ms faster: the tick's sample waited through a sleep that began 2 ms before its forecast
    arrivals.add(t_tick, t_tick + delay_s - 0.002, backlog=True)
    next_tick = t_tick + 4 / RATE_HZ
    assert arrivals.earliest() == pytest.approx(next_tick + delay_s - 0.002 - MARGIN_S, abs=1e-9)
    arrivals.add(t_tick + 1 / RATE_HZ, t_tick + 1.0, backlog=True)  # before the next tick: says nothing of the floor
    assert arrivals.earliest() == pytest.approx(next_tick + delay_s - 0.002 - MARGIN_S, abs=1e-9)
    arrivals.forget()
    assert arrivals.earliest() == -math.inf


def _raw_imu(peer: UdpPeer, time_s: float) -> bytes:
    sample = units.ImuSample(time_s, (0.0, 0.0, -9.8), (0.0, 0.0, 0.0), (20.0, 0.0, 40.0))
    return peer.pack(mavlink2.MAVLink_raw_imu_message(**units.encode(sample, units.PROFILES["ardupilot"], "RAW_IMU")))


def test_what_waited_through_a_sleep_is_stamped_with_its_start():
    decoder = MavlinkDecoder("RAW_IMU", units.PROFILES["ardupilot"])
    link = MavlinkLink("udpin:127.0.0.1:0", source_system=1)
    peer = UdpPeer()
    peer.target = link.local_address
    try:
        count = MAX_MESSAGES_PER_RECV + 10
        for i in range(count):
            peer.send_raw(_raw_imu(peer, 1.0 + i / RATE_HZ))
        started = time.monotonic()
        first = link.recv_items(1.0, decoder, decoder.direct, quiet_until=started + 0.05)
        assert time.monotonic() >= started + 0.05 and link.backlog
        rest = link.recv_items(1.0, decoder, decoder.direct)  # the backlog's rest: stamped as it
        assert link.backlog and len(first) == MAX_MESSAGES_PER_RECV and len(rest) == count - len(first)
        stamps = {t_rx for t_rx, _, _ in first + rest}
        assert len(stamps) == 1 and started <= stamps.pop() <= started + 0.01
        peer.send_raw(_raw_imu(peer, 2.0))
        before = time.monotonic()
        (t_rx, _, sample), *_ = link.recv_items(1.0, decoder, decoder.direct, quiet_until=before - 1.0)
        assert not link.backlog and t_rx >= before and sample.time_s == 2.0
    finally:
        link.close()
        peer.close()
