"""Where a failover's CPU went: the CPU time each kind of process of a live rig ran during one switch.

A failover on one host is a race of every process for its cores, so the stages' wall times
(:func:`bench.uniformity_live._stages`) do not say whose work filled them. This reads each thread's
run time from ``/proc/PID/task/TID/schedstat`` (nanoseconds on the CPU, Linux) at two moments and
sums the difference per group (and, for one process, per thread name): the node processes (their
network side), their presenter processes (rendering, llvmpipe's threads included), the room process
and this process (the coordinator and the benchmark's own polling); beside them the whole host's busy
time (``/proc/stat``, 10 ms steps) and what of it was none of theirs (``others``: on a shared machine,
other people's work). Elsewhere than Linux, or for a process gone meanwhile, a group counts what
could be read.
"""
from __future__ import annotations

import os
import time
from pathlib import Path

__all__ = ["CpuSnapshot", "children_of"]


def _run_ns(pid: int) -> int:
    """Nanoseconds every thread of ``pid`` has run (0 when unreadable)."""
    total = 0
    try:
        tasks = os.listdir(f"/proc/{pid}/task")
    except OSError:
        return 0
    for tid in tasks:
        try:
            total += int(Path(f"/proc/{pid}/task/{tid}/schedstat").read_text().split()[0])
        except (OSError, ValueError, IndexError):
            pass
    return total


def _host_busy_ns() -> int:
    """Nanoseconds every CPU of the host spent not idle (``/proc/stat``'s first line, in USER_HZ ticks:
    10 ms steps), or 0 when unreadable."""
    try:
        fields = [int(v) for v in Path("/proc/stat").read_text().split("\n", 1)[0].split()[1:]]
    except (OSError, ValueError):
        return 0
    idle = sum(fields[3:5])             # idle, iowait
    busy = sum(fields[:8]) - idle       # user, nice, system, idle, iowait, irq, softirq, steal
    return busy * 1_000_000_000 // os.sysconf("SC_CLK_TCK")


def _tasks(pid: int) -> list[str]:
    """The thread ids of ``pid`` as /proc names them ([] once it is gone)."""
    try:
        return os.listdir(f"/proc/{pid}/task")
    except OSError:
        return []


def _threads_ns(pid: int) -> dict[str, int]:
    """Nanoseconds run per thread name of ``pid`` (threads of one name summed)."""
    out: dict[str, int] = {}
    for tid in _tasks(pid):
        try:
            name = Path(f"/proc/{pid}/task/{tid}/comm").read_text().strip()
            ns = int(Path(f"/proc/{pid}/task/{tid}/schedstat").read_text().split()[0])
        except (OSError, ValueError, IndexError):
            continue
        out[name] = out.get(name, 0) + ns
    return out


def children_of(pid: int) -> list[int]:
    """The direct children of ``pid`` (a node process's presenter)."""
    out: list[int] = []
    for tid in _tasks(pid):
        try:
            out += [int(v) for v in Path(f"/proc/{pid}/task/{tid}/children").read_text().split()]
        except (OSError, ValueError):
            pass
    return out


class CpuSnapshot:
    """Run times of groups of processes (group name -> pids) now; :meth:`since` another gives ms per group.

    Reading ``/proc`` for fifty processes costs this process a few milliseconds: this process (any group
    holding it), the threads of ``threads_of`` (this process) and the host are read both before and after
    the others, and :meth:`since` counts from the earlier snapshot's end to the later one's start, so that
    neither snapshot's own reading is counted."""

    def __init__(self, groups: dict[str, list[int]], *, threads_of: int | None = None):
        self.me = os.getpid()
        self.groups = {k: list(v) for k, v in groups.items()}
        self._threads_of = threads_of
        self.first = self._mark()
        self.ns = {k: {p: _run_ns(p) for p in v if p != self.me} for k, v in self.groups.items()}
        self.last = self._mark()

    def _mark(self) -> tuple[int, int, int, dict[str, int]]:
        """(monotonic ns, the host's busy ns, this process's run ns, its threads' run ns by name)"""
        return (time.monotonic_ns(), _host_busy_ns(), _run_ns(self.me),
                _threads_ns(self._threads_of) if self._threads_of else {})

    def since(self, before: "CpuSnapshot") -> dict[str, float]:
        """CPU ms per group between ``before`` and this snapshot (processes present in both), ``span_ms`` the
        time between the two, ``host`` the whole host's busy ms and ``others`` what of it no group ran."""
        t0, host0, me0, threads0 = before.last
        t1, host1, me1, threads1 = self.first
        out: dict = {"span_ms": round((t1 - t0) / 1e6, 1)}
        for k, now in self.ns.items():
            was = before.ns.get(k, {})
            ns = sum(max(0, v - was[p]) for p, v in now.items() if p in was)
            if self.me in self.groups[k] and self.me in before.groups.get(k, ()):
                ns += max(0, me1 - me0)
            out[k] = round(ns / 1e6, 2)
        if host0 and host1:     # the whole host, and what was not the groups' (others' work)
            out["host"] = round((host1 - host0) / 1e6, 1)
            out["others"] = round(max(0.0, out["host"] - sum(out[k] for k in self.ns)), 1)
        if threads1:       # one process's threads by name, the busiest first
            diff = {n: (v - threads0.get(n, 0)) / 1e6 for n, v in threads1.items()}
            out["threads"] = {n: round(v, 2) for n, v in sorted(diff.items(), key=lambda kv: -kv[1]) if v >= 0.5}
        return out
