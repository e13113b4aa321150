"""CPU budgets' groups (shadowless/cpu_budget.py): which hierarchy a host's mounts give, what a v1
and a v2 group's files are set to, the v2 threaded layout written into a directory standing in for
the hierarchy (this machine has cgroup v1's cpu controller, not v2's), and, for real in the host's
hierarchy, a budget that holds a busy process, splits off one of its threads, measures both, and
is removed; a run killed with SIGKILL leaves groups that the next budget removes; a budget with a
CFS burst spends saved quota at once; a rig's node groups weigh ten times its coordinator's. The
real parts skip when not root or when the host has no cgroup cpu controller."""
from __future__ import annotations

import errno
import os
import signal
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest
from waits import wait_until

from shadowless.cpu_budget import (CpuBudget, CpuBudgetError, Hierarchy, cleanup_leftovers, enable_cpu,
                                   find_hierarchy, group_name, groups_of, host_hierarchy, leftover_groups,
                                   parse_cpu_stat, remove_group, unavailable, v1_files, v2_files)
from shadowless.rig_budget import COORDINATOR_RESERVE_WEIGHT, NODE_WEIGHT, RESERVE_WEIGHT, RigBudgets

HYBRID = """\
cgroup /sys/fs/cgroup/cpu cgroup rw,relatime,cpu 0 0
cgroup /sys/fs/cgroup/cpuacct cgroup rw,relatime,cpuacct 0 0
cgroup2 /sys/fs/cgroup/unified cgroup2 rw,relatime 0 0
"""
COMOUNTED = "cgroup /sys/fs/cgroup/cpu,cpuacct cgroup rw,nosuid,cpu,cpuacct 0 0\n"
V2_ONLY = "cgroup2 /sys/fs/cgroup cgroup2 rw,nosuid,nodev,noexec,relatime,nsdelegate 0 0\n"


def test_the_hierarchy_is_read_from_the_mounts():
    h, why = find_hierarchy(HYBRID, controllers=lambda root: "")
    assert h == Hierarchy(1, Path("/sys/fs/cgroup/cpu"), Path("/sys/fs/cgroup/cpuacct")) and why == ""
    h, _ = find_hierarchy(COMOUNTED)
    assert h == Hierarchy(1, Path("/sys/fs/cgroup/cpu,cpuacct"), Path("/sys/fs/cgroup/cpu,cpuacct"))
    h, _ = find_hierarchy(V2_ONLY, controllers=lambda root: "cpuset cpu io memory pids")
    assert h == Hierarchy(2, Path("/sys/fs/cgroup")) and h.label == "cgroup v2 (/sys/fs/cgroup)"
    h, why = find_hierarchy(V2_ONLY, controllers=lambda root: "memory pids")
    assert h is None and "has no cpu controller" in why and "\n" not in why
    h, why = find_hierarchy("proc /proc proc rw 0 0\n")
    assert h is None and "no cgroup cpu controller" in why


def test_group_files_names_and_stats():
    assert v1_files(0.4, 10_000) == {"cpu.cfs_period_us": "10000", "cpu.cfs_quota_us": "4000"}
    assert v1_files(None, 100_000)["cpu.cfs_quota_us"] == "-1"
    assert v2_files(0.4, 10_000) == {"cpu.max": "4000 10000"} and v2_files(None, 20_000) == {"cpu.max": "max 20000"}
    assert v1_files(0.4, 10_000, weight=10_000)["cpu.shares"] == "102400"          # 100 is 1024 shares
    assert v2_files(0.4, 10_000, weight=10_000) == {"cpu.max": "4000 10000", "cpu.weight": "10000"}
    with pytest.raises(CpuBudgetError, match="weight is 1..10000"):
        CpuBudget(0.4, weight=20_000)
    assert enable_cpu("cpuset io memory") == "+cpu" and enable_cpu("cpu memory") is None
    assert group_name("node", 42, 3) == "shadowless-node-42-3"
    with pytest.raises(CpuBudgetError):
        group_name("Node r0c0", 42, 3)
    alive = {10}.__contains__
    names = ["shadowless-node-10-0", "shadowless-gpu-11-1", "shadowless-bench-12-0", "shadowless-node-x",
             "other-13-0", "shadowless-venue-probe-14-2"]
    assert leftover_groups(names, alive) == ["shadowless-bench-12-0", "shadowless-gpu-11-1",
                                             "shadowless-venue-probe-14-2"]
    v1 = "nr_periods 50\nnr_throttled 7\nthrottled_time 2500000000\nnr_bursts 3\nburst_time 6000000\n"
    assert parse_cpu_stat(v1, 1, usage_ns=1_234_000_000) == {"periods": 50, "throttled": 7, "throttled_s": 2.5,
                                                           "cpu_s": 1.234, "bursts": 3, "burst_s": 0.006}
    v2 = "usage_usec 3000000\nuser_usec 2000000\nsystem_usec 1000000\nnr_periods 9\nnr_throttled 2\nthrottled_usec 40000\n"
    assert parse_cpu_stat(v2, 2) == {"periods": 9, "throttled": 2, "throttled_s": 0.04, "cpu_s": 3.0}
    assert parse_cpu_stat(v2 + "nr_bursts 1\nburst_usec 2500\n", 2)["burst_s"] == 0.003
    # a burst is at most the quota, and only with a limit
    assert v1_files(0.4, 10_000, burst_us=4000)["cpu.cfs_burst_us"] == "4000"
    assert v1_files(0.4, 10_000, burst_us=9000)["cpu.cfs_burst_us"] == "4000"
    assert "cpu.cfs_burst_us" not in v1_files(None, 10_000, burst_us=4000)
    assert list(v1_files(0.4, 10_000, burst_us=4000)) == ["cpu.cfs_period_us", "cpu.cfs_quota_us", "cpu.cfs_burst_us"]
    assert v2_files(0.2, 10_000, burst_us=5000) == {"cpu.max": "2000 10000", "cpu.max.burst": "2000"}
    with pytest.raises(CpuBudgetError, match="burst is a whole number"):
        CpuBudget(0.4, burst_us=-1)
    with pytest.raises(CpuBudgetError, match="under the kernel's 1 ms"):
        CpuBudget(0.05, period_us=10_000)
    with pytest.raises(CpuBudgetError, match="fraction of one core"):
        CpuBudget(0.0)


