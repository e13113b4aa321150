"""Decoders behind the node's frame source: an asset's image files and videos to arrays the
renderer uploads as they are (:mod:`node.asset_frames` puts them together).

What comes out is ``(H, W, C)`` in the content dtype of the asset's bit depth
(:func:`content_dtype`: uint8 for 8-bit, uint16 for 10/12/16-bit, float32 for float), channels in
RGB(A) order. How each kind of file is read:

* **PNG** -- FFmpeg's PNG decoder through PyAV, either :func:`node.image_files.decode_png`
  (:func:`decode_image` with ``png="node"``: the decoder alone, packed planes read as they are)
  or the ``png_pipe`` demuxer and :func:`frame_to_array` (``png="av"``). Both are lossless and
  give the same pixels for 8/16-bit grey, grey+alpha, RGB(A), palette, interlaced and 1/2/4-bit
  files; ``png_pipe`` is the fallback for what the strict decoder refuses. A 1080p RGB 8-bit PNG
  decodes in ~50 ms whatever its row filters (x86 desktop core).
* **JPEG, TIFF** -- PyAV, through FFmpeg's ``jpeg_pipe`` / ``tiff_pipe`` demuxers (a cached blob
  has no file suffix, so the demuxer is named from the blob's original name).
* **.npy** -- ``numpy.load(mmap_mode="r")`` then a copy: float32 ``(H, W)`` or ``(H, W, C)``.
* **Video** -- :class:`VideoDecoder`: PyAV, slice threads (:data:`THREAD_TYPE`), sequential
  decoding, seeking for jumps;
  the decoder chosen by :mod:`node.decoders` (hardware where it opens, else software). With
  ``yuv`` an RGB video's frames are handed over as the decoder's planes
  (:class:`protos.yuv.YuvFrame`, :mod:`node.yuv`), which the renderer converts in its shader,
  instead of going through swscale below.

Pixel conversions go through FFmpeg's swscale (PyAV's ``to_ndarray(format=...)``), honouring the
frame's colour tags (untagged YUV is treated as BT.601 limited range, as FFmpeg does):

* 8-bit YUV, RGB, palette -> ``rgb24`` uint8; grey -> ``gray`` (1 channel); with alpha -> ``rgba``.
* 10/12/16-bit -> ``rgb48le`` / ``gray16le`` / ``rgba64le`` uint16 **scaled to the full 16-bit
  range**: an n-bit sample ``v`` becomes ``v << (16 - n) | v >> (2n - 16)`` (the high bits
  replicated into the low ones, so 0 -> 0 and 1023 -> 65535); exact for grey and planar RGB
  (``gray10le``, ``gbrp10le``, ...). From 10/12-bit YUV swscale's limited-range expansion lands
  nominal white (940 of 1023) on 65283, not 65535 (a uniform 255/256 gain, 0.4 % low);
  super-whites reach 65535.
* float formats -> ``gbrpf32le`` / ``grayf32le`` float32.

Only standard library, numpy, PyAV and ``node.*``: the edge node's install.
"""
from __future__ import annotations

import logging
import os
from bisect import bisect_right
from fractions import Fraction
from pathlib import Path

import av
import numpy as np

from node.decoders import DecoderChoice, choose
from node.errors import NodeError
from node.image_files import PngError, PngTooLarge, decode_png
from node.yuv import why_not, yuv_planes
from protos.yuv import YuvFrame

log = logging.getLogger(__name__)

__all__ = ["DecodeError", "VideoDecoder", "content_dtype", "decode_image", "frame_to_array", "match_channels"]

# blob suffix -> FFmpeg demuxer (a cached blob's path has no suffix to guess from)
_IMAGE_DEMUXERS = {".png": "png_pipe", ".jpg": "jpeg_pipe", ".jpeg": "jpeg_pipe", ".tif": "tiff_pipe",
                   ".tiff": "tiff_pipe"}
