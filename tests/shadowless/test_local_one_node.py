"""`shadowless local --nodes 1`, a newcomer's smallest rig, prints its figures in words: with one node
there is no swap skew to measure, and it says so instead of "p50 None ms, p99 None ms, max None ms ()".
What it prints names no path that is gone when the operator reads it: its temporary directory (rig,
token, logs, snapshots) is removed at the end, so a line naming a path in it says so.
A real run: a coordinator and one offscreen node process, a 1 s sequence."""
from __future__ import annotations

import re
import subprocess
import sys
from pathlib import Path

import pytest


@pytest.fixture(scope="module")
def one_node_run() -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "shadowless", "local", "--nodes", "1", "--seconds", "1"],
                          capture_output=True, text=True, timeout=300)


def test_one_node_says_there_is_no_skew_to_measure(one_node_run):
    r = one_node_run
    assert r.returncode == 0, r.stderr
    assert "1 node, 30 frames at 30 fps: shown by all " in r.stdout, r.stdout          # a busy host may miss one
    assert "swap skew: none (one node, nothing to compare); clock error p99 " in r.stdout, r.stdout
    assert "None" not in r.stdout, r.stdout


def test_every_path_it_names_is_still_there_or_said_to_be_removed(one_node_run):
    r = one_node_run
    assert r.returncode == 0, r.stderr
    named = []
    for line in (r.stdout + r.stderr).splitlines():
        for path in re.findall(r"(/[^\s,;:()]+)", line):
            if path.startswith("//") or "127.0.0.1" in path:      # a URL's tail, not a file
                continue
            named.append(path)
            assert Path(path).exists() or "removed" in line, f"{path} is gone, and its line does not say so: {line!r}"
    assert any("shadowless-local-" in p for p in named), (r.stdout, r.stderr)     # the run does name its paths
