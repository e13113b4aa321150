"""`shadowless bench startup`: real coordinator and node processes started on a temporary rig; the JSON
gives each kind's CPU per start, and a bad --kinds is refused in one line."""
from __future__ import annotations

import json
import subprocess
import sys


def bench(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "shadowless", "bench", "startup", *args], capture_output=True,
                          text=True, timeout=300)


def test_the_bench_measures_a_coordinators_and_a_nodes_start():
    r = bench("--starts", "1", "--kinds", "coordinator,node")
    assert r.returncode == 0, r.stderr[-2000:]
    out = json.loads(r.stdout)
    assert out["benchmark"] == "startup" and out["starts"] == 1 and "coordinator_full" not in out
    for kind in ("coordinator", "node"):
        starts = out[kind]["now"]["starts_cpu_s"]
        # a Python interpreter with numpy and grpc cannot start on nothing: a CPU of 0 means nothing was read
        assert len(starts) == 1 and starts[0] > 0.05, out[kind]


def test_an_unknown_kind_is_refused_in_one_line():
    r = bench("--kinds", "coordinator,gpu")
    assert r.returncode != 0
    assert "gpu is not one of coordinator, coordinator_full, node" in r.stderr
    assert "Traceback" not in r.stderr
