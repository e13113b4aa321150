"""The one place the coordinator converts between protobuf messages and its own types.

The coordinator's state, its jobs and the operator client's callers speak the plain types
of :mod:`coordinator.api`, :mod:`coordinator.sessions`, :mod:`coordinator.fanout` and
:mod:`coordinator.rig`; the gRPC services (:mod:`coordinator.services`) and the operator
client (:mod:`rigctl.client`) call these functions at the edge.
"""
from __future__ import annotations

import itertools
import json
import math
import threading
from collections import OrderedDict
from dataclasses import asdict, fields
from pathlib import Path
from typing import Any, Callable, Iterable, Sequence

import numpy as np

from coordinator.api import (AdmissionFigures, AssetProgress, DropReason, NodeShow, NodeShowState, NodeState,
                             NodeStatus, PlayResult, PlaySettings, Refusal, RigStatus, ShowResult, ShowState, Space,
                             SyncSummary)
from coordinator.distribution import WantedList
from coordinator.fanout import Frame
from coordinator.jobs.context import Event, Progress
from coordinator.live_video import EncodedPicture
from coordinator.previews import Preview
from coordinator.rig import Content, HomographyPose, Mesh, ProjectionPose, SlotState, mesh_with_id, validate_lut
from coordinator.sessions import NO_SWAPS, Heartbeat, NodeInfo, Report, Swaps
from coordinator.show import ShowUpdate
from protos import codec, common_pb2, control_pb2, node_pb2

# ---------------------------------------------------------------------- enums
_SPACE = {Space.CONTENT: node_pb2.SPACE_CONTENT, Space.PROJECTOR: node_pb2.SPACE_PROJECTOR}
_SPACE_BACK = {v: k for k, v in _SPACE.items()}
_STATE = {NodeState.EXPECTED: control_pb2.NODE_STATE_EXPECTED, NodeState.JOINED: control_pb2.NODE_STATE_JOINED,
          NodeState.LIVE: control_pb2.NODE_STATE_LIVE, NodeState.LOST: control_pb2.NODE_STATE_LOST}
_STATE_BACK = {v: k for k, v in _STATE.items()}
_DROP = {node_pb2.DROP_REASON_LATE: DropReason.LATE, node_pb2.DROP_REASON_SUPERSEDED: DropReason.SUPERSEDED,
         node_pb2.DROP_REASON_MISSING_CONTENT: DropReason.MISSING_CONTENT,
         node_pb2.DROP_REASON_UNRENDERABLE: DropReason.UNRENDERABLE}


def space_from_message(value: int) -> Space:
    """A request's space (unspecified means content)."""
    return _SPACE_BACK.get(value, Space.CONTENT)


def space_message(space: Space) -> int:
    return _SPACE[space]


# ---------------------------------------------------------------------- nodes
def assignment_message(st: SlotState, *, content_size: tuple[int, int]) -> node_pb2.Assignment:
    msg = node_pb2.Assignment(
        revision=st.revision, slot=st.name, output_width=st.width, output_height=st.height,
        gain=st.gain, content_width=content_size[0], content_height=content_size[1],
    )
    if isinstance(st.pose, HomographyPose):
        msg.homography.m.extend(st.pose.matrix.ravel().tolist())
    elif isinstance(st.pose, ProjectionPose):
        mesh = st.pose.mesh
        msg.projection.p.extend(st.pose.matrix.ravel().tolist())
        msg.projection.near_mm = st.pose.near_mm
        msg.projection.far_mm = st.pose.far_mm
        msg.projection.mesh.mesh_id = mesh.mesh_id
        msg.projection.mesh.vertices = mesh.vertices.astype("<f4").tobytes()
        msg.projection.mesh.uvs = mesh.uvs.astype("<f4").tobytes()
        msg.projection.mesh.faces = mesh.faces.astype("<u4").tobytes()
    if st.lut is not None:
        msg.lut.CopyFrom(lut_message(st.lut))
    return msg


def lut_message(lut: np.ndarray) -> node_pb2.Lut:
    lut = np.ascontiguousarray(lut, dtype="<f4")
    return node_pb2.Lut(channels=lut.shape[0], entries=lut.shape[1], values=lut.tobytes())