#: how a video decoder's threads share a stream's work (FFmpeg's ``thread_type``): "SLICE", the
#: slices of one picture, so no thread holds a picture of its own. Frame threads ("FRAME", "AUTO")
#: decode pictures side by side, each thread keeping a picture in flight and a copy of the decoder's
#: state: 12 MB more resident at 1080p with two threads, for the same CPU per frame
#: (bench/node_video_memory.py). A stream of one slice per picture (x264's default) then decodes
#: on one thread: 3.5 ms per 1080p frame on this project's x86 machine, well within a 30 fps
#: period; a small board decodes in hardware (node/decoders.py)
THREAD_TYPE = "SLICE"
_EOF_SLACK = 2   # frames a stream may fall short of its manifest's count (then its last frame is held)
_VIDEO_DEMUXERS = {".mp4": "mov", ".mov": "mov", ".mkv": "matroska", ".avi": "avi"}
# (channels, sample depth) -> swscale output format
_TARGET_FORMATS = {(1, 8): "gray", (1, 16): "gray16le", (1, 32): "grayf32le",
                   (3, 8): "rgb24", (3, 16): "rgb48le", (3, 32): "gbrpf32le",
                   (4, 8): "rgba", (4, 16): "rgba64le", (4, 32): "gbrapf32le"}


class DecodeError(NodeError, ValueError):
    """A file of an asset could not be decoded into frames; the message says what failed."""


def content_dtype(bit_depth: int) -> np.dtype:
    """The dtype the renderer uploads for content of ``bit_depth`` bits per sample (8 -> uint8,
    10/12/16 -> uint16, 32 -> float32); ``ValueError`` for any other depth."""
    if bit_depth == 8:
        return np.dtype(np.uint8)
    if bit_depth in (10, 12, 16):
        return np.dtype(np.uint16)
    if bit_depth == 32:
        return np.dtype(np.float32)
    raise ValueError(f"bit depth must be 8, 10, 12, 16 or 32, got {bit_depth}")


def match_channels(image: np.ndarray, channels: int) -> np.ndarray:
    """``image`` (H, W, C) with ``channels`` channels: as it is when C already matches; grey is
    replicated to RGB (1 -> 3, 1 -> 4, 2 -> 4 keeping alpha) and a missing alpha is opaque
    (3 -> 4), which is how the coordinator's OpenCV probe counts grey+alpha and transparent PNGs.
    Anything that would drop information raises :class:`DecodeError`."""
    have = image.shape[2]
    if have == channels:
        return image
    opaque = np.float32(1.0) if image.dtype == np.float32 else np.iinfo(image.dtype).max
    grey = image[:, :, :1]
    if (have, channels) == (1, 3):
        return np.ascontiguousarray(np.repeat(grey, 3, axis=2))
    if (have, channels) in ((1, 4), (2, 4), (3, 4)):
        out = np.empty(image.shape[:2] + (4,), image.dtype)
        out[:, :, :3] = grey if have < 3 else image
        out[:, :, 3] = image[:, :, 1] if have == 2 else opaque
        return out
    raise DecodeError(f"it decodes to {have} channel(s), not the {channels} its manifest says")


def frame_to_array(frame: av.VideoFrame, channels: int, bit_depth: int,
                   size: tuple[int, int] | None = None) -> np.ndarray:
    """Convert a decoded PyAV frame to ``(H, W, channels)`` C-contiguous in
    :func:`content_dtype` of ``bit_depth`` (see the module docstring for the conversions).

    ``size`` ``(w, h)``: resample to it in the same swscale pass (area averaging when shrinking,
    bilinear when enlarging; pixel centres aligned), which costs less than converting at the
    frame's own size and leaves the renderer a smaller texture to upload. None: the frame's size.
    """
    depth = 8 if bit_depth == 8 else 32 if bit_depth == 32 else 16
    want = 4 if channels == 2 else channels   # swscale has no grey+alpha output PyAV can read
    fmt = _TARGET_FORMATS.get((want, depth))
    if fmt is None:
        raise DecodeError(f"no conversion to {channels} channel(s) at {bit_depth} bits")
    scale = {}
    if size is not None and tuple(size) != (frame.width, frame.height):
        w, h = size
        scale = dict(width=w, height=h, interpolation="AREA" if w * h < frame.width * frame.height else "BILINEAR")
    try:
        arr = frame.to_ndarray(format=fmt, **scale)
    except (av.FFmpegError, ValueError) as exc:
        raise DecodeError(f"cannot convert its {frame.format.name} pixels to {fmt} ({exc})") from exc
    if arr.ndim == 2:
        arr = arr[:, :, None]
    if channels == 2:
        arr = arr[:, :, [0, 3]]
    return np.ascontiguousarray(arr)


