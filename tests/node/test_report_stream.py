"""The node's report stream, end to end on an event loop: the fetcher's news (an asset ready, or
given up on) sends one heartbeat at once, never one per progress byte; swaps go in batches; a
show's ticks wait for the heartbeat unless a streamed frame takes them along. The fetcher calls
``on_change`` exactly for that news (plain objects, a real cache on disk, a scripted link).

When things are sent is :mod:`node.report_batch`'s to decide, and tests/node/test_report_batch.py
checks it with the instants it chooses; here every step waits for the message it causes, and
what came before is judged by what each message holds.
"""
from __future__ import annotations

import asyncio

from waits import wait_until_async

from node.app import Node, NodeConfig
from node.asset_fetch import AssetFetcher
from node.link import LinkError
from node.records import BlobChunkData, DropReason, DropRecord, SwapRecord, WantedAssets
from protos.asset_manifest import Blob, Manifest, sha256_hex


class ReportLink:
    """Collects what the report stream sends."""

    def __init__(self):
        self.batches = []

    async def report(self, batches):
        async for b in batches:
            self.batches.append(b)

    def heartbeats(self) -> int:
        return sum(b.heartbeat is not None for b in self.batches)


def a_node(tmp_path) -> Node:
    node = Node(NodeConfig(slot="r0c0", token=b"x" * 32, cache_dir=tmp_path / "cache"))
    node._heartbeat = object       # no presenter here: any object stands for the heartbeat's record
    return node


def with_stream(node: Node, body, heartbeat_s: float, **batching) -> None:
    """Run the node's report stream on a collecting link while ``await body(link)`` drives it."""
    async def go():
        link = ReportLink()
        task = asyncio.create_task(node._report_stream(link, heartbeat_s, **batching))
        try:
            await body(link)
            assert not task.done(), task
        finally:
            task.cancel()
            await asyncio.gather(task, return_exceptions=True)

    asyncio.run(go())


async def batches(link: ReportLink, n: int, what: str) -> list:
    return await wait_until_async(lambda: list(link.batches), lambda bs: len(bs) >= n, what=what)


def test_news_sends_one_heartbeat_at_once_and_swaps_none(tmp_path):
    node = a_node(tmp_path)

    async def body(link):
        node.fetcher.on_change()              # news from before the session: its first heartbeat covers it
        await batches(link, 1, "the session's first heartbeat")
        node.fetcher.on_change()              # an asset ready: one heartbeat, long before the regular one (60 s)
        node.fetcher.on_change()              # in the same instant: the same heartbeat
        await wait_until_async(link.heartbeats, lambda n: n >= 2, what="the heartbeat the news sends")

        node._report(SwapRecord(1, 0, 0, 0))
        node._report(SwapRecord(2, 0, 0, 0))
        got = await batches(link, 3, "the swaps' batch")
        # had the double news, or the news before the session, sent a heartbeat of its own, it
        # would have gone before the swaps were even reported
        assert len(got) == 3 and link.heartbeats() == 2
        assert got[2].heartbeat is None and [s.frame_id for s in got[2].swaps] == [1, 2]

        node.fetcher.on_change()              # given up on another: one more
        node._report(SwapRecord(3, 0, 0, 0))  # reported in the same instant: it rides with that heartbeat
        got = await batches(link, 4, "the next heartbeat")
        assert got[3].heartbeat is not None and [s.frame_id for s in got[3].swaps] == [3]
        node._report(SwapRecord(4, 0, 0, 0))
        got = await batches(link, 5, "the batch after it")
        assert len(got) == 5 and link.heartbeats() == 3 and [s.frame_id for s in got[4].swaps] == [4]

    with_stream(node, body, 60.0, batch_s=0.01)


def test_regular_heartbeats_go_on_without_news(tmp_path):
    node = a_node(tmp_path)

    async def body(link):
        got = await batches(link, 3, "three regular heartbeats")
        assert all(b.heartbeat is not None and not b.swaps for b in got[:3])

    with_stream(node, body, 0.2)


def test_timeline_ticks_wait_for_the_heartbeat_and_streamed_frames_do_not(tmp_path):
    """A show's ticks travel with the next heartbeat (one message), a streamed frame's swap within
    the short batch, carrying the ticks waiting with it; nothing is lost or reordered."""
    node = a_node(tmp_path)

    async def body(link):
        await batches(link, 1, "the session's first heartbeat")
        for k in range(5):
            node._report(SwapRecord(100 + k, 0, 0, 0, timeline=True))
        node.fetcher.on_change()                            # the next heartbeat (else 60 s away)
        got = await batches(link, 2, "the heartbeat with the ticks")
        assert got[1].heartbeat is not None and [s.frame_id for s in got[1].swaps] == [100, 101, 102, 103, 104]

        node._report(SwapRecord(105, 0, 0, 0, timeline=True))
        node._report(DropRecord(106, DropReason.LATE, timeline=True))
        node._report(SwapRecord(900, 0, 0, 0))              # a still: it goes at once, with the ticks before it
        got = await batches(link, 3, "the still's batch")
        b = got[2]
        assert len(got) == 3, "the ticks did not go alone before the still"
        assert b.heartbeat is None and [s.frame_id for s in b.swaps] == [105, 900]
        assert [d.frame_id for d in b.drops] == [106]

    with_stream(node, body, 60.0, batch_s=0.01)