def lut_from_message(msg: node_pb2.Lut) -> np.ndarray:
    if msg.channels * msg.entries * 4 != len(msg.values):
        raise ValueError(f"LUT says {msg.channels}x{msg.entries} but carries {len(msg.values)} bytes")
    lut = np.frombuffer(msg.values, dtype="<f4").reshape(msg.channels, msg.entries).astype(np.float32)
    validate_lut(lut)
    return lut


def homography_from_message(msg: node_pb2.Homography) -> HomographyPose:
    if len(msg.m) != 9:
        raise ValueError(f"a homography has 9 values, got {len(msg.m)}")
    return HomographyPose(np.array(msg.m, dtype=np.float64).reshape(3, 3))


def node_info_from_message(msg: node_pb2.NodeInfo) -> NodeInfo:
    return NodeInfo(hostname=msg.hostname, pid=msg.pid, host_boot_id=msg.host_boot_id,
                    native_size=(msg.native_width, msg.native_height), software_version=msg.software_version[:64],
                    output=msg.output[:64], gl=msg.gl[:160])


def asset_progress_message(p: AssetProgress) -> node_pb2.AssetProgress:
    msg = node_pb2.AssetProgress(asset_id=p.asset_id, have_bytes=p.have_bytes, total_bytes=p.total_bytes,
                                 ready=p.ready, error=p.error, name=p.name)
    if not math.isnan(p.ready_age_ms):
        msg.ready_age_ms = p.ready_age_ms
    return msg


def asset_progress_from_message(m: node_pb2.AssetProgress) -> AssetProgress:
    return AssetProgress(asset_id=m.asset_id, have_bytes=m.have_bytes, total_bytes=m.total_bytes, ready=m.ready,
                         error=m.error, name=m.name,
                         ready_age_ms=m.ready_age_ms if m.HasField("ready_age_ms") else math.nan)


_SHOW_STATE = {NodeShowState.NONE: node_pb2.NODE_SHOW_NONE, NodeShowState.WAITING: node_pb2.NODE_SHOW_WAITING,
               NodeShowState.PLAYING: node_pb2.NODE_SHOW_PLAYING, NodeShowState.PAUSED: node_pb2.NODE_SHOW_PAUSED,
               NodeShowState.SUSPENDED: node_pb2.NODE_SHOW_SUSPENDED}
_SHOW_STATE_BACK = {v: k for k, v in _SHOW_STATE.items()}


def node_show_message(s: NodeShow) -> node_pb2.NodeShow:
    return node_pb2.NodeShow(revision=s.revision, state=_SHOW_STATE[s.state], last_frame=s.last_frame,
                             frames_shown=s.frames_shown, frames_late=s.frames_late, alone_ms=int(s.alone_ms))


def node_show_from_message(m: node_pb2.NodeShow) -> NodeShow:
    return NodeShow(revision=m.revision, state=_SHOW_STATE_BACK.get(m.state, NodeShowState.NONE),
                    last_frame=m.last_frame if m.state else -1, frames_shown=m.frames_shown,
                    frames_late=m.frames_late, alone_ms=float(m.alone_ms))


def swaps_from_message(m: node_pb2.Swaps) -> Swaps:
    """Undo the columns' delta coding (protos/node.proto, ``Swaps``); columns of unequal length are refused."""
    n = len(m.frame_id)
    if len(m.swap_rig_ns) != n or len(m.host_monotonic_ns) != n:
        raise ValueError(f"a report's swap columns differ in length ({n}, {len(m.swap_rig_ns)}, "
                         f"{len(m.host_monotonic_ns)})")
    cols = np.fromiter(itertools.chain(m.frame_id, m.swap_rig_ns, m.host_monotonic_ns), dtype=np.int64, count=3 * n)
    return Swaps(*np.cumsum(cols.reshape(3, n), axis=1))


