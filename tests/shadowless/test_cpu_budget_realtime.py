"""A v1 budget group grants real-time time, so that a node's swap window (SCHED_FIFO, node/realtime.py)
works inside its budget: a process moved into a group made without the grant is refused SCHED_FIFO by the
kernel, one moved into a group with it is not. Skips when not root, on v2, or without real-time groups."""
from __future__ import annotations

import subprocess
import sys

import pytest
from procs import stop

from shadowless.cpu_budget import NODE_REALTIME_US, CpuBudget, host_hierarchy, unavailable

# waits for one line, then tries SCHED_FIFO for itself and says what the kernel answered
CHILD = """
import os, sys
sys.stdin.readline()
try:
    os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(10))
    os.sched_setscheduler(0, os.SCHED_OTHER, os.sched_param(0))
    print("fifo", flush=True)
except OSError as exc:
    print("refused", exc.errno, flush=True)
"""


def _fifo_in(budget: CpuBudget) -> str:
    proc = subprocess.Popen([sys.executable, "-c", CHILD], stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True)
    try:
        budget.add(proc.pid, children=False)
        out, _ = proc.communicate("go\n", timeout=60)
        return out.strip()
    finally:
        stop(proc)


def test_a_node_group_with_the_grant_lets_its_swap_window_take_fifo_and_one_without_does_not():
    why = unavailable()
    hierarchy, _ = host_hierarchy()
    if why or hierarchy.version != 1 or not (hierarchy.root / "cpu.rt_runtime_us").exists():
        pytest.skip(why or "real-time group scheduling needs cgroup v1's cpu.rt_runtime_us")
    with CpuBudget(0.2, kind="node", realtime_us=NODE_REALTIME_US) as granted, CpuBudget(0.2, kind="node") as plain:
        assert granted.realtime_granted_us == NODE_REALTIME_US
        assert int((granted.path / "cpu.rt_runtime_us").read_text()) == NODE_REALTIME_US
        assert granted.stats()["realtime_granted_us"] == NODE_REALTIME_US
        assert plain.realtime_granted_us == 0
        assert _fifo_in(granted) == "fifo"
        assert _fifo_in(plain).startswith("refused")
        paths = [granted.path, plain.path]
    assert not any(p.exists() for p in paths), "both groups are removed"


def test_a_grant_outside_its_range_is_refused_in_one_line():
    from shadowless.cpu_budget import CpuBudgetError
    with pytest.raises(CpuBudgetError, match="real-time grant"):
        CpuBudget(0.2, kind="node", realtime_us=10)
