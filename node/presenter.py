"""The presenter: the one thread that owns the node's GL context and shows frames.

It takes assignments, content, frames and clock estimates in arrival order
(:meth:`Presenter.handle`), renders each frame into the back buffer as soon as it
arrives, waits until the frame's presentation time on its estimate of the rig
clock, swaps, and reports the swap. Which frames are dropped instead (late,
superseded, missing content) is decided by :class:`node.pacing.FramePacer`; a
frame is never shown late and never out of order.

A slot's blend maps (:mod:`protos.blend`) arrive with its assignment, each with the rig instant
from which it is shown. The presenter uploads them ahead and switches the renderer to them for the
first frame whose pts is at or after that instant (a streamed frame or a show's tick), so every
node of the rig switches at one common swap instant; when no frame is due then (a still, a paused
show), it shows the frame on screen again with them at that instant, held rendered until then while
the pipe is read: a message that may change what is shown (a stop, a frame, a show) is handled at once,
and the switch made again after it. Maps that cannot be used are refused in one log line (the blend
on screen stays). A blend switch that reaches the presenter while a rendered frame waits for its time
is taken then (:attr:`Presenter.inbox`), and that frame rendered again with the new maps when it is at
or after their instant: a failover's maps do not wait for the frame after it. What the switch holds
is :mod:`node.blend_switch`'s.

Between frames it also makes the previews the coordinator asks for (:mod:`node.preview`):
right after a swap, or while idle, when the renderer's framebuffer holds what the projector
shows and the preview fits before the next frame is due; never between a render and its swap.

It runs in a process of its own (:mod:`node.presenter_process`), or in a test's
thread with a clock the test moves.
"""
from __future__ import annotations

import logging
import os
import statistics
import time
from collections import deque
from dataclasses import replace
from typing import Callable, Protocol

import numpy as np

from node.asset_frames import FrameError, FrameNotReady
from node.blend_switch import BlendSwitch, same_but_blend as _same_but_blend
from node.clock import ClockEstimate
from node.decoders import choose, wish_from_env
from node.fade import Crossfade, ShowFade
from node.live_video import LiveDecoder
from node.outputs.base import Output, SwapInfo
from node.pacing import LATE_TOLERANCE_NS, FramePacer
from node.preview import PreviewMaker
from node.realtime import RealtimeWindow
from node.records import (AssetFiles, DropReason, DropRecord, FrameOrder, NodeAssignment, PresenterStatus, ShowStatus,
                          ShowUpdateData)
from node.render.renderer import Mesh, Renderer
from node.render.shaders import gl_description
from node.render.warm_start import warm_start
from node.timeline_player import TimelineEvent, TimelinePlayer, fit_frame
from node.wire import live_packet_from_bytes

log = logging.getLogger(__name__)

#: log each swap's distance from its deadline (diagnostics)
_DEBUG_TIMING = bool(os.environ.get("SHADOWLESS_DEBUG_TIMING"))


class PresenterClock(Protocol):
    """What the presenter needs of a clock (:class:`node.clock.LocalClock` is one)."""

    def now(self) -> int: ...

    def host_now(self) -> int: ...

    def from_host(self, host_ns: int) -> int: ...

    def to_host(self, local_ns: int) -> int: ...

    def sleep_until(self, local_ns: int) -> int: ...


