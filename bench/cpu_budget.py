"""A CPU budget for a group of processes, through a cgroup v1 ``cpu`` controller (benchmarks only).

A benchmark that runs many processes on one machine (25 node processes on 2 cores) cannot tell a
protocol that is slow from processes that starve each other. :class:`CpuBudget` gives the
processes put in it at most ``fraction`` of one core (CFS bandwidth control: a quota of
``fraction * period`` microseconds of CPU per ``period``), one group per budget::

    with CpuBudget(0.06, name="r2c2") as budget:
        budget.add(proc.pid)          # the process, its threads and children it makes from now on
        ...
        budget.stats()                # {"periods": ..., "throttled": ..., "throttled_s": ..., "cpu_s": ...}

The group is ``/sys/fs/cgroup/cpu/shadowless-bench-<pid>-<n>`` (``<pid>`` this process, ``<n>`` a
counter). On leaving the block, even on an error, every process still in it is moved back to the
root group and the group is removed; groups a crashed run left (their ``<pid>`` no longer runs) are
removed by the next budget made. :func:`unavailable` says in one line why budgets cannot be made
here (not root, no cgroup v1 ``cpu`` hierarchy: e.g. a cgroup v2 only host); a benchmark prints
it and runs without budgets.

``python -m bench.cpu_budget [FRACTION]`` checks a budget here: a busy process held to FRACTION (0.1)
for 2 s, and the share of a core it got. Only the standard library: any benchmark may use it.
"""
from __future__ import annotations

import itertools
import math
import os
import re
from pathlib import Path

__all__ = ["CPU_ROOT", "CpuBudget", "CpuBudgetError", "MIN_QUOTA_US", "cleanup_leftovers", "unavailable"]

#: where the cgroup v1 ``cpu`` hierarchy is mounted on systemd and Docker hosts
CPU_ROOT = Path("/sys/fs/cgroup/cpu")
#: the kernel refuses a CFS quota below 1 ms and a period outside 1 ms .. 1 s
MIN_QUOTA_US = 1000
MIN_PERIOD_US, MAX_PERIOD_US = 1000, 1_000_000
PREFIX = "shadowless-bench-"
_NAME = re.compile(rf"^{PREFIX}(\d+)-(\d+)$")
_counter = itertools.count()


class CpuBudgetError(RuntimeError):
    """A budget cannot be made or used here; the message is one line."""


def _v1_cpu_mount(root: Path) -> bool:
    """Whether ``root`` is a cgroup v1 mount with the ``cpu`` controller (``/proc/mounts``)."""
    try:
        mounts = Path("/proc/mounts").read_text().splitlines()
    except OSError:
        return False
    for line in mounts:
        parts = line.split()
        if len(parts) >= 4 and parts[2] == "cgroup" and Path(parts[1]) == root and "cpu" in parts[3].split(","):
            return True
    return False


def unavailable(root: Path = CPU_ROOT) -> str:
    """Why CPU budgets cannot be made here, in one line ("" when they can)."""
    if os.geteuid() != 0:
        return "CPU budgets need root (a cgroup v1 cpu group is made per budget): run as root, or without the budget"
    if not _v1_cpu_mount(root) or not (root / "cpu.cfs_quota_us").exists():
        return (f"CPU budgets need the cgroup v1 cpu controller at {root} (this host has none: cgroup v2 only?); "
                "run without the budget")
    return ""


def _pid_alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    return True


def _write(path: Path, value: object) -> None:
    with open(path, "w") as f:
        f.write(f"{value}\n")


def _empty_and_remove(group: Path, root: Path) -> None:
    """Move every task of ``group`` to ``root`` (a group with tasks cannot be removed), then remove it."""
    for _ in range(5):      # a process may fork while we move its siblings: go round again
        try:
            pids = [p for p in (group / "cgroup.procs").read_text().split() if p]
        except FileNotFoundError:
            return
        if not pids:
            break
        for p in pids:
            try:
                _write(root / "cgroup.procs", p)
            except (ProcessLookupError, OSError):
                pass        # gone meanwhile
    try:
        group.rmdir()
    except FileNotFoundError:
        pass


def cleanup_leftovers(root: Path = CPU_ROOT) -> list[str]:
    """Remove the groups of benchmark runs that are gone (``shadowless-bench-<pid>-<n>`` whose pid no
    longer runs); the names removed."""
    removed = []
    try:
        entries = list(root.iterdir())
    except OSError:
        return removed
    for d in entries:
        m = _NAME.match(d.name)
        if m and d.is_dir() and not _pid_alive(int(m.group(1))):
            try:
                _empty_and_remove(d, root)
                removed.append(d.name)
            except OSError:
                pass
    return removed


