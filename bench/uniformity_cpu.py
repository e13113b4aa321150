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


def _threads_ns(pid: int) -> dict[str, int]:
    """Nanoseconds run per thread name of ``pid`` (threads of one name summed)."""
    out: dict[str, int] = {}
    try:
        tasks = os.listdir(f"/proc/{pid}/task")
    except OSError:
        return out
    for tid in tasks:
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
    try:
        tasks = os.listdir(f"/proc/{pid}/task")
    except OSError:
        return out
    for tid in tasks:
        try:
            out += [int(v) for v in Path(f"/proc/{pid}/task/{tid}/children").read_text().split()]
        except (OSError, ValueError):
            pass
    return out


class CpuSnapshot:
    """Run times of groups of processes (group name -> pids) now; :meth:`since` another gives ms per group."""

    def __init__(self, groups: dict[str, list[int]], *, threads_of: int | None = None):
        self.groups = {k: list(v) for k, v in groups.items()}
        self.ns = {k: {p: _run_ns(p) for p in v} for k, v in self.groups.items()}
        self.threads = _threads_ns(threads_of) if threads_of else {}
        self.host_ns = _host_busy_ns()

    def since(self, before: "CpuSnapshot") -> dict[str, float]:
        """CPU ms per group between ``before`` and this snapshot (processes present in both)."""
        out = {}
        for k, now in self.ns.items():
            was = before.ns.get(k, {})
            out[k] = round(sum(max(0, v - was[p]) for p, v in now.items() if p in was) / 1e6, 2)
        if self.host_ns and before.host_ns:     # the whole host, and what was not the groups' (others' work)
            out["host"] = round((self.host_ns - before.host_ns) / 1e6, 1)
            out["others"] = round(max(0.0, out["host"] - sum(out[k] for k in self.ns)), 1)
        if self.threads:       # one process's threads by name, the busiest first
            diff = {n: (v - before.threads.get(n, 0)) / 1e6 for n, v in self.threads.items()}
            out["threads"] = {n: round(v, 2) for n, v in sorted(diff.items(), key=lambda kv: -kv[1]) if v >= 0.5}
        return out
