"""The virtual-room output: render offscreen and send every swapped frame to ``shadowless room``.

``--output room://HOST:PORT`` makes a node's projector the room's projector of
the same slot. The node renders into an offscreen EGL context at the size the
room reports for the slot; after each swap the frame is read back and queued,
and a background thread streams it to the room (``Room.Display``) with its swap
instants. The presenter is never held up: the queue is bounded and, if the room
is slow or away, the oldest frames are dropped and counted. The stream is
reopened whenever the room restarts.

The pixels themselves do not cross the socket when they need not: each frame is copied into a ring
of buffers in shared memory (:mod:`node.outputs.frame_ring`) and the message says where it lies;
the room copies it out on arrival. Sent inline, a 320×200 frame cost the node 1.2 ms and the room
0.9 ms of CPU, on the one host that runs the whole rig. A room that cannot open the memory (on
another host, another user's, or an older room) ends the stream with FAILED_PRECONDITION, and the
output sends its frames inline from then on (``share_frames=False`` does so from the start).

This output is a gRPC client of the room's service, so it is a link module by name: with
:mod:`node.wire` and :mod:`node.link`, one of the node's three modules that use protobuf messages
and the only others that import grpc.
"""
from __future__ import annotations

import collections
import logging
import threading
import time
from pathlib import Path
from typing import TYPE_CHECKING, Any

import grpc
import numpy as np

from node.outputs.frame_ring import FrameRing
from node.outputs.base import (
    Output,
    OutputError,
    SwapInfo,
    check_slot,
    headless_context,
    parse_room_spec,
    wants_snapshot,
    write_snapshot,
)
from protos import codec, room_pb2, room_pb2_grpc
from protos.version import GRPC_OPTIONS

if TYPE_CHECKING:  # pragma: no cover
    import moderngl

    from node.render.renderer import Renderer

log = logging.getLogger(__name__)

__all__ = ["RoomOutput", "parse_room_spec"]


