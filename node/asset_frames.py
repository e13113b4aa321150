"""The node's frame source: frame ``k`` of a cached asset, decoded ahead of its time.

Timeline playback asks, for each upcoming frame period, for frame ``k`` of asset ``A``, ready
to upload. :func:`open_frames` gives a :class:`FrameSource` for an asset whose blobs are all in
the node's :class:`~node.asset_cache.AssetCache`; :meth:`FrameSource.frame` returns frame ``k``
as ``(H, W, C)`` in the dtype :meth:`node.render.renderer.Renderer.upload` takes as it is: uint8
for 8-bit content, uint16 for 10/12/16-bit (scaled to the full 16-bit range), float32 for float;
``C`` the manifest's channel count (1 grey, 3 RGB; 2 and 4 carry alpha), RGB order. Arrays are
C-contiguous and read-only (one frame may be handed out more than once).

* ``still``: decoded once, on the first request (PNG with :mod:`node.image_files`, ``.npy`` with numpy,
  JPEG/TIFF with PyAV).
* ``sequence``: frame ``k`` decoded from blob ``k`` (PNG with PyAV's ``png_pipe``, same
  pixels as :mod:`node.image_files`; see :mod:`node.asset_decode`).
* ``video``: :class:`node.asset_decode.VideoDecoder`: sequential decoding, seeking for jumps,
  frame index from each frame's timestamp. With ``yuv`` (:func:`open_frames`) an RGB video's
  frames come as :class:`protos.yuv.YuvFrame`, the decoder's planes, which the renderer converts
  and scales on the GPU (a 1080p 4:2:0 frame holds 3.1 MB instead of 6.2 MB of RGB); formats the
  shader does not cover still come as arrays.

:class:`DecodeAhead` runs a source on a background thread that keeps the next ``depth`` frames
of the expected order decoded. **Memory**: it holds at most ``depth`` decoded frames (the
current one included) plus the one being decoded, and fewer of large frames: no more than
:data:`AHEAD_BYTES` of them, but always :data:`MIN_AHEAD` (133 ms at 30 fps, more than a CPU
budget's throttled stretch of 60 ms). A 1080p 4:2:0 frame is 3.1 MB (4 frames ahead instead of
8: 12 MB less), a 1080p RGB uint8 frame 6.2 MB, 10/12/16-bit content doubles that; frames of
640x360 and smaller keep the whole ``depth``. A video decoder adds its own reference frames
(H.264/HEVC: up to 16 YUV frames of 3.1 MB at 1080p 8-bit, plus one in flight per frame
thread); YUV frames handed over as views of the decoder's buffers (:mod:`node.yuv`) are those
buffers, held until the frame leaves the window.

Failures are :class:`FrameError` (a :class:`~node.errors.NodeError`) naming the asset and the
frame, with the decoder's reason.
"""
from __future__ import annotations

import itertools
import logging
import threading
import time
from collections import deque
from dataclasses import dataclass
from fractions import Fraction
from typing import Callable, Iterable, Iterator

import numpy as np

from node.asset_cache import AssetCache
from node.asset_decode import DecodeError, VideoDecoder, content_dtype, decode_image, match_channels, video_demuxer
from node.errors import NodeError
from protos.asset_manifest import Manifest
from protos.yuv import YuvFrame

log = logging.getLogger(__name__)

__all__ = ["DecodeAhead", "DecodeError", "DecodeStats", "FrameError", "FrameNotReady", "FrameSource", "open_frames"]

_TIMINGS_KEPT = 512
#: decoded frames ahead hold at most this many bytes (but always MIN_AHEAD frames)
AHEAD_BYTES = 12 * 2**20
#: frames decoded ahead whatever their size (when depth allows)
MIN_AHEAD = 4


def frame_bytes(frame) -> int:
    """Bytes of a decoded frame: an array's, or the sum of a :class:`YuvFrame`'s planes."""
    planes = getattr(frame, "planes", None)
    if planes is not None:
        return sum(int(p.nbytes) for p in planes)
    return int(getattr(frame, "nbytes", 0))


