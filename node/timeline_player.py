"""The show's timeline as the presenter follows it: which frame to swap in next, and when.

The presenter process keeps one :class:`TimelinePlayer`. The node process forwards every
message of the coordinator's Show stream (:class:`~node.records.ShowUpdateData`, a few dozen
bytes) and, once the show's asset is complete in its cache, the asset's files
(:class:`~node.records.AssetFiles`: the manifest and blob paths; the cache itself, and its
lock, stay with the node process). Frames are decoded here, ahead of their time
(:class:`~node.asset_frames.DecodeAhead`), so decoded frames never cross the pipe.

For each frame period ``tick`` of the timeline in force, the frame ``k =
timeline.frame_of_tick(tick)`` is swapped in at ``timeline.pts(tick)`` and reported as frame id
``frame_id_base + tick`` (:meth:`TimelinePlayer.next_event`). Rules, as built:

* **Changes** (a newer revision) take effect at their anchor (:class:`protos.timeline.Schedule`);
  a stop blacks the output at its instant; a show that does not loop holds its last frame.
* **Joining mid-show**: the first tick considered is the next one to begin; a node that joins a
  paused show shows the held frame as soon as it can (with the same frame id as the others).
* **Never late, never out of order**: ticks whose time passed before the presenter got to them
  are reported dropped (late); the presenter's :class:`~node.pacing.FramePacer` checks every
  timeline frame as it checks the coordinator's.
* **Precedence**: a coordinator frame (a still, a pattern, a played sequence) reaching the
  presenter suspends the timeline (:meth:`TimelinePlayer.suspend`) until a newer revision
  arrives; repeated beacons of the same revision do not resume it.
"""
from __future__ import annotations

import logging
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from node.asset_frames import DecodeAhead, DecodeStats, FrameError, open_frames
from node.decoders import DecoderChoice, choose, wish_from_env
from node.heap_trim import trim_now
from node.records import AssetFiles, ShowUpdateData
from protos.asset_manifest import Manifest, ManifestError
from protos.timeline import NS, Schedule, Timeline
from protos.yuv import YuvFrame

log = logging.getLogger(__name__)

#: a node that catches up with a held (paused) frame shows it this far ahead of now
CATCH_UP_NS = 30_000_000
#: the decode-ahead thread starts nothing from this long before a swap (or a third of a frame
#: period, if shorter) to this long after it: the swap never waits for the interpreter lock
QUIET_BEFORE_NS = 8_000_000
QUIET_AFTER_NS = 1_000_000
#: while the presenter makes a frame (from its start to its render finished) no decode starts either, for at
#: most this long (and half a frame period): the frame due next period comes before one due frames later
RENDER_QUIET_MAX_NS = 16_000_000
#: ticks reported late at most at once (after a long stall)
MAX_SKIPPED_REPORTS = 120
#: a video's decoder threads, slice threads (:data:`node.asset_decode.THREAD_TYPE`): they share
#: the slices of one picture, so a stream cut in slices decodes on two threads and one of a single
#: slice on one, with no picture held per thread. Frame threads held a picture in flight and a
#: decoder's state each: 12 MB more at 1080p with two threads (FFmpeg's choice, one per core plus
#: one, 25 MB more), for the same CPU per frame (bench/node_video_memory.py)
DECODE_THREADS = 2
#: a stopped or suspended show's decoder is closed and its memory given back this long after the
#: stop is prepared (the presenter prepares a swap PREPARE_NS, 50 ms, before it), on the decode
#: thread: the trim took 6 ms on a quiet host, 54-69 ms of wall time at load 27, during which the
#: presenter's thread waited up to 10-23 ms for a 4 kB allocation (6 ms at worst without the trim)
LET_GO_AFTER_S = 0.25


class AssetFilesView:
    """The part of :class:`node.asset_cache.AssetCache` that :func:`node.asset_frames.open_frames`
    reads, over the files the node process passed (no lock, no writes)."""

    def __init__(self, files: AssetFiles):
        self.files = files
        try:
            self._manifest = Manifest.from_bytes(files.manifest, asset_id=files.asset_id)
        except ManifestError as exc:
            raise FrameError(f"asset {files.asset_id[:12]}: bad manifest: {exc}") from exc

    def manifest(self, asset_id: str) -> Manifest:
        if asset_id != self.files.asset_id:
            raise FrameError(f"asset {asset_id[:12]} was not passed to the presenter")
        return self._manifest

    def missing(self, asset_id: str) -> list[tuple[str, int, int]]:
        out, seen = [], set()
        for b in self.manifest(asset_id).blobs:
            path = self.files.blob_paths.get(b.sha256)
            if b.sha256 not in seen and (path is None or not Path(path).is_file()):
                seen.add(b.sha256)
                out.append((b.sha256, b.size, 0))
        return out

    def ready(self, asset_id: str) -> bool:
        return not self.missing(asset_id)

    def blob_path(self, sha256: str) -> Path:
        path = self.files.blob_paths.get(sha256)
        if path is None:
            raise FrameError(f"blob {sha256[:12]} was not passed to the presenter")
        return Path(path)


