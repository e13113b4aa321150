"""Swap bookkeeping: per-frame swap skew across nodes, clock-estimate errors, drops.

The skew of a frame is ``max - min`` of its swap instants over the nodes that
showed it. When every node shares the coordinator's host (a local rig, a test)
the instants are read from the host's own monotonic clock, which is the truth;
otherwise they are the nodes' estimates of the rig clock.
"""
from __future__ import annotations

import itertools
import math
import time
from collections import deque
from dataclasses import dataclass
from typing import Callable, Iterable

import numpy as np

from coordinator.api import DropReason, SyncSummary


@dataclass(frozen=True, eq=False)
class FrameResult:
    frame_id: int
    tag: str
    shown_by_all: bool
    nodes: int
    skew_ms: float            # NaN with fewer than two swaps
    source: str               # "host-clock" or "estimates"
    clock_errors_ms: np.ndarray   # float64, shape (k,): rig estimate - host truth of the k swaps on the coordinator's host
    late: int
    dropped: int
    missing: tuple[str, ...] = ()   # expected slots that did not swap it in


def percentile(values, q: float) -> float:
    arr = np.asarray(values if isinstance(values, np.ndarray) else list(values), dtype=np.float64)
    arr = arr[np.isfinite(arr)]
    return float(np.percentile(arr, q)) if arr.size else math.nan