class FrameError(NodeError):
    """A frame of an asset could not be produced; the message names the asset and the frame."""


class FrameNotReady(FrameError, TimeoutError):
    """:meth:`DecodeAhead.get` ran out of time before the frame was decoded (it still will be)."""


def _what(asset_id: str, m: Manifest) -> str:
    return f"asset {asset_id[:12]} ({m.name!r}, {m.kind})" if m.name else f"asset {asset_id[:12]} ({m.kind})"


class FrameSource:
    """The frames of one cached asset, by index (see the module docstring).

    Properties come from the manifest: ``kind``, ``width``, ``height``, ``channels``,
    ``bit_depth``, ``frames``, ``fps``; ``dtype``, ``shape`` (H, W, C) and ``frame_bytes`` describe
    what :meth:`frame` returns. Not thread-safe: one thread calls :meth:`frame` (give the source
    to a :class:`DecodeAhead` to decode on its thread). Use as a context manager or :meth:`close`.
    """

    def __init__(self, cache: AssetCache, asset_id: str, manifest: Manifest) -> None:
        self.asset_id = asset_id
        self.manifest = manifest
        self.dtype = content_dtype(manifest.bit_depth)
        self.shape = (manifest.height, manifest.width, manifest.channels)
        self._cache = cache
        self._closed = False

    kind = property(lambda self: self.manifest.kind)
    width = property(lambda self: self.manifest.width)
    height = property(lambda self: self.manifest.height)
    channels = property(lambda self: self.manifest.channels)
    bit_depth = property(lambda self: self.manifest.bit_depth)
    frames = property(lambda self: self.manifest.frames)
    fps = property(lambda self: self.manifest.fps)

    @property
    def frame_bytes(self) -> int:
        """Bytes of one decoded frame."""
        return int(np.prod(self.shape)) * self.dtype.itemsize

    def describe(self, k: int | None = None) -> str:
        """``asset 1a2b3c4d5e6f ('name', video)`` [``frame k``]: how errors name the frame."""
        text = _what(self.asset_id, self.manifest)
        return text if k is None else f"{text} frame {k}"

    def check_index(self, k: int) -> int:
        """``k`` as an int in ``0..frames-1``; ``ValueError`` otherwise."""
        if isinstance(k, bool) or not isinstance(k, (int, np.integer)) or not 0 <= k < self.frames:
            raise ValueError(f"{self.describe()} has frames 0..{self.frames - 1}, not {k!r}")
        return int(k)

    def frame(self, k: int) -> np.ndarray:
        """Frame ``k`` as ``(H, W, C)`` ``dtype``, C-contiguous, read-only.

        Raises
        ------
        ValueError
            ``k`` is not a frame index of the asset.
        FrameError
            The source is closed, or the frame's blob is missing, unreadable, corrupt or of
            another size, channel count or depth than the manifest says.
        """
        if self._closed:
            raise FrameError(f"{self.describe(k)}: the frame source is closed")
        k = self.check_index(k)
        try:
            arr = self._decode(k)
            if isinstance(arr, YuvFrame):
                return arr
            arr = match_channels(arr, self.channels)
        except Exception as exc:   # every decoder failure becomes one clear error
            raise FrameError(f"{self.describe(k)}: {exc}") from exc
        if arr.shape != self.shape or arr.dtype != self.dtype:
            raise FrameError(f"{self.describe(k)} decodes to {arr.shape} {arr.dtype}, but its manifest says "
                             f"{self.shape} {self.dtype} ({self.bit_depth}-bit)")
        if arr.flags.writeable:
            arr.flags.writeable = False
        return arr

    def _decode(self, k: int) -> np.ndarray:
        raise NotImplementedError

    def _image(self, index: int, *, png: str) -> np.ndarray:
        blob = self.manifest.blobs[index]
        return decode_image(self._cache.blob_path(blob.sha256), name=blob.name, channels=self.channels,
                            bit_depth=self.bit_depth, png=png)

    def close(self) -> None:
        """Release files and decoded data. Idempotent."""
        self._closed = True

    def __enter__(self) -> "FrameSource":
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


