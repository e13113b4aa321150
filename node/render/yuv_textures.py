"""A YUV picture's textures and the shader uniforms that convert it (the renderer's YUV part).

:class:`YuvTextures` holds one texture per plane of a :class:`protos.yuv.YuvFrame`: Y as a
one-channel texture (R8, or R16 normalised for 10-bit samples), U and V likewise (planar), or UV
as a two-channel one (RG8 / RG16: NV12, P010). With ``interleave`` a planar picture's U and V go
up interleaved into one two-channel texture, as NV12's, and draw as semi-planar: the shader then
fetches four chroma texels per pixel instead of eight. The renderer asks for it on a software
rasterizer (llvmpipe), where the same CPU pays for both: the interleave costs about 0.4 ms per
1080p 4:2:0 frame (and a 1 MB buffer kept for the next, one per thread), four R8 fetches about 13 ns per output
pixel (3 ms per 640x360 frame). Where 16-bit normalised textures do not exist (OpenGL ES without
GL_EXT_texture_norm16) 16-bit planes go up as float32 divided by 65535, which samples the same
values. The conversion to RGB runs in ``pipeline.glsl``'s ``sample_yuv`` with the uniforms
:meth:`YuvTextures.bind` sets (its ``mode`` picks the shader's variant), from
:func:`protos.yuv.yuv_affine`.

Threading: as the renderer, on the thread that owns the GL context.
"""
from __future__ import annotations

import threading
from typing import Any, Callable

import numpy as np

from protos.yuv import YuvFrame, chroma_offsets, yuv_affine

__all__ = ["YuvTextures", "layout_key"]


def layout_key(frame: YuvFrame) -> tuple:
    """What two frames must share to reuse each other's textures: each plane's shape and dtype."""
    return tuple((p.shape, p.dtype.str) for p in frame.planes)


#: the interleaved chroma's buffer, one per thread and shared by every :class:`YuvTextures` on it: the
#: texture's write copies it at once, so a picture's textures need not keep their own (1 MB per
#: 1080p 4:2:0 picture, and a renderer keeps two or three pictures' textures while a video plays)
_scratch = threading.local()


def _interleave_buffer(shape: tuple[int, int], dtype: np.dtype) -> np.ndarray:
    """A (h, w, 2) array of ``dtype`` for U and V interleaved, reused on this thread."""
    buf = getattr(_scratch, "uv", None)
    if buf is None or buf.shape[:2] != shape or buf.dtype != dtype:
        buf = _scratch.uv = np.empty((*shape, 2), dtype)
    return buf


def _mat_bytes(m: np.ndarray) -> bytes:
    return np.ascontiguousarray(m.T, dtype=np.float32).tobytes()


class YuvTextures:
    """The textures of one YUV picture (see the module docstring).

    ``make(array) -> texture`` creates a texture for a plane ((h, w) or (h, w, 2), uint8 or
    uint16); ``write(texture, array)`` refills one (a video's next frame reuses the textures).
    ``norm16``: whether 16-bit normalised textures exist (else planes go up as float32).
    ``interleave``: a planar picture's U and V go up as one (h, w, 2) texture (semi-planar).
    """

    def __init__(self, frame: YuvFrame, make: Callable[[np.ndarray], Any], norm16: bool,
                 interleave: bool = False) -> None:
        self.key = layout_key(frame)
        self._norm16 = norm16
        self._interleave = interleave and frame.layout == "planar"
        self.textures = [make(self._data(p)) for p in self._planes(frame)]
        self.set_frame(frame)

    @property
    def interleaved(self) -> bool:
        """Whether this planar picture's U and V share one texture (it draws as semi-planar)."""
        return self._interleave

    def _planes(self, frame: YuvFrame) -> tuple[np.ndarray, ...]:
        """The arrays that go up: the frame's planes, or Y and U, V interleaved ((h, w, 2))."""
        if not self._interleave:
            return tuple(frame.planes)
        y, u, v = frame.planes
        uv = _interleave_buffer(u.shape, u.dtype)
        uv[:, :, 0] = u
        uv[:, :, 1] = v
        return y, uv

    def _data(self, plane: np.ndarray) -> np.ndarray:
        if plane.dtype == np.uint8 or self._norm16:
            return plane
        out = plane.astype(np.float32)
        out /= np.float32(65535.0)
        return out

    def refill(self, frame: YuvFrame) -> None:
        """Write ``frame``'s planes into these textures (same :func:`layout_key`)."""
        for tex, plane in zip(self.textures, self._planes(frame)):
            tex.write(self._data(plane), alignment=1)
        self.set_frame(frame)

    def set_frame(self, frame: YuvFrame) -> None:
        """The uniforms' values for ``frame`` (kept until :meth:`bind`)."""
        if frame.bits == 8:
            sample_max = 255.0
        elif frame.msb:
            sample_max = 65535.0 / float(1 << (16 - frame.bits))
        else:
            sample_max = 65535.0
        m, o = yuv_affine(frame.matrix, frame.full_range, frame.bits, sample_max)
        sx, sy = frame.sub
        ox, oy = chroma_offsets(frame.siting, frame.sub)
        self.mode = 1 if frame.layout == "planar" and not self._interleave else 2
        self.matrix = _mat_bytes(m)
        self.offset = tuple(float(v) for v in o)
        self.chroma_xform = (1.0 / sx, 1.0 / sy, -ox / sx, -oy / sy)
        self.luma_size = frame.luma_size
        self.content_size = frame.content_size

    def bind(self, uniforms: dict, prefix: str, units: tuple[int, int, int], *, mesh: bool = False) -> None:
        """Bind the planes to ``units`` (Y, then the chroma planes) and set the uniforms named
        ``prefix`` + ``yuv_matrix``... in ``uniforms`` (the renderer's values, which go to the program
        a draw uses; "" for the content, "from_" for a fade's start). ``mesh``: the mesh shader
        addresses the luma's own texels (no content-size scaling)."""
        lw, lh = self.luma_size
        cw, ch = self.content_size
        scale = (1.0, 1.0) if mesh else (lw / cw, lh / ch)
        for tex, unit in zip(self.textures, units):
            tex.use(unit)
        uniforms[f"{prefix}yuv_matrix"] = self.matrix
        uniforms[f"{prefix}yuv_offset"] = self.offset
        uniforms[f"{prefix}chroma_xform"] = self.chroma_xform
        uniforms[f"{prefix}luma_scale"] = scale

    def release(self) -> None:
        for tex in self.textures:
            tex.release()
        self.textures = []
