"""Operator calls (RigControl ``RunJob`` and ``Play``, coordinator/wire/control_service.py) cancelled
by their client at the worst moments leave nothing behind on the coordinator, and leave it running.

``RunJob`` cancelled right as a progress event reaches the client (its handler writing that event,
or waiting for the next one), over and over: each time the job is cancelled, the rig is free for the
next one and no task of the call is left. The handler waited for the job's next event with a task of
its own (``events.get()``); cancelled there, it left that task pending for good ("Task was destroyed
but it is pending" when collected).

``RunJob`` writes the action log's entry of a call cancelled by its client in its ``finally``, after
gRPC let the call go (a handler that yields is closed later, not awaited). That entry asked gRPC's
context for the caller's address then: the coordinator died of a segmentation fault (trial 0, every
run). The address is now read as the call starts (``Play`` too, whose entry comes while its handler
still runs). ``Play`` cancelled while it plays stops the sequence and its entry says so."""
from __future__ import annotations

import asyncio
import sys
import types
from dataclasses import dataclass

import pytest

from coordinator.api import PlaySettings
from coordinator.console.audit import ActionLog
from coordinator.jobs import JobContext, registry
from coordinator.jobs.results import JobResult
from coordinator.rig import Rig, init_rig
from inprocess_coordinator import inprocess_coordinator
from protos import auth
from rigctl.link import Client
from rigctl.job_command import run_job
from strict_loop import HANG_S, run_clean
from waits import wait_until_async

JOB = "test-cancel-ticks"
TICKS = 5


@dataclass(frozen=True)
class NoOptions:
    pass


@dataclass(frozen=True, kw_only=True)
class Ticked(JobResult):
    ticks: int


async def ticking_job(ctx: JobContext, opts: NoOptions) -> Ticked:
    """Progress at each of its first TICKS loop turns, then nothing until it is cancelled: the call's
    handler is writing an event or waiting for the next one when its client goes."""
    for i in range(1, TICKS + 1):
        ctx.progress("ticks", "", i, TICKS)
        await asyncio.sleep(0)
    await asyncio.Event().wait()
    return Ticked(ticks=TICKS)


@pytest.fixture
def ticking(monkeypatch):
    mod = types.ModuleType("_test_cancel_ticks")
    mod.OPTIONS, mod.run = NoOptions, ticking_job
    sys.modules[mod.__name__] = mod
    monkeypatch.setitem(registry.JOBS, JOB, mod.__name__)
    yield
    sys.modules.pop(mod.__name__, None)


class CancelAt:
    """A progress view that cancels the client's call as its ``n``-th event arrives."""

    def __init__(self, n: int):
        self.n, self.seen, self.call = n, 0, None

    def event(self, ev) -> None:
        self.seen += 1
        if self.seen == self.n and self.call is not None:
            self.call.cancel()

    def close(self) -> None:
        pass


def test_a_job_call_cancelled_as_its_events_arrive_leaves_nothing(tmp_path, ticking):
    rig_dir = init_rig(tmp_path / "rig", name="jobs", slots=["r0c0"], width=32, height=32, content_width=32,
                       content_height=32)
    token = auth.read_token(rig_dir / "token")
    trials = 30

    async def go():
        async with inprocess_coordinator(Rig(rig_dir), token, stop_within=HANG_S) as app:
            c = app.coordinator
            async with await Client.connect(f"127.0.0.1:{app.port}", token) as client:
                base = None
                for trial in range(trials):
                    view = CancelAt(1 + trial % TICKS)   # the last: the handler waits, nothing comes
                    view.call = call = asyncio.ensure_future(run_job(client, JOB, {}, view=view))
                    async with asyncio.timeout(HANG_S):
                        await asyncio.gather(call, return_exceptions=True)
                    assert call.cancelled(), f"trial {trial}: {call!r}"
                    if base is None:    # after the first call: the client's and server's own tasks settled
                        await wait_until_async(c.running_job, lambda kind: kind is None, timeout=HANG_S,
                                               what="the first job cancelled")
                        await asyncio.sleep(0.2)    # only lets the first call's transport tasks end
                        base = len(asyncio.all_tasks())
                        continue
                    await wait_until_async(lambda: (c.running_job(), len(asyncio.all_tasks())),
                                           lambda s: s == (None, base), timeout=HANG_S,
                                           what=f"trial {trial}: the job cancelled and no task of its call "
                                                f"left ({base} tasks before)")

    run_clean(go())


def test_a_play_call_cancelled_while_it_plays_stops_the_sequence_and_says_so(tmp_path):
    rig_dir = init_rig(tmp_path / "rig", name="play", slots=["r0c0"], width=32, height=32, content_width=32,
                       content_height=32)
    token = auth.read_token(rig_dir / "token")
    trials = 10

    async def go():
        async with inprocess_coordinator(Rig(rig_dir), token, stop_within=HANG_S) as app:
            c = app.coordinator
            actions = ActionLog(rig_dir)
            async with await Client.connect(f"127.0.0.1:{app.port}", token) as client:
                for trial in range(trials):
                    entries = len(actions.entries)
                    call = asyncio.ensure_future(client.play(PlaySettings(fps=50, pattern="counter", frames=100_000)))
                    await wait_until_async(lambda: c.playback.playing, what=f"trial {trial}: the sequence playing")
                    for _ in range(trial % 5):      # the cancel 0-4 loop turns after the poll saw it play
                        await asyncio.sleep(0)
                    call.cancel()
                    async with asyncio.timeout(HANG_S):
                        await asyncio.gather(call, return_exceptions=True)
                    entry = await wait_until_async(lambda: list(actions.entries)[entries:], lambda new: new,
                                                   timeout=HANG_S, what=f"trial {trial}: the cancelled play's entry")
                    assert entry[0]["action"] == "cli play" and not entry[0]["ok"], entry
                    assert "cancelled by its client" in entry[0]["result"] and entry[0]["address"] == "127.0.0.1"
                    assert not c.playback.playing, f"trial {trial}: the sequence plays on after its call's cancel"

    run_clean(go())