class Presenter:
    """The presenter loop (runs in the presenter process, or in a test's thread).

    Parameters
    ----------
    slot : str
        The node's slot (which content of a frame is this node's).
    output : Output
        Where frames go; provides the GL context (:meth:`open` makes it).
    clock : PresenterClock
        The node's local clock: frames are timed, and waited for, on it.
    report : callable
        ``report(kind, payload)`` receives ``("swap", SwapRecord)``, ``("drop", DropRecord)``,
        ``("stats", PresenterStatus)`` and ``("preview", PreviewRecord)``.
    realtime : bool
        Swap at real-time priority if the system allows it.

    :meth:`handle` takes ``(kind, payload)``: ``("clock", ClockEstimate | None)``,
    ``("assignment", NodeAssignment)``, ``("packet", bytes)`` (a serialized FramePacket),
    ``("content", (content_id, image))``, ``("frame", FrameOrder)``, ``("evict", [content_id])``,
    ``("show", ShowUpdateData)``, ``("asset", AssetFiles)``, ``("preview", request_id)`` and ``("reset", None)``.

    The show's timeline (:mod:`node.timeline_player`) is followed between messages: the loop
    asks :meth:`timeline_wait` how long it may wait for a message, and calls
    :meth:`timeline_step` when that time has come. **Precedence**: a coordinator frame (a still,
    a pattern, a sequence) suspends the timeline until a newer revision of it arrives; the
    newest swap always wins, in frame id order (timeline ids and coordinator ids share one
    increasing sequence, see :mod:`coordinator.show`).
    """

    #: start preparing a timeline frame this long before its presentation time (at the latest)
    PREPARE_NS = 50_000_000
    #: a preview is made only with this much room left before the next frame, beyond twice its cost
    #: and the longest recent frame's work (decode, render, finish)
    PREVIEW_MARGIN_NS = 2_000_000
    #: streamed frames further apart than this are stills: none is expected after one
    STREAM_GAP_NS = 1_000_000_000
    #: a frame shown this long with no next one known is taken for a still (not a sequence's first)
    STILL_AFTER_NS = 250_000_000
    #: while a rendered frame waits for its time, blend switches are taken until this long (plus the
    #: longest recent frame's work until ready to swap) before it: what rendering it again needs
    REDRAW_MARGIN_NS = 3_000_000
    #: a still is rendered again with new blend maps this long before their instant at the earliest, and
    #: held in the back buffer until it, reading the pipe (:meth:`_hold`)
    BLEND_EARLY_NS = 150_000_000
    #: messages read while a still is held for its maps' instant that do not end the hold (handled after
    #: the swap): they change neither what is shown nor when
    HOLD_GOES_ON = frozenset({"clock", "content", "evict", "preview"})

    def __init__(self, *, slot: str, output: Output, clock: PresenterClock,
                 report: Callable[[str, object], None], realtime: bool = True):
        self.slot = slot
        self.clock = clock
        self.report = report
        self.out = output
        self.pacer = FramePacer(clock)
        self.shown = 0
        self.late = 0
        self.dropped = 0
        self.assignment: NodeAssignment | None = None
        self.native_size: tuple[int, int] | None = None
        self.gl_info = ""
        self._realtime_wanted = realtime
        self._render_ms: deque[float] = deque(maxlen=120)
        self._current: FrameOrder | None = None
        self._evicted: set[str] = set()
        self.player = TimelinePlayer()
        self.timeline_shown = 0          # timeline frames swapped in
        self.timeline_missed = 0         # timeline ticks not shown (late, undecodable, unrenderable)
        self.timeline_last_frame = -1    # the asset frame index last swapped in
        self._timeline_reports = False   # reports made now are of timeline ticks
        self._holding = False            # a paused show's frame is being shown (a late one is retried)
        self._held_late = False
        self._timeline_cid: str | None = None
        self._last_event_pts: int | None = None
        self.live = LiveDecoder(yuv=True)   # live video pictures (coordinator/live_video.py), as YUV planes
        self.previews = PreviewMaker(clock.now)
        self._fbo_shown = False          # the renderer's framebuffer holds what the projector shows
        self._stream_next_ns: int | None = None   # when the next streamed frame is expected (local ns)
        self._work_from_ns = 0           # when the current message's (or tick's) work began
        self._work_ns: deque[int] = deque(maxlen=30)   # per frame shown: its work until ready to swap
        self._swapped_at_ns = 0          # local time of the last frame swapped in
        # blend maps: the next ones and their instant, those on screen (node/blend_switch.py)
        self.blend = BlendSwitch(clock.host_now, lambda host, est: est.rig_time(clock.from_host(host)))
        #: where messages come from while the presenter waits for a frame's time (its process's pipe:
        #: ``poll(timeout_s) -> bool``, ``recv() -> (kind, payload)``), so that blend maps that arrive
        #: meanwhile reach the frame already rendered; None: the wait only sleeps (a test's thread)
        self.inbox = None
        self._deferred: deque = deque()  # messages read while waiting, not handled then: handled next, in order
        self._fade: Crossfade | None = None   # a crossfade under way (node/fade.py)
        self._show_fade: ShowFade | None = None   # a timeline show's crossfade in

    @property
    def estimate(self) -> ClockEstimate | None:
        return self.pacer.estimate

    def render_ms_p50(self) -> float:
        # statistics, not numpy: np.median imports numpy.ma on first use (~0.1 s, mid-playback)
        return statistics.median(self._render_ms) if self._render_ms else 0.0

    def status(self) -> PresenterStatus:
        est = self.pacer.estimate
        now = est.rig_time(self.clock.now()) if est is not None else None
        show = ShowStatus(revision=max(0, self.player.schedule.revision), state=self.player.state(now),
                          last_frame=self.timeline_last_frame, shown=self.timeline_shown, late=self.timeline_missed)
        blend_id = self.blend.on_screen
        decoder = self.player.decoder_in_use()      # the heartbeat's own field (node/decoders.py)
        return PresenterStatus(shown=self.shown, late=self.late, dropped=self.dropped,
                               render_ms_p50=self.render_ms_p50(),
                               revision=self.assignment.revision if self.assignment else 0, show=show,
                               blend_id=blend_id, blend_since_rig_ns=self.blend.since_rig_ns if blend_id else 0,
                               decoder=decoder.label, decoder_note=decoder.note)

    def open(self) -> None:
        ctx = self.out.make_context()
        self._ctx = ctx
        self.native_size = self.out.native_size()
        w, h = self.native_size or (640, 360)
        self.renderer = Renderer(ctx, w, h)
        # the video decoder has a heartbeat field of its own (status(), node/decoders.py: --decoder)
        self.gl_info = gl_description(ctx)
        log.info("rendering with %s; video decoder %s", self.gl_info, choose('h264', wish_from_env()).describe())
        self._rt = RealtimeWindow(self._realtime_wanted)
        warm_start(self.renderer, ctx)     # every shader path drawn once: compiled now, not for a frame
        self.renderer.render(None)
        self.out.prepare(self.renderer)
        self.out.swap()
        self._fbo_shown = True
        self.previews.time_once(self.renderer)    # the PNG encoder's first run, and what a preview costs

    def close(self) -> None:
        self.player.close()
        self.renderer.release()
        self.out.close()

    def handle(self, kind: str, payload) -> None:
        t = time.perf_counter()
        self._work_from_ns = self.clock.now()
        getattr(self, "_on_" + kind)(self.renderer, self.out, payload)
        if _DEBUG_TIMING and (dt := time.perf_counter() - t) > 0.005 and kind != "frame":
            log.info("timing: %s took %.1f ms", kind, dt * 1e3)

    def next_deferred(self):
        """A message read from the inbox while waiting for a frame's time and not handled then (the loop
        handles it before reading the inbox again), or None."""
        return self._deferred.popleft() if self._deferred else None

    def idle(self) -> None:
        self.out.poll()   # a window keeps handling its events between frames
        self._maybe_preview()

    def _send_stats(self) -> None:
        self.report("stats", self.status())

    # ---------------------------------------------------------------- previews
    def _on_preview(self, renderer, out, request_id: int) -> None:
        self.previews.request(request_id)
        # a frame swapped a moment ago may be a sequence's first: with no next frame known yet, the
        # preview waits for the next swap, a later request or the idle loop
        self._maybe_preview(unknown_ok=self.clock.now() - self._swapped_at_ns > self.STILL_AFTER_NS)

    def _next_due_ns(self) -> int | None:
        """When the next frame is due (local ns), as far as the presenter can tell: the show's next
        tick, or the last streamed frame's deadline plus its interval; None: no frame is expected."""
        ev = self._next_event()
        if ev is not None:
            return self.pacer.estimate.local_time(ev.pts_ns)
        due = self._stream_next_ns
        return due if due is not None and due > self.clock.now() else None

    def _maybe_preview(self, *, unknown_ok: bool = True) -> None:
        """Make the preview asked for if it may be made now: the framebuffer holds what the projector
        shows, none was made within the interval, and it fits before the next frame is due (else it
        waits for the next swap or idle moment). ``unknown_ok``: also when no next frame is known
        (right after a swap, that may be a sequence's first frame: the idle loop makes it instead)."""
        pv = self.previews
        if not (self._fbo_shown and pv.due()):
            return
        due = self._next_due_ns()
        if due is None and not unknown_ok:
            return
        if due is not None:
            need = 2 * pv.cost_ns + max(self._work_ns, default=0) + self.PREVIEW_MARGIN_NS
            if due - self.clock.now() < need:
                pv.deferred += 1
                return
        t = self.clock.now()
        try:
            rec = pv.make(self.renderer, self._current.frame_id if self._current is not None else 0)
        except Exception:  # noqa: BLE001 - a thumbnail must never take the projector down
            log.exception("cannot make a preview")
            pv.pending = 0
            return
        self.report("preview", rec)
        if _DEBUG_TIMING:
            log.info("timing: preview of frame %d took %.2f ms, %s ms before the next frame", rec.frame_id,
                     (self.clock.now() - t) / 1e6, "?" if due is None else f"{(due - t) / 1e6:.1f}")

    # ---------------------------------------------------------------- handlers
    def _on_clock(self, renderer, out, estimate: ClockEstimate | None) -> None:
        self.pacer.estimate = estimate

    def _on_packet(self, renderer, out, data: bytes) -> None:
        """A FramePacket as received: cache its contents, decode its live video picture, show its
        frame, forget evicted contents. A picture that cannot be decoded correctly (no keyframe
        yet) is not uploaded: the frame naming it is dropped as missing content."""
        pkt, video = live_packet_from_bytes(data, self.slot, known=renderer.has)
        for content in pkt.contents:
            if content.image is None:
                log.error("content %s is malformed: %s", content.content_id, content.error)
            else:
                self._on_content(renderer, out, (content.content_id, content.image))
        if video is not None and not renderer.has(video.content_id):
            image = self.live.feed(video)
            if image is not None:
                self._on_content(renderer, out, (video.content_id, image))
        if pkt.frame is not None:
            self._on_frame(renderer, out, pkt.frame)
        if pkt.evict is not None:
            self._on_evict(renderer, out, list(pkt.evict))

    def _on_assignment(self, renderer, out: Output, a: NodeAssignment) -> None:
        got = self.clock.host_now()
        # a failover's push changes the blend alone, for a later instant: the frame on screen is shown
        # again with the new maps then (_blend_step), not now with the old ones as well; and the
        # renderer's pose, LUT and gain stay as they are (nothing to set again on the switch's way)
        blend_only = self.assignment is not None and _same_but_blend(self.assignment, a)
        size = self.native_size or (a.width, a.height)
        if not blend_only:
            self._set_assignment(renderer, a, size)
        at_once = self._offer_blend(renderer, a, got)
        self.assignment = a
        if not blend_only:
            # a video asset decodes straight to the content size the homography maps (see fit_frame)
            self.player.content_size = (tuple(a.content_size) if a.pose_kind == "homography" and all(a.content_size)
                                        else None)
            log.info("assignment r%d: %s pose, %dx%d, gain %.3f, LUT %s", a.revision, a.pose_kind, *size, a.gain,
                     "yes" if a.lut is not None else "identity")
        if not at_once and not (blend_only and self.blend.next is not None):
            # a switch for a later instant reports nothing until its maps show (_blend_step or the swap
            # that first shows them): one stats message a switch, not two, each waking the node process
            self._send_stats()
        # what is on screen now follows the new assignment at once
        swapped = None
        if self._current is not None and (at_once or not blend_only):
            try:
                self._render(renderer, self._current)
            except ValueError as exc:
                log.error("cannot re-render the current frame with the new assignment: %s", exc)
                renderer.render(None)
            out.prepare(renderer)
            self._ctx.finish()      # drawn before the swap (else an output's read back would draw it after)
            self.blend.ready()
            out.swap()
            swapped = self._shown_again(out, renderer)
        if at_once:     # on screen from that swap (with no frame to show again: from now)
            self._blend_shown(self._rig_now() if swapped is None else swapped)
            self._send_stats()

    def _set_assignment(self, renderer, a: NodeAssignment, size: tuple[int, int]) -> None:
        """The renderer's size, pose, LUT and gain as ``a`` says (one that cannot be rendered: black)."""
        if self.native_size and (a.width, a.height) != self.native_size:
            log.warning("assignment says %dx%d but the output is %dx%d; rendering at the output's size",
                        a.width, a.height, *self.native_size)
        if (renderer.width, renderer.height) != size:
            renderer.resize(*size)   # cleared to black: what is shown when no frame is (re-rendered below if one is)
        try:
            if a.pose_kind == "homography":
                renderer.set_homography(a.homography, a.content_size)
            elif a.pose_kind == "projection":
                renderer.set_projection(a.projection, Mesh(a.mesh.vertices, a.mesh.uvs, a.mesh.faces),
                                        near=a.near_mm, far=a.far_mm)
            else:
                renderer.clear_pose()
            renderer.set_lut(a.lut)
            renderer.set_gain(a.gain)
        except ValueError as exc:   # one bad assignment must not take the projector down: black until the next
            log.error("assignment r%d cannot be rendered (%s); this projector shows black until the next one",
                      a.revision, exc)
            renderer.clear_pose()

    # ---------------------------------------------------------------- blend maps
    def _rig_now(self) -> int:
        est = self.pacer.estimate
        return est.rig_time(self.clock.now()) if est is not None else 0

    def _offer_blend(self, renderer, a: NodeAssignment, got_host_ns: int) -> bool:
        """The blend ``a`` asks for (:meth:`node.blend_switch.BlendSwitch.offer`); whether it shows now."""
        return self.blend.offer(renderer, a, self._rig_now() if self.pacer.estimate is not None else None, got_host_ns)

    def _inbox_until(self, until_ns: int):
        """Messages read from the inbox until local ``until_ns``, one at a time (none without an inbox, nor
        once the node process is gone: the loop finds out on its own read)."""
        inbox = self.inbox
        while inbox is not None and (left := until_ns - self.clock.now()) > 0:
            try:
                if not inbox.poll(left / 1e9):
                    return
                msg = inbox.recv()
            except (EOFError, OSError):
                return
            yield msg

    def _wait_taking_blends(self, frame: FrameOrder, deadline: int) -> None:
        """Wait until shortly before ``deadline`` (local ns), the frame ``frame`` rendered for it, taking
        any blend switch that arrives meanwhile (an assignment that changes the blend alone): if the
        frame is at or after the new maps' instant, it is rendered again with them, so a failover's maps
        reach the frame already waiting for its time instead of the one after it. Anything else read is
        kept for the loop (in order: once a message is kept, every later one is too). The last stretch
        before the deadline, the time to render the frame again, is left to the swap's precise sleep."""
        if self._deferred:
            return
        for msg in self._inbox_until(deadline - self.REDRAW_MARGIN_NS - max(self._work_ns, default=0)):
            kind, payload = msg
            if kind != "assignment" or self.assignment is None or not _same_but_blend(self.assignment, payload):
                self._deferred.append(msg)
                return
            self._blend_while_waiting(payload, frame)

    def _hold(self, due: int) -> bool:
        """Hold the frame rendered with the next maps until shortly before ``due`` (local ns), reading the
        pipe: a message that may change what is shown or when (a stop, a frame, a show, an assignment, an
        asset, a reset) ends the hold at once (False), kept for the loop after those read before it; the
        others (HOLD_GOES_ON) are kept and the hold goes on. The last stretch is the swap's sleep."""
        for msg in self._inbox_until(due - self.REDRAW_MARGIN_NS - max(self._work_ns, default=0)):
            self._deferred.append(msg)
            if msg[0] not in self.HOLD_GOES_ON:
                return False
        return True

    def _blend_while_waiting(self, a: NodeAssignment, frame: FrameOrder) -> None:
        """A blend switch read while ``frame`` waits for its time: taken as :meth:`_on_assignment` takes
        it, and the frame rendered again when the new maps are due at its pts."""
        renderer = self.renderer
        at_once = self._offer_blend(renderer, a, self.clock.host_now())
        self.assignment = a
        log.info("assignment r%d: the blend alone, taken while frame %d waits for its time", a.revision, frame.frame_id)
        # no stats now: the frame's swap (or drop) sends them in a moment, with the revision and any new maps
        if at_once or self.blend.due_for(frame.pts_ns):
            try:
                self._render(renderer, frame)       # switches to the next maps (at once: already)
            except ValueError as exc:
                log.error("cannot render frame %d again with the new blend: %s", frame.frame_id, exc)
                return
            self.out.prepare(renderer)
            self._ctx.finish()
            self.blend.ready()

    def _blend_shown(self, pts_ns: int) -> None:
        self.blend.shown(self.renderer.blend_id, pts_ns, self.pacer.estimate)

    def _blend_due(self) -> tuple[int, int] | None:
        """When to show the frame on screen again with the next maps, when no frame will: (local ns,
        rig ns); None when no switch is due, the clock is unknown, or a show's tick at or after the
        instant will switch them. While streamed frames come, the first one at or after the instant
        switches them: this waits until one is overdue (the stream stopped)."""
        nxt, est = self.blend.next, self.pacer.estimate
        if nxt is None or est is None or self._next_event() is not None:
            return None
        due, pts = est.local_time(nxt[1]), nxt[1]
        if self._stream_next_ns is not None and self._stream_next_ns + self.STILL_AFTER_NS > due:
            due = self._stream_next_ns + self.STILL_AFTER_NS
            pts = est.rig_time(due)
        return due, pts

    def _blend_due_local(self) -> int | None:
        """When the loop must step for the blend: its instant less the time to render the frame again."""
        when = self._blend_due()
        return None if when is None else when[0] - self._blend_lead_ns() + self.PREPARE_NS

    def _blend_lead_ns(self) -> int:
        """How long before a blend's instant the frame on screen is rendered again: on a still, as soon as
        the maps are known (at most BLEND_EARLY_NS ahead), so that nodes sharing cores render in turn
        during the whole lead, not all in its last moment; else PREPARE_NS, or twice the longest recent
        frame's work when that is longer (a 1080p frame on a slow GPU)."""
        lead = max(self.PREPARE_NS, 2 * max(self._work_ns, default=0))
        stream = self._stream_next_ns
        if stream is None or stream + self.STILL_AFTER_NS <= self.clock.now():   # no stream due: a still
            lead = max(lead, self.BLEND_EARLY_NS)
        return lead

    def _blend_step(self) -> None:
        """Show the frame on screen again with the next maps, swapped in at their instant (or at once,
        when a stream that stopped made it wait past it)."""
        when = self._blend_due()
        if when is None or when[0] - self.clock.now() > self._blend_lead_ns():
            return      # not yet (the loop asks timeline_wait again)
        (due, pts), est = when, self.pacer.estimate
        renderer, out = self.renderer, self.out
        self.blend.switch(renderer)
        frame = self._current
        if frame is not None:
            try:
                self._render(renderer, frame)
            except ValueError as exc:
                log.error("cannot show the current frame with the new blend: %s", exc)
                renderer.render(None)
            out.prepare(renderer)
            self._ctx.finish()
            self.blend.ready()
        late = self.clock.now() - due > LATE_TOLERANCE_NS    # rendered too slowly for its instant (as a frame)
        if not self._hold(due):
            # a message that may change what is shown is handled first (a stop, at once): a still whose pts
            # is at or after the instant then shows the maps itself; else this step comes again after it
            self.blend.undo(renderer)
            return
        with self._rt:
            self.clock.sleep_until(due)
            if frame is not None:
                out.swap()
            host = self.clock.host_now()
        swap_rig = est.rig_time(self.clock.from_host(host))
        if frame is not None:
            self._shown_again(out, renderer, swap_rig, host)
        if late:          # shown all the same (it would be, a moment later): on screen from its swap
            log.warning("blend %s shown %.1f ms after its instant", renderer.blend_id or "none", (swap_rig - pts) / 1e6)
            pts = swap_rig
        self._blend_shown(pts)
        self._send_stats()

    def _shown_again(self, out: Output, renderer, swap_rig_ns: int | None = None, host: int | None = None) -> int:
        """The frame on screen was rendered again (a new assignment, or blend) and swapped in: the
        output hears of it as of a swap (the room shows it; a snapshot is written). The swap's rig
        instant (``swap_rig_ns``, or now, taken before the output reads the frame back)."""
        self._fbo_shown = True
        f = self._current
        host = self.clock.host_now() if host is None else host
        if swap_rig_ns is None:
            swap_rig_ns = self._rig_now()
        out.after_swap(renderer, SwapInfo(slot=self.slot, frame_id=f.frame_id, tag=f.tag, pts_ns=f.pts_ns,
                                          swap_rig_ns=swap_rig_ns, host_monotonic_ns=host))
        return swap_rig_ns

    def _on_content(self, renderer, out, content: tuple[str, np.ndarray]) -> None:
        cid, image = content
        if not renderer.has(cid):
            renderer.upload(cid, image)

    def _on_evict(self, renderer, out, ids: list[str]) -> None:
        for cid in ids:
            if self._current is not None and self._current.content_id == cid:
                self._evicted.add(cid)   # still on screen: forget once replaced
            else:
                renderer.forget(cid)

    def _on_reset(self, renderer, out, _payload) -> None:
        """A coordinator on a new rig clock (another host, a reboot): its frame ids and timeline
        times are not comparable with the old ones; the timeline is sent again."""
        self.pacer.reset()
        self.player.reset()
        self._end_fade()
        self._end_show_fade()
        self.live.reset()
        self._last_event_pts = None

    # ---------------------------------------------------------------- the show's timeline
    def _on_show(self, renderer, out, update: ShowUpdateData) -> None:
        if self.player.offer(update):
            if update.timeline is not None:
                tl = update.timeline
                log.info("timeline r%d: asset %s frame %d at %d%s%s", tl.revision, tl.asset_id[:12], tl.anchor_frame,
                         tl.anchor_ns, " paused" if tl.paused else "", " loop" if tl.loop else "")
            else:
                log.info("timeline r%d: stop at %d", update.stop_revision, update.stop_at_ns)
            self._end_show_fade()
            tl = update.timeline
            if tl is not None and tl.fade_ns > 0:     # its first tick fades in from what is on screen then
                self._show_fade = ShowFade(tl.revision, tl.anchor_ns, tl.fade_ns)
            self._prepare_timeline()
            self._send_stats()

    def _on_asset(self, renderer, out, files: AssetFiles) -> None:
        self.player.add_asset(files)
        self._prepare_timeline()
        self._send_stats()

    def _prepare_timeline(self) -> None:
        """Decoding starts as soon as the show and its asset are known, ahead of the first tick."""
        est = self.pacer.estimate
        if est is not None:
            after = est.rig_time(self.clock.now())
            if self._last_event_pts is not None:
                after = max(after, self._last_event_pts + 1)
            self.player.prepare(after)

    def _next_event(self) -> TimelineEvent | None:
        est = self.pacer.estimate
        if est is None or not self.player.active:
            return None
        after = est.rig_time(self.clock.now())
        if self._last_event_pts is not None:
            after = max(after, self._last_event_pts + 1)
        ev = self.player.next_event(after)
        if ev is not None and ev.kind == "frame" and not self.player.has_asset(ev.asset_id):
            return None
        return ev

    def timeline_wait(self) -> float | None:
        """Seconds the loop may wait for messages before :meth:`timeline_step` (None: no timeline work,
        and no blend switch due with no frame to make it)."""
        if self._fade is not None:      # a crossfade's next step, unless a show's tick takes over
            ev = self._next_event()
            if ev is None:
                return self._fade_wait()
            if ev.kind == "stop":       # a show stopped for the fade: it leaves the fade's frame on screen
                until = self.pacer.estimate.local_time(ev.pts_ns) - self.clock.now()
                return min(self._fade_wait(), max(0.0, (until - self.PREPARE_NS) / 1e9))
            self._end_fade()
        ev = self._next_event()
        if ev is None:
            due = self._blend_due_local()
            if due is None:
                return None
            return max(0.0, (due - self.clock.now() - self.PREPARE_NS) / 1e9)
        until = self.pacer.estimate.local_time(ev.pts_ns) - self.clock.now()
        return max(0.0, (until - self.PREPARE_NS) / 1e9)

    def timeline_step(self) -> None:
        """Prepare the next timeline frame (or the stop), swap it in at its time, report it (its
        swap and drop records marked ``timeline``); with no timeline work, show the frame on screen
        with the next blend maps at their instant."""
        if self._fade is not None:
            ev = self._next_event()
            if ev is None or (ev.kind == "stop" and self._fade.next_order().pts_ns <= ev.pts_ns):
                self._fade_step()
                return
            if ev.kind != "stop":
                self._end_fade()
        if self._next_event() is None:
            self._blend_step()
            return
        self._timeline_reports = True
        try:
            self._timeline_step()
        finally:
            self._timeline_reports = False

    def _timeline_step(self) -> None:
        self._work_from_ns = self.clock.now()
        ev = self._next_event()
        if ev is None:
            return
        renderer, out, pacer = self.renderer, self.out, self.pacer
        for frame_id in self.player.skipped_ids(ev):
            self.timeline_missed += 1
            self._drop(DropRecord(frame_id, DropReason.LATE))
        self._last_event_pts = ev.pts_ns
        if ev.held:
            # A paused show's frame stays on the projectors for the whole pause: one that misses
            # its instant is shown a moment later (CATCH_UP_NS), never left out (that node would
            # show another frame than its peers until the show resumes).
            self._holding, self._held_late = True, False
            try:
                shown = self._timeline_frame(ev)
            finally:
                self._holding = False
            if shown or not self._held_late:
                self.player.mark_done(ev)
            if not shown and not self._held_late:
                self.timeline_missed += 1
                self._send_stats()
            return
        self.player.mark_done(ev)
        if ev.kind == "stop":
            cur = self._current
            if cur is not None and not cur.content_id.startswith("timeline:") and cur.pts_ns >= ev.pts_ns:
                # the still the stop makes way for (Stop restoring the content) came on the Frames
                # stream before the stop on the Show stream and is on screen: it stays there
                self._forget_timeline_content()
                return
            renderer.render(None)
            out.prepare(renderer)
            self._ctx.finish()
            with self._rt:
                self.clock.sleep_until(pacer.estimate.local_time(ev.pts_ns))
                out.swap()
            self._fbo_shown = True
            self._current = None
            self._forget_timeline_content()
            return
        if not self._timeline_frame(ev):
            self.timeline_missed += 1
            self._send_stats()

    def _timeline_frame(self, ev: TimelineEvent) -> bool:
        """Decode, render and swap in timeline frame ``ev`` at its time; whether it was shown (a
        frame that cannot be is reported dropped)."""
        renderer, out, pacer = self.renderer, self.out, self.pacer
        order = FrameOrder(frame_id=ev.frame_id, pts_ns=ev.pts_ns, content_id=f"timeline:{ev.frame_id}",
                           space="content", apply_lut=True, tag=f"timeline:{ev.revision}")
        drop = pacer.admit(replace(order, content_id=""), renderer.has)
        if drop is not None:
            self._drop(drop)
            return False
        try:
            image = self.player.frame(ev, (-pacer.late_by(order) - 2_000_000) / 1e9)
        except FrameNotReady:
            self._drop(DropRecord(ev.frame_id, DropReason.LATE, pacer.late_by(order)))
            return False
        except FrameError as exc:
            log.error("cannot show frame %d of asset %s: %s", ev.frame, ev.asset_id[:12], exc)
            self._drop(DropRecord(ev.frame_id, DropReason.UNRENDERABLE))
            return False
        self.player.quiet_around(ev, self.clock.to_host(pacer.deadline(order)), rendering=True)
        a = self.assignment
        if a is not None and a.pose_kind == "homography" and all(a.content_size):
            image = fit_frame(image, a.content_size)
        self._begin_show_fade(ev)
        try:
            renderer.upload(order.content_id, image)
            self._render(renderer, order)
        except ValueError as exc:
            log.error("cannot show frame %d of asset %s: %s", ev.frame, ev.asset_id[:12], exc)
            renderer.forget(order.content_id)
            self._drop(DropRecord(ev.frame_id, DropReason.UNRENDERABLE))
            return False
        # counted before the swap, so the stats sent with it say so; taken back if it was dropped
        before = self.timeline_last_frame
        self.timeline_shown += 1
        self.timeline_last_frame = ev.frame
        self._swap_at_pts(renderer, out, order)
        if self._show_fade is not None and self._show_fade.started and ev.pts_ns >= self._show_fade.end_ns:
            self._end_show_fade()
        if self._current is not order:
            self.timeline_shown -= 1
            self.timeline_last_frame = before
            return False
        return True

    def _drop(self, drop: DropRecord) -> None:
        if self._holding and drop.reason is DropReason.LATE:
            self._held_late = True      # tried again a moment later (see _timeline_step)
            if _DEBUG_TIMING:
                log.info("timing frame %d: held frame %.3f ms late, shown a moment later", drop.frame_id,
                         drop.late_by_ns / 1e6)
            return
        if _DEBUG_TIMING:
            log.info("timing frame %d: dropped (%s) %.3f ms late", drop.frame_id, drop.reason.value,
                     drop.late_by_ns / 1e6)
        if drop.reason is DropReason.LATE:
            self.late += 1
        else:
            self.dropped += 1
        self.report("drop", replace(drop, timeline=True) if self._timeline_reports else drop)
        self._send_stats()

    def _render(self, renderer, frame: FrameOrder) -> None:
        self._fbo_shown = False
        if self.blend.due_for(frame.pts_ns):
            self.blend.switch(renderer)       # the first frame at or after the blend's instant
        t = time.perf_counter()
        apply_lut, fade = frame.apply_lut, None
        if self._fade is not None and self._fade.covers(frame):
            apply_lut, fade = self._fade.render_args(frame)
        elif self._show_fade is not None and self._show_fade.covers(frame):
            apply_lut, fade = self._show_fade.render_args(frame)
        try:
            renderer.render(frame.content_id or None, space=frame.space, apply_lut=apply_lut, fade=fade)
        except (KeyError, ValueError) as exc:
            if fade is None:
                raise
            log.error("cannot crossfade into frame %d (%s): cut to it", frame.frame_id, exc)
            self._end_fade()
            self._end_show_fade()
            renderer.render(frame.content_id or None, space=frame.space, apply_lut=frame.apply_lut)
        self._render_ms.append((time.perf_counter() - t) * 1e3)

    def _on_frame(self, renderer, out: Output, frame: FrameOrder) -> None:
        pacer = self.pacer
        if self.player.issued_before_newest(frame.frame_id):
            # sent before the newest show began (a still's resend the Show stream overtook): the show stays
            self._drop(DropRecord(frame.frame_id, DropReason.SUPERSEDED))
            return
        self.player.suspend()    # a coordinator frame takes the output from the timeline
        drop = pacer.admit(frame, renderer.has)
        if drop is not None:
            self._drop(drop)
            if frame.fade_steps and drop.reason is DropReason.LATE:
                self._start_fade(frame)     # a crossfade goes on from its steps still ahead
            return
        if _DEBUG_TIMING:
            log.info("timing: frame %d reached the presenter %.1f ms before its deadline", frame.frame_id,
                     -pacer.late_by(frame) / 1e6)
        self._start_fade(frame)
        try:
            self._render(renderer, frame)
        except ValueError as exc:   # the renderer refuses what it cannot show correctly
            log.error("cannot show frame %d: %s", frame.frame_id, exc)
            self._drop(DropRecord(frame.frame_id, DropReason.UNRENDERABLE))
            return
        self._swap_at_pts(renderer, out, frame)

    # ---------------------------------------------------------------- crossfades (node/fade.py)
    def _start_fade(self, frame: FrameOrder) -> None:
        """A frame admitted: a fade under way ends where it is; the frame's own fade (if any) starts
        from what is on screen, which is kept until the fade ends."""
        self._end_fade()
        self._end_show_fade()
        fade = Crossfade.start(frame, self._current, self.renderer.has)
        if fade is None:
            return
        before = fade.before_id
        if before and before == self._timeline_cid:      # a show's frame: the fade forgets it
            self._timeline_cid, fade.forget_before = None, True
        elif before in self._evicted:
            self._evicted.discard(before)
            fade.forget_before = True
        self._fade = fade

    def _end_fade(self) -> None:
        fade, self._fade = self._fade, None
        if fade is not None and fade.forget_before and (self._current is None
                                                        or self._current.content_id != fade.before_id):
            self.renderer.forget(fade.before_id)

    def _begin_show_fade(self, ev: TimelineEvent) -> None:
        """The show's first tick: its fade in starts from what is on screen now (a pattern: a cut)."""
        sf = self._show_fade
        if sf is None or sf.started or ev.revision != sf.revision:
            return
        cur = self._current
        if cur is not None and cur.content_id and (cur.space != "content" or not self.renderer.has(cur.content_id)):
            self._show_fade = None
            return
        sf.started, sf.before_id = True, cur.content_id if cur is not None else ""
        if sf.before_id and sf.before_id == self._timeline_cid:      # the previous show's frame
            self._timeline_cid, sf.forget_before = None, True
        elif sf.before_id and sf.before_id in self._evicted:
            self._evicted.discard(sf.before_id)
            sf.forget_before = True

    def _end_show_fade(self) -> None:
        sf, self._show_fade = self._show_fade, None
        if sf is not None and sf.forget_before and (self._current is None
                                                    or self._current.content_id != sf.before_id):
            self.renderer.forget(sf.before_id)

    def _fade_wait(self) -> float | None:
        est = self.pacer.estimate
        if est is None:
            return None
        until = est.local_time(self._fade.next_order().pts_ns) - self.clock.now()
        return max(0.0, (until - self.PREPARE_NS) / 1e9)

    def _fade_step(self) -> None:
        """Render the fade's next step and swap it in at its instant; a late step is dropped, except
        the last, which is shown at once (the fade ends on the new picture)."""
        fade = self._fade
        order = fade.next_order()
        fade.next_k += 1
        last = fade.is_last(order)
        self._work_from_ns = self.clock.now()
        renderer, out = self.renderer, self.out
        drop = self.pacer.admit(order, renderer.has)
        if drop is not None and not last:
            self._drop(drop)
            return
        if drop is None:
            self._render(renderer, order)
            self._swap_at_pts(renderer, out, order)
        if last and self._current is not order and self._fade is fade:     # the last step missed its instant
            if drop is not None:
                self._drop(drop)
            self._render(renderer, order)
            out.prepare(renderer)
            out.swap()
            self._current = order
            self._shown_again(out, renderer)
            log.warning("crossfade into frame %d ended %.1f ms after its instant", fade.frame.frame_id,
                        (self._rig_now() - order.pts_ns) / 1e6)
        if last:
            self._end_fade()

    def _forget_timeline_content(self, keep: str | None = None) -> None:
        if self._timeline_cid is not None and self._timeline_cid != keep:
            self.renderer.forget(self._timeline_cid)
        self._timeline_cid = keep

    def _swap_at_pts(self, renderer, out: Output, frame: FrameOrder) -> None:
        """Finish the rendered frame, wait for its time, swap, report (or drop it as late)."""
        out.prepare(renderer)
        self._ctx.finish()   # the frame must be complete in the back buffer before its time comes
        self.player.rendered()      # a timeline frame's decoder, quiet while it was made, may work again
        self.blend.ready()
        drop = self.pacer.ready(frame)
        if drop is not None:
            if frame.content_id == f"timeline:{frame.frame_id}":
                renderer.forget(frame.content_id)
            self._drop(drop)
            return
        deadline = self.pacer.deadline(frame)
        self._work_ns.append(max(0, self.clock.now() - self._work_from_ns))
        self._wait_taking_blends(frame, deadline)
        with self._rt:
            self.clock.sleep_until(deadline)
            out.swap()
            host = self.clock.host_now()
        self._fbo_shown = True
        self._swapped_at_ns = self.clock.from_host(host)
        if _DEBUG_TIMING:
            log.info("timing frame %d: swap %.3f ms after deadline", frame.frame_id,
                     (host - self.clock.to_host(deadline)) / 1e6)
        swap = self.pacer.shown(frame, host)
        self._blend_shown(frame.pts_ns)
        if self._timeline_reports:
            swap = replace(swap, timeline=True)
        previous = self._current
        self._current = frame
        self._forget_timeline_content(keep=frame.content_id if frame.content_id.startswith("timeline:") else None)
        self.shown += 1
        self.report("swap", swap)
        out.after_swap(renderer, SwapInfo(slot=self.slot, frame_id=frame.frame_id, tag=frame.tag, pts_ns=frame.pts_ns,
                                          swap_rig_ns=swap.swap_rig_ns, host_monotonic_ns=host))
        if previous is not None and previous.content_id in self._evicted and previous.content_id != frame.content_id:
            renderer.forget(previous.content_id)
            self._evicted.discard(previous.content_id)
        self._send_stats()
        # the next streamed frame is expected one interval on (a still: none); then a preview, if it fits
        gap = frame.pts_ns - previous.pts_ns if previous is not None and not self._timeline_reports else 0
        self._stream_next_ns = deadline + gap if 0 < gap <= self.STREAM_GAP_NS else None
        self._maybe_preview(unknown_ok=False)
