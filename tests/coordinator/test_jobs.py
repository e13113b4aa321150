"""Jobs on the coordinator: per-slot patterns shown and swapped by every node before
the job goes on, progress streamed to the client, errors named, cancellation; a job's typed
result reaches the client as its wire dict."""
from __future__ import annotations

import asyncio
import io
import sys
import types
from dataclasses import dataclass

import numpy as np
import pytest

from coordinator.jobs import JobContext, JobError, Progress, option, registry
from coordinator.jobs.results import JobResult, optional
from rigctl.client import CallRefused
from rigctl.job_command import ProgressView, run_job
from coordinator.rig import Rig
from shadowless.local import LocalRig
from waits import wait_until_async
from inprocess_coordinator import inprocess_coordinator

SLOTS = ["r0c0", "r0c1", "r0c2"]
SIZE = (40, 24)


@dataclass(frozen=True)
class CountOptions:
    count: int = option(1, lo=1, hi=100, help="patterns to show")


@dataclass(frozen=True)
class NoOptions:
    pass


@dataclass(frozen=True, kw_only=True)
class Shown(JobResult):
    shown: int
    slots: list[str]
    note: str | None = optional()


async def pattern_job(ctx: JobContext, opts: CountOptions) -> Shown:
    slots = ctx.live_slots()
    for i in range(opts.count):
        images = {s: np.full((SIZE[1], SIZE[0], 3), (40 * i + 10 * k) % 256, np.uint8) for k, s in enumerate(slots)}
        images[slots[-1]] = None   # one projector dark
        await ctx.show(images, settle_s=0.01, require=slots)   # returns once every node swapped it in
        ctx.progress("patterns", "all", i + 1, opts.count)
    ctx.log("done")
    return Shown(shown=opts.count, slots=slots)


async def failing_job(ctx: JobContext, opts: NoOptions) -> Shown:
    raise JobError("projector r0c9 not seen by the camera")


async def slow_job(ctx: JobContext, opts: NoOptions) -> Shown:
    ctx.progress("waiting", "", 0, 1)
    await asyncio.Event().wait()     # until cancelled
    return Shown(shown=0, slots=[])


def _job_module(name: str, options: type, run) -> str:
    mod = types.ModuleType(name)
    mod.OPTIONS, mod.run = options, run
    sys.modules[name] = mod
    return name


class Capture:
    def __init__(self):
        self.events = []

    def event(self, ev):
        if isinstance(ev, Progress):
            self.events.append(("progress", ev.stage, ev.done, ev.total))
        else:
            self.events.append(("log", ev))

    def close(self):
        pass


@pytest.fixture
def nodes_rig(tmp_path, monkeypatch):
    monkeypatch.setitem(registry.JOBS, "test-patterns", _job_module("_test_jobs_patterns", CountOptions, pattern_job))
    monkeypatch.setitem(registry.JOBS, "test-fail", _job_module("_test_jobs_fail", NoOptions, failing_job))
    monkeypatch.setitem(registry.JOBS, "test-slow", _job_module("_test_jobs_slow", NoOptions, slow_job))
    r = LocalRig(SLOTS, tmp_path, output_size=SIZE, content_size=SIZE, mdns=False).create()
    yield r
    r.close()
    for name in ("_test_jobs_patterns", "_test_jobs_fail", "_test_jobs_slow"):
        sys.modules.pop(name, None)


def test_jobs_show_patterns_report_progress_fail_clearly_and_cancel(nodes_rig):
    async def go():
        async with inprocess_coordinator(Rig(nodes_rig.rig_dir), nodes_rig.token,
                                         listen=f"127.0.0.1:{nodes_rig.port}") as app:
            coord = app.coordinator
            try:
                for s in SLOTS:
                    nodes_rig.start_node(s)
                async with await nodes_rig.client() as c:
                    await nodes_rig.wait_live(c, timeout=120)
                    view = Capture()
                    result = await run_job(c, "test-patterns", {"count": 4}, view=view)
                    assert result == {"shown": 4, "slots": SLOTS}   # the typed result's wire dict, its None note left out
                    assert ("progress", "patterns", 4, 4) in view.events and ("log", "done") in view.events

                    with pytest.raises(CallRefused) as err:
                        await run_job(c, "test-fail", {}, view=Capture())
                    assert "r0c9 not seen by the camera" in err.value.details

                    with pytest.raises(CallRefused) as err:
                        await run_job(c, "no-such-job", {}, view=Capture())
                    assert "unknown job" in err.value.details

                    with pytest.raises(CallRefused) as err:   # options are checked before the job runs
                        await run_job(c, "test-patterns", {"count": 0, "colour": 1}, view=Capture())
                    assert "unknown test-patterns parameter(s) colour" in err.value.details

                    # cancelling the call cancels the job and frees the rig for the next one
                    view = Capture()
                    slow = asyncio.ensure_future(run_job(c, "test-slow", {}, view=view))
                    await wait_until_async(lambda: list(view.events), lambda ev: ("progress", "waiting", 0, 1) in ev,
                                           what="the slow job's first progress")
                    slow.cancel()
                    await asyncio.gather(slow, return_exceptions=True)
                    await wait_until_async(lambda: coord._job_lock.locked(), lambda locked: not locked,
                                           what="the cancelled job to free the rig")
                    assert (await run_job(c, "test-patterns", {"count": 1}, view=Capture()))["shown"] == 1
            finally:
                nodes_rig.close()

    asyncio.run(go())


def test_progress_view_draws_bars_without_a_terminal():
    out = io.StringIO()
    v = ProgressView(out)
    v.event(Progress(stage="gray codes", item="r0c0", done=3, total=12))
    v.event(Progress(stage="gray codes", item="r0c1", done=12, total=12, message="ok"))
    v.event("camera exposure fine")
    text = out.getvalue()
    assert "gray codes r0c0: 3/12 (25%)" in text and "gray codes r0c1: 12/12 (100%)" in text
    assert "camera exposure fine" in text and "\r" not in text and "\x1b" not in text
