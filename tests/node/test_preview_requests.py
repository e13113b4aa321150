"""The node process's side of previews: the coordinator's requests reach the presenter at most
twice a second whatever it asks (the newest one), a coordinator without previews is no error,
and a preview travels in the next report batch (plain objects and a scripted link)."""
from __future__ import annotations

import asyncio
import time

from node.app import PREVIEW_EVERY_S, Node, NodeConfig
from node.link import LinkError
from node.records import PreviewRecord, SwapRecord


class Presenter:
    def __init__(self):
        self.sent: list[tuple[float, str, object]] = []

    def submit(self, kind: str, payload=None) -> None:
        self.sent.append((time.monotonic(), kind, payload))


class PreviewLink:
    """Sends the request ids given, ``gap_s`` apart; then stays open (or raises ``error``)."""

    def __init__(self, ids: list[int], gap_s: float, error: LinkError | None = None):
        self.ids, self.gap_s, self.error = ids, gap_s, error
        self.batches = []

    async def previews(self):
        if self.error is not None:
            raise self.error
        for rid in self.ids:
            yield rid
            await asyncio.sleep(self.gap_s)
        await asyncio.Event().wait()

    async def report(self, batches):
        async for b in batches:
            self.batches.append(b)


def node(tmp_path) -> Node:
    n = Node(NodeConfig(slot="r0c0", token=b"x" * 32, cache_dir=tmp_path / "cache"))
    n.presenter = Presenter()
    return n


def run_for(coro, seconds: float) -> None:
    async def go():
        task = asyncio.create_task(coro)
        await asyncio.sleep(seconds)
        assert not task.done() or task.exception() is None
        task.cancel()
        await asyncio.gather(task, return_exceptions=True)

    asyncio.run(go())


def test_a_flood_of_requests_reaches_the_presenter_twice_a_second_the_newest_each_time(tmp_path):
    n = node(tmp_path)
    t0 = time.monotonic()
    run_for(n._previews(PreviewLink(list(range(1, 201)), 0.005)), 2.2)   # 200 requests in ~1 s
    sent = [(t, rid) for t, kind, rid in n.presenter.sent if kind == "preview"]
    gaps = [b[0] - a[0] for a, b in zip(sent, sent[1:])]
    assert min(gaps) >= PREVIEW_EVERY_S - 0.01
    assert len(sent) <= (sent[-1][0] - t0) / PREVIEW_EVERY_S + 1.5, sent
    # the first at once, then the newest each time, the last one asked included
    assert sent[0][1] == 1 and sent[-1][1] == 200 and [rid for _, rid in sent] == sorted({rid for _, rid in sent})


def test_requests_a_second_apart_pass_at_once(tmp_path):
    n = node(tmp_path)
    run_for(n._previews(PreviewLink([1, 2, 3], 0.6)), 1.5)
    assert [rid for _, kind, rid in n.presenter.sent if kind == "preview"] == [1, 2, 3]


def test_a_coordinator_without_previews_is_no_error(tmp_path):
    n = node(tmp_path)
    run_for(n._previews(PreviewLink([], 0, LinkError("UNIMPLEMENTED", "no Previews"))), 0.2)
    assert n.presenter.sent == []


def test_a_preview_goes_in_the_next_batch(tmp_path):
    n = node(tmp_path)
    n._heartbeat = lambda: object()
    link = PreviewLink([], 0)
    rec = PreviewRecord(request_id=4, frame_id=9, png=b"png", width=1, height=1, output_width=1, output_height=1)

    async def go():
        n._reports = asyncio.Queue()
        task = asyncio.create_task(n._report_stream(link, 60.0, batch_s=0.01))
        try:
            for _ in range(100):
                if link.batches:
                    break
                await asyncio.sleep(0.01)
            n._report(SwapRecord(9, 0, 0, 0))
            n._report(rec)
            for _ in range(200):
                if len(link.batches) >= 2:
                    break
                await asyncio.sleep(0.01)
            b = link.batches[1]
            assert b.preview == rec and [s.frame_id for s in b.swaps] == [9] and b.heartbeat is None
        finally:
            task.cancel()
            await asyncio.gather(task, return_exceptions=True)

    asyncio.run(go())