def _root_only():
    if os.geteuid() != 0:
        pytest.skip("CPU budgets need root")


def test_v2_threaded_layout_in_a_stand_in_hierarchy(tmp_path):
    """What a v2 budget writes where, in order: +cpu in the parent, the threaded children, cpu.max for
    each, processes to proc/, threads to thr/; then what removal moves back and removes."""
    _root_only()
    root = tmp_path / "cg"
    root.mkdir()
    (root / "cgroup.controllers").write_text("cpuset cpu io memory\n")
    (root / "cgroup.subtree_control").write_text("memory\n")
    h, _ = find_hierarchy(f"cgroup2 {root} cgroup2 rw 0 0\n")
    assert h == Hierarchy(2, root)
    plain = CpuBudget(0.3, period_us=20_000, kind="coordinator", hierarchy=h).open()
    split = CpuBudget(0.4, period_us=20_000, kind="node", threads=True, thread_fraction=None, hierarchy=h).open()
    assert (root / "cgroup.subtree_control").read_text() == "+cpu\n"
    assert (plain.path / "cpu.max").read_text() == "6000 20000\n"
    d = split.path
    assert d.name == f"shadowless-node-{os.getpid()}-{d.name.rsplit('-', 1)[1]}"
    assert (d / "cgroup.subtree_control").read_text() == "+cpu\n"
    assert [(d / c / "cgroup.type").read_text() for c in ("proc", "thr")] == ["threaded\n", "threaded\n"]
    assert (d / "proc" / "cpu.max").read_text() == "8000 20000\n" and (d / "thr" / "cpu.max").read_text() == "max 20000\n"
    # the throttle counts that say the limit held the group back are the limited child's
    assert split.limited_stat_path() == d / "proc" / "cpu.stat" and plain.limited_stat_path() == plain.path / "cpu.stat"
    split.add(os.getpid(), children=False)
    assert (d / "proc" / "cgroup.procs").read_text() == f"{os.getpid()}\n"
    assert split.add_thread(1234) and (d / "thr" / "cgroup.threads").read_text() == "1234\n"
    with pytest.raises(CpuBudgetError, match="without threads=True"):
        plain.add_thread(1234)
    # removal: the subtree's processes (the domain's cgroup.procs) back to the root, children first, then
    # the group; a real cgroupfs has no regular files to remove, a stand-in directory does
    (d / "cgroup.procs").write_text("4321\n")
    for g in (d, d / "proc", d / "thr", plain.path):
        for f in g.iterdir():
            if f.is_file() and f.name != "cgroup.procs":
                f.unlink()
    (d / "proc" / "cgroup.procs").unlink()
    (plain.path / "cgroup.procs").unlink(missing_ok=True)
    with pytest.raises(OSError) as exc:        # the domain's own cgroup.procs still stands in it
        split.close()
    assert exc.value.errno == errno.ENOTEMPTY
    assert (root / "cgroup.procs").read_text() == "4321\n"       # moved back to the root group
    assert not (d / "proc").exists() and not (d / "thr").exists()  # children removed before the group
    name = plain.path.name
    plain.close()
    assert not (root / name).exists() and plain.path is None


