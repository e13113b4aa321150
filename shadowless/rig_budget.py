"""CPU budgets for a rig's processes: each node held to a small computer's share of a core, its
rasterizer's threads (llvmpipe, the GPU's stand-in here) in a group of their own, the coordinator
and the process that runs the rig each in theirs (:mod:`shadowless.cpu_budget` makes the groups).

A node's budget emulates a small computer's CPU, not its GPU: on a Raspberry Pi the GPU draws, so
the threads that draw here (llvmpipe's ``llvmpipe-N``, found in ``/proc/PID/task/TID/comm``) are
split off into a per-node rasterizer group, without a limit unless one is asked (``gpu=G``), or
left in the node's budget (``gpu="node"``: a board that draws on its CPU). Those threads appear
only once the node's presenter made its GL context, so :class:`RigBudgets` looks for them in a
short bounded poll after each node starts or restarts (:data:`THREAD_POLL_S`, until none has
appeared for :data:`THREAD_SETTLE_S`) and moves each it finds.

A budget caps, it does not reserve: on a host busy with other work a node gets less than its
share and its late frames measure that work. ``reserve=True`` gives the budget groups a high CFS
weight, so they get their limits whenever they can run (never more) and the other work waits.

**The nodes come first.** On a real rig no node shares a CPU with the coordinator or with another
node; here they share two cores, and someone waits when all want to run at once. A node's groups
(its budget and its rasterizer's) get ten times the coordinator's CFS weight
(:data:`NODE_WEIGHT` against the kernel's 100; with ``reserve``, :data:`RESERVE_WEIGHT` against
:data:`COORDINATOR_RESERVE_WEIGHT`), so that the coordinator gets what the nodes leave, as its
default share (:func:`coordinator_default`) already says, and a restarted coordinator's start-up
(about 1 s of CPU, mostly imports) does not make the nodes' frames late: it takes longer instead,
which the figures show (``back_s``). The nodes cannot take more than their limits for it.

**Bursts.** A quota per period (0.4 of a core over 10 ms: 4 ms) cuts work that comes at once into
pieces: a frame's decode on two slice threads spends the quota in 2 ms and the frame's render
then waits 8 ms for the next period, which a small computer of its own, whose cores are not cut
into periods, never does. Each node's group may therefore spend, in one period, up to ``burst``
of its quota more out of what it left unused before (CFS burst: v1 ``cpu.cfs_burst_us``, v2
``cpu.max.burst``; 1.0 by default, the most the kernel allows); its average stays its limit.

With llvmpipe's threads turned off (``LP_NUM_THREADS=0``) the drawing runs on the presenter's own
thread and cannot be split; :func:`rasterizer_refusal` says so. In cgroup v2 a split node is a
threaded subtree (see :mod:`shadowless.cpu_budget`); where the host refuses threaded groups the
rasterizer stays in the node's budget and :attr:`RigBudgets.rasterizer` says why, in one line.
"""
from __future__ import annotations

import os
import sys
import threading
import time
from pathlib import Path

from shadowless.cpu_budget import NODE_REALTIME_US, CpuBudget, CpuBudgetError, Hierarchy, host_hierarchy, unavailable

__all__ = ["COORDINATOR_RESERVE_WEIGHT", "DEFAULT_BURST", "DEFAULT_PERIOD_MS", "NODE_WEIGHT", "RESERVE_WEIGHT",
           "RigBudgets", "coordinator_default", "parse_gpu", "rasterizer_refusal", "rasterizer_threads"]

#: the CFS period of every group: short, so a held node waits at most a few ms at a time (closer
#: to a slower CPU of its own than 100 ms on, 150 ms off would be)
DEFAULT_PERIOD_MS = 10.0
#: after a node (re)starts, look for its rasterizer threads this long at most ...
THREAD_POLL_S = 60.0
#: ... and stop once none appeared for this long after the first
THREAD_SETTLE_S = 3.0
POLL_INTERVAL_S = 0.1
#: the CFS weight of a node's groups (its budget, its rasterizer's), v2's scale (the kernel's default
#: is 100, the coordinator's): the nodes come first
NODE_WEIGHT = 1_000
#: with ``reserve``: the nodes' groups' weight, and the coordinator's (still a tenth of the nodes')
RESERVE_WEIGHT = 10_000
COORDINATOR_RESERVE_WEIGHT = 1_000
#: a node's CFS burst by default, as a fraction of its quota per period (1.0: the kernel's most)
DEFAULT_BURST = 1.0
RASTERIZER_PREFIX = "llvmpipe-"