class _StillFrames(FrameSource):
    _image_cache: np.ndarray | None = None

    def _decode(self, k: int) -> np.ndarray:
        if self._image_cache is None:
            self._image_cache = self._image(0, png="node")
        return self._image_cache

    def frame(self, k: int) -> np.ndarray:
        arr = super().frame(k)
        self._image_cache = arr      # conformed and read-only: handed out as it is from now on
        return arr

    def close(self) -> None:
        self._image_cache = None
        super().close()


class _SequenceFrames(FrameSource):
    def _decode(self, k: int) -> np.ndarray:
        return self._image(k, png="av")


class _VideoFrames(FrameSource):
    def __init__(self, cache: AssetCache, asset_id: str, manifest: Manifest, *, threads: int = 0,
                 size: tuple[int, int] | None = None, yuv: bool = False, decoder: str = "software") -> None:
        super().__init__(cache, asset_id, manifest)
        self._threads = threads
        self._yuv, self._wish = yuv, decoder
        self.size = size
        if size is not None:
            self.shape = (size[1], size[0], manifest.channels)
        self.decoder: VideoDecoder | None = None

    def _rate(self) -> Fraction:
        text = str(self.manifest.extra.get("rate", ""))
        try:
            num, _, den = text.partition("/")
            rate = Fraction(int(num), int(den or 1))
            if rate > 0:
                return rate
        except (ValueError, ZeroDivisionError):
            pass
        return Fraction(self.manifest.fps).limit_denominator(1001000)

    def _decode(self, k: int) -> np.ndarray:
        if self.decoder is None:
            blob = self.manifest.blobs[0]
            self.decoder = VideoDecoder(self._cache.blob_path(blob.sha256), frames=self.frames,
                                        channels=self.channels, bit_depth=self.bit_depth, rate=self._rate(),
                                        demuxer=video_demuxer(blob.name, self.manifest.extra.get("container")),
                                        threads=self._threads, size=self.size, yuv=self._yuv,
                                        decoder=self._wish)
        return self.decoder.read(k)

    def close(self) -> None:
        if self.decoder is not None:
            self.decoder.close()
        super().close()


def open_frames(cache: AssetCache, asset_id: str, *, threads: int = 0,
                size: tuple[int, int] | None = None, yuv: bool = False, decoder: str = "software") -> FrameSource:
    """The frame source of a cached asset whose blobs are all complete.

    Parameters
    ----------
    cache : AssetCache
        The node's cache holding the asset.
    asset_id : str
        The asset.
    threads : int
        Decoder threads for a video (0: FFmpeg picks, one per core).
    size : (w, h), optional
        A video's frames come resampled to this size, in the decoder's conversion (the content
        size the node warps from: cheaper than converting and uploading a larger frame). Stills
        and image sequences come at their own size.
    yuv : bool
        A video's frames come as :class:`protos.yuv.YuvFrame` where the renderer's shader
        converts their format (``size`` then rides along: the GPU scales).
    decoder : str
        The video decoder wish (:func:`node.decoders.choose`): "software", "auto", a name.

    Raises
    ------
    FrameError
        The asset is not in the cache, or not all of its blobs are there yet. Nothing is
        decoded here: decoding errors surface on :meth:`FrameSource.frame`.
    """
    try:
        m = cache.manifest(asset_id)
    except NodeError as exc:
        raise FrameError(f"cannot play asset {str(asset_id)[:12]}: {exc}") from exc
    if not cache.ready(asset_id):
        missing = cache.missing(asset_id)
        raise FrameError(f"cannot play {_what(asset_id, m)} yet: {len(missing)} of its {len(m.blobs)} blob(s) "
                         "are still to fetch")
    if m.kind == "still":
        return _StillFrames(cache, asset_id, m)
    if m.kind == "sequence":
        return _SequenceFrames(cache, asset_id, m)
    return _VideoFrames(cache, asset_id, m, threads=threads, size=size, yuv=yuv, decoder=decoder)


