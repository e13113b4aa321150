"""The node's report stream sends a heartbeat at once when the fetcher has news for the operator
(an asset ready, or given up on), one per event and never per progress byte, and keeps its
regular heartbeats; the fetcher calls ``on_change`` exactly for that news (plain objects, a real
cache on disk, a scripted link)."""
from __future__ import annotations

import asyncio
import itertools
import time

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


async def until(cond, timeout: float = 10.0) -> None:
    deadline = time.monotonic() + timeout
    while not cond():
        assert time.monotonic() < deadline
        await asyncio.sleep(0.005)


def test_news_sends_one_heartbeat_at_once_and_swaps_none(tmp_path):
    node = Node(NodeConfig(slot="r0c0", token=b"x" * 32, cache_dir=tmp_path / "cache"))
    beats = []
    node._heartbeat = lambda: beats.append(time.monotonic()) or object()

    async def go():
        node._reports = asyncio.Queue()
        link = ReportLink()
        node.fetcher.on_change()               # news from before the session: its first heartbeat covers it
        task = asyncio.create_task(node._report_stream(link, 60.0, batch_s=0.01))
        try:
            await until(lambda: link.heartbeats() == 1)
            await asyncio.sleep(0.1)
            assert link.heartbeats() == 1 and len(link.batches) == 1

            node.fetcher.on_change()          # an asset ready: one heartbeat, long before the regular one
            node.fetcher.on_change()          # in the same instant: the same heartbeat
            await until(lambda: link.heartbeats() == 2)

            node._report(SwapRecord(1, 0, 0, 0))
            node._report(SwapRecord(2, 0, 0, 0))
            await until(lambda: len(link.batches) == 3)
            assert link.batches[2].heartbeat is None and [s.frame_id for s in link.batches[2].swaps] == [1, 2]

            node.fetcher.on_change()          # given up on another: one more
            await until(lambda: link.heartbeats() == 3)
            await asyncio.sleep(0.1)
            assert link.heartbeats() == 3 and len(link.batches) == 4
        finally:
            task.cancel()
            await asyncio.gather(task, return_exceptions=True)

    asyncio.run(go())


def test_regular_heartbeats_go_on_and_news_restarts_the_period(tmp_path):
    node = Node(NodeConfig(slot="r0c0", token=b"x" * 32, cache_dir=tmp_path / "cache"))
    beats: list[float] = []
    node._heartbeat = lambda: beats.append(time.monotonic()) or object()

    async def go():
        node._reports = asyncio.Queue()
        link = ReportLink()
        task = asyncio.create_task(node._report_stream(link, 0.5))
        try:
            await until(lambda: len(beats) == 3)          # regular ones
            node.fetcher.on_change()
            await until(lambda: len(beats) == 4)
            await until(lambda: len(beats) == 5)
        finally:
            task.cancel()
            await asyncio.gather(task, return_exceptions=True)
        gaps = [b - a for a, b in itertools.pairwise(beats)]
        assert min(gaps[:2]) >= 0.49                      # the period holds between regular ones
        assert gaps[3] >= 0.49                            # after the extra one, a full period again

    asyncio.run(go())


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
            await asyncio.sleep(0)


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
        await until(lambda: all(p.ready or p.error for p in fetcher.progress())
                    and len(fetcher.progress()) == len(link.wanted_ids))
        await asyncio.sleep(0.05)
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


def test_timeline_ticks_wait_for_the_heartbeat_and_streamed_frames_do_not(tmp_path):
    """A show's ticks travel with the next heartbeat (one message), a streamed frame's swap within
    the short batch, carrying the ticks waiting with it; nothing is lost or reordered."""
    node = Node(NodeConfig(slot="r0c0", token=b"x" * 32, cache_dir=tmp_path / "cache"))
    node._heartbeat = lambda: object()

    async def go():
        node._reports = asyncio.Queue()
        link = ReportLink()
        task = asyncio.create_task(node._report_stream(link, 0.6, batch_s=0.01, timeline_batch_s=5.0))
        try:
            await until(lambda: link.heartbeats() == 1)
            for k in range(5):
                node._report(SwapRecord(100 + k, 0, 0, 0, timeline=True))
                await asyncio.sleep(0.02)
            assert len(link.batches) == 1                  # the ticks wait ...
            await until(lambda: link.heartbeats() == 2)    # ... for the heartbeat, and go with it
            hb = link.batches[-1]
            assert len(link.batches) == 2 and [s.frame_id for s in hb.swaps] == [100, 101, 102, 103, 104]
            node._report(SwapRecord(105, 0, 0, 0, timeline=True))
            node._report(DropRecord(106, DropReason.LATE, timeline=True))
            node._report(SwapRecord(900, 0, 0, 0))         # a still: it goes at once, with the ticks before it
            await until(lambda: len(link.batches) == 3)
            b = link.batches[2]
            assert b.heartbeat is None and [s.frame_id for s in b.swaps] == [105, 900]
            assert [d.frame_id for d in b.drops] == [106]
        finally:
            task.cancel()
            await asyncio.gather(task, return_exceptions=True)

    asyncio.run(go())
