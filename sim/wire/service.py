"""The room as gRPC services on one port (grpc.aio): ``Room`` for nodes and the coordinator,
``RoomTruth`` for tests and benchmarks, plus the standard health and reflection services.

Frames that nodes stream in are validated on arrival and handed to the
:class:`~sim.room.Room` by the capture worker (one thread owns all room work),
so the event loop never waits for a capture in progress.

Use :class:`RoomServer` inside an event loop, or :class:`RoomServerThread` to
run one in the background of synchronous code (tests, demo wiring).
"""
from __future__ import annotations

import asyncio
import concurrent.futures
import logging
import threading
import time
from dataclasses import dataclass
from typing import Callable

import grpc
import numpy as np
from grpc_health.v1 import health, health_pb2, health_pb2_grpc
from grpc_reflection.v1alpha import reflection

from protos import codec, room_pb2, room_pb2_grpc
from protos.version import SERVER_GRPC_OPTIONS
from sim.wire import messages as wire
from sim.errors import FrameError, SharedFrameUnavailable, SimError, UnknownSlotError
from sim.occluders import flatten
from sim.room import Room
from sim.wire.shared_frames import SharedFrames

log = logging.getLogger(__name__)

#: Default port of ``shadowless room``.
DEFAULT_PORT = 50070

#: Default wait of a Capture for late frames.
DEFAULT_CAPTURE_TIMEOUT_MS = 2000

#: A node without an open stream still counts as streaming this long after its last frame (s).
RECENT_S = 10.0

#: What a projector shows once no Display stream feeds it any more (its node died or stopped: a
#: node streams for as long as it runs): "keep" its last frame (the default, as the room always
#: did), or "black" (input 0, as a projector that lost its source; its black level stays). With
#: "black", frames sent by a one-shot stream (:meth:`sim.link.RoomClient.display`) go black as soon
#: as it ends: keep a stream open (a node) for as long as its frames are to be seen. A killed
#: process's stream ends as a clean one does, so the two cannot be told apart.
NO_SIGNAL = ("keep", "black")


@dataclass(frozen=True)
class _Shown:
    frame_id: int
    swap_rig_ns: int
    host_monotonic_ns: int
    tag: str


def _code_for(exc: BaseException) -> grpc.StatusCode:
    if isinstance(exc, UnknownSlotError):
        return grpc.StatusCode.NOT_FOUND
    if isinstance(exc, SharedFrameUnavailable):
        return grpc.StatusCode.FAILED_PRECONDITION
    if isinstance(exc, (FrameError, codec.ImageCodecError, ValueError, TypeError)):
        return grpc.StatusCode.INVALID_ARGUMENT
    return grpc.StatusCode.INTERNAL


class _Worker:
    """One thread that does all room work (captures, truth queries) in order."""

    def __init__(self) -> None:
        self._pool = concurrent.futures.ThreadPoolExecutor(max_workers=1, thread_name_prefix="room-worker")

    async def run(self, fn: Callable, *args):
        return await asyncio.get_running_loop().run_in_executor(self._pool, fn, *args)

    def close(self) -> None:
        self._pool.shutdown(wait=True, cancel_futures=True)


