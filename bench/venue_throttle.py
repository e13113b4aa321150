"""Why a node missed a tick: its CPU budget held it back, its decoder had no frame ready, or neither.

A node in a CPU budget (``--node-cpu``) that misses a tick has one of three stories, and the venue
bench's JSON cannot tell them apart from counts over a whole run (``throttled_s`` per group):

* **throttled**: the node's group ran out of quota in a CFS period shortly before the tick's
  instant (the kernel held every thread of the node, the presenter included, until the period's
  end): a tick late for CPU, of the emulation's making or of the node's own bursts;
* **decode**: the presenter was on time but the decoder thread had no frame for the tick 2 ms
  before its instant (the presenter logs a late drop with a negative lateness);
* **unthrottled**: the presenter itself came late without its group being held back (the host's
  other work, or its own render taking too long).

:class:`ThrottleSampler` reads each node group's ``cpu.stat`` every ``period_s`` on a thread of the
bench (the groups' ``nr_throttled`` counts the CFS periods in which each was held back) and keeps
the instants at which the count grew (each file is kept open and read with one ``pread``: about
6 us a read against 36 us for an open, read and close, measured at load 20; ``cpu_s`` says what the
thread used). :func:`miss_causes` sorts a node's missed ticks with them and
with the node's logged drops. The sampler's resolution is its period (5 ms: half a CFS period of
10 ms); a throttle is counted against a tick when it was seen from one tick period before the
tick's instant to ``SLACK_NS`` after it (the sample that sees a throttle comes up to a period
late).
"""
from __future__ import annotations

import os
import re
import threading
import time
from pathlib import Path

#: a node's late drop as the presenter logs it with SHADOWLESS_DEBUG_TIMING (frame id, ms late;
#: negative: the decoder had no frame for it in time, see node/presenter.py ``_timeline_frame``)
DROP = re.compile(r"timing frame (\d+): dropped \(late\) (-?[\d.]+) ms late")
#: how long after a tick's instant a sampled throttle still counts against it (ns)
SLACK_NS = 6_000_000


_KEY = b"nr_throttled "


def _throttled(fd: int | None) -> int | None:
    """``nr_throttled`` of the ``cpu.stat`` open as ``fd`` (a cgroup file is made afresh at each read
    from offset 0: one pread, no open and close), None when it cannot be read."""
    if fd is None:
        return None
    try:
        text = os.pread(fd, 4096, 0)
        i = text.index(_KEY) + len(_KEY)
        return int(text[i:text.index(b"\n", i)])
    except (OSError, ValueError):
        return None


def _open(path: Path) -> int | None:
    try:
        return os.open(path, os.O_RDONLY | os.O_CLOEXEC)
    except OSError:
        return None


class ThrottleSampler:
    """Instants (monotonic ns) at which each group's ``nr_throttled`` grew, by name, while running.

    ``stats`` maps a name to the group's ``cpu.stat`` path. Use as a context manager."""

    def __init__(self, stats: dict[str, Path], *, period_s: float = 0.005):
        self.stats = dict(stats)
        self.period_s = period_s
        self.events: dict[str, list[int]] = {name: [] for name in self.stats}
        self.samples = 0
        #: the CPU time the sampler's thread used (s): the bench's own cost, on the cores the nodes share
        self.cpu_s = 0.0
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name="throttle-sampler", daemon=True)

    def __enter__(self) -> "ThrottleSampler":
        self._thread.start()
        return self

    def __exit__(self, *exc) -> None:
        self.stop()

    def stop(self) -> None:
        self._stop.set()
        if self._thread.is_alive():
            self._thread.join(timeout=2.0)

    def _run(self) -> None:
        fds = {name: _open(p) for name, p in self.stats.items()}
        try:
            last = {name: _throttled(fd) for name, fd in fds.items()}
            while not self._stop.wait(self.period_s):
                now = time.monotonic_ns()
                self.samples += 1
                for name, fd in fds.items():
                    n = _throttled(fd)
                    if n is not None and last[name] is not None and n > last[name]:
                        self.events[name].append(now)
                    last[name] = n
        finally:
            self.cpu_s = time.thread_time()
            for fd in fds.values():
                if fd is not None:
                    os.close(fd)

    def throttled_between(self, name: str, lo_ns: int, hi_ns: int) -> bool:
        return any(lo_ns <= t <= hi_ns for t in self.events.get(name, ()))


def drops(log_text: str) -> dict[int, float]:
    """The late drops a node logged: frame id -> ms late (negative: no decoded frame in time)."""
    return {int(m.group(1)): float(m.group(2)) for m in DROP.finditer(log_text)}


def miss_causes(lost: list[int], instant_ns, period_ns: int, dropped: dict[int, float],
                sampler: ThrottleSampler | None, name: str) -> dict[str, int]:
    """Sort the missed ticks ``lost`` (ids; ``instant_ns(id)`` their rig instants, the host's monotonic
    clock) of node ``name``: ``decode`` (a late drop with negative lateness), ``throttled`` (its group
    held back within a tick period before the instant), ``unthrottled`` (a late drop without either),
    ``not_dropped`` (neither swapped nor dropped). Without a sampler, throttling is not told apart."""
    out = {"decode": 0, "throttled": 0, "unthrottled": 0, "not_dropped": 0}
    for t in lost:
        late = dropped.get(t)
        if late is None:
            out["not_dropped"] += 1
        elif late < 0:
            out["decode"] += 1
        elif sampler is not None and sampler.throttled_between(name, instant_ns(t) - period_ns,
                                                                instant_ns(t) + SLACK_NS):
            out["throttled"] += 1
        else:
            out["unthrottled"] += 1
    return out


def throttles_per_s(sampler: ThrottleSampler, name: str, lo_ns: int, hi_ns: int) -> float:
    """How many throttle instants of ``name`` the sampler saw per second between two instants."""
    n = sum(1 for t in sampler.events.get(name, ()) if lo_ns <= t < hi_ns)
    return round(n * 1e9 / max(1, hi_ns - lo_ns), 2)
