"""Gray-code structured light: patterns (OpenCV ``structured_light.GrayCodePattern``)
and a vectorised decoder giving dense camera <-> projector correspondences.

The patterns are OpenCV's: for a projector of ``(w, h)`` pixels,
``ceil(log2 w)`` column bits then ``ceil(log2 h)`` row bits, each shown as the
pattern and its inverse (most significant bit first). Decoding compares each
pattern with its inverse at every camera pixel, so no global threshold is
needed; a white and a black reference give the shadow / low-contrast mask.
The bit string seen at a camera pixel is turned into a projector column and
row through lookup tables read from the generated patterns themselves, so the
decoder follows whatever code OpenCV generates.

A Gray code changes one bit between neighbouring columns, so a camera pixel
straddling a stripe edge decodes to one of the two neighbours: the decoded
integer projector pixel differs from the true sub-pixel position by a
zero-mean error in [-0.5, 0.5] (pixel centres at integers, OpenCV's
convention). Fitting a model to thousands of such correspondences averages
that error away; see :mod:`imaging.calibration.planar`.
"""
from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache
from typing import Sequence

import cv2
import numpy as np

from imaging.channel_mean import channel_mean


@dataclass(frozen=True, eq=False)
class GrayCodeLayout:
    """The pattern sequence of one projector size.

    Attributes
    ----------
    size : (int, int)
        Projector (width, height).
    column_bits, row_bits : int
    column_lut : (2**column_bits,) int32
        Bit string (MSB first, pattern brighter than inverse = 1) -> column, -1 if unused.
    row_lut : (2**row_bits,) int32
    """

    size: tuple[int, int]
    column_bits: int
    row_bits: int
    column_lut: np.ndarray
    row_lut: np.ndarray

    @property
    def count(self) -> int:
        """Number of pattern images (pattern + inverse per bit), without the references."""
        return 2 * (self.column_bits + self.row_bits)


def _opencv_generator(size: tuple[int, int]):
    w, h = size
    return cv2.structured_light.GrayCodePattern.create(int(w), int(h))


@lru_cache(maxsize=16)
def _patterns_cached(size: tuple[int, int]) -> tuple[np.ndarray, ...]:
    ok, pats = _opencv_generator(size).generate()
    if not ok:  # pragma: no cover - OpenCV generates for any positive size
        raise ValueError(f"OpenCV cannot generate Gray codes for a {size[0]}x{size[1]} projector")
    out = []
    for p in pats:
        a = np.ascontiguousarray(p, dtype=np.uint8)
        a.setflags(write=False)
        out.append(a)
    return tuple(out)


def _check_size(size) -> tuple[int, int]:
    w, h = (int(v) for v in size)
    if w < 2 or h < 2:
        raise ValueError(f"projector size must be at least 2x2, got {size}")
    return w, h


def gray_patterns(size: tuple[int, int]) -> list[np.ndarray]:
    """The Gray-code patterns for a projector of ``size`` = (w, h).

    Returns
    -------
    list of (h, w) uint8 (0 or 255), read-only: column bits then row bits, each
    as pattern then inverse, most significant bit first.
    """
    return list(_patterns_cached(_check_size(size)))


@lru_cache(maxsize=16)
def gray_layout(size: tuple[int, int]) -> GrayCodeLayout:
    """Bit counts and decoding tables for ``size``, derived from the generated patterns."""
    w, h = _check_size(size)
    pats = _patterns_cached((w, h))
    ncol = int(np.ceil(np.log2(w)))
    nrow = int(np.ceil(np.log2(h)))
    if len(pats) != 2 * (ncol + nrow):  # pragma: no cover - guards an OpenCV change
        raise ValueError(f"unexpected Gray-code sequence: {len(pats)} patterns for {w}x{h}")
    col_codes = np.zeros(w, np.int64)
    for k in range(ncol):
        col_codes = (col_codes << 1) | (pats[2 * k][0, :] > pats[2 * k + 1][0, :])
    row_codes = np.zeros(h, np.int64)
    for k in range(nrow):
        p, q = pats[2 * (ncol + k)], pats[2 * (ncol + k) + 1]
        row_codes = (row_codes << 1) | (p[:, 0] > q[:, 0])
    col_lut = np.full(1 << ncol, -1, np.int32)
    col_lut[col_codes] = np.arange(w, dtype=np.int32)
    row_lut = np.full(1 << nrow, -1, np.int32)
    row_lut[row_codes] = np.arange(h, dtype=np.int32)
    if len(np.unique(col_codes)) != w or len(np.unique(row_codes)) != h:  # pragma: no cover
        raise ValueError("the Gray-code patterns do not give every column and row a unique code")
    for a in (col_lut, row_lut):
        a.setflags(write=False)
    return GrayCodeLayout((w, h), ncol, nrow, col_lut, row_lut)


