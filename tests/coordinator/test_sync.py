"""The swap bookkeeping, driven by hand with an injected clock: no node, no waiting."""
from __future__ import annotations

import math

import numpy as np

from coordinator.api import DropReason
from coordinator.sync import SyncTracker, summarize


class FakeClock:
    def __init__(self) -> None:
        self.t = 100.0

    def __call__(self) -> float:
        return self.t


def test_a_frame_is_final_once_every_expected_node_swapped_it():
    clock = FakeClock()
    tr = SyncTracker(clock=clock)
    seen = []
    tr.add_listener(seen.append)
    tr.expect(7, pts_ns=1_000, tag="play:x", slots={"a", "b", "c"})
    tr.on_swap("a", 7, rig_ns=1_000_000, host_ns=1_000_000, same_host=True)
    tr.on_swap("b", 7, rig_ns=1_400_000, host_ns=1_300_000, same_host=True)
    assert seen == []
    tr.on_swap("c", 7, rig_ns=1_100_000, host_ns=1_200_000, same_host=True)
    (r,) = seen
    assert r.shown_by_all and r.nodes == 3 and r.missing == ()
    assert r.source == "host-clock" and r.skew_ms == 0.3   # the host clock (the truth) when all share it
    assert sorted(r.clock_errors_ms) == [-0.1, 0.0, 0.1]


def test_skew_uses_the_estimates_when_a_node_is_on_another_host_and_ignores_strangers():
    tr = SyncTracker(clock=FakeClock())
    tr.expect(1, 0, "t", {"a", "b"})
    tr.on_swap("zz", 1, 5, 5, True)          # not expected: ignored
    tr.on_swap("a", 99, 5, 5, True)          # unknown frame: ignored
    tr.on_swap("a", 1, rig_ns=2_000_000, host_ns=0, same_host=False)
    tr.on_swap("b", 1, rig_ns=2_500_000, host_ns=0, same_host=True)
    (r,) = tr.results
    assert r.source == "estimates" and r.skew_ms == 0.5 and r.clock_errors_ms == (2.5,)


def test_drops_lost_nodes_and_timeouts_finish_a_frame_with_what_is_missing():
    clock = FakeClock()
    tr = SyncTracker(clock=clock, timeout_s=3.0)
    tr.expect(1, 0, "t", {"a", "b"})
    tr.on_swap("a", 1, 0, 0, True)
    tr.on_drop("b", 1, DropReason.LATE)
    tr.expect(2, 0, "t", {"a", "b"})
    tr.on_drop("a", 2, DropReason.SUPERSEDED)
    tr.forget_slot("b")                        # b was lost: frame 2 stops waiting for it
    tr.expect(3, 0, "t", {"a", "b"})
    tr.on_swap("b", 3, 0, 0, True)
    clock.t += 2.9
    tr.sweep()
    assert [r.frame_id for r in tr.results] == [1, 2], "not timed out yet"
    clock.t += 0.2
    tr.sweep()
    r1, r2, r3 = tr.results
    assert (r1.shown_by_all, r1.late, r1.dropped, r1.missing) == (False, 1, 0, ("b",))
    assert (r2.shown_by_all, r2.late, r2.dropped, r2.nodes) == (False, 0, 1, 0)
    assert (r3.shown_by_all, r3.missing) == (False, ("a",))
    assert math.isnan(r2.skew_ms) and math.isnan(r3.skew_ms), "no skew from fewer than two swaps"


def test_summary_percentiles_match_numpy_and_count_frames_shown_by_all():
    tr = SyncTracker(clock=FakeClock())
    rng = np.random.default_rng(3)
    skews = []
    for f in range(50):
        tr.expect(f, 0, "t", {"a", "b"})
        d = int(rng.integers(0, 2_000_000))
        skews.append(d / 1e6)
        tr.on_swap("a", f, 0, 0, True)
        if f % 10 == 9:
            tr.on_drop("b", f, DropReason.LATE)
        else:
            tr.on_swap("b", f, 0, d, True)
    s = summarize(list(tr.results), out_of_order=2)
    shown = [k for i, k in enumerate(skews) if i % 10 != 9]
    assert s.frames == 45 and s.frames_late == 5 and s.frames_dropped == 0 and s.out_of_order == 2
    assert math.isclose(s.skew_p50_ms, float(np.percentile(shown, 50)))
    assert math.isclose(s.skew_p99_ms, float(np.percentile(shown, 99)))
    assert s.skew_max_ms == max(shown) and s.skew_source == "host-clock"
    empty = summarize([])
    assert empty.frames == 0 and math.isnan(empty.skew_p50_ms) and empty.skew_source == ""
