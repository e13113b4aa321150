"""A synchronous client of a running room (``shadowless room``), for tests, benchmarks and the demo.

The coordinator does not use this module (nothing outside sim/ imports sim);
it speaks the ``Room`` service of ``protos/room.proto`` itself (:mod:`coordinator.wire.room_camera`).
"""
from __future__ import annotations

from dataclasses import dataclass

import grpc
import numpy as np
import scipy.sparse

from protos import codec, room_pb2, room_pb2_grpc
from protos.version import GRPC_OPTIONS
from sim.wire import messages as wire
from sim.errors import FrameError, SimError, UnknownSlotError
from sim.hand import HandPath


class RoomUnavailable(SimError, ConnectionError):
    """The room cannot be reached; the message names the address."""


@dataclass(frozen=True)
class Capture:
    """One capture: the image and which frame each projector showed."""

    image: np.ndarray  # (H, W, 3) float32
    host_monotonic_ns: int
    frames: dict[str, tuple[int, int]]  # slot -> (frame_id, swap_rig_ns)
    late_slots: list[str]


def _address(target: str) -> str:
    return target[len("room://") :] if target.startswith("room://") else target


class RoomClient:
    """Talks to a room at ``HOST:PORT`` (or ``room://HOST:PORT``)."""

    def __init__(self, address: str, *, timeout: float = 30.0) -> None:
        self.address = _address(address)
        self.timeout = timeout
        self._channel = grpc.insecure_channel(self.address, options=GRPC_OPTIONS)
        self._room = room_pb2_grpc.RoomStub(self._channel)
        self._truth = room_pb2_grpc.RoomTruthStub(self._channel)

    def close(self) -> None:
        self._channel.close()

    def __enter__(self) -> "RoomClient":
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def _call(self, fn, request, **kw):
        try:
            return fn(request, timeout=kw.pop("timeout", self.timeout), **kw)
        except grpc.RpcError as exc:
            code = exc.code()
            detail = exc.details() or str(code)
            if code == grpc.StatusCode.NOT_FOUND:
                raise UnknownSlotError(detail) from None
            if code == grpc.StatusCode.INVALID_ARGUMENT:
                raise FrameError(detail) from None
            if code in (grpc.StatusCode.UNAVAILABLE, grpc.StatusCode.DEADLINE_EXCEEDED):
                raise RoomUnavailable(f"the room at {self.address} does not answer ({detail}); is `shadowless room` running there?") from None
            raise SimError(f"room at {self.address}: {code.name}: {detail}") from None

    # ---------------------------------------------------------------- Room

    def wait_ready(self, timeout: float = 10.0) -> None:
        try:
            grpc.channel_ready_future(self._channel).result(timeout=timeout)
        except grpc.FutureTimeoutError:
            raise RoomUnavailable(f"no room answers at {self.address} within {timeout:.0f} s") from None

    def describe(self) -> room_pb2.RoomDescription:
        return self._call(self._room.DescribeRoom, room_pb2.DescribeRoomRequest())

    def projector_size(self, slot: str) -> tuple[int, int]:
        d = self._call(self._room.DescribeProjector, room_pb2.DescribeProjectorRequest(slot=slot))
        return d.width, d.height

    def display(self, frames: dict[str, np.ndarray], *, frame_id: int = 0, swap_rig_ns: int = 0) -> int:
        """Show ``frames`` (slot -> (h, w, 3) uint8) as one Display stream; returns the frames accepted."""
        msgs = [
            room_pb2.DisplayedFrame(slot=s, frame_id=frame_id, swap_rig_ns=swap_rig_ns, image=codec.encode_image(np.ascontiguousarray(f)))
            for s, f in frames.items()
        ]
        return self._call(self._room.Display, iter(msgs)).frames

    def capture(self, camera: int = 0, *, not_before_rig_ns: int = 0, timeout_ms: int = 0, exposure: float = 0.0) -> Capture:
        reply = self._call(
            self._room.Capture,
            room_pb2.CaptureRequest(camera=camera, not_before_rig_ns=not_before_rig_ns, timeout_ms=timeout_ms, exposure=exposure, compress=False),
        )
        return Capture(
            codec.decode_image(reply.image),
            reply.host_monotonic_ns,
            {f.slot: (f.frame_id, f.swap_rig_ns) for f in reply.frames},
            list(reply.late_slots),
        )

    # ---------------------------------------------------------------- RoomTruth

    def projector_truth(self, slot: str) -> room_pb2.ProjectorTruth:
        return self._call(self._truth.GetProjectorTruth, room_pb2.SlotRequest(slot=slot))

    def projector_matrix(self, slot: str) -> np.ndarray:
        """(3, 4) float64 world mm -> projector px."""
        return wire.matrix(self.projector_truth(slot).p, (3, 4))

    def camera_truth(self, camera: int = 0) -> room_pb2.CameraTruth:
        return self._call(self._truth.GetCameraTruth, room_pb2.CameraRequest(camera=camera))

    def set_active(self, slots: list[str]) -> list[str]:
        return list(self._call(self._truth.SetActive, room_pb2.SetActiveRequest(slots=slots)).active)

    def set_occluders(self, occluders=None, *, path: HandPath | None = None) -> int:
        """Place hands and boxes (or a moving hand); returns the number of primitives."""
        return self._call(self._truth.SetOccluders, wire.occluders_to_msg(occluders, path=path)).primitives

    def set_lamp(self, slot: str, gain) -> np.ndarray:
        """Dim or kill ``slot``'s lamp while its node keeps streaming (a bench switch).

        ``gain``: one number or three (r, g, b), each 0..1 (1 = as new, 0 = dead). Returns the
        lamp now, (3,) float64. An unknown slot raises UnknownSlotError, a bad gain FrameError
        (a ValueError); the lamp is then unchanged.
        """
        values = np.asarray(gain, np.float64).reshape(-1).tolist()
        reply = self._call(self._truth.SetLamp, room_pb2.SetLampRequest(slot=slot, gain=values))
        return np.asarray(list(reply.lamp), np.float64)

    def contribution(self, slot: str, camera: int = 0) -> np.ndarray:
        """(H, W, 3) float32: the signal ``slot`` alone adds at full white above its black (:meth:`sim.truth.Truth.contribution`)."""
        return codec.decode_image(self._call(self._truth.GetContribution, room_pb2.SlotRequest(slot=slot, camera=camera)).image)

    def light_drop(self, camera: int = 0) -> np.ndarray:
        """(H, W) float32."""
        return codec.decode_image(self._call(self._truth.GetLightDrop, room_pb2.CameraRequest(camera=camera)).image)[..., 0]

    def occluder_mask(self, camera: int = 0) -> np.ndarray:
        """(H, W) bool."""
        return codec.decode_image(self._call(self._truth.GetOccluderMask, room_pb2.CameraRequest(camera=camera)).image)[..., 0] > 0

    def projector_coordinates(self, slot: str, camera: int = 0) -> np.ndarray:
        """(H, W, 2) float32, NaN where unlit."""
        return codec.decode_image(self._call(self._truth.GetProjectorCoordinates, room_pb2.SlotRequest(slot=slot, camera=camera)).image)

    def transport(self, slot: str, camera: int = 0) -> scipy.sparse.csr_matrix:
        return wire.sparse_from_msg(self._call(self._truth.GetTransport, room_pb2.SlotRequest(slot=slot, camera=camera), timeout=max(self.timeout, 120.0)))
