"""`bench uniformity`'s CPU accounting of a failover: a real child process that burns CPU between two
snapshots is counted in its group, and its presenter-like grandchild is found as its child; an idle one
counts (almost) nothing."""
from __future__ import annotations

import os
import signal
import subprocess
import sys
import time

import pytest

from bench.uniformity_cpu import CpuSnapshot, children_of
from tests.support.waits import wait_until

pytestmark = pytest.mark.skipif(not sys.platform.startswith("linux"), reason="reads /proc")

#: a child that starts a grandchild, then burns CPU each time a line reaches its stdin
_PARENT = """
import subprocess, sys, time
child = subprocess.Popen([sys.executable, "-c", "import time; print('up', flush=True); time.sleep(60)"],
                         stdout=subprocess.PIPE, text=True)
child.stdout.readline()                # started: it only sleeps from now on
print(child.pid, flush=True)
for line in sys.stdin:
    t = time.process_time()
    while time.process_time() - t < 0.2:
        pass
    print("done", flush=True)
"""


def test_a_busy_process_counts_in_its_group_and_an_idle_one_does_not():
    busy = subprocess.Popen([sys.executable, "-c", _PARENT], stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True)
    idle = subprocess.Popen([sys.executable, "-c", "import time; print('up', flush=True); time.sleep(60)"],
                            stdout=subprocess.PIPE, text=True)
    grandchild = 0
    try:
        idle.stdout.readline()
        grandchild = int(busy.stdout.readline())
        kids = wait_until(lambda: children_of(busy.pid), lambda k: grandchild in k, what="the grandchild listed")
        groups = {"busy": [busy.pid], "idle": [idle.pid], "kids": kids}
        before = CpuSnapshot(groups)
        busy.stdin.write("go\n")
        busy.stdin.flush()
        assert busy.stdout.readline().strip() == "done"
        got = CpuSnapshot(groups).since(before)
        assert got["busy"] >= 150, got         # 200 ms of its own CPU time, read from the kernel's schedstat
        assert got["idle"] < 20 and got["kids"] < 20, got
        assert got["host"] >= got["busy"] - 20, got     # the host's busy time holds it (10 ms ticks)
    finally:
        if grandchild:
            os.kill(grandchild, signal.SIGKILL)
        for p in (busy, idle):
            p.kill()
            p.wait()


def test_threads_of_this_process_are_named():
    before = CpuSnapshot({}, threads_of=os.getpid())
    t = time.process_time()
    while time.process_time() - t < 0.05:
        pass
    got = CpuSnapshot({}, threads_of=os.getpid()).since(before)
    assert sum(got["threads"].values()) >= 40, got
