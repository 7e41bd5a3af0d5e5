"""The forecast of when the sample completing the next output tick can arrive (:class:`TickArrivals`), and the
link's sleep until then (:meth:`MavlinkLink.recv_items` with ``quiet_until``) over real UDP on 127.0.0.1."""

from __future__ import annotations

import math
import sys
import time

import numpy as np
import pytest
from pymavlink.dialects.v20 import ardupilotmega as mavlink2

from mavattitude.link import MavlinkLink
from mavattitude.link.arrivals import MARGIN_S, TickArrivals
from mavattitude.link.connection import CLOCK_READ_S, MAX_MESSAGES_PER_RECV
from mavattitude.link.memory import MemoryLink
from mavattitude.link.source import MavlinkDecoder
from mavattitude.sensors import units
from tests.link.peer import UdpPeer

SEED = 4242
RATE_HZ, OUTPUT_HZ = 200.0, 50.0
FLOOR_S = 0.003  # the link's delay floor in the simulated streams
WAIT_S = 3.0  # bound on waiting for the kernel's stamps to come on (deferred work: normally milliseconds)


def _stream(rng: np.random.Generator, n: int, jitter_s: float) -> tuple[np.ndarray, np.ndarray]:
    """Vehicle times (200 Hz, stamps jittered by ±0.5 ms) and arrival times (floor + exponential jitter)."""
    t = 10.0 + np.arange(n) / RATE_HZ + rng.uniform(-5e-4, 5e-4, n)
    return t, 500.0 + t + FLOOR_S + rng.exponential(jitter_s, n)


def _ticks(t: np.ndarray, start_s: float) -> np.ndarray:
    """Each sample's output tick (NaN for none): the ticks start_s + k / OUTPUT_HZ, each emitted by the first sample
    at or after it (the front end's grid with start_s 0, the fused filter's from its first sample)."""
    k = np.floor((t - start_s) * OUTPUT_HZ)
    first = np.concatenate([[True], k[1:] > k[:-1]])
    return np.where(first, start_s + k / OUTPUT_HZ, np.nan)


@pytest.mark.parametrize("start_s", [0.0, 10.0123])
def test_forecast_never_after_the_tick_sample_and_sleeps_through_most_others(start_s):
    rng = np.random.default_rng(SEED)
    t, t_rx = _stream(rng, 4000, jitter_s=0.0005)
    ticks = _ticks(t, start_s)
    emits = np.flatnonzero(np.isfinite(ticks))
    arrivals = TickArrivals()
    late, quiet = 0, 0
    for i in range(emits[-1]):
        arrivals.add(t[i], t_rx[i])
        if np.isfinite(ticks[i]):
            arrivals.output(float(ticks[i]))
        earliest = arrivals.earliest()
        late += earliest > t_rx[emits[emits > i][0]]  # the sample emitting the next tick
        quiet += earliest > t_rx[i + 1]  # the very next sample arrives while the loop sleeps
    assert late == 0
    assert quiet > 0.5 * emits[-1]  # two samples of four or more arrive in the sleep before the tick's


def test_a_tick_sample_that_came_early_lowers_the_floor():
    arrivals = TickArrivals()
    delay_s = 100.0 + FLOOR_S  # the two clocks' offset and the floor
    for i in range(40):
        arrivals.add(1.0 + i / RATE_HZ, 1.0 + i / RATE_HZ + delay_s)
        if i % 4 == 0:
            arrivals.output(1.0 + i / RATE_HZ)
    t_tick = 1.0 + 40 / RATE_HZ
    forecast = arrivals.earliest()
    assert forecast == pytest.approx(t_tick + delay_s - MARGIN_S, abs=1e-9)  # float rounding of the sums
    # the path got 2 ms faster: the tick's sample waited through a sleep that began 2 ms before its forecast
    arrivals.add(t_tick, t_tick + delay_s - 0.002, backlog=True)
    arrivals.output(t_tick)
    next_tick = t_tick + 4 / RATE_HZ
    assert arrivals.earliest() == pytest.approx(next_tick + delay_s - 0.002 - MARGIN_S, abs=1e-9)
    arrivals.add(t_tick + 1 / RATE_HZ, t_tick + 1.0, backlog=True)  # before the next tick: says nothing of the floor
    assert arrivals.earliest() == pytest.approx(next_tick + delay_s - 0.002 - MARGIN_S, abs=1e-9)
    arrivals.forget()
    assert arrivals.earliest() == -math.inf


def test_a_tick_out_of_step_with_the_samples_is_not_trusted():
    """A vehicle clock that went back (a reboot) or wrapped leaves the last output far from the new samples: the
    forecast falls back to the next sample's earliest arrival, never to the stale tick."""
    arrivals = TickArrivals()
    for i in range(40):
        arrivals.add(500.0 + i / RATE_HZ, 600.0 + i / RATE_HZ)
        if i % 4 == 0:
            arrivals.output(500.0 + i / RATE_HZ)
    arrivals.add(0.5, 600.2)  # rebooted: 0.5 s on its clock
    assert arrivals.earliest() == pytest.approx(0.5 + 1 / RATE_HZ + 100.0 - MARGIN_S, abs=1e-9)