class CpuBudget:
    """At most ``fraction`` of one core for the processes added (see the module docstring).

    Parameters
    ----------
    fraction : float
        Of one core, in (0, number of cores]: 0.06 is 6 ms of CPU every 100 ms.
    period_us : int
        The CFS period (1 ms .. 1 s). A short period makes a budgeted process wait less at a
        time when its quota runs out (closer to a slower CPU of its own), at some scheduling cost;
        the quota ``fraction * period_us`` must be at least 1 ms.
    name : str
        For messages only (e.g. the slot whose node runs in it).
    root : Path
        The cgroup v1 ``cpu`` hierarchy.
    """

    def __init__(self, fraction: float, *, period_us: int = 100_000, name: str = "", root: Path = CPU_ROOT):
        cores = os.cpu_count() or 1
        if not (isinstance(fraction, (int, float)) and 0.0 < float(fraction) <= cores):
            raise CpuBudgetError(f"a CPU budget is a fraction of one core in (0, {cores}], got {fraction!r}")
        if not (MIN_PERIOD_US <= int(period_us) <= MAX_PERIOD_US):
            raise CpuBudgetError(f"a CPU budget's period must be {MIN_PERIOD_US}..{MAX_PERIOD_US} us, got {period_us}")
        self.fraction = float(fraction)
        self.period_us = int(period_us)
        self.quota_us = int(round(self.fraction * self.period_us))
        if self.fraction < MIN_QUOTA_US / MAX_PERIOD_US:
            raise CpuBudgetError(f"a CPU budget is at least {MIN_QUOTA_US / MAX_PERIOD_US:g} of a core (1 ms a second), "
                                 f"got {self.fraction:g}")
        if self.quota_us < MIN_QUOTA_US:
            raise CpuBudgetError(f"a budget of {self.fraction:g} of a core over {self.period_us / 1000:g} ms is a quota "
                                 f"of {self.quota_us} us, under the kernel's 1 ms: use a period of at least "
                                 f"{math.ceil(MIN_QUOTA_US / self.fraction)} us")
        self.name = name
        self.root = Path(root)
        self.path: Path | None = None
        self.pids: list[int] = []

    def __enter__(self) -> "CpuBudget":
        why = unavailable(self.root)
        if why:
            raise CpuBudgetError(why)
        cleanup_leftovers(self.root)
        path = self.root / f"{PREFIX}{os.getpid()}-{next(_counter)}"
        path.mkdir()
        self.path = path
        try:
            _write(path / "cpu.cfs_period_us", self.period_us)
            _write(path / "cpu.cfs_quota_us", self.quota_us)
        except OSError as exc:
            self.close()
            raise CpuBudgetError(f"cannot set the CPU budget of {path}: {exc}") from None
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def close(self) -> None:
        """Move what is left in the group back to the root group and remove the group (idempotent)."""
        if self.path is not None:
            path, self.path = self.path, None
            _empty_and_remove(path, self.root)

    def add(self, pid: int, *, children: bool = True) -> None:
        """Put process ``pid`` in the budget: all its threads (``cgroup.procs``; a pid written to
        ``tasks`` would move only its main thread) and, with ``children``, its descendants now
        running; processes they start later are in the group from birth. CpuBudgetError if the
        process is gone."""
        if self.path is None:
            raise CpuBudgetError("the CPU budget is not open (use it as a context manager)")
        for p in [pid, *(_descendants(pid) if children else [])]:
            try:
                _write(self.path / "cgroup.procs", p)
            except (ProcessLookupError, FileNotFoundError):
                if p == pid:
                    raise CpuBudgetError(f"process {pid} is gone; it cannot join the CPU budget") from None
            except OSError as exc:
                if p == pid:
                    raise CpuBudgetError(f"cannot put process {pid} in the CPU budget: {exc}") from None
        self.pids.append(pid)

    def members(self) -> list[int]:
        """The pids in the group now."""
        if self.path is None:
            return []
        return [int(p) for p in (self.path / "cgroup.procs").read_text().split() if p]

    def stats(self) -> dict:
        """What the budget did: CFS periods elapsed, periods in which the group was throttled, the
        time it was held back (s) and the CPU time it used (s, when ``cpuacct`` shares the mount)."""
        if self.path is None:
            return {}
        out: dict = {"fraction": self.fraction, "period_ms": self.period_us / 1000}
        try:
            st = dict(line.split() for line in (self.path / "cpu.stat").read_text().splitlines() if line.strip())
            out.update(periods=int(st.get("nr_periods", 0)), throttled=int(st.get("nr_throttled", 0)),
                       throttled_s=round(int(st.get("throttled_time", 0)) / 1e9, 3))
        except OSError:
            pass
        usage = self.path / "cpuacct.usage"
        if usage.exists():
            out["cpu_s"] = round(int(usage.read_text()) / 1e9, 3)
        return out


def _descendants(pid: int) -> list[int]:
    """The pids descended from ``pid`` now (``/proc/<pid>/task/*/children``)."""
    out: list[int] = []
    todo = [pid]
    while todo:
        p = todo.pop()
        try:
            tasks = list(Path(f"/proc/{p}/task").iterdir())
        except OSError:
            continue
        for t in tasks:
            try:
                kids = [int(k) for k in (t / "children").read_text().split()]
            except OSError:
                continue
            out += kids
            todo += kids
    return out


def _self_check(fraction: float = 0.1, seconds: float = 2.0) -> dict:
    """A busy child process in a budget of ``fraction`` for ``seconds``: the share of a core it got."""
    import subprocess
    import sys
    import time

    child = subprocess.Popen([sys.executable, "-c", "while True: pass"])
    try:
        with CpuBudget(fraction, period_us=20_000, name="self-check") as budget:
            budget.add(child.pid)
            tick = os.sysconf("SC_CLK_TCK")

            def cpu() -> float:
                fields = Path(f"/proc/{child.pid}/stat").read_text().rsplit(")", 1)[1].split()
                return (int(fields[11]) + int(fields[12])) / tick
            c0, t0 = cpu(), time.monotonic()
            time.sleep(seconds)
            got = (cpu() - c0) / (time.monotonic() - t0)
            return {"asked": fraction, "got": round(got, 3), **budget.stats()}
    finally:
        child.kill()
        child.wait()


if __name__ == "__main__":       # python -m bench.cpu_budget [FRACTION]: can budgets be made here, and do they hold
    import json
    import sys

    why = unavailable()
    if why:
        print(why, file=sys.stderr)
        raise SystemExit(1)
    print(json.dumps(_self_check(float(sys.argv[1]) if len(sys.argv) > 1 else 0.1)))
