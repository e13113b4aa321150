"""A coordinator's waits keep a cancel that meets their wake-up. asyncio.wait_for on Python 3.11
returns normally when its task is cancelled in the same instant as the awaited event is set (the
inner wait finished first and the CancelledError is dropped): a node's Previews call then ran on
after its end, asking for previews every ASK_EVERY_S forever, and a call waiting for room before
authentication took a place although it was cancelled. ``asyncio.timeout`` keeps the cancel."""
from __future__ import annotations

import asyncio

from coordinator.admission import MIB, Budget
from coordinator.previews import WANTED_FOR_S, Previews
from waits import wait_until_async


class Clock:
    def __init__(self):
        self.t = 100.0

    def __call__(self) -> float:
        return self.t


def test_a_previews_call_ends_when_its_cancel_meets_a_wake_up():
    clock = Clock()
    previews = Previews(clock)
    wake = asyncio.Event()
    asked: list[int] = []

    async def call():           # what the node's Previews call does with the requests
        async for request_id in previews.asks("a", wake, lambda: False):
            asked.append(request_id)

    async def go():
        previews.want("a")
        task = asyncio.create_task(call())
        await wait_until_async(lambda: asked, what="the first preview request")
        for _ in range(5):      # the call waits for its next request, ASK_EVERY_S away
            await asyncio.sleep(0)
        clock.t += WANTED_FOR_S + 1     # nobody looked for a while...
        previews.want("a")              # ...someone looks again (sets the call's wake event)
        task.cancel()                   # right as the node's call ends
        async with asyncio.timeout(10):     # with the old wait_for the call asked every 0.9 s forever
            await asyncio.gather(task, return_exceptions=True)
        assert task.cancelled()
        assert asked == [1], "no request after the call's end"

    asyncio.run(go())


def test_a_call_waiting_for_room_takes_none_when_its_cancel_meets_the_room():
    async def go():
        budget = Budget(reserve_bytes=MIB, max_calls=1)
        held = budget.admit("ipv4:10.0.0.1:5000")
        assert held is not None
        waiting = asyncio.create_task(budget.enter("ipv4:10.0.0.2:5000", wait_s=30))
        await wait_until_async(lambda: budget.waiting, what="the second call waiting for room")
        budget.release(held)        # room: wakes the waiting call...
        waiting.cancel()            # ...whose caller went away in the same instant
        async with asyncio.timeout(10):
            await asyncio.gather(waiting, return_exceptions=True)
        assert waiting.cancelled(), "the cancel reached the caller (the old wait_for returned a ticket)"
        assert budget.total.calls == 0 and not budget.waiting, "a cancelled call holds no room"

    asyncio.run(go())
