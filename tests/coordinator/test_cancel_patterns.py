"""Pattern loops of the coordinator end when stopped, at the worst moment, and leave no task behind:
a job's pattern (``show_patterns``: returns once every live node swapped it in) cancelled in the
very instant its verdict arrives, and a played test-pattern sequence (``play --pattern counter``)
stopped at moments swept across its frame period (as a frame's wait ends, as it is packed on a
worker thread, as it is sent). A real coordinator on loopback; a stand-in node on the real node link
reports a swap for every frame it receives.

asyncio.wait_for on Python 3.11 returns normally when its task is cancelled in the same instant as
the awaited future completes: a job cancelled as its pattern was shown ran on to its next pattern.
``show_patterns`` waits with ``asyncio.timeout``, which keeps the cancel; these tests hold it there."""
from __future__ import annotations

import asyncio
import time

import numpy as np
import pytest

from coordinator.api import NodeState, PlaySettings
from coordinator.rig import Rig, init_rig
from node.clock import LocalClock
from node.link import CoordinatorLink
from node.records import HeartbeatRecord, NodeInfo, SwapRecord
from node.session import ReportStream, SessionCore
from node.wire import packet_from_bytes
from inprocess_coordinator import inprocess_coordinator
from protos import auth
from strict_loop import HANG_S, run_clean
from waits import wait_until_async

SLOT = "r0c0"
SIZE = 32


def heartbeat() -> HeartbeatRecord:
    return HeartbeatRecord(assignment_revision=0, frames_shown=0, frames_late=0, frames_dropped=0,
                           render_ms_p50=0.0, host_monotonic_ns=time.monotonic_ns())


class SwappingNode:
    """A node that swaps in every frame the moment it arrives (no screen): joined, reporting."""

    def __init__(self, target: str, token: bytes):
        self.link = CoordinatorLink(target)
        self.core = SessionCore(slot=SLOT, token=token, clock=LocalClock(), info=lambda: NodeInfo(hostname="t"))
        self.reports = ReportStream(heartbeat, 0.5, batch_s=0.0)
        self.frames: list[int] = []

    async def __aenter__(self) -> "SwappingNode":
        await self.link.__aenter__()
        await self.core.join(self.link)
        self._tasks = [asyncio.create_task(self.reports.run(self.link), name="report"),
                       asyncio.create_task(self._swap(), name="frames")]
        return self

    async def __aexit__(self, *exc) -> None:
        for t in self._tasks:
            t.cancel()
        await asyncio.gather(*self._tasks, return_exceptions=True)
        await self.link.__aexit__(*exc)

    async def _swap(self) -> None:
        async for data in self.link.frame_packets():
            f = packet_from_bytes(data, SLOT, known=lambda cid: True).frame
            if f is not None:
                self.frames.append(f.frame_id)
                self.reports.add(SwapRecord(frame_id=f.frame_id, pts_ns=f.pts_ns, swap_rig_ns=f.pts_ns,
                                            host_monotonic_ns=time.monotonic_ns()))


@pytest.fixture
def rig_dir(tmp_path):
    return init_rig(tmp_path / "rig", name="patterns", slots=[SLOT], width=SIZE, height=SIZE, content_width=SIZE,
                    content_height=SIZE)


async def wait_live(c) -> None:
    await wait_until_async(lambda: [n.state for n in c.status().nodes], lambda s: s == [NodeState.LIVE],
                           what="the stand-in node live")


def pattern(k: int) -> dict[str, np.ndarray]:
    img = np.zeros((SIZE, SIZE, 3), np.uint8)
    img[:, k % SIZE] = 255      # each one differs: a new content every time
    return {SLOT: img}


@pytest.mark.parametrize("turns", [0, 1, 2, 3])
def test_a_pattern_cancelled_as_its_verdict_arrives_is_cancelled(rig_dir, turns):
    """``turns``: how many loop turns after the verdict the cancel comes (0: in the same call that
    resolves the pattern's wait, before the waiting task runs again)."""
    token = auth.read_token(rig_dir / "token")
    trials = 10

    async def go():
        async with inprocess_coordinator(Rig(rig_dir), token, stop_within=HANG_S) as app:
            c = app.coordinator
            async with SwappingNode(f"127.0.0.1:{app.port}", token):
                await wait_live(c)
                await c.show_patterns(pattern(0), settle_s=0)     # the first one: contents reach the node
                base = len(asyncio.all_tasks())
                delivered = 0
                for trial in range(trials):
                    job = asyncio.create_task(c.show_patterns(pattern(trial + 1), settle_s=0), name="job")
                    loop = asyncio.get_running_loop()
                    cancelled: list[bool] = []

                    def cancel_later(n: int) -> None:
                        if n == 0:
                            cancelled.append(job.cancel())     # False: the job had returned already
                        else:
                            loop.call_soon(cancel_later, n - 1)

                    def on_verdict(result) -> None:     # called as the node's swap report is taken
                        if result.tag == "pattern" and not job.done():
                            cancel_later(turns)
                    stop_listening = c.listen_frames(on_verdict)
                    try:
                        async with asyncio.timeout(HANG_S):
                            await asyncio.gather(job, return_exceptions=True)
                    finally:
                        stop_listening()
                    await wait_until_async(lambda: cancelled, timeout=HANG_S,
                                           what=f"trial {trial}: the verdict, and the cancel {turns} turn(s) later")
                    if cancelled[0]:    # the cancel reached the job before it returned: it must end cancelled
                        delivered += 1
                        assert job.cancelled(), (f"trial {trial}: the job's cancel was lost as its pattern was "
                                                 f"shown (it returned {job.result()!r})")
                    await wait_until_async(lambda: len(asyncio.all_tasks()), lambda n: n == base, timeout=HANG_S,
                                           what=f"trial {trial}: the tasks there were before the pattern")
                if turns == 0:      # in the verdict's own call, the job has not run since: every cancel lands
                    assert delivered == trials

    run_clean(go())


def test_a_test_pattern_sequence_stops_at_any_moment_of_its_frame(rig_dir):
    token = auth.read_token(rig_dir / "token")
    fps, steps = 50.0, 24
    period = 1 / fps

    async def go():
        async with inprocess_coordinator(Rig(rig_dir), token, stop_within=HANG_S) as app:
            c = app.coordinator
            async with SwappingNode(f"127.0.0.1:{app.port}", token) as node:
                await wait_live(c)
                base = None
                for trial in range(2 * steps):
                    seen = len(node.frames)
                    await c.play_sequence(None, PlaySettings(fps=fps, pattern="counter", frames=100_000, wait=False))
                    # the second frame on the node: the loop runs, the moments below fall within its period
                    await wait_until_async(lambda: len(node.frames) - seen, lambda n: n >= 2,
                                           what=f"trial {trial}: the pattern's frames on the node")
                    stopped = asyncio.get_running_loop().create_future()
                    asyncio.get_running_loop().call_later(
                        (trial % steps) * period / steps,
                        lambda: stopped.set_result(c.stop_all()) if not stopped.done() else None)
                    async with asyncio.timeout(HANG_S):
                        await stopped
                    await wait_until_async(lambda: c.playback.playing, lambda p: not p, timeout=HANG_S,
                                           what=f"trial {trial}: the sequence's loop ended after its stop")
                    n = len(asyncio.all_tasks())
                    base = n if base is None else base
                    await wait_until_async(lambda: len(asyncio.all_tasks()), lambda k: k == base, timeout=HANG_S,
                                           what=f"trial {trial}: no task of the stopped sequence left")

    run_clean(go())