class SyncTracker:
    """Collects swap reports per frame and finalises each frame once all expected nodes answered.

    A frame is final when every expected node swapped it in or dropped it, when a node is
    forgotten (lost), or :attr:`timeout_s` after it was expected (:meth:`sweep`). ``clock``
    (seconds, monotonic) is injectable so tests decide when time passes.

    Open frames are rows and slots are columns of a few arrays, so a node's batch of swaps
    (a second of a show's ticks) is filed with a handful of array operations, whatever its
    length: ``_expected``, ``_answered`` (swapped or dropped), ``_swapped`` and ``_same``
    (bool, shape (rows, columns)), ``_rig`` and ``_host`` (int64, the swap instants) and
    ``_waiting`` (int64, shape (rows,): expected columns not answered yet; the frame is final
    at 0). Drops are rare and kept per row in a dict. Batches of swaps wait in a list until the
    next :meth:`flush`, which files all of them at once: with hundreds of nodes a node's second
    of ticks then costs an append, and the array operations are shared by every node.
    """

    def __init__(self, *, window: int = 20_000, timeout_s: float = 3.0, clock: Callable[[], float] = time.monotonic,
                 flush_swaps: int = 8192):
        self.timeout_s = timeout_s
        self.clock = clock
        self.flush_swaps = flush_swaps
        self._results: deque[FrameResult] = deque(maxlen=window)
        self._pending: list[tuple[int, np.ndarray, np.ndarray, np.ndarray, bool]] = []
        self._pending_swaps = 0
        self.out_of_order = 0
        self._listeners: list[Callable[[FrameResult], None]] = []
        self._col_of: dict[str, int] = {}
        self._names: list[str] = []
        self._row_of: dict[int, int] = {}                   # open frame id -> row
        self._meta: list[tuple[int, int, str, float] | None] = []   # row -> (frame_id, pts_ns, tag, created)
        self._drops: list[dict[str, DropReason] | None] = []
        self._free: list[int] = []
        self._rows, self._cols = 0, 0
        self._grow(64, 8)

    # ------------------------------------------------------------------ storage
    def _grow(self, rows: int, cols: int) -> None:
        """Room for at least ``rows`` open frames and ``cols`` slots (the arrays keep their contents)."""
        rows, cols = max(rows, self._rows), max(cols, self._cols)
        if (rows, cols) == (self._rows, self._cols):
            return

        def grown(old: np.ndarray | None, dtype) -> np.ndarray:
            new = np.zeros((rows, cols), dtype=dtype)
            if old is not None:
                new[:old.shape[0], :old.shape[1]] = old
            return new

        first = self._rows == 0
        for name, dtype in (("_expected", bool), ("_answered", bool), ("_swapped", bool), ("_same", bool),
                            ("_rig", np.int64), ("_host", np.int64)):
            setattr(self, name, grown(None if first else getattr(self, name), dtype))
        waiting = np.zeros(rows, dtype=np.int64)
        if not first:
            waiting[:self._rows] = self._waiting
        self._waiting = waiting
        self._free.extend(range(rows - 1, self._rows - 1, -1))
        self._meta.extend([None] * (rows - self._rows))
        self._drops.extend([None] * (rows - self._rows))
        self._rows, self._cols = rows, cols

    def _column(self, slot: str) -> int:
        c = self._col_of.get(slot)
        if c is None:
            c = self._col_of[slot] = len(self._names)
            self._names.append(slot)
            if c >= self._cols:
                self._grow(self._rows, 2 * self._cols)
        return c

    # ------------------------------------------------------------------ reports
    def add_listener(self, fn: Callable[[FrameResult], None]) -> Callable[[], None]:
        self._listeners.append(fn)
        return lambda: self._listeners.remove(fn)

    def expect(self, frame_id: int, pts_ns: int, tag: str, slots: Iterable[str]) -> None:
        """Frame ``frame_id`` will be swapped in by every slot of ``slots`` (none: not tracked)."""
        cols = [self._column(s) for s in set(slots)]
        if not cols:
            return
        row = self._row_of.pop(frame_id, None)      # expected again: it starts over
        if row is None:
            if not self._free:
                self._grow(2 * self._rows, self._cols)
            row = self._free.pop()
        for a in (self._expected, self._answered, self._swapped, self._same):
            a[row] = False
        self._expected[row, cols] = True
        self._waiting[row] = len(cols)
        self._meta[row] = (frame_id, pts_ns, tag, self.clock())
        self._drops[row] = None
        self._row_of[frame_id] = row

    def on_swap(self, slot: str, frame_id: int, rig_ns: int, host_ns: int, same_host: bool) -> None:
        self.on_swaps(slot, np.array([frame_id], dtype=np.int64), np.array([rig_ns], dtype=np.int64),
                      np.array([host_ns], dtype=np.int64), same_host)

    def on_swaps(self, slot: str, frame_ids: np.ndarray, rig_ns: np.ndarray, host_ns: np.ndarray,
                 same_host: bool) -> None:
        """Node ``slot`` swapped in ``frame_ids[i]`` at ``rig_ns[i]`` (its estimate of the rig
        clock) and ``host_ns[i]`` (its host's monotonic clock); int64 arrays of one length.
        Frames not expected from ``slot``, or that it already swapped in, are ignored.

        Batches wait until :meth:`flush` (at :attr:`flush_swaps` swaps, a sweep, a drop, a lost
        node or a read of :attr:`results`) and are then filed together."""
        c = self._col_of.get(slot)
        if c is None or not len(frame_ids):
            return
        self._pending.append((c, frame_ids, rig_ns, host_ns, same_host))
        self._pending_swaps += len(frame_ids)
        if self._pending_swaps >= self.flush_swaps:
            self.flush()

    def flush(self) -> None:
        """File every batch of swaps received since the last flush, with a few array operations
        whatever their number; frames nobody is waiting for any more are finished."""
        pending, self._pending, self._pending_swaps = self._pending, [], 0
        if not pending or not self._row_of:
            return
        lens = [len(p[1]) for p in pending]
        cols = np.repeat(np.array([p[0] for p in pending], dtype=np.int64), lens)
        same = np.repeat(np.array([p[4] for p in pending], dtype=bool), lens)
        ids, rig, host = (np.concatenate([p[k] for p in pending]) for k in (1, 2, 3))
        rows = np.array(list(map(self._row_of.get, ids.tolist(), itertools.repeat(-1, len(ids)))), dtype=np.int64)
        idx = np.flatnonzero(rows >= 0)
        idx = idx[self._expected[rows[idx], cols[idx]] & ~self._swapped[rows[idx], cols[idx]]]
        if not idx.size:
            return
        # a frame a slot reported twice counts once, with its first swap (np.unique's first occurrence)
        _, first = np.unique(rows[idx] * self._cols + cols[idx], return_index=True)
        idx = idx[first]
        r, c = rows[idx], cols[idx]
        self._rig[r, c] = rig[idx]
        self._host[r, c] = host[idx]
        self._same[r, c] = same[idx]
        self._swapped[r, c] = True
        new = ~self._answered[r, c]
        self._answer(r[new], c[new])

    @property
    def results(self) -> deque[FrameResult]:
        """The last ``window`` finished frames, oldest first (after a :meth:`flush`)."""
        self.flush()
        return self._results

    def on_drop(self, slot: str, frame_id: int, reason: DropReason) -> None:
        self.flush()        # the node's swaps before its drop: the drop may finish the frame
        c, row = self._col_of.get(slot), self._row_of.get(frame_id)
        if c is None or row is None or not self._expected[row, c]:
            return
        drops = self._drops[row] = self._drops[row] or {}
        drops[slot] = reason
        if not self._answered[row, c]:
            self._answer(np.array([row]), np.array([c]))

    def _answer(self, rows: np.ndarray, cols: np.ndarray) -> None:
        """Slot ``cols[i]`` answered frame row ``rows[i]`` (each pair once): finish the frames
        nobody else is waiting for."""
        if not rows.size:
            return
        self._answered[rows, cols] = True
        counts = np.bincount(rows, minlength=self._rows)
        self._waiting -= counts
        self._finish_rows(np.flatnonzero((counts > 0) & (self._waiting == 0)))

    def forget_slot(self, slot: str) -> None:
        """A node was lost: stop waiting for it."""
        self.flush()
        c = self._col_of.get(slot)
        if c is None or not self._row_of:
            return
        rows = np.fromiter(self._row_of.values(), dtype=np.int64, count=len(self._row_of))
        rows = rows[self._expected[rows, c] & ~self._answered[rows, c]]
        self._expected[rows, c] = False
        self._waiting[rows] -= 1
        self._finish_rows(rows[self._waiting[rows] == 0])

    def sweep(self) -> None:
        """File what waits (:meth:`flush`), then finish the frames expected longer than :attr:`timeout_s` ago."""
        self.flush()
        now = self.clock()
        stale = [row for row in self._row_of.values() if now - self._meta[row][3] > self.timeout_s]
        self._finish_rows(np.array(stale, dtype=np.int64))

    # ------------------------------------------------------------------ results
    def _finish_rows(self, rows: np.ndarray) -> None:
        for row in sorted(rows.tolist(), key=lambda r: self._meta[r][0]):
            self._finish(row)

    def _finish(self, row: int) -> None:
        frame_id, _, tag, _ = self._meta[row]
        del self._row_of[frame_id]
        self._meta[row] = None
        self._free.append(row)
        n = len(self._names)
        swapped, expected, same = self._swapped[row, :n], self._expected[row, :n], self._same[row, :n]
        rig, host = self._rig[row, :n], self._host[row, :n]
        count = int(swapped.sum())
        same_host = count > 0 and bool(same[swapped].all())
        instants = (host if same_host else rig)[swapped]
        skew = float(instants.max() - instants.min()) / 1e6 if count >= 2 else math.nan
        on_host = swapped & same
        drops = self._drops[row] or {}
        late = sum(1 for r in drops.values() if r == DropReason.LATE)
        missing = expected & ~swapped
        result = FrameResult(
            frame_id=frame_id, tag=tag, shown_by_all=bool(expected.any()) and not missing.any(),
            nodes=count, skew_ms=skew, source="host-clock" if same_host else "estimates",
            clock_errors_ms=(rig[on_host] - host[on_host]) / 1e6, late=late, dropped=len(drops) - late,
            missing=tuple(sorted(self._names[k] for k in np.flatnonzero(missing).tolist())),
        )
        self._results.append(result)
        for fn in list(self._listeners):
            fn(result)


def summarize(results: list[FrameResult], out_of_order: int = 0) -> SyncSummary:
    """Skew percentiles over frames swapped by two or more nodes, clock errors, late/dropped counts."""
    skews = [r.skew_ms for r in results]
    errors = np.abs(np.concatenate([r.clock_errors_ms for r in results])) if results else ()
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
