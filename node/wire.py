"""The one place a node converts protobuf messages to and from its own plain types.

Everything the coordinator sends becomes a :mod:`node.records` dataclass (numpy arrays
inside) here, and every report the node sends is built here from one. Only this module,
:mod:`node.link` (the gRPC client) and :mod:`node.outputs.room_link` (the virtual room's
client) touch protobuf.

The node process imports this module and no numpy: what needs arrays (an assignment's pose, mesh,
LUT and blend maps, a frame packet's images) is decoded in the presenter process, by the two
functions that import numpy's users when first called (:func:`assignment_from_bytes`,
:func:`live_packet_from_bytes`). The node process passes an assignment on as its bytes
(:func:`assignment_bytes`).
"""
from __future__ import annotations

import sys
import time
import zlib
from array import array
from fractions import Fraction
from typing import TYPE_CHECKING, Callable, Sequence

from google.protobuf.message import DecodeError

from node.records import (
    AssetProgressRecord,
    AssignmentBytes,
    BlobChunkData,
    ContentBlob,
    DropReason,
    DropRecord,
    FrameOrder,
    FramePacketData,
    HeartbeatRecord,
    HelloReply,
    JoinReply,
    JoinRequest,
    MeshData,
    NodeAssignment,
    PingReply,
    PreviewRecord,
    ReportBatch,
    ShowUpdateData,
    SwapRecord,
    WantedAssets,
)
from protos import common_pb2, node_pb2
from protos.timeline import Timeline

if TYPE_CHECKING:
    from node.live_video import VideoChunk

#: DropReason <-> the wire's enum
_VIDEO_CODECS = {node_pb2.VIDEO_CODEC_H264: "h264", node_pb2.VIDEO_CODEC_HEVC: "hevc"}

_DROP_REASONS = {
    DropReason.LATE: node_pb2.DROP_REASON_LATE,
    DropReason.SUPERSEDED: node_pb2.DROP_REASON_SUPERSEDED,
    DropReason.MISSING_CONTENT: node_pb2.DROP_REASON_MISSING_CONTENT,
    DropReason.UNRENDERABLE: node_pb2.DROP_REASON_UNRENDERABLE,
    DropReason.OTHER: node_pb2.DROP_REASON_UNSPECIFIED,     # a node never decides on it; kept total
}


# ------------------------------------------------------------------ coordinator -> node


def assignment_bytes(msg: node_pb2.Assignment) -> AssignmentBytes:
    """What the node process passes on of an assignment (``msg`` loses its revision): its bytes in
    the deterministic encoding, so that an assignment the coordinator renumbered alone (a rejoin's)
    has the same bytes as the one before, the time it was received, and why the presenter could not
    take it (:func:`assignment_problem`; "" it can)."""
    received = time.monotonic_ns()
    revision = msg.revision
    msg.ClearField("revision")
    return AssignmentBytes(revision=revision, data=msg.SerializeToString(deterministic=True), received_host_ns=received,
                           problem=assignment_problem(msg))


