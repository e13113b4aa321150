"""`shadowless swarm`: protocol-level nodes in one process against a real coordinator process.

Eight swarm nodes find the coordinator over mDNS (on 127.0.0.1), join with the rig token, fetch
their share of an asset, follow a looping timeline (the coordinator's status shows them live, with
swaps of the show's ticks in its sync figures) and a played live sequence (every node receives
every frame and reports it swapped or late). A swarm node and a real node keep their clock
estimates the same way across coordinator restarts: they run one session core.
"""
from __future__ import annotations

import argparse
import asyncio
import signal
import socket
import subprocess
import sys
import time

import numpy as np
import pytest
from inprocess_coordinator import inprocess_coordinator
from waits import wait_until, wait_until_async

from coordinator.api import NodeState, PlaySettings
from coordinator.assets import AssetStore
from coordinator.rig import Rig
from node.app import Node, NodeConfig
from node.image_files import write_png
from node.link import CoordinatorLink
from node.session import SessionCore
from protos.timeline import Schedule, Timeline, as_rate
from shadowless.local import LocalRig
from shadowless.swarm import Swarm, SwarmConfig, configure, default_slots
from shadowless.swarm_config import SwarmStats
from shadowless.swarm_node import SwarmNode, Ticker, next_tick

N = 8


def _frames(folder, n=4, w=32, h=24):
    folder.mkdir()
    for i in range(n):
        write_png(folder / f"{i:03d}.png", np.full((h, w, 3), 40 * i, np.uint8))


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

                await wait_until_async(ready, what="every swarm node live with the asset")
                assert swarm.stats.joins == N and swarm.stats.assets_ready == N
                assert swarm.stats.blobs_verified == N          # one blob each (4 blobs: each fetched twice)

                play = await c.play_asset("clip", loop=True, delay_s=0.3)
                base = play.frame_id_base

                async def swapped():
                    st = await c.status()
                    return st if all(n.last_swap_frame >= base + 20 for n in st.nodes) else None

                st = await wait_until_async(swapped, what="every swarm node to report 20 ticks of the show")
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
        # every swap the swarm woke up for on time is in the histogram of wake-up lateness, and the
        # fraction on time is of those against the ones it woke up for too late
        assert sum(out["swap_wake_late_ms_hist"].values()) == out["swaps"] > 0
        assert out["on_time_fraction"] == round(out["swaps"] / (out["swaps"] + out["woke_late"]), 5)
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


def test_settled_pings_take_0_as_the_help_says_and_refuse_what_lies_between():
    # bench swarm --rates dense passes 0 (a ping at --ping-hz always); 0 < S < 1 would flood the coordinator
    p = argparse.ArgumentParser()
    configure(p)
    assert p.parse_args(["--nodes", "2", "--ping-settled-s", "0"]).ping_settled_s == 0
    assert p.parse_args(["--nodes", "2", "--ping-settled-s", "60"]).ping_settled_s == 60
    for bad in ("0.5", "61", "-1"):
        with pytest.raises(SystemExit):
            p.parse_args(["--nodes", "2", "--ping-settled-s", bad])


@pytest.mark.parametrize("bad", [{"slots": []}, {"slots": ["a", "a"]}, {"slots": ["a"], "fetch": "some"}])
def test_config_errors(bad):
    with pytest.raises(ValueError):
        SwarmConfig(token=b"x" * 32, **bad)


#: the rig clock of the last coordinator in the restart test runs this far ahead of the host's
SHIFT_NS = 3_600_000_000_000


def _listening(target: str) -> bool:
    host, port = target.rsplit(":", 1)
    try:
        socket.create_connection((host, int(port)), timeout=1.0).close()
        return True
    except OSError:
        return False