class RoomService(room_pb2_grpc.RoomServicer):
    """Projectors that show what nodes stream, and cameras that capture."""

    def __init__(self, room: Room, worker: _Worker, *, no_signal: str = "keep") -> None:
        if no_signal not in NO_SIGNAL:
            raise ValueError(f"no_signal must be one of {', '.join(NO_SIGNAL)}, got {no_signal!r}")
        self.room = room
        self._worker = worker
        self.no_signal = no_signal
        self._pending: dict[str, tuple[np.ndarray, _Shown]] = {}
        self._pending_lock = threading.Lock()
        self._latest: dict[str, _Shown] = {}  # what arrived (loop thread)
        self._shown: dict[str, _Shown] = {}  # what the room shows (worker thread)
        self._streams: dict[str, int] = {}
        self._arrived: dict[str, float] = {}  # slot -> monotonic s of its last frame
        self._changed: asyncio.Condition | None = None
        self.frames_received = 0
        #: of those, frames read from the node's shared memory, and those skipped there (overwritten)
        self.frames_shared = 0
        self.frames_overwritten = 0

    def _condition(self) -> asyncio.Condition:
        if self._changed is None:
            self._changed = asyncio.Condition()
        return self._changed

    # ---------------------------------------------------------------- helpers used by the worker

    def apply_pending(self) -> None:
        """Hand every frame that arrived since the last capture to the room (worker thread)."""
        with self._pending_lock:
            pending, self._pending = self._pending, {}
        for slot, (frame, shown) in pending.items():
            self.room.set_frame(slot, frame)
            self._shown[slot] = shown

    def streaming_slots(self) -> set[str]:
        """Slots whose node streams frames: an open Display stream, or a frame in the last :data:`RECENT_S` s."""
        now = time.monotonic()
        return {s for s, n in self._streams.items() if n > 0} | {s for s, t in self._arrived.items() if now - t < RECENT_S}

    # ---------------------------------------------------------------- RPCs

    async def DescribeProjector(self, request, context):
        try:
            spec = self.room.projector(request.slot)
        except UnknownSlotError as exc:
            await context.abort(grpc.StatusCode.NOT_FOUND, str(exc))
        w, h = spec.size
        return room_pb2.ProjectorDescription(slot=spec.slot, width=w, height=h, powered=spec.slot in self.room.active)

    async def DescribeRoom(self, request, context):
        room = self.room
        active = set(room.active)
        scene = room.scene
        projectors = [
            room_pb2.ProjectorDescription(slot=s, width=room.projector_size(s)[0], height=room.projector_size(s)[1], powered=s in active)
            for s in room.slots + [s for s in room.all_slots if s not in room.slots]
        ]
        cameras = [
            room_pb2.CameraDescription(index=i, name=c.name, width=c.size[0], height=c.size[1], bits=c.sensor.bits) for i, c in enumerate(scene.cameras)
        ]
        surface = "+".join(k for k, present in (("table", scene.table is not None), ("mesh", scene.mesh is not None)) if present)
        return room_pb2.RoomDescription(name=scene.name, projectors=projectors, rig_slots=room.slots, cameras=cameras, surface=surface)

    async def Display(self, request_iterator, context):
        accepted = 0
        opened: set[str] = set()
        cond = self._condition()
        shared = SharedFrames()
        try:
            async for msg in request_iterator:
                try:
                    spec = self.room.projector(msg.slot)
                    if msg.HasField("shared"):
                        image = shared.read(msg.shared, spec.size)
                        if image is None:     # overwritten by a newer frame before it was read: that one follows
                            self.frames_overwritten += 1
                            continue
                        self.frames_shared += 1
                    else:
                        image = codec.decode_image(msg.image)
                    w, h = spec.size
                    if image.dtype != np.uint8 or image.shape[2] not in (1, 3):
                        raise FrameError(f"frame {msg.frame_id} for {msg.slot} must be uint8 RGB input values, got {image.shape[2]} channels of {image.dtype}")
                    if image.shape[:2] != (h, w):
                        raise FrameError(
                            f"frame {msg.frame_id} for {msg.slot} is {image.shape[1]}x{image.shape[0]}, but the room's "
                            f"projector {msg.slot} takes {w}x{h}: render at the size DescribeProjector reports"
                        )
                except (SimError, codec.ImageCodecError) as exc:
                    await context.abort(_code_for(exc), str(exc))
                if image.shape[2] == 1:
                    image = np.repeat(image, 3, axis=2)
                if msg.slot not in opened:
                    opened.add(msg.slot)
                    self._streams[msg.slot] = self._streams.get(msg.slot, 0) + 1
                shown = _Shown(msg.frame_id, msg.swap_rig_ns, msg.host_monotonic_ns, msg.tag)
                with self._pending_lock:
                    self._pending[msg.slot] = (image, shown)
                self._latest[msg.slot] = shown
                self._arrived[msg.slot] = time.monotonic()
                accepted += 1
                self.frames_received += 1
                async with cond:
                    cond.notify_all()
        finally:
            shared.close()
            for slot in opened:
                self._streams[slot] -= 1
            if self.no_signal == "black":
                self._lose_signal([s for s in opened if self._streams[s] == 0])
        return room_pb2.DisplayAck(frames=accepted)

    def _lose_signal(self, slots: list[str]) -> None:
        """Show black on ``slots``, which no stream feeds any more (``no_signal="black"``)."""
        for slot in slots:
            w, h = self.room.projector_size(slot)
            last = self._latest.get(slot, _Shown(0, 0, 0, ""))
            with self._pending_lock:
                self._pending[slot] = (np.zeros((h, w, 3), np.uint8), _Shown(last.frame_id, last.swap_rig_ns, last.host_monotonic_ns, "no-signal"))
            log.info("room: no stream feeds %s any more; it shows black", slot)

    async def Capture(self, request, context):
        room = self.room
        try:
            cam = room.scene.camera(request.camera)
        except UnknownSlotError as exc:
            await context.abort(grpc.StatusCode.NOT_FOUND, str(exc))
        if request.exposure < 0:
            await context.abort(grpc.StatusCode.INVALID_ARGUMENT, f"exposure must be positive (relative, 1.0 = the camera's), got {request.exposure}")
        late: list[str] = []
        if request.not_before_rig_ns:
            late = await self._wait_for_frames(request.not_before_rig_ns, (request.timeout_ms or DEFAULT_CAPTURE_TIMEOUT_MS) / 1000.0)
        # relative to the camera's own exposure, as the room takes it in its own units
        exposure = float(request.exposure) * cam.exposure if request.exposure > 0 else None

        def job():
            self.apply_pending()
            image = room.capture(request.camera, exposure=exposure)
            stamp = time.monotonic_ns()
            used = [
                room_pb2.FrameUsed(slot=s, frame_id=self._shown[s].frame_id, swap_rig_ns=self._shown[s].swap_rig_ns)
                for s in room.active
                if s in self._shown
            ]
            return codec.encode_image(image, compress=request.compress), stamp, used

        try:
            msg, stamp, used = await self._worker.run(job)
        except SimError as exc:
            await context.abort(_code_for(exc), str(exc))
        return room_pb2.CaptureReply(image=msg, host_monotonic_ns=stamp, bits=cam.sensor.bits, frames=used, late_slots=late)

    async def _wait_for_frames(self, not_before: int, timeout: float) -> list[str]:
        """Wait until every powered, streaming projector swapped at or after ``not_before``; return the late ones."""
        cond = self._condition()

        def late() -> list[str]:
            streaming = self.streaming_slots()
            return [s for s in self.room.active if s in streaming and (s not in self._latest or self._latest[s].swap_rig_ns < not_before)]

        async with cond:
            try:    # not asyncio.wait_for: on 3.11 it drops a cancel (the call cancelled) that meets the frames
                async with asyncio.timeout(timeout):
                    await cond.wait_for(lambda: not late())
            except TimeoutError:
                pass
            return late()


