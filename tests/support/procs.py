"""Running `shadowless` as a process of its own, and stopping a process a test started, whatever the
test's checks did before."""
from __future__ import annotations

import subprocess
import sys


def shadowless_process(*args: str, timeout: float = 120.0) -> subprocess.CompletedProcess:
    """`shadowless ARGS...` run to its end as a real process (this interpreter's), its output captured."""
    return subprocess.run([sys.executable, "-m", "shadowless", *args], capture_output=True, text=True, timeout=timeout)


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
