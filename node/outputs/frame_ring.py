"""Frames for the virtual room left in shared memory, so that only a small message crosses the socket.

A node that drives one of the room's projectors (:mod:`node.outputs.room_link`) used to send every
swapped frame as an image message: 192 KB for a 320×200 frame, encoded, framed by gRPC, parsed by
the room. On the host that runs the whole rig that is CPU taken from the other nodes. A
:class:`FrameRing` is a memfd of ``count`` buffers; each frame is copied into the next buffer and the
room, told where it lies (``room.proto``'s ``SharedFrame``), copies it out when the message arrives.
The layout of a buffer (the contract, also in ``room.proto``): a little-endian uint64 sequence
number, then the (H, W, 3) uint8 pixels. The sequence number is cleared before the pixels are
written and set after them, so a reader that copied a buffer while it was being written again sees
that it no longer holds its frame.

Linux only (``os.memfd_create``); :func:`FrameRing.available` says whether it can be made here.
"""
from __future__ import annotations

import mmap
import os

import numpy as np

__all__ = ["FrameRing", "MEMFD_NAME"]

#: the memfd's name starts with this; the room opens nothing else
MEMFD_NAME = "shadowless-room-frames"

_SEQ_BYTES = 8
_ALIGN = 64


class FrameRing:
    """``count`` buffers of (height, width, 3) uint8 frames in one memfd.

    Parameters
    ----------
    shape : (height, width, 3)
        The frames' shape; every :meth:`write` must match it.
    label : str
        Added to the memfd's name (e.g. the slot), for whoever lists /proc/PID/fd.
    count : int
        Buffers; a frame stays readable until ``count`` newer ones were written.
    """

    def __init__(self, shape: tuple[int, int, int], *, label: str = "", count: int = 8) -> None:
        h, w, c = (int(v) for v in shape)
        if h < 1 or w < 1 or c != 3 or count < 2:
            raise ValueError(f"a frame ring needs (h, w, 3) frames and at least 2 buffers, got {shape} x {count}")
        self.shape = (h, w, 3)
        self.count = int(count)
        self.frame_bytes = h * w * 3
        self.stride = -(-(_SEQ_BYTES + self.frame_bytes) // _ALIGN) * _ALIGN
        self.fd = os.memfd_create(f"{MEMFD_NAME}-{label}" if label else MEMFD_NAME, os.MFD_CLOEXEC)
        try:
            os.ftruncate(self.fd, self.stride * self.count)
            self._mm = mmap.mmap(self.fd, self.stride * self.count)
        except BaseException:
            os.close(self.fd)
            raise
        self.pid = os.getpid()
        self._seq = 0
        # per buffer: its sequence number (1,) uint64 and its pixels (h, w, 3) uint8, views of the map
        self._seqs = [np.ndarray((1,), "<u8", buffer=self._mm, offset=i * self.stride) for i in range(self.count)]
        self._pixels = [np.ndarray(self.shape, np.uint8, buffer=self._mm, offset=i * self.stride + _SEQ_BYTES)
                        for i in range(self.count)]

    @staticmethod
    def available() -> bool:
        """Whether this system can make a ring (Linux memfd)."""
        return hasattr(os, "memfd_create")

    def write(self, image: np.ndarray) -> tuple[int, int]:
        """Copy ``image`` ((h, w, 3) uint8, the ring's shape) into the next buffer; return the
        pixels' byte offset in the memfd and the frame's sequence number (from 1 up)."""
        if image.shape != self.shape or image.dtype != np.uint8:
            raise ValueError(f"frame of shape {image.shape} {image.dtype} does not fit a ring of {self.shape} uint8")
        self._seq += 1
        i = self._seq % self.count
        self._seqs[i][0] = 0
        np.copyto(self._pixels[i], image)
        self._seqs[i][0] = self._seq
        return i * self.stride + _SEQ_BYTES, self._seq

    def read(self, offset: int, seq: int) -> np.ndarray | None:
        """A copy of the frame :meth:`write` returned (offset, seq) for, or None once overwritten."""
        i, rest = divmod(offset - _SEQ_BYTES, self.stride)
        if rest or not 0 <= i < self.count or int(self._seqs[i][0]) != seq:
            return None
        copy = self._pixels[i].copy()
        return copy if int(self._seqs[i][0]) == seq else None     # written again meanwhile

    def close(self) -> None:
        """Unmap and close the memfd (the room may still hold its own mapping until it lets go)."""
        if self._mm is None:
            return
        self._seqs = []
        self._pixels = []
        self._mm.close()
        self._mm = None
        os.close(self.fd)