def fit_frame(image: np.ndarray, size: tuple[int, int]) -> np.ndarray:
    """``image`` (H, W, C) at ``size`` (w, h): itself if it has that size, else nearest-neighbour
    resampled (texel centres aligned)."""
    w, h = size
    if isinstance(image, YuvFrame):       # the renderer scales its planes on the GPU
        return image if image.content_size == (w, h) else image.at_size((w, h))
    if image.shape[1] == w and image.shape[0] == h:
        return image
    ys = ((np.arange(h) + 0.5) * image.shape[0] / h).astype(np.intp)
    xs = ((np.arange(w) + 0.5) * image.shape[1] / w).astype(np.intp)
    return np.ascontiguousarray(image[ys[:, None], xs[None, :]])


@dataclass(frozen=True)
class TimelineEvent:
    """What the presenter does next: swap in ``frame`` of ``asset_id`` at ``pts_ns`` (rig clock),
    reported as ``frame_id`` (tick ``tick`` of ``revision``), or black the output (``stop``)."""

    kind: str                # "frame" or "stop"
    pts_ns: int
    revision: int
    tick: int = 0
    frame: int = 0
    frame_id: int = 0
    asset_id: str = ""
    loop: bool = False
    held: bool = False       # a paused timeline's one frame: held for as long as the pause lasts


