"""What the rig shows: stills, calibration patterns and played sequences.

A **still** (the rig's content, or what an operator showed) is sent once and resent to
nodes that join later or dropped it (with a growing time budget). A **pattern** (a job's
projector-space images, or content through the poses) returns only once every live node
swapped it in. A **sequence** is sent frame by frame, each a latency budget ahead of its
presentation time, and reports its swap figures. A sequence of given frames (1 or 3 channels)
travels as live video (:mod:`coordinator.live_video`): encoded once for every node on a
worker thread, a frame ahead, a keyframe every second and one more whenever a node opens its
frame stream mid-sequence; generated patterns and RGBA frames travel as lossless images.

Time is the rig clock (``clock_ns``, injectable); nothing here assumes the machine is idle:
a frame that reaches a node late is dropped by the node and counted, never shown late.
"""
from __future__ import annotations

import asyncio
import logging
import resource
import time
import uuid
from dataclasses import replace
from typing import Callable, Mapping, Sequence

import numpy as np

from coordinator.api import PlayResult, PlaySettings, ShowResult, Space
from coordinator.errors import CoordinatorError
from coordinator.fanout import FanOut, Frame
from coordinator.fit import check_fit, fit_image
from coordinator.live_video import LiveStream, bit_depth_for, video_eligible
from coordinator.rig import Content, Rig
from coordinator.slot_regions import check_regions, masked_contents
from coordinator.sessions import NodeSession
from coordinator.sync import FrameResult, SyncTracker, summarize
from protos.fade import step_count

log = logging.getLogger(__name__)

MAX_BUDGET_NS = 2_000_000_000


def cpu_seconds() -> float:
    """CPU time of this process so far."""
    ru = resource.getrusage(resource.RUSAGE_SELF)
    return ru.ru_utime + ru.ru_stime


def said(tag: str) -> str:
    """What a frame's tag (a machine id: ``show:cue:2``, ``play:9d697ab1``) means to an operator, as the
    start of the "showing" line that status, stop, OSC and the console print."""
    if tag == "show:restored":
        return "the rig's content:"
    if tag.startswith("show:cue:"):
        return f"cue {tag.removeprefix('show:cue:')}:"
    if tag.startswith("play:"):
        return "a played sequence"
    return tag


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


def fit_content(content: Content, size: tuple[int, int], fit: str = "stretch") -> Content:
    """``content`` at the rig's content size ``(w, h)`` (the poses map content px), fitted as
    :func:`coordinator.fit.fit_image` says; the same Content when it has that size already."""
    check_fit(fit)
    img = content.image
    if img.shape[1] == size[0] and img.shape[0] == size[1]:
        return content
    return Content(fit_image(img, size, fit), name=content.name)


