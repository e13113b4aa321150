"""A CPU budget for a group of processes or threads: one cgroup, cgroup v1 or v2 (standard library only).

A run that puts many processes on one machine (node processes on 2 cores) cannot tell a protocol
that is slow from processes that starve each other. :class:`CpuBudget` gives what is put in it at
most ``fraction`` of one core (CFS bandwidth control: a quota of ``fraction * period``
microseconds of CPU per ``period``), or no limit (``fraction=None``: the group then only measures)::

    with CpuBudget(0.4, name="r0c0", kind="node") as budget:
        budget.add(proc.pid)          # the process, its threads and children it makes from now on
        budget.add_thread(tid)        # one thread (see below)
        budget.stats()                # {"cpu_s": ..., "periods": ..., "throttled": ..., "throttled_s": ...}

**Which cgroup.** :func:`find_hierarchy` reads ``/proc/mounts``: a cgroup v1 hierarchy with the
``cpu`` controller is used where there is one (``cpu.cfs_period_us``, ``cpu.cfs_quota_us``; the
CPU time from ``cpuacct.usage``, in a group of the same name in the ``cpuacct`` hierarchy when
that is mounted apart); else a cgroup v2 mount whose ``cgroup.controllers`` lists ``cpu``
(``cpu.max`` = ``"QUOTA PERIOD"`` or ``"max PERIOD"``, the time from ``cpu.stat``; ``+cpu`` is
written to the parent's ``cgroup.subtree_control`` when it is not enabled there yet).

**Threads.** A group made with ``threads=True`` takes single threads (``add_thread``) beside whole
processes. In v1 any thread may sit in any group (its id written to ``tasks``). In v2 a process's
threads may be split only inside a *threaded subtree*: such a budget is a domain group (no limit)
holding two threaded children, ``proc`` (the limit, where processes go) and ``thr`` (where
threads go, with a limit of their own, ``thread_fraction``); a thread cannot leave that subtree on
its own, so processes leave it whole (the v2 rules, checked by this module's tests on the kernel's
own cgroup2 mount where one is there).

**Names and leftovers.** A group is ``shadowless-<kind>-<pid>-<n>`` (``<kind>`` a word saying what
runs in it, ``<pid>`` the process that made it, ``<n>`` a counter) directly under the hierarchy's
root. On leaving the block, even on an error, everything still in the group moves back to the root
group and the group is removed; :func:`cleanup_leftovers` (run by every budget made, and by
``python -m shadowless.cpu_budget cleanup``) removes the groups of runs whose process is gone, in
every hierarchy this module writes to, whatever their kind. :func:`unavailable` says in one line
why budgets cannot be made here.

``python -m shadowless.cpu_budget check [FRACTION]``: a busy process held to FRACTION (0.1) for
2 s, and the share of a core it got; ``cleanup``: remove what crashed runs left.
"""
from __future__ import annotations

import errno
import itertools
import math
import os
import re
from dataclasses import dataclass
from pathlib import Path

__all__ = ["CpuBudget", "CpuBudgetError", "Hierarchy", "MIN_QUOTA_US", "PREFIX", "cleanup_leftovers",
           "find_hierarchy", "group_name", "groups_of", "leftover_groups", "parse_cpu_stat", "remove_group",
           "unavailable", "v1_files", "v2_files"]

#: the kernel refuses a CFS quota below 1 ms and a period outside 1 ms .. 1 s
MIN_QUOTA_US = 1000
MIN_PERIOD_US, MAX_PERIOD_US = 1000, 1_000_000
#: a group's real-time grant per real-time period (v1 ``cpu.rt_runtime_us``), and what a node asks for:
#: 2 % of the host's usual 1 s period, far more than a swap window's few microseconds a frame
MIN_REALTIME_US, MAX_REALTIME_US, NODE_REALTIME_US = 1000, 500_000, 20_000
PREFIX = "shadowless-"
#: ``shadowless-<kind>-<pid>-<n>``; ``<kind>`` may hold dashes (the last two numbers are pid and counter)
_NAME = re.compile(rf"^{PREFIX}([a-z0-9][a-z0-9-]*?)-(\d+)-(\d+)$")
_KIND = re.compile(r"^[a-z0-9][a-z0-9-]{0,30}$")
#: the two threaded children of a v2 budget that splits threads off
V2_PROCS, V2_THREADS = "proc", "thr"
_counter = itertools.count()


