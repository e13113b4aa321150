"""Frames in and out of the asset store for ``compensate_video``: a stored video (or image
sequence) asset decoded frame by frame on the coordinator, and compensated frames written as a
lossless 16-bit FFV1 video in Matroska.

Reading (:class:`AssetFrames`): a video asset is decoded with PyAV in order, each frame converted
by swscale as the nodes convert it (:mod:`node.asset_decode`): 8-bit sources to ``rgb24`` /
``gray`` uint8, deeper ones to ``rgb48le`` / ``gray16le`` uint16 scaled to the full 16-bit range;
alpha is dropped. An image-sequence asset's frames are read with OpenCV or numpy
(:func:`~.image_param.decode_image_bytes`).

Writing (:class:`Ffv1Writer`): ``(H, W, 1)`` uint16 frames as ``gray16le``, ``(H, W, 3)`` as
``gbrp16le`` (planar RGB; PyAV's ``rgb48le`` frames are repacked by swscale, a lossless
reordering), FFV1 version 3 (slices decoded on several threads, a CRC per slice), in Matroska at
an exact rational frame rate. Decoding gives back every sample bit-exactly, and the same frames
give the same bytes (the muxer's ``bitexact`` flag), hence the same asset.
"""
from __future__ import annotations

import os
from fractions import Fraction
from pathlib import Path
from typing import Iterator

import av
import numpy as np

from coordinator.assets import AssetStore
from coordinator.compensation.errors import CompensationError
from coordinator.compensation.image_param import decode_image_bytes
from protos.asset_manifest import Manifest

__all__ = ["AssetFrames", "Ffv1Writer", "FFV1_FORMATS", "join_segments"]

#: channels -> FFV1 pixel format of the compensated asset
FFV1_FORMATS = {1: "gray16le", 3: "gbrp16le"}
#: channels -> PyAV ndarray format the frames are handed over in
_ARRAY_FORMATS = {1: "gray16le", 3: "rgb48le"}


class AssetFrames:
    """The frames of a stored video or image-sequence asset, in order (blocking; one thread).

    Parameters
    ----------
    store : AssetStore
    manifest : Manifest
        A ``video`` (one blob) or ``sequence`` asset.
    start : int
        Frames to skip (a resumed run): decoded in order but not converted.

    Iterating yields ``(H, W, C)`` arrays, C 1 or 3, uint8 (8-bit sources) or uint16 (deeper
    ones, full 16-bit range) or float32 (float sequences). :meth:`close` closes the file.
    """

    def __init__(self, store: AssetStore, manifest: Manifest, *, start: int = 0) -> None:
        if manifest.kind not in ("video", "sequence"):
            raise CompensationError(f"asset {manifest.name!r} is a {manifest.kind}, not a video")
        self.store, self.manifest, self.start = store, manifest, max(0, int(start))
        self._container = None

    def __iter__(self) -> Iterator[np.ndarray]:
        if self.manifest.kind == "sequence":
            for blob in self.manifest.blobs[self.start:]:
                path = self.store.blob_path(blob.sha256)
                try:
                    raw = path.read_bytes()
                except OSError as exc:
                    raise CompensationError(f"frame {blob.name!r}: cannot be read from the store ({exc})") from exc
                img, _ = decode_image_bytes(raw, blob.name)
                yield img
            return
        yield from self._video()

    def _video(self) -> Iterator[np.ndarray]:
        m = self.manifest
        blob = m.blobs[0]
        path = self.store.blob_path(blob.sha256)
        container = str(m.extra.get("container") or "") or None
        try:
            self._container = av.open(str(path), mode="r",
                                      format=container if container in av.formats_available else None)
        except (av.FFmpegError, OSError) as exc:
            raise CompensationError(f"asset {m.name!r}: cannot open its video ({exc})") from exc
        grey = m.channels in (1, 2)
        fmt = ("gray" if grey else "rgb24") if m.bit_depth == 8 else ("gray16le" if grey else "rgb48le")
        try:
            stream = self._container.streams.video[0]
            stream.codec_context.thread_type = "AUTO"
            for k, frame in enumerate(self._container.decode(stream)):
                if k < self.start:
                    continue
                arr = frame.to_ndarray(format=fmt)
                yield np.ascontiguousarray(arr[:, :, None] if arr.ndim == 2 else arr)
        except (av.FFmpegError, ValueError, IndexError) as exc:
            raise CompensationError(f"asset {m.name!r}: decoding failed ({exc})") from exc
        finally:
            self.close()

    def close(self) -> None:
        """Close the video file (idempotent)."""
        if self._container is not None:
            self._container.close()
            self._container = None


