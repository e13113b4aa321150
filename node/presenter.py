"""The presenter: a process of its own that owns the node's GL context.

It takes assignments, content, frames and clock estimates in arrival order
from a pipe, renders each frame into the back buffer as soon as it arrives,
waits until the frame's presentation time on its estimate of the rig clock,
swaps, and reports the swap. A frame whose time has passed is dropped and
counted, never shown late; a frame older than the one on screen is never shown
(no reordering).

Why a process: the swap is a real-time deadline, and a Python thread that
wakes on time still needs the GIL. If the network thread held it and was then
descheduled on a busy machine, the swap would wait for it (tens of ms were
measured with 16 nodes on 2 cores). Alone in its process, the presenter's
single thread never waits for anyone's GIL.
"""
from __future__ import annotations

import logging
import multiprocessing
import os
import statistics
import sys
import threading
import time
from collections import deque
from dataclasses import dataclass
from pathlib import Path
from typing import Callable

import numpy as np

from node.clock import ClockEstimate, LocalClock
from node.outputs import Output, SwapInfo, open_output
from node.wire import FrameOrder, NodeAssignment, frame_for_slot
from protos import codec, common_pb2, node_pb2

log = logging.getLogger(__name__)

#: log each swap's distance from its deadline (diagnostics)
_DEBUG_TIMING = bool(os.environ.get("SHADOWLESS_DEBUG_TIMING"))
#: a frame may be shown this late (ns) before it counts as late and is dropped
LATE_TOLERANCE_NS = 500_000


class RealtimeWindow:
    """Run the last sleep and the swap at real-time priority (SCHED_FIFO), the rest normally.

    A projector's swap is a real-time deadline: when a dozen nodes share a small
    machine, or a node's other threads are busy, a normal thread that wakes on
    time may still wait for a CPU. The thread enters this window once the frame
    is rendered, sleeps in it until the deadline (using no CPU), swaps,
    timestamps and leaves: it never renders at that priority and cannot starve
    the machine. Needs CAP_SYS_NICE (the systemd unit grants it); without it the
    node says so once and runs at normal priority.
    """

    def __init__(self, enabled: bool, priority: int = 50):
        self.active = False
        if not enabled or not hasattr(os, "sched_setscheduler"):
            return
        try:
            self._fifo = os.sched_param(priority)
            self._normal = os.sched_param(0)
            os.sched_setscheduler(0, os.SCHED_FIFO, self._fifo)
            os.sched_setscheduler(0, os.SCHED_OTHER, self._normal)
            self.active = True
        except (PermissionError, OSError) as exc:
            log.info("real-time swap priority unavailable (%s); swapping at normal priority", exc.strerror or exc)

    def __enter__(self) -> None:
        if self.active:
            os.sched_setscheduler(0, os.SCHED_FIFO, self._fifo)

    def __exit__(self, *exc) -> None:
        if self.active:
            os.sched_setscheduler(0, os.SCHED_OTHER, self._normal)


@dataclass
class PresenterStats:
    shown: int = 0
    late: int = 0
    dropped: int = 0


@dataclass(frozen=True)
class PresenterSettings:
    slot: str
    output_spec: str
    clock_offset_ns: int
    clock_drift_ppm: float
    clock_anchor_ns: int
    snapshot_dir: Path | None = None
    realtime: bool = True
    log_level: int = logging.INFO
    log_format: str = "%(asctime)s %(levelname)-7s %(message)s"


