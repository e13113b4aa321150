"""The coordinator's core: the rig's single source of truth.

:class:`Coordinator` owns the rig state and composes the parts: the handshake and sessions
(:mod:`coordinator.sessions`), the frame fan-out (:mod:`coordinator.fanout`), what the rig
shows (:mod:`coordinator.playback`), the swap bookkeeping (:mod:`coordinator.sync`) and the
assets nodes fetch ahead (:mod:`coordinator.distribution`). It serves nothing itself: the
composition root (:mod:`coordinator.app`) builds the gRPC services, the console and the mDNS
advertiser beside it, and they see it through the Protocols of :mod:`coordinator.ports`. It
implements :class:`coordinator.jobs.driver.RigDriver`, so jobs run on it through a
:class:`~coordinator.jobs.context.JobContext` and never see it.

One asyncio loop owns all state. The rig clock is the coordinator's monotonic clock,
injectable (``clock_ns``) so tests decide when time passes.
"""
from __future__ import annotations

import asyncio
import hashlib
import hmac
import logging
import math
import secrets
import time
import uuid
from functools import lru_cache, partial
from typing import Any, AsyncIterator, Callable, Mapping, Sequence

import numpy as np

from coordinator.api import (
    AssetProgress,
    DropReason,
    NodeState,
    NodeStatus,
    PlayResult,
    PlaySettings,
    RigStatus,
    ShowResult,
    ShowState,
    Space,
)
from coordinator.admission import Budget, trim_memory
from coordinator.api import BlendStatus
from coordinator.assets import AssetStore
from coordinator.blending.state import BlendState
from coordinator.blending.watchdog import LampWatchdog, steady_span
from coordinator.camera import Camera, RoomCamera, open_camera
from coordinator.distribution import Distribution, WantedList, note_ready
from coordinator import cues
from coordinator.errors import CoordinatorError, Refusal, RefusalKind
from coordinator.fanout import FanOut, PacketEncoding
from coordinator.jobs.context import Event
from coordinator.jobs.registry import run_job
from coordinator.identify import identify_cards
from coordinator.late_window import LateWindow
from coordinator import slot_tools
from coordinator.unposed import unposed_warning
from coordinator.jobs.tracker import JobState, JobTracker
from coordinator.playback import Playback, cpu_seconds
from coordinator.previews import Previews
from coordinator.refusals import Refusals
from coordinator.rig import Content, Rig
from coordinator.recovery import recover
from coordinator.rig_lock import RigLock
from coordinator.sessions import Handshake, NodeInfo, NodeSession, Report
from coordinator.ports import SlotLink
from coordinator.show import MIN_LEAD_NS, Show, ShowUpdate
from coordinator.sync import FrameResult, SyncTracker, summarize
from protos import sd_notify
from protos.asset_manifest import Manifest
from protos.host import boot_id
from protos.version import MAX_REQUEST_BYTES, PROTOCOL_VERSION

log = logging.getLogger(__name__)

#: how often the watchdog looks for assets added or removed by `shadowless content`
STORE_POLL_S = 1.0


class _AfterLastPattern:
    """A job's room camera that captures only frames swapped after the last pattern was shown."""

    def __init__(self, camera: RoomCamera, coordinator: "Coordinator"):
        self.camera, self._coordinator = camera, coordinator
        self.spec = camera.spec
        self.supports_exposure = camera.supports_exposure

    @property
    def size(self) -> tuple[int, int] | None:
        return self.camera.size

    def capture(self, *, exposure: float | None = None) -> np.ndarray:
        pts = self._coordinator.playback.last_pattern_pts_ns
        if pts:
            self.camera.not_before(pts)
        return self.camera.capture(exposure=exposure)

    def close(self) -> None:
        self.camera.close()