def report_from_message(msg: node_pb2.NodeReport) -> Report:
    hb = None
    if msg.HasField("heartbeat"):
        h = msg.heartbeat
        hb = Heartbeat(assignment_revision=h.assignment_revision, clock_offset_ns=h.clock_offset_ns,
                       clock_drift_ppm=h.clock_drift_ppm, clock_rtt_ns=h.clock_rtt_ns,
                       host_monotonic_ns=h.host_monotonic_ns, rig_estimate_ns=h.rig_estimate_ns,
                       assets=tuple(asset_progress_from_message(a) for a in h.assets),
                       show=node_show_from_message(h.show))
    swaps = swaps_from_message(msg.swaps) if msg.HasField("swaps") else NO_SWAPS
    drops = tuple((d.frame_id, _DROP.get(d.reason, DropReason.OTHER)) for d in msg.drops)
    preview = None
    if msg.HasField("preview"):      # bounded by the Previews that keeps it (coordinator.previews)
        p = msg.preview
        preview = Preview(request_id=p.request_id, frame_id=p.frame_id, png=p.png, width=p.width, height=p.height,
                          output_width=p.output_width, output_height=p.output_height)
    return Report(heartbeat=hb, swaps=swaps, drops=drops, preview=preview)


def preview_request_message(request_id: int) -> node_pb2.PreviewRequest:
    return node_pb2.PreviewRequest(request_id=request_id)


def wanted_message(w: WantedList) -> node_pb2.WantedAssets:
    return node_pb2.WantedAssets(revision=w.revision, asset_ids=list(w.asset_ids), pinned_ids=list(w.pinned_ids))


def manifest_reply(data: bytes) -> node_pb2.ManifestReply:
    return node_pb2.ManifestReply(manifest=data)


def blob_chunk_message(offset: int, data: bytes) -> node_pb2.BlobChunk:
    return node_pb2.BlobChunk(offset=offset, data=data)


def content_message(content: Content, *, compress: bool = True) -> node_pb2.Content:
    """The wire form of ``content`` (encode once, reuse for every packet); lossless, compressed
    (protos/codec.py's gradient + zstd) unless ``compress`` is false."""
    return node_pb2.Content(content_id=content.content_id, image=codec.encode_image(content.image, compress=compress))


_VIDEO_CODECS = {"h264": node_pb2.VIDEO_CODEC_H264, "hevc": node_pb2.VIDEO_CODEC_HEVC}


def video_message(pic: EncodedPicture) -> node_pb2.VideoPacket:
    """The wire form of one encoded live picture (:mod:`coordinator.live_video`)."""
    return node_pb2.VideoPacket(stream_id=pic.stream_id, sequence=pic.sequence, keyframe=pic.keyframe, data=pic.data,
                                width=pic.width, height=pic.height, channels=pic.channels, bit_depth=pic.bit_depth,
                                codec=_VIDEO_CODECS[pic.codec], content_id=pic.content_id)


class _EncodedContents:
    """Wire forms of contents by id, shared by every :class:`PacketEncoder` of the process.

    A content id is a hash of its pixels (:func:`coordinator.rig.content_id_of`), so an entry never
    goes stale; the least recently used go beyond ``max_bytes``. Filled from worker threads too
    (:meth:`PacketEncoder.prepare`), hence the lock.
    """

    def __init__(self, max_bytes: int):
        self.max_bytes = max_bytes
        self._items: OrderedDict[str, node_pb2.Content] = OrderedDict()
        self._bytes = 0
        self._lock = threading.Lock()

    def get(self, cid: str) -> node_pb2.Content | None:
        with self._lock:
            msg = self._items.get(cid)
            if msg is not None:
                self._items.move_to_end(cid)
            return msg

    def put(self, cid: str, msg: node_pb2.Content) -> None:
        with self._lock:
            if cid in self._items:
                return
            self._items[cid] = msg
            self._bytes += len(msg.image.data)
            while self._bytes > self.max_bytes and len(self._items) > 1:
                _, old = self._items.popitem(last=False)
                self._bytes -= len(old.image.data)


#: contents encoded for the Frames stream, kept for resends, late joiners and retries
ENCODED_CONTENTS = _EncodedContents(max_bytes=256 * 2**20)


