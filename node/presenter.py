"""The presenter: the one thread that owns the node's GL context.

It takes assignments, content and frames in arrival order from a queue,
renders each frame into the back buffer as soon as it arrives, waits until the
frame's presentation time on its estimate of the rig clock, swaps, and reports
the swap. A frame whose time has passed is dropped and counted, never shown
late; a frame older than the one on screen is never shown (no reordering).
"""
from __future__ import annotations

import logging
import os
import queue
import sys
import threading
import time
from collections import deque
from dataclasses import dataclass
from pathlib import Path
from typing import Callable

import numpy as np

from node.clock import ClockEstimator, LocalClock
from node.outputs import Output, SwapInfo, open_output
from node.wire import FrameOrder, NodeAssignment
from protos import codec, common_pb2, node_pb2

log = logging.getLogger(__name__)

#: log each swap's distance from its deadline (diagnostics)
_DEBUG_TIMING = bool(os.environ.get("SHADOWLESS_DEBUG_TIMING"))
#: a frame may be shown this late (ns) before it counts as late and is dropped
LATE_TOLERANCE_NS = 500_000
#: wake this long before the deadline, then sleep the rest precisely
COARSE_WAKE_NS = 2_000_000


class RealtimeWindow:
    """Run the last sleep and the swap at real-time priority (SCHED_FIFO), the rest normally.

    A projector's swap is a real-time deadline: when a dozen nodes share a small
    machine, or a node's other threads are busy, a normal thread that wakes on
    time may still wait for a CPU. Only the short wake-swap-timestamp window is
    real-time, so the thread never renders at that priority and cannot starve
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


class Presenter(threading.Thread):
    """Drives an :class:`~node.outputs.Output` and a renderer from one thread.

    ``report`` is called (from this thread) with a ``node_pb2.SwapReport`` for
    every swap and a ``node_pb2.FrameDrop`` for every drop; it must be
    thread-safe and must not block.
    """

    def __init__(self, *, slot: str, output_spec: str, clock: LocalClock, estimator: ClockEstimator,
                 report: Callable[[node_pb2.SwapReport | node_pb2.FrameDrop], None], snapshot_dir: Path | None = None,
                 output: Output | None = None, realtime: bool = True):
        super().__init__(name=f"presenter-{slot}", daemon=True)
        self.slot = slot
        self.clock = clock
        self.estimator = estimator
        self.report = report
        self.output_spec = output_spec
        self.snapshot_dir = snapshot_dir
        self._output = output
        self._realtime_wanted = realtime
        self.inbox: queue.Queue = queue.Queue()
        self.stats = PresenterStats()
        self.assignment: NodeAssignment | None = None
        self.ready = threading.Event()
        self.failed: BaseException | None = None
        self.native_size: tuple[int, int] | None = None
        self._render_ms: deque[float] = deque(maxlen=120)
        self._last_frame_id = 0
        self._current: FrameOrder | None = None
        self._evicted: set[str] = set()
        self._halt = False

    # ---- called from other threads --------------------------------------
    def submit(self, kind: str, payload=None) -> None:
        self.inbox.put((kind, payload))

    def stop(self) -> None:
        self._halt = True
        self.inbox.put(("stop", None))

    def render_ms_p50(self) -> float:
        vals = list(self._render_ms)
        return float(np.median(vals)) if vals else 0.0

    # ---- the thread ---------------------------------------------------------
    def run(self) -> None:
        try:
            self._run()
        except BaseException as exc:  # reported to the app, which exits non-zero
            self.failed = exc
            log.exception("presenter failed")
            self.ready.set()

    def _run(self) -> None:
        from node.render.renderer import Renderer

        out = self._output or open_output(self.output_spec, slot=self.slot, snapshot_dir=self.snapshot_dir)
        self._output = out
        ctx = out.make_context()
        self._ctx = ctx
        size = out.native_size()
        self.native_size = size
        w, h = size or (640, 360)
        renderer = Renderer(ctx, w, h)
        self.renderer = renderer
        self._rt = RealtimeWindow(self._realtime_wanted)
        renderer.render(None)
        out.prepare(renderer)
        out.swap()
        self.ready.set()
        try:
            while not self._halt:
                try:
                    kind, payload = self.inbox.get(timeout=0.5)
                except queue.Empty:
                    out.poll()   # a window keeps handling its events between frames
                    continue
                if kind == "stop":
                    break
                handler = getattr(self, "_on_" + kind)
                handler(renderer, out, payload)
        finally:
            renderer.release()
            out.close()

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
        # what is on screen now follows the new assignment at once
        if self._current is not None:
            try:
                self._render(renderer, self._current)
            except ValueError as exc:
                log.error("cannot re-render the current frame with the new assignment: %s", exc)
                renderer.render(None)
            out.prepare(renderer)
            out.swap()

    def _on_content(self, renderer, out, msg: common_pb2.Image | tuple[str, common_pb2.Image]) -> None:
        cid, image_msg = msg
        if renderer.has(cid):
            return
        try:
            img = codec.decode_image(image_msg)
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
        if reason == node_pb2.DROP_REASON_LATE:
            self.stats.late += 1
        else:
            self.stats.dropped += 1
        self.report(node_pb2.FrameDrop(frame_id=frame.frame_id, reason=reason, late_by_ns=late_by))

    def _render(self, renderer, frame: FrameOrder) -> None:
        t = time.perf_counter()
        renderer.render(frame.content_id or None, space=frame.space, apply_lut=frame.apply_lut)
        self._render_ms.append((time.perf_counter() - t) * 1e3)

    def _on_frame(self, renderer, out: Output, frame: FrameOrder) -> None:
        if frame.frame_id <= self._last_frame_id:
            self._drop(frame, node_pb2.DROP_REASON_SUPERSEDED)
            return
        est = self.estimator.estimate
        if est is None:
            self._drop(frame, node_pb2.DROP_REASON_LATE)
            return
        deadline = est.local_time(frame.pts_ns)
        late_by = self.clock.now() - deadline
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
        # sleep coarsely, then re-read the estimate (it may have been refined) and land on the deadline
        if deadline - self.clock.now() > COARSE_WAKE_NS:
            self.clock.sleep_until(deadline - COARSE_WAKE_NS)
            est = self.estimator.estimate or est
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
        self.report(node_pb2.SwapReport(frame_id=frame.frame_id, pts_ns=frame.pts_ns, swap_rig_ns=swap_rig,
                                        host_monotonic_ns=host))
        out.after_swap(renderer, SwapInfo(slot=self.slot, frame_id=frame.frame_id, tag=frame.tag, pts_ns=frame.pts_ns,
                                          swap_rig_ns=swap_rig, host_monotonic_ns=host))
        if previous is not None and previous.content_id in self._evicted and previous.content_id != frame.content_id:
            renderer.forget(previous.content_id)
            self._evicted.discard(previous.content_id)


def tune_interpreter() -> None:
    """Let the presenter thread take the GIL back quickly when its deadline comes,
    and let its sleeps end close to the deadline."""
    from node.clock import precise_timers

    sys.setswitchinterval(0.0005)
    precise_timers()
