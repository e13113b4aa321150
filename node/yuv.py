"""A decoded video frame's planes, as the renderer uploads them (:class:`protos.yuv.YuvFrame`).

:func:`yuv_planes` copies a PyAV frame's planes out of the decoder's buffers (one copy per
plane, no conversion) and reads its colour tags; the renderer converts to RGB in its shader.
It answers None for what the shader does not cover, and the caller converts with swscale as
before (:func:`node.asset_decode.frame_to_array`), saying so once per stream (:func:`why_not`).

Covered: 8-bit ``yuv420p``, ``yuv422p``, ``yuv444p`` (and their full-range ``yuvj`` names),
``nv12``; 10-bit ``yuv420p10le``, ``yuv422p10le``, ``yuv444p10le`` and ``p010le``. Matrices
BT.601 (``bt470bg``, ``smpte170m``), BT.709 and BT.2020 non-constant luminance; limited or full
range. Untagged streams: BT.601 under 720 rows, BT.709 from 720 rows, limited range (``yuvj``
formats: full). PyAV does not expose a frame's chroma location, so chroma is taken as H.264's
and HEVC's default, ``left`` (co-sited with the even luma columns, centred between rows).
"""
from __future__ import annotations

import numpy as np

from protos.yuv import YuvFrame, guess_matrix

__all__ = ["FORMATS", "why_not", "yuv_planes"]

#: pixel format -> (layout, chroma subsampling, bits, MSB-aligned, full range implied)
FORMATS = {
    "yuv420p": ("planar", (2, 2), 8, False, False),
    "yuvj420p": ("planar", (2, 2), 8, False, True),
    "yuv422p": ("planar", (2, 1), 8, False, False),
    "yuvj422p": ("planar", (2, 1), 8, False, True),
    "yuv444p": ("planar", (1, 1), 8, False, False),
    "yuvj444p": ("planar", (1, 1), 8, False, True),
    "nv12": ("semiplanar", (2, 2), 8, False, False),
    "yuv420p10le": ("planar", (2, 2), 10, False, False),
    "yuv422p10le": ("planar", (2, 1), 10, False, False),
    "yuv444p10le": ("planar", (1, 1), 10, False, False),
    "p010le": ("semiplanar", (2, 2), 10, True, False),
}
# AVColorSpace values -> matrix (2: unspecified, guessed from the height)
_COLORSPACES = {1: "bt709", 5: "bt601", 6: "bt601", 9: "bt2020"}
_UNSPECIFIED = (2,)
# AVColorRange: 1 MPEG (limited), 2 JPEG (full), 0 unspecified
_FULL = 2


def why_not(frame) -> str:
    """Why :func:`yuv_planes` answers None for ``frame`` ("" if it does not)."""
    name = frame.format.name
    if name not in FORMATS:
        return f"pixel format {name} is not one the shader converts"
    cs = int(frame.colorspace)
    if cs not in _COLORSPACES and cs not in _UNSPECIFIED:
        return f"colour matrix {cs} (AVColorSpace) is not BT.601, BT.709 or BT.2020 non-constant"
    return ""


def _plane(plane, rows: int, cols: int, comps: int, dtype: np.dtype) -> np.ndarray:
    """A PyAV plane's samples without the row padding: (rows, cols) or (rows, cols, comps), copied."""
    per_row = plane.line_size // dtype.itemsize
    arr = np.frombuffer(plane, dtype=dtype, count=rows * per_row).reshape(rows, per_row)[:, :cols * comps]
    out = np.array(arr, order="C")    # one copy: off the decoder's buffer, which it reuses
    return out if comps == 1 else out.reshape(rows, cols, comps)


def yuv_planes(frame, size: tuple[int, int] | None = None) -> YuvFrame | None:
    """``frame`` (a PyAV ``VideoFrame``) as a :class:`~protos.yuv.YuvFrame` standing for content
    of ``size`` (w, h; None: the frame's own), or None when its format or matrix is not covered
    (:func:`why_not` says why)."""
    if why_not(frame):
        return None
    layout, sub, bits, msb, full_implied = FORMATS[frame.format.name]
    dtype = np.dtype(np.uint8) if bits == 8 else np.dtype("<u2")
    w, h = frame.width, frame.height
    cw, ch = -(-w // sub[0]), -(-h // sub[1])
    planes = [_plane(frame.planes[0], h, w, 1, dtype)]
    if layout == "planar":
        planes += [_plane(frame.planes[1], ch, cw, 1, dtype), _plane(frame.planes[2], ch, cw, 1, dtype)]
    else:
        planes.append(_plane(frame.planes[1], ch, cw, 2, dtype))
    cs = int(frame.colorspace)
    matrix = _COLORSPACES.get(cs) or guess_matrix(h)
    full = full_implied or int(frame.color_range) == _FULL
    return YuvFrame(planes=tuple(planes), layout=layout, sub=sub, bits=bits, msb=msb, matrix=matrix,
                    full_range=full, siting="left", size=None if size is None else (int(size[0]), int(size[1])))