class PacketEncoder:
    """Serializes Frames packets; each content is encoded once (then kept in :data:`ENCODED_CONTENTS`),
    whatever the packet count."""

    def __init__(self) -> None:
        self._contents: dict[str, node_pb2.Content] = {}
        self._video: tuple[EncodedPicture, node_pb2.VideoPacket] | None = None

    def prepare(self, contents: Iterable[Content]) -> None:
        """Encode ``contents`` now (callable from a worker thread), so sends find them encoded."""
        for c in contents:
            self._content(c)

    def _content(self, c: Content) -> node_pb2.Content:
        msg = self._contents.get(c.content_id) or ENCODED_CONTENTS.get(c.content_id)
        if msg is None:
            msg = content_message(c)
            ENCODED_CONTENTS.put(c.content_id, msg)
        self._contents[c.content_id] = msg
        return msg

    def packet(self, *, frame: Frame | None, contents: Sequence[Content], evict: Sequence[str] = (),
               video: EncodedPicture | None = None) -> bytes:
        pkt = node_pb2.FramePacket()
        for c in contents:
            pkt.contents.append(self._content(c))
        if video is not None:
            if self._video is None or self._video[0] is not video:
                self._video = (video, video_message(video))
            pkt.video.CopyFrom(self._video[1])
        if frame is not None:
            pkt.frame.CopyFrom(node_pb2.Frame(frame_id=frame.frame_id, pts_ns=frame.pts_ns, content_id=frame.content_id,
                                              space=_SPACE[frame.space], apply_lut=frame.apply_lut, tag=frame.tag,
                                              slot_content=frame.slot_content))
        if evict:
            pkt.evict.content_ids.extend(evict)
        return pkt.SerializeToString()


# ---------------------------------------------------------------------- operators
def _sync_message(s: SyncSummary) -> control_pb2.SyncStats:
    return control_pb2.SyncStats(**asdict(s))


def _sync_from_message(m: control_pb2.SyncStats) -> SyncSummary:
    return SyncSummary(frames=m.frames, skew_p50_ms=m.skew_p50_ms, skew_p99_ms=m.skew_p99_ms, skew_max_ms=m.skew_max_ms,
                       skew_source=m.skew_source, clock_error_p99_ms=m.clock_error_p99_ms, frames_late=m.frames_late,
                       frames_dropped=m.frames_dropped, out_of_order=m.out_of_order)


def _node_status_message(n: NodeStatus) -> control_pb2.NodeStatus:
    d = asdict(n)
    d["state"] = _STATE[n.state]
    d["assets"] = [asset_progress_message(a) for a in n.assets]
    d["show"] = node_show_message(n.show)
    if math.isnan(n.live_age_ms):
        del d["live_age_ms"]   # unset: not live
    return control_pb2.NodeStatus(**d)


def _node_status_from_message(m: control_pb2.NodeStatus) -> NodeStatus:
    return NodeStatus(slot=m.slot, state=_STATE_BACK.get(m.state, NodeState.EXPECTED), hostname=m.hostname, pid=m.pid,
                      clock_offset_ms=m.clock_offset_ms, clock_drift_ppm=m.clock_drift_ppm, clock_rtt_ms=m.clock_rtt_ms,
                      clock_error_ms=m.clock_error_ms, last_swap_frame=m.last_swap_frame,
                      last_swap_age_ms=m.last_swap_age_ms, last_seen_age_ms=m.last_seen_age_ms,
                      frames_shown=m.frames_shown, frames_late=m.frames_late, frames_dropped=m.frames_dropped,
                      assignment_revision=m.assignment_revision, pose_kind=m.pose_kind, joins=m.joins,
                      assets_wanted=m.assets_wanted, assets_ready=m.assets_ready, asset_bytes_have=m.asset_bytes_have,
                      asset_bytes_total=m.asset_bytes_total,
                      assets=tuple(asset_progress_from_message(a) for a in m.assets),
                      live_age_ms=m.live_age_ms if m.HasField("live_age_ms") else math.nan,
                      show=node_show_from_message(m.show), software_version=m.software_version, output=m.output,
                      gl=m.gl)