class TimelinePlayer:
    """The presenter's timeline state (see the module docstring). Not thread-safe: the
    presenter's thread calls it."""

    def __init__(self, *, depth: int = 8):
        self.depth = depth
        self.schedule = Schedule()
        self._bases: dict[int, int] = {}
        self._stops: dict[int, int] = {}             # stop instant -> revision
        self._files: dict[str, AssetFiles] = {}
        self._decoder: DecodeAhead | None = None
        self._after_render: tuple[int, int] | None = None     # the window around a swap, once its frame is made
        self._decoder_size: tuple[int, int] | None = None
        #: (w, h) a video's frames are decoded to (the content size the node warps from; None: the
        #: video's own). The presenter sets it from its assignment; a change reopens the decoder.
        self.content_size: tuple[int, int] | None = None
        #: a video's frames come as YUV planes, converted by the renderer (node/yuv.py), decoded by
        #: the decoder the node's --decoder wishes for (node/decoders.py)
        self.yuv = True
        self.decoder = wish_from_env()
        self._decoder_revision = -1
        self.suspended_revision = -1
        self.done: tuple[int, int] | None = None     # (revision, tick) of the last event handled
        self._failed: set[str] = set()

    # ------------------------------------------------------------------ input
    def offer(self, update: ShowUpdateData) -> bool:
        """Take a Show stream message; whether it was a new revision."""
        if update.timeline is not None:
            new = self.schedule.offer(update.timeline)
            if new:
                self._bases[update.timeline.revision] = update.frame_id_base
        else:
            new = self.schedule.offer_stop(update.stop_at_ns, update.stop_revision)
            if new:
                self._stops[update.stop_at_ns] = update.stop_revision
        return new

    def add_asset(self, files: AssetFiles) -> None:
        self._files[files.asset_id] = files
        self._failed.discard(files.asset_id)

    def has_asset(self, asset_id: str) -> bool:
        return asset_id in self._files and asset_id not in self._failed

    def suspend(self) -> None:
        """A coordinator frame takes the output: ignore the timeline until a newer revision (which
        reopens a decoder when it is scheduled: the open one is let go, :meth:`_let_decoder_go`)."""
        self.suspended_revision = self.schedule.revision
        self._let_decoder_go()

    def issued_before_newest(self, frame_id: int) -> bool:
        """Whether coordinator frame ``frame_id`` was issued before the newest revision, a timeline:
        its id is below that revision's frame id base (the coordinator takes every base above every
        id it issued before, and a takeover's frames above every tick a node may still swap). Such a
        frame, e.g. a still's resend that raced the show's start on the other stream, must not
        suspend the show."""
        base = self._bases.get(self.schedule.revision)
        return base is not None and frame_id < base

    def reset(self) -> None:
        """A coordinator on a new rig clock: forget the schedule (its Show stream sends it again)."""
        self.schedule = Schedule()
        self._bases.clear()
        self._stops.clear()
        self.suspended_revision = -1
        self.done = None

    def state(self, now_ns: int | None) -> str:
        """Where the show is at rig time ``now_ns`` (None: no clock yet): "none", "waiting",
        "playing", "paused" or "suspended" (see :class:`node.records.ShowStatus`)."""
        if self.schedule.revision <= 0:
            return "none"
        if self.schedule.revision <= self.suspended_revision:
            return "suspended"
        tl = self.schedule.at(now_ns) if now_ns is not None else None
        if tl is None:
            return "none"
        if not self.has_asset(tl.asset_id):
            return "waiting"
        return "paused" if tl.paused else "playing"

    @property
    def active(self) -> bool:
        return bool(self.schedule.pending) and self.schedule.revision > self.suspended_revision

    # ------------------------------------------------------------------ what next
    def _revision_of(self, at_ns: int, tl: Timeline | None) -> int:
        return tl.revision if tl is not None else self._stops.get(at_ns, -1)

    def next_event(self, after_ns: int) -> TimelineEvent | None:
        """The first thing to do at or after rig time ``after_ns`` that was not done yet."""
        if not self.active:
            return None
        self.schedule.forget_before(after_ns - 1_000_000_000)
        entries = [(a, tl) for a, tl in self.schedule.pending if self._revision_of(a, tl) > self.suspended_revision]
        current = [e for e in entries if e[0] <= after_ns]
        later = [e for e in entries if e[0] > after_ns]
        event = None
        if current:
            a, tl = current[-1]
            event = self._tick_event(tl, after_ns) if tl is not None else self._stop_event(a, after_ns)
        if later:
            a, tl = later[0]
            nxt = self._tick_event(tl, a) if tl is not None else self._stop_event(a, a)
            if nxt is not None and (event is None or nxt.pts_ns <= event.pts_ns):
                event = nxt
        return event

    def _stop_event(self, at_ns: int, after_ns: int) -> TimelineEvent | None:
        rev = self._stops.get(at_ns, -1)
        if self.done is not None and self.done[0] >= rev:
            return None
        return TimelineEvent("stop", max(at_ns, after_ns), rev)

    def _tick_event(self, tl: Timeline, after_ns: int) -> TimelineEvent | None:
        base = self._bases.get(tl.revision)
        if base is None:
            return None
        done_tick = self.done[1] if self.done is not None and self.done[0] == tl.revision else None
        if self.done is not None and self.done[0] > tl.revision:
            return None
        if tl.paused:
            if done_tick is not None:
                return None
            pts = tl.anchor_ns if tl.anchor_ns >= after_ns else after_ns + CATCH_UP_NS
            return TimelineEvent("frame", pts, tl.revision, 0, tl.anchor_frame, base, tl.asset_id, tl.loop, held=True)
        if after_ns <= tl.anchor_ns:
            k = 0
        else:
            k = tl.tick_at(after_ns)
            if tl.pts(k) < after_ns:
                k += 1
        if done_tick is not None and k <= done_tick:
            k = done_tick + 1
        frame = tl.frame_of_tick(k)
        if frame is None:
            return None
        return TimelineEvent("frame", tl.pts(k), tl.revision, k, frame, base + k, tl.asset_id, tl.loop)

    def skipped_ids(self, event: TimelineEvent) -> list[int]:
        """Frame ids of the ticks of ``event``'s revision passed over since the last one handled."""
        if event.kind != "frame" or self.done is None or self.done[0] != event.revision:
            return []
        first = self.done[1] + 1
        ids = [event.frame_id - event.tick + t for t in range(first, event.tick)]
        return ids[-MAX_SKIPPED_REPORTS:]

    def mark_done(self, event: TimelineEvent) -> None:
        self.done = (event.revision, event.tick)
        if event.kind == "stop":
            self._let_decoder_go()

    def _let_decoder_go(self) -> None:
        """The show stopped or was suspended: its decoder (its pictures, its context: 28 MB at 1080p)
        is not kept for a show that may never come; a newer revision reopens one when it is scheduled
        (:meth:`prepare`). The decode thread closes it and gives its memory back
        (:mod:`node.heap_trim`), :data:`LET_GO_AFTER_S` from now, so the presenter's thread, about to
        swap the stop or the coordinator's frame in, waits for neither the frame being decoded nor the
        trim, and the trim (a few ms of arena locks and GIL hand-offs) falls after that swap."""
        if self._decoder is not None:
            self._decoder.close(wait=False, then=trim_now, linger_s=LET_GO_AFTER_S)
            self._decoder = None

    # ------------------------------------------------------------------ frames
    def frame(self, event: TimelineEvent, timeout_s: float) -> np.ndarray:
        """The decoded frame of ``event`` (waiting at most ``timeout_s``); FrameError (or
        FrameNotReady) when it cannot be had."""
        return self._decoder_for(event).get(event.frame, max(0.0, timeout_s))

    def prepare(self, after_ns: int) -> None:
        """Start decoding the next frame event's asset now (a show scheduled, an asset arrived), so
        its first frames are ready when their time comes instead of being decoded in the last
        moment before it. A decoder already open on that asset is left alone: re-planning it for a
        change (a pause, a seek) while the ticks before the change still play would make it jump
        back and forth. A decoder that cannot open says so at :meth:`frame`."""
        ev = self.next_event(after_ns)
        if ev is None or ev.kind != "frame" or not self.has_asset(ev.asset_id):
            return
        if self._decoder is not None and self._decoder.source.asset_id == ev.asset_id:
            return
        try:
            self._decoder_for(ev)
        except FrameError:
            pass

    def decode_stats(self) -> DecodeStats | None:
        """The open decoder's counters (None: no decoder open)."""
        return self._decoder.stats() if self._decoder is not None else None

    def _decoder_for(self, event: TimelineEvent) -> DecodeAhead:
        """The decoder of ``event``'s asset, opened if need be, its order starting at ``event``'s
        frame when the revision changed."""
        dec = self._decoder
        if dec is None or dec.source.asset_id != event.asset_id or self._decoder_size != self.content_size:
            self.close()
            files = self._files.get(event.asset_id)
            if files is None:
                raise FrameError(f"asset {event.asset_id[:12]} is not in the node's cache yet")
            try:
                dec = DecodeAhead(open_frames(AssetFilesView(files), event.asset_id, size=self.content_size,
                                              yuv=self.yuv, decoder=self.decoder, threads=DECODE_THREADS),
                                  depth=self.depth, loop=event.loop)
            except FrameError:
                self._failed.add(event.asset_id)
                raise
            self._decoder, self._decoder_revision, self._decoder_size = dec, -1, self.content_size
        if self._decoder_revision != event.revision:
            dec.want(event.frame, loop=event.loop)
            self._decoder_revision = event.revision
        return dec

    def decoder_in_use(self) -> DecoderChoice:
        """What videos are decoded with: the open video's decoder (a hardware one that failed on the
        stream's first picture became software there), else what the node's wish resolves to for
        H.264 (probed once per process, :func:`node.decoders.choose`)."""
        dec = self._decoder
        video = getattr(dec.source, "decoder", None) if dec is not None else None
        choice = getattr(video, "choice", None)
        return choice if choice is not None else choose("h264", self.decoder)

    def quiet_around(self, event: TimelineEvent, swap_host_ns: int, *, rendering: bool = False) -> None:
        """``event`` swaps in at ``swap_host_ns`` (the host's clock): its decoder starts no work
        from QUIET_BEFORE_NS (at most a third of a frame period) before it to QUIET_AFTER_NS
        after it (:meth:`node.asset_frames.DecodeAhead.quiet`). With ``rendering`` the frame is being
        made now: no decode starts from now until :meth:`rendered` (at most RENDER_QUIET_MAX_NS and
        half a frame period), then the window around the swap holds."""
        if self._decoder is None:
            return
        tl = self.schedule.at(event.pts_ns)
        before = QUIET_BEFORE_NS if tl is None else min(QUIET_BEFORE_NS, int(NS / tl.rate / 3))
        window = (swap_host_ns - before, swap_host_ns + QUIET_AFTER_NS)
        if rendering:
            now = time.monotonic_ns()
            most = RENDER_QUIET_MAX_NS if tl is None else min(RENDER_QUIET_MAX_NS, int(NS / tl.rate / 2))
            self._after_render = window
            self._decoder.quiet(now, window[1] if now + most >= window[0] else now + most)
            return
        self._decoder.quiet(*window)

    def rendered(self) -> None:
        """The frame :meth:`quiet_around` was told of with ``rendering`` is made: the decoder may work
        until the window around its swap."""
        window, self._after_render = self._after_render, None
        if window is not None and self._decoder is not None:
            self._decoder.quiet(*window)

    def close(self) -> None:
        if self._decoder is not None:
            self._decoder.close()
            self._decoder = None
