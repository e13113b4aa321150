"""Frames in and out of the asset store for ``compensate_video``: a stored video (or image
sequence) asset decoded frame by frame on the coordinator, and compensated frames written as a
lossless 16-bit FFV1 video in Matroska.

Reading (:class:`AssetFrames`): a video asset is decoded with PyAV in order, each frame converted
by swscale as the nodes convert it (:mod:`node.asset_decode`): 8-bit sources to ``rgb24`` /
``gray`` uint8, deeper ones to ``rgb48le`` / ``gray16le`` uint16 scaled to the full 16-bit range;
alpha is dropped. An image-sequence asset's frames are read with OpenCV or numpy
(:func:`~.image_param.decode_image_bytes`). :class:`SourceFrames` reads frames ``[start, stop)``
from the blobs' files or bytes (a cluster worker, :mod:`.cluster`), seeking to ``start``.

Writing (:class:`Ffv1Writer`): ``(H, W, 1)`` uint16 frames as ``gray16le``, ``(H, W, 3)`` as
``gbrp16le`` (planar RGB; PyAV's ``rgb48le`` frames are repacked by swscale, a lossless
reordering), FFV1 version 3 (slices decoded on several threads, a CRC per slice), in Matroska at
an exact rational frame rate. Decoding gives back every sample bit-exactly, and the same frames
give the same bytes (the muxer's ``bitexact`` flag), hence the same asset.
"""
from __future__ import annotations

import io
import itertools
import os
from collections.abc import Callable, Iterator
from fractions import Fraction
from pathlib import Path
from typing import Any, BinaryIO

import av
import numpy as np

from coordinator.assets import AssetStore
from imaging.compensation.errors import CompensationError
from coordinator.compensation.image_param import decode_image_bytes
from protos.asset_manifest import Manifest

__all__ = ["AssetFrames", "SourceFrames", "Ffv1Writer", "FFV1_FORMATS", "join_segments", "segment_writer"]

#: channels -> FFV1 pixel format of the compensated asset
FFV1_FORMATS = {1: "gray16le", 3: "gbrp16le"}
#: channels -> PyAV ndarray format the frames are handed over in
_ARRAY_FORMATS = {1: "gray16le", 3: "rgb48le"}


Blob = Callable[[int], "Path | bytes"]


def _rate_index(pts: int, pts0: int, time_base: Fraction, rate: Fraction) -> Fraction:
    """Where a timestamp falls on the frame grid: ``(pts - pts0) * time_base * rate`` (exact)."""
    return (pts - pts0) * time_base * rate


class SourceFrames:
    """Frames ``[start, stop)`` of a video or image-sequence asset, in order (blocking; one thread),
    from its blobs as files or bytes: no store needed (a cluster worker holds only the bytes).

    Parameters
    ----------
    manifest : Manifest
        A ``video`` (one blob) or ``sequence`` asset.
    blob : callable
        ``blob(k)`` -> the ``k``-th blob of the manifest as a path or as its bytes.
    rate : Fraction
        The asset's exact frame rate (:func:`coordinator.show.manifest_rate`): frame ``k`` of a
        video is the one at ``k / rate`` after the first frame's timestamp.
    start, stop : int, int or None
        The frames wanted (``stop`` None: to the end).

    Frame ``k`` is the ``k``-th frame the decoder gives from the start of the file. A video read
    from ``start > 0`` seeks to the keyframe at or before ``start``'s timestamp and decodes from
    there, so a segment late in a long video costs its own frames, not all the ones before it;
    frames are counted on from the first one whose timestamp is ``start``'s. When the seek lands
    past it (an imprecise index) or the timestamps are off the ``rate`` grid, it decodes from the
    start and counts instead. Both give the same frames wherever the timestamps follow the rate
    (a constant-rate video: what cameras, editors and encoders write); a variable-rate video with
    frames missing before ``start`` would differ.

    Iterating yields ``(H, W, C)`` arrays, C 1 or 3, uint8 (8-bit sources) or uint16 (deeper
    ones, full 16-bit range) or float32 (float sequences). ``seeked`` says whether the last
    iteration seeked. :meth:`close` closes the file.
    """

    def __init__(self, manifest: Manifest, blob: Blob, *, rate: Fraction, start: int = 0,
                 stop: int | None = None) -> None:
        if manifest.kind not in ("video", "sequence"):
            raise CompensationError(f"asset {manifest.name!r} is a {manifest.kind}, not a video")
        self.manifest, self.blob, self.rate = manifest, blob, Fraction(rate)
        self.start = max(0, int(start))
        self.stop = None if stop is None else max(self.start, int(stop))
        self.seeked = False
        self._container = None

    def __iter__(self) -> Iterator[np.ndarray]:
        if self.manifest.kind == "sequence":
            end = len(self.manifest.blobs) if self.stop is None else min(self.stop, len(self.manifest.blobs))
            for k in range(self.start, end):
                name = self.manifest.blobs[k].name
                try:
                    raw = self.blob(k)
                    raw = raw if isinstance(raw, bytes) else Path(raw).read_bytes()
                except OSError as exc:
                    raise CompensationError(f"frame {name!r}: cannot be read ({exc})") from exc
                img, _ = decode_image_bytes(raw, name)
                yield img
            return
        yield from self._video()

    def _open(self) -> tuple[Any, Any]:
        """Open the video (closing one already open); its container and first video stream."""
        self.close()
        m = self.manifest
        src = self.blob(0)
        container = str(m.extra.get("container") or "") or None
        try:
            self._container = av.open(io.BytesIO(src) if isinstance(src, bytes) else str(src), mode="r",
                                      format=container if container in av.formats_available else None)
            stream = self._container.streams.video[0]
        except (av.FFmpegError, OSError, IndexError) as exc:
            self.close()
            raise CompensationError(f"asset {m.name!r}: cannot open its video ({exc})") from exc
        stream.codec_context.thread_type = "AUTO"
        return self._container, stream

    def _seek(self) -> Iterator[av.VideoFrame] | None:
        """The decoder's frames from frame ``start`` on, after a seek; None when a seek cannot find it."""
        c, stream = self._open()
        tb = stream.time_base
        first = next(c.decode(stream), None)
        pts0 = None if first is None else first.pts
        if pts0 is None or tb is None:
            return None
        c.seek(pts0 + round(self.start / (self.rate * tb)), stream=stream, backward=True, any_frame=False)
        frames = c.decode(stream)
        for frame in frames:
            if frame.pts is None:
                return None
            at = _rate_index(frame.pts, pts0, tb, self.rate)
            if at > self.start + Fraction(1, 4) or abs(at - round(at)) > Fraction(1, 4):
                return None        # landed past it, or timestamps off the grid: count from the start
            if round(at) == self.start:
                return itertools.chain([frame], frames)
        return None

    def _video(self) -> Iterator[np.ndarray]:
        m = self.manifest
        grey = m.channels in (1, 2)
        fmt = ("gray" if grey else "rgb24") if m.bit_depth == 8 else ("gray16le" if grey else "rgb48le")
        try:
            found = self._seek() if self.start > 0 else None
            self.seeked = found is not None
            if found is None:
                c, stream = self._open()
                found = itertools.islice(c.decode(stream), self.start, None)
            for k, frame in enumerate(found, start=self.start):
                if self.stop is not None and k >= self.stop:
                    break
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