class CpuBudgetError(RuntimeError):
    """A budget cannot be made or used here; the message is one line."""


# ---------------------------------------------------------------- where the groups go (pure)
@dataclass(frozen=True)
class Hierarchy:
    """The cgroup hierarchy budgets are made in.

    ``version`` 1 or 2; ``root`` the mount with the cpu controller; ``acct`` (v1) where the CPU time
    is counted: ``root`` itself when ``cpuacct`` is mounted with ``cpu``, another mount when apart,
    None when there is none."""

    version: int
    root: Path
    acct: Path | None = None

    @property
    def label(self) -> str:
        return f"cgroup v{self.version} ({self.root})"


def _mounts(text: str) -> list[tuple[str, str, set[str]]]:
    out = []
    for line in text.splitlines():
        parts = line.split()
        if len(parts) >= 4:
            out.append((parts[1].replace("\\040", " "), parts[2], set(parts[3].split(","))))
    return out


def find_hierarchy(mounts: str, *, controllers=lambda root: (root / "cgroup.controllers").read_text()) \
        -> tuple[Hierarchy | None, str]:
    """The hierarchy to make budgets in, from the text of ``/proc/mounts``; or None and why, in words.

    ``controllers(root)`` reads a v2 mount's ``cgroup.controllers`` (a parameter, so that a test can
    stand a directory in for the hierarchy). A v1 ``cpu`` mount wins: where a host has one, the cpu
    controller is bound to it and no v2 mount can have it."""
    table = _mounts(mounts)
    v1 = [(Path(m), opts) for m, fs, opts in table if fs == "cgroup" and "cpu" in opts]
    if v1:
        root, opts = v1[0]
        if "cpuacct" in opts:
            acct = root
        else:
            apart = [Path(m) for m, fs, o in table if fs == "cgroup" and "cpuacct" in o]
            acct = apart[0] if apart else None
        return Hierarchy(1, root, acct), ""
    v2 = [Path(m) for m, fs, _ in table if fs == "cgroup2"]
    for root in v2:
        try:
            if "cpu" in controllers(root).split():
                return Hierarchy(2, root), ""
        except OSError:
            continue
    if v2:
        return None, (f"the cgroup v2 hierarchy at {v2[0]} has no cpu controller (it is bound elsewhere, "
                      "or not delegated to this container)")
    return None, "this host has no cgroup cpu controller mounted (neither cgroup v1 cpu nor cgroup v2)"


def group_name(kind: str, pid: int, n: int) -> str:
    """The name of a budget's group: ``shadowless-<kind>-<pid>-<n>``."""
    if not _KIND.match(kind):
        raise CpuBudgetError(f"a CPU budget's kind is a short lower-case word, got {kind!r}")
    return f"{PREFIX}{kind}-{pid}-{n}"


def leftover_groups(names, alive) -> list[str]:
    """Of the directory ``names`` of a hierarchy's root, the groups of runs that are gone: the
    project's names whose pid ``alive(pid)`` says no longer runs."""
    out = []
    for name in names:
        m = _NAME.match(name)
        if m and not alive(int(m.group(2))):
            out.append(name)
    return sorted(out)


def _quota(fraction: float | None, period_us: int) -> int | None:
    return None if fraction is None else int(round(fraction * period_us))


