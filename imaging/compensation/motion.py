"""Carry a per-pixel field along the motion between two video frames (for warm starts).

A warm-started frame starts from the previous solution. Added to the *change* of the target
(``x_prev + c_new - c_prev``, :class:`~imaging.compensation.solver.FrameCompensator`'s
default), it follows content that changes in place, but not content that moves: the
compensation's correction ``x - c`` is a sharpening pattern tied to the picture's edges, and
when the picture slides by a pixel the correction must slide with it. Left in place, the error
is a high-frequency image, exactly what the iterations fix slowest (a 1 px/frame pan stays
1.7 dB short of its converged solve after 8 iterations at 960x540). :class:`MotionWarp`
estimates the dense motion from the previous target to the new one (OpenCV's DIS optical flow
on 8-bit pictures, at half resolution by default) and moves the correction along it (``remap``),
so the start is ``c_new + warp(x_prev - c_prev)``.

The move interpolates bicubically by default. The estimated flow is fractional (DIS is about
0.3 px off on a 1 px pan), and at a fractional offset bilinear interpolation is a low-pass filter
(at half a pixel its response at the highest frequency is zero), while the correction is mostly
high frequencies: a bilinear move erased part of what the previous frame's iterations had
built. Measured at 960x540, 25 projectors (``bench compensation``'s clips), the largest shortfall
from converged after 4 iterations went from 0.55 / 0.49 dB (pan / overlay) to 0.41 / 0.46, and
after 5 from 0.41 / 0.32 to 0.30 / 0.32. The bicubic ``remap`` costs more (2.2 against 0.7 ms at
960x540, 9.0 against 2.8 ms at 1920x1080), less than the iteration it saves.

Where the picture does not move, the flow is not exactly zero: around a moving object DIS smears
its motion over the still background, and a correction moved there lands a fraction of a pixel
off. :meth:`MotionWarp.carry` therefore decides per pixel, as a video codec chooses between a
motion-compensated and a static reference: it moves the previous picture along with the field
and keeps the moved field only where the moved picture explains the new one better than the
unmoved picture does (absolute differences summed over a small window); elsewhere the field
stays in place. On a bright disc moving over a still picture (the bench's overlay clip, 960x540,
ridge problem, 4 iterations) this took the largest shortfall from converged from 0.37 to 0.11
dB, and it changes nothing on a pan, where the moved picture wins everywhere.
"""
from __future__ import annotations

import cv2
import numpy as np

from imaging.channel_mean import channel_mean

__all__ = ["MotionWarp", "PRESETS"]

_INTERPOLATIONS = (cv2.INTER_LINEAR, cv2.INTER_CUBIC, cv2.INTER_LANCZOS4)
#: DIS optical flow presets by name, fastest first
PRESETS = {"ultrafast": cv2.DISOPTICAL_FLOW_PRESET_ULTRAFAST, "fast": cv2.DISOPTICAL_FLOW_PRESET_FAST,
           "medium": cv2.DISOPTICAL_FLOW_PRESET_MEDIUM}


