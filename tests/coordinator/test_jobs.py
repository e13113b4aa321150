"""Jobs on the coordinator: per-slot patterns shown and swapped by every node before
the job goes on, progress streamed to the client, errors named, cancellation."""
from __future__ import annotations

import asyncio
import sys

import grpc
import numpy as np
import pytest

from coordinator import jobs
from coordinator.jobclient import ProgressView, run_job
from coordinator.local import LocalRig
from coordinator.rig import Rig
from coordinator.server import Coordinator

SLOTS = ["r0c0", "r0c1", "r0c2"]
SIZE = (40, 24)


async def pattern_job(ctx: jobs.JobContext, params: dict) -> dict:
    shown = []
    slots = ctx.live_slots()
    for i in range(params["count"]):
        images = {s: np.full((SIZE[1], SIZE[0], 3), (40 * i + 10 * k) % 256, np.uint8) for k, s in enumerate(slots)}
        images[slots[-1]] = None   # one projector dark
        result = await ctx.coordinator.show_patterns(images, settle_s=0.01)
        shown.append(sorted(result.missing))
        ctx.progress("patterns", "all", i + 1, params["count"])
    ctx.log("done")
    return {"shown": shown, "slots": slots}


async def failing_job(ctx, params):
    raise jobs.JobError("projector r0c9 not seen by the camera")


async def slow_job(ctx, params):
    ctx.progress("waiting", "", 0, 1)
    await asyncio.sleep(60)
    return {}


class Capture:
    def __init__(self):
        self.events = []

    def progress(self, p):
        self.events.append(("progress", p.stage, p.done, p.total))

    def log(self, text):
        self.events.append(("log", text))

    def close(self):
        pass


@pytest.fixture
def nodes_rig(tmp_path, monkeypatch):
    monkeypatch.setitem(jobs.JOBS, "test-patterns", f"{__name__}:pattern_job")
    monkeypatch.setitem(jobs.JOBS, "test-fail", f"{__name__}:failing_job")
    monkeypatch.setitem(jobs.JOBS, "test-slow", f"{__name__}:slow_job")
    sys.modules.setdefault(__name__, sys.modules[__name__])
    r = LocalRig(SLOTS, tmp_path, output_size=SIZE, content_size=SIZE, mdns=False).create()
    yield r
    r.close()


def test_jobs_show_patterns_report_progress_fail_clearly_and_cancel(nodes_rig):
    async def go():
        coord = Coordinator(Rig(nodes_rig.rig_dir), nodes_rig.token, listen=f"127.0.0.1:{nodes_rig.port}", advertise=False)
        await coord.start()
        try:
            for s in SLOTS:
                nodes_rig.start_node(s)
            async with await nodes_rig.client() as c:
                await nodes_rig.wait_live(c, timeout=120)
                view = Capture()
                result = await run_job(c, "test-patterns", {"count": 4}, view=view)
                assert result["slots"] == SLOTS
                assert result["shown"] == [[], [], [], []], "every node swapped every pattern in"
                assert ("progress", "patterns", 4, 4) in view.events and ("log", "done") in view.events

                with pytest.raises(grpc.aio.AioRpcError) as err:
                    await run_job(c, "test-fail", {}, view=Capture())
                assert "r0c9 not seen by the camera" in err.value.details()

                with pytest.raises(grpc.aio.AioRpcError) as err:
                    await run_job(c, "no-such-job", {}, view=Capture())
                assert "unknown job" in err.value.details()

                # cancelling the call cancels the job and frees the rig for the next one
                slow = asyncio.ensure_future(run_job(c, "test-slow", {}, view=Capture()))
                await asyncio.sleep(1.0)
                slow.cancel()
                await asyncio.gather(slow, return_exceptions=True)
                for _ in range(50):
                    if not coord._job_lock.locked():
                        break
                    await asyncio.sleep(0.1)
                assert not coord._job_lock.locked()
                assert (await run_job(c, "test-patterns", {"count": 1}, view=Capture()))["shown"] == [[]]
        finally:
            nodes_rig.close()
            await coord.stop()

    asyncio.run(go())


def test_progress_view_draws_bars_without_a_terminal():
    import io

    out = io.StringIO()
    v = ProgressView(out)
    from protos import control_pb2

    v.progress(control_pb2.JobProgress(stage="gray codes", item="r0c0", done=3, total=12))
    v.progress(control_pb2.JobProgress(stage="gray codes", item="r0c1", done=12, total=12, message="ok"))
    v.log("camera exposure fine")
    text = out.getvalue()
    assert "gray codes r0c0 [#######....................." in text and "12/12" in text and "camera exposure fine" in text
