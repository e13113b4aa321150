"""What a node's report stream sends, and when: heartbeats and batches of swaps and drops.

:class:`ReportBatcher` is pure logic. The caller passes the time (``now``, seconds on any
monotonic clock) to every method; the batcher decides what goes in the next message and when the
next one is due, and never waits or reads a clock itself. The real node and the swarm both drive
one (see :class:`node.session.ReportStream`), and tests drive it with the instants they choose.

The rules, which a coordinator's cost per node rests on (its cost is mostly per message):

* a heartbeat every ``heartbeat_s``; the first at once; one at once when news is wanted
  (:meth:`ReportBatcher.want_heartbeat`), the next regular one a full period after it;
* a streamed frame's swap or drop (a still, a pattern, a sequence: callers wait for these) goes
  within ``batch_s``, with whatever else waits;
* a timeline tick's waits up to ``timeline_batch_s`` (default: the heartbeat interval), and
  travels with the next heartbeat when that is due by then: a node playing a show sends one
  message per heartbeat;
* a heartbeat due within ``ride_along_s`` of a batch goes with it rather than alone just after;
* a preview goes like a streamed frame's report (the newest, if several wait).
"""
from __future__ import annotations

import math
from typing import Callable

from node.records import DropRecord, HeartbeatRecord, PreviewRecord, ReportBatch, SwapRecord

#: a heartbeat due within this many seconds of a batch goes with the batch
RIDE_ALONG_S = 0.005

Report = SwapRecord | DropRecord | PreviewRecord


class ReportBatcher:
    """The report stream's decisions, with the time injected.

    Parameters
    ----------
    heartbeat_s : float
        Seconds between regular heartbeats (> 0).
    batch_s : float
        How long a streamed frame's report may wait for others to join it.
    timeline_batch_s : float, optional
        How long a timeline tick's report may wait; None: the heartbeat interval.
    ride_along_s : float
        A heartbeat due within this long of a batch goes with it.
    """

    def __init__(self, heartbeat_s: float, *, batch_s: float = 0.05, timeline_batch_s: float | None = None,
                 ride_along_s: float = RIDE_ALONG_S):
        if not heartbeat_s > 0:
            raise ValueError(f"the heartbeat interval must be > 0 s, got {heartbeat_s}")
        self.heartbeat_s = float(heartbeat_s)
        self.batch_s = float(batch_s)
        self.timeline_batch_s = float(heartbeat_s if timeline_batch_s is None else timeline_batch_s)
        self.ride_along_s = float(ride_along_s)
        self._pending: list[Report] = []
        self._next_hb = -math.inf          # the first heartbeat is due at once
        self._flush_at = math.inf          # when the pending reports must go (inf: nothing waits)
        self._hb_wanted = False

    @property
    def pending(self) -> int:
        """How many reports wait for the next message."""
        return len(self._pending)

    def add(self, report: Report, now: float) -> bool:
        """Queue ``report`` (reported at ``now``). True when this brought the next message forward:
        a caller waiting for :meth:`next_due` must look again."""
        before = self.next_due()
        self._pending.append(report)
        if getattr(report, "timeline", False):      # with the heartbeat if it comes within the wait
            wait = self.timeline_batch_s
            due = self._next_hb if self._next_hb <= now + wait else now + wait
        else:                                         # gather what follows into the same message
            due = now + self.batch_s
        self._flush_at = min(self._flush_at, due)
        return self.next_due() < before

    def want_heartbeat(self) -> None:
        """News for the operator (an asset ready, or given up on): a heartbeat goes at once."""
        self._hb_wanted = True

    def next_due(self) -> float:
        """When :meth:`poll` next has something to send (-inf: now)."""
        if self._hb_wanted:
            return -math.inf
        return min(self._next_hb, self._flush_at)

    def poll(self, now: float, heartbeat: Callable[[], HeartbeatRecord]) -> ReportBatch | None:
        """The message to send at ``now``, or None when nothing is due yet. ``heartbeat`` is called
        only when the message carries one."""
        flush = now >= self._flush_at
        hb_due = self._hb_wanted or now >= self._next_hb or (flush and now >= self._next_hb - self.ride_along_s)
        if not (hb_due or flush):
            return None
        beat = None
        if hb_due:
            self._hb_wanted = False
            self._next_hb = now + self.heartbeat_s
            beat = heartbeat()
        items, self._pending, self._flush_at = self._pending, [], math.inf
        previews = [i for i in items if isinstance(i, PreviewRecord)]
        return ReportBatch(heartbeat=beat, swaps=tuple(i for i in items if isinstance(i, SwapRecord)),
                           drops=tuple(i for i in items if isinstance(i, DropRecord)),
                           preview=previews[-1] if previews else None)
