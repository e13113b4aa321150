"""An operator's image in parts: Show and Play send an image in messages of IMAGE_PART_BYTES, and
the coordinator reassembles it, never beyond what the image's declared size can hold.

The parts are read only after the call's session was checked (from its metadata), so a peer
without a session never makes the coordinator hold an image.
"""
from __future__ import annotations

import numpy as np

from coordinator.api import Space
from coordinator.wire.node_messages import space_message
from protos import codec, common_pb2, control_pb2

#: Image bytes per message from an operator (the coordinator accepts MAX_REQUEST_BYTES a message).
IMAGE_PART_BYTES = 1 << 20


def _image_parts(image: np.ndarray) -> tuple[common_pb2.Image, list[bytes]]:
    """``image`` packed for the wire: the message with its first part, and the rest."""
    msg = codec.encode_image(image, compress=True)
    data = msg.data
    msg.data = data[:IMAGE_PART_BYTES]
    return msg, [data[i:i + IMAGE_PART_BYTES] for i in range(IMAGE_PART_BYTES, len(data), IMAGE_PART_BYTES)]


def show_request_parts(image: np.ndarray, *, name: str, persist: bool, space: Space, apply_lut: bool,
                       fit: str = "", slot_regions=None) -> list[control_pb2.ShowRequest]:
    """The messages of one Show call: settings (and ``slot_regions``), the image's first part, then the rest."""
    msg, rest = _image_parts(image)
    first = control_pb2.ShowRequest(image=msg, name=name, persist=persist, space=space_message(space),
                                    apply_lut=apply_lut, fit=fit)
    for slot, rects in (slot_regions or {}).items():     # a slot named with no rectangle is present: black
        first.slot_regions[slot].rects.extend(control_pb2.ContentRect(x=x, y=y, width=w, height=h) for x, y, w, h in rects)
    return [first, *(control_pb2.ShowRequest(more=part) for part in rest)]


def play_frame_items(image: np.ndarray) -> list[control_pb2.PlayItem]:
    """One frame of a Play call: the frame with its first part, then ``more`` items."""
    msg, rest = _image_parts(image)
    return [control_pb2.PlayItem(frame=msg), *(control_pb2.PlayItem(more=part) for part in rest)]


class ImageParts:
    """Reassembles an image sent in parts, refusing more bytes than its size can hold.

    ``start(msg)`` with the Image message of the first part, ``add(bytes)`` for each further
    part, ``finish()`` returns the whole Image message. The bound is the raw size of the
    declared (height, width, channels, dtype) plus a margin for the packing's headers: an
    image never takes more memory than it could need, whatever a client sends.
    """

    MARGIN = 1 << 16

    def __init__(self) -> None:
        self._msg: common_pb2.Image | None = None
        self._parts: list[bytes] = []
        self._size = 0
        self._limit = 0

    @property
    def started(self) -> bool:
        return self._msg is not None

    def start(self, msg: common_pb2.Image) -> None:
        codec.check_header(msg)
        self._msg, self._parts, self._size = msg, [msg.data], len(msg.data)
        self._limit = msg.width * msg.height * msg.channels * codec.dtype_size(msg.dtype) + self.MARGIN
        self._check()

    def add(self, data: bytes) -> None:
        if self._msg is None:
            raise ValueError("image bytes arrived before the image they belong to")
        self._parts.append(data)
        self._size += len(data)
        self._check()

    def _check(self) -> None:
        if self._size > self._limit:
            m = self._msg
            raise ValueError(f"image of {m.width}x{m.height}x{m.channels} sent more than {self._limit} bytes")

    def finish(self) -> common_pb2.Image:
        if self._msg is None:
            raise ValueError("no image was sent")
        msg = self._msg
        msg.data = b"".join(self._parts)
        self._msg, self._parts, self._size = None, [], 0
        return msg


def regions_from_request(msg: control_pb2.ShowRequest) -> dict[str, list[tuple[int, int, int, int]]]:
    """A Show's per-slot regions, slot -> rectangles (x, y, width, height); checked by the playback."""
    return {slot: [(r.x, r.y, r.width, r.height) for r in e.rects] for slot, e in msg.slot_regions.items()}
