"""A node rejoining a restarted coordinator keeps what it holds: a real coordinator and node process
on loopback, a short video fetched and played by timeline, then the coordinator killed (SIGKILL)
and started again on the same rig directory mid-show.

What the node does on its return is read from its own record of it, its log: it must not fetch the
asset again, pass it to its presenter again, re-apply an unchanged assignment (pose, LUT, gain) or
take the unchanged show as a new one (which would restart its decoder), and it keeps its clock
estimate with a single exchange instead of a burst. The restarted coordinator numbers the unchanged
assignment otherwise (its slot file renumbered while it was down): the node does not pass it to its
presenter either, and reports it under the new number. Every one of these steps logs a line when it
happens (``fetching asset``, ``passed to the presenter``, the presenter's ``assignment rN: ... pose``
and a blend's ``assignment rN: blend``, ``timeline rN``, ``clock burst``), and the test first checks
that the node's first join logged them (a blend aside: this rig has none), so that their absence
after the restart means something.
"""
from __future__ import annotations

import asyncio
import re
import signal

import pytest

from coordinator.rig import Rig
from shadowless.local import LocalRig
from clip_rig import clip_rig
from waits import wait_until_async

SLOT = "r0c0"
W, H, FPS, SECONDS = 64, 48, 30, 1
SWAP = re.compile(r"timing frame (\d+): swap")
#: the presenter set a pose, LUT and gain from an assignment (one that changes the blend alone is not)
APPLIED = re.compile(r"node.presenter: assignment r\d+: \w+ pose,")
#: blend maps loaded into the renderer
BLEND_LOADED = re.compile(r"assignment r\d+: blend ")


async def node_revision(c) -> int:
    return (await c.status()).nodes[0].assignment_revision


async def node_show(c) -> tuple:
    n = (await c.status()).nodes[0]
    return n.state.value, n.show.state.value, n.show.revision, n.assets_ready


def swapped_since(rig: LocalRig, at: int, base: int) -> list[int]:
    return [i for i in (int(m.group(1)) for m in SWAP.finditer(rig.log("node-" + SLOT)[at:])) if i >= base]


@pytest.mark.allow_leaks     # the restarted coordinator belongs to the rig, stopped with it
def test_a_node_rejoining_a_restarted_coordinator_fetches_passes_and_applies_nothing_again(tmp_path):
    rig = clip_rig([SLOT], tmp_path, size=(W, H), fps=FPS, seconds=SECONDS)
    with rig:
        async def play():
            async with await rig.client() as c:
                await rig.wait_live(c)
                await wait_until_async(lambda: node_show(c), lambda s: s[0] == "live" and s[3] == 1,
                                       what="the node live and holding the clip (state, show, revision, ready)")
                p = await c.play_asset("clip", loop=True, delay_s=0.3)
                await wait_until_async(lambda: node_show(c), lambda s: s[1] == "playing" and s[2] == p.revision,
                                       what=f"the node playing revision {p.revision}")
                return p

        p = asyncio.run(play())
        first = rig.log("node-" + SLOT)
        # the steps this test then expects NOT to see again did happen on the first join
        for step in ("fetching asset", "passed to the presenter", f"node.presenter: timeline r{p.revision}:",
                     "clock burst of 8 exchanges"):
            assert step in first, step
        assert APPLIED.search(first), first[-3000:]
        since = len(first)
        rig.stop_coordinator(signal.SIGKILL)
        # the restarted coordinator numbers the same assignment otherwise (here: 3 revisions on, the slot
        # itself unchanged), as one does after a failover's blend-only revisions, which it never stored
        stored = Rig(rig.rig_dir)
        held = stored.slots[SLOT].revision
        for _ in range(3):
            renumbered = stored.update_slot(SLOT, gain=stored.slots[SLOT].gain).revision
        del stored
        rig.start_coordinator()

        async def back():
            async with await rig.client(timeout=90.0) as c:
                st = await c.status()
                assert st.show.state == "playing" and st.show.revision == p.revision   # taken back from show.json
                await rig.wait_live(c, min_joins={SLOT: 1})
                # 10 ticks of the same show swapped in after the rejoin
                await wait_until_async(lambda: swapped_since(rig, since, p.frame_id_base),
                                       lambda ids: len(ids) >= 10, what="10 ticks of the show swapped after the restart")
                shown = await wait_until_async(lambda: node_show(c), lambda s: s[1] == "playing",
                                               what="the node reporting the show it plays")
                # the node reports the new number for the assignment its presenter kept
                revision = await wait_until_async(lambda: node_revision(c), lambda r: r == renumbered,
                                                  what=f"the node reporting assignment r{renumbered}")
                await c.stop_show()
                return shown, revision

        shown, revision = asyncio.run(back())
    after = rig.log("node-" + SLOT)[since:]
    assert "same rig clock, keeping the clock estimate and the show" in after, after[-3000:]
    assert "joined rig" in after and "1 ready in the cache" in after, after[-3000:]
    assert "clock burst of 1 exchanges" in after, after[-3000:]
    # nothing it held was fetched, passed, re-applied or restarted
    assert "fetching asset" not in after and "ready: " not in after
    assert "passed to the presenter" not in after
    assert not APPLIED.search(after) and not BLEND_LOADED.search(after)
    # the renumbered assignment was recognised as the one held, and not passed to the presenter
    assert f"assignment r{renumbered} is the one the presenter holds (r{held}): not passed again" in after, after[-3000:]
    assert f"node.presenter: assignment r{renumbered}" not in after
    assert revision == renumbered
    assert f"node.presenter: timeline r{p.revision}:" not in after
    assert "resyncing" not in after
    assert shown[2] == p.revision and shown[3] == 1