def test_the_node_and_the_swarm_keep_their_clocks_the_same_way_across_a_coordinator_restart(tmp_path):
    """A real node's session core and a swarm node's, joined to a coordinator process: restarted on
    this host (the same rig clock, CLOCK_MONOTONIC of this boot), both keep their clock estimates
    and settle nothing anew; then a coordinator with another rig clock (an hour ahead): both drop
    their estimates and measure the new clock."""
    rig = LocalRig(["r0c0", "r0c1"], tmp_path, mdns=False)
    rig.create()
    node = Node(NodeConfig(slot="r0c0", token=rig.token, cache_dir=tmp_path / "cache"))

    async def go():
        gate = asyncio.Semaphore(1)
        swarm_node = SwarmNode("r0c1", 0, SwarmConfig(slots=["r0c1"], token=rig.token), SwarmStats(),
                               Ticker(asyncio.get_running_loop()), targets=None, join_gate=gate, fetch_gate=gate)
        cores: dict[str, SessionCore] = {"node": node.session, "swarm": swarm_node.session}

        async def join_all(target: str) -> dict:
            """Each core joins ``target``: (the join, the estimate right after it, the one after pings)."""
            out = {}
            for name, core in cores.items():
                async with CoordinatorLink(target) as link:
                    joined = await core.join(link)
                    before = core.estimator.estimate
                    await core.ping_burst(link)
                out[name] = (joined, before, core.estimator.estimate)
            return out

        def restart() -> None:
            rig.stop_coordinator()
            rig.start_coordinator()
            wait_until(lambda: _listening(rig.target), what=f"the coordinator listening at {rig.target}")

        try:
            rig.start_coordinator()
            wait_until(lambda: _listening(rig.target), what=f"the coordinator listening at {rig.target}")
            first = await join_all(rig.target)
            restart()
            second = await join_all(rig.target)
        finally:
            rig.stop_coordinator()
        async with inprocess_coordinator(Rig(rig.rig_dir), rig.token,
                                         clock_ns=lambda: time.monotonic_ns() + SHIFT_NS) as app:
            third = await join_all(f"127.0.0.1:{app.port}")
        return first, second, third

    try:
        first, second, third = asyncio.run(go())
    finally:
        rig.close()
    def offset_ns(est) -> int:
        now = time.monotonic_ns()          # local time is host time here (no clock hooks)
        return est.rig_time(now) - now

    for name in ("node", "swarm"):
        joined, before, after = first[name]
        assert not joined.clock_kept and before is None and after is not None, name
        assert abs(offset_ns(after)) < 50_000_000, name          # this host's own clock: no offset to speak of

        joined, before, after = second[name]
        assert joined.reply.instance_id != first[name][0].reply.instance_id, name   # a new instance ...
        assert joined.reply.clock_id == first[name][0].reply.clock_id, name          # ... on the same clock
        assert joined.clock_kept and joined.previous_instance == first[name][0].reply.instance_id, name
        assert before == first[name][2], f"{name}: the estimate from before the restart carried over"

        joined, before, after = third[name]
        assert joined.reply.clock_id != second[name][0].reply.clock_id, name
        assert not joined.clock_kept and before is None, f"{name}: another rig clock drops the estimate"
        assert abs(offset_ns(after) - SHIFT_NS) < 50_000_000, f"{name}: and the new clock is measured"
    assert {k: v[0].clock_kept for k, v in second.items()} == {"node": True, "swarm": True}


def test_a_killed_coordinator_is_one_session_lost_per_swarm_node(tmp_path):
    """Every stream of a swarm node's session breaks when its coordinator is killed; that is one loss of
    the coordinator, counted once (``swarm_sessions_lost`` of `bench swarm`), not once per stream."""
    slots = ["r0c0", "r0c1", "r0c2"]
    rig = LocalRig(slots, tmp_path, mdns=False)
    rig.create()

    async def go():
        swarm = Swarm(SwarmConfig(slots=slots, token=rig.token, coordinator=rig.target, backoff_max_s=0.5))
        await swarm.start()
        try:
            async with await rig.client() as c:
                async def live():
                    st = await c.status()
                    return st if sum(n.state == NodeState.LIVE for n in st.nodes) == len(slots) else None

                await wait_until_async(live, what="every swarm node live")
            rig.stop_coordinator(signal.SIGKILL)
            await wait_until_async(lambda: swarm.stats.sessions_lost, lambda n: n >= len(slots),
                                   what=f"each of {len(slots)} swarm nodes to count its loss (sessions lost)")
            # each node counts a loss in one pass over its session's ended streams: past one per node
            # the count would have jumped by several at once
            assert swarm.stats.sessions_lost == len(slots), swarm.stats.sessions_lost
        finally:
            await swarm.stop()

    rig.start_coordinator()
    try:
        asyncio.run(go())
    finally:
        rig.close()
