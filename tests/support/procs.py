"""Stopping a process a test started, whatever the test's checks did before."""
from __future__ import annotations

import subprocess


def stop(proc: subprocess.Popen, timeout: float = 60.0) -> None:
    """If ``proc`` still runs (a check failed before it was stopped the normal way): SIGTERM, which
    still stops what it started, then SIGKILL after ``timeout`` seconds."""
    if proc.poll() is None:
        proc.terminate()
        try:
            proc.wait(timeout=timeout)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()
