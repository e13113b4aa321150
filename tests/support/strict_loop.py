"""A fresh event loop that fails a test on what a leaked task leaves behind.

    run_clean(scenario())

runs the coroutine on a new loop whose exception handler collects what asyncio reports instead of
logging it: an exception nobody retrieved, "Task was destroyed but it is pending" (said when a
dropped pending task is collected, which ``gc.collect()`` forces at the end). After the coroutine
returns, every other task must end within ``HANG_S`` (a stopped gRPC server's tasks may still be
winding down); one still pending then fails the test, as does anything the handler collected.

grpc.aio's completion-queue poller is bound to the first loop of the process. When a test process
runs several loops (one per test), it reports "Event loop is closed" about an earlier test's loop:
that is the test process's doing, not the product's (one loop a process), and is not a failure.
"""
from __future__ import annotations

import asyncio
import gc
from typing import Any, Coroutine

from waits import wait_until_async

#: the longest any stop or end may take before a test calls it a hang (generous for a loaded host)
HANG_S = 30.0


def grpc_poller_of_a_closed_loop(context: dict) -> bool:
    """Whether an exception-handler ``context`` is grpc.aio's poller complaining about a closed loop."""
    return "PollerCompletionQueue" in context.get("message", "") and "closed" in str(context.get("exception"))


def run_clean(coro: Coroutine[Any, Any, Any], *, hang_s: float = HANG_S) -> None:
    """Run ``coro`` on a fresh loop; fail on a task still pending ``hang_s`` after it returned, or on
    anything the loop reported (an unretrieved exception, a pending task destroyed)."""
    seen: list[dict] = []
    loop = asyncio.new_event_loop()
    loop.set_exception_handler(lambda _loop, context: seen.append(context))

    async def checked():
        await coro
        me = asyncio.current_task()
        await wait_until_async(lambda: asyncio.all_tasks() - {me}, lambda left: not left, timeout=hang_s,
                               what="no task left pending at the end")

    try:
        loop.run_until_complete(checked())
        loop.run_until_complete(loop.shutdown_asyncgens())
        loop.run_until_complete(loop.shutdown_default_executor())
    finally:
        loop.close()
        gc.collect()    # a pending task dropped now says so (through the handler) here
    seen = [c for c in seen if not grpc_poller_of_a_closed_loop(c)]
    assert not seen, f"the loop reported: {[c.get('message') for c in seen]}"