def v1_files(fraction: float | None, period_us: int, weight: int | None = None,
             burst_us: int | None = None) -> dict[str, str]:
    """What a v1 group's files are set to, in order: the period, then the quota (-1: no limit), with
    ``burst_us`` (and a limit) ``cpu.cfs_burst_us``, and with ``weight`` (v2's scale, 1..10000, 100
    the kernel's default) ``cpu.shares`` (1024 the default)."""
    q = _quota(fraction, period_us)
    out = {"cpu.cfs_period_us": str(period_us), "cpu.cfs_quota_us": str(-1 if q is None else q)}
    if burst_us and q is not None:
        out["cpu.cfs_burst_us"] = str(min(int(burst_us), q))
    if weight is not None:
        out["cpu.shares"] = str(max(2, round(weight * 1024 / 100)))
    return out


def v2_files(fraction: float | None, period_us: int, weight: int | None = None,
             burst_us: int | None = None) -> dict[str, str]:
    """What a v2 group's ``cpu.max`` is set to: ``"QUOTA PERIOD"``, or ``"max PERIOD"`` for no limit;
    with ``burst_us`` (and a limit) its ``cpu.max.burst``, and its ``cpu.weight`` with ``weight``."""
    q = _quota(fraction, period_us)
    out = {"cpu.max": f"{'max' if q is None else q} {period_us}"}
    if burst_us and q is not None:
        out["cpu.max.burst"] = str(min(int(burst_us), q))
    if weight:
        out["cpu.weight"] = str(weight)
    return out


def enable_cpu(subtree_control: str) -> str | None:
    """What to write to a v2 ``cgroup.subtree_control`` so its children have the cpu controller (None:
    it is enabled already)."""
    return None if "cpu" in subtree_control.split() else "+cpu"


def parse_cpu_stat(text: str, version: int, usage_ns: int | None = None) -> dict:
    """A group's ``cpu.stat`` as figures: ``periods``, ``throttled`` (periods held back),
    ``throttled_s``, ``cpu_s`` (v2: its ``usage_usec``; v1: ``usage_ns`` from ``cpuacct.usage``),
    and where the kernel counts CFS bursts, ``bursts`` (periods that spent saved quota) and ``burst_s``."""
    st: dict[str, int] = {}
    for line in text.splitlines():
        parts = line.split()
        if len(parts) == 2 and parts[1].lstrip("-").isdigit():
            st[parts[0]] = int(parts[1])
    out: dict = {"periods": st.get("nr_periods", 0), "throttled": st.get("nr_throttled", 0)}
    if "nr_bursts" in st:
        out["bursts"] = st["nr_bursts"]
        burst = st.get("burst_usec", 0) * 1000 if version == 2 else st.get("burst_time", 0)
        out["burst_s"] = round(burst / 1e9, 3)
    if version == 2:
        out["throttled_s"] = round(st.get("throttled_usec", 0) / 1e6, 3)
        if "usage_usec" in st:
            out["cpu_s"] = round(st["usage_usec"] / 1e6, 3)
    else:
        out["throttled_s"] = round(st.get("throttled_time", 0) / 1e9, 3)
        if usage_ns is not None:
            out["cpu_s"] = round(usage_ns / 1e9, 3)
    return out


# ---------------------------------------------------------------- this host
def host_hierarchy() -> tuple[Hierarchy | None, str]:
    try:
        mounts = Path("/proc/mounts").read_text()
    except OSError as exc:
        return None, f"cannot read /proc/mounts: {exc}"
    return find_hierarchy(mounts)


def unavailable(hierarchy: Hierarchy | None = None) -> str:
    """Why CPU budgets cannot be made here, in one line ("" when they can)."""
    if os.geteuid() != 0:
        return "CPU budgets need root (a cgroup is made per budget): run as root, or without the budget"
    if hierarchy is None:
        hierarchy, why = host_hierarchy()
        if hierarchy is None:
            return f"CPU budgets need a cgroup cpu controller: {why}; run without the budget"
    if hierarchy.version == 1 and not (hierarchy.root / "cpu.cfs_quota_us").exists():
        return f"CPU budgets need CFS bandwidth control (cpu.cfs_quota_us) in {hierarchy.root}; run without the budget"
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


