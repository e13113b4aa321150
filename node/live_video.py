"""A node's side of live video: encoded pictures in, decoded content pictures out, never garbage.

The coordinator encodes a played sequence once (:mod:`coordinator.live_video`) and sends each
encoded picture to every node in its frame packet (:class:`VideoChunk`, parsed by
:mod:`node.wire`); the packet's frame references the decoded picture by its content id.
:class:`LiveDecoder` decodes them with PyAV, in the presenter, under one rule: a picture is
decoded only when every picture it may reference was decoded, that is from a keyframe of its
stream on, through consecutive sequence numbers. A node that joined mid-stream, lost packets
(its Frames stream reconnected) or met a decode error waits for the next keyframe; the frames
it could not decode name content it does not hold and are dropped as MISSING_CONTENT.
"""
from __future__ import annotations

import logging
from dataclasses import dataclass

import numpy as np

from node.yuv import yuv_planes
from protos.yuv import YuvFrame

log = logging.getLogger(__name__)

#: hard limits on a live picture, so a malformed packet cannot exhaust memory
MAX_SIDE = 8192
#: the codecs a node decodes, by the wire's name
DECODERS = {"h264": "h264", "hevc": "hevc"}


@dataclass(frozen=True)
class VideoChunk:
    """One encoded picture of a live stream, as received (see :class:`coordinator.live_video.EncodedPicture`)."""

    stream_id: str
    sequence: int
    keyframe: bool
    data: bytes
    width: int
    height: int
    channels: int                # 1 or 3
    bit_depth: int               # 8 -> uint8 pictures, 10 -> uint16 pictures
    codec: str                   # "h264" or "hevc"
    content_id: str


class LiveDecoder:
    """Decodes the live stream's pictures in order; see the module docstring.

    Counters: ``decoded`` pictures, ``skipped`` (waiting for a keyframe, or undecodable).
    ``yuv``: an RGB picture comes as the decoder's planes (:class:`protos.yuv.YuvFrame`, converted
    by the renderer's shader) when the shader covers its format and it has the packet's size.
    """

    def __init__(self, *, yuv: bool = False) -> None:
        self.yuv = yuv
        self._ctx = None
        self._stream: str | None = None
        self._next: int | None = None        # sequence expected next; None: wait for a keyframe
        self.decoded = 0
        self.skipped = 0

    def _open(self, chunk: VideoChunk) -> None:
        import av

        if chunk.codec not in DECODERS:
            raise ValueError(f"unknown live codec {chunk.codec!r}")
        ctx = av.CodecContext.create(DECODERS[chunk.codec], "r")
        ctx.thread_type = "SLICE"        # frame threads would hold pictures back by a frame each
        self._ctx = ctx

    def reset(self) -> None:
        """Forget the stream (a new coordinator instance): wait for a keyframe again."""
        self._ctx, self._stream, self._next = None, None, None

    def feed(self, chunk: VideoChunk) -> np.ndarray | YuvFrame | None:
        """The decoded picture of ``chunk``, ``(height, width, channels)`` uint8 (8-bit) or uint16
        (10-bit) (with ``yuv``, RGB pictures as a :class:`~protos.yuv.YuvFrame`), or None when it cannot be decoded correctly (waiting for a keyframe, a gap in
        the sequence, a malformed packet)."""
        if not (0 < chunk.width <= MAX_SIDE and 0 < chunk.height <= MAX_SIDE) or chunk.channels not in (1, 3) \
                or chunk.bit_depth not in (8, 10):
            log.error("live picture %s: %dx%dx%d %d-bit is outside what a node decodes", chunk.content_id,
                      chunk.width, chunk.height, chunk.channels, chunk.bit_depth)
            self.skipped += 1
            return None
        if chunk.stream_id != self._stream:
            self.reset()
            self._stream = chunk.stream_id
        if not chunk.keyframe and self._next != chunk.sequence:
            if self._next is not None:
                log.warning("live stream %s: picture %d after %d; waiting for a keyframe", chunk.stream_id,
                            chunk.sequence, self._next - 1)
            self._next = None
            self.skipped += 1
            return None
        try:
            if self._ctx is None or (chunk.keyframe and self._next != chunk.sequence):
                self._open(chunk)
            image = self._decode(chunk)
        except Exception as exc:    # noqa: BLE001 - av.FFmpegError, ValueError: a bad packet is the sender's fault
            log.error("live picture %s cannot be decoded: %s; waiting for a keyframe", chunk.content_id, exc)
            self._ctx, self._next = None, None
            self.skipped += 1
            return None
        self._next = chunk.sequence + 1
        self.decoded += 1
        return image

    def _decode(self, chunk: VideoChunk) -> np.ndarray | YuvFrame:
        import av

        frames = self._ctx.decode(av.Packet(chunk.data))
        if len(frames) != 1:
            raise ValueError(f"{len(frames)} pictures decoded from one packet")
        f = frames[0]
        if f.width < chunk.width or f.height < chunk.height or f.width > chunk.width + 1 or f.height > chunk.height + 1:
            raise ValueError(f"picture is {f.width}x{f.height}, the packet says {chunk.width}x{chunk.height}")
        if self.yuv and chunk.channels == 3 and (f.width, f.height) == (chunk.width, chunk.height):
            planes = yuv_planes(f)
            if planes is not None:
                return planes
        img = f.to_ndarray(format="rgb24" if chunk.bit_depth == 8 else "rgb48le")
        img = img[:chunk.height, :chunk.width, :chunk.channels]
        return np.ascontiguousarray(img)
