"""The coordinator process: rig state, node sessions, frame fan-out, swap metrics,
mDNS advertisement and the two gRPC services (NodeLink for nodes, RigControl
for operators), plus the standard health and reflection services.

One asyncio loop owns all state. Frames are serialized once and the same bytes
are queued for every node (the Frames RPC is registered with an identity
serializer), so the cost per frame does not grow with the node count beyond
the sends themselves.
"""
from __future__ import annotations

import asyncio
import logging
import math
import resource
import secrets
import time
import uuid
from collections import deque
from dataclasses import dataclass, field
from pathlib import Path

import grpc
import numpy as np

from coordinator import wire
from coordinator.errors import CoordinatorError
from coordinator.mdns import Advertiser
from coordinator.rig import Content, Rig
from coordinator.sync import FrameResult, SyncTracker, summarize
from protos import auth, codec, common_pb2, control_pb2, node_pb2
from protos.version import GRPC_OPTIONS, PROTOCOL_VERSION, SERVER_GRPC_OPTIONS, SESSION_KEY

log = logging.getLogger(__name__)

SERVER_OPTIONS = SERVER_GRPC_OPTIONS + [("grpc.so_reuseport", 0)]
NONCE_TTL_S = 30.0
MAX_OPERATOR_SESSIONS = 256
OPERATOR_SESSION_TTL_S = 12 * 3600.0
MAX_PENDING_PACKETS = 512
HOST_BOOT_ID = ""
try:
    HOST_BOOT_ID = Path("/proc/sys/kernel/random/boot_id").read_text().strip()
except OSError:  # pragma: no cover - non-Linux
    pass


def cpu_seconds() -> float:
    ru = resource.getrusage(resource.RUSAGE_SELF)
    return ru.ru_utime + ru.ru_stime


@dataclass
class NodeSession:
    session: str
    slot: str
    peer: str
    info: node_pb2.NodeInfo
    instance_joins: int
    joined: float = field(default_factory=time.monotonic)
    last_seen: float = field(default_factory=time.monotonic)
    state: int = control_pb2.NODE_STATE_JOINED
    closed: bool = False
    frames_open: bool = False
    packets: deque = field(default_factory=deque)
    packet_event: asyncio.Event = field(default_factory=asyncio.Event)
    assignment_event: asyncio.Event = field(default_factory=asyncio.Event)
    sent_content: set[str] = field(default_factory=set)
    heartbeat: node_pb2.Heartbeat | None = None
    last_swap_frame: int = 0
    last_swap_at: float = 0.0
    shown: int = 0
    late: int = 0
    dropped: int = 0
    still_frames: set[int] = field(default_factory=set)   # ids of still frames sent to this node
    still_retries: int = 0

    @property
    def same_host(self) -> bool:
        return bool(HOST_BOOT_ID) and self.info.host_boot_id == HOST_BOOT_ID

    def push(self, packet: bytes) -> None:
        if self.closed:
            return
        if len(self.packets) >= MAX_PENDING_PACKETS:
            # The node stopped draining its stream: drop its backlog and resend what it needs.
            log.warning("node %s is not keeping up; dropping %d queued packets", self.slot, len(self.packets))
            self.packets.clear()
            self.sent_content.clear()
        self.packets.append(packet)
        self.packet_event.set()

    def close(self) -> None:
        self.closed = True
        self.packet_event.set()
        self.assignment_event.set()


class RpcRefusal(Exception):
    def __init__(self, code: grpc.StatusCode, message: str):
        super().__init__(message)
        self.code, self.message = code, message


