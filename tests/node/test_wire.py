"""node/wire.py: the node's records to and from the coordinator's protobuf messages (the wire format)."""
from __future__ import annotations

import numpy as np
import pytest

from node import wire
from node.records import (
    ClockStatus,
    DropReason,
    DropRecord,
    HeartbeatRecord,
    JoinRequest,
    NodeInfo,
    ReportBatch,
    SwapRecord,
)
from protos import codec, common_pb2, node_pb2


def test_reports_keep_the_wire_format():
    swap = SwapRecord(frame_id=7, pts_ns=-5, swap_rig_ns=1_000_000_123, host_monotonic_ns=42)
    # columns, each value after the first the difference to the one before (a frame reported out of order too)
    swaps = [swap, SwapRecord(8, 1, 1_033_333_456, 33_333_375), SwapRecord(6, 1, 1_066_666_789, 66_666_708)]
    assert wire.swaps_message(swaps) == node_pb2.Swaps(frame_id=[7, 1, -2],
                                                       swap_rig_ns=[1_000_000_123, 33_333_333, 33_333_333],
                                                       host_monotonic_ns=[42, 33_333_333, 33_333_333])
    expected = {DropReason.LATE: node_pb2.DROP_REASON_LATE, DropReason.SUPERSEDED: node_pb2.DROP_REASON_SUPERSEDED,
                DropReason.MISSING_CONTENT: node_pb2.DROP_REASON_MISSING_CONTENT,
                DropReason.UNRENDERABLE: node_pb2.DROP_REASON_UNRENDERABLE,
                DropReason.OTHER: node_pb2.DROP_REASON_UNSPECIFIED}
    assert set(expected) == set(DropReason)
    for reason, number in expected.items():
        assert wire.drop_message(DropRecord(3, reason, 9)) == node_pb2.FrameDrop(frame_id=3, reason=number, late_by_ns=9)

    batch = ReportBatch(swaps=(swap, SwapRecord(8, 1, 2, 3)), drops=(DropRecord(9, DropReason.LATE, 4),))
    msg = wire.report_message(batch)
    assert not msg.HasField("heartbeat")
    assert list(msg.swaps.frame_id) == [7, 1] and [d.frame_id for d in msg.drops] == [9]
    assert node_pb2.NodeReport.FromString(msg.SerializeToString()) == msg


def test_heartbeats_carry_the_clock_only_once_there_is_an_estimate():
    base = dict(assignment_revision=4, frames_shown=10, frames_late=2, frames_dropped=1, render_ms_p50=1.5,
                host_monotonic_ns=123)
    msg = wire.report_message(ReportBatch(heartbeat=HeartbeatRecord(**base)))
    assert msg.heartbeat == node_pb2.Heartbeat(**base)
    clock = ClockStatus(offset_ns=-77, drift_ppm=12.5, rtt_ns=300_000, samples=6, rig_estimate_ns=456)
    hb = wire.heartbeat_message(HeartbeatRecord(**base, clock=clock))
    assert hb == node_pb2.Heartbeat(**base, clock_offset_ns=-77, clock_drift_ppm=12.5, clock_rtt_ns=300_000,
                                    clock_samples=6, rig_estimate_ns=456)


def test_handshake_messages():
    hello = wire.hello_request(protocol_version=3, client_nonce=b"n" * 32, slot="r1c1")
    assert hello == common_pb2.HelloRequest(protocol_version=3, client_nonce=b"n" * 32, role="node", slot="r1c1")
    info = NodeInfo(hostname="h", host_boot_id="b", pid=9, software_version="0.1.0", output="offscreen",
                    native_size=(640, 480))
    req = wire.join_request(JoinRequest(protocol_version=3, slot="r1c1", client_nonce=b"c", server_nonce=b"s",
                                        client_proof=b"p", info=info))
    assert req.login == common_pb2.LoginRequest(protocol_version=3, role="node", slot="r1c1", client_nonce=b"c",
                                                server_nonce=b"s", client_proof=b"p")
    assert req.info == node_pb2.NodeInfo(hostname="h", host_boot_id="b", pid=9, software_version="0.1.0",
                                         output="offscreen", native_width=640, native_height=480)
    reply = wire.join_reply_from_message(node_pb2.JoinReply(session="s1", instance_id="i1"))
    assert (reply.session, reply.instance_id, reply.heartbeat_interval_ms) == ("s1", "i1", 500)   # default interval
    pong = wire.ping_reply_from_message(node_pb2.PingReply(t0_local_ns=1, t1_rig_ns=2, t2_rig_ns=3))
    assert (pong.t1_rig_ns, pong.t2_rig_ns) == (2, 3)
    h = wire.hello_reply_from_message(common_pb2.HelloReply(rig_id="r", rig_name="n", server_nonce=b"x",
                                                            server_proof=b"y"))
    assert (h.rig_id, h.rig_name, h.server_nonce, h.server_proof) == ("r", "n", b"x", b"y")


