"""The virtual room's Capture call, as the coordinator's room cameras make it.

:class:`RoomCaptureLink` is the gRPC client of the room's ``Room`` service
(:mod:`sim.wire.service`); :class:`coordinator.camera.RoomCamera` drives it and words its errors.
A failed call raises :class:`RoomCallError` saying which way it failed, so nothing above this
module sees gRPC.
"""
from __future__ import annotations

import enum
import time
from dataclasses import dataclass

import grpc
import numpy as np

from protos import codec, room_pb2, room_pb2_grpc
from protos.version import GRPC_OPTIONS


class RoomFailure(enum.Enum):
    UNREACHABLE = "unreachable"      # nothing answers at the room's address
    TIMEOUT = "timeout"              # the call's deadline passed
    REFUSED = "refused"              # the room answered with an error
    MALFORMED = "malformed"          # the room's image does not decode


class RoomCallError(Exception):
    """A Capture call that failed: how (:class:`RoomFailure`) and the details the room or gRPC gave."""

    def __init__(self, failure: RoomFailure, details: str):
        super().__init__(details)
        self.failure, self.details = failure, details


@dataclass(frozen=True)
class RoomCapture:
    """One capture: the projectors that had not yet shown the frame it had to wait for, or else
    the image as the room sent it, decoded (None when a projector was late); ``received_ns``: the
    monotonic clock when the room's answer arrived."""

    late_slots: tuple[str, ...]
    image: np.ndarray | None
    received_ns: int


class RoomCaptureLink:
    """A channel to the room at ``target`` (HOST:PORT); blocking calls, for a worker thread."""

    def __init__(self, target: str):
        self._channel = grpc.insecure_channel(target, options=GRPC_OPTIONS)
        self._stub = room_pb2_grpc.RoomStub(self._channel)

    def capture(self, *, camera: int, not_before_rig_ns: int, timeout_ms: int, exposure: float,
                deadline_s: float) -> RoomCapture:
        """Camera ``camera``'s image once every streaming projector swapped at or after
        ``not_before_rig_ns`` (0: at once), waiting at most ``timeout_ms`` in the room; ``exposure``
        relative to the camera's own (0: its own)."""
        req = room_pb2.CaptureRequest(camera=camera, not_before_rig_ns=not_before_rig_ns, timeout_ms=timeout_ms,
                                      exposure=exposure)
        try:
            reply = self._stub.Capture(req, timeout=deadline_s)
            received_ns = time.monotonic_ns()
        except grpc.RpcError as exc:
            code = exc.code() if hasattr(exc, "code") else None
            if code == grpc.StatusCode.UNAVAILABLE:
                raise RoomCallError(RoomFailure.UNREACHABLE, exc.details() or "") from exc
            if code == grpc.StatusCode.DEADLINE_EXCEEDED:
                raise RoomCallError(RoomFailure.TIMEOUT, exc.details() or "") from exc
            details = exc.details() if hasattr(exc, "details") else str(exc)
            raise RoomCallError(RoomFailure.REFUSED, details) from exc
        if reply.late_slots:
            return RoomCapture(tuple(reply.late_slots), None, received_ns)
        try:
            return RoomCapture((), codec.decode_image(reply.image), received_ns)
        except codec.ImageCodecError as exc:
            raise RoomCallError(RoomFailure.MALFORMED, str(exc)) from exc

    def close(self) -> None:
        self._channel.close()