class RoomOutput(Output):
    """Frames go to the virtual room.

    Parameters
    ----------
    spec : str
        ``room://HOST:PORT``.
    slot : str
        The node's slot, i.e. which of the room's projectors this node drives.
    snapshot_dir : Path, optional
        As for the offscreen output: ``show`` frames are also written as PNG + JSON.
    queue_size : int
        Frames waiting to be sent; beyond it the oldest is dropped (:attr:`frames_dropped`).
    connect_timeout : float
        How long :meth:`native_size` keeps trying to reach the room (it may still be starting).
    share_frames : bool
        Leave the pixels in shared memory for the room (the default, where the system can); False
        sends them inline in every message.
    """

    kind = "room"

    def __init__(self, spec: str, *, slot: str, snapshot_dir: Path | None = None, queue_size: int = 4, connect_timeout: float = 10.0,
                 share_frames: bool = True) -> None:
        self.slot = check_slot(slot)
        self.address = parse_room_spec(spec)
        self.snapshot_dir = Path(snapshot_dir) if snapshot_dir is not None else None
        self.connect_timeout = connect_timeout
        self._ctx: Any = None
        self._queue: collections.deque = collections.deque()
        self._queue_size = max(1, int(queue_size))
        self._cond = threading.Condition()
        self._stop = False
        self._thread: threading.Thread | None = None
        self._inflight: tuple | None = None
        self._channel = None
        self._stub = None
        #: counters (read them from any thread)
        self.frames_queued = 0
        self.frames_sent = 0
        self.frames_dropped = 0
        self.streams_opened = 0
        self.last_error: str | None = None
        #: frames left in shared memory (None: sent inline); the presenter thread writes it
        self._ring: FrameRing | None = None
        self._share = bool(share_frames) and FrameRing.available()
        self._last: tuple | None = None      # the last frame queued: (image or None, ref or None, info)

    # ---------------------------------------------------------------- connection

    def _ensure_channel(self):
        if self._stub is None:
            options = [*GRPC_OPTIONS, ("grpc.initial_reconnect_backoff_ms", 100), ("grpc.max_reconnect_backoff_ms", 1000)]
            self._channel = grpc.insecure_channel(self.address, options=options)
            self._stub = room_pb2_grpc.RoomStub(self._channel)
        return self._stub

    # ---------------------------------------------------------------- Output

    def make_context(self) -> "moderngl.Context":
        if self._ctx is None:
            self._ctx = headless_context()
        return self._ctx

    def native_size(self) -> tuple[int, int]:
        """The room's resolution for this slot (asks the room; retries while it starts up)."""
        stub = self._ensure_channel()
        deadline = time.monotonic() + self.connect_timeout
        while True:
            try:
                d = stub.DescribeProjector(room_pb2.DescribeProjectorRequest(slot=self.slot), timeout=max(0.5, min(5.0, deadline - time.monotonic())))
                return int(d.width), int(d.height)
            except grpc.RpcError as exc:
                code = exc.code()
                if code == grpc.StatusCode.NOT_FOUND:
                    raise OutputError(f"the room at {self.address} has no projector for slot {self.slot!r}: {exc.details()}") from None
                if time.monotonic() >= deadline or code not in (grpc.StatusCode.UNAVAILABLE, grpc.StatusCode.DEADLINE_EXCEEDED):
                    raise OutputError(
                        f"cannot reach the virtual room at {self.address} ({code.name}: {exc.details()}); "
                        "start it with `shadowless room` or fix --output room://HOST:PORT"
                    ) from None
                time.sleep(0.2)

    @property
    def shares_frames(self) -> bool:
        """Whether frames go to the room through shared memory (False: inline, from now on)."""
        return self._share

    @property
    def last_image(self) -> np.ndarray | None:
        """A copy of the last frame handed to the room ((h, w, 3) uint8), None before any (or once
        its shared buffer was written again, which takes several newer frames)."""
        last = self._last
        if last is None:
            return None
        image, ref, _ = last
        if image is not None:
            return image.copy()
        ring = self._ring
        return None if ring is None or ref is None else ring.read(ref.offset, ref.seq)

    def after_swap(self, renderer: "Renderer", info: SwapInfo) -> None:
        frame = renderer.read()  # (h, w, 3) uint8, the renderer's own buffer (reused)
        if self.snapshot_dir is not None and wants_snapshot(info):
            try:
                write_snapshot(self.snapshot_dir, frame, info)
            except OSError as exc:
                log.warning("cannot write the snapshot of frame %d to %s: %s", info.frame_id, self.snapshot_dir, exc)
        if self._share:
            try:
                ref = self._share_frame(frame)
            except (OSError, ValueError) as exc:
                log.warning("cannot share frames with the room through memory (%s); sending them inline", exc)
                self._share = False
            else:
                self._enqueue(None, ref, info)
                return
        self._enqueue(np.array(frame, dtype=np.uint8, copy=True), None, info)

    def _share_frame(self, frame: np.ndarray):
        """Copy ``frame`` into the ring (made, or made again at a new size, here); its SharedFrame."""
        ring = self._ring
        if ring is None or ring.shape != frame.shape:
            ring = FrameRing(frame.shape, label=self.slot)
            old, self._ring = self._ring, ring
            if old is not None:
                old.close()   # the room keeps its own mapping; frames queued in it no longer match
        offset, seq = ring.write(np.asarray(frame, dtype=np.uint8))
        h, w = frame.shape[:2]
        return room_pb2.SharedFrame(pid=ring.pid, fd=ring.fd, offset=offset, seq=seq, width=w, height=h)

    def send(self, image: np.ndarray, info: SwapInfo) -> None:
        """Queue a frame ((h, w, 3) uint8, kept as given) for the room inline, without waiting
        (drops the oldest if the queue is full)."""
        self._enqueue(image, None, info)

    def _enqueue(self, image: np.ndarray | None, ref, info: SwapInfo) -> None:
        with self._cond:
            if len(self._queue) >= self._queue_size:
                self._queue.popleft()
                self.frames_dropped += 1
            self._last = (image, ref, info)
            self._queue.append((image, ref, info))
            self.frames_queued += 1
            self._cond.notify_all()
        if self._thread is None:
            self._start_sender()

    def flush(self, timeout: float = 5.0) -> bool:
        """Wait until the queue is empty (sent or dropped); True if it emptied in time."""
        deadline = time.monotonic() + timeout
        with self._cond:
            while self._queue:
                left = deadline - time.monotonic()
                if left <= 0:
                    return False
                self._cond.wait(min(left, 0.05))
        return True

    def close(self) -> None:
        with self._cond:
            self._stop = True
            self._cond.notify_all()
        if self._thread is not None:
            self._thread.join(timeout=10)
            self._thread = None
        if self._channel is not None:
            self._channel.close()
            self._channel = None
            self._stub = None
        if self._ctx is not None:
            self._ctx.release()
            self._ctx = None
        if self._ring is not None:
            self._ring.close()
            self._ring = None

    # ---------------------------------------------------------------- sender thread

    def _start_sender(self) -> None:
        self._ensure_channel()
        self._thread = threading.Thread(target=self._run, name=f"room-output-{self.slot}", daemon=True)
        self._thread.start()

    def _messages(self, done: threading.Event):
        while True:
            with self._cond:
                while not self._queue and not self._stop and not done.is_set():
                    self._cond.wait(0.1)
                if (self._stop and not self._queue) or done.is_set():
                    return
                image, ref, info = self._queue.popleft()
                if ref is not None and not self._share:     # queued just as the room refused shared memory
                    image = None if self._ring is None else self._ring.read(ref.offset, ref.seq)
                    if image is None:
                        self.frames_dropped += 1
                        continue
                    ref = None
                self._inflight = (image, ref, info)
                self._cond.notify_all()
            msg = room_pb2.DisplayedFrame(
                slot=info.slot or self.slot,
                frame_id=info.frame_id,
                swap_rig_ns=info.swap_rig_ns,
                host_monotonic_ns=info.host_monotonic_ns,
                tag=info.tag,
            )
            if ref is not None:
                msg.shared.CopyFrom(ref)
            else:
                msg.image.CopyFrom(codec.encode_image(image))
            self.frames_sent += 1  # handed to grpc (a frame in flight when the room goes away is lost)
            yield msg

    def _run(self) -> None:
        backoff = 0.1
        while True:
            with self._cond:
                if self._stop and not self._queue:
                    return
                while not self._queue and not self._stop:
                    self._cond.wait(0.1)
                if self._stop and not self._queue:
                    return
            done = threading.Event()
            try:
                self.streams_opened += 1
                self._stub.Display(self._messages(done))
                backoff = 0.1
            except grpc.RpcError as exc:
                done.set()  # first: the broken stream's generator must take no more frames
                code = exc.code()
                self.last_error = f"{code.name}: {exc.details()}"
                refused = code in (grpc.StatusCode.INVALID_ARGUMENT, grpc.StatusCode.NOT_FOUND)
                if code == grpc.StatusCode.FAILED_PRECONDITION and self._share:
                    log.info("the room at %s cannot read %s's frames from shared memory (%s); sending them inline",
                             self.address, self.slot, exc.details())
                    self._unshare()
                    continue
                if refused:
                    log.error("the room at %s refuses %s's frames: %s", self.address, self.slot, exc.details())
                else:
                    log.info("room stream for %s ended (%s); reconnecting", self.slot, self.last_error)
                with self._cond:
                    # The projector must end up showing the newest frame: if the stream broke with it
                    # in flight and nothing newer is waiting, send it again on the next stream.
                    if self._inflight is not None and not self._queue and not self._stop and not refused:
                        self._queue.append(self._inflight)
                    self._inflight = None
                    if self._stop:
                        self.frames_dropped += len(self._queue)
                        self._queue.clear()
                        return
                    self._cond.wait(backoff)
                backoff = min(2.0, backoff * 2)
            finally:
                done.set()

    def _unshare(self) -> None:
        """From now on send frames inline: those queued (and the one in flight) are read out of the
        ring, or dropped if newer frames overwrote them."""
        self._share = False
        with self._cond:
            entries = ([self._inflight] if self._inflight is not None else []) + list(self._queue)
            self._inflight = None
            self._queue.clear()
            ring = self._ring
            for image, ref, info in entries[-self._queue_size:]:
                if ref is not None:
                    image = None if ring is None else ring.read(ref.offset, ref.seq)
                    if image is None:
                        self.frames_dropped += 1
                        continue
                self._queue.append((image, None, info))
            last = self._last
            if last is not None and last[1] is not None:
                self._last = (None if ring is None else ring.read(last[1].offset, last[1].seq), None, last[2])
            self._cond.notify_all()
