"""The coordinator under systemd (Type=notify, WatchdogSec): READY once it serves, keep-alives
from its event loop that stop while the process is frozen and resume, STOPPING on the way out.
The notification socket is the test's own."""
from __future__ import annotations

import os
import signal
import socket
import subprocess
import sys
import time

from coordinator.rig import init_rig


def _drain(s: socket.socket, until: float) -> list[tuple[float, str]]:
    out = []
    while time.monotonic() < until:
        s.settimeout(max(0.01, until - time.monotonic()))
        try:
            out.append((time.monotonic(), s.recv(4096).decode()))
        except (socket.timeout, BlockingIOError):
            break
    return out


def _count_keepalives(s: socket.socket, n: int, guard_s: float = 60.0) -> bool:
    """Whether ``n`` keep-alives arrive (the guard only bounds a broken run; load may slow them)."""
    seen, deadline = 0, time.monotonic() + guard_s
    while seen < n and time.monotonic() < deadline:
        seen += sum(m == "WATCHDOG=1" for _, m in _drain(s, time.monotonic() + 1.0))
    return seen >= n


def test_ready_keepalives_freeze_and_stopping(tmp_path):
    rig = init_rig(tmp_path / "rig", name="sd", slots=["a"], width=64, height=48, content_width=64,
                   content_height=48)
    sock = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
    sock.bind(str(tmp_path / "notify"))
    env = {**os.environ, "NOTIFY_SOCKET": str(tmp_path / "notify"), "WATCHDOG_USEC": "1000000"}
    proc = subprocess.Popen([sys.executable, "-m", "shadowless", "coordinator", "--rig", str(rig), "--listen",
                             "127.0.0.1:0", "--no-mdns", "--no-console"], env=env, stdout=subprocess.DEVNULL,
                            stderr=subprocess.PIPE, text=True)
    try:
        deadline = time.monotonic() + 60
        msgs: list[tuple[float, str]] = []
        while time.monotonic() < deadline and not any("READY=1" in m for _, m in msgs):
            msgs += _drain(sock, time.monotonic() + 1.0)
        assert any("READY=1" in m and "STATUS=rig sd on port" in m for _, m in msgs), msgs
        assert _count_keepalives(sock, 2), "keep-alives while it runs (every WatchdogSec / 2)"

        proc.send_signal(signal.SIGSTOP)           # a hung coordinator
        _drain(sock, time.monotonic() + 0.2)       # what was in flight before the stop
        frozen = [m for _, m in _drain(sock, time.monotonic() + 1.5) if m == "WATCHDOG=1"]   # 3 periods
        proc.send_signal(signal.SIGCONT)
        assert frozen == [], "no keep-alive from a frozen process: systemd restarts it"
        assert _count_keepalives(sock, 1), "keep-alives resume when it runs again"

        proc.send_signal(signal.SIGTERM)
        tail: list = []               # until STOPPING arrives (at most 10 s)
        end = time.monotonic() + 10.0
        while time.monotonic() < end and not any("STOPPING=1" in m for _, m in tail):
            tail += _drain(sock, min(end, time.monotonic() + 0.5))
        assert any("STOPPING=1" in m for _, m in tail)
        assert proc.wait(timeout=30) == 0
    finally:
        if proc.poll() is None:
            proc.send_signal(signal.SIGCONT)
            proc.kill()
            proc.wait(timeout=30)
        if proc.stderr:
            proc.stderr.close()
        sock.close()