def status_message(st: RigStatus) -> control_pb2.RigStatus:
    msg = control_pb2.RigStatus(
        rig_id=st.rig_id, rig_name=st.rig_name, instance_id=st.instance_id, rig_dir=st.rig_dir,
        protocol_version=st.protocol_version, uptime_s=st.uptime_s, showing=st.showing,
        latency_budget_ms=st.latency_budget_ms, cpu_s=st.cpu_s, sync=_sync_message(st.sync),
        show=show_state_message(st.show), frame_packets_sent=st.frame_packets_sent,
        frame_bytes_sent=st.frame_bytes_sent, show_updates_sent=st.show_updates_sent,
        show_bytes_sent=st.show_bytes_sent, console=st.console,
        admission=control_pb2.Admission(**asdict(st.admission)),
    )
    msg.nodes.extend(_node_status_message(n) for n in st.nodes)
    msg.refusals.extend(control_pb2.Refusal(peer=r.peer, slot=r.slot, reason=r.reason, age_s=r.age_s,
                                                    count=r.count) for r in st.refusals)
    return msg


def status_from_message(m: control_pb2.RigStatus) -> RigStatus:
    return RigStatus(rig_id=m.rig_id, rig_name=m.rig_name, instance_id=m.instance_id, rig_dir=m.rig_dir,
                     protocol_version=m.protocol_version, uptime_s=m.uptime_s, showing=m.showing,
                     latency_budget_ms=m.latency_budget_ms, cpu_s=m.cpu_s,
                     nodes=tuple(_node_status_from_message(n) for n in m.nodes), sync=_sync_from_message(m.sync),
                     refusals=tuple(Refusal(r.peer, r.slot, r.reason, r.age_s, r.count) for r in m.refusals),
                     show=show_state_from_message(m.show) if m.HasField("show") else ShowState(),
                     frame_packets_sent=m.frame_packets_sent, frame_bytes_sent=m.frame_bytes_sent,
                     show_updates_sent=m.show_updates_sent, show_bytes_sent=m.show_bytes_sent, console=m.console,
                     admission=AdmissionFigures(**{f.name: getattr(m.admission, f.name)
                                                   for f in fields(AdmissionFigures)}))


# ---------------------------------------------------------------------- the timeline show
def show_update_message(u: ShowUpdate) -> node_pb2.ShowUpdate:
    msg = node_pb2.ShowUpdate(beacon=u.beacon)
    tl = u.timeline
    if tl is None:
        msg.stop, msg.stop_at_ns, msg.stop_revision = True, u.stop_at_ns, u.stop_revision
    else:
        msg.timeline.CopyFrom(node_pb2.Timeline(
            asset_id=tl.asset_id, frames=tl.frames, rate_num=tl.rate.numerator, rate_den=tl.rate.denominator,
            anchor_ns=tl.anchor_ns, anchor_frame=tl.anchor_frame, loop=tl.loop, paused=tl.paused,
            revision=tl.revision, frame_id_base=u.frame_id_base))
    return msg


_SHOW_FIELDS = ("state", "asset_id", "name", "frames", "rate_num", "rate_den", "anchor_ns", "anchor_frame", "loop",
                "paused", "revision", "frame_id_base", "frame", "now_ns", "change_at_ns")


def show_state_message(s: ShowState) -> control_pb2.ShowState:
    return control_pb2.ShowState(**{f: getattr(s, f) for f in _SHOW_FIELDS})


def show_state_from_message(m: control_pb2.ShowState) -> ShowState:
    return ShowState(**{f: getattr(m, f) for f in _SHOW_FIELDS})


def play_asset_request(asset: str, *, at_ns: int = 0, delay_ms: float = 0.0, loop: bool = False, fps: float = 0.0,
                       start_without: bool = False) -> control_pb2.PlayAssetRequest:
    return control_pb2.PlayAssetRequest(asset=asset, at_ns=at_ns, delay_ms=delay_ms, loop=loop, fps=fps,
                                        start_without=start_without)