def luminance(image: np.ndarray) -> np.ndarray:
    """(H, W) float32 from (H, W) or (H, W, C) camera images: the channel mean (less noise than one channel)."""
    a = np.asarray(image, np.float32)
    if a.ndim == 3:
        return channel_mean(a)
    if a.ndim != 2:
        raise ValueError(f"a capture must be (H, W) or (H, W, C), got {a.shape}")
    return a


@dataclass(frozen=True, eq=False)
class GrayDecode:
    """Result of decoding one projector's captures.

    Attributes
    ----------
    projector : (H, W, 2) int32
        Decoded projector pixel (x, y) per camera pixel; -1 where invalid.
    valid : (H, W) bool
        Lit (white - black > ``min_contrast``), with a code that names a real column and row.
    contrast : (H, W) float32
        white - black.
    lit : (H, W) bool
        The shadow mask alone (contrast above the threshold).
    """

    projector: np.ndarray
    valid: np.ndarray
    contrast: np.ndarray
    lit: np.ndarray

    @property
    def count(self) -> int:
        return int(self.valid.sum())

    def correspondences(self) -> tuple[np.ndarray, np.ndarray]:
        """Camera pixel centres and decoded projector pixels of every valid pixel.

        Returns
        -------
        camera : (N, 2) float64   (x, y) camera pixels (integer centres)
        projector : (N, 2) float64 (x, y) projector pixels (integers)
        """
        ys, xs = np.nonzero(self.valid)
        cam = np.column_stack([xs, ys]).astype(np.float64)
        proj = self.projector[ys, xs].astype(np.float64)
        return cam, proj


def decode_gray(captures: Sequence[np.ndarray], *, white: np.ndarray, black: np.ndarray, layout: GrayCodeLayout,
                min_contrast: float = 0.004, min_bit_contrast: float = 0.0) -> GrayDecode:
    """Decode the captures of :func:`gray_patterns` into projector pixels.

    Parameters
    ----------
    captures : sequence of (H, W) or (H, W, C) float32
        One capture per pattern, in the order :func:`gray_patterns` returns them.
    white, black : (H, W) or (H, W, C) float32
        Captures of the projector at full white and at black (the references).
    layout : GrayCodeLayout
        From :func:`gray_layout` for the projector's size.
    min_contrast : float
        Shadow / low-contrast mask: camera pixels with ``white - black`` at or
        below this (fraction of full scale) are invalid.
    min_bit_contrast : float
        Optional stricter mask: a pixel is invalid when, for any bit,
        ``|pattern - inverse|`` is below this fraction of its ``white - black``.
        0 keeps pixels on stripe edges (they decode to a neighbour, which
        is harmless for Gray codes).

    Returns
    -------
    GrayDecode
    """
    if len(captures) != layout.count:
        raise ValueError(f"expected {layout.count} captures for a {layout.size[0]}x{layout.size[1]} projector, got {len(captures)}")
    wl, bl = luminance(white), luminance(black)
    if wl.shape != bl.shape:
        raise ValueError(f"white and black references differ in shape: {wl.shape} vs {bl.shape}")
    contrast = wl - bl
    lit = contrast > np.float32(min_contrast)
    valid = lit.copy()
    col = np.zeros(wl.shape, np.int64)
    row = np.zeros(wl.shape, np.int64)
    limit = np.float32(min_bit_contrast) * contrast if min_bit_contrast > 0 else None
    for k in range(layout.column_bits + layout.row_bits):
        p, q = luminance(captures[2 * k]), luminance(captures[2 * k + 1])
        if p.shape != wl.shape or q.shape != wl.shape:
            raise ValueError(f"capture {2 * k} has shape {p.shape}, the references {wl.shape}")
        diff = p - q
        bit = diff > 0
        if limit is not None:
            valid &= np.abs(diff) >= limit
        if k < layout.column_bits:
            col = (col << 1) | bit
        else:
            row = (row << 1) | bit
    x = layout.column_lut[col]
    y = layout.row_lut[row]
    valid &= (x >= 0) & (y >= 0)
    proj = np.stack([np.where(valid, x, -1), np.where(valid, y, -1)], axis=-1).astype(np.int32)
    return GrayDecode(proj, valid, contrast.astype(np.float32), lit)

