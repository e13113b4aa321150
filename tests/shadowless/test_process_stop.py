"""shadowless.process_stop: a child is stopped by the signal it handles, and killed when it ignores it."""
from __future__ import annotations

import signal
import subprocess
import sys

from shadowless.process_stop import stop_process

CHILD = """
import signal, sys, time
if sys.argv[1] == "ignore":
    signal.signal(signal.SIGTERM, signal.SIG_IGN)
print("ready", flush=True)
time.sleep(120)
"""


def _child(mode: str) -> subprocess.Popen:
    proc = subprocess.Popen([sys.executable, "-c", CHILD, mode], stdout=subprocess.PIPE, text=True)
    assert proc.stdout.readline().strip() == "ready"       # its handler is in place
    return proc


def test_a_child_that_handles_the_signal_ends_by_it():
    proc = _child("default")
    stop_process(proc)
    assert proc.returncode == -signal.SIGTERM, proc.returncode
    proc.stdout.close()


def test_a_child_that_ignores_the_signal_is_killed_after_the_bound():
    proc = _child("ignore")
    stop_process(proc, timeout=0.5)
    assert proc.returncode == -signal.SIGKILL, proc.returncode
    proc.stdout.close()


def test_an_ended_child_is_left_as_it_ended():
    proc = subprocess.Popen([sys.executable, "-c", "raise SystemExit(3)"])
    proc.wait()
    stop_process(proc, sig=signal.SIGINT)
    assert proc.returncode == 3
