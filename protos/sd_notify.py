"""systemd's service notifications (sd_notify), without libsystemd: readiness, status, and
watchdog keep-alives that stop when any part of the process stops making progress.

Under ``Type=notify`` systemd passes ``NOTIFY_SOCKET`` (a Unix datagram socket; a leading ``@``
names an abstract one); with ``WatchdogSec=`` it also passes ``WATCHDOG_USEC`` (and
``WATCHDOG_PID``) and restarts the service when no ``WATCHDOG=1`` arrives within that time.
Outside systemd every call is a no-op.
"""
from __future__ import annotations

import os
import socket
import time
from typing import Callable, Mapping


def _address(env: Mapping[str, str]) -> str | None:
    addr = env.get("NOTIFY_SOCKET", "")
    if not addr or not (addr.startswith("/") or addr.startswith("@")):
        return None
    return "\0" + addr[1:] if addr.startswith("@") else addr


def notify(*lines: str, env: Mapping[str, str] | None = None) -> bool:
    """Send ``lines`` (e.g. ``READY=1``, ``STATUS=joined r0c0``) to systemd; False when not
    under systemd (or the socket is gone)."""
    addr = _address(os.environ if env is None else env)
    if addr is None:
        return False
    try:
        with socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM | socket.SOCK_CLOEXEC) as s:
            s.sendto("\n".join(lines).encode(), addr)
    except OSError:
        return False
    return True


class Watchdog:
    """Keep-alives for ``WatchdogSec``, sent only while every part has shown progress.

    Each part of the process (e.g. ``network``, ``presenter``) calls :meth:`beat` whenever it
    makes progress; the process calls :meth:`tick` often (at least every :attr:`interval_s`).
    ``tick`` sends ``WATCHDOG=1`` at most every :attr:`interval_s` (half of systemd's timeout),
    and only if every part registered with :meth:`expect` beat within :attr:`interval_s`: a
    frozen part stops the keep-alives, and systemd restarts the service.
    """

    def __init__(self, *, env: Mapping[str, str] | None = None, clock: Callable[[], float] = time.monotonic):
        self.env = dict(os.environ if env is None else env)
        self.clock = clock
        usec = self.env.get("WATCHDOG_USEC", "")
        pid = self.env.get("WATCHDOG_PID", "")
        mine = not pid or pid == str(os.getpid())
        self.enabled = usec.isdigit() and int(usec) > 0 and mine and _address(self.env) is not None
        self.interval_s = int(usec) / 2e6 if self.enabled else 0.0
        self._beats: dict[str, float] = {}
        self._last_sent = float("-inf")
        self.sent = 0

    def expect(self, *parts: str) -> None:
        """Parts that must beat for keep-alives to go out (each counts as alive from now)."""
        now = self.clock()
        for p in parts:
            self._beats.setdefault(p, now)

    def beat(self, part: str) -> None:
        self._beats[part] = self.clock()

    def stale(self) -> list[str]:
        """The parts that have not beaten within :attr:`interval_s`."""
        now = self.clock()
        return sorted(p for p, t in self._beats.items() if now - t > self.interval_s)

    def tick(self) -> bool:
        """Send a keep-alive if one is due and nothing is stale; whether one was sent."""
        if not self.enabled:
            return False
        now = self.clock()
        if now - self._last_sent < self.interval_s or self.stale():
            return False
        if notify("WATCHDOG=1", env=self.env):
            self._last_sent = now
            self.sent += 1
            return True
        return False
