"""Reading the renderer's framebuffer back to the CPU (:meth:`node.render.renderer.Renderer.read`
and :meth:`~node.render.renderer.Renderer.read_rows`), a strip of rows at a time.

A whole picture flipped in place (GL counts rows from the bottom, images from the top) made numpy
buffer it: a second full-size copy, 6 MB at 1080p, which the allocator then kept resident (glibc
raises its mmap threshold to a freed block's size, so the next blocks of that size stay in the
heap). Read a strip at a time, the picture needs its own buffer only, and a caller that wants a
band at a time (a preview, :mod:`node.preview`) needs no full-size buffer at all.
"""
from __future__ import annotations

from typing import Any

import numpy as np

#: rows read back at a time (1920 x 96 x 3 bytes: 0.55 MB at 1080p; a preview's bands are as
#: tall, :data:`node.preview.BAND_ROWS`)
STRIP_ROWS = 96


class ReadBack:
    """The read-back buffers of a ``width`` x ``height`` framebuffer; ``rgba``: the driver reads RGBA
    only (OpenGL ES: GL_RGB is not a format glReadPixels must accept there), alpha dropped here."""

    def __init__(self, width: int, height: int, *, rgba: bool) -> None:
        self.width, self.height, self._comps = width, height, 4 if rgba else 3
        # the whole picture, row 0 at the top: its pages become resident only once read() writes them
        self._image = np.empty((height, width, 3), np.uint8)
        self._strip: np.ndarray | None = None

    def rows(self, fbo: Any, top: int, rows: int) -> np.ndarray:
        """Rows ``top`` to ``top + rows - 1`` of the picture in ``fbo`` (a moderngl framebuffer):
        (rows, width, 3) uint8 RGB, row 0 the picture's row ``top``. A view of a strip buffer kept
        for the next call (as tall as the most rows asked for at once, at least :data:`STRIP_ROWS`).
        ValueError if the rows are not within the picture."""
        top, rows = int(top), int(rows)
        if rows < 1 or top < 0 or top + rows > self.height:
            raise ValueError(f"rows {top}..{top + rows - 1} are not within the output's {self.height} rows")
        if self._strip is None or self._strip.shape[0] < rows:
            self._strip = np.empty((max(rows, STRIP_ROWS), self.width, self._comps), np.uint8)
        out = self._strip[:rows]
        # GL rows count from the bottom: the picture's rows top..top+rows-1 are GL rows h-top-rows..h-top-1
        fbo.read_into(out, viewport=(0, self.height - top - rows, self.width, rows), components=self._comps,
                      alignment=1)
        return out[::-1, :, :3]

    def read(self, fbo: Any) -> np.ndarray:
        """The whole picture in ``fbo``: (height, width, 3) uint8 RGB, row 0 at the top; the same
        buffer each call (overwritten by the next)."""
        for top in range(0, self.height, STRIP_ROWS):
            rows = min(STRIP_ROWS, self.height - top)
            self._image[top:top + rows] = self.rows(fbo, top, rows)
        return self._image
