"""A decoded video frame's planes, as the renderer uploads them (:class:`protos.yuv.YuvFrame`).

:func:`yuv_planes` hands a PyAV frame's planes over as read-only views of the decoder's own
buffers where their rows are unpadded (1080p and 720p 4:2:0 are), else as copies without the
padding, and reads its colour tags; the renderer converts to RGB in its shader. A view holds
the decoded frame (FFmpeg counts references to its buffers: the decoder allocates others while
a frame is held, and never writes into one it has output), so no copy is made between the
decoder and the texture. Decoders that lend out a fixed set of device buffers (V4L2 M2M) must
get theirs back: their frames are copied (``copy=True``).
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

__all__ = ["COPY_PLANES", "FORMATS", "why_not", "yuv_planes"]

#: copy every plane out of the decoder's frame (the node before it handed over views): what
#: ``bench node --video``'s memory figures compare (bench/node_video_memory.py)
COPY_PLANES = False

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


def _plane(plane, rows: int, cols: int, comps: int, dtype: np.dtype, copy: bool) -> np.ndarray:
    """A PyAV plane's samples without the row padding: (rows, cols) or (rows, cols, comps),
    C-contiguous: a read-only view of the frame's buffer when its rows are unpadded and ``copy``
    is False (the view keeps the frame alive), else a copy."""
    per_row = plane.line_size // dtype.itemsize
    arr = np.frombuffer(plane, dtype=dtype, count=rows * per_row).reshape(rows, per_row)
    if copy or per_row != cols * comps:
        arr = np.array(arr[:, :cols * comps], order="C")
    else:
        arr.flags.writeable = False       # the decoder's buffer: nobody writes into it
    return arr if comps == 1 else arr.reshape(rows, cols, comps)


def yuv_planes(frame, size: tuple[int, int] | None = None, *, copy: bool | None = None) -> YuvFrame | None:
    """``frame`` (a PyAV ``VideoFrame``) as a :class:`~protos.yuv.YuvFrame` standing for content
    of ``size`` (w, h; None: the frame's own), or None when its format or matrix is not covered
    (:func:`why_not` says why). ``copy``: copy the planes out of the frame (True: a decoder that
    needs its buffers back; None: :data:`COPY_PLANES`); else unpadded planes are views of it."""
    if why_not(frame):
        return None
    layout, sub, bits, msb, full_implied = FORMATS[frame.format.name]
    dtype = np.dtype(np.uint8) if bits == 8 else np.dtype("<u2")
    w, h = frame.width, frame.height
    cw, ch = -(-w // sub[0]), -(-h // sub[1])
    copy = COPY_PLANES if copy is None else copy
    planes = [_plane(frame.planes[0], h, w, 1, dtype, copy)]
    if layout == "planar":
        planes += [_plane(frame.planes[1], ch, cw, 1, dtype, copy), _plane(frame.planes[2], ch, cw, 1, dtype, copy)]
    else:
        planes.append(_plane(frame.planes[1], ch, cw, 2, dtype, copy))
    cs = int(frame.colorspace)
    matrix = _COLORSPACES.get(cs) or guess_matrix(h)
    full = full_implied or int(frame.color_range) == _FULL
    return YuvFrame(planes=tuple(planes), layout=layout, sub=sub, bits=bits, msb=msb, matrix=matrix,
                    full_range=full, siting="left", size=None if size is None else (int(size[0]), int(size[1])))