class Coordinator:
    """The rig's single source of truth. Create, :meth:`open`, :meth:`start` once the edges serve;
    :meth:`end_sessions` and ``await close()`` to stop (the composition root does all of it).

    It takes no transport: the composition root (:mod:`coordinator.app`) builds the gRPC
    services, the console and the mDNS advertiser beside it, and they see it through the
    Protocols of :mod:`coordinator.ports`.

    Parameters
    ----------
    rig : Rig
    token : bytes
        The rig's secret.
    encoding : callable
        Makes the fan-out's packet encoding (the wire's; see :class:`coordinator.fanout.FanOut`).
    latency_ms : float, optional
        How far ahead frames are sent (default: rig.toml's).
    cameras : list of str, optional
        Camera specs for jobs (default: rig.toml's).
    clock_ns : callable
        The rig clock, monotonic nanoseconds (injectable for tests).
    console_state : callable
        What ``status`` says of the operator console: its address, "NOT SERVED (why)" or "off"
        (the composition root knows; the core serves no console).
    """

    def __init__(self, rig: Rig, token: bytes, *, encoding: Callable[[], PacketEncoding], latency_ms: float | None = None,
                 cameras: list[str] | None = None, clock_ns: Callable[[], int] = time.monotonic_ns,
                 console_state: Callable[[], str] = lambda: "off"):
        self._rig = rig
        self._console_state = console_state
        self.clock_ns = clock_ns
        self.latency_ns = int((latency_ms if latency_ms is not None else rig.config.latency_ms) * 1e6)
        self.instance_id = uuid.uuid4().hex[:12]
        # The rig clock's identity. The default clock is this boot's CLOCK_MONOTONIC, which a
        # coordinator restarted on this host shares; an injected clock is its instance's own.
        self.clock_id = (f"monotonic:{boot_id()}" if clock_ns is time.monotonic_ns and boot_id()
                         else f"instance:{self.instance_id}")
        self.started = self.now()
        self.sessions: dict[str, NodeSession] = {}      # session id -> node session
        self.by_slot: dict[str, NodeSession] = {}
        self.joins: dict[str, int] = {}
        # rig-clock instants (ns) by session id: when it turned live; when each asset was first seen ready
        self.live_at: dict[str, int] = {}
        self.ready_at: dict[str, dict[str, int]] = {}
        self.refusals = Refusals()
        self.admission = Budget(reserve_bytes=MAX_REQUEST_BYTES)   # calls without a session
        self.jobs = JobTracker()
        self._job_task: asyncio.Task | None = None
        self._systemd = sd_notify.Watchdog()
        self.handshake = Handshake(token, rig_id=rig.config.rig_id, rig_name=rig.config.name,
                                   instance_id=self.instance_id, clock=self.now,
                                   on_refusal=lambda peer, slot, msg: self.refusals.record(peer, slot, msg, self.now()))
        # a show's ticks are reported with the node's next heartbeat: wait at least two intervals and a second
        self.sync = SyncTracker(clock=self.now, timeout_s=max(3.0, 1.0 + 2.0 * rig.config.heartbeat_ms / 1000.0))
        self.fanout = FanOut(self.sync, encoding)
        self.playback = Playback(rig, self.fanout, self.sync, live_sessions=self.live_sessions, clock_ns=self.clock_ns,
                                 latency_ns=self.latency_ns)
        self.distribution = Distribution(AssetStore(rig.path))
        self.previews = Previews()      # the console's thumbnails: asked of the nodes only while someone looks
        self.show_state = Show(rig.path, resolve=self.distribution.store.resolve, manifest=self._manifest,
                               ids=self.playback, progress=self._asset_progress, clock_ns=self.clock_ns,
                               lead_ns=max(self.latency_ns, MIN_LEAD_NS))
        self.playback.takeover = self.show_state.takeover
        self.playback.show_active = lambda: self.show_state.active
        # what the coordinator sent the nodes: frame packets (Frames) and show messages (Show)
        self.frame_packets_sent = self.frame_bytes_sent = 0
        self.show_updates_sent = self.show_bytes_sent = 0
        self._camera_specs: list[str] = list(cameras if cameras is not None else rig.config.cameras)
        self._job_lock = asyncio.Lock()
        self._tasks: list[asyncio.Task] = []
        self._rig_lock = RigLock(rig.path)   # one coordinator (or `rig import`) per rig directory
        self._swapped_ns: dict[str, int] = {}     # slot -> rig instant of the last swap its node reported
        self._late_window = LateWindow()          # frames each node missed lately, for status
        # the per-pixel blend: its failover switches take effect a switch lead ahead, on every node at once
        lead = rig.config.blend.switch_lead_ms
        self.blending = BlendState(rig, update_slot=self.update_slot, clock_ns=self.clock_ns,
                                   lead_ns=None if lead is None else int(lead * 1e6), node_session=self.by_slot.get,
                                   show_active=lambda: self.show_state.active)
        self.lamp_watchdog = LampWatchdog(self.blending, camera_specs=lambda: self._camera_specs, busy=self.running_job,
                                          on_screen=self.still_on_screen, live_slots=self.live_slots,
                                          interval_s=rig.config.blend.watchdog_interval_s, clock_ns=self.clock_ns,
                                          last_swap_ns=self._last_swap_ns)

    # ------------------------------------------------------------------ lifecycle
    def open(self) -> None:
        """Take the rig directory's lock (RigLockError if another coordinator serves it), settle
        what a crash left (:mod:`coordinator.recovery`) and read the asset store: before anything
        serves. :meth:`close` undoes it."""
        self._rig_lock.acquire()
        try:
            recover(self._rig.path)
            self.distribution.load()
            self.blending.load()
        except BaseException:
            self._rig_lock.release()
            raise

    def start(self) -> None:
        """Watch the nodes and the show (call once the edges serve: :meth:`open` first)."""
        self._tasks.append(asyncio.create_task(self._watchdog(), name="watchdog"))
        self._tasks.append(asyncio.create_task(self._follow_show(), name="show"))
        self.blending.start(self.jobs)
        cues.start_cues(self)       # the current cue on screen again after a restart
        if self.rig.config.blend.watchdog:
            self._tasks.append(asyncio.create_task(self.lamp_watchdog.run(), name="lamp-watchdog"))
        # under systemd (Type=notify): keep-alives from the loop that serves everything
        self._systemd.expect("loop")

    def end_sessions(self) -> None:
        """Stop watching and close every node session (their streams end): the first half of a stop."""
        for t in self._tasks:
            t.cancel()
        self.blending.close()
        for sess in list(self.sessions.values()):
            sess.close()

    async def close(self) -> None:
        """The second half of a stop (after the edges stopped): playback ends, the watchers are
        gone and the rig's lock is free. Also undoes an :meth:`open` whose start was refused."""
        self.end_sessions()
        await self.playback.close()
        await asyncio.gather(*self._tasks, return_exceptions=True)
        self._tasks.clear()
        self._rig_lock.release()

    # ------------------------------------------------------------------ clocks
    def now(self) -> float:
        """Rig time in seconds (for ages and timeouts)."""
        return self.clock_ns() / 1e9

    def rig_now(self) -> int:
        """Rig time in nanoseconds (presentation times, pings)."""
        return self.clock_ns()

    # ------------------------------------------------------------------ nodes
    def join(self, *, slot: str, info: NodeInfo, peer: str) -> NodeSession:
        """A node that passed the handshake takes its slot.

        A slot held by a live node (heard from within ``lost_after_ms``) is not given to a node
        on another machine, nor to the process on the same machine that the holder took it
        over from: two nodes started for one slot would otherwise take it from each other
        forever. The newcomer is refused with the holder named; the holder keeps the slot. A
        node rejoining (the same process, or a new process on the holder's machine: a restart)
        takes over, and so does anyone once the holder went silent."""
        if slot not in self.rig.slots:
            raise self.handshake.refuse(peer, slot, RefusalKind.NOT_FOUND,
                                        f"slot {slot!r} is not in rig {self.rig.config.name!r} "
                                        f"(slots: {', '.join(self.rig.slots)}); add it to rig.toml or start the node "
                                        "with one of these")
        old = self.by_slot.get(slot)
        replaced_pid = 0
        if old is not None and not old.closed:
            if self._holds_slot(old, info):
                h = old.info
                raise self.handshake.refuse(
                    peer, slot, RefusalKind.CONFLICT,
                    f"slot {slot!r} is taken by the live node at {old.peer} ({h.hostname or 'unknown host'}, pid {h.pid}); "
                    "stop one of the two, or start this one with another --slot")
            if _same_machine(old.info, info) and old.info.pid != info.pid:
                replaced_pid = old.info.pid
            log.info("node %s rejoined from %s; closing its previous session", slot, peer)
            self._drop_session(old, lost=False)
        if old is not None:
            self.live_at.pop(old.session, None)
            self.ready_at.pop(old.session, None)
        st = self.rig.slot(slot)
        native = info.native_size
        if all(native) and native != (st.width, st.height):
            # the display knows its resolution better than rig.toml; a pose made for another size is stale
            log.warning("node %s drives a %dx%d output, rig.toml says %dx%d: adopting the node's size%s", slot,
                        *native, st.width, st.height, " (recalibrate this slot)" if st.pose is not None else "")
            self.rig.update_slot(slot, size=native, source="node")
        self.joins[slot] = self.joins.get(slot, 0) + 1
        now = self.now()
        sess = NodeSession(session=secrets.token_hex(16), slot=slot, peer=peer, info=info,
                           instance_joins=self.joins[slot], joined=now, last_seen=now, replaced_pid=replaced_pid,
                           on_backlog_dropped=self.playback.request_keyframe)
        self.sessions[sess.session] = sess
        self.by_slot[slot] = sess
        log.info("node %s joined from %s (%s, pid %d)", slot, peer, info.hostname, info.pid)
        return sess

    def _holds_slot(self, holder: NodeSession, newcomer: NodeInfo) -> bool:
        """Whether the live ``holder`` keeps its slot against ``newcomer`` (see :meth:`join`)."""
        if self.now() - holder.last_seen > self.rig.config.lost_after_ms / 1000.0:
            return False
        if not _same_machine(holder.info, newcomer):
            return True
        return newcomer.pid != holder.info.pid and newcomer.pid == holder.replaced_pid

    def node_session(self, session_id: str) -> NodeSession:
        sess = self.sessions.get(session_id)
        if sess is None or sess.closed:
            raise Refusal(RefusalKind.UNAUTHENTICATED,
                          f"unknown or closed session (coordinator instance {self.instance_id}): join again")
        return sess

    def live_sessions(self) -> list[NodeSession]:
        return [s for s in self.by_slot.values() if not s.closed and s.frames_open]

    def _drop_session(self, sess: NodeSession, *, lost: bool, left: str = "") -> None:
        sess.close()
        self.sessions.pop(sess.session, None)
        if lost:
            sess.state = NodeState.LOST
            if left:      # it said goodbye: its projector is gone all the same
                sess.left = left
                log.info("node %s left (%s)", sess.slot, left)
            else:
                log.warning("node %s lost (last seen %.1f s ago)", sess.slot, self.now() - sess.last_seen)
            self.blending.node_lost(sess.slot)      # the others' maps take over its footprint
        self.sync.forget_slot(sess.slot)

    def mark_lost(self, sess: NodeSession) -> None:
        if not sess.closed:
            self._drop_session(sess, lost=True)

    def mark_left(self, sess: NodeSession, why: str) -> None:
        """The node stops on purpose (its last report said why): "left", not "lost", same failover."""
        if not sess.closed:
            self._drop_session(sess, lost=True, left=why or "stopping")

    def sweep(self) -> None:
        """Mark nodes silent for longer than rig.toml's ``lost_after_ms`` lost; finalise stale frames."""
        lost_after = self.rig.config.lost_after_ms / 1000.0
        now = self.now()
        for sess in list(self.by_slot.values()):
            if not sess.closed and now - sess.last_seen > lost_after:
                self.mark_lost(sess)
        if now - self.started > lost_after:     # a projector of the blend whose node never came: as lost
            for slot in self.blending.slots:
                if slot not in self.by_slot:
                    self.blending.node_lost(slot)
        self.sync.sweep()

    async def _watchdog(self) -> None:
        next_poll = 0.0
        while True:
            await asyncio.sleep(0.25)
            self._systemd.beat("loop")     # a frozen event loop stops systemd's keep-alives
            self._systemd.tick()
            self.sweep()
            if self.admission.should_trim():    # a burst before authentication ended
                freed = await asyncio.to_thread(trim_memory)
                if freed:
                    log.info("returned %.0f MiB to the system after a burst of calls before authentication",
                             freed / 2**20)
            if time.monotonic() >= next_poll:   # host time: an injected rig clock may stand still
                next_poll = time.monotonic() + STORE_POLL_S
                await self.refresh_assets()

    async def refresh_assets(self) -> bool:
        """Look for assets added or removed in the rig's store; push a changed wanted list to every
        node. Whether it changed (a store that cannot be read is logged, and tried again)."""
        try:
            changed = await self.distribution.refresh()
        except OSError as exc:
            log.warning("cannot read the asset store in %s: %s", self.rig.path, exc)
            return False
        if changed:
            for sess in self.by_slot.values():
                sess.wanted_event.set()
        return changed

    # ------------------------------------------------------------------ the timeline show
    def _manifest(self, asset_id: str):
        m = self.distribution.manifests.get(asset_id)
        return m if m is not None else self.distribution.store.get(asset_id)

    def _asset_progress(self, asset_id: str) -> dict[str, AssetProgress | None]:
        """Each live node's progress with ``asset_id`` (None: it reported nothing about it)."""
        out: dict[str, AssetProgress | None] = {}
        for sess in self.live_sessions():
            reported = sess.heartbeat.assets if sess.heartbeat is not None else ()
            out[sess.slot] = next((p for p in reported if p.asset_id == asset_id), None)
        return out

    async def _follow_show(self, period_s: float = 0.2) -> None:
        """Tell the sync tracker which tick ids the nodes holding the asset will swap in, ahead of time."""
        while True:
            await asyncio.sleep(period_s)
            ticks = self.show_state.upcoming_ticks()
            if not ticks:
                continue
            slots = self.show_state.ready_slots(s.slot for s in self.live_sessions())
            tag = f"timeline:{self.show_state.timeline.asset_id[:8]}" if self.show_state.timeline else "timeline"
            for frame_id, pts in ticks:
                self.sync.expect(frame_id, pts, tag, slots)

    def _before_show(self) -> None:
        self._refuse_while_job("wait for it or cancel it before playing an asset")
        self.playback.stop()    # a played sequence ends; its frames already sent are shown or dropped

    def stop_all(self, *, blackout: bool = False) -> str:
        """Stop a played sequence or a timeline show: the rig's content is shown again (black when
        there is none, or with ``blackout``). Returns what the rig shows now."""
        self._refuse_while_job("cancel it (Ctrl-C on its command) before stopping or blacking out")
        self.playback.stop()
        if blackout or self.rig.content is None:
            self.playback.blackout()     # its still takes over from a timeline show
        else:
            self.playback.show(self.rig.content, tag="show:restored")
        log.info("stopped by an operator: showing %s", self.playback.showing)
        return self.playback.showing

    async def identify(self) -> str:
        """Every projector shows its slot name, large, until the next show, stop or blackout."""
        self._refuse_while_job("cancel it first")

        def cards() -> dict[str, Content]:
            cards = identify_cards({name: (st.width, st.height) for name, st in self.rig.slots.items()})
            out = {name: Content(card, name=f"identify {name}") for name, card in cards.items()}
            self.fanout.prepare(list(out.values()))
            return out

        contents = await asyncio.to_thread(cards)
        self.playback.show_per_slot(contents, tag="show:identify", showing="slot names (identify)")
        log.info("identify: every projector shows its slot name")
        return self.playback.showing

    # test patterns on chosen slots, and solo (coordinator/slot_tools.py)
    show_test_pattern = slot_tools.show_test_pattern
    solo = slot_tools.solo

    def play_asset(self, key: str, *, at_ns: int | None = None, delay_ns: int | None = None, loop: bool = False,
                   fps: float | None = None, start_without: bool = False, fade_ns: int = 0) -> ShowState:
        self._before_show()
        return self.show_state.play(key, at_ns=at_ns, delay_ns=delay_ns, loop=loop, fps=fps,
                                    start_without=start_without, fade_ns=fade_ns)

    def show_control(self, action: str, *, at_ns: int | None = None, delay_ns: int | None = None,
                     frame: int = 0) -> ShowState:
        """``pause``, ``resume``, ``seek`` (to ``frame``) or ``stop`` the timeline show."""
        s = self.show_state
        if action == "seek":
            return s.seek(frame, at_ns=at_ns, delay_ns=delay_ns)
        if action in ("pause", "resume", "stop"):
            return getattr(s, action)(at_ns=at_ns, delay_ns=delay_ns)
        raise ValueError(f"unknown show action {action!r}")

    # the cue list: GO, back, jump, auto-follow (coordinator/cues.py)
    cue_state, set_cues, cue_engine = cues.cue_state, cues.set_cues, cues.cue_engine
    cue_go, cue_back, cue_jump = cues.cue_go, cues.cue_back, cues.cue_jump

    def on_frames_open(self, sess: NodeSession) -> None:
        sess.frames_open = True
        self.playback.on_frames_open(sess)

    def on_report(self, sess: NodeSession, rep: Report) -> None:
        """A node's batch of heartbeat, swaps and drops."""
        now_ns = self.clock_ns()
        sess.last_seen = now_ns / 1e9
        if sess.state == NodeState.JOINED:
            sess.state = NodeState.LIVE
            self.live_at[sess.session] = now_ns
            if self.playback.current_frame is None and not self.playback.playing and not self.show_state.active:
                # nothing on screen for its maps to wait for: a returning projector rejoins the blend now
                self.blending.node_live(sess.slot)
        if rep.heartbeat is not None:
            sess.heartbeat = rep.heartbeat
            note_ready(self.ready_at.setdefault(sess.session, {}), rep.heartbeat.assets, now_ns)
        n = len(rep.swaps)
        if n:       # as arrays: a show's ticks come a second's worth at a time
            ids = rep.swaps.frame_id
            before = np.concatenate(([sess.last_swap_frame], ids[:-1]))
            for k in np.flatnonzero(ids < before).tolist():
                self.sync.out_of_order += 1
                log.error("node %s reported frame %d after frame %d", sess.slot, ids[k], before[k])
            self.sync.on_swaps(sess.slot, ids, rep.swaps.swap_rig_ns, rep.swaps.host_monotonic_ns, sess.same_host)
            sess.last_swap_frame = int(ids[-1])
            sess.last_swap_at = now_ns / 1e9
            sess.shown += n
            self._swapped_ns[sess.slot] = int(rep.swaps.swap_rig_ns[-1])
            # a lost projector shows frames again: the full blend, from an instant it has a frame on screen
            self.blending.node_live(sess.slot)
        if rep.preview is not None:
            self.previews.accept(sess.slot, rep.preview)
        for frame_id, reason in rep.drops:
            if reason == DropReason.LATE:
                sess.late += 1
            else:
                sess.dropped += 1
            self.sync.on_drop(sess.slot, frame_id, reason)
            self.playback.retry_still(sess, frame_id)

    # ------------------------------------------------------------------ what the edges ask (coordinator/ports.py)
    @property
    def content_size(self) -> tuple[int, int]:
        return self.playback.content_size

    @property
    def asset_store(self) -> AssetStore:
        return self.distribution.store

    @property
    def wanted(self) -> WantedList:
        return self.distribution.wanted

    def asset_manifests(self) -> Mapping[str, Manifest]:
        return self.distribution.manifests

    async def manifest_bytes(self, asset_id: str) -> bytes:
        return await self.distribution.manifest_bytes(asset_id)

    def blob_chunks(self, sha256: str, offset: int) -> AsyncIterator[tuple[int, bytes]]:
        return self.distribution.blob_chunks(sha256, offset)

    def subscribe_show(self, event: asyncio.Event) -> Callable[[], None]:
        return self.show_state.subscribe(event)

    def show_update(self, *, beacon: bool = False) -> ShowUpdate | None:
        return self.show_state.update(beacon=beacon)

    def prepare_still(self, content: Content, space: Space = Space.CONTENT, *, fit: str = "") -> Content:
        return self.playback.prepare_still(content, space, fit=fit)

    def prepare_regions(self, content: Content, regions: Mapping[str, Sequence[Sequence[int]]]
                        ) -> dict[str, Content | None]:
        return self.playback.prepare_regions(content, regions)

    def token_matches(self, given: str) -> bool:
        """Whether pasted text is the rig token (surrounding whitespace ignored; constant time in its content)."""
        return hmac.compare_digest(given.strip().encode("utf-8", "surrogateescape"), self.handshake.token.strip())

    def token_key(self, purpose: bytes) -> bytes:
        return hmac.new(self.handshake.token.strip(), purpose, hashlib.sha256).digest()

    def slot_link(self, slot: str) -> SlotLink:
        sess = self.by_slot.get(slot)
        return "none" if sess is None else "closed" if sess.closed else "open"

    def listen_frames(self, listener: Callable[[FrameResult], None]) -> Callable[[], None]:
        return self.sync.add_listener(listener)

    def listen_jobs(self, listener: Callable[[], None]) -> Callable[[], None]:
        return self.jobs.subscribe(listener)

    def current_job(self) -> JobState | None:
        return self.jobs.current

    def job_snapshot(self) -> dict[str, Any] | None:
        return self.jobs.snapshot()

    # ------------------------------------------------------------------ RigDriver
    @property
    def rig(self) -> Rig:
        return self._rig

    @property
    def camera_specs(self) -> list[str]:
        return list(self._camera_specs)

    def live_slots(self) -> list[str]:
        live = {s.slot for s in self.live_sessions()}
        return [s for s in self.rig.slots if s in live]

    async def show_patterns(self, images: Mapping[str, np.ndarray | None], *, content: np.ndarray | None = None,
                            apply_lut: bool = False, settle_s: float = 0.05) -> None:
        await self.playback.show_patterns(images, content=content, apply_lut=apply_lut, settle_s=settle_s)

    def show_still(self, image: np.ndarray, *, name: str, persist: bool) -> None:
        self.playback.show(Content(image, name=name), persist=persist)

    async def play(self, frames: Sequence[np.ndarray], *, fps: float, loops: int = 0) -> PlayResult:
        return await self.playback.play([Content(f) for f in frames], PlaySettings(fps=fps, loops=loops, wait=True))

    def update_slot(self, slot: str, **changes: Any):
        """Change a slot's assignment (persisted first), then push it to the slot's node."""
        st = self.rig.update_slot(slot, **changes)
        sess = self.by_slot.get(slot)
        if sess is not None:
            sess.assignment_event.set()
        return st

    def update_slots(self, slots: Sequence[str], **changes: Any) -> list:
        """The same change on several slots, their files written in one batch (:meth:`Rig.update_slots`:
        all checked first, a refusal changes none), then pushed to their nodes."""
        states = self.rig.update_slots(list(slots), **changes)
        for st in states:
            sess = self.by_slot.get(st.name)
            if sess is not None:
                sess.assignment_event.set()
        return states

    def open_camera(self, spec: str) -> Camera:
        cam = open_camera(spec)
        return _AfterLastPattern(cam, self) if isinstance(cam, RoomCamera) else cam

    # ------------------------------------------------------------------ operators
    def show(self, content: Content, **kwargs: Any) -> ShowResult:
        return self.playback.show(content, **kwargs)

    async def play_sequence(self, frames: Sequence[Content] | None, settings: PlaySettings) -> PlayResult:
        return await self.playback.play(frames, settings)

    def running_job(self) -> str | None:
        """The kind of the job that holds the rig (its patterns hold the projectors), or None."""
        if not self._job_lock.locked():
            return None
        return self.jobs.current.kind if self.jobs.current is not None else "job"

    def _refuse_while_job(self, then: str) -> None:
        """CoordinatorError while a job holds the rig, saying which, and ``then`` what to do."""
        kind = self.running_job()
        if kind is not None:
            raise CoordinatorError(f"a {kind} job is running on this rig (its patterns hold the projectors); {then}")

    def start_job(self, kind: str, params: dict) -> "asyncio.Task[dict]":
        """Start a job that runs on after the call (the console's way: its progress is followed by
        :attr:`jobs`); refused at once while another holds the rig."""
        self._refuse_while_job("wait for it or cancel it")
        return asyncio.create_task(self.run_job(kind, params, lambda ev: None), name=f"console:{kind}")

    async def run_job(self, kind: str, params: dict, emit: Callable[[Event], None]) -> dict:
        """Run one job at a time; the rig's content is shown again afterwards. :attr:`jobs`
        follows it (stage, progress, time left, log) for the console and status."""
        self._refuse_while_job("wait for it or cancel it")
        async with self._job_lock:
            self._job_task = asyncio.current_task()
            self.jobs.begin(kind, params)

            def both(ev: Event) -> None:
                self.jobs.event(ev)
                emit(ev)

            try:
                result = await run_job(self, kind, params, emit=both)
            except asyncio.CancelledError:
                self.jobs.end(cancelled=True)
                raise
            except Exception as exc:
                self.jobs.end(error=str(exc))
                raise
            else:
                self.jobs.end(result=result)
                return result
            finally:
                self._job_task = None
                self.playback.restore_content()

    def blend_status(self) -> BlendStatus:
        """The rig's blend and any failover (:mod:`coordinator.blending.state`)."""
        return self.blending.status()

    def _last_swap_ns(self, slot: str) -> int:
        """The rig instant the slot's node last swapped a frame in, as it reported (0: no node, or none yet)."""
        sess = self.by_slot.get(slot)
        return self._swapped_ns.get(slot, 0) if sess is not None and not sess.closed else 0

    def still_on_screen(self) -> tuple[np.ndarray | Callable[[], np.ndarray], int] | None:
        """The still every projector shows through its pose, as (content image, the rig instant it
        is on screen from), or None (nothing, a played sequence, a pattern, black, per-slot regions,
        a timeline show of a video, or of a sequence whose frames change). A timeline show of a still
        asset gives a function that reads its image at the content size (blocking: the watchdog calls
        it in a worker thread); a span of a sequence's show whose frames are one file gives that frame
        and the instant it ends as a third item (:func:`coordinator.blending.watchdog.steady_span`)."""
        pb = self.playback
        if self.running_job() is not None or pb.playing:
            return None
        if self.show_state.active:
            tl = self.show_state.timeline
            m = self._manifest(tl.asset_id) if tl is not None else None
            if m is not None and m.kind == "sequence":       # a span of frames that are one picture
                span = steady_span(tl, [b.sha256 for b in m.blobs], self.clock_ns())
                if span is None:
                    return None
                path = self.distribution.store.blob_path(m.blobs[span[0]].sha256)
                return partial(_still_asset_image, path, self.content_size), span[1], span[2]
            if m is None or m.kind != "still":
                return None
            path = self.distribution.store.blob_path(m.blobs[0].sha256)
            return partial(_still_asset_image, path, self.content_size), tl.anchor_ns
        frame = pb.current_frame
        if frame is None or frame.space != Space.CONTENT or not frame.apply_lut or frame.slot_content:
            return None
        content = pb.current_contents.get(frame.content_id)
        return None if content is None else (content.image, frame.pts_ns)

    def cancel_job(self) -> str:
        """Cancel the running job, whoever started it (its own call ends as cancelled)."""
        task = self._job_task
        if task is None or task.done():
            raise CoordinatorError("no job is running")
        task.cancel()
        return self.jobs.current.kind if self.jobs.current else "job"

    def status(self) -> RigStatus:
        now_ns = self.clock_ns()
        now = now_ns / 1e9
        nodes = []
        for name, st in self.rig.slots.items():
            base = dict(slot=name, assignment_revision=st.revision, joins=self.joins.get(name, 0),
                        pose_kind=st.pose.kind if st.pose is not None else "none")
            sess = self.by_slot.get(name)
            ready = self.distribution.readiness(sess.heartbeat.assets if sess and sess.heartbeat else (),
                                                ready_since=self.ready_at.get(sess.session) if sess else None,
                                                now_ns=now_ns)
            base.update(assets_wanted=ready.wanted, assets_ready=ready.ready, asset_bytes_have=ready.bytes_have,
                        asset_bytes_total=ready.bytes_total, assets=ready.assets)
            if sess is None:
                nodes.append(NodeStatus(**base))
                continue
            hb = sess.heartbeat
            if hb is not None:
                base.update(clock_offset_ms=hb.clock_offset_ns / 1e6, clock_drift_ppm=hb.clock_drift_ppm, show=hb.show,
                            clock_rtt_ms=hb.clock_rtt_ns / 1e6, assignment_revision=hb.assignment_revision,
                            decoder=hb.decoder, decoder_note=hb.decoder_note,
                            assignment_refused=hb.assignment_refused)
                if sess.same_host and hb.host_monotonic_ns:
                    base["clock_error_ms"] = (hb.rig_estimate_ns - hb.host_monotonic_ns) / 1e6
            live_at = self.live_at.get(sess.session) if sess.state == NodeState.LIVE else None
            nodes.append(NodeStatus(
                **base, state=sess.state, hostname=sess.info.hostname, pid=sess.info.pid,
                software_version=sess.info.software_version, output=sess.info.output, gl=sess.info.gl,
                live_age_ms=(now_ns - live_at) / 1e6 if live_at is not None else math.nan,
                last_seen_age_ms=(now - sess.last_seen) * 1e3, last_swap_frame=sess.last_swap_frame,
                last_swap_age_ms=(now - sess.last_swap_at) * 1e3 if sess.last_swap_at else math.nan,
                frames_late=sess.late, frames_dropped=sess.dropped, frames_shown=sess.shown,
                left=sess.left if sess.state == NodeState.LOST else ""))
        late_s, late = self._late_window.observe(now, {n.slot: n.frames_late + n.frames_dropped for n in nodes
                                                       if n.state in (NodeState.LIVE, NodeState.JOINED)})
        return RigStatus(
            rig_id=self.rig.config.rig_id, rig_name=self.rig.config.name, instance_id=self.instance_id,
            rig_dir=str(self.rig.path), protocol_version=PROTOCOL_VERSION, uptime_s=now - self.started,
            showing=self.show_state.describe() if self.show_state.active else self.playback.showing,
            show=self.show_state.state(), frame_packets_sent=self.frame_packets_sent,
            frame_bytes_sent=self.frame_bytes_sent, show_updates_sent=self.show_updates_sent,
            show_bytes_sent=self.show_bytes_sent, latency_budget_ms=self.latency_ns / 1e6, cpu_s=cpu_seconds(),
            nodes=tuple(nodes), sync=summarize(list(self.sync.results), self.sync.out_of_order),
            refusals=self.refusals.summary(now), admission=self.admission.figures(), console=self._console_state(),
            blend=self.blend_status(), late_window_s=late_s, late_recent=tuple(sorted(late.items())),
            unposed_warning=unposed_warning([n.slot for n in nodes if n.pose_kind == "none"]))


@lru_cache(maxsize=2)
def _still_asset_image(path, size: tuple[int, int]) -> np.ndarray:
    """A still asset's image at the content size (H, W, C), as a node warps it (bilinear)."""
    import cv2

    from coordinator.image_decode import read_image_file

    image = np.asarray(read_image_file(path))
    if image.shape[1::-1] != tuple(size):
        image = cv2.resize(image, tuple(size), interpolation=cv2.INTER_LINEAR).reshape(size[1], size[0], -1)
    return image


def _same_machine(a: NodeInfo, b: NodeInfo) -> bool:
    """Whether two joins come from one machine (its boot id and host name; both unknown: the same)."""
    return (a.host_boot_id, a.hostname) == (b.host_boot_id, b.hostname)