def _raw_imu(peer: UdpPeer, time_s: float) -> bytes:
    sample = units.ImuSample(time_s, (0.0, 0.0, -9.8), (0.0, 0.0, 0.0), (20.0, 0.0, 40.0))
    return peer.pack(mavlink2.MAVLink_raw_imu_message(**units.encode(sample, units.PROFILES["ardupilot"], "RAW_IMU")))


DECODER = MavlinkDecoder("RAW_IMU", units.PROFILES["ardupilot"])


def _until_stamped_on_arrival(link: MavlinkLink, peer: UdpPeer) -> None:
    """Until the kernel stamps a datagram when it arrives, not when it is read. Linux turns its receive stamps on
    for the whole system in deferred work when the first socket asks for them (``net_enable_timestamp``); what
    arrives before that work has run is stamped at its read, later than it came. Under a loaded suite that took
    milliseconds: the first datagrams of a burst sent at once came out stamped 47 ms late, after those behind them."""
    deadline = time.monotonic() + WAIT_S
    while time.monotonic() < deadline:
        peer.send_raw(_raw_imu(peer, 0.5))
        sent = time.monotonic()
        got = link.recv_items(1.0, DECODER, DECODER.direct, quiet_until=sent + 0.01)  # read 10 ms after it came
        if got and got[0][0] < sent + 0.005:
            return
    pytest.fail(f"the kernel stamped no datagram at its arrival within {WAIT_S} s")


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="the kernel's arrival stamps are Linux's")
def test_what_waited_through_a_sleep_is_stamped_with_its_arrival():
    """Over UDP the kernel stamps each datagram: one read after a 50 ms sleep keeps its own arrival, so its latency
    is neither hidden nor counted from the sleep's start."""
    link = MavlinkLink("udpin:127.0.0.1:0", source_system=1)
    peer = UdpPeer()
    peer.target = link.local_address
    try:
        assert link.stamps_arrivals
        _until_stamped_on_arrival(link, peer)
        count = MAX_MESSAGES_PER_RECV + 10
        started = time.monotonic()
        for i in range(count):
            peer.send_raw(_raw_imu(peer, 1.0 + i / RATE_HZ))
        sent = time.monotonic()
        first = link.recv_items(1.0, DECODER, DECODER.direct, quiet_until=started + 0.05)
        assert time.monotonic() >= started + 0.05
        rest = link.recv_items(1.0, DECODER, DECODER.direct)  # the backlog's rest
        assert len(first) == MAX_MESSAGES_PER_RECV and len(rest) == count - len(first) and not link.backlog
        stamps = np.array([t_rx for t_rx, _, _ in first + rest])
        # in order and each between its send and the last one's, within the CLOCK_READ_S the wall and monotonic
        # clocks may be read apart (1 ms of margin at the ends): well before the sleep ended, 50 ms after the sends
        assert np.all(np.diff(stamps) >= -CLOCK_READ_S)
        assert started - 1e-3 <= stamps[0] and stamps[-1] <= sent + 1e-3
    finally:
        link.close()
        peer.close()


def test_without_arrival_stamps_what_waited_through_a_sleep_is_stamped_with_its_start():
    """A link whose OS does not stamp arrivals (here in memory; serial, TCP) stamps what waited through a sleep
    with the sleep's start, the earliest it can have come: latency counted from there is never understated."""
    link = MemoryLink()
    peer = UdpPeer()  # packs only
    try:
        assert not link.stamps_arrivals
        count = MAX_MESSAGES_PER_RECV + 10
        link.deliver(*(_raw_imu(peer, 1.0 + i / RATE_HZ) for i in range(count)))
        started = time.monotonic()
        first = link.recv_items(1.0, DECODER, DECODER.direct, quiet_until=started + 0.05)
        assert time.monotonic() >= started + 0.05 and link.backlog
        rest = link.recv_items(1.0, DECODER, DECODER.direct)  # the backlog's rest: stamped as it
        assert link.backlog and len(first) == MAX_MESSAGES_PER_RECV and len(rest) == count - len(first)
        stamps = {t_rx for t_rx, _, _ in first + rest}
        assert len(stamps) == 1 and started <= stamps.pop() <= started + 0.01
        link.deliver(_raw_imu(peer, 2.0))
        before = time.monotonic()
        (t_rx, _, sample), *_ = link.recv_items(1.0, DECODER, DECODER.direct, quiet_until=before - 1.0)
        assert not link.backlog and t_rx >= before and sample.time_s == 2.0
    finally:
        link.close()
        peer.close()
