"""Waiting for a condition in tests: poll it until it holds or a deadline passes, then say what was seen.

Tests never sleep and then assert: on a loaded machine the sleep is too short, on a quiet one
too long. They wait for the event itself, with a deadline generous enough for two CPU burners
beside the suite, and on failure the message names what was awaited and the last thing seen.

    state = wait_until(lambda: rig.status(), lambda s: len(s.nodes) == 4, what="4 nodes live")
    frames = await wait_until_async(fetch_ids, lambda ids: len(ids) >= 30, what="30 frame ids")

``probe`` returns the current state (any value); ``done`` says whether it is good enough (by
default, its truth). The state that satisfied ``done`` is returned, so the test asserts on the
same observation it waited for. The poll interval is the one place the suite sleeps for a
condition: every ``wait_until`` call shares it.
"""
from __future__ import annotations

import asyncio
import time
from typing import Awaitable, Callable, TypeVar

T = TypeVar("T")

#: seconds between polls; short enough not to slow a passing test, long enough not to spin a core
POLL_S = 0.05
#: the default deadline: far above any quiet-machine time, so only a real hang fails
DEFAULT_TIMEOUT_S = 60.0


class WaitTimeout(AssertionError):
    """The condition did not hold by the deadline; the message says what was awaited and seen."""


def _clip(value: object, limit: int = 600) -> str:
    """``repr(value)``, its end kept when it is long: a log or a list grows at its end, where the news is."""
    text = repr(value)
    return text if len(text) <= limit else "…" + text[-(limit - 1):]


def wait_until(probe: Callable[[], T], done: Callable[[T], bool] = bool, *, what: str,
               timeout: float = DEFAULT_TIMEOUT_S, interval: float = POLL_S) -> T:
    """Poll ``probe()`` until ``done(state)``; return that state, or raise :class:`WaitTimeout`."""
    deadline = time.monotonic() + timeout
    polls = 0
    while True:
        state = probe()
        polls += 1
        if done(state):
            return state
        if time.monotonic() >= deadline:
            raise WaitTimeout(f"waited {timeout:g} s ({polls} polls) for {what}; last seen: {_clip(state)}")
        time.sleep(interval)  # the suite's one poll interval: the condition has no event to wait on


async def wait_until_async(probe: Callable[[], Awaitable[T] | T], done: Callable[[T], bool] = bool, *,
                           what: str, timeout: float = DEFAULT_TIMEOUT_S, interval: float = POLL_S) -> T:
    """The same inside an event loop: ``probe`` may be a coroutine function; the loop keeps running
    between polls."""
    deadline = time.monotonic() + timeout
    polls = 0
    while True:
        state = probe()
        if asyncio.iscoroutine(state) or isinstance(state, asyncio.Future):
            state = await state
        polls += 1
        if done(state):
            return state
        if time.monotonic() >= deadline:
            raise WaitTimeout(f"waited {timeout:g} s ({polls} polls) for {what}; last seen: {_clip(state)}")
        await asyncio.sleep(interval)  # the suite's one async poll interval: as above
