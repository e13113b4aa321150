"""Swap bookkeeping: per-frame swap skew across nodes, clock-estimate errors, drops.

The skew of a frame is ``max - min`` of its swap instants over the nodes that
showed it. When every node shares the coordinator's host (a local rig, a test)
the instants are read from the host's own monotonic clock, which is the truth;
otherwise they are the nodes' estimates of the rig clock.
"""
from __future__ import annotations

import math
import time
from collections import deque
from dataclasses import dataclass, field
from typing import Callable

import numpy as np

from coordinator.api import DropReason, SyncSummary


@dataclass
class FrameRecord:
    frame_id: int
    pts_ns: int
    tag: str
    expected: set[str]
    created: float
    swaps: dict[str, tuple[int, int, bool]] = field(default_factory=dict)  # slot -> (rig_ns, host_ns, same_host)
    drops: dict[str, DropReason] = field(default_factory=dict)
    #: expected slots that neither swapped nor dropped it yet (a frame is final once empty: checking
    #: it costs O(1) per report, where comparing the sets cost O(nodes), O(nodes²) per frame)
    waiting: set[str] = field(default_factory=set)


@dataclass(frozen=True)
class FrameResult:
    frame_id: int
    tag: str
    shown_by_all: bool
    nodes: int
    skew_ms: float            # NaN with fewer than two swaps
    source: str               # "host-clock" or "estimates"
    clock_errors_ms: tuple[float, ...]
    late: int
    dropped: int
    missing: tuple[str, ...] = ()   # expected slots that did not swap it in


def percentile(values, q: float) -> float:
    arr = np.asarray(list(values), dtype=np.float64)
    arr = arr[np.isfinite(arr)]
    return float(np.percentile(arr, q)) if arr.size else math.nan


class SyncTracker:
    """Collects swap reports per frame and finalises each frame once all expected nodes answered.

    A frame is final when every expected node swapped it in or dropped it, when a node is
    forgotten (lost), or :attr:`timeout_s` after it was expected (:meth:`sweep`). ``clock``
    (seconds, monotonic) is injectable so tests decide when time passes.
    """

    def __init__(self, *, window: int = 20_000, timeout_s: float = 3.0, clock: Callable[[], float] = time.monotonic):
        self.timeout_s = timeout_s
        self.clock = clock
        self._open: dict[int, FrameRecord] = {}
        self.results: deque[FrameResult] = deque(maxlen=window)
        self.out_of_order = 0
        self._listeners: list[Callable[[FrameResult], None]] = []

    def add_listener(self, fn: Callable[[FrameResult], None]) -> Callable[[], None]:
        self._listeners.append(fn)
        return lambda: self._listeners.remove(fn)

    def expect(self, frame_id: int, pts_ns: int, tag: str, slots: set[str]) -> None:
        if slots:
            expected = set(slots)
            self._open[frame_id] = FrameRecord(frame_id, pts_ns, tag, expected, created=self.clock(),
                                               waiting=set(expected))

    def on_swap(self, slot: str, frame_id: int, rig_ns: int, host_ns: int, same_host: bool) -> None:
        rec = self._open.get(frame_id)
        if rec is None or slot not in rec.expected:
            return
        rec.swaps[slot] = (rig_ns, host_ns, same_host)
        rec.waiting.discard(slot)
        if not rec.waiting:
            self._finish(rec)

    def on_drop(self, slot: str, frame_id: int, reason: DropReason) -> None:
        rec = self._open.get(frame_id)
        if rec is None or slot not in rec.expected:
            return
        rec.drops[slot] = reason
        rec.waiting.discard(slot)
        if not rec.waiting:
            self._finish(rec)

    def forget_slot(self, slot: str) -> None:
        """A node was lost: stop waiting for it."""
        for rec in list(self._open.values()):
            if slot in rec.waiting:
                rec.expected.discard(slot)
                rec.waiting.discard(slot)
                if not rec.waiting:
                    self._finish(rec)

    def sweep(self) -> None:
        now = self.clock()
        for rec in list(self._open.values()):
            if now - rec.created > self.timeout_s:
                self._finish(rec)

    def _finish(self, rec: FrameRecord) -> None:
        self._open.pop(rec.frame_id, None)
        swaps = list(rec.swaps.values())
        same_host = bool(swaps) and all(s[2] for s in swaps)
        instants = [s[1] if same_host else s[0] for s in swaps]
        skew = (max(instants) - min(instants)) / 1e6 if len(instants) >= 2 else math.nan
        errors = tuple((s[0] - s[1]) / 1e6 for s in swaps if s[2])
        late = sum(1 for r in rec.drops.values() if r == DropReason.LATE)
        result = FrameResult(
            frame_id=rec.frame_id, tag=rec.tag, shown_by_all=bool(rec.expected) and set(rec.swaps) >= rec.expected,
            nodes=len(swaps), skew_ms=skew, source="host-clock" if same_host else "estimates",
            clock_errors_ms=errors, late=late, dropped=len(rec.drops) - late,
            missing=tuple(sorted(rec.expected - set(rec.swaps))),
        )
        self.results.append(result)
        for fn in list(self._listeners):
            fn(result)


def summarize(results: list[FrameResult], out_of_order: int = 0) -> SyncSummary:
    """Skew percentiles over frames swapped by two or more nodes, clock errors, late/dropped counts."""
    skews = [r.skew_ms for r in results]
    errors = [abs(e) for r in results for e in r.clock_errors_ms]
    sources = {r.source for r in results if r.nodes >= 2}
    return SyncSummary(
        frames=sum(1 for r in results if r.shown_by_all),
        skew_p50_ms=percentile(skews, 50),
        skew_p99_ms=percentile(skews, 99),
        skew_max_ms=percentile(skews, 100),
        skew_source="host-clock" if sources == {"host-clock"} else ("estimates" if sources else ""),
        clock_error_p99_ms=percentile(errors, 99),
        frames_late=sum(r.late for r in results),
        frames_dropped=sum(r.dropped for r in results),
        out_of_order=out_of_order,
    )
