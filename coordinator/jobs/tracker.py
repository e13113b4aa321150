"""What the rig's job is doing, for whoever asks (the console, status): the running job's stage,
progress and estimated time left, its last log lines, and how the last one ended.

The coordinator runs one job at a time, started from the CLI (RunJob) or the console alike; the
tracker sees every event it emits. The estimate is per stage: the rate of progress since the
stage began, extrapolated to its total.
"""
from __future__ import annotations

import math
import time
from collections import deque
from dataclasses import dataclass, field
from typing import Any, Callable

from coordinator.jobs.context import Event, Progress

#: log lines kept per job
LOG_LINES = 200


def summarize_params(params: dict[str, Any], *, max_text: int = 200, max_items: int = 16) -> dict[str, Any]:
    """A job's parameters as shown to people: small values as they are; long text, long lists and
    nested documents (e.g. a sequence's encoded frames) replaced by what they are and their size."""
    out: dict[str, Any] = {}
    for k, v in params.items():
        if isinstance(v, (bool, int, float)) or v is None:
            out[k] = v
        elif isinstance(v, str):
            out[k] = v if len(v) <= max_text else f"({len(v)} characters)"
        elif isinstance(v, (list, tuple)):
            small = len(v) <= max_items and all(isinstance(x, (bool, int, float, str)) and len(str(x)) <= max_text
                                                or isinstance(x, (list, tuple)) and len(x) <= 8 for x in v)
            out[k] = list(v) if small else f"({len(v)} items)"
        else:
            out[k] = f"({type(v).__name__})"
    return out


@dataclass
class JobState:
    kind: str
    params: dict[str, Any]
    started: float                       # wall clock, seconds
    state: str = "running"               # running, done, failed, cancelled
    stage: str = ""
    item: str = ""
    done: int = 0
    total: int = 0
    message: str = ""
    eta_s: float = math.nan
    ended: float = math.nan
    error: str = ""
    result: dict[str, Any] = field(default_factory=dict)
    log: deque = field(default_factory=lambda: deque(maxlen=LOG_LINES))
    _stage_start: tuple[float, int] = (0.0, 0)

    def as_dict(self, now: float) -> dict[str, Any]:
        fin = lambda x: round(x, 1) if math.isfinite(x) else None  # noqa: E731
        return {"kind": self.kind, "params": self.params, "state": self.state, "stage": self.stage,
                "item": self.item, "done": self.done, "total": self.total, "message": self.message,
                "eta_s": fin(self.eta_s) if self.state == "running" else None,
                "elapsed_s": fin((self.ended if math.isfinite(self.ended) else now) - self.started),
                "started": round(self.started, 3), "error": self.error, "result": self.result,
                "log": list(self.log)[-50:]}


class JobTracker:
    """Follows the current job (``begin`` / ``event`` / ``end``); ``clock`` is wall seconds.

    Whoever wants to hear of every change (the console's live view, several pages' worth of them)
    calls :meth:`subscribe`; each listener is called with no argument after each change."""

    def __init__(self, clock: Callable[[], float] = time.time):
        self.clock = clock
        self.current: JobState | None = None
        self._listeners: list[Callable[[], None]] = []

    def subscribe(self, listener: Callable[[], None]) -> Callable[[], None]:
        """Call ``listener()`` after every change from now on; returns the function that stops it."""
        self._listeners.append(listener)

        def unsubscribe() -> None:
            if listener in self._listeners:
                self._listeners.remove(listener)
        return unsubscribe

    def _changed(self) -> None:
        for listener in list(self._listeners):
            listener()

    def begin(self, kind: str, params: dict[str, Any]) -> JobState:
        self.current = JobState(kind, summarize_params(params), self.clock())
        self._changed()
        return self.current

    def event(self, ev: Event) -> None:
        job = self.current
        if job is None:
            return
        now = self.clock()
        if isinstance(ev, Progress):
            if ev.stage != job.stage or ev.done < job.done:
                job._stage_start = (now, ev.done)
            job.stage, job.item, job.done, job.total = ev.stage, ev.item, ev.done, ev.total
            if ev.message:
                job.message = ev.message
            t0, d0 = job._stage_start
            rate = (ev.done - d0) / (now - t0) if now > t0 and ev.done > d0 else 0.0
            job.eta_s = (ev.total - ev.done) / rate if rate > 0 and ev.total >= ev.done else math.nan
        else:
            job.log.append(f"{time.strftime('%H:%M:%S', time.localtime(now))} {ev}")
        self._changed()

    def end(self, *, result: dict | None = None, error: str = "", cancelled: bool = False) -> None:
        job = self.current
        if job is None:
            return
        job.ended = self.clock()
        job.state = "cancelled" if cancelled else ("failed" if error else "done")
        job.error = error
        job.result = {k: v for k, v in (result or {}).items() if isinstance(v, (int, float, str, bool))}
        self._changed()

    def snapshot(self) -> dict[str, Any] | None:
        return None if self.current is None else self.current.as_dict(self.clock())
