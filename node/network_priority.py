"""The node's network side yields the CPU to its presenter.

A node is two processes: this one (the coordinator link, mDNS, the asset fetcher, reports) and the
presenter it starts (decode, render, swap). On a small computer, or in a CPU budget
(``--node-cpu``), both draw on the same share of a core, and the network side's work comes in
bursts the presenter never asked for: a rejoin after a coordinator restart (handshake, clock
exchanges, streams opened, the wanted list, the first reports), a fetch. With both at the same
priority, the scheduler splits the share between them during such a burst, and the presenter, which
needs its share every frame period, swaps late.

:func:`yield_to_presenter` lowers this process's priority (every thread's nice value, and so the
threads started later, which inherit it) once the presenter has been started, so that when both want
the CPU the presenter gets it first; the network side runs in the time the presenter leaves, which
is most of it (it needs well under a millisecond per frame period). Lowering a priority needs no
privilege; the presenter keeps the priority the node was started with.
"""
from __future__ import annotations

import logging
import os

log = logging.getLogger("node")

#: nice value added to the network side (CFS weight 1024 at 0 against 110 at 10: when the two
#: processes compete, the presenter gets about nine tenths of the CPU)
NETWORK_NICE = 10
#: the environment variable that sets another step (0: none), so that a benchmark can measure what
#: the step is worth (``SHADOWLESS_NETWORK_NICE=0 shadowless bench venue ...``)
NICE_ENV = "SHADOWLESS_NETWORK_NICE"


def nice_step(env: dict | None = None) -> int:
    """The step :func:`yield_to_presenter` takes by default: :data:`NETWORK_NICE`, or the environment's
    ``SHADOWLESS_NETWORK_NICE`` (0..19; anything else is ignored with a warning)."""
    text = (os.environ if env is None else env).get(NICE_ENV, "").strip()
    if not text:
        return NETWORK_NICE
    try:
        step = int(text)
    except ValueError:
        step = -1
    if not 0 <= step <= 19:
        log.warning("%s=%r is not a nice step 0..19: using %d", NICE_ENV, text, NETWORK_NICE)
        return NETWORK_NICE
    return step


def yield_to_presenter(step: int | None = None) -> int:
    """Raise the nice value of every thread of this process by ``step`` (default :func:`nice_step`;
    capped at 19). Returns the threads changed (0 where the platform has no per-thread priorities,
    or for a step of 0)."""
    if step is None:
        step = nice_step()
    if step == 0 or not hasattr(os, "setpriority") or not os.path.isdir("/proc/self/task"):
        return 0
    changed = 0
    for tid in os.listdir("/proc/self/task"):
        try:
            t = int(tid)
            os.setpriority(os.PRIO_PROCESS, t, min(19, os.getpriority(os.PRIO_PROCESS, t) + step))
            changed += 1
        except (OSError, ValueError):      # a thread that ended meanwhile
            continue
    log.debug("network side: %d thread(s) at nice +%d, below the presenter", changed, step)
    return changed