class Coordinator:
    """The rig's single source of truth. Create, ``await start()``, ``await stop()``."""

    def __init__(self, rig: Rig, token: bytes, *, listen: str = "0.0.0.0:7600", mdns_interfaces: list[str] | None = None,
                 advertise: bool = True, tls: tuple[bytes, bytes] | None = None, latency_ms: float | None = None,
                 cameras: list[str] | None = None):
        self.rig = rig
        self.token = token
        self.listen = listen
        self.mdns_interfaces = mdns_interfaces
        self.advertise = advertise
        self.tls = tls
        self.latency_ns = int((latency_ms if latency_ms is not None else rig.config.latency_ms) * 1e6)
        self.instance_id = uuid.uuid4().hex[:12]
        self.started = time.monotonic()
        self.port = 0
        self.sessions: dict[str, NodeSession] = {}      # session id -> node session
        self.by_slot: dict[str, NodeSession] = {}
        self.operators: dict[str, float] = {}   # operator session -> last use (monotonic)
        self.joins: dict[str, int] = {}
        self.pending: dict[bytes, tuple[bytes, float]] = {}   # server nonce -> (client nonce, expiry)
        self.refusals: deque[tuple[str, str, str, float]] = deque(maxlen=64)
        self.sync = SyncTracker()
        # frame ids grow across restarts too (seeded from the wall clock in µs)
        self._next_frame_id = time.time_ns() // 1000
        self.current_frame: node_pb2.Frame | None = None   # what the rig shows (a still), resent to late joiners
        self.current_contents: dict[str, Content] = {}
        self.showing = "nothing"
        self._play_task: asyncio.Task | None = None
        self._waiters: dict[int, asyncio.Future] = {}
        self.encode_cpu_s = 0.0
        self._pattern_ids: set[str] = set()
        self.last_pattern_pts_ns = 0
        self.camera_specs: list[str] = list(cameras if cameras is not None else rig.config.cameras)
        self._job_lock = asyncio.Lock()
        self.sync.add_listener(self._resolve_waiter)
        self._server: grpc.aio.Server | None = None
        self._health = None
        self._advertiser: Advertiser | None = None
        self._tasks: list[asyncio.Task] = []
        if rig.content is not None:
            self._set_still(rig.content, tag="show:restored", space=node_pb2.SPACE_CONTENT, apply_lut=True, publish=False)

    # ------------------------------------------------------------------ lifecycle
    async def start(self) -> None:
        from grpc_health.v1 import health, health_pb2, health_pb2_grpc
        from grpc_reflection.v1alpha import reflection

        self._server = grpc.aio.server(options=SERVER_OPTIONS)
        _add_node_link(self._server, NodeLinkService(self))
        from protos import control_pb2_grpc

        control_pb2_grpc.add_RigControlServicer_to_server(RigControlService(self), self._server)
        self._health = health.aio.HealthServicer()
        health_pb2_grpc.add_HealthServicer_to_server(self._health, self._server)
        names = (
            node_pb2.DESCRIPTOR.services_by_name["NodeLink"].full_name,
            control_pb2.DESCRIPTOR.services_by_name["RigControl"].full_name,
            health_pb2.DESCRIPTOR.services_by_name["Health"].full_name,
            reflection.SERVICE_NAME,
        )
        reflection.enable_server_reflection(names, self._server)
        try:
            if self.tls:
                creds = grpc.ssl_server_credentials([(self.tls[1], self.tls[0])])
                self.port = self._server.add_secure_port(self.listen, creds)
            else:
                self.port = self._server.add_insecure_port(self.listen)
        except RuntimeError as exc:
            raise CoordinatorError(f"cannot listen on {self.listen}: {exc}") from exc
        if not self.port:
            raise CoordinatorError(f"cannot listen on {self.listen} (address in use or not on this host?)")
        await self._server.start()
        for name in names[:3]:
            await self._health.set(name, health_pb2.HealthCheckResponse.SERVING)
        await self._health.set("", health_pb2.HealthCheckResponse.SERVING)
        if self.advertise:
            self._advertiser = Advertiser(rig_name=self.rig.config.name, rig_id=self.rig.config.rig_id,
                                          instance_id=self.instance_id, port=self.port, interfaces=self.mdns_interfaces)
            await self._advertiser.start()
        self._tasks.append(asyncio.create_task(self._watchdog(), name="watchdog"))
        log.info("coordinator for rig %r (%s) listening on port %d, instance %s",
                 self.rig.config.name, self.rig.config.rig_id, self.port, self.instance_id)

    async def stop(self, grace: float = 2.0) -> None:
        """Graceful shutdown: health NOT_SERVING, mDNS unregister, streams closed, server stopped."""
        if self._health is not None:
            await self._health.enter_graceful_shutdown()
        if self._advertiser is not None:
            try:
                await self._advertiser.stop()
            except Exception:  # pragma: no cover - best effort on shutdown
                log.exception("mDNS unregister failed")
        if self._play_task is not None:
            self._play_task.cancel()
        for t in self._tasks:
            t.cancel()
        for sess in list(self.sessions.values()):
            sess.close()
        if self._server is not None:
            await self._server.stop(grace)
        pending = self._tasks + ([self._play_task] if self._play_task else [])
        await asyncio.gather(*pending, return_exceptions=True)

    # ------------------------------------------------------------------ helpers
    def rig_now(self) -> int:
        return time.monotonic_ns()

    def new_frame_id(self) -> int:
        self._next_frame_id += 1
        return self._next_frame_id

    def refuse(self, peer: str, slot: str, code: grpc.StatusCode, message: str) -> RpcRefusal:
        self.refusals.append((peer, slot, message, time.monotonic()))
        log.warning("refused %s (slot %s): %s", peer, slot or "-", message)
        return RpcRefusal(code, message)

    def live_sessions(self) -> list[NodeSession]:
        return [s for s in self.by_slot.values() if not s.closed and s.frames_open]

    def content_size(self) -> tuple[int, int]:
        return self.rig.config.content_width, self.rig.config.content_height

    # ------------------------------------------------------------------ auth
    def hello(self, req: common_pb2.HelloRequest, peer: str) -> common_pb2.HelloReply:
        if req.protocol_version != PROTOCOL_VERSION:
            raise self.refuse(peer, req.slot, grpc.StatusCode.FAILED_PRECONDITION,
                              f"protocol version mismatch: {req.role or 'client'} {req.slot} speaks shadowless protocol "
                              f"{req.protocol_version}, coordinator of rig {self.rig.config.name!r} speaks {PROTOCOL_VERSION}; "
                              f"install the same shadowless release on both")
        if len(req.client_nonce) != auth.NONCE_BYTES:
            raise self.refuse(peer, req.slot, grpc.StatusCode.INVALID_ARGUMENT, "client nonce must be 32 bytes")
        now = time.monotonic()
        for n, (_, exp) in list(self.pending.items()):
            if exp < now:
                del self.pending[n]
        if len(self.pending) > 4096:
            raise self.refuse(peer, req.slot, grpc.StatusCode.RESOURCE_EXHAUSTED, "too many handshakes in flight")
        server_nonce = auth.new_nonce()
        self.pending[server_nonce] = (req.client_nonce, now + NONCE_TTL_S)
        cfg = self.rig.config
        return common_pb2.HelloReply(
            protocol_version=PROTOCOL_VERSION, rig_id=cfg.rig_id, rig_name=cfg.name, server_nonce=server_nonce,
            server_proof=auth.coordinator_proof(self.token, cfg.rig_id, req.client_nonce, server_nonce),
            instance_id=self.instance_id,
        )

    def check_login(self, req: common_pb2.LoginRequest, peer: str, role: str) -> None:
        if req.protocol_version != PROTOCOL_VERSION:
            raise self.refuse(peer, req.slot, grpc.StatusCode.FAILED_PRECONDITION,
                              f"protocol version mismatch: {role} speaks {req.protocol_version}, coordinator speaks {PROTOCOL_VERSION}")
        if req.role != role:
            raise self.refuse(peer, req.slot, grpc.StatusCode.INVALID_ARGUMENT, f"this call is for role {role!r}, not {req.role!r}")
        entry = self.pending.pop(req.server_nonce, None)
        if entry is None or entry[0] != req.client_nonce or entry[1] < time.monotonic():
            raise self.refuse(peer, req.slot, grpc.StatusCode.UNAUTHENTICATED,
                              "handshake expired or unknown: call Hello again (nonces are single use)")
        expected = auth.client_proof(self.token, role, self.rig.config.rig_id, req.slot, req.client_nonce, req.server_nonce)
        if not auth.verify(expected, req.client_proof):
            who = f"node {req.slot}" if role == "node" else "operator"
            raise self.refuse(peer, req.slot, grpc.StatusCode.UNAUTHENTICATED,
                              f"rig token mismatch: {who} at {peer} does not know the token of rig "
                              f"{self.rig.config.name!r} (id {self.rig.config.rig_id}); give it this rig's token file")

    def join(self, req: node_pb2.JoinRequest, peer: str) -> node_pb2.JoinReply:
        login = req.login
        self.check_login(login, peer, "node")
        if login.slot not in self.rig.slots:
            raise self.refuse(peer, login.slot, grpc.StatusCode.NOT_FOUND,
                              f"slot {login.slot!r} is not in rig {self.rig.config.name!r} "
                              f"(slots: {', '.join(self.rig.slots)}); add it to rig.toml or start the node with one of these")
        old = self.by_slot.get(login.slot)
        if old is not None and not old.closed:
            log.info("node %s rejoined from %s; closing its previous session", login.slot, peer)
            self._drop_session(old, lost=False)
        st = self.rig.slot(login.slot)
        native = (req.info.native_width, req.info.native_height)
        if all(native) and native != (st.width, st.height):
            # the display knows its resolution better than rig.toml; a pose made for another size is stale
            log.warning("node %s drives a %dx%d output, rig.toml says %dx%d: adopting the node's size%s", login.slot,
                        *native, st.width, st.height, " (recalibrate this slot)" if st.pose is not None else "")
            self.rig.update_slot(login.slot, size=native, source="node")
        self.joins[login.slot] = self.joins.get(login.slot, 0) + 1
        sess = NodeSession(session=secrets.token_hex(16), slot=login.slot, peer=peer, info=req.info,
                           instance_joins=self.joins[login.slot])
        self.sessions[sess.session] = sess
        self.by_slot[login.slot] = sess
        log.info("node %s joined from %s (%s, pid %d)", login.slot, peer, req.info.hostname, req.info.pid)
        return node_pb2.JoinReply(session=sess.session, slot=login.slot, rig_id=self.rig.config.rig_id,
                                  instance_id=self.instance_id, heartbeat_interval_ms=self.rig.config.heartbeat_ms)

    def login(self, req: common_pb2.LoginRequest, peer: str) -> common_pb2.LoginReply:
        self.check_login(req, peer, "operator")
        session = secrets.token_hex(16)
        self.operators[session] = time.monotonic()
        if len(self.operators) > MAX_OPERATOR_SESSIONS:   # every CLI call logs in: forget the oldest
            for old in sorted(self.operators, key=self.operators.get)[: len(self.operators) - MAX_OPERATOR_SESSIONS]:
                del self.operators[old]
        return common_pb2.LoginReply(session=session, rig_id=self.rig.config.rig_id, instance_id=self.instance_id)

    def node_session(self, context: grpc.aio.ServicerContext) -> NodeSession:
        sid = dict(context.invocation_metadata() or ()).get(SESSION_KEY, "")
        sess = self.sessions.get(sid)
        if sess is None or sess.closed:
            raise RpcRefusal(grpc.StatusCode.UNAUTHENTICATED,
                             f"unknown or closed session (coordinator instance {self.instance_id}): join again")
        return sess

    def operator_session(self, context: grpc.aio.ServicerContext) -> None:
        sid = dict(context.invocation_metadata() or ()).get(SESSION_KEY, "")
        if sid not in self.operators or time.monotonic() - self.operators[sid] > OPERATOR_SESSION_TTL_S:
            self.operators.pop(sid, None)
            raise RpcRefusal(grpc.StatusCode.UNAUTHENTICATED, "not logged in: call Hello and Login with the rig token")
        self.operators[sid] = time.monotonic()

    # ------------------------------------------------------------------ sessions
    def _drop_session(self, sess: NodeSession, *, lost: bool) -> None:
        sess.close()
        self.sessions.pop(sess.session, None)
        if lost:
            sess.state = control_pb2.NODE_STATE_LOST
            log.warning("node %s lost (last seen %.1f s ago)", sess.slot, time.monotonic() - sess.last_seen)
        self.sync.forget_slot(sess.slot)

    def mark_lost(self, sess: NodeSession) -> None:
        if not sess.closed:
            self._drop_session(sess, lost=True)

    async def _watchdog(self) -> None:
        lost_after = self.rig.config.lost_after_ms / 1000.0
        while True:
            await asyncio.sleep(0.25)
            now = time.monotonic()
            for sess in list(self.by_slot.values()):
                if not sess.closed and now - sess.last_seen > lost_after:
                    self.mark_lost(sess)
            self.sync.sweep()

    def on_frames_open(self, sess: NodeSession) -> None:
        sess.frames_open = True
        sess.sent_content.clear()
        if self.current_frame is not None and (self._play_task is None or self._play_task.done()):
            self._send_still_to(sess)

    # ------------------------------------------------------------------ frames
    def _send(self, sessions: list[NodeSession], *, frame: node_pb2.Frame | None = None,
              contents: dict[str, Content] | None = None, evict: list[str] | None = None) -> None:
        """Queue one packet per group of sessions that lack the same contents.

        Contents are encoded once; each distinct packet is serialized once and the
        same bytes go to every session of its group.
        """
        t0 = time.thread_time()
        contents = contents or {}
        groups: dict[frozenset[str], list[NodeSession]] = {}
        for s in sessions:
            if frame is not None:   # a node needs only what its own slot shows
                cid = frame.slot_content[s.slot] if s.slot in frame.slot_content else frame.content_id
                needed = {cid} & contents.keys()
            else:
                needed = contents.keys()
            missing = frozenset(cid for cid in needed if cid not in s.sent_content)
            groups.setdefault(missing, []).append(s)
        encoded: dict[str, node_pb2.Content] = {}
        for missing, members in groups.items():
            pkt = node_pb2.FramePacket()
            for cid in sorted(missing):
                if cid not in encoded:
                    encoded[cid] = wire.content_message(contents[cid])
                pkt.contents.append(encoded[cid])
            if frame is not None:
                pkt.frame.CopyFrom(frame)
            if evict:
                pkt.evict.content_ids.extend(evict)
            data = pkt.SerializeToString()
            self.encode_cpu_s += time.thread_time() - t0
            for s in members:
                s.push(data)
                s.sent_content |= missing
                if evict:
                    s.sent_content.difference_update(evict)
            t0 = time.thread_time()
        if frame is not None:
            self.sync.expect(frame.frame_id, frame.pts_ns, frame.tag, {s.slot for s in sessions})

    def _frame(self, content_id: str, *, tag: str, space: int, apply_lut: bool, pts_ns: int | None = None,
               slot_content: dict[str, str] | None = None) -> node_pb2.Frame:
        return node_pb2.Frame(frame_id=self.new_frame_id(), pts_ns=pts_ns or self.rig_now() + self.latency_ns,
                              content_id=content_id, space=space, apply_lut=apply_lut, tag=tag,
                              slot_content=slot_content or {})

    def _send_still_to(self, sess: NodeSession, *, budget_ns: int | None = None) -> None:
        frame = node_pb2.Frame()
        frame.CopyFrom(self.current_frame)
        frame.frame_id = self.new_frame_id()
        frame.pts_ns = self.rig_now() + (budget_ns or self.latency_ns)
        sess.still_frames = {frame.frame_id}
        self._send([sess], frame=frame, contents=self.current_contents)

    def _retry_still(self, sess: NodeSession, frame_id: int) -> None:
        """A still must end up on every projector: a node that dropped it gets it again, with more time."""
        if frame_id not in sess.still_frames or self.current_frame is None or not self.current_frame.tag.startswith("show"):
            return
        sess.still_retries += 1
        budget = min(2_000_000_000, self.latency_ns * 2 ** min(sess.still_retries, 6))
        log.info("node %s dropped still frame %d; resending with %.0f ms budget", sess.slot, frame_id, budget / 1e6)
        self._send_still_to(sess, budget_ns=budget)

    def _set_still(self, content: Content, *, tag: str, space: int, apply_lut: bool, publish: bool = True) -> node_pb2.Frame:
        self.current_contents = {content.content_id: content}
        frame = self._frame(content.content_id, tag=tag, space=space, apply_lut=apply_lut)
        self.current_frame = frame
        self.showing = f"{tag} {content.name or content.content_id}"
        if publish:
            sessions = self.live_sessions()
            for sess in sessions:
                sess.still_frames = {frame.frame_id}
                sess.still_retries = 0
            self._send(sessions, frame=frame, contents=self.current_contents)
        return frame

    def fit_content(self, content: Content) -> Content:
        """Scale an image to the rig's content size (the poses map content px); same dtype."""
        w, h = self.content_size()
        img = content.image
        if img.shape[1] == w and img.shape[0] == h:
            return content
        import cv2

        interp = cv2.INTER_AREA if img.shape[1] > w else cv2.INTER_LINEAR
        scaled = cv2.resize(img, (w, h), interpolation=interp)
        if scaled.ndim == 2:
            scaled = scaled[:, :, None]
        return Content(scaled, name=content.name)

    def show(self, content: Content, *, space: int = node_pb2.SPACE_CONTENT, apply_lut: bool = True,
             persist: bool = False, tag: str = "show") -> node_pb2.Frame:
        self.stop_playback()
        if space == node_pb2.SPACE_CONTENT:
            content = self.fit_content(content)
        if persist:
            self.rig.set_content(content)
        return self._set_still(content, tag=tag, space=space, apply_lut=apply_lut)

    def stop_playback(self) -> None:
        if self._play_task is not None and not self._play_task.done():
            self._play_task.cancel()
        self._play_task = None

    def _resolve_waiter(self, result: FrameResult) -> None:
        fut = self._waiters.pop(result.frame_id, None)
        if fut is not None and not fut.done():
            fut.set_result(result)

    async def show_patterns(self, images: dict[str, np.ndarray | None], *, content: np.ndarray | None = None,
                            apply_lut: bool = False, settle_s: float = 0.05, attempts: int = 4,
                            timeout_s: float = 15.0) -> FrameResult:
        """Show per-slot projector-space images (or one content image through the poses) on every
        connected node and return once all of them swapped it in, plus ``settle_s``.

        A node that dropped the frame (late) gets it again with a longer budget; after ``attempts``
        the call fails and names the nodes that never showed it.
        """
        self.stop_playback()
        sessions = self.live_sessions()
        contents: dict[str, Content] = {}
        slot_content: dict[str, str] = {}
        default, space = "", node_pb2.SPACE_PROJECTOR
        if content is not None:
            c = self.fit_content(Content(content, name="pattern"))
            contents[c.content_id] = c
            default, space = c.content_id, node_pb2.SPACE_CONTENT
        for slot, img in images.items():
            st = self.rig.slot(slot)
            if img is None:
                slot_content[slot] = ""
                continue
            c = Content(img, name=f"pattern {slot}")
            if c.image.shape[:2] != (st.height, st.width):
                raise ValueError(f"pattern for {slot} is {c.image.shape[1]}x{c.image.shape[0]}, "
                                 f"its projector is {st.width}x{st.height}")
            contents[c.content_id] = c
            slot_content[slot] = c.content_id
        evict = sorted(self._pattern_ids - contents.keys())
        budget = self.latency_ns
        loop = asyncio.get_running_loop()
        for _ in range(attempts):
            frame = self._frame(default, tag="pattern", space=space, apply_lut=apply_lut,
                                slot_content=slot_content, pts_ns=self.rig_now() + budget)
            fut = loop.create_future()
            self._waiters[frame.frame_id] = fut
            self._send(sessions, frame=frame, contents=contents, evict=evict)
            evict = []
            self.current_frame, self.current_contents = frame, contents
            self.showing = "calibration pattern"
            try:
                result = await asyncio.wait_for(fut, timeout_s)
            finally:
                self._waiters.pop(frame.frame_id, None)
            if result.shown_by_all:
                break
            budget = min(4 * budget, 2_000_000_000)
            sessions = self.live_sessions()
        else:
            raise CoordinatorError(f"node(s) {', '.join(result.missing)} did not show the pattern after "
                                   f"{attempts} tries (late or disconnected); check `shadowless status`")
        self._pattern_ids = set(contents)
        self.last_pattern_pts_ns = frame.pts_ns
        if settle_s > 0:
            await asyncio.sleep(settle_s)
        return result

    def restore_content(self) -> None:
        """After a job: show the rig's content again (or black)."""
        if self.rig.content is not None:
            self.show(self.rig.content, tag="show:restored")
        else:
            self.current_frame, self.current_contents = None, {}
            self.showing = "nothing"

    async def run_job(self, kind: str, params: dict, emit) -> dict:
        from coordinator.jobs import JobContext, resolve

        job = resolve(kind)
        if self._job_lock.locked():
            raise CoordinatorError("another job is running on this rig; wait for it or cancel it")
        async with self._job_lock:
            specs = params.pop("cameras", None) or self.camera_specs
            ctx = JobContext(coordinator=self, emit=emit, camera_specs=list(specs))
            try:
                return await job(ctx, params)
            finally:
                ctx.close()
                self.restore_content()

    async def play(self, frames: list[Content] | None, settings: control_pb2.PlaySettings) -> control_pb2.PlayReply:
        """Play ``frames`` (or a generated pattern) at ``settings.fps``; return the figures."""
        self.stop_playback()
        task = asyncio.create_task(self._play(frames, settings), name="play")
        self._play_task = task
        if not settings.wait:
            task.add_done_callback(lambda t: t.cancelled() or t.exception())
            return control_pb2.PlayReply()
        return await asyncio.shield(task)

    async def _play(self, frames: list[Content] | None, st: control_pb2.PlaySettings) -> control_pb2.PlayReply:
        fps = st.fps or 30.0
        if not 0.1 <= fps <= 1000:
            raise ValueError(f"fps must be in 0.1..1000, got {fps}")
        latency_ns = int(st.latency_ms * 1e6) if st.latency_ms > 0 else self.latency_ns
        if frames is None:
            count = st.frames or int(fps * 5)
            w, h = self.content_size()
            make = lambda i: counter_pattern(i, w, h)  # noqa: E731
        else:
            count = len(frames) * (st.loops + 1)
            frames = [self.fit_content(f) for f in frames]
            make = lambda i: frames[i % len(frames)]  # noqa: E731
        tag = f"play:{uuid.uuid4().hex[:8]}"
        results: list[FrameResult] = []
        remove = self.sync.add_listener(lambda r: results.append(r) if r.tag == tag else None)
        oo_before = self.sync.out_of_order
        cpu0, wall0, enc0 = cpu_seconds(), time.monotonic(), self.encode_cpu_s
        sent: list[int] = []
        nodes_seen: set[str] = set()
        prev_content: str | None = None
        cache_all = frames is not None and st.loops > 0 and sum(f.image.nbytes for f in frames) < 256 * 2**20
        self.showing = f"{tag} ({count} frames at {fps:g} fps)"
        try:
            t0 = self.rig_now() + latency_ns
            for i in range(count):
                tick = t0 + int(i * 1e9 / fps)
                wait = (tick - latency_ns - self.rig_now()) / 1e9
                if wait > 0:
                    await asyncio.sleep(wait)
                content = make(i)
                sessions = self.live_sessions()
                nodes_seen.update(s.slot for s in sessions)
                frame = self._frame(content.content_id, tag=tag, space=node_pb2.SPACE_CONTENT, apply_lut=True,
                                    pts_ns=max(tick, self.rig_now() + latency_ns // 2))
                evict = [prev_content] if prev_content and prev_content != content.content_id and not cache_all else None
                self._send(sessions, frame=frame, contents={content.content_id: content}, evict=evict)
                sent.append(frame.frame_id)
                self.current_frame, self.current_contents = frame, {content.content_id: content}
                prev_content = content.content_id
            # wait for the last swap reports
            deadline = time.monotonic() + (latency_ns / 1e9) + (st.settle_s or 1.0) + self.sync.timeout_s
            while time.monotonic() < deadline and len(results) < len(sent):
                await asyncio.sleep(0.05)
        finally:
            remove()
        cpu = cpu_seconds() - cpu0
        summary = summarize(results, self.sync.out_of_order - oo_before)
        reply = control_pb2.PlayReply(
            frames_sent=len(sent), frames_shown=summary["frames"], frames_late=summary["frames_late"],
            frames_dropped=summary["frames_dropped"] + (len(sent) - len(results)), coordinator_cpu_s=cpu,
            nodes=len(nodes_seen), wall_s=time.monotonic() - wall0,
            skews_ms=[r.skew_ms for r in sorted(results, key=lambda r: r.frame_id)],
            clock_errors_ms=[e for r in results for e in r.clock_errors_ms],
            encode_cpu_s=self.encode_cpu_s - enc0,
        )
        reply.sync.CopyFrom(sync_message(summary))
        self.showing = f"{tag} finished"
        return reply

    # ------------------------------------------------------------------ reports
    def on_report(self, sess: NodeSession, rep: node_pb2.NodeReport) -> None:
        sess.last_seen = time.monotonic()
        if sess.state == control_pb2.NODE_STATE_JOINED:
            sess.state = control_pb2.NODE_STATE_LIVE
        if rep.HasField("heartbeat"):
            sess.heartbeat = rep.heartbeat
        for sw in rep.swaps:
            if sw.frame_id < sess.last_swap_frame:
                self.sync.out_of_order += 1
                log.error("node %s reported frame %d after frame %d", sess.slot, sw.frame_id, sess.last_swap_frame)
            sess.last_swap_frame = sw.frame_id
            sess.last_swap_at = time.monotonic()
            sess.shown += 1
            self.sync.on_swap(sess.slot, sw.frame_id, sw.swap_rig_ns, sw.host_monotonic_ns, sess.same_host)
        for drop in rep.drops:
            if drop.reason == node_pb2.DROP_REASON_LATE:
                sess.late += 1
            else:
                sess.dropped += 1
            self.sync.on_drop(sess.slot, drop.frame_id, drop.reason)
            self._retry_still(sess, drop.frame_id)

    # ------------------------------------------------------------------ configure
    def update_slot(self, slot: str, **changes):
        """Change a slot's assignment (persisted first), then push it to the slot's node."""
        st = self.rig.update_slot(slot, **changes)
        sess = self.by_slot.get(slot)
        if sess is not None:
            sess.assignment_event.set()
        return st

    def configure(self, req: control_pb2.ConfigureRequest) -> int:
        kwargs: dict = {}
        if req.HasField("homography"):
            kwargs["pose"] = wire.homography_from_message(req.homography)
        elif req.clear_pose:
            kwargs["pose"] = None
        if req.HasField("lut"):
            kwargs["lut"] = wire.lut_from_message(req.lut)
        if req.gain > 0:
            kwargs["gain"] = req.gain
        if req.output_width or req.output_height:
            kwargs["size"] = (req.output_width, req.output_height)
        return self.update_slot(req.slot, **kwargs).revision

    # ------------------------------------------------------------------ status
    def status(self) -> control_pb2.RigStatus:
        now = time.monotonic()
        msg = control_pb2.RigStatus(
            rig_id=self.rig.config.rig_id, rig_name=self.rig.config.name, instance_id=self.instance_id,
            rig_dir=str(self.rig.path), protocol_version=PROTOCOL_VERSION, uptime_s=now - self.started,
            showing=self.showing, latency_budget_ms=self.latency_ns / 1e6, cpu_s=cpu_seconds(),
        )
        for name, st in self.rig.slots.items():
            n = msg.nodes.add(slot=name, state=control_pb2.NODE_STATE_EXPECTED, assignment_revision=st.revision,
                              pose_kind=st.pose.kind if st.pose is not None else "none", clock_error_ms=math.nan,
                              joins=self.joins.get(name, 0))
            sess = self.by_slot.get(name)
            if sess is None:
                continue
            n.state = sess.state
            n.hostname, n.pid = sess.info.hostname, sess.info.pid
            n.last_seen_age_ms = (now - sess.last_seen) * 1e3
            n.last_swap_frame = sess.last_swap_frame
            n.last_swap_age_ms = (now - sess.last_swap_at) * 1e3 if sess.last_swap_at else math.nan
            n.frames_late, n.frames_dropped = sess.late, sess.dropped
            n.frames_shown = sess.shown
            hb = sess.heartbeat
            if hb is not None:
                n.clock_offset_ms = hb.clock_offset_ns / 1e6
                n.clock_drift_ppm = hb.clock_drift_ppm
                n.clock_rtt_ms = hb.clock_rtt_ns / 1e6
                n.assignment_revision = hb.assignment_revision
                if sess.same_host and hb.host_monotonic_ns:
                    n.clock_error_ms = (hb.rig_estimate_ns - hb.host_monotonic_ns) / 1e6
        msg.sync.CopyFrom(sync_message(summarize(list(self.sync.results), self.sync.out_of_order)))
        for peer, slot, reason, at in self.refusals:
            msg.refusals.add(peer=peer, slot=slot, reason=reason, age_s=now - at)
        return msg


def _json_default(o):
    if isinstance(o, np.generic):
        return o.item()
    if isinstance(o, np.ndarray):
        return o.tolist()
    if isinstance(o, Path):
        return str(o)
    raise TypeError(f"not JSON serializable: {type(o).__name__}")


def sync_message(summary: dict) -> control_pb2.SyncStats:
    return control_pb2.SyncStats(**summary)


def counter_pattern(i: int, width: int, height: int) -> Content:
    """Test frame ``i``: a moving bar and the frame number in binary blocks; (H, W, 3) uint8."""
    img = np.zeros((height, width, 3), np.uint8)
    x = (i * 7) % width
    img[:, max(0, x - 4): x + 4, :] = 255
    bits = [(i >> b) & 1 for b in range(16)]
    bw = max(1, width // 16)
    for b, on in enumerate(bits):
        if on:
            img[: max(1, height // 8), b * bw: (b + 1) * bw, 1] = 255
    img[..., 2] = np.uint8(i % 256)
    return Content(img, name=f"counter {i}")


# ---------------------------------------------------------------------- servicers
def _peer(context) -> str:
    return context.peer() or "unknown"


def _guard(fn):
    """Turn RpcRefusal and validation errors into gRPC statuses with clear messages."""
    import functools

    @functools.wraps(fn)
    async def wrapper(self, request, context):
        try:
            return await fn(self, request, context)
        except RpcRefusal as exc:
            await context.abort(exc.code, exc.message)
        except (ValueError, codec.ImageCodecError) as exc:
            await context.abort(grpc.StatusCode.INVALID_ARGUMENT, str(exc))
        except CoordinatorError as exc:
            await context.abort(grpc.StatusCode.FAILED_PRECONDITION, str(exc))

    return wrapper


class _Handshake:
    """The first half of the rig-token handshake, the same on both services."""

    def __init__(self, coord: Coordinator):
        self.c = coord

    @_guard
    async def Hello(self, request, context):
        return self.c.hello(request, _peer(context))


class NodeLinkService(_Handshake):

    @_guard
    async def Join(self, request, context):
        return self.c.join(request, _peer(context))

    async def Assignments(self, request, context):
        try:
            sess = self.c.node_session(context)
        except RpcRefusal as exc:
            await context.abort(exc.code, exc.message)
        sent = -1
        while not sess.closed:
            st = self.c.rig.slots[sess.slot]
            if st.revision != sent:
                sent = st.revision
                yield wire.assignment_message(st, content_size=self.c.content_size())
            sess.assignment_event.clear()
            await sess.assignment_event.wait()

    async def Frames(self, request, context):
        try:
            sess = self.c.node_session(context)
        except RpcRefusal as exc:
            await context.abort(exc.code, exc.message)
        self.c.on_frames_open(sess)
        try:
            while not sess.closed:
                while sess.packets:
                    yield sess.packets.popleft()
                    if sess.closed:
                        return
                sess.packet_event.clear()
                if not sess.packets:
                    await sess.packet_event.wait()
        finally:
            sess.frames_open = False

    async def Report(self, request_iterator, context):
        try:
            sess = self.c.node_session(context)
        except RpcRefusal as exc:
            await context.abort(exc.code, exc.message)
        try:
            async for rep in request_iterator:
                if sess.closed:
                    break
                self.c.on_report(sess, rep)
        except (asyncio.CancelledError, grpc.aio.AioRpcError):
            pass
        finally:
            # the report stream is the node's lifeline: when it ends, the node is gone
            self.c.mark_lost(sess)
        return node_pb2.ReportAck()

    async def Ping(self, request, context):
        t1 = time.monotonic_ns()
        # a session check keeps the clock service to members of the rig
        sid = dict(context.invocation_metadata() or ()).get(SESSION_KEY, "")
        if sid not in self.c.sessions:
            await context.abort(grpc.StatusCode.UNAUTHENTICATED, "join before pinging")
        return node_pb2.PingReply(t0_local_ns=request.t0_local_ns, t1_rig_ns=t1, t2_rig_ns=time.monotonic_ns(),
                                  instance_id=self.c.instance_id)


def _add_node_link(server: grpc.aio.Server, svc: NodeLinkService) -> None:
    """Register NodeLink; Frames yields pre-serialized bytes (identity serializer)."""
    handlers = {
        "Hello": grpc.unary_unary_rpc_method_handler(
            svc.Hello, request_deserializer=common_pb2.HelloRequest.FromString,
            response_serializer=common_pb2.HelloReply.SerializeToString),
        "Join": grpc.unary_unary_rpc_method_handler(
            svc.Join, request_deserializer=node_pb2.JoinRequest.FromString,
            response_serializer=node_pb2.JoinReply.SerializeToString),
        "Assignments": grpc.unary_stream_rpc_method_handler(
            svc.Assignments, request_deserializer=node_pb2.StreamRequest.FromString,
            response_serializer=node_pb2.Assignment.SerializeToString),
        "Frames": grpc.unary_stream_rpc_method_handler(
            svc.Frames, request_deserializer=node_pb2.StreamRequest.FromString, response_serializer=None),
        "Report": grpc.stream_unary_rpc_method_handler(
            svc.Report, request_deserializer=node_pb2.NodeReport.FromString,
            response_serializer=node_pb2.ReportAck.SerializeToString),
        "Ping": grpc.unary_unary_rpc_method_handler(
            svc.Ping, request_deserializer=node_pb2.PingRequest.FromString,
            response_serializer=node_pb2.PingReply.SerializeToString),
    }
    server.add_generic_rpc_handlers((grpc.method_handlers_generic_handler("shadowless.v1.NodeLink", handlers),))


class RigControlService(_Handshake):

    @_guard
    async def Login(self, request, context):
        return self.c.login(request, _peer(context))

    @_guard
    async def Status(self, request, context):
        self.c.operator_session(context)
        return self.c.status()

    @_guard
    async def ListNodes(self, request, context):
        self.c.operator_session(context)
        return control_pb2.NodeList(nodes=self.c.status().nodes)

    @_guard
    async def Show(self, request, context):
        self.c.operator_session(context)
        img = codec.decode_image(request.image)
        if img.dtype == np.float16:
            img = img.astype(np.float32)
        content = Content(img, name=request.name)
        space = request.space or node_pb2.SPACE_CONTENT
        apply_lut = request.apply_lut or space == node_pb2.SPACE_CONTENT
        frame = self.c.show(content, space=space, apply_lut=apply_lut, persist=request.persist)
        return control_pb2.ShowReply(frame_id=frame.frame_id, content_id=content.content_id, pts_ns=frame.pts_ns)

    async def Play(self, request_iterator, context):
        try:
            self.c.operator_session(context)
            settings: control_pb2.PlaySettings | None = None
            frames: list[Content] = []
            async for item in request_iterator:
                kind = item.WhichOneof("item")
                if kind == "settings":
                    settings = item.settings
                elif kind == "frame":
                    img = codec.decode_image(item.frame)
                    frames.append(Content(img.astype(np.float32) if img.dtype == np.float16 else img))
            if settings is None:
                raise ValueError("the first PlayItem must carry the settings")
            if not settings.pattern and not frames:
                raise ValueError("nothing to play: send frames or set a pattern")
            if settings.pattern and settings.pattern != "counter":
                raise ValueError(f"unknown pattern {settings.pattern!r} (known: counter)")
            return await self.c.play(None if settings.pattern else frames, settings)
        except RpcRefusal as exc:
            await context.abort(exc.code, exc.message)
        except (ValueError, codec.ImageCodecError) as exc:
            await context.abort(grpc.StatusCode.INVALID_ARGUMENT, str(exc))

    @_guard
    async def Stop(self, request, context):
        self.c.operator_session(context)
        self.c.stop_playback()
        return control_pb2.StopReply()

    async def RunJob(self, request, context):
        import json

        from coordinator.jobs import Progress

        try:
            self.c.operator_session(context)
            params = json.loads(request.params_json or "{}")
            if not isinstance(params, dict):
                raise ValueError("job parameters must be a JSON object")
        except RpcRefusal as exc:
            await context.abort(exc.code, exc.message)
        except ValueError as exc:
            await context.abort(grpc.StatusCode.INVALID_ARGUMENT, f"bad job parameters: {exc}")
        events: asyncio.Queue = asyncio.Queue()

        def emit(ev) -> None:
            if isinstance(ev, Progress):
                events.put_nowait(control_pb2.JobEvent(progress=control_pb2.JobProgress(
                    stage=ev.stage, item=ev.item, done=ev.done, total=ev.total, message=ev.message, value=ev.value)))
            else:
                events.put_nowait(control_pb2.JobEvent(log=str(ev)))

        task = asyncio.create_task(self.c.run_job(request.kind, params, emit), name=f"job:{request.kind}")
        try:
            while True:
                getter = asyncio.ensure_future(events.get())
                done, _ = await asyncio.wait({getter, task}, return_when=asyncio.FIRST_COMPLETED)
                if getter in done:
                    yield getter.result()
                    continue
                getter.cancel()
                while not events.empty():
                    yield events.get_nowait()
                break
            try:
                result = task.result()
            except (CoordinatorError, ValueError, OSError) as exc:
                log.error("job %s failed: %s", request.kind, exc)
                await context.abort(grpc.StatusCode.FAILED_PRECONDITION, f"{request.kind}: {exc}")
            yield control_pb2.JobEvent(result_json=json.dumps(result, default=_json_default))
        finally:
            if not task.done():
                log.warning("job %s cancelled by its client", request.kind)
                task.cancel()
                await asyncio.gather(task, return_exceptions=True)

    @_guard
    async def Configure(self, request, context):
        self.c.operator_session(context)
        return control_pb2.ConfigureReply(revision=self.c.configure(request))