def parse_gpu(text: str) -> float | str | None:
    """``--node-gpu``: a fraction of a core, ``max`` (None: a group of its own, no limit), or ``node``
    (the rasterizer stays in the node's budget). ValueError in words otherwise."""
    t = str(text).strip().lower()
    if t in ("max", "none", "unlimited"):
        return None
    if t == "node":
        return "node"
    try:
        v = float(t)
    except ValueError:
        raise ValueError(f"--node-gpu is a fraction of a core, 'max' or 'node', got {text!r}") from None
    if not (v > 0):
        raise ValueError(f"--node-gpu must be > 0, got {text!r}")
    return v


def coordinator_default(nodes: int, node_cpu: float, node_gpu: float | str | None, cores: int | None = None) -> float:
    """The coordinator's share by default: what is left of the machine's cores after the nodes' budgets
    (their rasterizers' too, when those have a limit), at least 0.5 of a core."""
    cores = cores or os.cpu_count() or 1
    per_node = node_cpu + (node_gpu if isinstance(node_gpu, float) else 0.0)
    return round(max(0.5, cores - nodes * per_node), 3)


def rasterizer_refusal(env: dict | None = None) -> str:
    """Why rasterizer threads cannot be split off here, in one line ("" when they can)."""
    env = os.environ if env is None else env
    if env.get("LP_NUM_THREADS", "1").strip() == "0":
        return ("the rasterizer's threads cannot be split off from the nodes: LP_NUM_THREADS=0 makes llvmpipe draw "
                "on the presenter's own thread; unset it, or give --node-gpu node")
    return ""


def rasterizer_threads(pid: int) -> list[int]:
    """Thread ids of process ``pid`` named ``llvmpipe-N`` (the rasterizer's threads) now."""
    out = []
    try:
        tasks = list(Path(f"/proc/{pid}/task").iterdir())
    except OSError:
        return out
    for t in tasks:
        try:
            if (t / "comm").read_text().startswith(RASTERIZER_PREFIX):
                out.append(int(t.name))
        except (OSError, ValueError):
            continue
    return sorted(out)


class _Node:
    """One node's groups: its budget and (v1) its rasterizer's group; the threads placed so far."""

    def __init__(self, cpu: CpuBudget, gpu: CpuBudget | None):
        self.cpu, self.gpu = cpu, gpu
        self.placed: set[int] = set()
        self.deadline = 0.0
        self.last_new = 0.0
        self.polls = 0