def test_packets_become_plain_data_for_one_slot():
    pkt = node_pb2.FramePacket()
    a = np.arange(24, dtype=np.uint16).reshape(2, 4, 3)
    pkt.contents.add(content_id="a", image=codec.encode_image(a))
    pkt.contents.add(content_id="known", image=codec.encode_image(a))
    pkt.contents.add(content_id="a", image=codec.encode_image(a[:1]))     # a repeat: ignored
    bad = pkt.contents.add(content_id="bad", image=codec.encode_image(a))
    bad.image.data = b"\x00"
    pkt.frame.frame_id = 5
    pkt.frame.pts_ns = 99
    pkt.frame.content_id = "a"
    pkt.frame.slot_content["r0c1"] = ""
    pkt.frame.space = node_pb2.SPACE_PROJECTOR
    pkt.frame.apply_lut = True
    pkt.frame.tag = "play:1"
    pkt.evict.content_ids.extend(["old"])
    data = pkt.SerializeToString()

    mine = wire.packet_from_bytes(data, "r0c0", known={"known"}.__contains__)
    assert [c.content_id for c in mine.contents] == ["a", "bad"]
    np.testing.assert_array_equal(mine.contents[0].image, a)
    assert mine.contents[1].image is None and "bytes" in mine.contents[1].error
    assert (mine.frame.frame_id, mine.frame.pts_ns, mine.frame.content_id, mine.frame.space, mine.frame.apply_lut,
            mine.frame.tag) == (5, 99, "a", "projector", True, "play:1")
    assert mine.evict == ("old",)
    other = wire.packet_from_bytes(data, "r0c1")
    assert other.frame.content_id == "" and len(other.contents) == 3   # its override: black

    empty = wire.packet_from_bytes(node_pb2.FramePacket().SerializeToString(), "r0c0")
    assert empty.contents == () and empty.frame is None and empty.evict is None


def assignment_message(revision: int = 3) -> node_pb2.Assignment:
    msg = node_pb2.Assignment(revision=revision, slot="r0c0", output_width=64, output_height=48, gain=0.0,
                              content_width=32, content_height=24)
    msg.homography.m.extend(np.eye(3).ravel().tolist())
    msg.lut.channels, msg.lut.entries = 1, 4
    msg.lut.values = np.linspace(0, 1, 4, dtype="<f4").tobytes()
    alpha = np.full((2, 3, 3), 0.5, "<f2").tobytes()
    msg.blend.CopyFrom(node_pb2.Blend(width=3, height=2, alpha=alpha, beta=bytes(12), blend_id="b1", at_rig_ns=77))
    return msg


def test_assignments_become_plain_data():
    a = wire.assignment_from_message(assignment_message())
    assert (a.revision, a.pose_kind, a.width, a.height, a.gain, a.content_size) == (3, "homography", 64, 48, 1.0, (32, 24))
    np.testing.assert_array_equal(a.homography, np.eye(3))
    assert a.lut.shape == (1, 4) and a.mesh is None
    assert (a.blend.blend_id, a.blend.size, a.blend_at_ns, a.blend_error) == ("b1", (3, 2), 77, "")
    assert a.received_host_ns <= a.decoded_host_ns
    msg = assignment_message()
    msg.homography.m.append(1.0)
    with pytest.raises(ValueError, match="9 values"):
        wire.assignment_from_message(msg)


def projection_message(faces: list[int], *, vertices: int = 4, uvs: int | None = None) -> node_pb2.Assignment:
    msg = assignment_message()
    msg.projection.p.extend(np.eye(3, 4).ravel().tolist())        # (the homography gives way: a oneof)
    m = msg.projection.mesh
    m.mesh_id = "m1"
    m.vertices = np.zeros((vertices, 3), "<f4").tobytes()
    m.uvs = np.zeros((vertices if uvs is None else uvs, 2), "<f4").tobytes()
    m.faces = np.array(faces, "<u4").tobytes()
    return msg


def test_the_node_process_refuses_whatever_the_presenter_could_not_decode_and_nothing_else():
    """One check (:func:`node.wire.assignment_problem`, no numpy) says why for both processes: the node
    process refuses with it, and the presenter's decode raises it."""
    def spoil(change):
        msg = assignment_message()
        change(msg)
        return msg

    bad = {
        "homography needs 9 values": spoil(lambda m: m.homography.m.append(1.0)),
        "projection needs 12 values": spoil(lambda m: (m.projection.p.extend([0.0] * 11))),
        "mesh faces name vertices beyond": projection_message([0, 1, 4]),
        "mesh has 4 vertices and 3 uvs": projection_message([0, 1, 2], uvs=3),
        "mesh arrays are not whole": projection_message([0, 1]),
        "LUT message is inconsistent": spoil(lambda m: setattr(m.lut, "entries", 5)),
    }
    bad["LUT message is inconsistent (3 channels"] = spoil(lambda m: setattr(m.lut, "channels", 3))
    for why, msg in bad.items():
        rec = wire.assignment_bytes(msg)
        assert rec.problem.startswith(why), (why, rec.problem)
        with pytest.raises(ValueError) as raised:
            wire.assignment_from_message(node_pb2.Assignment.FromString(rec.data))
        assert str(raised.value) == rec.problem
    good = {"homography": assignment_message(), "projection": projection_message([0, 1, 2, 3, 2, 1])}
    blend = assignment_message()
    blend.blend.beta = b"\x00"                                     # maps that cannot be used: no refusal
    for what, msg in {**good, "a bad blend": blend}.items():
        rec = wire.assignment_bytes(msg)
        assert rec.problem == "", what
        wire.assignment_from_bytes(rec)
    assert wire.assignment_from_bytes(wire.assignment_bytes(blend)).blend_error