def _first_av_frame(path: str | os.PathLike[str], demuxer: str | None) -> av.VideoFrame:
    try:
        with av.open(str(path), mode="r", format=demuxer) as container:
            if not container.streams.video:
                raise DecodeError("it holds no image")
            for frame in container.decode(container.streams.video[0]):
                return frame
    except av.FFmpegError as exc:
        raise DecodeError(f"FFmpeg cannot decode it ({exc})") from exc
    raise DecodeError("it holds no decodable image (empty or truncated)")


def _load_npy(path: str | os.PathLike[str]) -> np.ndarray:
    try:
        mapped = np.load(path, mmap_mode="r", allow_pickle=False)
    except (ValueError, OSError, EOFError) as exc:
        raise DecodeError(f"not a readable .npy array ({exc})") from exc
    if mapped.dtype != np.dtype(np.float32) or mapped.ndim not in (2, 3):
        raise DecodeError(f"a .npy frame must be float32 (H, W) or (H, W, C), got {mapped.dtype} {mapped.shape}")
    arr = np.array(mapped, dtype=np.float32, order="C", copy=True)   # off the mapping: the blob may go
    del mapped
    return arr if arr.ndim == 3 else arr[:, :, None]


def decode_image(path: str | os.PathLike[str], *, name: str, channels: int, bit_depth: int,
                 png: str = "node") -> np.ndarray:
    """Decode one image file of an asset.

    Parameters
    ----------
    path : str or os.PathLike
        The file (a cached blob: its path has no suffix).
    name : str
        The blob's original file name; its suffix says how to decode (``.png``, ``.jpg``,
        ``.jpeg``, ``.tif``, ``.tiff``, ``.npy``; anything else is left to FFmpeg's probing).
    channels, bit_depth : int
        What the manifest says, for the conversion (PyAV) and the channel count.
    png : {"node", "av"}
        PNG path: :func:`node.image_files.decode_png` first (``png_pipe`` for what it refuses)
        or the ``png_pipe`` demuxer only; both are FFmpeg's PNG decoder.

    Returns
    -------
    (H, W, channels) ndarray
        uint8 or uint16 (PNG, JPEG, TIFF), float32 (``.npy``, float TIFF); C-contiguous.

    Raises
    ------
    DecodeError
        Unreadable, corrupt or truncated file, or a channel count that cannot match.
    """
    suffix = Path(name).suffix.lower()
    if suffix == ".npy":
        return match_channels(_load_npy(path), channels)
    if suffix == ".png" and png == "node":
        try:
            img = decode_png(Path(path).read_bytes())
        except PngTooLarge as exc:       # refused from its header: no other decoder may try it
            raise DecodeError(str(exc)) from exc
        except PngError as exc:
            try:
                return frame_to_array(_first_av_frame(path, "png_pipe"), channels, bit_depth)
            except DecodeError as exc2:
                raise DecodeError(f"{exc}; FFmpeg could not decode it either: {exc2}") from exc
        except OSError as exc:
            raise DecodeError(f"cannot read it ({exc})") from exc
        return match_channels(img if img.ndim == 3 else img[:, :, None], channels)
    return frame_to_array(_first_av_frame(path, _IMAGE_DEMUXERS.get(suffix)), channels, bit_depth)


def video_demuxer(name: str, container: str | None = None) -> str | None:
    """FFmpeg's demuxer for a video blob: the probe's ``container`` when FFmpeg has it, else by
    the blob name's suffix, else None (FFmpeg probes the bytes)."""
    if container and container in av.formats_available:
        return container
    return _VIDEO_DEMUXERS.get(Path(name).suffix.lower())