def assignment_problem(msg: node_pb2.Assignment, largest: Callable[[bytes], int] | None = None) -> str:
    """Why the presenter process could not decode assignment ``msg`` ("" it can): the one place its
    shapes are checked against its byte lengths, so that the node process refuses what the presenter's
    decode would (:func:`assignment_from_message` raises ValueError with it). Blend maps that cannot be
    used are no reason: the presenter keeps the blend on screen and applies the rest. ``largest``: the
    largest of little-endian uint32s in bytes (default: without numpy, for the node process)."""
    kind = msg.WhichOneof("pose")
    if kind == "homography" and len(msg.homography.m) != 9:
        return f"homography needs 9 values, got {len(msg.homography.m)}"
    if kind == "projection":
        if len(msg.projection.p) != 12:
            return f"projection needs 12 values, got {len(msg.projection.p)}"
        m = msg.projection.mesh     # little-endian float32 (x, y, z) and (u, v) per vertex, uint32 triples
        vertices, uvs, faces = len(m.vertices), len(m.uvs), len(m.faces)
        if vertices % 12 or uvs % 8 or faces % 12:
            return f"mesh arrays are not whole (bytes: {vertices} of vertices, {uvs} of uvs, {faces} of faces)"
        if uvs // 8 != vertices // 12:
            return f"mesh has {vertices // 12} vertices and {uvs // 8} uvs"
        if faces and not _faces_within(m.faces, vertices // 12, largest):
            return f"mesh faces name vertices beyond its {vertices // 12}"
    if msg.HasField("lut"):
        lut = msg.lut
        if lut.channels not in (1, 3) or lut.entries < 2 or len(lut.values) != 4 * lut.channels * lut.entries:
            return (f"LUT message is inconsistent ({lut.channels} channels of {lut.entries} entries in "
                    f"{len(lut.values)} bytes)")
    return ""


#: the faces last found within their mesh's vertices without numpy, as (vertex count, faces' byte length,
#: their crc32): a failover's pushes carry the same mesh again and again, and the node process scans it
#: once (8 ms for 100k triangles here; the crc32 of 300k takes 1 ms)
_faces_seen_within: tuple[int, int, int] | None = None


def _faces_within(faces: bytes, vertices: int, largest: Callable[[bytes], int] | None) -> bool:
    """Whether every index ``faces`` holds (little-endian uint32s) names one of ``vertices``."""
    global _faces_seen_within
    if largest is not None:
        return largest(faces) < vertices
    seen = (vertices, len(faces), zlib.crc32(faces))
    if seen == _faces_seen_within:
        return True
    within = _largest_uint32(faces) < vertices
    if within:
        _faces_seen_within = seen
    return within


def _largest_uint32(data: bytes) -> int:
    """The largest of the little-endian uint32s ``data`` holds (its length a multiple of 4, not 0)."""
    values = array("I")
    if values.itemsize != 4:           # pragma: no cover - an ABI whose unsigned int is not 32 bits
        values = array("L")
    values.frombytes(data)
    if sys.byteorder != "little":      # pragma: no cover - every target is little-endian
        values.byteswap()
    return max(values)


def assignment_from_bytes(rec: AssignmentBytes) -> NodeAssignment:
    """The presenter process's side of :func:`assignment_bytes`: :func:`assignment_from_message` of the
    bytes, with the revision and the time the node process received it. ValueError as there, or if
    the bytes are no Assignment."""
    try:
        msg = node_pb2.Assignment.FromString(rec.data)
    except DecodeError as exc:
        raise ValueError(f"not an assignment: {exc}") from exc
    msg.revision = rec.revision
    return assignment_from_message(msg, received_host_ns=rec.received_host_ns or None)


def assignment_from_message(msg: node_pb2.Assignment, *, received_host_ns: int | None = None) -> NodeAssignment:
    """ValueError if the message is inconsistent (wrong matrix sizes, mesh or LUT arrays: the reasons of
    :func:`assignment_problem`). Blend maps that cannot be used do not refuse the assignment: it carries
    why in ``blend_error`` (the presenter keeps the blend it shows and applies the rest). It carries the
    host's monotonic times it was received (``received_host_ns``; None: now, when its decoding begins)
    and decoded (the presenter logs them with a blend switch: where a failover's time goes)."""
    import numpy as np                                   # the presenter process's (see the module's docstring)

    from protos.blend import BlendMapError, BlendMaps

    if problem := assignment_problem(msg, lambda data: int(np.frombuffer(data, "<u4").max())):
        raise ValueError(problem)
    received = time.monotonic_ns() if received_host_ns is None else received_host_ns
    kind = msg.WhichOneof("pose") or "none"
    homography = projection = None
    mesh = None
    near, far = 100.0, 10_000.0
    if kind == "homography":
        homography = np.array(msg.homography.m, dtype=np.float64).reshape(3, 3)
    elif kind == "projection":
        projection = np.array(msg.projection.p, dtype=np.float64).reshape(3, 4)
        m = msg.projection.mesh
        v = np.frombuffer(m.vertices, dtype="<f4").reshape(-1, 3).astype(np.float32)
        uv = np.frombuffer(m.uvs, dtype="<f4").reshape(-1, 2).astype(np.float32)
        f = np.frombuffer(m.faces, dtype="<u4").reshape(-1, 3).astype(np.uint32)
        mesh = MeshData(m.mesh_id, v, uv, f)
        near, far = msg.projection.near_mm or near, msg.projection.far_mm or far
    lut = None
    if msg.HasField("lut"):
        lut = np.frombuffer(msg.lut.values, dtype="<f4").astype(np.float32).reshape(msg.lut.channels, msg.lut.entries)
    blend, blend_at, blend_error = None, 0, ""
    if msg.HasField("blend"):
        b = msg.blend
        try:
            blend = BlendMaps.decode(b.width, b.height, b.alpha, b.beta, b.blend_id[:64])
            blend_at = max(0, b.at_rig_ns)
        except BlendMapError as exc:
            blend_error = str(exc)
    return NodeAssignment(
        revision=msg.revision, slot=msg.slot, width=msg.output_width, height=msg.output_height, pose_kind=kind,
        homography=homography, projection=projection, mesh=mesh, near_mm=near, far_mm=far, lut=lut,
        gain=msg.gain if msg.gain > 0 else 1.0, content_size=(msg.content_width, msg.content_height),
        blend=blend, blend_at_ns=blend_at, blend_error=blend_error,
        received_host_ns=received, decoded_host_ns=time.monotonic_ns(),
    )


def frame_for_slot(msg: node_pb2.Frame, slot: str) -> FrameOrder:
    cid = msg.slot_content[slot] if slot in msg.slot_content else msg.content_id
    space = "projector" if msg.space == node_pb2.SPACE_PROJECTOR else "content"
    return FrameOrder(frame_id=msg.frame_id, pts_ns=msg.pts_ns, content_id=cid, space=space,
                      apply_lut=msg.apply_lut, tag=msg.tag, fade_ns=max(0, msg.fade_ns),
                      fade_steps=msg.fade_steps if msg.fade_ns > 0 else 0)


def packet_from_bytes(data: bytes, slot: str, *, known: Callable[[str], bool] = lambda cid: False) -> FramePacketData:
    """A serialized ``FramePacket`` as ``slot`` sees it (its live video picture left out: see
    :func:`live_packet_from_bytes`).

    Contents for which ``known(content_id)`` is true (already cached), or that appeared
    earlier in the same packet, are left out without being decoded. A content that
    cannot be decoded is kept with ``image=None`` and the reason in ``error``.
    """
    return live_packet_from_bytes(data, slot, known=known)[0]


def live_packet_from_bytes(data: bytes, slot: str, *, known: Callable[[str], bool] = lambda cid: False
                           ) -> tuple[FramePacketData, VideoChunk | None]:
    """:func:`packet_from_bytes`, and the packet's encoded live video picture (None: none).

    ValueError (a protobuf DecodeError) if ``data`` is not a FramePacket.
    """
    from node.live_video import VideoChunk           # the presenter process's, as the images' numpy
    from protos import codec

    pkt = node_pb2.FramePacket.FromString(data)
    contents = []
    seen: set[str] = set()
    for content in pkt.contents:
        cid = content.content_id
        if cid in seen or known(cid):
            continue
        seen.add(cid)
        try:
            contents.append(ContentBlob(cid, codec.decode_image(content.image)))
        except codec.ImageCodecError as exc:
            contents.append(ContentBlob(cid, None, str(exc)))
    frame = frame_for_slot(pkt.frame, slot) if pkt.HasField("frame") else None
    evict = tuple(pkt.evict.content_ids) if pkt.HasField("evict") else None
    video = None
    if pkt.HasField("video"):
        v = pkt.video
        video = VideoChunk(stream_id=v.stream_id, sequence=v.sequence, keyframe=v.keyframe, data=v.data,
                           width=v.width, height=v.height, channels=v.channels, bit_depth=v.bit_depth,
                           codec=_VIDEO_CODECS.get(v.codec, "unknown"), content_id=v.content_id)
    return FramePacketData(tuple(contents), frame, evict), video


def wanted_from_message(msg: node_pb2.WantedAssets) -> WantedAssets:
    return WantedAssets(revision=msg.revision, asset_ids=tuple(msg.asset_ids), pinned_ids=tuple(msg.pinned_ids))


def show_update_from_message(msg: node_pb2.ShowUpdate) -> ShowUpdateData:
    """ValueError (a TimelineError) if the timeline is impossible (bad rate, frame out of range)."""
    if msg.stop or not msg.HasField("timeline"):
        return ShowUpdateData(stop_at_ns=msg.stop_at_ns, stop_revision=msg.stop_revision, beacon=msg.beacon)
    t = msg.timeline
    if not t.rate_den:
        raise ValueError("timeline without a rate")
    tl = Timeline(asset_id=t.asset_id, frames=t.frames, rate=Fraction(t.rate_num, t.rate_den), anchor_ns=t.anchor_ns,
                  anchor_frame=t.anchor_frame, loop=t.loop, paused=t.paused, revision=t.revision,
                  fade_ns=max(0, t.fade_ns))
    return ShowUpdateData(timeline=tl, frame_id_base=t.frame_id_base, beacon=msg.beacon)


def preview_request_from_message(msg: node_pb2.PreviewRequest) -> int:
    """The request's id (>= 1)."""
    return max(1, msg.request_id)


def blob_chunk_from_message(msg: node_pb2.BlobChunk) -> BlobChunkData:
    return BlobChunkData(offset=msg.offset, data=msg.data)


def hello_reply_from_message(msg: common_pb2.HelloReply) -> HelloReply:
    return HelloReply(rig_id=msg.rig_id, rig_name=msg.rig_name, server_nonce=msg.server_nonce,
                      server_proof=msg.server_proof)


def join_reply_from_message(msg: node_pb2.JoinReply) -> JoinReply:
    return JoinReply(session=msg.session, instance_id=msg.instance_id,
                     heartbeat_interval_ms=msg.heartbeat_interval_ms or 500, clock_id=msg.clock_id)


def ping_reply_from_message(msg: node_pb2.PingReply) -> PingReply:
    return PingReply(t1_rig_ns=msg.t1_rig_ns, t2_rig_ns=msg.t2_rig_ns)


# ------------------------------------------------------------------ node -> coordinator


def hello_request(*, protocol_version: int, client_nonce: bytes, slot: str) -> common_pb2.HelloRequest:
    return common_pb2.HelloRequest(protocol_version=protocol_version, client_nonce=client_nonce, role="node", slot=slot)


def join_request(req: JoinRequest) -> node_pb2.JoinRequest:
    i = req.info
    info = node_pb2.NodeInfo(hostname=i.hostname, host_boot_id=i.host_boot_id, pid=i.pid,
                             software_version=i.software_version, output=i.output,
                             native_width=i.native_size[0], native_height=i.native_size[1], gl=i.gl)
    login = common_pb2.LoginRequest(protocol_version=req.protocol_version, role="node", slot=req.slot,
                                    client_nonce=req.client_nonce, server_nonce=req.server_nonce,
                                    client_proof=req.client_proof)
    return node_pb2.JoinRequest(login=login, info=info)


def ping_request(t0_local_ns: int) -> node_pb2.PingRequest:
    return node_pb2.PingRequest(t0_local_ns=t0_local_ns)


def stream_request() -> node_pb2.StreamRequest:
    return node_pb2.StreamRequest()


def manifest_request(asset_id: str) -> node_pb2.ManifestRequest:
    return node_pb2.ManifestRequest(asset_id=asset_id)


def blob_request(sha256: str, offset: int) -> node_pb2.BlobRequest:
    return node_pb2.BlobRequest(sha256=sha256, offset=offset)


def asset_progress_message(p: AssetProgressRecord) -> node_pb2.AssetProgress:
    return node_pb2.AssetProgress(asset_id=p.asset_id, have_bytes=p.have_bytes, total_bytes=p.total_bytes,
                                  ready=p.ready, error=p.error, name=p.name)


def swaps_message(swaps: Sequence[SwapRecord]) -> node_pb2.Swaps:
    """``swaps`` as delta-coded columns (protos/node.proto, ``Swaps``): each value after a
    column's first is the difference to the value before it."""
    def deltas(values: list[int]) -> list[int]:
        return [v - u for u, v in zip([0, *values[:-1]], values)]

    return node_pb2.Swaps(frame_id=deltas([s.frame_id for s in swaps]),
                          swap_rig_ns=deltas([s.swap_rig_ns for s in swaps]),
                          host_monotonic_ns=deltas([s.host_monotonic_ns for s in swaps]))


def drop_message(rec: DropRecord) -> node_pb2.FrameDrop:
    return node_pb2.FrameDrop(frame_id=rec.frame_id, reason=_DROP_REASONS[rec.reason], late_by_ns=rec.late_by_ns)


_SHOW_STATES = {"none": node_pb2.NODE_SHOW_NONE, "waiting": node_pb2.NODE_SHOW_WAITING,
                "playing": node_pb2.NODE_SHOW_PLAYING, "paused": node_pb2.NODE_SHOW_PAUSED,
                "suspended": node_pb2.NODE_SHOW_SUSPENDED}


def heartbeat_message(hb: HeartbeatRecord) -> node_pb2.Heartbeat:
    msg = node_pb2.Heartbeat(
        assignment_revision=hb.assignment_revision, frames_shown=hb.frames_shown, frames_late=hb.frames_late,
        frames_dropped=hb.frames_dropped, render_ms_p50=hb.render_ms_p50, host_monotonic_ns=hb.host_monotonic_ns,
        blend_id=hb.blend_id, blend_since_rig_ns=hb.blend_since_rig_ns, decoder=hb.decoder,
        decoder_note=hb.decoder_note,
        assignment_refused=hb.assignment_refused,
    )
    if hb.clock is not None:
        msg.clock_offset_ns = hb.clock.offset_ns
        msg.clock_drift_ppm = hb.clock.drift_ppm
        msg.clock_rtt_ns = hb.clock.rtt_ns
        msg.clock_samples = hb.clock.samples
        msg.rig_estimate_ns = hb.clock.rig_estimate_ns
    msg.assets.extend(asset_progress_message(a) for a in hb.assets)
    if hb.show is not None:
        s = hb.show
        msg.show.CopyFrom(node_pb2.NodeShow(revision=s.revision, state=_SHOW_STATES[s.state], last_frame=s.last_frame,
                                            frames_shown=s.shown, frames_late=s.late, alone_ms=int(s.alone_ms)))
    return msg


def preview_message(p: PreviewRecord) -> node_pb2.Preview:
    return node_pb2.Preview(request_id=p.request_id, frame_id=p.frame_id, png=p.png, width=p.width, height=p.height,
                            output_width=p.output_width, output_height=p.output_height)


def report_message(batch: ReportBatch) -> node_pb2.NodeReport:
    msg = node_pb2.NodeReport()
    if batch.preview is not None:
        msg.preview.CopyFrom(preview_message(batch.preview))
    if batch.heartbeat is not None:
        msg.heartbeat.CopyFrom(heartbeat_message(batch.heartbeat))
    if batch.swaps:
        msg.swaps.CopyFrom(swaps_message(batch.swaps))
    msg.drops.extend(drop_message(d) for d in batch.drops)
    msg.goodbye = batch.goodbye
    return msg
