"""Frame fan-out: each packet is serialized once and the same bytes go to every node;
a still is sent once and afterwards only referenced."""
from __future__ import annotations

import asyncio

import numpy as np

from coordinator.rig import Content, Rig, grid_slots, init_rig
from coordinator.app import CoordinatorApp
from coordinator.sessions import NodeInfo, NodeSession, Report, Swaps
from protos import common_pb2, node_pb2
from waits import wait_until_async


def make(tmp_path, n=3):
    rig = Rig(init_rig(tmp_path / "rig", name="t", slots=grid_slots(1, n), width=32, height=32,
                       content_width=32, content_height=32))

    async def build():
        coord = CoordinatorApp(rig, b"x" * 32, advertise=False).coordinator
        sessions = []
        for slot in rig.slots:
            s = NodeSession(session=slot, slot=slot, peer="test", info=NodeInfo(), instance_joins=1, joined=0.0,
                            last_seen=0.0)
            s.frames_open = True
            coord.by_slot[slot] = coord.sessions[slot] = s
            sessions.append(s)
        return coord, sessions

    return asyncio.run(build())


def packets(s: NodeSession) -> list[bytes]:
    out = list(s.packets)
    s.packets.clear()
    return out


def test_one_serialization_for_every_node_and_a_still_is_sent_once(tmp_path):
    coord, sessions = make(tmp_path)
    img = (np.random.default_rng(0).random((32, 32, 3)) * 65535).astype(np.uint16)
    coord.show(Content(img))
    first = [packets(s) for s in sessions]
    assert all(len(p) == 1 for p in first)
    assert len({id(p[0]) for p in first}) == 1, "the same bytes object is queued for every node"
    pkt = node_pb2.FramePacket.FromString(first[0][0])
    assert len(pkt.contents) == 1 and pkt.frame.content_id == pkt.contents[0].content_id
    assert pkt.contents[0].image.dtype == common_pb2.DTYPE_UINT16, "a 16-bit still stays 16-bit on the wire"

    coord.show(Content(img))   # the same still again: only a reference travels
    again = node_pb2.FramePacket.FromString(packets(sessions[0])[0])
    assert len(again.contents) == 0 and again.frame.content_id == pkt.frame.content_id
    assert again.frame.frame_id > pkt.frame.frame_id


def test_a_late_joiner_gets_the_content_others_already_have(tmp_path):
    coord, sessions = make(tmp_path)
    img = np.full((32, 32, 3), 7, np.uint8)
    coord.show(Content(img))
    for s in sessions:
        packets(s)
    sessions[1].sent_content.clear()          # as after a rejoin
    coord.on_frames_open(sessions[1])
    pkt = node_pb2.FramePacket.FromString(packets(sessions[1])[0])
    assert len(pkt.contents) == 1 and pkt.frame.pts_ns > 0
    assert not sessions[0].packets


def test_per_slot_patterns_carry_only_each_nodes_own_image(tmp_path):
    coord, sessions = make(tmp_path)
    images = {s.slot: np.full((32, 32), 10 * i, np.uint8) for i, s in enumerate(sessions)}

    async def go():
        task = asyncio.ensure_future(coord.playback.show_patterns(images, settle_s=0))
        await wait_until_async(lambda: [len(s.packets) for s in sessions], lambda queued: all(queued),
                               what="a packet queued for every node")
        got = {s.slot: node_pb2.FramePacket.FromString(packets(s)[0]) for s in sessions}
        task.cancel()
        return got

    got = asyncio.run(go())
    for slot, pkt in got.items():
        assert len(pkt.contents) == 1
        assert pkt.frame.slot_content[slot] == pkt.contents[0].content_id
        assert pkt.frame.space == node_pb2.SPACE_PROJECTOR


