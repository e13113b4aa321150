"""node/clock.py's fit in plain Python (the node process imports no numpy) gives what the numpy fit it
replaced gave, on clock exchanges recorded against a real coordinator and on a simulated network.

The numpy fit is kept here, as it was in node/clock.py, as the reference. Every prefix of each
recording is fitted, as a node does after each exchange, with each window and bucket setting the
node and the tests use: the exchanges kept, the fitted flag and the best round trip must be the
same, and the offset and drift equal to within float rounding (the sums are exact in the new fit,
pairwise in numpy's).
"""
from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest

from node.clock import CLOCK_WINDOW_NS, ClockEstimate, ClockEstimator, ClockSample

RECORDED = json.loads((Path(__file__).parent / "data" / "clock_exchanges.json").read_text())["exchanges"]


def numpy_fit(est: ClockEstimator, samples: list[ClockSample]) -> ClockEstimate | None:
    """node/clock.py's ClockEstimator._fit up to 193e523, on numpy."""
    if not samples:
        return None
    rtts = np.array([s.rtt for s in samples], dtype=np.float64)
    mids = np.array([s.midpoint for s in samples], dtype=np.float64)
    offs = np.array([s.offset for s in samples], dtype=np.float64)
    best = float(rtts.min())
    buckets = np.floor((mids - mids.min()) / est.bucket_ns).astype(np.int64)
    order = np.lexsort((rtts, buckets))
    first = np.ones(len(order), dtype=bool)
    first[1:] = buckets[order][1:] != buckets[order][:-1]
    pick = order[first]
    keep = pick[rtts[pick] <= best * (1.0 + est.rtt_slack) + est.rtt_margin_ns]
    m, o, r = mids[keep], offs[keep], rtts[keep]
    w = 1.0 / (r - best + max(best, 100_000.0))
    ref = float(mids[-1])
    span = float(m.max() - m.min()) if len(m) else 0.0
    fitted = len(m) >= 4 and span >= est.min_drift_span_ns
    if fitted:
        x = m - ref
        sw = w.sum()
        xm = (w * x).sum() / sw
        ym = (w * o).sum() / sw
        var = (w * (x - xm) ** 2).sum()
        drift = float((w * (x - xm) * (o - ym)).sum() / var) if var > 0 else 0.0
        offset = ym - drift * xm
    else:
        i = int(np.argmin(rtts))
        drift, offset, ref = 0.0, float(offs[i]), float(mids[i])
    return ClockEstimate(offset_ns=offset, drift=drift, ref_local_ns=ref, best_rtt_ns=int(best), samples=int(len(keep)),
                         span_ns=span, drift_fitted=fitted)


def assert_same_fit(mine: ClockEstimate, ref: ClockEstimate) -> None:
    assert (mine.samples, mine.best_rtt_ns, mine.drift_fitted) == (ref.samples, ref.best_rtt_ns, ref.drift_fitted)
    assert (mine.ref_local_ns, mine.span_ns) == (ref.ref_local_ns, ref.span_ns)
    assert math.isclose(mine.drift, ref.drift, rel_tol=1e-9, abs_tol=1e-15)
    assert abs(mine.offset_ns - ref.offset_ns) < 1e-3          # ns: float rounding of the sums alone
    probe = int(ref.ref_local_ns) + 5_000_000_000              # and where a node uses it, 5 s on
    assert abs(mine.rig_time(probe) - ref.rig_time(probe)) <= 1


def fit_each_prefix(exchanges: list[ClockSample], **settings) -> int:
    """Feed ``exchanges`` one by one; after each, the fit must be the reference's on the same window."""
    est = ClockEstimator(**settings)
    fitted = 0
    for s in exchanges:
        mine = est.add(s)
        ref = numpy_fit(est, list(est._samples))
        assert_same_fit(mine, ref)
        fitted += mine.drift_fitted
    return fitted


@pytest.mark.parametrize("recording", sorted(RECORDED))
@pytest.mark.parametrize("settings", [dict(window_ns=CLOCK_WINDOW_NS),                   # the node's
                                      dict(),                                           # the default 30 s
                                      dict(window_ns=8_000_000_000, bucket_ns=250_000_000, max_samples=64)])
def test_the_plain_fit_matches_numpys_on_recorded_exchanges(recording, settings):
    exchanges = [ClockSample(*map(int, e)) for e in RECORDED[recording]]
    assert len(exchanges) >= 200
    assert fit_each_prefix(exchanges, **settings) > 100                # the drift fit itself is compared


def test_the_plain_fit_matches_numpys_under_queueing_spikes_and_equal_round_trips():
    rng = np.random.default_rng(5)
    exchanges = []
    t = 10_000_000_000
    for i in range(300):
        # round trips on a coarse grid: ties inside a bucket, where the earliest exchange must win
        d1 = int(rng.choice([100_000, 200_000, 200_000, 5_000_000]))
        d2 = int(rng.choice([100_000, 200_000, 40_000_000]))
        rig = int(t * (1 + 25e-6)) + 7_000_000_000
        exchanges.append(ClockSample(t, rig + d1, rig + d1 + 20_000, t + d1 + 20_000 + d2))
        t += int(rng.integers(50_000_000, 400_000_000))
    assert fit_each_prefix(exchanges, window_ns=CLOCK_WINDOW_NS) > 200
