"""The compensation solver's worker threads, one set shared by every solve in the process.

A solve splits each product or sweep into row ranges and runs them on these threads. They are
started once and kept, so that a video, which solves every frame, does not start and join threads
for each one. Only the solver's own leaf tasks run on them (a row range of a product or a sweep,
never a task that itself waits on the pool), so solves running at once from several threads share
them without deadlock.
"""
from __future__ import annotations

import threading
from collections.abc import Callable, Sequence
from concurrent.futures import Executor, ThreadPoolExecutor
from typing import Any

__all__ = ["run_all", "workers"]

_POOLS: list[tuple[int, ThreadPoolExecutor]] = []  # (workers, pool) made so far, the largest last; none is shut down
_LOCK = threading.Lock()


def workers(threads: int) -> ThreadPoolExecutor | None:
    """A pool of at least ``threads`` workers (None for one thread: the caller does the work).

    Asking for more threads than the current pool has makes a larger one for later solves; the
    old one stays open, since a solve still running may submit to it (its threads idle until exit).
    """
    if threads < 2:
        return None
    with _LOCK:
        if not _POOLS or _POOLS[-1][0] < threads:
            _POOLS.append((threads, ThreadPoolExecutor(max_workers=threads)))
        return _POOLS[-1][1]


def run_all(pool: Executor | None, fn: Callable[[Any], Any], items: Sequence) -> list:
    """``[fn(i) for i in items]``, the items after the first on ``pool`` while the calling thread
    takes the first itself (one hand-off fewer per product or sweep); in order, on the calling
    thread alone when there is no pool or one item."""
    if pool is None or len(items) < 2:
        return [fn(i) for i in items]
    rest = [pool.submit(fn, i) for i in items[1:]]
    first = fn(items[0])
    return [first, *(f.result() for f in rest)]
