"""What a blend switch costs the pipe between a node process and its presenter process: a failover's
switch for a later instant on a still sends the node one stats message, when the maps show (each message
wakes the node process; 24 nodes share the cores the switch is drawn with). A real presenter process
(offscreen output, the node's pipes)."""
from __future__ import annotations

import asyncio
import time

import numpy as np
from waits import wait_until_async

from node.clock import ClockEstimate
from node.presenter_process import PresenterProcess, PresenterSettings
from node.records import FrameOrder, NodeAssignment
from protos.blend import BlendMaps

W, H = 32, 24
MS = 1_000_000


def assignment(revision: int, blend: BlendMaps | None = None, at_ns: int = 0) -> NodeAssignment:
    return NodeAssignment(revision=revision, slot="r0c0", width=W, height=H, pose_kind="homography",
                          homography=np.eye(3), projection=None, mesh=None, near_mm=100.0, far_mm=10_000.0,
                          lut=None, gain=1.0, content_size=(W, H), blend=blend, blend_at_ns=at_ns)


def maps(seed: int) -> BlendMaps:
    rng = np.random.default_rng(seed)
    return BlendMaps(rng.random((6, 8, 3), dtype=np.float32), rng.random((6, 8), dtype=np.float32) * 0.2)


async def _three_switches() -> None:
    # the presenter's clock is this host's monotonic clock, and the rig clock is the same (offset 0)
    p = PresenterProcess(PresenterSettings(slot="r0c0", output_spec="offscreen", clock_offset_ns=0,
                                           clock_drift_ppm=0.0, clock_anchor_ns=0, realtime=False))
    p.start()
    loop = asyncio.get_running_loop()
    swaps = []
    try:
        assert await asyncio.to_thread(p.wait_ready, 120.0), p.failed
        p.attach(loop, swaps.append)
        p.submit("assignment", assignment(1, maps(1)))
        p.submit("clock", ClockEstimate(offset_ns=0.0, drift=0.0, ref_local_ns=float(time.monotonic_ns()),
                                        best_rtt_ns=100_000, samples=8))
        p.submit("content", ("grey", np.full((H, W, 3), 0.5, np.float32)))
        p.submit("frame", FrameOrder(frame_id=1, pts_ns=time.monotonic_ns() + 50 * MS, content_id="grey",
                                     space="content", apply_lut=True, tag="show"))
        # the stats sent after the still's swap: nothing else is due to the node until the next switch
        await wait_until_async(lambda: (p.stats.blend_id, p.stats.shown), lambda got: got == (maps(1).blend_id, 1),
                               what="the still shown with the first maps", timeout=60)
        before = p.received["stats"]
        for i, m in enumerate((maps(2), maps(1), maps(2))):
            at = time.monotonic_ns() + 300 * MS
            p.submit("assignment", assignment(2 + i, m, at))
            await wait_until_async(lambda: (p.stats.blend_id, p.stats.revision),
                                   lambda got, m=m, i=i: got == (m.blend_id, 2 + i),
                                   what=f"switch {i}: the maps on screen", timeout=60)
            assert p.stats.blend_since_rig_ns >= at, "shown from their instant, not before"
        assert p.received["stats"] - before == 3, \
            f"{p.received['stats'] - before} stats messages for 3 switches: one a switch expected"
        assert [s.frame_id for s in swaps if hasattr(s, "frame_id")][:1] == [1]
    finally:
        p.detach(loop)
        await asyncio.to_thread(p.stop)


def test_a_blend_switch_for_a_later_instant_sends_the_node_one_stats_message():
    asyncio.run(_three_switches())
