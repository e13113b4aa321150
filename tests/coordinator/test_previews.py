"""The coordinator's previews (console thumbnails): a node's preview crosses the wire as it was
made; only bounded ones answering a request are kept; nodes are asked only while a thumbnail is
wanted, about once a second."""
from __future__ import annotations

import asyncio

import numpy as np
import pytest

from coordinator import previews as previews_mod
from coordinator.wire import node_messages
from coordinator.previews import MAX_PNG_BYTES, Preview, Previews, png_header
from node import wire as node_wire
from node.image_files import encode_png
from node.records import PreviewRecord, ReportBatch
from protos import node_pb2
from waits import wait_until_async


class Clock:
    def __init__(self):
        self.t = 100.0

    def __call__(self) -> float:
        return self.t


def png(w: int, h: int, value: int = 90) -> bytes:
    return encode_png(np.full((h, w, 3), value, np.uint8))


def preview(request_id: int, w: int = 160, h: int = 90, **kw) -> Preview:
    return Preview(request_id=request_id, frame_id=kw.pop("frame_id", 5), png=kw.pop("data", None) or png(w, h),
                   width=w, height=h, **kw)


def test_a_preview_crosses_the_report_wire_as_the_node_made_it():
    data = png(64, 36)
    rec = PreviewRecord(request_id=12, frame_id=3456, png=data, width=64, height=36, output_width=1920,
                        output_height=1080)
    msg = node_pb2.NodeReport.FromString(node_wire.report_message(ReportBatch(preview=rec)).SerializeToString())
    rep = node_messages.report_from_message(msg)
    assert rep.preview == Preview(12, 3456, data, 64, 36, 1920, 1080)
    assert rep.heartbeat is None and len(rep.swaps) == 0
    assert node_messages.report_from_message(node_pb2.NodeReport()).preview is None     # an older node: none
    assert node_wire.preview_request_from_message(node_messages.preview_request_message(7)) == 7


def test_only_bounded_pngs_answering_a_request_are_kept():
    clock = Clock()
    p = Previews(clock)
    assert png_header(png(160, 90)) == (160, 90, 8, 2)
    assert not p.accept("r0c0", preview(1)), "nothing was asked"
    p._asked_id["r0c0"] = 3                         # requests 1..3 sent
    assert not p.accept("r0c0", preview(4)), "not asked yet"
    assert not p.accept("r0c0", preview(2, 161, 90)), "too wide"
    assert not p.accept("r0c0", preview(2, 160, 121)), "too tall"
    assert not p.accept("r0c0", preview(2, data=b"GIF89a" + bytes(100))), "not a PNG"
    assert not p.accept("r0c0", preview(2, 100, 50, data=png(80, 50))), "its header disagrees"
    grey = encode_png(np.full((90, 160), 7, np.uint8))
    assert not p.accept("r0c0", preview(2, data=grey)), "not RGB"
    noise = np.random.default_rng(1).integers(0, 256, (120, 160, 3), np.uint8)
    assert len(encode_png(noise, compress_level=0)) <= MAX_PNG_BYTES    # a node's largest fits
    assert not p.accept("r0c0", preview(2, data=png(160, 90) + bytes(MAX_PNG_BYTES))), "too many bytes"
    assert p.refused == 8 and p.thumbnail("r0c0") is None
    assert p.accept("r0c0", preview(2, frame_id=77))
    clock.t += 1.5
    t = p.thumbnail("r0c0")
    assert t.preview.frame_id == 77 and clock() - t.received_s == pytest.approx(1.5)
    assert not p.accept("r0c0", preview(2)) and not p.accept("r0c0", preview(1)), "answered already"
    assert p.accept("r0c0", preview(3)) and p.received == {"r0c0": 2}


def test_nodes_are_asked_only_while_a_thumbnail_is_wanted(monkeypatch):
    monkeypatch.setattr(previews_mod, "ASK_EVERY_S", 0.05)
    clock = Clock()
    p = Previews(clock)

    async def go():
        wake, closed = asyncio.Event(), [False]
        got: list[int] = []

        async def node():
            async for rid in p.asks("r0c0", wake, lambda: closed[0]):
                got.append(rid)

        async def one_pass(what: str) -> None:
            """Wake the stream and wait until it went to sleep again: it looked at the clock and
            the wanted slots once more (it clears ``wake`` whenever it decides not to ask now)."""
            wake.set()
            await wait_until_async(lambda: not wake.is_set(), what=f"the stream asleep again ({what})")

        task = asyncio.create_task(node())
        await one_pass("nobody looks")
        assert got == [] and p.asked == {}, "nobody looks: nothing asked"
        p.want("r0c0")
        await wait_until_async(lambda: list(got), lambda g: len(g) >= 1, what="the first request")
        assert got == [1]
        for k in range(3):                  # once per ASK_EVERY_S while wanted
            await one_pass("the clock not moved")
            assert len(got) == 1 + k, "asked again before ASK_EVERY_S passed"
            clock.t += previews_mod.ASK_EVERY_S
            await wait_until_async(lambda: list(got), lambda g, k=k: len(g) >= 2 + k, what=f"request {2 + k}")
        assert got == [1, 2, 3, 4]
        clock.t += previews_mod.WANTED_FOR_S     # nobody fetched it since: the node is no longer asked
        await one_pass("the thumbnail no longer wanted")
        clock.t += 1.0
        await one_pass("a second later")
        assert got == [1, 2, 3, 4] and p.asked["r0c0"] == 4
        p.want("r0c1")                      # another slot's thumbnail: not this node's business
        await one_pass("another slot wanted")
        assert len(got) == 4
        closed[0] = True                    # the session ends: so does the stream
        wake.set()
        await asyncio.wait_for(task, 60.0)

    asyncio.run(go())