@dataclass(frozen=True)
class DecodeStats:
    """What a :class:`DecodeAhead` did: ``hits`` (``get`` found the frame decoded), ``misses``
    (it had to wait for it), ``jumps`` (misses outside the expected order, which restart it at
    the frame asked for), ``decoded`` frames and ``errors``, decode time per frame over the last
    512 decodes, and the frames ``buffered`` now (at most ``depth``)."""

    hits: int
    misses: int
    jumps: int
    decoded: int
    errors: int
    decode_ms_p50: float
    decode_ms_p99: float
    buffered: int
    depth: int


class DecodeAhead:
    """Decode a :class:`FrameSource`'s frames ahead of use on a background thread.

    The expected order is a stream of frame indices (:meth:`expect`, or :meth:`want` for
    ``k, k+1, ...``, wrapping with ``loop``); the thread keeps the first ``depth`` of them
    decoded (repeated indices are decoded once: a paused show costs one frame). :meth:`get`
    consumes the order up to the frame asked for: a frame in the order that is decoded is a
    hit; one not decoded yet is a miss (the call waits for it); one outside the order is a miss
    and a jump (the order restarts at it, ``k, k+1, ...``, and the call waits, the thread
    decoding it first). The iterable given to :meth:`expect` is only read on the callers'
    threads, when they call :meth:`expect` or :meth:`get`.

    The source belongs to the object from then on (it is not thread-safe): :meth:`close`
    stops and joins the thread, then closes the source. Memory: see the module docstring.
    """

    def __init__(self, source: FrameSource, *, depth: int = 8, loop: bool = False) -> None:
        if isinstance(depth, bool) or not isinstance(depth, int) or depth < 1:
            raise ValueError(f"depth must be a positive integer, got {depth!r}")
        self.source = source
        self.depth = depth
        self.loop = loop
        self._ahead = depth       # frames of the window decoded ahead (fewer of large frames)
        self._cond = threading.Condition()
        self._window: deque[int] = deque()      # the next frames of the order; [0] is the current one
        self._plan: Iterator[int] = iter(())    # the rest of the order
        self._ready: dict[int, np.ndarray | FrameError] = {}
        self._closed = False
        self._finished = False    # the thread left its loop (set under the lock)
        self._detached: Callable[[], None] | None = None   # close(wait=False): the thread closes the source, then calls it
        self._linger_s = 0.0
        self._source_closed = False
        self._fatal: BaseException | None = None
        self._hits = self._misses = self._jumps = self._decoded = self._errors = 0
        self._quiet: tuple[int, int] = (0, 0)   # host ns: start no decode within [start, end)
        self._ms: deque[float] = deque(maxlen=_TIMINGS_KEPT)
        self._thread = threading.Thread(target=self._run, name=f"decode-ahead-{source.asset_id[:8]}", daemon=True)
        self._thread.start()

    # ------------------------------------------------------------------ the order (caller side)
    def _sequential(self, k: int, loop: bool) -> Iterator[int]:
        n = self.source.frames
        return (i % n for i in itertools.count(k)) if loop else iter(range(k, n))

    def _fill(self) -> None:
        """Top the window up from the plan and drop decoded frames that left it (lock held)."""
        while len(self._window) < self.depth:
            k = next(self._plan, None)
            if k is None:
                break
            self._window.append(self.source.check_index(k))
        wanted = set(self._window)
        for k in [k for k in self._ready if k not in wanted]:
            del self._ready[k]
        self._cond.notify_all()

    def expect(self, ticks: Iterable[int]) -> None:
        """Set the expected order: the frame indices upcoming, in order (finite or not).
        Frames already decoded that are still expected are kept. ``ValueError`` on an index
        outside the asset (raised when it is reached)."""
        with self._cond:
            self._check_open()
            self._window.clear()
            self._plan = iter(ticks)
            self._fill()

    def want(self, k: int, *, loop: bool | None = None) -> None:
        """Expect ``k, k+1, ...`` (after the last frame: frame 0 again with ``loop``, else the end)."""
        if loop is not None:
            self.loop = loop
        self.expect(self._sequential(self.source.check_index(k), self.loop))

    # ------------------------------------------------------------------ getting frames
    def get(self, k: int, timeout: float) -> np.ndarray:
        """Frame ``k``, waiting at most ``timeout`` seconds for it.

        Returns
        -------
        (H, W, C) ndarray
            As :meth:`FrameSource.frame` returns it (read-only).

        Raises
        ------
        FrameNotReady
            Not decoded within ``timeout`` (it stays first in line: ask again).
        FrameError
            Decoding it failed (the message names the asset and the frame), or the object is
            closed, or its thread died.
        ValueError
            ``k`` is not a frame index of the asset.
        """
        k = self.source.check_index(k)
        deadline = time.monotonic() + max(0.0, timeout)
        with self._cond:
            self._check_open()
            if k in self._window:
                while self._window[0] != k:
                    self._window.popleft()
            else:
                self._jumps += 1
                self._window.clear()
                self._plan = self._sequential(k, self.loop)
            self._fill()
            if k in self._ready:
                self._hits += 1
            else:
                self._misses += 1
                while k not in self._ready and not self._closed and self._fatal is None:
                    left = deadline - time.monotonic()
                    if left <= 0:
                        raise FrameNotReady(f"{self.source.describe(k)} was not decoded within {timeout * 1000:.0f} ms")
                    self._cond.wait(left)
                self._check_open()
            out = self._ready[k]
        if isinstance(out, FrameError):
            raise FrameError(str(out)) from out
        return out

    def ready(self, k: int) -> bool:
        """Whether frame ``k`` is decoded and buffered now (never blocks on decoding)."""
        with self._cond:
            return k in self._ready

    def wait_ahead(self, timeout: float) -> bool:
        """Wait until every expected frame in the window is decoded; whether it happened in time."""
        deadline = time.monotonic() + max(0.0, timeout)
        with self._cond:
            while not self._closed and self._fatal is None and self._next_job() is not None:
                left = deadline - time.monotonic()
                if left <= 0:
                    return False
                self._cond.wait(left)
            return not self._closed and self._fatal is None

    def stats(self) -> DecodeStats:
        """Counters and decode times so far (see :class:`DecodeStats`)."""
        with self._cond:
            ms = np.array(self._ms) if self._ms else np.zeros(1)
            return DecodeStats(hits=self._hits, misses=self._misses, jumps=self._jumps, decoded=self._decoded,
                               errors=self._errors, decode_ms_p50=float(np.percentile(ms, 50)),
                               decode_ms_p99=float(np.percentile(ms, 99)), buffered=len(self._ready),
                               depth=self.depth)

    def _check_open(self) -> None:
        if self._fatal is not None:
            raise FrameError(f"the decode-ahead thread of {self.source.describe()} died: {self._fatal!r}") \
                from self._fatal
        if self._closed:
            raise FrameError(f"the decode-ahead of {self.source.describe()} is closed")

    def quiet(self, start_host_ns: int, end_host_ns: int) -> None:
        """Start no decode between these instants of the host's monotonic clock (a swap's).

        The thread holds the interpreter lock for parts of each decode (a few milliseconds);
        a swap whose thread wakes at real-time priority and then waits for that lock is late
        by as much, more when other processes hold the CPU the decode thread needs to let go
        of it (measured: swaps up to 20 ms late, a few per thousand, four nodes on two cores)."""
        with self._cond:
            self._quiet = (int(start_host_ns), int(end_host_ns))
            self._cond.notify_all()

    def _keep_quiet(self) -> None:
        """Wait while the quiet window holds; a window set meanwhile (moved, cut short) is followed."""
        with self._cond:
            while not self._closed:
                start, end = self._quiet
                now = time.monotonic_ns()
                if not start <= now < end:
                    return
                self._cond.wait((end - now) / 1e9)

    # ------------------------------------------------------------------ the thread
    def _next_job(self) -> int | None:
        """The first frame of the window's first ``_ahead`` not decoded yet (lock held)."""
        for k in itertools.islice(self._window, self._ahead):
            if k not in self._ready:
                return k
        return None

    def _run(self) -> None:
        try:
            while True:
                with self._cond:
                    while not self._closed and (k := self._next_job()) is None:
                        self._cond.wait()
                    if self._closed:
                        return
                self._keep_quiet()
                t0 = time.perf_counter()
                try:
                    out: np.ndarray | FrameError = self.source.frame(k)
                except FrameError as exc:
                    out = exc
                except ValueError as exc:     # an index the source refuses: keep it with the frame
                    out = FrameError(f"{self.source.describe(k)}: {exc}")
                ms = (time.perf_counter() - t0) * 1000.0
                with self._cond:
                    self._decoded += 1
                    if isinstance(out, FrameError):
                        self._errors += 1
                    else:
                        self._ms.append(ms)
                        size = frame_bytes(out)
                        self._ahead = min(self.depth, max(MIN_AHEAD, AHEAD_BYTES // size if size else self.depth))
                    if k in self._window:
                        self._ready[k] = out
                    self._cond.notify_all()
        except BaseException as exc:   # noqa: BLE001 - surfaces on the callers' next get
            with self._cond:
                self._fatal = exc
                self._cond.notify_all()
        finally:
            with self._cond:
                self._finished = True
                then, linger = self._detached, self._linger_s
            if then is not None:
                if linger > 0:
                    time.sleep(linger)     # this thread's last act: nothing waits for it
                try:
                    self._close_source(then)
                except Exception:  # noqa: BLE001 - nobody is left to raise it to
                    log.exception("closing %s after its show let it go", self.source.asset_id[:12])

    def _close_source(self, then: Callable[[], None] | None = None) -> None:
        """Close the source once, whoever gets here first; then call ``then``."""
        with self._cond:
            if self._source_closed:
                return
            self._source_closed = True
        self.source.close()
        if then is not None:
            then()

    def close(self, *, wait: bool = True, then: Callable[[], None] | None = None, linger_s: float = 0.0) -> None:
        """Stop the thread (it finishes the frame it is decoding), join it, close the source.
        Idempotent. ``wait=False``: return at once; the thread closes the source itself once the
        frame it is decoding is done (the caller's thread never waits for a decode). ``then`` is called
        after the source's close, on the thread that closed it, by the call that closed it (not by a
        later one): e.g. :func:`node.heap_trim.trim_now`, the decoder's memory given back there.
        ``linger_s`` (with ``wait=False``): the thread waits this long first, so that the close and
        ``then`` fall after a swap the caller is about to make."""
        with self._cond:
            self._closed = True
            self._window.clear()
            self._ready.clear()
            if not wait:
                self._detached = then or (lambda: None)
                self._linger_s = max(0.0, float(linger_s))
            finished = self._finished
            self._cond.notify_all()
        if not wait:
            if finished:       # the thread is gone (or going) and did not see the request
                self._close_source(then)
            return
        if self._thread.is_alive() and self._thread is not threading.current_thread():
            self._thread.join()
        self._close_source(then)

    def closed(self) -> bool:
        """Whether the source is closed (after :meth:`close`; with ``wait=False``, once the thread closed it)."""
        with self._cond:
            return self._source_closed

    def __enter__(self) -> "DecodeAhead":
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