def _write_optional(path: Path, value: object) -> int:
    """Write a number to a cgroup file the kernel may lack (CFS burst came in Linux 5.14): the
    number written, 0 when the file is not there."""
    if not path.exists():
        return 0
    _write(path, value)
    return int(value)


def _text(path: Path) -> str:
    """A cgroup file's text ("" when the file is not there)."""
    try:
        return path.read_text()
    except FileNotFoundError:
        return ""


def _ids(path: Path) -> list[int]:
    try:
        return [int(p) for p in path.read_text().split() if p]
    except (FileNotFoundError, OSError):
        return []


def remove_group(group: Path, root: Path, version: int, *, patience_s: float = 3.0) -> None:
    """Remove a group made here: move everything in ``group`` (and its children, for v2's threaded ones) back to ``root``, then
    remove the children and the group (a group with tasks cannot be removed). A task that is exiting
    holds its group busy for a moment: the removal is tried again for up to ``patience_s``."""
    import time

    deadline = time.monotonic() + patience_s
    while True:
        try:
            _empty_once(group, root, version)
            return
        except OSError as exc:
            if exc.errno != errno.EBUSY or time.monotonic() > deadline:
                raise
            time.sleep(0.05)


def _empty_once(group: Path, root: Path, version: int) -> None:
    if not group.is_dir():
        return
    for _ in range(5):      # a process may fork or make a thread while we move its siblings: go round again
        if version == 1:
            ids, dest = _ids(group / "tasks"), root / "tasks"      # threads one by one: a split process stays split
        else:
            ids, dest = _ids(group / "cgroup.procs"), root / "cgroup.procs"   # v2: whole processes (the subtree's)
        if not ids:
            break
        for i in ids:
            try:
                _write(dest, i)
            except OSError:
                pass        # gone meanwhile
    for child in sorted((d for d in group.iterdir() if d.is_dir()), reverse=True) if version == 2 else []:
        try:
            child.rmdir()
        except FileNotFoundError:
            pass
    try:
        group.rmdir()
    except FileNotFoundError:
        pass


def _roots(hierarchy: Hierarchy) -> list[Path]:
    """Every hierarchy root this module makes groups in (v1: cpu, and cpuacct when apart)."""
    return [hierarchy.root] + ([hierarchy.acct] if hierarchy.acct not in (None, hierarchy.root) else [])


def cleanup_leftovers(hierarchy: Hierarchy | None = None) -> list[str]:
    """Remove the groups of runs that are gone (``shadowless-<kind>-<pid>-<n>`` whose pid no longer
    runs), in every hierarchy budgets are made in; the names removed. What still runs in them (a
    killed run's orphans) moves back to the root group."""
    if hierarchy is None:
        hierarchy, _ = host_hierarchy()
        if hierarchy is None:
            return []
    removed = []
    for root in _roots(hierarchy):
        try:
            names = [d.name for d in root.iterdir() if d.is_dir()]
        except OSError:
            continue
        for name in leftover_groups(names, _pid_alive):
            try:
                remove_group(root / name, root, hierarchy.version)
                removed.append(name if root == hierarchy.root else f"{name} ({root.name})")
            except OSError:
                pass
    return removed


def groups_of(pid: int, tid: int | None = None) -> list[str]:
    """The project's groups a process (or one of its threads) is in now, from ``/proc/PID/cgroup``
    (``/proc/PID/task/TID/cgroup``): their paths under the hierarchy's root, e.g.
    ``/shadowless-node-123-0``."""
    path = Path(f"/proc/{pid}/cgroup") if tid is None else Path(f"/proc/{pid}/task/{tid}/cgroup")
    try:
        lines = path.read_text().splitlines()
    except OSError:
        return []
    return sorted({line.split(":", 2)[2] for line in lines if line.count(":") >= 2 and PREFIX in line})