class TruthService(room_pb2_grpc.RoomTruthServicer):
    """Ground truth and controls; for tests and benchmarks only."""

    def __init__(self, room: Room, worker: _Worker) -> None:
        self.room = room
        self._worker = worker

    async def _call(self, context, fn, *args):
        try:
            return await self._worker.run(fn, *args)
        except (SimError, ValueError, TypeError, codec.ImageCodecError) as exc:
            await context.abort(_code_for(exc), str(exc))

    async def GetProjectorTruth(self, request, context):
        def job():
            t = self.room.truth.projector(request.slot)
            return room_pb2.ProjectorTruth(
                slot=t.slot, k=t.K.ravel(), r=t.R.ravel(), t=t.t, p=t.P.ravel(), width=t.size[0], height=t.size[1],
                native_width=t.native_size[0], native_height=t.native_size[1], center=t.center, gamma=t.gamma, black=t.black,
                peak=t.peak, aperture_mm=t.aperture, focus_mm=t.focus, falloff=t.falloff, powered=t.slot in self.room.active,
                white=t.white, lamp=t.lamp, hotspot=t.hotspot, hotspot_width=t.hotspot_width,
                hotspot_center=list(t.hotspot_center), vignetting=t.vignetting,
            )

        return await self._call(context, job)

    async def GetCameraTruth(self, request, context):
        def job():
            c = self.room.truth.camera(request.camera)
            return room_pb2.CameraTruth(
                k=c.K.ravel(), r=c.R.ravel(), t=c.t, p=c.P.ravel(), width=c.size[0], height=c.size[1], center=c.center,
                gain=c.gain, exposure=c.exposure, full_well=c.sensor.full_well, read_noise=c.sensor.read_noise, bits=c.sensor.bits,
            )

        return await self._call(context, job)

    async def SetActive(self, request, context):
        def job():
            self.room.set_active(list(request.slots))
            return room_pb2.SetActiveReply(active=self.room.active)

        return await self._call(context, job)

    async def SetOccluders(self, request, context):
        def job():
            occ = wire.occluders_from_msg(request)
            self.room.set_occluders(occ)
            return room_pb2.SetOccludersReply(primitives=len(flatten(self.room.occluders())))

        return await self._call(context, job)

    async def SetLamp(self, request, context):
        def job():
            gain = list(request.gain)
            lamp = self.room.set_lamp(request.slot, gain[0] if len(gain) == 1 else gain)
            log.info("room: lamp of %s set to %s", request.slot, ", ".join(f"{v:g}" for v in lamp))
            return room_pb2.SetLampReply(slot=request.slot, lamp=lamp)

        return await self._call(context, job)

    async def GetContribution(self, request, context):
        return await self._call(context, lambda: room_pb2.TruthImage(image=codec.encode_image(self.room.truth.contribution(request.slot, request.camera))))

    async def GetLightDrop(self, request, context):
        return await self._call(context, lambda: room_pb2.TruthImage(image=codec.encode_image(self.room.truth.light_drop(request.camera))))

    async def GetOccluderMask(self, request, context):
        return await self._call(context, lambda: room_pb2.TruthImage(image=codec.encode_image(self.room.truth.occluder_mask(request.camera).astype(np.uint8))))

    async def GetProjectorCoordinates(self, request, context):
        return await self._call(context, lambda: room_pb2.TruthImage(image=codec.encode_image(self.room.truth.projector_coordinates(request.slot, request.camera))))

    async def GetTransport(self, request, context):
        return await self._call(context, lambda: wire.sparse_to_msg(self.room.truth.transport(request.slot, request.camera)))


