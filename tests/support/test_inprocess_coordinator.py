"""The in-process coordinator serves for the length of its block and is stopped however the block
ends, the block's own exception going on as it was."""
from __future__ import annotations

import asyncio
import os
import socket

import pytest

from coordinator.rig import Rig, init_rig
from coordinator.rig_lock import RigLockError, holder
from inprocess_coordinator import inprocess_coordinator
from waits import WaitTimeout

TOKEN = b"p" * 32


@pytest.fixture
def rig(tmp_path) -> Rig:
    return Rig(init_rig(tmp_path / "rig", name="inproc", slots=["a"], width=32, height=32,
                        content_width=32, content_height=32))


def serving(rig: Rig) -> bool:
    """Whether a coordinator of this process holds the rig directory's lock."""
    return holder(rig.path) == (os.getpid(), "coordinator")


def test_the_block_gets_a_serving_app_and_the_rig_is_free_after_it(rig):
    async def go():
        async with inprocess_coordinator(rig, TOKEN, console="127.0.0.1:0") as app:
            assert serving(rig) and app.coordinator.status().rig_name == "inproc"
            for port in (app.port, app.console_port):
                socket.create_connection(("127.0.0.1", port), timeout=30).close()
        assert not serving(rig)

    asyncio.run(go())


def test_a_failing_block_stops_the_app_and_its_exception_goes_on(rig):
    async def go():
        async with inprocess_coordinator(rig, TOKEN):
            assert serving(rig)
            raise LookupError("the test's own failure")

    with pytest.raises(LookupError, match="the test's own failure") as exc:
        asyncio.run(go())
    assert not serving(rig)
    assert not getattr(exc.value, "__notes__", None)


def test_a_cancelled_block_stops_the_app_and_stays_cancelled(rig):
    async def go():
        entered = asyncio.Event()

        async def body():
            async with inprocess_coordinator(rig, TOKEN):
                entered.set()
                await asyncio.Event().wait()        # until cancelled

        task = asyncio.create_task(body())
        await entered.wait()
        assert serving(rig)
        task.cancel()
        with pytest.raises(asyncio.CancelledError):
            await task
        assert task.cancelled()

    asyncio.run(go())
    assert not serving(rig)


def test_a_failing_stop_does_not_hide_the_blocks_exception(rig):
    async def go():
        async with inprocess_coordinator(rig, TOKEN) as app:
            real_stop = app.stop

            async def stop_then_fail(grace: float = 2.0) -> None:
                await real_stop(grace)          # really stopped: nothing left serving
                raise RuntimeError("stop went wrong")

            app.stop = stop_then_fail
            raise LookupError("the test's own failure")

    with pytest.raises(LookupError, match="the test's own failure") as exc:
        asyncio.run(go())
    assert any("stop went wrong" in note for note in exc.value.__notes__), exc.value.__notes__
    assert not serving(rig)


def test_a_stop_that_hangs_fails_by_its_deadline_when_given_one(rig):
    async def go():
        async with inprocess_coordinator(rig, TOKEN, stop_within=0.5) as app:
            real_stop = app.stop

            async def stop_then_hang(grace: float = 2.0) -> None:
                await real_stop(grace)          # really stopped: nothing left serving
                await asyncio.Event().wait()    # until the deadline cancels it

            app.stop = stop_then_hang

    with pytest.raises(WaitTimeout, match="waited 0.5 s for the in-process coordinator to stop"):
        asyncio.run(go())
    assert not serving(rig)


def test_a_start_that_fails_raises_before_the_block(rig):
    async def go():
        async with inprocess_coordinator(rig, TOKEN):
            with pytest.raises(RigLockError, match="already served by the coordinator with pid"):
                async with inprocess_coordinator(Rig(rig.path), TOKEN):
                    raise AssertionError("the block ran without a coordinator")
            assert serving(rig)         # the first one serves on

    asyncio.run(go())
    assert not serving(rig)
