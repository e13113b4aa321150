"""The clock estimator against a simulated network with known truth."""
from __future__ import annotations

import numpy as np
import pytest

from node.clock import ClockEstimator, ClockSample, LocalClock


def simulate(offset_ns: float, drift: float, *, seconds: float, hz: float, seed: int, base_delay=150_000,
             jitter=2_000_000, asym=0.3):
    """Exchanges between a local clock (local = host*(1+drift) + offset) and the rig (= host) clock.

    One-way delays are a base plus exponential queueing; a fraction of exchanges are
    badly asymmetric (one direction queued). Returns samples and a truth function.
    """
    rng = np.random.default_rng(seed)
    local = lambda host: host * (1 + drift) + offset_ns  # noqa: E731
    samples = []
    t = 1e9
    for _ in range(int(seconds * hz)):
        t += 1e9 / hz
        d1 = base_delay + rng.exponential(jitter * (asym if rng.random() < 0.5 else 1))
        d2 = base_delay + rng.exponential(jitter)
        proc = 30_000
        t0h, t1h = t, t + d1
        t2h, t3h = t1h + proc, t1h + proc + d2
        samples.append(ClockSample(int(local(t0h)), int(t1h), int(t2h), int(local(t3h))))
    truth = lambda local_ns: (local_ns - offset_ns) / (1 + drift)  # noqa: E731 - rig time at a local time
    return samples, truth


@pytest.mark.parametrize("offset_ms,drift_ppm", [(0, 0), (500, 200), (-500, -200), (123.4, 57)])
def test_estimate_converges_to_truth(offset_ms, drift_ppm):
    samples, truth = simulate(offset_ms * 1e6, drift_ppm * 1e-6, seconds=20, hz=4, seed=3)
    est = ClockEstimator()
    for s in samples:
        e = est.add(s)
    probe = samples[-1].t3 + 1_000_000_000  # extrapolate one second ahead
    err_ms = abs(e.rig_time(probe) - truth(probe)) / 1e6
    # queueing of mean 2 ms each way: the fastest exchanges still carry ~0.1-0.3 ms of asymmetry
    assert err_ms < 0.5, err_ms
    assert abs(e.drift * 1e6 - (-drift_ppm / (1 + drift_ppm * 1e-6))) < 25  # ppm, over a 20 s window


def test_quiet_network_gives_tens_of_microseconds():
    samples, truth = simulate(-3e8, 1.5e-4, seconds=20, hz=4, seed=7, jitter=100_000)
    est = ClockEstimator()
    for s in samples:
        e = est.add(s)
    probe = samples[-1].t3 + 500_000_000
    assert abs(e.rig_time(probe) - truth(probe)) / 1e6 < 0.05


def test_min_rtt_filter_beats_plain_average():
    samples, truth = simulate(0, 0, seconds=10, hz=8, seed=5, jitter=5_000_000)
    est = ClockEstimator()
    for s in samples:
        e = est.add(s)
    probe = samples[-1].t3
    filtered = abs(e.rig_time(probe) - truth(probe))
    naive = abs(np.mean([s.offset for s in samples]))
    assert filtered < naive / 3


def test_local_time_inverts_rig_time():
    samples, _ = simulate(5e8, 2e-4, seconds=5, hz=4, seed=1)
    est = ClockEstimator()
    for s in samples:
        e = est.add(s)
    for rig in (0, 10**12, 3 * 10**12 + 7):
        assert abs(e.rig_time(e.local_time(rig)) - rig) <= 2


def test_impossible_exchange_is_ignored():
    est = ClockEstimator()
    est.add(ClockSample(0, 10, 20, 1000))
    before = est.estimate
    est.add(ClockSample(2000, 10, 5000, 2100))  # negative round trip
    assert est.estimate == before


def test_local_clock_hooks_round_trip():
    host = [10**12]
    clk = LocalClock(offset_ns=500_000_000, drift_ppm=200, source=lambda: host[0])
    host[0] += 10**10
    local = clk.now()
    assert local == host[0] + 500_000_000 + round(10**10 * 200e-6)
    assert abs(clk.to_host(local) - host[0]) <= 1


def test_sleep_until_lands_on_the_deadline():
    clk = LocalClock(offset_ns=-123_000_000, drift_ppm=-150)
    deadline = clk.now() + 20_000_000
    woke_host = clk.sleep_until(deadline)
    assert clk.from_host(woke_host) >= deadline