class Presenter:
    """The presenter loop (runs in the presenter process, or in a test's thread).

    ``report(kind, payload)`` receives ``("swap", SwapReport)``, ``("drop", FrameDrop)``
    and ``("stats", dict)``.
    """

    def __init__(self, *, slot: str, output: Output, clock: LocalClock,
                 report: Callable[[str, object], None], realtime: bool = True):
        self.slot = slot
        self.clock = clock
        self.report = report
        self.out = output
        self.estimate: ClockEstimate | None = None
        self.stats = PresenterStats()
        self.assignment: NodeAssignment | None = None
        self.native_size: tuple[int, int] | None = None
        self._realtime_wanted = realtime
        self._render_ms: deque[float] = deque(maxlen=120)
        self._last_frame_id = 0
        self._current: FrameOrder | None = None
        self._evicted: set[str] = set()

    def render_ms_p50(self) -> float:
        # statistics, not numpy: np.median imports numpy.ma on first use (~0.1 s, mid-playback)
        return statistics.median(self._render_ms) if self._render_ms else 0.0

    def open(self) -> None:
        from node.render.renderer import Renderer

        ctx = self.out.make_context()
        self._ctx = ctx
        self.native_size = self.out.native_size()
        w, h = self.native_size or (640, 360)
        self.renderer = Renderer(ctx, w, h)
        self._rt = RealtimeWindow(self._realtime_wanted)
        self._warm_up()
        self.renderer.render(None)
        self.out.prepare(self.renderer)
        self.out.swap()

    def _warm_up(self) -> None:
        """Draw once with every shader path so the driver compiles them now (llvmpipe JITs a
        shader at its first draw, ~0.1 s), not while the first real frame waits for its deadline."""
        r = self.renderer
        img = np.zeros((r.height, r.width, 3), np.uint8)
        r.upload("__warm__", img)
        r.set_homography(np.eye(3), (r.width, r.height))
        for lut in (None, np.tile(np.linspace(0, 1, 16, dtype=np.float32), (3, 1))):
            r.set_lut(lut)
            r.render("__warm__", space="content", apply_lut=True)
            r.render("__warm__", space="content", apply_lut=False)
        r.render("__warm__", space="projector", apply_lut=False)
        self._ctx.finish()
        r.forget("__warm__")
        r.set_lut(None)
        r.clear_pose()

    def close(self) -> None:
        self.renderer.release()
        self.out.close()

    def handle(self, kind: str, payload) -> None:
        t = time.perf_counter()
        getattr(self, "_on_" + kind)(self.renderer, self.out, payload)
        if _DEBUG_TIMING and (dt := time.perf_counter() - t) > 0.005 and kind != "frame":
            log.info("timing: %s took %.1f ms", kind, dt * 1e3)

    def idle(self) -> None:
        self.out.poll()   # a window keeps handling its events between frames

    def _send_stats(self) -> None:
        self.report("stats", {"shown": self.stats.shown, "late": self.stats.late, "dropped": self.stats.dropped,
                              "render_ms_p50": self.render_ms_p50(),
                              "revision": self.assignment.revision if self.assignment else 0})

    def _on_clock(self, renderer, out, estimate: ClockEstimate | None) -> None:
        self.estimate = estimate

    def _on_packet(self, renderer, out, data: bytes) -> None:
        """A FramePacket as received: cache its contents, show its frame, forget evicted contents."""
        pkt = node_pb2.FramePacket.FromString(data)
        for content in pkt.contents:
            self._on_content(renderer, out, (content.content_id, content.image))
        if pkt.HasField("frame"):
            self._on_frame(renderer, out, frame_for_slot(pkt.frame, self.slot))
        if pkt.HasField("evict"):
            self._on_evict(renderer, out, list(pkt.evict.content_ids))

    def _on_assignment(self, renderer, out: Output, a: NodeAssignment) -> None:
        from node.render.renderer import Mesh

        size = self.native_size or (a.width, a.height)
        if self.native_size and (a.width, a.height) != self.native_size:
            log.warning("assignment says %dx%d but the output is %dx%d; rendering at the output's size",
                        a.width, a.height, *self.native_size)
        if (renderer.width, renderer.height) != size:
            renderer.resize(*size)
        if a.pose_kind == "homography":
            renderer.set_homography(a.homography, a.content_size)
        elif a.pose_kind == "projection":
            renderer.set_projection(a.projection, Mesh(a.mesh.vertices, a.mesh.uvs, a.mesh.faces),
                                    near=a.near_mm, far=a.far_mm)
        else:
            renderer.clear_pose()
        renderer.set_lut(a.lut)
        renderer.set_gain(a.gain)
        self.assignment = a
        log.info("assignment r%d: %s pose, %dx%d, gain %.3f, LUT %s", a.revision, a.pose_kind, *size, a.gain,
                 "yes" if a.lut is not None else "identity")
        self._send_stats()
        # what is on screen now follows the new assignment at once
        if self._current is not None:
            try:
                self._render(renderer, self._current)
            except ValueError as exc:
                log.error("cannot re-render the current frame with the new assignment: %s", exc)
                renderer.render(None)
            out.prepare(renderer)
            out.swap()

    def _on_content(self, renderer, out, msg: tuple[str, common_pb2.Image]) -> None:
        cid, image = msg
        if renderer.has(cid):
            return
        try:
            img = codec.decode_image(image)
        except codec.ImageCodecError as exc:
            log.error("content %s is malformed: %s", cid, exc)
            return
        renderer.upload(cid, img)

    def _on_evict(self, renderer, out, ids: list[str]) -> None:
        for cid in ids:
            if self._current is not None and self._current.content_id == cid:
                self._evicted.add(cid)   # still on screen: forget once replaced
            else:
                renderer.forget(cid)

    def _on_reset(self, renderer, out, _payload) -> None:
        """A new coordinator instance: frame ids restart their ordering."""
        self._last_frame_id = 0

    def _drop(self, frame: FrameOrder, reason: int, late_by: int = 0) -> None:
        if _DEBUG_TIMING:
            log.info("timing frame %d: dropped (reason %d) %.3f ms late", frame.frame_id, reason, late_by / 1e6)
        if reason == node_pb2.DROP_REASON_LATE:
            self.stats.late += 1
        else:
            self.stats.dropped += 1
        self.report("drop", node_pb2.FrameDrop(frame_id=frame.frame_id, reason=reason, late_by_ns=late_by))
        self._send_stats()

    def _render(self, renderer, frame: FrameOrder) -> None:
        t = time.perf_counter()
        renderer.render(frame.content_id or None, space=frame.space, apply_lut=frame.apply_lut)
        self._render_ms.append((time.perf_counter() - t) * 1e3)

    def _on_frame(self, renderer, out: Output, frame: FrameOrder) -> None:
        if frame.frame_id <= self._last_frame_id:
            self._drop(frame, node_pb2.DROP_REASON_SUPERSEDED)
            return
        est = self.estimate
        if est is None:
            self._drop(frame, node_pb2.DROP_REASON_LATE)
            return
        deadline = est.local_time(frame.pts_ns)
        late_by = self.clock.now() - deadline
        if _DEBUG_TIMING:
            log.info("timing: frame %d reached the presenter %.1f ms before its deadline", frame.frame_id, -late_by / 1e6)
        if late_by > LATE_TOLERANCE_NS:
            self._drop(frame, node_pb2.DROP_REASON_LATE, late_by)
            return
        if frame.content_id and not renderer.has(frame.content_id):
            self._drop(frame, node_pb2.DROP_REASON_MISSING_CONTENT)
            return
        try:
            self._render(renderer, frame)
        except ValueError as exc:   # the renderer refuses what it cannot show correctly
            log.error("cannot show frame %d: %s", frame.frame_id, exc)
            self._drop(frame, node_pb2.DROP_REASON_UNRENDERABLE)
            return
        out.prepare(renderer)
        self._ctx.finish()   # the frame must be complete in the back buffer before its time comes
        deadline = est.local_time(frame.pts_ns)
        late_by = self.clock.now() - deadline
        if late_by > LATE_TOLERANCE_NS:
            self._drop(frame, node_pb2.DROP_REASON_LATE, late_by)
            return
        with self._rt:
            self.clock.sleep_until(deadline)
            out.swap()
            host = self.clock.host_now()
        if _DEBUG_TIMING:
            log.info("timing frame %d: swap %.3f ms after deadline", frame.frame_id,
                     (host - self.clock.to_host(deadline)) / 1e6)
        swap_rig = est.rig_time(self.clock.from_host(host))
        previous = self._current
        self._current = frame
        self._last_frame_id = frame.frame_id
        self.stats.shown += 1
        self.report("swap", node_pb2.SwapReport(frame_id=frame.frame_id, pts_ns=frame.pts_ns, swap_rig_ns=swap_rig,
                                                host_monotonic_ns=host))
        out.after_swap(renderer, SwapInfo(slot=self.slot, frame_id=frame.frame_id, tag=frame.tag, pts_ns=frame.pts_ns,
                                          swap_rig_ns=swap_rig, host_monotonic_ns=host))
        if previous is not None and previous.content_id in self._evicted and previous.content_id != frame.content_id:
            renderer.forget(previous.content_id)
            self._evicted.discard(previous.content_id)
        self._send_stats()


