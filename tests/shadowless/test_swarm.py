"""`shadowless swarm`: protocol-level nodes in one process against a real coordinator process.

Eight swarm nodes find the coordinator over mDNS (on 127.0.0.1), join with the rig token, fetch
their share of an asset, follow a looping timeline (the coordinator's status shows them live, with
swaps of the show's ticks in its sync figures) and a played live sequence (every node receives
every frame and reports it swapped or late).
"""
from __future__ import annotations

import asyncio
import subprocess
import sys
import time

import numpy as np
import pytest

from coordinator.api import NodeState, PlaySettings
from coordinator.assets import AssetStore
from node.image_files import write_png
from protos.timeline import Schedule, Timeline, as_rate
from shadowless.local import LocalRig
from shadowless.swarm import Swarm, SwarmConfig, default_slots
from shadowless.swarm_node import next_tick

N = 8


def _frames(folder, n=4, w=32, h=24):
    folder.mkdir()
    for i in range(n):
        write_png(folder / f"{i:03d}.png", np.full((h, w, 3), 40 * i, np.uint8))


async def _until(check, what: str, timeout: float = 60.0):
    deadline = time.monotonic() + timeout
    while True:
        got = await check()
        if got:
            return got
        assert time.monotonic() < deadline, f"timed out waiting for {what}"
        await asyncio.sleep(0.2)


def test_swarm_joins_follows_timeline_and_live_frames(tmp_path):
    slots = default_slots(N)
    rig = LocalRig(slots, tmp_path, output_size=(32, 24), content_size=(32, 24))
    rig.create()
    _frames(tmp_path / "clip")
    AssetStore(rig.rig_dir).add(tmp_path / "clip", name="clip", fps=30)

    async def go():
        swarm = Swarm(SwarmConfig(slots=slots, token=rig.token, rig=rig.rig_name, mdns_interfaces=["127.0.0.1"]))
        await swarm.start()
        try:
            async with await rig.client() as c:
                async def ready():
                    st = await c.status()
                    ok = [n for n in st.nodes if n.state == NodeState.LIVE and n.assets_ready == 1]
                    return st if len(ok) == N else None

                await _until(ready, "every swarm node live with the asset")
                assert swarm.stats.joins == N and swarm.stats.assets_ready == N
                assert swarm.stats.blobs_verified == N          # one blob each (4 blobs: each fetched twice)

                play = await c.play_asset("clip", loop=True, delay_s=0.3)
                base = play.frame_id_base

                async def swapped():
                    st = await c.status()
                    return st if all(n.last_swap_frame >= base + 20 for n in st.nodes) else None

                st = await _until(swapped, "every swarm node to report 20 ticks of the show")
                assert st.show.state == "playing"
                assert st.sync.frames > 0 and st.sync.out_of_order == 0
                assert st.sync.skew_source == "host-clock"
                assert all(n.frames_shown > 0 for n in st.nodes)
                assert swarm.stats.ticks > 0 and swarm.stats.swaps > 0
                await c.stop_show()

                before = swarm.stats.swaps + swarm.stats.late + swarm.stats.superseded
                frames = 30
                reply = await c.play(PlaySettings(fps=30, pattern="counter", frames=frames, wait=True))
                assert reply.frames_sent == frames
                assert swarm.stats.live_frames >= N * frames       # every node received every frame
                answered = swarm.stats.swaps + swarm.stats.late + swarm.stats.superseded - before
                assert answered >= N * frames                      # and reported each as swapped or dropped

                # frames sent too close to their instant arrive late: reported as late drops, the sessions go on
                reply = await c.play(PlaySettings(fps=30, pattern="counter", frames=10, latency_ms=0.001, wait=True))
                assert reply.frames_late > 0 and swarm.stats.arrived_late > 0
                assert swarm.stats.joins == N
        finally:
            await swarm.stop()
        out = swarm.summary()
        assert out["nodes"] == N and out["errors"] == 0 and out["sessions_lost"] == 0
        assert 0.0 <= out["on_time_fraction"] <= 1.0
        assert out["cpu_s"] > 0
        return out

    rig.start_coordinator()    # no node processes: the swarm is the rig's nodes
    try:
        asyncio.run(go())
    finally:
        rig.close()


def test_next_tick_follows_changes_and_pauses():
    rate = as_rate(10)
    sch = Schedule()
    tl = Timeline(asset_id="a", frames=100, rate=rate, anchor_ns=1_000_000_000, revision=1)
    sch.offer(tl)
    bases = {1: 500}
    assert next_tick(sch, bases, 0) == (500, 1_000_000_000)
    assert next_tick(sch, bases, 1_000_000_000) == (501, 1_100_000_000)
    paused = tl.paused_at(1_250_000_000)
    assert paused.revision == 2
    sch.offer(paused)
    bases[2] = 600
    assert next_tick(sch, bases, 1_150_000_000) == (502, 1_200_000_000)
    assert next_tick(sch, bases, 1_200_000_000) == (600, 1_250_000_000)   # the held frame, once
    assert next_tick(sch, bases, 1_250_000_000) is None
    sch.offer_stop(2_000_000_000, 3)
    assert next_tick(sch, bases, 1_250_000_000) is None


def test_cli_refuses_a_rig_without_enough_slots(tmp_path):
    rig = LocalRig(default_slots(4), tmp_path)
    rig.create()
    r = subprocess.run([sys.executable, "-m", "shadowless", "swarm", "--nodes", "9", "--rig-dir", str(rig.rig_dir)],
                       capture_output=True, text=True, timeout=60, check=False)
    assert r.returncode == 2
    assert "9 swarm nodes need 9 slots, the rig has 4" in r.stderr and "rig init" in r.stderr
    r = subprocess.run([sys.executable, "-m", "shadowless", "swarm", "--help"], capture_output=True, text=True,
                       timeout=60, check=False)
    assert r.returncode == 0 and "load-test" in r.stdout.lower() and "--fetch" in r.stdout


@pytest.mark.parametrize("bad", [{"slots": []}, {"slots": ["a", "a"]}, {"slots": ["a"], "fetch": "some"}])
def test_config_errors(bad):
    with pytest.raises(ValueError):
        SwarmConfig(token=b"x" * 32, **bad)
