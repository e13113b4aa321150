"""`shadowless local --nodes 1`, a newcomer's smallest rig, prints its figures in words: with one node
there is no swap skew to measure, and it says so instead of "p50 None ms, p99 None ms, max None ms ()".
A real run: a coordinator and one offscreen node process, a 1 s sequence."""
from __future__ import annotations

import subprocess
import sys


def test_one_node_says_there_is_no_skew_to_measure():
    r = subprocess.run([sys.executable, "-m", "shadowless", "local", "--nodes", "1", "--seconds", "1"],
                       capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stderr
    assert "1 node, 30 frames at 30 fps: shown by all " in r.stdout, r.stdout          # a busy host may miss one
    assert "swap skew: none (one node, nothing to compare); clock error p99 " in r.stdout, r.stdout
    assert "None" not in r.stdout, r.stdout