def show_control_request(*, at_ns: int = 0, delay_ms: float = 0.0, frame: int = 0) -> control_pb2.ShowControlRequest:
    return control_pb2.ShowControlRequest(at_ns=at_ns, delay_ms=delay_ms, frame=frame)


def nodes_message(nodes: Iterable[NodeStatus]) -> control_pb2.NodeList:
    return control_pb2.NodeList(nodes=[_node_status_message(n) for n in nodes])


def play_settings_message(s: PlaySettings) -> control_pb2.PlaySettings:
    return control_pb2.PlaySettings(fps=s.fps, loops=s.loops, wait=s.wait, pattern=s.pattern, frames=s.frames,
                                    latency_ms=s.latency_ms, settle_s=s.settle_s, fit=s.fit)


def play_settings_from_message(m: control_pb2.PlaySettings) -> PlaySettings:
    return PlaySettings(fps=m.fps or 30.0, loops=m.loops, wait=m.wait, pattern=m.pattern, frames=m.frames,
                        latency_ms=m.latency_ms, settle_s=m.settle_s, fit=m.fit)


def play_result_message(r: PlayResult) -> control_pb2.PlayReply:
    return control_pb2.PlayReply(
        frames_sent=r.frames_sent, frames_shown=r.frames_shown, frames_late=r.frames_late,
        frames_dropped=r.frames_dropped, coordinator_cpu_s=r.coordinator_cpu_s, nodes=r.nodes, wall_s=r.wall_s,
        skews_ms=list(r.skews_ms), clock_errors_ms=list(r.clock_errors_ms), encode_cpu_s=r.encode_cpu_s,
        sync=_sync_message(r.sync))


def play_result_from_message(m: control_pb2.PlayReply) -> PlayResult:
    return PlayResult(frames_sent=m.frames_sent, frames_shown=m.frames_shown, frames_late=m.frames_late,
                      frames_dropped=m.frames_dropped, nodes=m.nodes, wall_s=m.wall_s,
                      coordinator_cpu_s=m.coordinator_cpu_s, encode_cpu_s=m.encode_cpu_s, skews_ms=tuple(m.skews_ms),
                      clock_errors_ms=tuple(m.clock_errors_ms), sync=_sync_from_message(m.sync))


def show_result_message(r: ShowResult) -> control_pb2.ShowReply:
    return control_pb2.ShowReply(frame_id=r.frame_id, content_id=r.content_id, pts_ns=r.pts_ns)


def show_result_from_message(m: control_pb2.ShowReply) -> ShowResult:
    return ShowResult(frame_id=m.frame_id, content_id=m.content_id, pts_ns=m.pts_ns)


#: Image bytes per message from an operator (the coordinator accepts MAX_REQUEST_BYTES a message).
IMAGE_PART_BYTES = 1 << 20


def _image_parts(image: np.ndarray) -> tuple[common_pb2.Image, list[bytes]]:
    """``image`` packed for the wire: the message with its first part, and the rest."""
    msg = codec.encode_image(image, compress=True)
    data = msg.data
    msg.data = data[:IMAGE_PART_BYTES]
    return msg, [data[i:i + IMAGE_PART_BYTES] for i in range(IMAGE_PART_BYTES, len(data), IMAGE_PART_BYTES)]


def show_request_parts(image: np.ndarray, *, name: str, persist: bool, space: Space, apply_lut: bool,
                       fit: str = "", slot_regions=None) -> list[control_pb2.ShowRequest]:
    """The messages of one Show call: settings (and ``slot_regions``), the image's first part, then the rest."""
    msg, rest = _image_parts(image)
    first = control_pb2.ShowRequest(image=msg, name=name, persist=persist, space=_SPACE[space], apply_lut=apply_lut,
                                    fit=fit)
    for slot, rects in (slot_regions or {}).items():     # a slot named with no rectangle is present: black
        first.slot_regions[slot].rects.extend(control_pb2.ContentRect(x=x, y=y, width=w, height=h) for x, y, w, h in rects)
    return [first, *(control_pb2.ShowRequest(more=part) for part in rest)]