def test_the_network_side_yields_the_cpu_to_the_presenter_in_every_thread():
    """yield_to_presenter, in a process of its own: every thread that ran before it (grpc's, mDNS's)
    and every thread started after it runs 10 nice steps below the process that started it (the
    presenter keeps the node's priority)."""
    import os
    import subprocess
    import sys

    script = """
import os, threading
from node.network_priority import NETWORK_NICE, yield_to_presenter
nice = lambda: os.getpriority(os.PRIO_PROCESS, threading.get_native_id())
seen, go = {}, threading.Event()
def before():
    go.wait(); seen["before"] = nice()
t = threading.Thread(target=before); t.start()
base = nice()
n = yield_to_presenter()
go.set(); t.join()
after = threading.Thread(target=lambda: seen.__setitem__("after", nice())); after.start(); after.join()
print(base, n, nice(), seen["before"], seen["after"], NETWORK_NICE)
"""
    env = {k: v for k, v in os.environ.items() if k != "SHADOWLESS_NETWORK_NICE"}
    out = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=60, check=True,
                         env=env)
    base, changed, main, before, after, step = map(int, out.stdout.split())
    assert changed >= 2                     # the main thread and the one started before
    assert main == before == after == min(19, base + step)
    assert os.getpriority(os.PRIO_PROCESS, 0) == base     # the process that started it is untouched
    # SHADOWLESS_NETWORK_NICE=0 (a benchmark measuring what the step is worth): no thread is changed
    out = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=60, check=True,
                         env={**env, "SHADOWLESS_NETWORK_NICE": "0"})
    base, changed, main, before, after, _ = map(int, out.stdout.split())
    assert changed == 0 and main == before == after == base


def test_the_network_side_s_nice_step_is_read_from_the_environment():
    from node.network_priority import NETWORK_NICE, nice_step

    assert nice_step({}) == NETWORK_NICE
    assert nice_step({"SHADOWLESS_NETWORK_NICE": "0"}) == 0
    assert nice_step({"SHADOWLESS_NETWORK_NICE": " 5 "}) == 5
    assert nice_step({"SHADOWLESS_NETWORK_NICE": "20"}) == NETWORK_NICE     # out of range: ignored
    assert nice_step({"SHADOWLESS_NETWORK_NICE": "high"}) == NETWORK_NICE
