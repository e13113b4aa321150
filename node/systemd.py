"""The node under systemd (``Type=notify``, ``WatchdogSec=``): ready once its output is open,
a status line saying whether it has joined, and watchdog keep-alives only while both halves of
the node make progress: the network loop (this process's asyncio loop) and the presenter (the
process that renders and swaps, which says it is alive at least every second). A frozen half
stops the keep-alives and systemd restarts the service. Outside systemd, nothing is sent.
"""
from __future__ import annotations

import asyncio
import logging

from protos import sd_notify

log = logging.getLogger("node")

__all__ = ["NodeNotifier"]


class NodeNotifier:
    """``presenter_alive()`` returns seconds since the presenter last said it was alive."""

    def __init__(self, presenter_alive, *, watchdog: sd_notify.Watchdog | None = None):
        self.presenter_alive = presenter_alive
        self.watchdog = watchdog or sd_notify.Watchdog()
        self.watchdog.expect("network", "presenter")

    def ready(self, status: str) -> None:
        sd_notify.notify("READY=1", f"STATUS={status}")
        if self.watchdog.enabled:
            log.info("systemd watchdog: keep-alives every %.1f s while the network loop and the presenter run",
                     self.watchdog.interval_s)

    def status(self, text: str) -> None:
        sd_notify.notify(f"STATUS={text}")

    def stopping(self) -> None:
        sd_notify.notify("STOPPING=1")

    async def run(self) -> None:
        """Feed the watchdog until cancelled (a no-op loop-free return outside systemd)."""
        wd = self.watchdog
        if not wd.enabled:
            return
        period = max(0.05, wd.interval_s / 4)
        while True:
            wd.beat("network")                       # this coroutine runs: the loop is not stuck
            if self.presenter_alive() <= wd.interval_s:
                wd.beat("presenter")
            wd.tick()
            await asyncio.sleep(period)
