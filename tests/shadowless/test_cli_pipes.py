"""Output into a pipe whose reader has gone (`shadowless status | head -1`) ends a command quietly:
exit status 1 and nothing on stderr (no BrokenPipeError traceback), as Python's "Note on
SIGPIPE" advises."""
from __future__ import annotations

import os
import subprocess
import sys

import pytest

from coordinator.rig import grid_slots, init_rig

PY = [sys.executable, "-m", "shadowless"]


def _into_head(argv: list[str]) -> tuple[str, str, int]:
    """``shadowless ARGV | head -1``: (head's output, shadowless's stderr, its exit status)."""
    first = subprocess.Popen([*PY, *argv], stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    head = subprocess.Popen(["head", "-1"], stdin=first.stdout, stdout=subprocess.PIPE)
    first.stdout.close()                  # head holds the only reader
    out, _ = head.communicate(timeout=120)
    err = first.stderr.read()
    first.stderr.close()
    return out.decode(), err.decode(), first.wait(timeout=120)


def _into_closed_pipe(argv: list[str]) -> tuple[str, int]:
    """``shadowless ARGV`` writing into a pipe whose reader is closed before it starts (its first
    write fails, whatever the output's size): (stderr, exit status)."""
    r, w = os.pipe()
    os.close(r)
    try:
        p = subprocess.run([*PY, *argv], stdout=w, stderr=subprocess.PIPE, timeout=120)
    finally:
        os.close(w)
    return p.stderr.decode(), p.returncode


def test_a_long_output_into_head_ends_quietly(tmp_path):
    rig = init_rig(tmp_path / "rig", name="pipes", slots=grid_slots(32, 32), width=32, height=32)
    out, err, code = _into_head(["rig", "show", str(rig)])   # ~200 kB: more than the pipe and head take
    assert out == "{\n"
    assert err == "" and code == 1, (code, err)


@pytest.fixture
def coordinator(tmp_path, coordinator_process):
    rig = init_rig(tmp_path / "rig", name="pipes", slots=["r0c0", "r0c1"], width=32, height=32)
    return ["--coordinator", coordinator_process(rig), "--rig-dir", str(rig)]


def test_status_into_a_closed_pipe_or_head_ends_quietly(coordinator):
    for argv in (["status", *coordinator], ["status", "--json", *coordinator]):
        err, code = _into_closed_pipe(argv)
        assert err == "" and code == 1, (argv, code, err)
    out, err, code = _into_head(["status", *coordinator])
    assert out.strip() and err == "", err          # head's line; the status, cut or whole, quiet
    assert code in (0, 1), code