class RoomServer:
    """The room's gRPC server (grpc.aio).

    Parameters
    ----------
    room : Room
    host : str
        Address to bind; 127.0.0.1 by default (the room is a local instrument).
    port : int
        0 picks a free port (see :attr:`port` after :meth:`start`).
    truth : bool
        Also serve ``RoomTruth`` (ground truth and hand control).
    no_signal : "keep" or "black"
        What a projector shows when its node's stream breaks off (:data:`NO_SIGNAL`).
    """

    def __init__(self, room: Room, *, host: str = "127.0.0.1", port: int = DEFAULT_PORT, truth: bool = True, no_signal: str = "keep") -> None:
        if no_signal not in NO_SIGNAL:
            raise ValueError(f"no_signal must be one of {', '.join(NO_SIGNAL)}, got {no_signal!r}")
        self.no_signal = no_signal
        self.room = room
        self.host = host
        self.requested_port = port
        self.truth = truth
        self.port: int | None = None
        self._server: grpc.aio.Server | None = None
        self._worker: _Worker | None = None
        self._health = None
        self.service: RoomService | None = None

    @property
    def address(self) -> str:
        return f"{self.host}:{self.port}"

    async def start(self) -> int:
        self._worker = _Worker()
        self._server = grpc.aio.server(options=SERVER_GRPC_OPTIONS)
        self.service = RoomService(self.room, self._worker, no_signal=self.no_signal)
        room_pb2_grpc.add_RoomServicer_to_server(self.service, self._server)
        names = [room_pb2.DESCRIPTOR.services_by_name["Room"].full_name]
        if self.truth:
            room_pb2_grpc.add_RoomTruthServicer_to_server(TruthService(self.room, self._worker), self._server)
            names.append(room_pb2.DESCRIPTOR.services_by_name["RoomTruth"].full_name)
        self._health = health.aio.HealthServicer()
        health_pb2_grpc.add_HealthServicer_to_server(self._health, self._server)
        reflection.enable_server_reflection([*names, health_pb2.DESCRIPTOR.services_by_name["Health"].full_name, reflection.SERVICE_NAME], self._server)
        try:
            port = self._server.add_insecure_port(f"{self.host}:{self.requested_port}")
        except RuntimeError as exc:
            raise SimError(f"cannot listen on {self.host}:{self.requested_port} ({exc}); is another room running? choose --port") from exc
        if port == 0:
            raise SimError(f"cannot listen on {self.host}:{self.requested_port}; is another room running? choose another --port")
        self.port = port
        await self._server.start()
        for name in [*names, ""]:
            await self._health.set(name, health_pb2.HealthCheckResponse.SERVING)
        return port

    async def stop(self, grace: float = 1.0) -> None:
        """Graceful shutdown: health NOT_SERVING, finish calls for ``grace`` seconds, stop the worker."""
        if self._health is not None:
            await self._health.enter_graceful_shutdown()
        if self._server is not None:
            await self._server.stop(grace)
            self._server = None
        if self._worker is not None:
            worker, self._worker = self._worker, None
            await asyncio.get_running_loop().run_in_executor(None, worker.close)

    async def wait_for_termination(self) -> None:
        if self._server is not None:
            await self._server.wait_for_termination()


