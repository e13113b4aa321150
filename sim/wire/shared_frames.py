"""The room's side of frames a node leaves in shared memory (``room.proto``'s ``SharedFrame``).

A node on the room's host copies each frame it swaps into a ring of buffers in a memfd and sends
only where it lies. The room opens the memfd through ``/proc/<pid>/fd/<fd>`` (once per stream),
copies the pixels out as the message arrives, and keeps them only if the buffer still holds that
frame's sequence number: a frame the node overwrote before the room read it is skipped, and a newer
one follows. The buffer layout is ``room.proto``'s: a little-endian uint64 sequence number 8 bytes
before the pixels, then (height, width, 3) uint8 RGB.

Only memfds whose name starts with ``shadowless-room-frames`` are opened: a stream cannot make the
room read an arbitrary file of the node's process.
"""
from __future__ import annotations

import mmap
import os

import numpy as np

from sim.errors import FrameError, SharedFrameUnavailable

__all__ = ["SharedFrames", "MEMFD_NAME"]

#: the prefix of the memfd's name (``/proc/PID/fd/FD`` reads ``/memfd:<name> (deleted)``)
MEMFD_NAME = "shadowless-room-frames"

_SEQ_BYTES = 8


class SharedFrames:
    """The shared memory one Display stream's node writes its frames to (opened on first use)."""

    def __init__(self) -> None:
        self._maps: dict[tuple[int, int], mmap.mmap] = {}
        #: frames whose buffer the node had written again before the room read it
        self.overwritten = 0

    def _map(self, pid: int, fd: int) -> mmap.mmap:
        key = (pid, fd)
        mm = self._maps.get(key)
        if mm is not None:
            return mm
        path = f"/proc/{pid}/fd/{fd}"
        try:
            target = os.readlink(path)
            if not target.startswith(f"/memfd:{MEMFD_NAME}"):
                raise SharedFrameUnavailable(f"{path} is not a frame ring of a node ({target!r})")
            handle = os.open(path, os.O_RDONLY | os.O_CLOEXEC)
            try:
                size = os.fstat(handle).st_size
                mm = mmap.mmap(handle, size, prot=mmap.PROT_READ)
            finally:
                os.close(handle)
        except OSError as exc:
            raise SharedFrameUnavailable(f"cannot open the node's frames at {path}: {exc.strerror or exc}") from None
        self._maps[key] = mm
        return mm

    def read(self, ref, size: tuple[int, int]) -> np.ndarray | None:
        """A copy of the frame ``ref`` (a ``SharedFrame``) names: (h, w, 3) uint8, or None if the node
        wrote that buffer again first. ``size`` is the projector's (width, height); FrameError when
        the frame has another size or lies outside the memory, SharedFrameUnavailable when the
        memory cannot be opened."""
        w, h = size
        if (ref.width, ref.height) != (w, h):
            raise FrameError(f"the frame is {ref.width}x{ref.height}, but the room's projector takes {w}x{h}: "
                             "render at the size DescribeProjector reports")
        mm = self._map(ref.pid, ref.fd)
        nbytes = w * h * 3
        if ref.offset < _SEQ_BYTES or ref.offset + nbytes > len(mm):
            raise FrameError(f"a shared frame at byte {ref.offset} ({nbytes} bytes) lies outside the node's {len(mm)} bytes")
        image = np.frombuffer(mm, np.uint8, nbytes, ref.offset).reshape(h, w, 3).copy()
        if int(np.frombuffer(mm, "<u8", 1, ref.offset - _SEQ_BYTES)[0]) != ref.seq:
            self.overwritten += 1
            return None
        return image

    def close(self) -> None:
        for mm in self._maps.values():
            mm.close()
        self._maps.clear()
