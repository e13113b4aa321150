"""RigControl's messages: the operator's calls and their answers, both ways.

The coordinator's side (:mod:`coordinator.wire.control_service`) and the operator's client
(:mod:`rigctl.link`) both call these, so a field is read the way it was written. An image an
operator sends travels in parts (:mod:`coordinator.wire.image_parts`).
"""
from __future__ import annotations

import json
import math
from dataclasses import asdict, fields
from pathlib import Path
from typing import Any, Callable, Iterable

import numpy as np

from coordinator.api import (AdmissionFigures, BlendStatus, NodeState, NodeStatus, PlayResult, PlaySettings, RefusedPeer,
                             RigStatus, ShowResult, ShowState, SyncSummary)
from coordinator.jobs.context import Event, Progress
from coordinator.rig import Mesh, ProjectionPose, mesh_with_id
from coordinator.wire.node_messages import (asset_progress_from_message, asset_progress_message,
                                            homography_from_message, lut_from_message, lut_message,
                                            node_show_from_message, node_show_message)
from protos import control_pb2, node_pb2

_STATE = {NodeState.EXPECTED: control_pb2.NODE_STATE_EXPECTED, NodeState.JOINED: control_pb2.NODE_STATE_JOINED,
          NodeState.LIVE: control_pb2.NODE_STATE_LIVE, NodeState.LOST: control_pb2.NODE_STATE_LOST}
_STATE_BACK = {v: k for k, v in _STATE.items()}


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
                      gl=m.gl, decoder=m.decoder, decoder_note=m.decoder_note, left=m.left,
                      assignment_refused=m.assignment_refused)


def status_message(st: RigStatus) -> control_pb2.RigStatus:
    msg = control_pb2.RigStatus(
        rig_id=st.rig_id, rig_name=st.rig_name, instance_id=st.instance_id, rig_dir=st.rig_dir,
        protocol_version=st.protocol_version, uptime_s=st.uptime_s, showing=st.showing,
        latency_budget_ms=st.latency_budget_ms, cpu_s=st.cpu_s, sync=_sync_message(st.sync),
        show=show_state_message(st.show), frame_packets_sent=st.frame_packets_sent,
        frame_bytes_sent=st.frame_bytes_sent, show_updates_sent=st.show_updates_sent,
        show_bytes_sent=st.show_bytes_sent, console=st.console,
        admission=control_pb2.Admission(**asdict(st.admission)), blend=blend_status_message(st.blend),
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
                     refusals=tuple(RefusedPeer(r.peer, r.slot, r.reason, r.age_s, r.count) for r in m.refusals),
                     show=show_state_from_message(m.show) if m.HasField("show") else ShowState(),
                     frame_packets_sent=m.frame_packets_sent, frame_bytes_sent=m.frame_bytes_sent,
                     show_updates_sent=m.show_updates_sent, show_bytes_sent=m.show_bytes_sent, console=m.console,
                     admission=AdmissionFigures(**{f.name: getattr(m.admission, f.name)
                                                   for f in fields(AdmissionFigures)}),
                     blend=blend_status_from_message(m.blend) if m.HasField("blend") else BlendStatus())


def blend_status_message(b: BlendStatus) -> control_pb2.BlendStatus:
    return control_pb2.BlendStatus(
        state=b.state, blend_id=b.blend_id, created_at=b.created_at, headroom=b.headroom,
        brightness_cost=b.brightness_cost, lost=list(b.lost), since=b.since, covered=b.covered,
        lamps=[control_pb2.LampGain(slot=s, gain=g) for s, g in b.lamps], message=b.message)


def blend_status_from_message(m: control_pb2.BlendStatus) -> BlendStatus:
    return BlendStatus(state=m.state or "none", blend_id=m.blend_id, created_at=m.created_at, headroom=m.headroom,
                       brightness_cost=m.brightness_cost, lost=tuple(m.lost), since=m.since, covered=m.covered,
                       lamps=tuple((x.slot, x.gain) for x in m.lamps), message=m.message)


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


# ---------------------------------------------------------------- the cue list (coordinator/cues.py)
def cue_reply(state: Any, result: str = "") -> control_pb2.CueReply:
    """A :class:`~coordinator.api.CueState` (its JSON) and one line of result."""
    return control_pb2.CueReply(state_json=json.dumps(state.to_json()), result=result)


def cue_reply_from_message(m: control_pb2.CueReply) -> tuple[dict, str]:
    """The cue state's JSON (see :meth:`coordinator.api.CueState.to_json`) and the result line."""
    return json.loads(m.state_json or "{}"), m.result