class MotionWarp:
    """``warp(field, prev, new)``: ``field``, defined on ``prev``'s picture, moved to ``new``'s.

    Parameters
    ----------
    scale : int
        The flow is estimated on pictures ``scale`` times smaller (area-averaged), then resized
        back (1: full resolution; 2, the default, costs about a quarter and loses little on
        smooth motion).
    interpolation : int
        OpenCV's interpolation of the move: ``cv2.INTER_CUBIC`` (the default, see the module
        docstring), ``cv2.INTER_LINEAR`` or ``cv2.INTER_LANCZOS4``.
    preset : str
        The DIS preset (a key of :data:`PRESETS`): ``"ultrafast"`` (the default, for real time),
        ``"fast"`` or ``"medium"``, each more accurate and slower than the one before.
    window : int
        Side (odd, in the flow's small pixels) of the window over which :meth:`carry` compares the
        moved and the unmoved picture.
    """

    def __init__(self, *, scale: int = 2, interpolation: int = cv2.INTER_CUBIC, preset: str = "ultrafast",
                 window: int = 7) -> None:
        if scale < 1:
            raise ValueError(f"scale must be >= 1, got {scale}")
        if preset not in PRESETS:
            raise ValueError(f"preset must be one of {', '.join(PRESETS)}, got {preset!r}")
        if window < 1 or window % 2 == 0:
            raise ValueError(f"window must be odd and >= 1, got {window}")
        if interpolation not in _INTERPOLATIONS:
            raise ValueError(f"interpolation must be one of cv2.INTER_LINEAR, INTER_CUBIC or INTER_LANCZOS4, "
                             f"got {interpolation!r}")
        self.scale = int(scale)
        self.interpolation = int(interpolation)
        self.preset, self.window = preset, int(window)
        self._dis = cv2.DISOpticalFlow_create(PRESETS[preset])
        self._grids: dict[tuple[int, int], np.ndarray] = {}

    def _shrink(self, img: np.ndarray) -> np.ndarray:
        """A grey (H, W) float32 picture, ``scale`` times smaller (area-averaged)."""
        if self.scale == 1:
            return img
        return cv2.resize(img, None, fx=1 / self.scale, fy=1 / self.scale, interpolation=cv2.INTER_AREA)

    def _grid_for(self, h: int, w: int) -> np.ndarray:
        """(h, w, 2) float32 pixel coordinates (x, y), cached per size."""
        grid = self._grids.get((h, w))
        if grid is None:
            gx, gy = np.meshgrid(np.arange(w, dtype=np.float32), np.arange(h, dtype=np.float32))
            grid = self._grids[(h, w)] = np.dstack([gx, gy])
        return grid

    def _small_flow(self, small_prev: np.ndarray, small_new: np.ndarray) -> np.ndarray | None:
        """DIS flow between the small pictures, in small pixels ((h, w, 2) float32); None when too small."""
        if min(small_new.shape) < 8:  # DIS needs a patch: tiny pictures do not move
            return None
        as_bytes = [np.clip(img * np.float32(255), 0, 255).astype(np.uint8) for img in (small_new, small_prev)]
        return self._dis.calc(as_bytes[0], as_bytes[1], None)

    def _full(self, small_flow: np.ndarray, h: int, w: int) -> np.ndarray:
        """A small flow at full resolution, in full pixels ((h, w, 2) float32)."""
        if self.scale == 1:
            return small_flow
        f = small_flow * np.float32(self.scale)  # scaled while small: a quarter of the pixels
        return cv2.resize(f, (w, h), interpolation=cv2.INTER_LINEAR)

    def _estimate(self, prev: np.ndarray,
                  new: np.ndarray) -> tuple[tuple[int, int], np.ndarray, np.ndarray, np.ndarray | None]:
        """The pictures' full size ``(H, W)``, their grey small versions (``prev``'s, ``new``'s) and the
        small flow between them (:meth:`_small_flow`; colour pictures by their channel mean)."""
        small_prev, small_new = self._shrink(channel_mean(prev)), self._shrink(channel_mean(new))
        return np.shape(new)[:2], small_prev, small_new, self._small_flow(small_prev, small_new)

    def flow(self, prev: np.ndarray, new: np.ndarray) -> np.ndarray:
        """(H, W, 2) float32: for each pixel of ``new``, the offset to where it was in ``prev``."""
        (h, w), _, _, small = self._estimate(prev, new)
        return np.zeros((h, w, 2), dtype=np.float32) if small is None else self._full(small, h, w)

    def _move(self, field: np.ndarray, where: np.ndarray) -> np.ndarray:
        return cv2.remap(field, where, None, self.interpolation, borderMode=cv2.BORDER_REPLICATE)

    def __call__(self, field: np.ndarray, prev: np.ndarray, new: np.ndarray) -> np.ndarray:
        """``field`` moved along the motion from ``prev`` to ``new``: (H, W) or (H, W, C) float32 (C <= 4),
        pictures in [0, 1] of the same size (colour pictures move by their channel mean)."""
        field = np.asarray(field, np.float32)
        h, w = field.shape[:2]
        where = self.flow(prev, new)
        where += self._grid_for(h, w)  # the flow becomes the map: where each pixel of new was in prev
        return self._move(field, where)

    def carry(self, field: np.ndarray, prev: np.ndarray, new: np.ndarray) -> np.ndarray:
        """``field`` moved along the motion where that motion explains ``new`` better than no motion
        (see the module docstring), left in place elsewhere.

        ``field``: (H, W) or (H, W, C) float32, C <= 4; ``prev``, ``new``: (H, W) or (H, W, C')
        pictures in [0, 1] of the field's size (compared by their channel mean). The decision is
        made on the flow's small pictures, over ``window`` x ``window`` of their pixels. Returns a
        new array of ``field``'s shape, float32.
        """
        field = np.asarray(field, np.float32)
        (h, w), small_prev, small_new, small = self._estimate(prev, new)
        if field.shape[:2] != (h, w):
            raise ValueError(f"field {field.shape} and pictures {(h, w)} differ in size")
        out = field.copy()
        if small is None:
            return out
        where = self._full(small, h, w) + self._grid_for(h, w)
        moved = self._move(field, where)
        small_map = where if self.scale == 1 else small + self._grid_for(*small_new.shape)
        back = cv2.remap(small_prev, small_map, None, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
        k = (self.window, self.window)
        use = cv2.compare(cv2.blur(cv2.absdiff(small_new, back), k), cv2.blur(cv2.absdiff(small_new, small_prev), k),
                          cv2.CMP_LT)
        if self.scale > 1:
            use = cv2.resize(use, (w, h), interpolation=cv2.INTER_NEAREST)
        return cv2.copyTo(moved, use, out)
