"""A coordinator served in the test's own event loop: its gRPC services (and, when asked, its console
and show control) on 127.0.0.1, started and stopped around a block.

    async with inprocess_coordinator(Rig(rig_dir), token, console="127.0.0.1:0") as app:
        ...  # app.port, app.console_port, app.coordinator, app.osc

What it gives: a started :class:`~coordinator.app.CoordinatorApp` that does not advertise over mDNS
(a test that wants mDNS starts a coordinator process). ``listen`` defaults to any free port on
127.0.0.1 (``app.port`` says which); every other keyword goes to ``CoordinatorApp`` as it is
(``console``, ``console_hosts``, ``console_optional``, ``tls``, ``cameras``, ``clock_ns``, ``mtc_port``).
``stop_within`` (seconds) bounds the stop for a test whose point is that stopping never hangs: a stop
still running then fails the test (:class:`~waits.WaitTimeout`) instead of hanging it.

How it cleans up: ``app.stop()`` runs when the block ends, however it ends (normally, by an
exception, or by the task being cancelled), so the rig directory's lock is free again and no
listener is left; a body that stops the app itself is fine (stopping twice is harmless). A start
that fails undoes itself (``CoordinatorApp.start``) and raises here, before the block runs. When
the block raised and stopping fails too, the block's exception is the one that propagates, with a
note saying how the stop failed: the test's own failure is never hidden behind its teardown's.
"""
from __future__ import annotations

import asyncio
import contextlib
from typing import Any, AsyncIterator

from coordinator.app import CoordinatorApp
from coordinator.rig import Rig
from waits import WaitTimeout


@contextlib.asynccontextmanager
async def inprocess_coordinator(rig: Rig, token: bytes, *, listen: str = "127.0.0.1:0",
                                stop_within: float | None = None, **options: Any) -> AsyncIterator[CoordinatorApp]:
    """Start a coordinator for ``rig`` (no mDNS) on ``listen``; yield the app; stop it on the way out."""
    app = CoordinatorApp(rig, token, listen=listen, advertise=False, **options)
    await app.start()
    try:
        yield app
    except BaseException as body_error:     # a failure or a cancellation: stop, then let it through as it is
        try:
            await _stop(app, stop_within)
        except Exception as stop_error:     # noqa: BLE001 - said on the body's exception, which goes on
            body_error.add_note(f"(and stopping the in-process coordinator failed too: {stop_error!r})")
        raise
    await _stop(app, stop_within)


async def _stop(app: CoordinatorApp, within: float | None) -> None:
    """``app.stop()``, failing with :class:`~waits.WaitTimeout` if it runs longer than ``within`` seconds."""
    if within is None:
        await app.stop()
        return
    try:
        async with asyncio.timeout(within):
            await app.stop()
    except TimeoutError:
        raise WaitTimeout(f"waited {within:g} s for the in-process coordinator to stop; it was still stopping") \
            from None