def _host() -> Hierarchy:
    why = unavailable()
    if why:
        pytest.skip(why)
    h, _ = host_hierarchy()
    return h


def test_a_real_budget_holds_a_process_splits_a_thread_and_is_removed():
    h = _host()
    code = textwrap.dedent("""
        import threading, time
        def spin():
            while True: pass
        t = threading.Thread(target=spin, name="spinner", daemon=True); t.start()
        print(threading.get_native_id(), t.native_id, flush=True)
        spin()
    """)
    proc = subprocess.Popen([sys.executable, "-c", code], stdout=subprocess.PIPE, text=True)
    try:
        main_tid, spin_tid = map(int, proc.stdout.readline().split())
        with CpuBudget(0.2, period_us=10_000, name="test", kind="node", threads=h.version == 2) as node, \
                CpuBudget(0.1, period_us=10_000, name="test", kind="gpu") as gpu:
            node.add(proc.pid)
            assert node.members() == [proc.pid]
            v2 = h.version == 2
            assert groups_of(proc.pid) == [f"/{node.path.name}" + ("/proc" if v2 else "")]
            assert node.add_thread(spin_tid, into=gpu)
            assert groups_of(proc.pid, spin_tid) == [f"/{node.path.name}/thr" if v2 else f"/{gpu.path.name}"]
            assert groups_of(proc.pid, main_tid) == groups_of(proc.pid)        # the other thread stays
            # both groups are held: 0.2 and 0.1 of a core, over enough periods to be throttled
            wait_until(lambda: (node.stats(), gpu.stats()), lambda s: s[0].get("throttled", 0) >= 20
                       and s[1].get("throttled", 0) >= 20, what="both groups throttled")
            if h.version == 1 and h.acct is not None:
                wait_until(lambda: (node.stats(), gpu.stats()), lambda s: s[0]["cpu_s"] > 0 and s[1]["cpu_s"] > 0,
                           what="CPU time counted in both groups")
            paths = [node.path, gpu.path]
        assert all(not p.exists() for p in paths)
        assert groups_of(proc.pid) == [] and groups_of(proc.pid, spin_tid) == []   # moved back, still running
        assert proc.poll() is None
    finally:
        proc.kill()
        proc.wait()


def test_a_killed_runs_groups_are_removed_by_the_next_budget(tmp_path):
    h = _host()
    code = textwrap.dedent("""
        import subprocess, sys, time
        from shadowless.rig_budget import RigBudgets
        b = RigBudgets(["r0c0"], node_cpu=0.5, coordinator_cpu=0.5, own=True).open()
        child = subprocess.Popen([sys.executable, "-c", "import time; time.sleep(600)"])
        b.place("r0c0", child.pid)
        print(child.pid, flush=True)
        time.sleep(600)
    """)
    owner = subprocess.Popen([sys.executable, "-c", code], stdout=subprocess.PIPE, text=True,
                             cwd=Path(__file__).resolve().parents[2])
    child = None
    try:
        child = int(owner.stdout.readline())
        made = [d.name for d in h.root.iterdir() if d.name.startswith("shadowless-") and f"-{owner.pid}-" in d.name]
        assert sorted(n.split("-")[1] for n in made) == ["bench", "coordinator", "gpu", "node"], made
        assert groups_of(child) and groups_of(owner.pid)
        owner.send_signal(signal.SIGKILL)
        owner.wait()
        removed = cleanup_leftovers(h)
        assert set(made) <= {r.split(" ")[0] for r in removed}
        assert not [d for d in h.root.iterdir() if f"-{owner.pid}-" in d.name]
        if h.acct is not None and h.acct != h.root:
            assert not [d for d in h.acct.iterdir() if f"-{owner.pid}-" in d.name]
        assert groups_of(child) == []           # the orphan is back in the root group (its owner's to stop)
    finally:
        if owner.poll() is None:
            owner.kill()
            owner.wait()
        if child is not None:
            try:
                os.kill(child, signal.SIGKILL)
            except ProcessLookupError:
                pass


