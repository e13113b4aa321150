"""The tests' waiting helper returns the state it waited for and fails saying what it saw."""
from __future__ import annotations

import asyncio
import itertools

import pytest
from waits import WaitTimeout, wait_until, wait_until_async


def test_wait_until_returns_the_state_that_satisfied_the_condition():
    counter = itertools.count()
    assert wait_until(lambda: next(counter), lambda n: n >= 3, what="three polls", interval=0) == 3


def test_wait_until_fails_naming_what_it_awaited_and_the_last_state():
    with pytest.raises(WaitTimeout, match=r"for the answer; last seen: 41"):
        wait_until(lambda: 41, lambda n: n == 42, what="the answer", timeout=0.05, interval=0.01)


def test_wait_until_async_awaits_a_coroutine_probe():
    counter = itertools.count()

    async def probe():
        return next(counter)

    assert asyncio.run(wait_until_async(probe, lambda n: n == 2, what="two", interval=0)) == 2


def test_a_long_state_is_shown_by_its_end():
    log = "started\n" + "x" * 2000 + "\nthe line that matters"
    with pytest.raises(WaitTimeout, match="the line that matters"):
        wait_until(lambda: log, lambda s: False, what="a line", timeout=0.01, interval=0.01)
