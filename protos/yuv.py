"""YUV pictures as a decoder gives them, and their conversion to RGB, defined once.

A node draws a video's frames from the decoder's own planes: it uploads them as textures and
converts to RGB in its shader (``node/render/pipeline.glsl``'s ``sample_yuv``), instead of
converting every pixel with swscale on the CPU. :class:`YuvFrame` is such a picture;
:func:`yuv_affine` is the conversion's arithmetic (one 3x3 matrix and an offset, applied to the
values the GPU samples from the textures), which the renderer hands its shader as uniforms;
:func:`to_rgb` is the numpy reference the tests compare the shader with.

The conversion (ITU-R BT.601, BT.709 and BT.2020 non-constant luminance):

* A sample's code value ``y`` (``bits`` 8 or 10) is normalised by the range: **limited**
  (studio) ``Y = (y - 16 k) / (219 k)``, ``C = (c - 128 k) / (224 k)`` with ``k = 2^(bits-8)``;
  **full** ``Y = y / (2^bits - 1)``, ``C = (c - 2^(bits-1)) / (2^bits - 1)`` (FFmpeg's arithmetic).
* ``R = Y + 2 (1 - Kr) V``, ``B = Y + 2 (1 - Kb) U``, ``G = (Y - Kr R - Kb B) / Kg``, with
  ``(Kr, Kb)`` = (0.299, 0.114) for BT.601, (0.2126, 0.0722) for BT.709, (0.2627, 0.0593) for
  BT.2020, ``Kg = 1 - Kr - Kb``. The result is the RGB the stream encodes, 0..1 (not clipped
  here: the shader clips after warping, as it does every content value).
* Chroma planes have ``1 / sub`` of the luma's columns and rows. Chroma is interpolated
  bilinearly at each luma sample's position, clamped at the edges; chroma sample ``i`` sits at
  luma position ``sub * i + offset``: **left** (H.264/HEVC's default, chroma location type 0:
  co-sited with the even luma columns, between the rows) has offsets ``(0, (sub_y - 1) / 2)``,
  **center** (MPEG-1, JPEG) ``((sub_x - 1) / 2, (sub_y - 1) / 2)``, **topleft** ``(0, 0)``.

Tags a stream leaves unspecified are guessed as players do: BT.601 for pictures under 720 rows
(SD) and BT.709 from 720 rows on (HD), limited range, left-sited chroma (:func:`guess_matrix`).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["LAYOUTS", "MATRICES", "SITINGS", "YuvFrame", "chroma_offsets", "guess_matrix", "to_rgb",
           "yuv_affine"]

#: (Kr, Kb) of each matrix
MATRICES = {"bt601": (0.299, 0.114), "bt709": (0.2126, 0.0722), "bt2020": (0.2627, 0.0593)}
#: "planar": Y, U, V planes; "semiplanar": Y and one interleaved UV plane (NV12, P010)
LAYOUTS = ("planar", "semiplanar")
SITINGS = ("left", "center", "topleft")


def guess_matrix(height: int) -> str:
    """The matrix of an untagged stream of ``height`` rows: "bt601" under 720 rows, else "bt709"."""
    return "bt601" if height < 720 else "bt709"


@dataclass(frozen=True, eq=False)
class YuvFrame:
    """One decoded picture's planes, as the decoder laid them out.

    ``planes``: ``planar``: ``(Y, U, V)``, Y ``(H, W)``, U and V ``(H / sub_y, W / sub_x)``
    (rounded up); ``semiplanar``: ``(Y, UV)``, UV ``(H / sub_y, W / sub_x, 2)`` with U first. All
    C-contiguous, uint8 for 8-bit, uint16 for 10-bit (little-endian, native), the ``bits``
    significant bits in the low bits (``msb`` False: yuv420p10le) or the high bits (``msb`` True:
    P010). ``size``: the content size (w, h) the picture stands for; the renderer scales the
    planes to it while it warps (None: the luma's own size).
    """

    planes: tuple[np.ndarray, ...]
    layout: str = "planar"
    sub: tuple[int, int] = (2, 2)
    bits: int = 8
    msb: bool = False
    matrix: str = "bt709"
    full_range: bool = False
    siting: str = "left"
    size: tuple[int, int] | None = None

    def __post_init__(self) -> None:
        if self.layout not in LAYOUTS:
            raise ValueError(f"layout must be one of {LAYOUTS}, got {self.layout!r}")
        if self.matrix not in MATRICES:
            raise ValueError(f"matrix must be one of {tuple(MATRICES)}, got {self.matrix!r}")
        if self.siting not in SITINGS:
            raise ValueError(f"chroma siting must be one of {SITINGS}, got {self.siting!r}")
        if self.bits not in (8, 10, 12, 16) or tuple(self.sub) not in ((1, 1), (2, 1), (2, 2)):
            raise ValueError(f"unsupported YUV: {self.bits}-bit, chroma subsampled {self.sub}")
        want = np.dtype(np.uint8) if self.bits == 8 else np.dtype(np.uint16)
        n = 3 if self.layout == "planar" else 2
        if len(self.planes) != n or any(p.dtype != want for p in self.planes):
            raise ValueError(f"a {self.layout} {self.bits}-bit frame has {n} {want} planes")
        h, w = self.planes[0].shape[:2]
        ch, cw = -(-h // self.sub[1]), -(-w // self.sub[0])
        for p in self.planes[1:]:
            if p.shape[:2] != (ch, cw) or p.ndim != (2 if self.layout == "planar" else 3):
                raise ValueError(f"chroma plane {p.shape} does not match luma {w}x{h} subsampled {self.sub}")

    @property
    def luma_size(self) -> tuple[int, int]:
        """(w, h) of the luma plane."""
        return (self.planes[0].shape[1], self.planes[0].shape[0])

    @property
    def content_size(self) -> tuple[int, int]:
        """(w, h) the picture stands for (``size``, else the luma's)."""
        return tuple(self.size) if self.size is not None else self.luma_size

    @property
    def nbytes(self) -> int:
        return sum(p.nbytes for p in self.planes)

    def at_size(self, size: tuple[int, int]) -> "YuvFrame":
        """The same planes standing for content of ``size`` (w, h)."""
        from dataclasses import replace

        return replace(self, size=(int(size[0]), int(size[1])))


def chroma_offsets(siting: str, sub: tuple[int, int]) -> tuple[float, float]:
    """Luma position of chroma sample 0: ``(offset_x, offset_y)`` (see the module docstring)."""
    sx, sy = sub
    if siting == "center":
        return ((sx - 1) / 2.0, (sy - 1) / 2.0)
    if siting == "topleft":
        return (0.0, 0.0)
    return (0.0, (sy - 1) / 2.0)


def yuv_affine(matrix: str, full_range: bool, bits: int, sample_max: float) -> tuple[np.ndarray, np.ndarray]:
    """``(M, o)``: RGB = ``M @ s + o`` for ``s`` = (Y, U, V) as sampled, each ``code / sample_max``.

    ``sample_max`` is what a code value is divided by when sampled: 255 for 8-bit textures,
    65535 for 16-bit ones holding LSB-aligned samples, ``65535 / 2^(16 - bits)`` for MSB-aligned
    ones (P010). Returns ``M`` (3, 3) float64 and ``o`` (3,) float64.
    """
    kr, kb = MATRICES[matrix]
    kg = 1.0 - kr - kb
    to_rgb_m = np.array([[1.0, 0.0, 2.0 * (1.0 - kr)],
                         [1.0, -2.0 * kb * (1.0 - kb) / kg, -2.0 * kr * (1.0 - kr) / kg],
                         [1.0, 2.0 * (1.0 - kb), 0.0]])
    k = float(1 << (bits - 8))
    if full_range:
        top = float((1 << bits) - 1)
        scale = np.array([top, top, top])
        offset = np.array([0.0, float(1 << (bits - 1)), float(1 << (bits - 1))])
    else:
        scale = np.array([219.0 * k, 224.0 * k, 224.0 * k])
        offset = np.array([16.0 * k, 128.0 * k, 128.0 * k])
    d = np.diag(sample_max / scale)
    return to_rgb_m @ d, -(to_rgb_m @ (offset / scale))


def _upsample(c: np.ndarray, w: int, h: int, sub: tuple[int, int], offsets: tuple[float, float]) -> np.ndarray:
    """(ch, cw) float64 chroma -> (h, w) float64, bilinear at each luma position, clamped at the edges."""
    ch, cw = c.shape
    x = (np.arange(w) - offsets[0]) / sub[0]
    y = (np.arange(h) - offsets[1]) / sub[1]
    x0 = np.floor(x).astype(np.intp)
    y0 = np.floor(y).astype(np.intp)
    fx, fy = x - x0, y - y0
    xa, xb = np.clip(x0, 0, cw - 1), np.clip(x0 + 1, 0, cw - 1)
    ya, yb = np.clip(y0, 0, ch - 1), np.clip(y0 + 1, 0, ch - 1)
    top = c[ya][:, xa] * (1 - fx) + c[ya][:, xb] * fx
    bottom = c[yb][:, xa] * (1 - fx) + c[yb][:, xb] * fx
    return top * (1 - fy)[:, None] + bottom * fy[:, None]


def to_rgb(frame: YuvFrame) -> np.ndarray:
    """The reference conversion: ``(H, W, 3)`` float64 RGB at the luma's size, not clipped.

    Chroma is upsampled bilinearly at each luma position as ``frame.siting`` places it (edges
    clamped), then each pixel goes through :func:`yuv_affine`. Computed in float64 from the code
    values, independently of any texture's normalisation.
    """
    y = frame.planes[0].astype(np.float64)
    if frame.layout == "planar":
        u, v = frame.planes[1].astype(np.float64), frame.planes[2].astype(np.float64)
    else:
        u, v = frame.planes[1][:, :, 0].astype(np.float64), frame.planes[1][:, :, 1].astype(np.float64)
    if frame.msb:
        shift = float(1 << (16 - frame.bits))
        y, u, v = y / shift, u / shift, v / shift
    h, w = y.shape
    offs = chroma_offsets(frame.siting, frame.sub)
    u, v = _upsample(u, w, h, frame.sub, offs), _upsample(v, w, h, frame.sub, offs)
    m, o = yuv_affine(frame.matrix, frame.full_range, frame.bits, 1.0)
    s = np.stack([y, u, v], axis=-1)
    return s @ m.T + o
