"""The console's live loop (coordinator/console/live.py) ends when stopped, even when a poke (an
action recorded, a job's change) comes in the same instant: asyncio.wait_for on Python 3.11 drops a
cancel that meets its just-set event, and the loop ran on, so the console's stop() awaited it forever."""
from __future__ import annotations

import asyncio

from coordinator.console.audit import ActionLog
from coordinator.console.live import Live
from coordinator.rig import Rig, grid_slots, init_rig
from coordinator.server import Coordinator
from coordinator.wire.frame_packets import FramePackets

TOKEN = b"l" * 32


def test_stop_ends_when_it_meets_a_poke(tmp_path):
    rig_dir = init_rig(tmp_path / "rig", name="live", slots=grid_slots(1, 1), width=32, height=32,
                       content_width=32, content_height=32)

    async def go():
        coord = Coordinator(Rig(rig_dir), TOKEN, encoding=FramePackets)     # the core: no network
        live = Live(coord, ActionLog(rig_dir), max_hz=0.01)    # a 100 s period: the loop sits in its wait
        live.start()
        for _ in range(5):      # the loop reaches its wait for a poke
            await asyncio.sleep(0)
        live.poke()             # an action recorded right as the console stops
        async with asyncio.timeout(10):     # with the old wait_for loop, stop() never returned
            await live.stop()

    asyncio.run(go())