class Playback:
    """Decides and sends what every node shows.

    Parameters
    ----------
    rig : Rig
    fanout : FanOut
    sync : SyncTracker
    live_sessions : callable
        The node sessions that currently stream frames.
    clock_ns : callable
        The rig clock (monotonic ns).
    latency_ns : int
        How far ahead of its presentation time a frame is sent.
    """

    def __init__(self, rig: Rig, fanout: FanOut, sync: SyncTracker, *, live_sessions: Callable[[], list[NodeSession]],
                 clock_ns: Callable[[], int], latency_ns: int):
        self.rig = rig
        self.fanout = fanout
        self.sync = sync
        self.live_sessions = live_sessions
        self.clock_ns = clock_ns
        self.latency_ns = latency_ns
        # frame ids grow across restarts too (seeded from the wall clock in µs)
        self._next_frame_id = time.time_ns() // 1000
        self.current_frame: Frame | None = None        # what the rig shows, resent to late joiners
        self.current_contents: dict[str, Content] = {}
        self.showing = "nothing"
        self.last_pattern_pts_ns = 0
        self._pattern_ids: set[str] = set()
        self._play_task: asyncio.Task | None = None
        self._waiters: dict[int, asyncio.Future] = {}
        #: played sequences of given frames go as live video (False: as lossless images, frame by frame)
        self.live_video = True
        self._live: LiveStream | None = None          # the live video stream being played
        #: what the last live video sequence cost: frames, bytes of encoded pictures, raw bytes, encode CPU s
        self.live_stats: dict[str, float] = {}
        #: a still, pattern or sequence is about to be sent: the timeline show stops (set by the coordinator)
        self.takeover: Callable[[], None] = lambda: None
        #: whether a timeline show holds the projectors (then joining nodes are not sent the still)
        self.show_active: Callable[[], bool] = lambda: False
        sync.add_listener(self._resolve_waiter)
        if rig.content is not None:
            self._set_still(rig.content, tag="show:restored", space=Space.CONTENT, apply_lut=True, publish=False)

    # ------------------------------------------------------------------ frames
    @property
    def content_size(self) -> tuple[int, int]:
        return self.rig.config.content_width, self.rig.config.content_height

    def new_frame_id(self) -> int:
        self._next_frame_id += 1
        return self._next_frame_id

    def reserve_ids_through(self, last_id: int) -> None:
        """Frame ids up to ``last_id`` are taken (by a timeline show's ticks): never issue them."""
        self._next_frame_id = max(self._next_frame_id, int(last_id))

    def _frame(self, content_id: str, *, tag: str, space: Space, apply_lut: bool, pts_ns: int | None = None,
               slot_content: Mapping[str, str] | None = None, fade_ns: int = 0) -> Frame:
        steps = step_count(fade_ns) if fade_ns > 0 and space == Space.CONTENT else 0
        frame = Frame(frame_id=self.new_frame_id(), pts_ns=pts_ns or self.clock_ns() + self.latency_ns,
                      content_id=content_id, space=space, apply_lut=apply_lut, tag=tag,
                      slot_content=dict(slot_content or {}), fade_ns=int(fade_ns) if steps else 0, fade_steps=steps)
        self.reserve_ids_through(frame.frame_id + steps)     # a crossfade's steps are frames of their own
        return frame

    @property
    def playing(self) -> bool:
        return self._play_task is not None and not self._play_task.done()

    # ------------------------------------------------------------------ stills
    def request_keyframe(self) -> None:
        """A node lost pictures of the live video playing (its backlog was dropped): the next
        picture is a keyframe, so it can decode again at once, not at the next regular one."""
        if self._live is not None:
            self._live.request_keyframe()

    def on_frames_open(self, sess: NodeSession) -> None:
        """A node opened its frame stream: it gets what the rig shows (unless a sequence plays)."""
        sess.sent_content.clear()
        if self._live is not None:
            self._live.request_keyframe()     # it cannot decode the stream before the next keyframe
        if self.current_frame is not None and not self.playing and not self.show_active():
            self._send_still_to(sess)

    def _send_still_to(self, sess: NodeSession, *, budget_ns: int | None = None) -> None:
        assert self.current_frame is not None
        frame = replace(self.current_frame, frame_id=self.new_frame_id(), fade_ns=0, fade_steps=0,
                        pts_ns=self.clock_ns() + (budget_ns or self.latency_ns))
        sess.still_frames = {frame.frame_id}
        self.fanout.send([sess], frame=frame, contents=self.current_contents)

    def retry_still(self, sess: NodeSession, frame_id: int) -> None:
        """A still must end up on every projector: a node that dropped it gets it again, with more time."""
        if frame_id not in sess.still_frames or self.current_frame is None or not self.current_frame.tag.startswith("show"):
            return
        if self.current_frame.fade_steps and frame_id == self.current_frame.frame_id:
            return      # a crossfade's first step: the node fades on, and its last step decides
        if self.show_active():
            return
        sess.still_retries += 1
        budget = min(MAX_BUDGET_NS, self.latency_ns * 2 ** min(sess.still_retries, 6))
        log.info("node %s dropped still frame %d; resending with %.0f ms budget", sess.slot, frame_id, budget / 1e6)
        self._send_still_to(sess, budget_ns=budget)

    def _set_still(self, content: Content, *, tag: str, space: Space, apply_lut: bool, publish: bool = True,
                   slot_contents: Mapping[str, Content | None] | None = None, fade_ns: int = 0) -> Frame:
        if publish:
            self.takeover()
        per_slot = slot_contents or {}
        self.current_contents = {content.content_id: content, **{c.content_id: c for c in per_slot.values() if c}}
        frame = self._frame(content.content_id, tag=tag, space=space, apply_lut=apply_lut,
                            slot_content={s: c.content_id if c else "" for s, c in per_slot.items()}, fade_ns=fade_ns)
        self.current_frame = frame
        self.showing = f"{said(tag)} {content.name or content.content_id}"
        if publish:
            self._publish_still(frame)
        return frame

    def _publish_still(self, frame: Frame) -> None:
        sessions = self.live_sessions()
        for sess in sessions:
            sess.still_frames = {frame.frame_id, frame.frame_id + frame.fade_steps}
            sess.still_retries = 0
        self.fanout.send(sessions, frame=frame, contents=self.current_contents)

    def show_per_slot(self, contents: Mapping[str, Content], *, tag: str, showing: str) -> ShowResult:
        """A still of projector-space images, one per slot (other slots black), held as any still
        (late joiners get it, a node that dropped it gets it again). Encode ``contents`` with
        :meth:`FanOut.prepare` first (off the event loop)."""
        self.stop()
        self.takeover()
        self.current_contents = {c.content_id: c for c in contents.values()}
        frame = self._frame("", tag=tag, space=Space.PROJECTOR, apply_lut=False,
                            slot_content={slot: c.content_id for slot, c in contents.items()})
        self.current_frame = frame
        self.showing = showing
        self._publish_still(frame)
        return ShowResult(frame_id=frame.frame_id, content_id="", pts_ns=frame.pts_ns)

    def reshow_slots(self, base: Frame, contents: Mapping[str, Content], slot_content: Mapping[str, str], *,
                     showing: str) -> Frame:
        """Show the still of frame ``base`` (its contents ``contents``) again with another choice per
        slot (``slot_content``: slot -> content id, "" black), held as any still (the solo of
        :mod:`coordinator.slot_tools`). Returns the frame now on screen."""
        self.stop()
        self.takeover()
        self.current_contents = dict(contents)
        frame = self._frame(base.content_id, tag=base.tag, space=base.space, apply_lut=base.apply_lut,
                            slot_content=slot_content)
        self.current_frame = frame
        self.showing = showing
        self._publish_still(frame)
        return frame

    def show(self, content: Content, *, space: Space = Space.CONTENT, apply_lut: bool = True, persist: bool = False,
             tag: str = "show", slot_contents: Mapping[str, Content | None] | None = None,
             fade_ns: int = 0) -> ShowResult:
        """Show a still on every node (content through the poses, or projector pixels); ``persist``
        makes it the rig's content. ``slot_contents``: what some slots show instead (None: black),
        content-space images of the content's size, e.g. from :meth:`prepare_regions`. ``fade_ns``: the
        nodes crossfade from what they show into it over that long (:mod:`protos.fade`)."""
        if slot_contents and (persist or space != Space.CONTENT):
            raise ValueError("slot regions apply to a content-space show that is not persisted: the rig's content "
                             "is one picture for every slot")
        self.stop()
        if space == Space.CONTENT:
            content = fit_content(content, self.content_size)
        if persist:
            self.rig.set_content(content)
        frame = self._set_still(content, tag=tag, space=space, apply_lut=apply_lut, slot_contents=slot_contents,
                                fade_ns=fade_ns)
        return ShowResult(frame_id=frame.frame_id, content_id=content.content_id, pts_ns=frame.pts_ns)

    def prepare_still(self, content: Content, space: Space = Space.CONTENT, *, fit: str = "") -> Content:
        """What :meth:`show` will send for ``content``, fitted (``fit``: see :mod:`coordinator.fit`;
        ValueError for an image of another aspect and no choice) and encoded for the wire
        (blocking: run it in a worker thread, so a large still is not packed on the event loop)."""
        if space == Space.CONTENT:
            content = fit_content(content, self.content_size, fit)
        self.fanout.prepare([content])
        return content

    def prepare_regions(self, content: Content, regions: Mapping[str, Sequence[Sequence[int]]]
                        ) -> dict[str, Content | None]:
        """What each slot named in ``regions`` shows of the fitted ``content``: it masked to the slot's
        rectangles (see :mod:`coordinator.slot_regions`; ValueError for a bad slot or rectangle), encoded
        for the wire (blocking, like :meth:`prepare_still`)."""
        checked = check_regions(regions, self.content_size, self.rig.slots)
        out = masked_contents(content, checked)
        self.fanout.prepare([c for c in out.values() if c is not None])
        return out

    def blackout(self, *, fade_ns: int = 0, tag: str = "blackout") -> None:
        """Black on every projector (held until the next show; the rig's content is kept), faded
        to over ``fade_ns`` (0: at once)."""
        w, h = self.content_size
        self._set_still(Content(np.zeros((h, w, 1), np.uint8), name="black"), tag=tag, space=Space.CONTENT,
                        apply_lut=False, fade_ns=fade_ns)
        self.showing = "black (blackout)"

    def restore_content(self) -> None:
        """After a job: show the rig's content again (or black)."""
        if self.rig.content is not None:
            self.show(self.rig.content, tag="show:restored")
        else:
            self.current_frame, self.current_contents = None, {}
            self.showing = "nothing"

    # ------------------------------------------------------------------ patterns
    def _resolve_waiter(self, result: FrameResult) -> None:
        fut = self._waiters.pop(result.frame_id, None)
        if fut is not None and not fut.done():
            fut.set_result(result)

    async def show_patterns(self, images: Mapping[str, np.ndarray | None], *, content: np.ndarray | None = None,
                            apply_lut: bool = False, settle_s: float = 0.05, attempts: int = 4,
                            timeout_s: float = 15.0) -> FrameResult:
        """Show per-slot projector-space images (or one content image through the poses) on every
        live node and return once all of them swapped it in, plus ``settle_s``.

        A node that dropped the frame (late) gets it again with a longer budget; after ``attempts``
        the call fails and names the nodes that never showed it.
        """
        self.stop()
        self.takeover()
        sessions = self.live_sessions()
        contents: dict[str, Content] = {}
        slot_content: dict[str, str] = {}
        default, space = "", Space.PROJECTOR
        if content is not None:
            c = fit_content(Content(content, name="pattern"), self.content_size)
            contents[c.content_id] = c
            default, space = c.content_id, Space.CONTENT
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
        # encode them for the wire off the event loop, before the frame's time is fixed
        await asyncio.to_thread(self.fanout.prepare, list(contents.values()))
        result: FrameResult | None = None
        timed_out: list[str] = []
        for _ in range(attempts):
            frame = self._frame(default, tag="pattern", space=space, apply_lut=apply_lut, slot_content=slot_content,
                                pts_ns=self.clock_ns() + budget)
            fut = loop.create_future()
            self._waiters[frame.frame_id] = fut
            self.fanout.send(sessions, frame=frame, contents=contents, evict=evict)
            evict = []
            self.current_frame, self.current_contents = frame, contents
            self.showing = "calibration pattern"
            try:    # not wait_for: on 3.11 it drops a cancel (a job cancelled) that meets the verdict
                async with asyncio.timeout(timeout_s):
                    result = await fut
            except TimeoutError:    # no verdict in time (a node silent): try again, as for a late one
                result = None
                timed_out = sorted(s.slot for s in sessions)
            finally:
                self._waiters.pop(frame.frame_id, None)
            if result is not None and result.shown_by_all:
                break
            budget = min(4 * budget, MAX_BUDGET_NS)
            sessions = self.live_sessions()
        else:
            missing = ", ".join(result.missing if result is not None else timed_out)
            raise CoordinatorError(f"node(s) {missing} did not show the pattern after {attempts} tries "
                                   "(late or disconnected); check `shadowless status`")
        self._pattern_ids = set(contents)
        self.last_pattern_pts_ns = frame.pts_ns
        if settle_s > 0:
            await asyncio.sleep(settle_s)
        return result

    # ------------------------------------------------------------------ sequences
    def stop(self) -> None:
        """Stop a playing sequence (its task ends; what it sent is shown or dropped by the nodes)."""
        if self._play_task is not None and not self._play_task.done():
            self._play_task.cancel()
        self._play_task = None

    async def play(self, frames: Sequence[Content] | None, settings: PlaySettings) -> PlayResult:
        """Play ``frames`` (None: the settings' generated pattern) at ``settings.fps``.

        With ``settings.wait`` the result once played; otherwise at once (an empty result).
        """
        if not 0.1 <= settings.fps <= 1000:
            raise ValueError(f"fps must be in 0.1..1000, got {settings.fps:g}")
        if frames is None and settings.pattern != "counter":
            raise ValueError(f"unknown pattern {settings.pattern!r} (known: counter)")
        if frames is not None and not frames:
            raise ValueError("nothing to play: send frames or set a pattern")
        if frames is not None:   # fitted before anything stops: an image of another aspect is refused here
            frames = [fit_content(f, self.content_size, settings.fit) for f in frames]
        self.stop()
        self.takeover()
        task = asyncio.create_task(self._play(frames, settings), name="play")
        self._play_task = task
        if not settings.wait:
            task.add_done_callback(lambda t: t.cancelled() or t.exception())
            return PlayResult()
        return await asyncio.shield(task)

    async def _play(self, frames: Sequence[Content] | None, st: PlaySettings) -> PlayResult:
        fps = st.fps
        latency_ns = int(st.latency_ms * 1e6) if st.latency_ms > 0 else self.latency_ns
        if frames is None:
            count = st.frames or int(fps * 5)
            w, h = self.content_size
            make = lambda i: counter_pattern(i, w, h)  # noqa: E731
        else:
            count = len(frames) * (st.loops + 1)
            fitted = list(frames)
            make = lambda i: fitted[i % len(fitted)]  # noqa: E731
        tag = f"play:{uuid.uuid4().hex[:8]}"
        live = None
        if frames is not None and self.live_video and video_eligible([f.image for f in fitted]):
            first = fitted[0].image
            live = LiveStream(width=first.shape[1], height=first.shape[0], channels=first.shape[2],
                              bit_depth=bit_depth_for([f.image for f in fitted]), fps=fps)
            self._live = live
        results: list[FrameResult] = []
        remove = self.sync.add_listener(lambda r: results.append(r) if r.tag == tag else None)
        oo_before = self.sync.out_of_order
        cpu0, wall0, enc0 = cpu_seconds(), time.monotonic(), self.fanout.encode_cpu_s
        sent: list[int] = []
        nodes_seen: set[str] = set()
        prev_content: str | None = None
        cache_all = frames is not None and st.loops > 0 and sum(f.image.nbytes for f in frames) < 256 * 2**20
        self.showing = f"{said(tag)} ({count} frames at {fps:g} fps{', live video' if live else ''})"
        pending = None
        video_bytes = raw_bytes = 0
        try:
            t0 = self.clock_ns() + latency_ns
            for i in range(count):
                tick = t0 + int(i * 1e9 / fps)
                content = make(i)
                if live is not None and pending is None:
                    pending = live.submit(content.image)
                elif live is None:     # lossless contents: encoded on a worker thread while we wait
                    pending = asyncio.ensure_future(asyncio.to_thread(self.fanout.prepare, [content]))
                wait = (tick - latency_ns - self.clock_ns()) / 1e9
                if wait > 0:
                    await asyncio.sleep(wait)
                pic = None
                if live is None:
                    await pending
                else:
                    pic = await pending
                    pending = live.submit(make(i + 1).image) if i + 1 < count else None   # encode ahead
                    video_bytes += len(pic.data)
                    raw_bytes += content.image.nbytes
                sessions = self.live_sessions()
                nodes_seen.update(s.slot for s in sessions)
                cid = pic.content_id if pic is not None else content.content_id
                frame = self._frame(cid, tag=tag, space=Space.CONTENT, apply_lut=True,
                                    pts_ns=max(tick, self.clock_ns() + latency_ns // 2))
                if pic is not None:
                    self.fanout.send(sessions, frame=frame, video=pic, evict=[prev_content] if prev_content else [])
                else:
                    evict = [prev_content] if prev_content and prev_content != cid and not cache_all else []
                    self.fanout.send(sessions, frame=frame, contents={cid: content}, evict=evict)
                sent.append(frame.frame_id)
                # a node that joins later is sent the last frame as a still: the source image, losslessly
                self.current_frame = replace(frame, content_id=content.content_id)
                self.current_contents = {content.content_id: content}
                prev_content = cid
            # wait for the last swap reports
            deadline = time.monotonic() + (latency_ns / 1e9) + (st.settle_s or 1.0) + self.sync.timeout_s
            while time.monotonic() < deadline and len(results) < len(sent):
                await asyncio.sleep(0.05)
        finally:
            remove()
            if pending is not None:
                pending.cancel()
            if live is not None:
                live.close()
                if self._live is live:
                    self._live = None
                self.live_stats = {"frames": live.frames, "keyframes": live.keyframes, "bytes": video_bytes,
                                   "raw_bytes": raw_bytes, "encode_cpu_s": live.cpu_s,
                                   "bit_depth": live.bit_depth}
        summary = summarize(results, self.sync.out_of_order - oo_before)
        self.showing = f"{said(tag)}, finished"
        return PlayResult(
            frames_sent=len(sent), frames_shown=summary.frames, frames_late=summary.frames_late,
            frames_dropped=summary.frames_dropped + (len(sent) - len(results)), nodes=len(nodes_seen),
            wall_s=time.monotonic() - wall0, coordinator_cpu_s=cpu_seconds() - cpu0,
            encode_cpu_s=self.fanout.encode_cpu_s - enc0 + (live.cpu_s if live is not None else 0.0),
            skews_ms=tuple(r.skew_ms for r in sorted(results, key=lambda r: r.frame_id)),
            clock_errors_ms=tuple(np.concatenate([r.clock_errors_ms for r in results]).tolist()) if results else (),
            sync=summary,
        )

    async def close(self) -> None:
        task = self._play_task
        self.stop()
        if task is not None:
            await asyncio.gather(task, return_exceptions=True)