# ---------------------------------------------------------------- a budget
class CpuBudget:
    """At most ``fraction`` of one core for what is added (see the module docstring).

    Parameters
    ----------
    fraction : float or None
        Of one core, in (0, number of cores]: 0.06 is 6 ms of CPU every 100 ms. None: no limit
        (the group only measures).
    period_us : int
        The CFS period (1 ms .. 1 s). A short period makes a budgeted process wait less at a
        time when its quota runs out (closer to a slower CPU of its own), at some scheduling cost;
        the quota ``fraction * period_us`` must be at least 1 ms.
    name : str
        For messages and reports only (e.g. the slot whose node runs in it).
    kind : str
        In the group's name: what runs in it (``node``, ``gpu``, ``coordinator``, ``bench``).
    threads : bool
        Whether single threads will be added (v2: the threaded layout, see the module docstring).
    thread_fraction : float or None
        With ``threads`` on v2: the limit of the threads' child group (v1: give threads a budget
        of their own instead).
    weight : int or None
        The group's CFS weight against other work when cores are contended, on v2's scale (1..10000;
        None: the kernel's default, 100). A high weight makes a budget closer to a computer of its
        own on a busy host: the group gets its limit whenever it can run (never more).
    burst_us : int or None
        CPU time (us, at most the quota) the group may spend in one period beyond its quota out of
        what it left unused in earlier periods (v1 ``cpu.cfs_burst_us``, v2 ``cpu.max.burst``; None:
        none, the kernel's default). The average stays ``fraction``; a burst lets work that comes
        at once (a frame's decode on two threads) finish as it would on a computer of its own, whose
        cores are not cut into periods. ``burst_granted_us`` says what the kernel took (0: none, a
        kernel without CFS burst).
    realtime_us : int or None
        v1 only: real-time time granted to the group per real-time period (``cpu.rt_runtime_us``,
        the period is the host's ``cpu.rt_period_us``, usually 1 s). A v1 group is made with none,
        so a thread in it cannot take SCHED_FIFO at all: a node's swap window (node/realtime.py)
        is refused and its swap waits behind its own threads. The grant is small (the node sleeps
        to the deadline and swaps in it, it never renders there) and is not part of ``fraction``.
        What the host's real-time budget allows is granted, halving down to 1 ms when the sum over
        sibling groups is full; ``realtime_granted_us`` says what was (0: none; v2 has no
        per-group real-time time, so there it stays 0).
    hierarchy : Hierarchy or None
        Where (default: this host's, :func:`find_hierarchy`).
    """

    def __init__(self, fraction: float | None, *, period_us: int = 100_000, name: str = "", kind: str = "bench",
                 threads: bool = False, thread_fraction: float | None = None, weight: int | None = None,
                 realtime_us: int | None = None, burst_us: int | None = None, hierarchy: Hierarchy | None = None):
        self.fraction = None if fraction is None else _check_fraction(fraction, period_us)
        self.thread_fraction = None if thread_fraction is None else _check_fraction(thread_fraction, period_us)
        if not (MIN_PERIOD_US <= int(period_us) <= MAX_PERIOD_US):
            raise CpuBudgetError(f"a CPU budget's period must be {MIN_PERIOD_US}..{MAX_PERIOD_US} us, got {period_us}")
        self.period_us = int(period_us)
        self.quota_us = _quota(self.fraction, self.period_us)
        if weight is not None and not (isinstance(weight, int) and 1 <= weight <= 10_000):
            raise CpuBudgetError(f"a CPU budget's weight is 1..10000 (100: the kernel's default), got {weight!r}")
        self.weight = weight
        if realtime_us is not None and not (isinstance(realtime_us, int) and MIN_REALTIME_US <= realtime_us <= MAX_REALTIME_US):
            raise CpuBudgetError(f"a CPU budget's real-time grant is {MIN_REALTIME_US}..{MAX_REALTIME_US} us a period, "
                                 f"got {realtime_us!r}")
        self.realtime_us = realtime_us
        self.realtime_granted_us = 0
        if burst_us is not None and not (isinstance(burst_us, int) and burst_us >= 0):
            raise CpuBudgetError(f"a CPU budget's burst is a whole number of us >= 0, got {burst_us!r}")
        self.burst_us = burst_us or None
        self.burst_granted_us = 0
        self.name, self.kind, self.threads = name, kind, bool(threads)
        group_name(kind, 0, 0)                   # the kind is checked now, not when the group is made
        self.hierarchy = hierarchy
        self.path: Path | None = None            # the group (v2 with threads: the domain holding proc/ and thr/)
        self.acct_path: Path | None = None       # v1: the group in a cpuacct hierarchy mounted apart
        self.pids: list[int] = []

    # ------------------------------------------------------------ life
    def __enter__(self) -> "CpuBudget":
        self.open()
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def open(self) -> "CpuBudget":
        """Make the group (after removing crashed runs' leftovers); CpuBudgetError in one line if it cannot."""
        if self.hierarchy is None:
            self.hierarchy, why = host_hierarchy()
            if self.hierarchy is None:
                raise CpuBudgetError(f"CPU budgets need a cgroup cpu controller: {why}")
        why = unavailable(self.hierarchy)
        if why:
            raise CpuBudgetError(why)
        cleanup_leftovers(self.hierarchy)
        h = self.hierarchy
        name = group_name(self.kind, os.getpid(), next(_counter))
        path = h.root / name
        try:
            path.mkdir()
        except OSError as exc:
            raise CpuBudgetError(f"cannot make the cgroup {path}: {exc.strerror or exc}") from None
        self.path = path
        try:
            if h.version == 1:
                for f, v in v1_files(self.fraction, self.period_us, self.weight, self.burst_us).items():
                    if f == "cpu.cfs_burst_us":
                        self.burst_granted_us = _write_optional(path / f, v)
                    else:
                        _write(path / f, v)
                if h.acct is not None and h.acct != h.root:
                    self.acct_path = h.acct / name
                    self.acct_path.mkdir()
                if self.realtime_us:
                    self.realtime_granted_us = grant_realtime(path, self.realtime_us)
            else:
                self._open_v2(path)
        except OSError as exc:
            self.close()
            raise CpuBudgetError(f"cannot set the CPU budget of {path}: {exc.strerror or exc}") from None
        return self

    def _open_v2(self, path: Path) -> None:
        h = self.hierarchy
        want = enable_cpu(_text(h.root / "cgroup.subtree_control"))
        if want:
            _write(h.root / "cgroup.subtree_control", want)
        if not self.threads:
            for f, v in v2_files(self.fraction, self.period_us, self.weight, self.burst_us).items():
                if f == "cpu.max.burst":
                    self.burst_granted_us = _write_optional(path / f, v)
                else:
                    _write(path / f, v)
            return
        if self.weight is not None:          # the subtree competes with its siblings as one
            _write(path / "cpu.weight", self.weight)
        # the threaded layout: children first made threaded, then cpu enabled for them
        for child, fraction in ((V2_PROCS, self.fraction), (V2_THREADS, self.thread_fraction)):
            (path / child).mkdir()
            _write(path / child / "cgroup.type", "threaded")
        want = enable_cpu(_text(path / "cgroup.subtree_control"))
        if want:
            _write(path / "cgroup.subtree_control", want)
        for child, fraction in ((V2_PROCS, self.fraction), (V2_THREADS, self.thread_fraction)):
            for f, v in v2_files(fraction, self.period_us, burst_us=self.burst_us if child == V2_PROCS else None).items():
                if f == "cpu.max.burst":
                    self.burst_granted_us = _write_optional(path / child / f, v)
                else:
                    _write(path / child / f, v)

    def close(self) -> None:
        """Move what is left in the group back to the root group and remove the group (idempotent)."""
        if self.path is not None:
            path, self.path = self.path, None
            remove_group(path, self.hierarchy.root, self.hierarchy.version)
        if self.acct_path is not None:
            path, self.acct_path = self.acct_path, None
            remove_group(path, self.hierarchy.acct, 1)

    # ------------------------------------------------------------ members
    @property
    def _procs_dir(self) -> Path:
        assert self.path is not None
        return self.path / V2_PROCS if self.hierarchy.version == 2 and self.threads else self.path

    def add(self, pid: int, *, children: bool = True) -> None:
        """Put process ``pid`` in the budget: all its threads (``cgroup.procs``) and, with ``children``,
        its descendants now running; processes and threads they start later are in the group from
        birth. CpuBudgetError if the process is gone."""
        if self.path is None:
            raise CpuBudgetError("the CPU budget is not open (use it as a context manager)")
        for p in [pid, *(_descendants(pid) if children else [])]:
            try:
                for d in [self._procs_dir, *([self.acct_path] if self.acct_path is not None else [])]:
                    _write(d / "cgroup.procs", p)
            except (ProcessLookupError, FileNotFoundError):
                if p == pid:
                    raise CpuBudgetError(f"process {pid} is gone; it cannot join the CPU budget") from None
            except OSError as exc:
                if p == pid:
                    raise CpuBudgetError(f"cannot put process {pid} in the CPU budget: {exc.strerror or exc}") from None
        self.pids.append(pid)

    def add_thread(self, tid: int, *, into: "CpuBudget | None" = None) -> bool:
        """Put thread ``tid`` (of a process in this budget) in ``into`` (v1: another budget) or in this
        budget's thread group (v2, ``threads=True``); whether it moved (False: the thread is gone)."""
        if self.path is None:
            raise CpuBudgetError("the CPU budget is not open (use it as a context manager)")
        if self.hierarchy.version == 2:
            if not self.threads:
                raise CpuBudgetError("this CPU budget was made without threads=True")
            dirs, f = [self.path / V2_THREADS], "cgroup.threads"
        else:
            target = into if into is not None else self
            dirs = [target.path, *([target.acct_path] if target.acct_path is not None else [])]
            f = "tasks"
        try:
            for d in dirs:
                _write(d / f, tid)
        except (ProcessLookupError, FileNotFoundError):
            return False
        except OSError as exc:
            raise CpuBudgetError(f"cannot put thread {tid} in the CPU budget: {exc.strerror or exc}") from None
        return True

    def threads_in(self, which: str = "threads") -> list[int]:
        """Thread ids in the group now: with v2's threaded layout ``which`` = ``"threads"`` (the
        thread group) or ``"procs"`` (the rest)."""
        if self.path is None:
            return []
        if self.hierarchy.version == 2:
            d = self.path / (V2_THREADS if which == "threads" else V2_PROCS) if self.threads else self.path
            return _ids(d / "cgroup.threads")
        return _ids(self.path / "tasks")

    def members(self) -> list[int]:
        """The process ids in the group now."""
        if self.path is None:
            return []
        return _ids(self.path / "cgroup.procs")

    def limited_stat_path(self) -> Path | None:
        """The ``cpu.stat`` of the group that holds this budget's limit (v2's threaded layout: its
        processes' child, whose ``nr_throttled`` the domain does not count), or None before
        :meth:`open`."""
        if self.path is None:
            return None
        if self.hierarchy.version == 2 and self.threads:
            return self.path / V2_PROCS / "cpu.stat"
        return self.path / "cpu.stat"

    def stats(self, part: str | None = None) -> dict:
        """What the budget did: its limit, CFS periods elapsed, periods in which it was held back
        (``throttled``), the time held back (``throttled_s``) and the CPU time used (``cpu_s``).
        With v2's threaded layout ``part`` = ``"threads"`` reads the thread group's alone,
        ``"procs"`` the rest; None the whole group."""
        if self.path is None:
            return {}
        h = self.hierarchy
        d = self.path
        if h.version == 2 and self.threads and part is not None:
            d = self.path / (V2_THREADS if part == "threads" else V2_PROCS)
        fraction = self.thread_fraction if part == "threads" else self.fraction
        out: dict = {"limit": fraction, "period_ms": self.period_us / 1000}
        if self.realtime_us:
            out["realtime_granted_us"] = self.realtime_granted_us
        if self.burst_us:
            out["burst_us"] = self.burst_granted_us
        try:
            text = (d / "cpu.stat").read_text()
        except OSError:
            return out
        usage = None
        if h.version == 1:
            acct = self.acct_path if self.acct_path is not None else (d if h.acct == h.root else None)
            try:
                usage = int((acct / "cpuacct.usage").read_text()) if acct is not None else None
            except (OSError, ValueError):
                usage = None
        out.update(parse_cpu_stat(text, h.version, usage))
        return out