def test_v2_thread_rules_and_removal_on_the_kernels_cgroup2_mount():
    """The cgroup v2 rules the threaded layout relies on, on this kernel's cgroup2 mount (which has
    no cpu controller on a v1 host, so no limits here): a process written into a threaded child,
    one of its threads into the other child, no thread leaving the subtree alone; then the module's
    removal takes the whole subtree's processes back to the root and removes children and group."""
    _root_only()
    mounts = [line.split() for line in Path("/proc/mounts").read_text().splitlines()]
    v2 = [Path(m[1]) for m in mounts if len(m) > 2 and m[2] == "cgroup2"]
    if not v2:
        pytest.skip("no cgroup2 mount on this host")
    root = v2[0]
    group = root / group_name("probe", os.getpid(), 0)
    code = "import threading, time\nt = threading.Thread(target=time.sleep, args=(600,), daemon=True); t.start()\n" \
           "print(t.native_id, flush=True); time.sleep(600)\n"
    proc = subprocess.Popen([sys.executable, "-c", code], stdout=subprocess.PIPE, text=True)
    try:
        tid = int(proc.stdout.readline())
        group.mkdir()
        for child in ("proc", "thr"):
            (group / child).mkdir()
            (group / child / "cgroup.type").write_text("threaded")
        assert (group / "cgroup.type").read_text().strip() == "domain threaded"
        (group / "proc" / "cgroup.procs").write_text(str(proc.pid))
        (group / "thr" / "cgroup.threads").write_text(str(tid))
        assert groups_of(proc.pid) == [f"/{group.name}/proc"]
        assert groups_of(proc.pid, tid) == [f"/{group.name}/thr"]
        assert (group / "cgroup.procs").read_text().split() == [str(proc.pid)]   # the subtree's processes
        with pytest.raises(OSError) as exc:              # a thread does not leave its threaded subtree alone
            (root / "cgroup.threads").write_text(str(tid))
        assert exc.value.errno == errno.EOPNOTSUPP
        remove_group(group, root, 2)
        assert not group.exists() and groups_of(proc.pid) == [] and groups_of(proc.pid, tid) == []
    finally:
        proc.kill()
        proc.wait()
        if group.exists():
            for child in ("proc", "thr"):
                if (group / child).exists():
                    (group / child).rmdir()
            group.rmdir()


def test_a_real_budgets_burst_lets_work_that_comes_at_once_spend_saved_quota():
    """A process that sleeps, then spins for several ms, in a budget of 0.2 of a core over 10 ms: with
    a burst the kernel lets it spend quota it saved while asleep (``bursts`` counted), and its
    average stays held (throttled too, since each spin is longer than quota and burst together)."""
    h = _host()
    code = textwrap.dedent("""
        import time
        while True:
            time.sleep(0.03)
            t = time.thread_time()
            while time.thread_time() - t < 0.006: pass
    """)
    proc = subprocess.Popen([sys.executable, "-c", code])
    try:
        with CpuBudget(0.2, period_us=10_000, name="test", kind="node", burst_us=2000, hierarchy=h) as b:
            if not b.burst_granted_us:
                pytest.skip("this kernel has no CFS burst (Linux 5.14+)")
            assert b.burst_granted_us == 2000
            b.add(proc.pid)
            st = wait_until(b.stats, lambda s: s.get("bursts", 0) >= 5 and s.get("throttled", 0) >= 5,
                            what="bursts spent and the group still held")
            assert st["burst_us"] == 2000 and st["burst_s"] > 0, st
    finally:
        proc.kill()
        proc.wait()


@pytest.mark.parametrize("reserve", [False, True])
def test_a_rigs_nodes_come_first_and_may_burst(reserve):
    """A rig's groups as made on this host: each node's budget and its rasterizer's group weigh ten
    times the coordinator's (the coordinator gets what the nodes leave, as on separate computers
    nobody waits for another), higher still with ``reserve``; each node's budget may burst by its
    quota, and the document says all of it."""
    h = _host()
    with RigBudgets(["a", "b"], node_cpu=0.4, coordinator_cpu=0.5, own=True, reserve=reserve, hierarchy=h) as rb:
        node_w, coord_w = (RESERVE_WEIGHT, COORDINATOR_RESERVE_WEIGHT) if reserve else (NODE_WEIGHT, 100)
        assert node_w == 10 * coord_w

        def weight(b) -> int:
            if h.version == 2:
                return int((b.path / "cpu.weight").read_text())
            return round(int((b.path / "cpu.shares").read_text()) * 100 / 1024)
        for s in ("a", "b"):
            node = rb.nodes[s]
            assert weight(node.cpu) == node_w
            if node.gpu is not None:
                assert weight(node.gpu) == node_w
        assert weight(rb.coordinator) == coord_w and weight(rb.bench) == 100
        d = rb.describe()
        assert (d["node_weight"], d["coordinator_weight"]) == (node_w, coord_w if reserve else None)
        burst = rb.nodes["a"].cpu.burst_granted_us
        assert d["node_burst_us"] == {"a": burst, "b": burst}
        if burst:
            assert burst == 4000 and rb.stats()["node a"]["burst_us"] == 4000
        assert "burst_us" not in rb.stats()["coordinator"]
    with pytest.raises(CpuBudgetError, match="burst is a fraction"):
        RigBudgets(["a"], node_cpu=0.4, burst=1.5)
    with RigBudgets(["a"], node_cpu=0.4, burst=0, hierarchy=h) as rb:
        assert rb.describe()["node_burst_us"] == {"a": 0}
