"""The node process's side of previews: the coordinator's requests reach the presenter at most
once per PREVIEW_EVERY_S whatever it asks (the newest one), a coordinator without previews is no
error, and a preview travels in the next report batch (plain objects and a scripted link)."""
from __future__ import annotations

import asyncio
import logging
import time

from waits import wait_until_async

from node.app import PREVIEW_EVERY_S, Node, NodeConfig
from node.link import LinkError
from node.records import PreviewRecord, SwapRecord


class Presenter:
    def __init__(self):
        self.sent: list[tuple[float, str, object]] = []

    def submit(self, kind: str, payload=None) -> None:
        self.sent.append((time.monotonic(), kind, payload))


class PreviewLink:
    """Sends the request ids the test asks with :meth:`ask` (or raises ``error``); the stream stays
    open."""

    def __init__(self, error: LinkError | None = None):
        self.error = error
        self.requests: asyncio.Queue[int] = asyncio.Queue()
        self.batches = []

    async def ask(self, *ids: int) -> None:
        """Send ``ids`` at once and return when the node has handled every one (it asks for the
        next request only after handling the last)."""
        for rid in ids:
            self.requests.put_nowait(rid)
        await self.requests.join()

    async def previews(self):
        if self.error is not None:
            raise self.error
        while True:
            rid = await self.requests.get()
            yield rid
            self.requests.task_done()

    async def report(self, batches):
        async for b in batches:
            self.batches.append(b)


def node(tmp_path) -> Node:
    n = Node(NodeConfig(slot="r0c0", token=b"x" * 32, cache_dir=tmp_path / "cache"))
    n.presenter = Presenter()
    return n


def previews(n: Node) -> list[int]:
    """The request ids the presenter was given, in order."""
    return [rid for _, kind, rid in n.presenter.sent if kind == "preview"]


def with_previews(n: Node, link_error: LinkError | None, body) -> None:
    """Run ``n._previews`` on a scripted link while ``await body(link, task)`` drives it; the task
    must not have failed when the body ends."""
    async def go():
        link = PreviewLink(link_error)
        task = asyncio.create_task(n._previews(link))
        try:
            await body(link, task)
            assert not task.done() or task.exception() is None
        finally:
            task.cancel()
            await asyncio.gather(task, return_exceptions=True)

    asyncio.run(go())


def test_a_flood_of_requests_reaches_the_presenter_once_a_window_the_newest_each_time(tmp_path):
    n = node(tmp_path)

    async def body(link, task):
        await link.ask(1)
        assert previews(n) == [1], "the first request passes at once"
        await link.ask(*range(2, 201))       # handled within microseconds, far inside the window
        assert previews(n) == [1], "requests inside the window are held back"
        sent = await wait_until_async(lambda: previews(n), lambda s: len(s) >= 2,
                                      what="the held-back request once the window has passed")
        assert sent == [1, 200], "the newest one passes, the ones in between coalesce"
        await link.ask(*range(201, 301))     # the window reopened with that send
        assert previews(n) == [1, 200]
        sent = await wait_until_async(lambda: previews(n), lambda s: len(s) >= 3, what="the next window's request")
        assert sent == [1, 200, 300]

    with_previews(n, None, body)


def test_a_request_after_the_window_passes_at_once(tmp_path):
    n = node(tmp_path)

    async def body(link, task):
        await link.ask(1)
        (sent_at, _, _), = n.presenter.sent     # on the host's clock, just after the node's own stamp
        await wait_until_async(time.monotonic, lambda now: now > sent_at + PREVIEW_EVERY_S,
                               what="the window after the first preview to pass")
        await link.ask(2)
        assert previews(n) == [1, 2], "handled without waiting for a timer"

    with_previews(n, None, body)


def test_a_coordinator_without_previews_is_no_error(tmp_path, caplog):
    n = node(tmp_path)
    caplog.set_level(logging.INFO, logger="node")

    async def body(link, task):
        await wait_until_async(lambda: task.done() or "asks for no previews" in caplog.text,
                               what="the node to note that this coordinator has no previews")
        assert not task.done(), "the session goes on without previews"

    with_previews(n, LinkError("UNIMPLEMENTED", "no Previews"), body)
    assert n.presenter.sent == []


def test_a_preview_goes_in_the_next_batch(tmp_path):
    n = node(tmp_path)
    n._heartbeat = lambda: object()
    link = PreviewLink()
    rec = PreviewRecord(request_id=4, frame_id=9, png=b"png", width=1, height=1, output_width=1, output_height=1)

    async def go():
        task = asyncio.create_task(n._report_stream(link, 60.0, batch_s=0.01))
        try:
            await wait_until_async(lambda: list(link.batches), what="the stream's first batch (its heartbeat)")
            n._report(SwapRecord(9, 0, 0, 0))
            n._report(rec)
            batches = await wait_until_async(lambda: list(link.batches), lambda bs: len(bs) >= 2,
                                             what="the batch after the swap and the preview")
            b = batches[1]
            assert b.preview == rec and [s.frame_id for s in b.swaps] == [9] and b.heartbeat is None
        finally:
            task.cancel()
            await asyncio.gather(task, return_exceptions=True)

    asyncio.run(go())
