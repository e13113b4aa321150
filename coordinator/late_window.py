"""Frames each node missed lately: the late and dropped frames of the last minute or so, per slot,
from the running counts ``status`` sees each time it is asked (a health alarm needs "is it
missing frames now", which a count since the node joined cannot say).

Pure bookkeeping with the time as a parameter: :meth:`LateWindow.observe` is called with the
rig clock's seconds and each slot's running count.
"""
from __future__ import annotations

from collections import deque
from typing import Mapping

#: how far back the window reaches (seconds)
WINDOW_S = 60.0
#: one kept sample per this many seconds at most (a status asked 4 times a second keeps 1)
SAMPLE_EVERY_S = 1.0


class LateWindow:
    """Keeps samples of each slot's running count of missed frames over :data:`WINDOW_S`."""

    def __init__(self, window_s: float = WINDOW_S, every_s: float = SAMPLE_EVERY_S):
        self.window_s, self.every_s = window_s, every_s
        self._samples: deque[tuple[float, dict[str, int]]] = deque()

    def observe(self, now: float, counts: Mapping[str, int]) -> tuple[float, dict[str, int]]:
        """Note ``counts`` (slot -> frames missed since its node joined) at ``now`` (seconds) and
        return (the seconds the window spans, slot -> frames missed within it; only slots that
        missed any). A count that went down (a node rejoined, its count restarted) counts from 0."""
        counts = {s: int(c) for s, c in counts.items()}
        if not self._samples or now - self._samples[-1][0] >= self.every_s:
            self._samples.append((now, counts))
        while len(self._samples) > 1 and now - self._samples[1][0] >= self.window_s:
            self._samples.popleft()
        t0, old = self._samples[0]
        missed = {}
        for slot, c in counts.items():
            before = old.get(slot, 0)
            n = c - before if c >= before else c
            if n > 0:
                missed[slot] = n
        return max(0.0, now - t0), missed