def test_the_node_process_passes_an_assignment_on_as_bytes_that_a_renumbering_leaves_alone():
    rec = wire.assignment_bytes(assignment_message(3))
    assert rec.revision == 3 and rec.received_host_ns > 0
    assert wire.assignment_bytes(assignment_message(9)).data == rec.data          # renumbered alone: the same bytes
    changed = assignment_message(3)
    changed.blend.at_rig_ns = 78
    assert wire.assignment_bytes(changed).data != rec.data
    # the presenter process's side: the same assignment as decoding the message there would give
    a, direct = wire.assignment_from_bytes(rec), wire.assignment_from_message(assignment_message(3))
    assert a.revision == 3 and a.received_host_ns == rec.received_host_ns <= a.decoded_host_ns
    for name in ("pose_kind", "width", "height", "gain", "content_size", "blend_at_ns", "blend_error"):
        assert getattr(a, name) == getattr(direct, name), name
    np.testing.assert_array_equal(a.homography, direct.homography)
    np.testing.assert_array_equal(a.lut, direct.lut)
    assert a.blend.blend_id == direct.blend.blend_id and a.blend.encode() == direct.blend.encode()
    with pytest.raises(ValueError, match="not an assignment"):
        wire.assignment_from_bytes(type(rec)(revision=4, data=b"\xff\xff\xff"))


def test_asset_calls_and_progress_keep_the_wire_format():
    from node.records import AssetProgressRecord

    a, b = "a" * 64, "b" * 64
    wanted = wire.wanted_from_message(node_pb2.WantedAssets(revision=3, asset_ids=[a, b], pinned_ids=[b]))
    assert (wanted.revision, wanted.asset_ids, wanted.pinned_ids) == (3, (a, b), (b,))
    assert wire.manifest_request(a) == node_pb2.ManifestRequest(asset_id=a)
    assert wire.blob_request(b, 1 << 20) == node_pb2.BlobRequest(sha256=b, offset=1 << 20)
    chunk = wire.blob_chunk_from_message(node_pb2.BlobChunk(offset=7, data=b"xyz"))
    assert (chunk.offset, chunk.data) == (7, b"xyz")
    progress = (AssetProgressRecord(a, 10, 20, False, "", "clip"), AssetProgressRecord(b, 5, 5, True, "", ""),
                AssetProgressRecord("c" * 64, error="failed its hash check 3 times"))
    hb = HeartbeatRecord(assignment_revision=1, frames_shown=0, frames_late=0, frames_dropped=0, render_ms_p50=0.0,
                         host_monotonic_ns=1, assets=progress)
    msg = wire.report_message(ReportBatch(heartbeat=hb))
    assert [(p.asset_id, p.have_bytes, p.total_bytes, p.ready, p.error, p.name) for p in msg.heartbeat.assets] == [
        (p.asset_id, p.have_bytes, p.total_bytes, p.ready, p.error, p.name) for p in progress]
    assert node_pb2.NodeReport.FromString(msg.SerializeToString()) == msg


def test_the_records_both_sides_speak_come_back_the_same_from_the_coordinators_wire():
    """NodeInfo and DropReason are one definition (protos.records): what a node sends, the
    coordinator reads back as the very same records."""
    from coordinator.wire import node_messages as coordinator_wire

    info = NodeInfo(hostname="pi-7", pid=4242, host_boot_id="boot", native_size=(1920, 1080), software_version="1.2.3",
                    output="kms", gl="OpenGL ES 3.1")
    req = wire.join_request(JoinRequest(protocol_version=3, slot="r0c0", client_nonce=b"c", server_nonce=b"s",
                                        client_proof=b"p", info=info))
    assert coordinator_wire.node_info_from_message(node_pb2.JoinRequest.FromString(req.SerializeToString()).info) == info

    drops = tuple(DropRecord(i, reason) for i, reason in enumerate(DropReason))
    back = coordinator_wire.report_from_message(wire.report_message(ReportBatch(drops=drops)))
    assert back.drops == tuple((d.frame_id, d.reason) for d in drops)
