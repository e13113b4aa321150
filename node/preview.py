"""Previews: small pictures of what the projector shows, for the operator console's thumbnails.

The coordinator asks (about once a second, only while someone looks); the presenter makes one
between frames, never between a frame's render and its swap and never when it would not fit
before the next frame is due (:meth:`node.presenter.Presenter`), at most one per
:data:`MIN_INTERVAL_NS` whatever it is asked. A preview is the renderer's output read back a band
of rows at a time (:meth:`node.render.renderer.Renderer.read_rows`), area-averaged down to at most
:data:`MAX_WIDTH` x :data:`MAX_HEIGHT` pixels (numpy, see :func:`downscale`) and encoded as an
8-bit RGB PNG (:func:`node.image_files.encode_png`): at most ~58 kB, usually a few kB.
"""
from __future__ import annotations

import math
import statistics
from collections import deque
from typing import TYPE_CHECKING, Callable

import numpy as np

from node.image_files import encode_png
from node.records import PreviewRecord

if TYPE_CHECKING:  # pragma: no cover
    from node.render.renderer import Renderer

MAX_WIDTH = 160
MAX_HEIGHT = 120
#: at most one preview per half second (two a second), whatever the coordinator asks
MIN_INTERVAL_NS = 500_000_000
#: what a preview is assumed to cost before one was timed (the presenter times one at open)
FIRST_COST_NS = 5_000_000


def preview_factor(width: int, height: int) -> int:
    """The block side k (>= 1) that brings a ``width`` x ``height`` output within MAX_WIDTH x MAX_HEIGHT."""
    return max(1, math.ceil(width / MAX_WIDTH), math.ceil(height / MAX_HEIGHT))


def downscale(image: np.ndarray, factor: int | None = None) -> np.ndarray:
    """Area-average an output image down to a preview.

    Parameters
    ----------
    image : (H, W, 3) uint8
        What the projector receives (RGB, row 0 at the top).
    factor : int, optional
        The block side k; default :func:`preview_factor` of the image's size.

    Returns
    -------
    (ceil(H / k), ceil(W / k), 3) uint8
        Each pixel the mean of a k x k block of ``image`` rounded to the nearest integer (the
        blocks of the last row and column are cut short by the image's edge). k = 1: a copy.
    """
    img = np.asarray(image)
    if img.ndim != 3 or img.shape[2] != 3 or img.dtype != np.uint8:
        raise ValueError(f"a preview is made of an (H, W, 3) uint8 image, got {img.shape} {img.dtype}")
    h, w = img.shape[:2]
    k = preview_factor(w, h) if factor is None else int(factor)
    if k < 1:
        raise ValueError(f"the block side must be >= 1, got {factor!r}")
    if k == 1:
        return np.array(img, order="C")
    # k strided adds per axis (contiguous rows first): ~2 ms for 1920x1080 where a reshape's
    # sum over two axes takes ~40 ms; the row sums fit uint16 up to k = 257
    hb, wb = -(-h // k), -(-w // k)
    rows = np.zeros((hb, w, 3), np.uint16 if k <= 257 else np.uint32)
    for i in range(k):
        part = img[i::k]
        rows[: part.shape[0]] += part
    sums = np.zeros((hb, wb, 3), np.uint32)
    for j in range(k):
        part = rows[:, j::k]
        sums[:, : part.shape[1]] += part
    per_row = np.full(hb, k, np.uint32)
    per_row[-1] = h - (hb - 1) * k
    per_col = np.full(wb, k, np.uint32)
    per_col[-1] = w - (wb - 1) * k
    n = (per_row[:, None] * per_col[None, :])[:, :, None]
    return ((sums + n // 2) // n).astype(np.uint8)


#: the rows of the output a preview reads back at a time, at most (whole blocks of the preview's factor)
BAND_ROWS = 96


def downscale_rendered(renderer: "Renderer") -> np.ndarray:
    """:func:`downscale` of what ``renderer`` holds (``downscale(renderer.read())``, the same pixels),
    read back a band of whole blocks at a time (:meth:`Renderer.read_rows`): a preview never holds
    the full-size picture, which at 1080p the presenter kept resident twice over (6 MB read back,
    6 MB left to the allocator by the flip) for a picture of at most 160 x 120.

    Returns
    -------
    (ceil(height / k), ceil(width / k), 3) uint8, k = :func:`preview_factor` of the output's size.
    """
    w, h = renderer.width, renderer.height
    k = preview_factor(w, h)
    band = k * max(1, BAND_ROWS // k)
    return np.concatenate([downscale(renderer.read_rows(top, min(band, h - top)), k) for top in range(0, h, band)])


def encode_preview(small: np.ndarray) -> bytes:
    """(h, w, 3) uint8 -> PNG bytes (fast zlib level: the picture is small and made between frames)."""
    return encode_png(small, compress_level=3, filter="paeth")


class PreviewMaker:
    """The presenter's previews: the request waiting, whether one may be made, what one costs.

    Parameters
    ----------
    now : callable
        The presenter's clock, local nanoseconds (a test's clock moves only when told to).
    min_interval_ns : int
        The least time between two previews.
    """

    def __init__(self, now: Callable[[], int], *, min_interval_ns: int = MIN_INTERVAL_NS):
        self.now = now
        self.min_interval_ns = min_interval_ns
        self.pending = 0          # the newest request not yet answered (0: none)
        self.made = 0             # previews made
        self.deferred = 0         # times a wanted preview waited: it would not have fit before the next frame
        self._last_ns: int | None = None
        self._costs: deque[int] = deque(maxlen=8)

    def request(self, request_id: int) -> None:
        """The coordinator asked for a preview (requests coalesce: the newest is answered)."""
        self.pending = max(1, int(request_id))

    def due(self) -> bool:
        """A preview is wanted and none was made within the interval."""
        return bool(self.pending) and (self._last_ns is None or self.now() - self._last_ns >= self.min_interval_ns)

    @property
    def cost_ns(self) -> int:
        """What a preview takes (read-back, downscale, PNG): the median of the last few, ns of the
        presenter's clock (one slow one does not keep the next from fitting between frames)."""
        return int(statistics.median(self._costs)) if self._costs else FIRST_COST_NS

    def make(self, renderer: "Renderer", frame_id: int) -> PreviewRecord:
        """Read back what the renderer holds (the caller makes sure it is what the projector shows)
        and answer the pending request with it."""
        t0 = self.now()
        small = downscale_rendered(renderer)
        png = encode_preview(small)
        self._costs.append(max(0, self.now() - t0))
        self._last_ns = t0
        request, self.pending = self.pending, 0
        self.made += 1
        return PreviewRecord(request_id=request, frame_id=frame_id, png=png, width=small.shape[1],
                             height=small.shape[0], output_width=renderer.width, output_height=renderer.height)

    def time_once(self, renderer: "Renderer") -> None:
        """Make a preview nobody asked for and keep only its cost (at open: the first real one is not
        the first to run the PNG encoder)."""
        t0 = self.now()
        encode_preview(downscale_rendered(renderer))
        self._costs.append(max(0, self.now() - t0))