def tune_process() -> None:
    """Let sleeps end close to their deadline (1 µs timer slack)."""
    from node.clock import precise_timers

    precise_timers()


def presenter_main(conn_in, conn_out, settings: PresenterSettings) -> None:
    """Entry point of the presenter process."""
    import signal

    signal.signal(signal.SIGINT, signal.SIG_IGN)   # the node process decides when we stop
    logging.basicConfig(level=settings.log_level, format=settings.log_format, stream=sys.stderr, force=True)
    tune_process()
    clock = LocalClock(offset_ns=settings.clock_offset_ns, drift_ppm=settings.clock_drift_ppm,
                       anchor_ns=settings.clock_anchor_ns)

    def report(kind: str, payload) -> None:
        if isinstance(payload, (node_pb2.SwapReport, node_pb2.FrameDrop)):
            payload = payload.SerializeToString()
        conn_out.send((kind, payload))

    try:
        out = open_output(settings.output_spec, slot=settings.slot, snapshot_dir=settings.snapshot_dir)
        p = Presenter(slot=settings.slot, output=out, clock=clock, report=report, realtime=settings.realtime)
        p.open()
    except Exception as exc:
        log.exception("cannot open output %r", settings.output_spec)
        conn_out.send(("failed", f"{type(exc).__name__}: {exc}"))
        return
    conn_out.send(("ready", p.native_size))
    try:
        while True:
            if not conn_in.poll(0.5):
                p.idle()
                continue
            try:
                kind, payload = conn_in.recv()
            except EOFError:   # the node process is gone
                break
            if kind == "stop":
                break
            p.handle(kind, payload)
    except Exception as exc:
        log.exception("presenter failed")
        try:
            conn_out.send(("failed", f"{type(exc).__name__}: {exc}"))
        except OSError:
            pass
    finally:
        p.close()