def play_frame_items(image: np.ndarray) -> list[control_pb2.PlayItem]:
    """One frame of a Play call: the frame with its first part, then ``more`` items."""
    msg, rest = _image_parts(image)
    return [control_pb2.PlayItem(frame=msg), *(control_pb2.PlayItem(more=part) for part in rest)]


class ImageParts:
    """Reassembles an image sent in parts, refusing more bytes than its size can hold.

    ``start(msg)`` with the Image message of the first part, ``add(bytes)`` for each further
    part, ``finish()`` returns the whole Image message. The bound is the raw size of the
    declared (height, width, channels, dtype) plus a margin for the packing's headers: an
    image never takes more memory than it could need, whatever a client sends.
    """

    MARGIN = 1 << 16

    def __init__(self) -> None:
        self._msg: common_pb2.Image | None = None
        self._parts: list[bytes] = []
        self._size = 0
        self._limit = 0

    @property
    def started(self) -> bool:
        return self._msg is not None

    def start(self, msg: common_pb2.Image) -> None:
        codec.check_header(msg)
        self._msg, self._parts, self._size = msg, [msg.data], len(msg.data)
        self._limit = msg.width * msg.height * msg.channels * codec.dtype_size(msg.dtype) + self.MARGIN
        self._check()

    def add(self, data: bytes) -> None:
        if self._msg is None:
            raise ValueError("image bytes arrived before the image they belong to")
        self._parts.append(data)
        self._size += len(data)
        self._check()

    def _check(self) -> None:
        if self._size > self._limit:
            m = self._msg
            raise ValueError(f"image of {m.width}x{m.height}x{m.channels} sent more than {self._limit} bytes")

    def finish(self) -> common_pb2.Image:
        if self._msg is None:
            raise ValueError("no image was sent")
        msg = self._msg
        msg.data = b"".join(self._parts)
        self._msg, self._parts, self._size = None, [], 0
        return msg


def configure_request(slot: str, *, homography: np.ndarray | None = None, lut: np.ndarray | None = None,
                      gain: float | None = None, size: tuple[int, int] | None = None,
                      clear_pose: bool = False, projection: np.ndarray | None = None,
                      mesh: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None, mesh_id: str = "",
                      near_far_mm: tuple[float, float] = (100.0, 10_000.0)) -> control_pb2.ConfigureRequest:
    """``projection``: (3, 4) float64 world mm -> projector px, rendering ``mesh`` (vertices (V, 3)
    float32 mm, uvs (V, 2) float32, faces (F, 3) uint32) or the rig's mesh ``mesh_id``."""
    req = control_pb2.ConfigureRequest(slot=slot, clear_pose=clear_pose, mesh_id=mesh_id)
    if homography is not None:
        req.homography.m.extend(np.asarray(homography, np.float64).ravel().tolist())
    if projection is not None:
        req.projection.p.extend(np.asarray(projection, np.float64).ravel().tolist())
        req.projection.near_mm, req.projection.far_mm = near_far_mm
        if mesh is not None:
            v, uv, f = mesh
            req.projection.mesh.vertices = np.ascontiguousarray(v, "<f4").tobytes()
            req.projection.mesh.uvs = np.ascontiguousarray(uv, "<f4").tobytes()
            req.projection.mesh.faces = np.ascontiguousarray(f, "<u4").tobytes()
    if lut is not None:
        req.lut.CopyFrom(lut_message(np.asarray(lut, np.float32)))
    if gain is not None:
        req.gain = gain
    if size is not None:
        req.output_width, req.output_height = size
    return req


def mesh_from_message(msg: node_pb2.Mesh) -> Mesh:
    """A mesh sent inline; ValueError naming what is malformed. Its id is a digest of its arrays."""
    if len(msg.vertices) % 12 or len(msg.uvs) % 8 or len(msg.faces) % 12:
        raise ValueError("a mesh's vertices, uvs and faces must be (V, 3) float32, (V, 2) float32 and (F, 3) uint32")
    v = np.frombuffer(msg.vertices, "<f4").reshape(-1, 3)
    uv = np.frombuffer(msg.uvs, "<f4").reshape(-1, 2)
    f = np.frombuffer(msg.faces, "<u4").reshape(-1, 3)
    if not (len(v) >= 3 and len(f) >= 1 and len(uv) == len(v)):
        raise ValueError(f"a mesh needs at least 3 vertices, a uv per vertex and a face; got {len(v)} vertices, "
                         f"{len(uv)} uvs, {len(f)} faces")
    if not (np.all(np.isfinite(v)) and np.all(np.isfinite(uv))):
        raise ValueError("a mesh's vertices and uvs must be finite numbers")
    return mesh_with_id(v, uv, f)


