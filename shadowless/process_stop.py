"""Stopping a child process in order: a signal it handles (SIGTERM by default: it stops what it
started and ends its sessions as closed), then SIGKILL if it has not ended within a bound."""
from __future__ import annotations

import signal
import subprocess


def stop_process(proc: subprocess.Popen, sig: int = signal.SIGTERM, timeout: float = 10.0) -> None:
    """If ``proc`` still runs: send ``sig``, wait up to ``timeout`` seconds, then SIGKILL and reap it.
    A process that has ended already is left as it is."""
    if proc.poll() is not None:
        return
    proc.send_signal(sig)
    try:
        proc.wait(timeout)
    except subprocess.TimeoutExpired:
        proc.kill()
        proc.wait()
