"""The strict loop fails on what it promises to catch, and passes a clean coroutine."""
from __future__ import annotations

import asyncio

import pytest

from strict_loop import run_clean
from waits import WaitTimeout


def test_a_clean_coroutine_passes_and_a_task_that_ends_in_time_is_waited_for():
    async def clean():
        asyncio.get_running_loop().call_later(0.05, lambda: None)
        asyncio.ensure_future(asyncio.sleep(0.05))      # still pending when the coroutine returns, ends soon

    run_clean(clean())


def test_a_task_left_pending_fails():
    async def leaks():
        asyncio.ensure_future(asyncio.Event().wait())   # never ends

    with pytest.raises(WaitTimeout, match="no task left pending"):
        run_clean(leaks(), hang_s=0.2)


def test_an_exception_nobody_retrieved_fails():
    async def drops_an_error():
        async def fails():
            raise RuntimeError("nobody reads this")
        task = asyncio.ensure_future(fails())
        await asyncio.sleep(0)
        await asyncio.sleep(0)
        assert task.done()
        del task

    with pytest.raises(AssertionError, match="the loop reported"):
        run_clean(drops_an_error())