def projection_from_message(req: control_pb2.ConfigureRequest,
                            mesh_lookup: Callable[[str], Mesh] | None) -> ProjectionPose:
    """A Configure request's 3x4 pose, its mesh inline or the rig's ``mesh_id`` (``mesh_lookup``)."""
    p = req.projection
    if len(p.p) != 12:
        raise ValueError(f"a projection pose has 12 values (3x4, row-major), got {len(p.p)}")
    if p.mesh.vertices:
        mesh = mesh_from_message(p.mesh)
    elif req.mesh_id and mesh_lookup is not None:
        mesh = mesh_lookup(req.mesh_id)
    else:
        raise ValueError("a projection pose needs its mesh: send it, or name one of the rig's meshes")
    near, far = (p.near_mm or 100.0), (p.far_mm or 10_000.0)
    return ProjectionPose(np.array(p.p, dtype=np.float64).reshape(3, 4), mesh, near, far)


def slot_changes_from_message(req: control_pb2.ConfigureRequest,
                              mesh_lookup: Callable[[str], Mesh] | None = None) -> dict[str, Any]:
    """A Configure request as ``update_slot`` keyword arguments (``mesh_lookup``: the rig's meshes by id)."""
    changes: dict[str, Any] = {}
    if req.HasField("homography") and req.HasField("projection"):
        raise ValueError("give a homography or a projection pose, not both")
    if req.HasField("projection"):
        changes["pose"] = projection_from_message(req, mesh_lookup)
    elif req.HasField("homography"):
        changes["pose"] = homography_from_message(req.homography)
    elif req.clear_pose:
        changes["pose"] = None
    if req.HasField("lut"):
        changes["lut"] = lut_from_message(req.lut)
    if req.HasField("gain"):
        changes["gain"] = req.gain
    if req.output_width or req.output_height:
        changes["size"] = (req.output_width, req.output_height)
    return changes


# ---------------------------------------------------------------------- jobs
def _json_default(o: Any) -> Any:
    if isinstance(o, np.generic):
        return o.item()
    if isinstance(o, np.ndarray):
        return o.tolist()
    if isinstance(o, Path):
        return str(o)
    raise TypeError(f"not JSON serializable: {type(o).__name__}")


def job_request(kind: str, params: dict) -> control_pb2.JobRequest:
    return control_pb2.JobRequest(kind=kind, params_json=json.dumps(params))


def job_params_from_request(req: control_pb2.JobRequest) -> dict:
    """A job request's parameters; ValueError when they are not a JSON object."""
    params = json.loads(req.params_json or "{}")
    if not isinstance(params, dict):
        raise ValueError("job parameters must be a JSON object")
    return params


def job_event_message(ev: Event) -> control_pb2.JobEvent:
    if isinstance(ev, Progress):
        return control_pb2.JobEvent(progress=control_pb2.JobProgress(
            stage=ev.stage, item=ev.item, done=ev.done, total=ev.total, message=ev.message, value=ev.value))
    return control_pb2.JobEvent(log=str(ev))


def job_result_message(result: dict) -> control_pb2.JobEvent:
    return control_pb2.JobEvent(result_json=json.dumps(result, default=_json_default))


def job_event_from_message(m: control_pb2.JobEvent) -> Event | dict:
    """A job's event: a :class:`Progress`, a log line (``str``) or, last, its result (``dict``)."""
    which = m.WhichOneof("event")
    if which == "progress":
        p = m.progress
        return Progress(p.stage, p.item, p.done, p.total, p.message, p.value if not math.isnan(p.value) else math.nan)
    if which == "log":
        return m.log
    return json.loads(m.result_json or "{}")