def grant_realtime(group: Path, want_us: int) -> int:
    """Give a v1 group ``want_us`` of real-time time per real-time period, or the most the host
    allows below it (halving down to :data:`MIN_REALTIME_US`: the kernel refuses a grant that would
    take the sibling groups' sum past their parent's); the time granted, 0 when none could be
    (no ``cpu.rt_runtime_us``: a kernel without real-time group scheduling, or v2)."""
    f = group / "cpu.rt_runtime_us"
    if not f.exists():
        return 0
    us = int(want_us)
    while us >= MIN_REALTIME_US:
        try:
            _write(f, us)
            return us
        except OSError:
            us //= 2
    return 0


def _check_fraction(fraction, period_us: int) -> float:
    cores = os.cpu_count() or 1
    if not (isinstance(fraction, (int, float)) and 0.0 < float(fraction) <= cores):
        raise CpuBudgetError(f"a CPU budget is a fraction of one core in (0, {cores}], got {fraction!r}")
    fraction = float(fraction)
    if fraction < MIN_QUOTA_US / MAX_PERIOD_US:
        raise CpuBudgetError(f"a CPU budget is at least {MIN_QUOTA_US / MAX_PERIOD_US:g} of a core (1 ms a second), "
                             f"got {fraction:g}")
    quota = int(round(fraction * int(period_us)))
    if quota < MIN_QUOTA_US:
        raise CpuBudgetError(f"a budget of {fraction:g} of a core over {int(period_us) / 1000:g} ms is a quota "
                             f"of {quota} us, under the kernel's 1 ms: use a period of at least "
                             f"{math.ceil(MIN_QUOTA_US / fraction / 1000)} ms")
    return fraction


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
        with CpuBudget(fraction, period_us=20_000, name="self-check", kind="check") as budget:
            budget.add(child.pid)
            tick = os.sysconf("SC_CLK_TCK")

            def cpu() -> float:
                fields = Path(f"/proc/{child.pid}/stat").read_text().rsplit(")", 1)[1].split()
                return (int(fields[11]) + int(fields[12])) / tick
            c0, t0 = cpu(), time.monotonic()
            time.sleep(seconds)
            got = (cpu() - c0) / (time.monotonic() - t0)
            return {"cgroup": budget.hierarchy.label, "asked": fraction, "got": round(got, 3), **budget.stats()}
    finally:
        child.kill()
        child.wait()


def main(argv: list[str] | None = None) -> int:
    import argparse
    import json
    import sys

    p = argparse.ArgumentParser(prog="python -m shadowless.cpu_budget",
                                description="CPU budgets (one cgroup each, v1 or v2): check that they hold here, "
                                            "or remove the groups crashed runs left.")
    sub = p.add_subparsers(dest="cmd", required=True)
    c = sub.add_parser("check", help="hold a busy process to FRACTION of a core for 2 s and print what it got (JSON)")
    c.add_argument("fraction", nargs="?", type=float, default=0.1, help="of one core (default 0.1)")
    sub.add_parser("cleanup", help="remove the groups of runs whose process is gone")
    args = p.parse_args(argv)
    why = unavailable()
    if why:
        print(why, file=sys.stderr)
        return 1
    if args.cmd == "cleanup":
        print("removed:", " ".join(cleanup_leftovers()) or "nothing")
        return 0
    try:
        print(json.dumps(_self_check(args.fraction)))
    except CpuBudgetError as exc:
        print(exc, file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
