"""protos/sd_notify.py: notifications reach a NOTIFY_SOCKET the test owns; keep-alives stop when a
part freezes and resume when it runs again."""
from __future__ import annotations

import os
import socket

import pytest

from protos.sd_notify import Watchdog, notify


@pytest.fixture
def notify_socket(tmp_path):
    s = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
    path = tmp_path / "notify"
    s.bind(str(path))
    s.setblocking(False)
    yield str(path), s
    s.close()


def received(s) -> list[str]:
    out = []
    while True:
        try:
            out.append(s.recv(4096).decode())
        except BlockingIOError:
            return out


class Clock:
    t = 100.0

    def __call__(self):
        return self.t


def test_notify_sends_lines_and_is_a_no_op_outside_systemd(notify_socket):
    path, s = notify_socket
    assert notify("READY=1", "STATUS=joined r0c0", env={"NOTIFY_SOCKET": path})
    assert received(s) == ["READY=1\nSTATUS=joined r0c0"]
    assert not notify("READY=1", env={})
    assert not notify("READY=1", env={"NOTIFY_SOCKET": "relative/path"})


def test_abstract_socket_names():
    s = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
    name = f"shadowless-test-{os.getpid()}"
    s.bind("\0" + name)
    s.setblocking(False)
    try:
        assert notify("WATCHDOG=1", env={"NOTIFY_SOCKET": "@" + name})
        assert received(s) == ["WATCHDOG=1"]
    finally:
        s.close()


def test_keepalives_stop_while_a_part_is_frozen_and_resume(notify_socket):
    path, s = notify_socket
    clock = Clock()
    wd = Watchdog(env={"NOTIFY_SOCKET": path, "WATCHDOG_USEC": "4000000"}, clock=clock)   # WatchdogSec=4
    assert wd.enabled and wd.interval_s == 2.0
    wd.expect("network", "presenter")
    sent_at = []
    for step in range(40):                      # 20 s in 0.5 s steps
        clock.t = 100.0 + 0.5 * step
        if not 6.0 <= clock.t - 100.0 < 12.0:   # the presenter freezes from 6 s to 12 s
            wd.beat("presenter")
        wd.beat("network")
        if wd.tick():
            sent_at.append(clock.t - 100.0)
    assert len(received(s)) == len(sent_at) == wd.sent
    gaps = [b - a for a, b in zip(sent_at, sent_at[1:])]
    frozen = [t for t in sent_at if 8.0 <= t < 12.0]
    assert not frozen, "no keep-alive once the presenter was stale for longer than the interval"
    assert any(t >= 12.0 for t in sent_at), "keep-alives resume when it runs again"
    assert max(gaps) >= 4.0 and all(g >= 2.0 for g in gaps)   # a gap systemd notices; never more often


def test_disabled_without_watchdog_or_for_another_pid(notify_socket):
    path, _ = notify_socket
    assert not Watchdog(env={"NOTIFY_SOCKET": path}).enabled
    assert not Watchdog(env={"NOTIFY_SOCKET": path, "WATCHDOG_USEC": "1000000", "WATCHDOG_PID": "1"}).enabled
    assert Watchdog(env={"NOTIFY_SOCKET": path, "WATCHDOG_USEC": "1000000",
                         "WATCHDOG_PID": str(os.getpid())}).enabled
    assert not Watchdog(env={}).tick()
