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
    tr.flush()
    assert seen == []
    tr.on_swap("c", 7, rig_ns=1_100_000, host_ns=1_200_000, same_host=True)
    assert seen == [], "swaps wait for the next flush"
    tr.flush()
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
    assert r.source == "estimates" and r.skew_ms == 0.5 and r.clock_errors_ms.tolist() == [2.5]


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


class _Reference:
    """The bookkeeping frame by frame in plain dicts and sets: what the tracker's arrays must reproduce."""

    def __init__(self) -> None:
        self.open: dict[int, dict] = {}
        self.results: list[tuple] = []

    def expect(self, f, slots):
        self.open[f] = {"expected": set(slots), "waiting": set(slots), "swaps": {}, "drops": {}}

    def swap(self, slot, f, rig, host, same):
        rec = self.open.get(f)
        if rec is None or slot not in rec["expected"] or slot in rec["swaps"]:
            return
        rec["swaps"][slot] = (rig, host, same)
        self._answer(f, rec, slot)

    def drop(self, slot, f, reason):
        rec = self.open.get(f)
        if rec is not None and slot in rec["expected"]:
            rec["drops"][slot] = reason
            self._answer(f, rec, slot)

    def forget(self, slot):
        for f, rec in sorted(self.open.items()):
            if slot in rec["waiting"]:
                rec["expected"].discard(slot)
                self._answer(f, rec, slot)

    def _answer(self, f, rec, slot):
        rec["waiting"].discard(slot)
        if not rec["waiting"]:
            del self.open[f]
            sw = list(rec["swaps"].values())
            same = bool(sw) and all(s[2] for s in sw)
            inst = [s[1] if same else s[0] for s in sw]
            late = sum(1 for r in rec["drops"].values() if r == DropReason.LATE)
            self.results.append((f, rec["expected"] <= set(rec["swaps"]) and bool(rec["expected"]), len(sw),
                                 (max(inst) - min(inst)) / 1e6 if len(inst) >= 2 else None,
                                 sorted((s[0] - s[1]) / 1e6 for s in sw if s[2]), late, len(rec["drops"]) - late,
                                 tuple(sorted(rec["expected"] - set(rec["swaps"])))))


def test_batches_of_swaps_give_what_frame_by_frame_bookkeeping_gives():
    """Random shows (more slots and open frames than the arrays start with, batches with repeats,
    frames out of order, drops, lost nodes) filed as batches and one by one agree."""
    rng = np.random.default_rng(11)
    for trial in range(20):
        slots = [f"s{k}" for k in range(int(rng.integers(1, 30)))]
        tr, ref = SyncTracker(clock=FakeClock(), flush_swaps=int(rng.integers(1, 400))), _Reference()
        frames = list(range(int(rng.integers(1, 200))))
        for f in frames:
            exp = [s for s in slots if rng.random() < 0.9]
            tr.expect(f, 0, "t", exp)
            if exp:
                ref.expect(f, exp)
        lost = set()
        for slot in slots:
            same = bool(rng.random() < 0.8)
            order = rng.permutation(frames + list(rng.choice(frames, size=5)) + [999])    # repeats, an unknown frame
            for batch in np.array_split(order, int(rng.integers(1, 6))):
                ids = batch.astype(np.int64)
                rig = rng.integers(0, 5_000_000, size=ids.size).astype(np.int64)
                host = rig + rng.integers(-300_000, 300_000, size=ids.size)
                if rng.random() < 0.2:
                    tr.on_drop(slot, int(ids[0]), DropReason.LATE)
                    ref.drop(slot, int(ids[0]), DropReason.LATE)
                keep = rng.random(ids.size) < 0.9        # some frames never reported: the node is then lost
                tr.on_swaps(slot, ids[keep], rig[keep], host[keep], same)
                if rng.random() < 0.3:
                    tr.flush()
                for i, r, h in zip(ids[keep].tolist(), rig[keep].tolist(), host[keep].tolist()):
                    ref.swap(slot, i, r, h, same)
            if rng.random() < 0.3:
                lost.add(slot)
                tr.forget_slot(slot)
                ref.forget(slot)
        for slot in slots:
            if slot not in lost:
                tr.forget_slot(slot)
                ref.forget(slot)
        got = [(r.frame_id, r.shown_by_all, r.nodes, None if math.isnan(r.skew_ms) else r.skew_ms,
                sorted(r.clock_errors_ms.tolist()), r.late, r.dropped, r.missing) for r in tr.results]
        assert sorted(got, key=lambda t: t[0]) == sorted(ref.results, key=lambda t: t[0]), f"trial {trial}"
        assert not ref.open and len(got) == len(ref.results)