def _grow_pipe(fd: int, want: int = 8 * 2**20) -> None:
    """Make a pipe's kernel buffer as large as allowed (default 64 KiB holds one small frame)."""
    try:
        import fcntl

        limit = int(Path("/proc/sys/fs/pipe-max-size").read_text())
        F_SETPIPE_SZ = getattr(fcntl, "F_SETPIPE_SZ", 1031)
        fcntl.fcntl(fd, F_SETPIPE_SZ, min(want, limit) if os.geteuid() else want)
    except (OSError, ValueError, ImportError):  # pragma: no cover - not Linux, or not permitted
        pass


class PresenterProcess:
    """The node process's handle on its presenter process.

    :meth:`submit` writes to a pipe with a large kernel buffer (no thread, so no
    GIL contention in the node process); reports arrive on the event loop
    through :meth:`attach`.
    """

    def __init__(self, settings: PresenterSettings):
        ctx = multiprocessing.get_context("spawn")
        child_in, self._to_child = ctx.Pipe(duplex=False)      # (reader, writer)
        self._from_child, child_out = ctx.Pipe(duplex=False)
        self._process = ctx.Process(target=presenter_main, args=(child_in, child_out, settings),
                                    name=f"presenter-{settings.slot}", daemon=True)
        self._child_ends = (child_in, child_out)
        _grow_pipe(self._to_child.fileno())
        self.native_size: tuple[int, int] | None = None
        self.failed: str | None = None
        self.stats: dict = {"shown": 0, "late": 0, "dropped": 0, "render_ms_p50": 0.0, "revision": 0}
        self._ready = threading.Event()
        self._on_report: Callable[[object], None] | None = None

    def start(self) -> None:
        self._process.start()
        for end in self._child_ends:
            end.close()

    def submit(self, kind: str, payload=None) -> None:
        """Send to the presenter. The pipe is grown to megabytes so this does not block
        for frames; a very large still may wait while the presenter reads it."""
        try:
            self._to_child.send((kind, payload))
        except (OSError, ValueError):   # the presenter is gone; the node notices and exits
            self.failed = self.failed or "the presenter process exited"

    def attach(self, loop, on_report: Callable[[object], None]) -> None:
        """Deliver swap/drop reports (as protobuf messages) to ``on_report`` on ``loop``."""
        self._on_report = on_report
        loop.add_reader(self._from_child.fileno(), self._readable)

    def detach(self, loop) -> None:
        try:
            loop.remove_reader(self._from_child.fileno())
        except (ValueError, OSError):
            pass

    def _readable(self) -> None:
        while self._from_child.poll():
            try:
                kind, payload = self._from_child.recv()
            except (EOFError, OSError):
                self.failed = self.failed or "the presenter process exited"
                self._ready.set()
                return
            self._dispatch(kind, payload)

    def _dispatch(self, kind: str, payload) -> None:
        if kind == "ready":
            self.native_size = tuple(payload) if payload else None
            self._ready.set()
        elif kind == "failed":
            self.failed = payload
            self._ready.set()
        elif kind == "stats":
            self.stats = payload
        elif kind == "swap" and self._on_report:
            self._on_report(node_pb2.SwapReport.FromString(payload))
        elif kind == "drop" and self._on_report:
            self._on_report(node_pb2.FrameDrop.FromString(payload))

    def wait_ready(self, timeout: float = 60.0) -> bool:
        """Block until the presenter reports ready or failed (reads the pipe itself)."""
        deadline = time.monotonic() + timeout
        while not self._ready.is_set() and time.monotonic() < deadline:
            if self._from_child.poll(0.1):
                self._readable()
            elif not self._process.is_alive():
                self.failed = self.failed or f"the presenter process exited with {self._process.exitcode}"
                break
        return self._ready.is_set() and self.failed is None

    def is_alive(self) -> bool:
        return self._process.is_alive() and self.failed is None

    def stop(self, timeout: float = 5.0) -> None:
        self.submit("stop")
        self._process.join(timeout)
        if self._process.is_alive():
            self._process.terminate()
            self._process.join(2.0)
        self._to_child.close()
        self._from_child.close()