def test_a_silent_node_is_marked_lost_on_the_injected_clock(tmp_path):
    path = init_rig(tmp_path / "rig", name="t", slots=grid_slots(1, 2), width=32, height=32,
                    content_width=32, content_height=32)
    toml = path / "rig.toml"      # lost before the sync tracker gives up on a frame (3 s)
    toml.write_text(toml.read_text().replace("heartbeat_ms = 1000", "heartbeat_ms = 500")
                    .replace("lost_after_ms = 5000", "lost_after_ms = 2500"))
    rig = Rig(path)
    now = [5_000_000_000]

    async def go():
        coord = CoordinatorApp(rig, b"x" * 32, advertise=False, clock_ns=lambda: now[0]).coordinator
        a = coord.join(slot="r0c0", info=NodeInfo(), peer="test")
        b = coord.join(slot="r0c1", info=NodeInfo(), peer="test")
        for s in (a, b):
            coord.on_frames_open(s)
        coord.fanout.sync.expect(1, 0, "t", {"r0c0", "r0c1"})
        lost_after_ns = rig.config.lost_after_ms * 1_000_000
        now[0] += lost_after_ns // 2
        coord.on_report(b, Report())
        now[0] += lost_after_ns // 2 + 1_000_000
        coord.sweep()
        status = {n.slot: n.state.value for n in coord.status().nodes}
        assert status == {"r0c0": "lost", "r0c1": "live"}
        assert coord.live_slots() == ["r0c1"]
        assert not coord.sync.results
        coord.on_report(b, Report(swaps=Swaps.of([(1, now[0], now[0])])))
        (result,) = coord.sync.results           # the lost node is no longer waited for
        assert result.shown_by_all and result.nodes == 1 and result.missing == ()

    asyncio.run(go())


def test_a_node_that_lost_its_backlog_asks_the_live_video_for_a_keyframe(tmp_path):
    """A node whose queue overflowed lost pictures of the live stream: the coordinator's next
    picture is a keyframe (it could not decode again until the next regular one otherwise)."""
    from coordinator.live_video import LiveStream
    from coordinator.sessions import MAX_PENDING_PACKETS

    rig = Rig(init_rig(tmp_path / "rig", name="t", slots=grid_slots(1, 1), width=32, height=32,
                       content_width=32, content_height=32))

    async def go():
        coord = CoordinatorApp(rig, b"x" * 32, advertise=False).coordinator
        sess = coord.join(slot="r0c0", info=NodeInfo(), peer="test")
        live = LiveStream(width=32, height=32, channels=3, bit_depth=8, fps=30)
        coord.playback._live = live
        try:
            frame = np.zeros((32, 32, 3), np.uint8)
            first = await live.submit(frame)
            second = await live.submit(frame)
            assert first.keyframe and not second.keyframe
            for _ in range(MAX_PENDING_PACKETS + 1):        # the node stops draining its queue
                sess.push(b"packet")
            assert len(sess.packets) == 1                   # its backlog was dropped ...
            assert (await live.submit(frame)).keyframe      # ... so the next picture is a keyframe
        finally:
            live.close()

    asyncio.run(go())


def test_each_fan_out_owns_its_cache_of_encoded_contents(tmp_path):
    """Two coordinators in one process share nothing: what one's fan-out encoded is in its own
    cache only, and the other encodes it again into its own."""
    (a, a_sessions), (b, _) = make(tmp_path / "a"), make(tmp_path / "b")
    img = Content(np.full((32, 32, 3), 9, np.uint8))
    a.show(img)
    assert len(node_pb2.FramePacket.FromString(packets(a_sessions[0])[0]).contents) == 1
    kept = a.fanout.encoding.contents.get(img.content_id)
    assert kept is not None and b.fanout.encoding.contents.get(img.content_id) is None
    b.fanout.prepare([img])
    again = b.fanout.encoding.contents.get(img.content_id)
    assert again is not None and again is not kept and again == kept      # encoded anew, to the same bytes
    assert a.fanout.encoding.contents.get(img.content_id) is kept