def test_reports_between_sessions_are_not_sent_with_the_next(tmp_path):
    node = a_node(tmp_path)
    node._report(SwapRecord(1, 0, 0, 0))           # no session: stale by the next one

    async def body(link):
        await batches(link, 1, "the session's first heartbeat")
        node._report(SwapRecord(2, 0, 0, 0))
        got = await wait_until_async(lambda: list(link.batches),
                                     lambda bs: [s.frame_id for b in bs for s in b.swaps] != [],
                                     what="the session's swap")
        assert [s.frame_id for b in got for s in b.swaps] == [2]

    with_stream(node, body, 60.0, batch_s=0.01)


# ---------------------------------------------------------------- the fetcher's news
class AssetLink:
    def __init__(self, manifests, blobs, wanted):
        self.manifests, self.blobs, self.wanted_ids = manifests, blobs, tuple(wanted)
        self.end = asyncio.Event()

    async def wanted(self):
        yield WantedAssets(1, self.wanted_ids)
        await self.end.wait()

    async def get_manifest(self, asset_id):
        if asset_id not in self.manifests:
            raise LinkError("NOT_FOUND", f"no asset {asset_id}", refused=True)
        return self.manifests[asset_id]

    async def fetch_blob(self, sha256, offset):
        data = self.blobs[sha256]
        for at in range(offset, len(data), 16 << 10):     # many chunks: progress bytes are no news
            yield BlobChunkData(at, data[at: at + (16 << 10)])


def test_the_fetcher_calls_on_change_once_per_ready_or_given_up_asset(tmp_path):
    data = bytes(range(256)) * 1000
    m = Manifest(kind="still", name="card", blobs=(Blob(sha256_hex(data), len(data), "card.png"),), width=4,
                 height=4, channels=3, bit_depth=8, frames=1, fps=0.0)
    missing = "f" * 64
    calls: list[tuple] = []
    fetcher = AssetFetcher(tmp_path / "cache", 10 << 20)
    fetcher.on_change = lambda: calls.append(fetcher.progress())

    async def go(link):
        task = asyncio.create_task(fetcher.run(link))
        await wait_until_async(fetcher.progress, lambda p: len(p) == len(link.wanted_ids)
                               and all(a.ready or a.error for a in p), what="every wanted asset ready or given up on")
        link.end.set()
        await task

    asyncio.run(go(AssetLink({m.asset_id: m.canonical()}, {m.blobs[0].sha256: data}, [m.asset_id, missing])))
    assert len(calls) == 2, calls                    # ready, then given up on; never per chunk
    first = {p.asset_id: p for p in calls[0]}
    assert first[m.asset_id].ready                   # the heartbeat it triggers carries the news
    assert "refused its manifest" in {p.asset_id: p for p in calls[1]}[missing].error

    def link():
        return AssetLink({m.asset_id: m.canonical()}, {m.blobs[0].sha256: data}, [m.asset_id])

    calls.clear()                                    # a rejoin: nothing new to tell
    asyncio.run(go(link()))
    assert calls == []
    fetcher.close()

    fetcher = AssetFetcher(tmp_path / "cache", 10 << 20)   # a restarted node: held in the cache, news once
    fetcher.on_change = lambda: calls.append(fetcher.progress())
    asyncio.run(go(link()))
    assert len(calls) == 1 and calls[0][0].ready
    fetcher.close()


# ---------------------------------------------------------------- the blend on screen
def test_other_maps_on_screen_send_one_heartbeat_at_once(tmp_path):
    """The presenter's stats naming other blend maps (or the same maps from another instant) make
    the node send a heartbeat at once; stats that change nothing of the blend do not."""
    from node.presenter_process import PresenterProcess, PresenterSettings
    from node.records import PresenterStatus

    node = a_node(tmp_path)
    proc = PresenterProcess(PresenterSettings(slot="r0c0", output_spec="offscreen", clock_offset_ns=0,
                                              clock_drift_ppm=0.0, clock_anchor_ns=0))
    proc.on_blend_change = node._news      # as Node.run wires it (the process itself is never started)
    try:
        async def body(link):
            await batches(link, 1, "the session's first heartbeat")
            proc._dispatch("stats", PresenterStatus(shown=5))                     # no blend news
            proc._dispatch("stats", PresenterStatus(shown=6, blend_id="a", blend_since_rig_ns=10))
            await wait_until_async(link.heartbeats, lambda n: n >= 2, what="the heartbeat the new maps send")
            proc._dispatch("stats", PresenterStatus(shown=7, blend_id="a", blend_since_rig_ns=10))   # the same
            node._report(SwapRecord(1, 0, 0, 0))
            got = await batches(link, 3, "the swap's batch")
            assert link.heartbeats() == 2 and got[2].heartbeat is None, "unchanged maps send no heartbeat"
            proc._dispatch("stats", PresenterStatus(shown=8))                     # back to none
            await wait_until_async(link.heartbeats, lambda n: n >= 3, what="the heartbeat for no maps")

        with_stream(node, body, 60.0, batch_s=0.01)
    finally:
        for conn in (proc._to_child, proc._from_child, *proc._child_ends):
            conn.close()