class Ffv1Writer:
    """Compensated frames into a 16-bit FFV1 Matroska file (blocking; one thread).

    Parameters
    ----------
    path : path of the ``.mkv`` to write (created; the caller removes it on failure)
    size : (W, H) of every frame
    channels : 1 (``gray16le``) or 3 (``gbrp16le``)
    rate : exact frame rate (e.g. ``Fraction(30000, 1001)``)
    first : index of the first frame (its timestamp: a segment of a longer video)
    """

    def __init__(self, path: str | os.PathLike[str], *, size: tuple[int, int], channels: int, rate: Fraction,
                 first: int = 0) -> None:
        if channels not in FFV1_FORMATS:
            raise ValueError(f"channels must be 1 or 3, got {channels}")
        if rate <= 0:
            raise ValueError(f"rate must be > 0, got {rate}")
        self.path = Path(path)
        self.size, self.channels, self.rate = (int(size[0]), int(size[1])), channels, Fraction(rate)
        self.first, self.frames = int(first), 0
        self._started = False
        # bitexact: no random segment/track UIDs nor version strings, so the same frames give the same bytes
        self._out = av.open(str(self.path), mode="w", format="matroska", options={"fflags": "+bitexact"})
        try:
            s = self._out.add_stream("ffv1", rate=self.rate)
            s.width, s.height = self.size
            s.pix_fmt = FFV1_FORMATS[channels]
            s.options = {"level": "3", "slicecrc": "1", "slices": "4", "g": "1"}
            s.codec_context.thread_count = 1   # deterministic bytes: the same frames give the same asset
            self._stream = s
        except BaseException:
            self._out.close()
            raise

    def write(self, frame: np.ndarray) -> None:
        """Append one frame: ``(H, W, channels)`` uint16 (``(H, W)`` accepted for one channel)."""
        a = np.asarray(frame)
        if a.ndim == 2:
            a = a[:, :, None]
        if a.dtype != np.uint16 or a.shape != (self.size[1], self.size[0], self.channels):
            raise ValueError(f"frame must be ({self.size[1]}, {self.size[0]}, {self.channels}) uint16, "
                             f"got {a.shape} {a.dtype}")
        fmt = _ARRAY_FORMATS[self.channels]
        vf = av.VideoFrame.from_ndarray(np.ascontiguousarray(a[:, :, 0] if self.channels == 1 else a), format=fmt)
        vf.pts = self.first + self.frames
        vf.time_base = 1 / self.rate
        for packet in self._stream.encode(vf):
            self._out.mux(packet)
        self._started = True
        self.frames += 1

    def copy(self, segment: str | os.PathLike[str]) -> None:
        """Append the frames of another writer's file as they are (packets copied, nothing decoded)."""
        if self.frames == 0 and not self._started:
            self._out.start_encoding()   # opens the encoder: its header (extradata) is what the segments carry
            self._started = True
        with av.open(str(segment), mode="r", format="matroska") as src:
            stream = src.streams.video[0]
            if stream.codec_context.extradata != self._stream.codec_context.extradata:
                raise CompensationError(f"segment {Path(segment).name} was encoded with other settings")
            for packet in src.demux(stream):
                if packet.size == 0:
                    continue
                packet.stream = self._stream
                packet.time_base = 1 / self.rate
                packet.pts = packet.dts = self.first + self.frames
                packet.duration = 1
                self._out.mux(packet)
                self.frames += 1

    def close(self) -> None:
        """Flush the encoder and finish the file (idempotent)."""
        if self._out is None:
            return
        try:
            for packet in self._stream.encode(None):
                self._out.mux(packet)
        finally:
            self._out.close()
            self._out = None

    def abort(self) -> None:
        """Close without flushing (after a failure; the caller removes the file)."""
        if self._out is not None:
            try:
                self._out.close()
            except av.FFmpegError:
                pass
            self._out = None


def join_segments(segments: list[Path], path: str | os.PathLike[str], *, rate: Fraction) -> int:
    """Copy the frames of :class:`Ffv1Writer` segment files (same size and format) in order into
    one file at ``rate``, without decoding (every FFV1 frame is intra-coded, so its packet stands
    alone); frame ``k`` gets timestamp ``k / rate``. Returns the frame count.

    The output stream is set up as :class:`Ffv1Writer` sets up its own, so the file is the same,
    byte for byte, as the frames written in one go: where the segments were cut does not show.
    """
    if not segments:
        raise ValueError("no segments to join")
    with av.open(str(segments[0]), mode="r", format="matroska") as first:
        ref = first.streams.video[0].codec_context
        size, fmt = (ref.width, ref.height), ref.format.name
    channels = next((c for c, f in FFV1_FORMATS.items() if f == fmt), None)
    if channels is None:
        raise CompensationError(f"segment {segments[0].name}: pixel format {fmt}, not one this writer writes")
    out = Ffv1Writer(path, size=size, channels=channels, rate=rate)
    try:
        for seg in segments:
            out.copy(seg)
    except BaseException:
        out.abort()
        raise
    out.close()
    return out.frames