class RigBudgets:
    """The groups of one rig run. Use as a context manager (every group is removed on leaving, also on
    an error); :meth:`place` puts a process just started in its group (the rig calls it for every
    start and restart, see ``LocalRig(budgets=...)``).

    Parameters
    ----------
    slots : list of str
        One node group each.
    node_cpu : float
        Each node's share of a core.
    node_gpu : float, None or "node"
        Each node's rasterizer threads: their own group held to this share, their own group with no
        limit (None), or left in the node's budget ("node").
    coordinator_cpu : float, None or False
        The coordinator's group: this share, no limit (None), or no group at all (False).
    own : bool
        Put this process (the one running the rig) in a group of its own without a limit, to measure it.
    period_ms : float
        The CFS period of every group.
    burst : float
        Each node's CFS burst as a fraction of its quota per period (0..1; 0: none), see above.
    reserve : bool
        Give the nodes' and rasterizers' groups :data:`RESERVE_WEIGHT` and the coordinator's
        :data:`COORDINATOR_RESERVE_WEIGHT` (not the kernel's 100 and :data:`NODE_WEIGHT`), so that other
        work on the host does not starve them: each gets its limit whenever it can run, never more
        (a computer of its own is not shared; on a quiet host this changes nothing).
    """

    def __init__(self, slots: list[str], *, node_cpu: float, node_gpu: float | str | None = None,
                 coordinator_cpu: float | None | bool = False, own: bool = False,
                 period_ms: float = DEFAULT_PERIOD_MS, reserve: bool = False, burst: float = DEFAULT_BURST,
                 hierarchy: Hierarchy | None = None):
        if not (isinstance(burst, (int, float)) and 0.0 <= burst <= 1.0):
            raise CpuBudgetError(f"a node's CFS burst is a fraction of its quota, 0..1, got {burst!r}")
        self.slots = list(slots)
        self.burst = float(burst)
        self.node_cpu, self.node_gpu = node_cpu, node_gpu
        self.coordinator_cpu, self.own = coordinator_cpu, own
        self.period_us = int(round(period_ms * 1000))
        self.reserve = reserve
        self.hierarchy = hierarchy
        self.nodes: dict[str, _Node] = {}
        self.coordinator: CpuBudget | None = None
        self.bench: CpuBudget | None = None
        self.split = node_gpu != "node"
        self.rasterizer = ""            # what became of the rasterizer's threads, in words
        self._budgets: list[CpuBudget] = []
        self._lock = threading.Lock()
        self._wake = threading.Event()
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self.errors: list[str] = []

    # ------------------------------------------------------------ life
    def __enter__(self) -> "RigBudgets":
        self.open()
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def check(self) -> str:
        """Why these budgets cannot be made here, in one line ("" when they can): run before anything starts."""
        if self.hierarchy is None:
            self.hierarchy, why = host_hierarchy()
            if self.hierarchy is None:
                return f"CPU budgets need a cgroup cpu controller: {why}"
        why = unavailable(self.hierarchy)
        if why:
            return why
        if self.split:
            why = rasterizer_refusal()
            if why:
                return why
        try:        # every share and the period are checked by making (not opening) each budget
            CpuBudget(self.node_cpu, period_us=self.period_us, kind="node")
            if isinstance(self.node_gpu, float):
                CpuBudget(self.node_gpu, period_us=self.period_us, kind="gpu")
            if self.coordinator_cpu not in (False, None):
                CpuBudget(self.coordinator_cpu, period_us=self.period_us, kind="coordinator")
        except CpuBudgetError as exc:
            return str(exc)
        return ""

    def open(self) -> "RigBudgets":
        """Make every group; CpuBudgetError in one line (nothing left made) if one cannot be."""
        why = self.check()
        if why:
            raise CpuBudgetError(why)
        gpu = self.node_gpu if isinstance(self.node_gpu, float) else None
        try:
            if self.own:
                self.bench = self._make(None, "bench", "bench")
                self.bench.add(os.getpid(), children=False)
            if self.coordinator_cpu is not False:
                self.coordinator = self._make(self.coordinator_cpu, "coordinator", "coordinator",
                                              weight=self.coordinator_weight)
            for s in self.slots:
                self.nodes[s] = self._node(s, gpu)
        except BaseException:
            self.close()
            raise
        if not self.split:
            self.rasterizer = "in the node's budget (--node-gpu node)"
        elif not self.rasterizer:
            self.rasterizer = (f"in a group of their own per node, held to {gpu:g} of a core" if gpu is not None
                               else "in a group of their own per node, without a limit")
        return self

    def _make(self, fraction, kind: str, name: str, **kw) -> CpuBudget:
        b = CpuBudget(fraction, period_us=self.period_us, name=name, kind=kind, hierarchy=self.hierarchy, **kw)
        b.open()
        self._budgets.append(b)
        return b

    @property
    def node_weight(self) -> int:
        """The CFS weight of a node's groups (v2's scale)."""
        return RESERVE_WEIGHT if self.reserve else NODE_WEIGHT

    @property
    def coordinator_weight(self) -> int | None:
        """The coordinator's CFS weight (None: the kernel's default, 100)."""
        return COORDINATOR_RESERVE_WEIGHT if self.reserve else None

    @property
    def burst_us(self) -> int | None:
        """A node's CFS burst (us a period; None: none)."""
        us = int(round(self.burst * self.node_cpu * self.period_us))
        return us or None

    def _node(self, slot: str, gpu: float | None) -> _Node:
        w = self.node_weight
        b = self.burst_us
        if self.hierarchy.version == 1:      # the node's swap window may take SCHED_FIFO, as on a computer of its own
            node = self._make(self.node_cpu, "node", slot, weight=w, realtime_us=NODE_REALTIME_US, burst_us=b)
            return _Node(node, self._make(gpu, "gpu", slot, weight=w) if self.split else None)
        if not self.split:
            return _Node(self._make(self.node_cpu, "node", slot, weight=w, burst_us=b), None)
        try:        # v2: one threaded subtree per node
            return _Node(self._make(self.node_cpu, "node", slot, threads=True, thread_fraction=gpu, weight=w,
                                    burst_us=b), None)
        except CpuBudgetError as exc:
            self.split = False
            self.rasterizer = (f"in the node's budget: this host refuses cgroup v2 threaded groups ({exc}); "
                               "the rasterizer's CPU counts as the node's")
            return _Node(self._make(self.node_cpu, "node", slot, weight=w, burst_us=b), None)

    def close(self) -> None:
        """Stop looking for threads; move everything back to the root group and remove every group (idempotent)."""
        self._stop.set()
        self._wake.set()
        if self._thread is not None and self._thread is not threading.current_thread():
            self._thread.join(timeout=5)
        self._thread = None
        for b in reversed(self._budgets):
            try:
                b.close()
            except OSError as exc:
                line = (f"cannot remove the CPU budget group of {b.kind} {b.name}: {exc.strerror or exc} "
                        "(`python -m shadowless.cpu_budget cleanup` removes it once this process is gone)")
                self.errors.append(line)
                print(line, file=sys.stderr, flush=True)
        self._budgets.clear()

    # ------------------------------------------------------------ processes
    def place(self, name: str, pid: int) -> None:
        """Put process ``pid`` just started in its group: ``name`` is ``coordinator`` or a slot. A
        node's rasterizer threads are then looked for (a bounded poll) and moved as they appear."""
        if name == "coordinator":
            if self.coordinator is not None:
                self._add(self.coordinator, pid, name)
            return
        node = self.nodes.get(name)
        if node is None:
            return
        self._add(node.cpu, pid, f"node {name}")
        if self.split:
            with self._lock:
                now = time.monotonic()
                node.deadline, node.last_new = now + THREAD_POLL_S, 0.0
                if self._thread is None and not self._stop.is_set():
                    self._thread = threading.Thread(target=self._watch, name="rasterizer-threads", daemon=True)
                    self._thread.start()
            self._wake.set()

    def _add(self, budget: CpuBudget, pid: int, what: str) -> None:
        try:
            budget.add(pid)
        except CpuBudgetError as exc:      # the process died at once: whoever started it sees that
            self.errors.append(f"{what}: {exc}")

    def _watch(self) -> None:
        while not self._stop.is_set():
            now = time.monotonic()
            with self._lock:
                pending = [(s, n) for s, n in self.nodes.items() if n.deadline > now]
            if not pending:
                self._wake.clear()
                self._wake.wait(1.0)
                continue
            for slot, node in pending:
                self._scan(slot, node, now)
            self._stop.wait(POLL_INTERVAL_S)

    def _scan(self, slot: str, node: _Node, now: float) -> None:
        node.polls += 1
        try:
            pids = node.cpu.members()
        except OSError:
            return
        new = 0
        for pid in pids:
            for tid in rasterizer_threads(pid):
                if tid in node.placed:
                    continue
                try:
                    moved = node.cpu.add_thread(tid, into=node.gpu)
                except CpuBudgetError as exc:
                    self.errors.append(f"node {slot}: {exc}")
                    moved = False
                if moved:
                    node.placed.add(tid)
                    new += 1
        with self._lock:
            if new:
                node.last_new = now
            if node.last_new and now - node.last_new > THREAD_SETTLE_S:
                node.deadline = 0.0         # settled: stop looking until the node starts again

    def rasterizer_placed(self, slot: str) -> list[int]:
        """Thread ids of ``slot``'s rasterizer in its rasterizer group now."""
        node = self.nodes.get(slot)
        if node is None or not self.split:
            return []
        if node.gpu is not None:
            return node.gpu.threads_in()
        return node.cpu.threads_in("threads")

    # ------------------------------------------------------------ figures
    def stats(self) -> dict:
        """Each group's limit, CPU time used and time held back so far (s), by name."""
        out: dict = {}
        if self.bench is not None:
            out["bench"] = self.bench.stats()
        if self.coordinator is not None:
            out["coordinator"] = self.coordinator.stats()
        for s, n in self.nodes.items():
            if n.gpu is not None:                       # v1: two groups
                out[f"node {s}"] = n.cpu.stats()
                out[f"rasterizer {s}"] = {**n.gpu.stats(), "threads": len(n.placed)}
            elif self.split:                            # v2: one threaded subtree
                out[f"node {s}"] = n.cpu.stats("procs")
                out[f"rasterizer {s}"] = {**n.cpu.stats("threads"), "threads": len(n.placed)}
            else:
                out[f"node {s}"] = n.cpu.stats()
        return out

    def describe(self) -> dict:
        """What was made, for a JSON document: the cgroup, the period, the limits, the rasterizer's place."""
        return {"cgroup": self.hierarchy.label if self.hierarchy else None, "period_ms": self.period_us / 1000,
                "node_cpu_limit": self.node_cpu,
                "node_gpu_limit": self.node_gpu if isinstance(self.node_gpu, float) else
                ("node" if self.node_gpu == "node" else None),
                "coordinator_cpu_limit": None if self.coordinator_cpu is False else self.coordinator_cpu,
                "rasterizer": self.rasterizer, "reserve_weight": RESERVE_WEIGHT if self.reserve else None,
                "node_weight": self.node_weight, "coordinator_weight": self.coordinator_weight,
                "node_burst_us": self.burst_granted(),
                "node_realtime_us": self.realtime_granted(),
                **({"errors": self.errors} if self.errors else {})}

    def burst_granted(self) -> dict[str, int]:
        """Per slot, the CFS burst its node's group was given (us a period; 0: none, or a kernel without it)."""
        return {s: n.cpu.burst_granted_us for s, n in self.nodes.items()}

    def realtime_granted(self) -> dict[str, int]:
        """Per slot, the real-time time its node's group was granted per real-time period (us; 0: none, so
        the node's swap window runs at normal priority and says so in its log)."""
        return {s: n.cpu.realtime_granted_us for s, n in self.nodes.items()}

    def summary(self) -> str:
        """One line for an operator: the budget and what the groups took so far."""
        st = self.stats()
        cpu = sum(v.get("cpu_s", 0.0) for k, v in st.items() if k.startswith("node "))
        held = sum(v.get("throttled_s", 0.0) for k, v in st.items() if k.startswith("node "))
        ras = sum(v.get("cpu_s", 0.0) for k, v in st.items() if k.startswith("rasterizer "))
        n = len(self.nodes)
        text = (f"CPU budget ({self.hierarchy.label}): {n} node{'s' if n != 1 else ''} at {self.node_cpu:g} of a core "
                f"each took {cpu:.1f} s of CPU, held back {held:.1f} s; rasterizer threads {self.rasterizer}")
        if self.split:
            text += f", took {ras:.1f} s"
        rt = self.realtime_granted()
        if self.hierarchy is not None and self.hierarchy.version == 1 and rt:
            short = sum(1 for v in rt.values() if not v)
            text += ("; swaps at real-time priority" if not short else
                     f"; {short} of {n} nodes swap at normal priority (the host's real-time time is used up)")
        return text