class RoomServerThread:
    """A :class:`RoomServer` on its own event loop in a background thread (for synchronous code).

    ``with RoomServerThread(room) as server: ... server.address ...``
    """

    def __init__(self, room: Room, *, host: str = "127.0.0.1", port: int = 0, truth: bool = True, no_signal: str = "keep") -> None:
        self.server = RoomServer(room, host=host, port=port, truth=truth, no_signal=no_signal)
        self._loop: asyncio.AbstractEventLoop | None = None
        self._thread: threading.Thread | None = None

    @property
    def address(self) -> str:
        return self.server.address

    @property
    def port(self) -> int | None:
        return self.server.port

    def start(self) -> "RoomServerThread":
        ready = concurrent.futures.Future()

        def main() -> None:
            loop = asyncio.new_event_loop()
            self._loop = loop
            asyncio.set_event_loop(loop)
            try:
                loop.run_until_complete(self.server.start())
            except BaseException as exc:  # report start-up failures to the caller
                ready.set_exception(exc)
                loop.close()
                return
            ready.set_result(None)
            loop.run_forever()
            loop.run_until_complete(self.server.stop(0.5))
            loop.run_until_complete(loop.shutdown_asyncgens())
            loop.run_until_complete(loop.shutdown_default_executor())
            loop.close()

        self._thread = threading.Thread(target=main, name="room-server", daemon=True)
        self._thread.start()
        ready.result(timeout=30)
        return self

    def stop(self) -> None:
        if self._loop is not None and self._thread is not None and self._thread.is_alive():
            self._loop.call_soon_threadsafe(self._loop.stop)
            self._thread.join(timeout=30)
        self._thread = None

    def __enter__(self) -> "RoomServerThread":
        return self.start()

    def __exit__(self, *exc) -> None:
        self.stop()


async def serve(room: Room, *, host: str = "127.0.0.1", port: int = DEFAULT_PORT, truth: bool = True, on_ready: Callable[[RoomServer], None] | None = None, stop: asyncio.Event | None = None,
                no_signal: str = "keep") -> None:
    """Serve ``room`` until ``stop`` is set (or forever), then shut down gracefully."""
    server = RoomServer(room, host=host, port=port, truth=truth, no_signal=no_signal)
    await server.start()
    try:
        if on_ready is not None:
            on_ready(server)
        if stop is None:
            await server.wait_for_termination()
        else:
            await stop.wait()
    finally:
        await server.stop(1.0)
