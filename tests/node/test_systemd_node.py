"""The node under systemd (Type=notify, WatchdogSec): READY once its output is open, keep-alives
only while both its network loop and its presenter process run (either frozen stops them, both
running again resumes them), STOPPING on the way out. The notification socket is the test's own."""
from __future__ import annotations

import os
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

from protos import auth


def _drain(s: socket.socket, until: float) -> list[str]:
    out = []
    while time.monotonic() < until:
        s.settimeout(max(0.01, until - time.monotonic()))
        try:
            out.append(s.recv(4096).decode())
        except (socket.timeout, BlockingIOError):
            break
    return out


def _keepalives(s: socket.socket, n: int, guard_s: float = 60.0) -> bool:
    """Whether ``n`` keep-alives arrive (the guard only bounds a broken run; load may slow them)."""
    seen, deadline = 0, time.monotonic() + guard_s
    while seen < n and time.monotonic() < deadline:
        seen += sum(m == "WATCHDOG=1" for m in _drain(s, time.monotonic() + 1.0))
    return seen >= n


def _frozen_silence(s: socket.socket, pid: int) -> list[str]:
    """Keep-alives received while ``pid`` is stopped, after the ones already due have drained."""
    os.kill(pid, signal.SIGSTOP)
    try:
        _drain(s, time.monotonic() + 1.5)      # in flight, or due before the part went stale (1 s)
        return [m for m in _drain(s, time.monotonic() + 2.0) if m == "WATCHDOG=1"]   # two keep-alive periods
    finally:
        os.kill(pid, signal.SIGCONT)


def _presenter_of(pid: int) -> int:
    """The node's presenter: its child started by node.presenter_process (child_main)."""
    for child in Path(f"/proc/{pid}/task/{pid}/children").read_text().split():
        cmd = Path(f"/proc/{child}/cmdline").read_bytes().replace(b"\0", b" ")
        if b"child_main" in cmd:
            return int(child)
    raise AssertionError(f"no presenter process under {pid}")


def test_ready_keepalives_from_both_halves_and_stopping(tmp_path):
    token = tmp_path / "token"
    token.write_text(auth.new_token() + "\n")
    token.chmod(0o600)
    sock = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
    sock.bind(str(tmp_path / "notify"))
    env = {**os.environ, "NOTIFY_SOCKET": str(tmp_path / "notify"), "WATCHDOG_USEC": "2000000"}
    # no coordinator answers: the watchdog is about the node's own health, joined or not
    proc = subprocess.Popen([sys.executable, "-m", "shadowless", "node", "--slot", "r0c0", "--coordinator",
                             "127.0.0.1:1", "--token-file", str(token), "--cache-dir", str(tmp_path / "cache")],
                            env=env, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    try:
        msgs: list[str] = []
        deadline = time.monotonic() + 120
        while time.monotonic() < deadline and not any("READY=1" in m for m in msgs):
            msgs += _drain(sock, time.monotonic() + 1.0)
            assert proc.poll() is None, proc.stderr.read()
        assert any("READY=1" in m and "STATUS=r0c0: output offscreen open" in m for m in msgs), msgs
        assert _keepalives(sock, 2), "keep-alives while both halves run (every WatchdogSec / 2)"

        assert _frozen_silence(sock, _presenter_of(proc.pid)) == [], "a frozen presenter stops the keep-alives"
        assert _keepalives(sock, 1), "they resume when the presenter runs again"
        assert _frozen_silence(sock, proc.pid) == [], "a frozen network loop stops them too"
        assert _keepalives(sock, 1), "and they resume"

        proc.send_signal(signal.SIGTERM)
        tail: list[str] = []          # until STOPPING arrives (at most 10 s)
        end = time.monotonic() + 10.0
        while time.monotonic() < end and not any("STOPPING=1" in m for m in tail):
            tail += _drain(sock, min(end, time.monotonic() + 0.5))
        assert proc.wait(30) == 0
        assert any("STOPPING=1" in m for m in tail), tail
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
        sock.close()