class AssetFrames(SourceFrames):
    """The frames of a stored video or image-sequence asset from frame ``start`` on (a resumed
    run), read from the store's blob files (see :class:`SourceFrames`)."""

    def __init__(self, store: AssetStore, manifest: Manifest, *, start: int = 0, stop: int | None = None) -> None:
        from coordinator.show import manifest_rate  # lazy: the show module is the coordinator's, not a worker's

        self.store = store
        super().__init__(manifest, lambda k: store.blob_path(manifest.blobs[k].sha256), rate=manifest_rate(manifest),
                         start=start, stop=stop)


class Ffv1Writer:
    """Compensated frames into a 16-bit FFV1 Matroska file (blocking; one thread).

    Parameters
    ----------
    path : path of the ``.mkv`` to write (created; the caller removes it on failure), or a seekable binary file
        object (an ``io.BytesIO``: a segment made in memory leaves no file behind if its process is killed)
    size : (W, H) of every frame
    channels : 1 (``gray16le``) or 3 (``gbrp16le``)
    rate : exact frame rate (e.g. ``Fraction(30000, 1001)``)
    first : index of the first frame (its timestamp: a segment of a longer video)
    """

    def __init__(self, path: str | os.PathLike[str] | BinaryIO, *, size: tuple[int, int], channels: int,
                 rate: Fraction, first: int = 0) -> None:
        if channels not in FFV1_FORMATS:
            raise ValueError(f"channels must be 1 or 3, got {channels}")
        if rate <= 0:
            raise ValueError(f"rate must be > 0, got {rate}")
        self.path = Path(path) if isinstance(path, (str, os.PathLike)) else None
        self.size, self.channels, self.rate = (int(size[0]), int(size[1])), channels, Fraction(rate)
        self.first, self.frames = int(first), 0
        self._started = False
        # bitexact: no random segment/track UIDs nor version strings, so the same frames give the same bytes
        self._out = av.open(str(self.path) if self.path is not None else path, mode="w", format="matroska",
                            options={"fflags": "+bitexact"})
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


def segment_writer(first: Path, path: str | os.PathLike[str], *, rate: Fraction) -> Ffv1Writer:
    """An :class:`Ffv1Writer` to ``path`` set up as the writer of the segment file ``first`` was
    (its size and pixel format), to :meth:`~Ffv1Writer.copy` segments into."""
    with av.open(str(first), mode="r", format="matroska") as f:
        ref = f.streams.video[0].codec_context
        size, fmt = (ref.width, ref.height), ref.format.name
    channels = next((c for c, f in FFV1_FORMATS.items() if f == fmt), None)
    if channels is None:
        raise CompensationError(f"segment {first.name}: pixel format {fmt}, not one this writer writes")
    return Ffv1Writer(path, size=size, channels=channels, rate=rate)


def join_segments(segments: list[Path], path: str | os.PathLike[str], *, rate: Fraction) -> int:
    """Copy the frames of :class:`Ffv1Writer` segment files (same size and format) in order into
    one file at ``rate``, without decoding (every FFV1 frame is intra-coded, so its packet stands
    alone); frame ``k`` gets timestamp ``k / rate``. Returns the frame count.

    The output stream is set up as :class:`Ffv1Writer` sets up its own, so the file is the same,
    byte for byte, as the frames written in one go: where the segments were cut does not show.
    """
    if not segments:
        raise ValueError("no segments to join")
    out = segment_writer(segments[0], path, rate=rate)
    try:
        for seg in segments:
            out.copy(seg)
    except BaseException:
        out.abort()
        raise
    out.close()
    return out.frames
