"""Real-time priority for the instant of the swap (SCHED_FIFO), normal priority otherwise."""
from __future__ import annotations

import logging
import os

log = logging.getLogger(__name__)


class RealtimeWindow:
    """Run the last sleep and the swap at real-time priority (SCHED_FIFO), the rest normally.

    A projector's swap is a real-time deadline: when a dozen nodes share a small
    machine, or a node's other threads are busy, a normal thread that wakes on
    time may still wait for a CPU. The thread enters this window once the frame
    is rendered, sleeps in it until the deadline (using no CPU), swaps,
    timestamps and leaves: it never renders at that priority and cannot starve
    the machine. Needs CAP_SYS_NICE (the systemd unit grants it); without it the
    node says so once and runs at normal priority.
    """

    def __init__(self, enabled: bool, priority: int = 50):
        self.active = False
        if not enabled or not hasattr(os, "sched_setscheduler"):
            return
        try:
            self._fifo = os.sched_param(priority)
            self._normal = os.sched_param(0)
            os.sched_setscheduler(0, os.SCHED_FIFO, self._fifo)
            os.sched_setscheduler(0, os.SCHED_OTHER, self._normal)
            self.active = True
        except (PermissionError, OSError) as exc:
            log.info("real-time swap priority unavailable (%s); swapping at normal priority", exc.strerror or exc)

    def __enter__(self) -> None:
        if self.active:
            os.sched_setscheduler(0, os.SCHED_FIFO, self._fifo)

    def __exit__(self, *exc) -> None:
        if self.active:
            os.sched_setscheduler(0, os.SCHED_OTHER, self._normal)
