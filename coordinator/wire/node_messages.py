"""NodeLink's messages: the coordinator's side of what it says to nodes and hears from them.

The coordinator's core speaks the plain types of :mod:`coordinator.api`, :mod:`coordinator.sessions`
and :mod:`coordinator.rig`; :mod:`coordinator.wire.node_service` calls these functions at the edge.
The Frames stream's packets are built by :mod:`coordinator.wire.frame_packets`; a node's side of
the same messages is :mod:`node.wire`.
"""
from __future__ import annotations

import itertools
import math

import numpy as np

from coordinator.api import AssetProgress, DropReason, NodeShow, NodeShowState, Space
from coordinator.distribution import WantedList
from coordinator.previews import Preview
from coordinator.rig import HomographyPose, ProjectionPose, SlotState, validate_lut
from coordinator.sessions import NO_SWAPS, Heartbeat, NodeInfo, Report, Swaps
from coordinator.show import ShowUpdate
from protos import node_pb2
from protos.blend import BlendMaps

_SPACE = {Space.CONTENT: node_pb2.SPACE_CONTENT, Space.PROJECTOR: node_pb2.SPACE_PROJECTOR}
_SPACE_BACK = {v: k for k, v in _SPACE.items()}
_DROP = {node_pb2.DROP_REASON_LATE: DropReason.LATE, node_pb2.DROP_REASON_SUPERSEDED: DropReason.SUPERSEDED,
         node_pb2.DROP_REASON_MISSING_CONTENT: DropReason.MISSING_CONTENT,
         node_pb2.DROP_REASON_UNRENDERABLE: DropReason.UNRENDERABLE}


def space_from_message(value: int) -> Space:
    """A request's space (unspecified means content)."""
    return _SPACE_BACK.get(value, Space.CONTENT)


def space_message(space: Space) -> int:
    return _SPACE[space]


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
    if st.blend is not None:
        msg.blend.CopyFrom(blend_message(st.blend, at_ns=st.blend_at_ns))
    return msg


def blend_message(maps: BlendMaps, *, at_ns: int = 0) -> node_pb2.Blend:
    """A slot's blend maps as the node receives them (float16, protos/blend.py's encoding)."""
    alpha, beta = maps.encode()
    w, h = maps.size
    return node_pb2.Blend(width=w, height=h, alpha=alpha, beta=beta, blend_id=maps.blend_id, at_rig_ns=int(at_ns))


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
                       show=node_show_from_message(h.show), blend_id=h.blend_id[:64],
                       blend_since_rig_ns=h.blend_since_rig_ns, decoder=h.decoder[:64],
                       decoder_note=h.decoder_note[:160],
                       assignment_refused=h.assignment_refused[:200])
    swaps = swaps_from_message(msg.swaps) if msg.HasField("swaps") else NO_SWAPS
    drops = tuple((d.frame_id, _DROP.get(d.reason, DropReason.OTHER)) for d in msg.drops)
    preview = None
    if msg.HasField("preview"):      # bounded by the Previews that keeps it (coordinator.previews)
        p = msg.preview
        preview = Preview(request_id=p.request_id, frame_id=p.frame_id, png=p.png, width=p.width, height=p.height,
                          output_width=p.output_width, output_height=p.output_height)
    return Report(heartbeat=hb, swaps=swaps, drops=drops, preview=preview, goodbye=msg.goodbye[:160])


def preview_request_message(request_id: int) -> node_pb2.PreviewRequest:
    return node_pb2.PreviewRequest(request_id=request_id)


def wanted_message(w: WantedList) -> node_pb2.WantedAssets:
    return node_pb2.WantedAssets(revision=w.revision, asset_ids=list(w.asset_ids), pinned_ids=list(w.pinned_ids))


def manifest_reply(data: bytes) -> node_pb2.ManifestReply:
    return node_pb2.ManifestReply(manifest=data)


def blob_chunk_message(offset: int, data: bytes) -> node_pb2.BlobChunk:
    return node_pb2.BlobChunk(offset=offset, data=data)


def show_update_message(u: ShowUpdate) -> node_pb2.ShowUpdate:
    msg = node_pb2.ShowUpdate(beacon=u.beacon)
    tl = u.timeline
    if tl is None:
        msg.stop, msg.stop_at_ns, msg.stop_revision = True, u.stop_at_ns, u.stop_revision
    else:
        msg.timeline.CopyFrom(node_pb2.Timeline(
            asset_id=tl.asset_id, frames=tl.frames, rate_num=tl.rate.numerator, rate_den=tl.rate.denominator,
            anchor_ns=tl.anchor_ns, anchor_frame=tl.anchor_frame, loop=tl.loop, paused=tl.paused,
            revision=tl.revision, frame_id_base=u.frame_id_base, fade_ns=tl.fade_ns))
    return msg