class VideoDecoder:
    """Frames of one video file by index, decoded with PyAV.

    Frame ``k`` is the frame whose timestamp is ``k`` frame periods after the first frame's:
    ``k = round((pts - pts0) * time_base * rate)``, so a frame's index comes from its own
    timestamp, never from counting after a seek. Reading ``k, k+1, k+2, ...`` decodes straight
    on. A jump seeks when that is cheaper: backwards always; forwards when the stream's index
    knows a keyframe after the current position and at or before ``k`` (without an index: when
    the jump is longer than ``max_forward`` frames). A seek lands on the keyframe at or before
    frame ``k`` (half a period of slack) and decodes forward to exactly ``k``, converting only
    that frame. When the first frame after a seek is already past ``k`` (open GOPs, imprecise
    indexes) it seeks 1, 2, 4, ... seconds earlier, and from the very start last. A frame
    missing from the stream (a gap in its timestamps, a stream up to 2 frames shorter than the
    manifest says) shows the frame before it; a stream that ends earlier (truncated) is an error.

    Not thread-safe: one thread reads (:class:`node.asset_frames.DecodeAhead`'s worker). The
    file is opened on the first :meth:`read`. ``seeks`` and ``decoded`` (frames out of the
    decoder, skipped ones included) count the work done.

    ``yuv``: a 3-channel video's frames come as :class:`protos.yuv.YuvFrame` (the decoder's
    planes, converted to RGB by the renderer's shader, scaled to ``size`` there) when the shader
    covers their format (:mod:`node.yuv`), else as arrays from swscale, said once in the log.
    ``decoder``: the wish :func:`node.decoders.choose` resolves per stream ("auto", "software",
    a decoder's name, a hardware device type); :attr:`choice` is the decoder in use. A hardware
    decoder that fails on the stream's first picture is passed over for software, said once.
    """

    def __init__(self, path: str | os.PathLike[str], *, frames: int, channels: int, bit_depth: int,
                 rate: Fraction | None = None, demuxer: str | None = None, threads: int = 0,
                 max_forward: int | None = None, size: tuple[int, int] | None = None, yuv: bool = False,
                 decoder: str = "software") -> None:
        self.path = str(path)
        self.yuv = yuv and channels == 3
        self.wish = decoder
        self.choice: DecoderChoice | None = None     # the decoder in use, once open
        self._ctx = None                           # a decoder by name: its own codec context
        self._rgb_noted = False
        self.size = size          # (w, h) frames are resampled to (None: the video's own)
        self.frames = frames
        self.channels = channels
        self.bit_depth = bit_depth
        self.seeks = 0
        self.decoded = 0
        self._rate_hint = rate
        self._demuxer = demuxer
        self._threads = threads
        self._max_forward = max_forward
        self._container = None
        self._stream = None
        self._gen = None
        self._pts0: int | None = None
        self._pending: tuple[int, av.VideoFrame] | None = None   # decoded, not yet passed
        self._prev: tuple[int, av.VideoFrame] | None = None      # the last frame passed
        self._last: tuple[int, np.ndarray] | None = None         # the last frame returned
        self._keyframes: list[int] | None = None

    # ------------------------------------------------------------------ opening
    def _open_file(self, hwaccel=None):
        try:
            container = av.open(self.path, mode="r", format=self._demuxer, hwaccel=hwaccel)
        except (av.FFmpegError, OSError) as exc:
            raise DecodeError(f"cannot open the video ({exc})") from exc
        if not container.streams.video:
            container.close()
            raise DecodeError("the file holds no video stream")
        return container

    def _frames(self):
        """The decoded frames from the container's position on (a decoder by name: through its own context)."""
        if self._ctx is None:
            return self._container.decode(self._stream)
        ctx = self._ctx
        ctx.flush_buffers()
        return (f for packet in self._container.demux(self._stream) for f in ctx.decode(packet))

    def _open(self) -> None:
        container = self._open_file()
        stream = container.streams.video[0]
        if self.choice is None:
            self.choice = choose(stream.codec_context.name, self.wish)
        self._ctx = None
        if self.choice.kind == "hwaccel":
            container.close()
            container = self._open_file(self.choice.hwaccel)
            stream = container.streams.video[0]
        elif self.choice.kind == "decoder":
            try:
                ctx = av.CodecContext.create(self.choice.name, "r")
                ctx.extradata = stream.codec_context.extradata
                ctx.width, ctx.height = stream.codec_context.width, stream.codec_context.height
                self._ctx = ctx
            except Exception as exc:   # noqa: BLE001 - it opened when probed: say so, use software
                self._software(f"{self.choice.name} failed on this stream ({exc})", stream.codec_context.name)
        stream.codec_context.thread_type = THREAD_TYPE
        stream.codec_context.thread_count = self._threads
        rate = self._rate_hint or stream.average_rate or stream.guessed_rate
        if not rate or stream.time_base is None:
            container.close()
            raise DecodeError("the video stream has no frame rate or time base")
        self._container, self._stream = container, stream
        self._tb, self._rate = Fraction(stream.time_base), Fraction(rate)
        self._gen = self._frames()
        self._prev = self._pending = None
        try:
            first = self._pull()
        except DecodeError as exc:
            if self.choice.kind == "software":
                raise
            self._software(f"{self.choice.describe()} failed on its first picture ({exc})", self.choice.codec)
            self.close()
            return self._open()
        if first is None:
            raise DecodeError("the video stream has no decodable frames")
        if self._pts0 is None:
            ts = first.pts if first.pts is not None else first.dts
            self._pts0 = ts if ts is not None else 0
        self._pending = (self._index(first, 0), first)

    def _reopen(self) -> None:
        self.close()
        self._open()
        self.seeks += 1

    def close(self) -> None:
        """Close the file (a later :meth:`read` opens it again). Idempotent."""
        if self._gen is not None:
            self._gen.close()
        if self._container is not None:
            self._container.close()
        self._container = self._stream = self._gen = self._ctx = None
        self._prev = self._pending = self._last = None

    def _software(self, why: str, codec: str) -> None:
        log.warning("video %s: %s; decoding it in software", Path(self.path).name[:12], why)
        self.choice = DecoderChoice(codec, codec, "software", note=why)

    # ------------------------------------------------------------------ time <-> index
    def _index(self, frame: av.VideoFrame, counted: int | None) -> int:
        ts = frame.pts if frame.pts is not None else frame.dts
        if ts is None:
            if counted is None:
                raise DecodeError("the video has frames without timestamps: they cannot be found after a seek")
            return counted
        return self._index_of_ts(ts)

    def _ts_of(self, k: int) -> int:
        """Stream timestamp half a period after frame ``k``'s nominal time."""
        num = (2 * k + 1) * self._tb.denominator * self._rate.denominator
        return self._pts0 + num // (2 * self._tb.numerator * self._rate.numerator)

    def _keyframe_indices(self) -> list[int]:
        """Frame indices of the keyframes the demuxer's index knows (empty: no index). MP4 indexes
        decode times, which trail presentation times by the reordering delay: the first entry's
        lag behind the first frame's timestamp is added back (MKV cues hold presentation times)."""
        if not self._keyframes:   # (MKV reads its cues at the first seek: ask again while empty)
            try:
                entries = self._stream.index_entries
                ts = [e.timestamp for e in entries if e.is_keyframe]
                lag = max(0, self._pts0 - entries[0].timestamp) if ts else 0
            except (AttributeError, av.FFmpegError):
                ts, lag = [], 0
            self._keyframes = sorted(self._index_of_ts(t + lag) for t in ts)
        return self._keyframes

    def _index_of_ts(self, ts: int) -> int:
        """The frame index of stream timestamp ``ts``, rounded to the nearest period."""
        num = (ts - self._pts0) * self._tb.numerator * self._rate.numerator
        den = self._tb.denominator * self._rate.denominator
        return (2 * num + den) // (2 * den)

    # ------------------------------------------------------------------ decoding
    def _pull(self) -> av.VideoFrame | None:
        try:
            frame = next(self._gen)
        except StopIteration:
            return None
        except av.FFmpegError as exc:
            self._gen.close()
            self._gen = self._frames()
            self._prev = self._pending = None   # position unknown: the next read seeks
            raise DecodeError(f"decoding failed ({exc})") from exc
        self.decoded += 1
        return frame

    def _position(self) -> int | None:
        """Index of the next frame out of the decoder (None: unknown, after a seek or an error)."""
        if self._pending is not None:
            return self._pending[0]
        return None if self._prev is None else self._prev[0] + 1

    def _worth_seeking(self, pos: int, k: int) -> bool:
        if k - pos <= 1:
            return False
        keyframes = self._keyframe_indices()
        if keyframes:
            i = bisect_right(keyframes, k)
            return i > 0 and keyframes[i - 1] > pos
        limit = self._max_forward if self._max_forward is not None else max(16, round(self._rate))
        return k - pos > limit

    def _forward(self, k: int) -> av.VideoFrame | None:
        """Decode on to frame ``k``; None when the first frame out is already past it (seek earlier)."""
        while True:
            if self._pending is not None:
                idx, frame = self._pending
                self._pending = None
            else:
                frame = self._pull()
                if frame is None:   # end of stream: hold the last frame, if it is close
                    if self._prev is not None and k - self._prev[0] <= _EOF_SLACK:
                        return self._prev[1]
                    last = "" if self._prev is None else f" (after frame {self._prev[0]})"
                    raise DecodeError(f"the video ends before frame {k}{last}: the file is truncated or "
                                      "shorter than its manifest says")
                idx = self._index(frame, None if self._prev is None else self._prev[0] + 1)
            if idx < k:
                self._prev = (idx, frame)
                continue
            if idx == k:
                self._prev = (idx, frame)
                return frame
            self._pending = (idx, frame)
            return None if self._prev is None else self._prev[1]   # no frame k: hold the one before

    def _seek(self, k: int) -> av.VideoFrame:
        back = 0
        while True:
            target = max(k - back, 0)
            try:
                self._container.seek(self._ts_of(target) if target else self._pts0, stream=self._stream,
                                     backward=True)
            except av.FFmpegError:
                self._reopen()          # not seekable: decode from the start
            else:
                self.seeks += 1
                self._gen.close()
                self._gen = self._frames()
                self._prev = self._pending = None
            frame = self._forward(k)
            if frame is not None:
                return frame
            if target == 0:
                self._reopen()
                frame = self._forward(k)
                if frame is not None:
                    return frame
                raise DecodeError(f"frame {k} precedes the video's first frame")
            back = 2 * back if back else max(1, round(self._rate))

    def read(self, k: int) -> np.ndarray | YuvFrame:
        """Frame ``k`` (0-based), ``(H, W, channels)`` in :func:`content_dtype` of the bit depth
        (``H, W`` from :attr:`size` when set), or with ``yuv`` a :class:`~protos.yuv.YuvFrame`.

        Reading the same ``k`` twice in a row returns the same array. Raises
        :class:`DecodeError` when the file cannot be opened or decoded.
        """
        if self._container is None:
            self._open()
        if self._last is not None and self._last[0] == k:
            return self._last[1]
        pos = self._position()
        frame = None
        if pos is not None and pos <= k and not self._worth_seeking(pos, k):
            frame = self._forward(k)
        if frame is None:
            frame = self._seek(k)
        # a decoder by name (V4L2 M2M) lends out a fixed set of buffers: its frames are copied, so that
        # the frames decoded ahead do not hold them; other frames' planes are views (node/yuv.py)
        arr = yuv_planes(frame, self.size, copy=True if self.choice.kind == "decoder" else None) if self.yuv else None
        if arr is None:
            if self.yuv and not self._rgb_noted:
                self._rgb_noted = True
                log.info("video %s: %s; converting its frames to RGB on the CPU (swscale)", Path(self.path).name[:12],
                         why_not(frame))
            arr = frame_to_array(frame, self.channels, self.bit_depth, self.size)
        self._last = (k, arr)
        return arr
