"""`shadowless local --node-cpu`: a real local rig of two node processes, each held in a CPU budget
group of its own while it runs (read from /proc/PID/cgroup: the node, its presenter, and the
rasterizer's thread moved into the node's rasterizer group), the budget in the summary, and no
group left once the rig stops. Skips when not root or the host has no cgroup cpu controller."""
from __future__ import annotations

import re
import signal
import subprocess
import sys

import psutil
import pytest
from procs import stop
from waits import wait_until

from shadowless.cpu_budget import groups_of, host_hierarchy, unavailable
from shadowless.rig_budget import rasterizer_threads


def test_local_holds_each_node_in_its_group_and_removes_every_group(tmp_path):
    why = unavailable()
    if why:
        pytest.skip(why)
    hierarchy, _ = host_hierarchy()
    err = tmp_path / "stderr.txt"
    with open(err, "wb") as f:
        proc = subprocess.Popen([sys.executable, "-m", "shadowless", "local", "--nodes", "2", "--size", "64x36",
                                 "--seconds", "0.2", "--fps", "10", "--hold", "--node-cpu", "0.5"],
                                stdout=subprocess.PIPE, stderr=f, text=True)
    children = []
    try:
        text = wait_until(lambda: err.read_text(), lambda t: "stays up until Ctrl-C" in t or proc.poll() is not None,
                          what="the rig held up", timeout=180)
        assert proc.poll() is None, text
        children = psutil.Process(proc.pid).children(recursive=True)
        nodes = {re.search(r"--slot (\S+)", " ".join(c.cmdline())).group(1): c for c in children
                 if " node " in f" {' '.join(c.cmdline())} "}
        assert set(nodes) == {"r0c0", "r0c1"}, [c.cmdline() for c in children]
        prefix = f"/shadowless-node-{proc.pid}-"
        seen = {}
        for slot, node in nodes.items():
            group = groups_of(node.pid)
            assert len(group) == 1 and group[0].startswith(prefix), (slot, group)
            seen[slot] = group[0]
            for kid in node.children(recursive=True):          # its presenter, born in the group
                assert groups_of(kid.pid) == group, (slot, kid.cmdline())
        assert seen["r0c0"] != seen["r0c1"]                      # a group each
        # the rasterizer's thread (llvmpipe-0, in the presenter) is moved to the node's rasterizer group
        for slot, node in nodes.items():
            def placed(node=node):
                tids = [(p.pid, t) for p in [node, *node.children(recursive=True)] for t in rasterizer_threads(p.pid)]
                return [groups_of(pid, tid) for pid, tid in tids]
            got = wait_until(placed, lambda g: g and all(x and x[0].startswith(f"/shadowless-gpu-{proc.pid}-")
                                                          for x in g),
                             what=f"node {slot}'s rasterizer thread in its rasterizer group")
            assert len({x[0] for x in got}) == 1
        proc.send_signal(signal.SIGINT)
        out, _ = proc.communicate(timeout=120)
        assert proc.returncode == 0, err.read_text()
    finally:
        stop(proc)
    gone, alive = psutil.wait_procs(children, timeout=30)
    assert not alive, alive
    assert re.search(r"CPU budget \(cgroup v\d .*\): 2 nodes at 0\.5 of a core each took [\d.]+ s of CPU", out), out
    assert "rasterizer threads in a group of their own per node, without a limit" in out
    roots = {hierarchy.root, hierarchy.acct} - {None}
    assert not [d.name for r in roots for d in r.iterdir() if f"-{proc.pid}-" in d.name], "every group is removed"
