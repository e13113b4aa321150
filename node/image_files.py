"""PNG files through FFmpeg's PNG codec (PyAV), written atomically (:mod:`protos.atomic_files`).

Decoding reads every PNG FFmpeg reads -- grey, grey+alpha, RGB, RGBA at 8 or 16 bits, palette
(with or without ``tRNS`` alpha), 1/2/4-bit grey, interlaced (Adam7) -- exactly, to
``(H, W)`` (grey) or ``(H, W, C)`` uint8/uint16 in RGB(A) order, row 0 at the top. Palette and
sub-byte images come back as 8-bit RGB(A) / grey. Encoding writes standard non-interlaced PNGs
(grey, grey+alpha, RGB, RGBA at 8 or 16 bits) losslessly, with optional ``tEXt`` chunks.

PyAV is already part of the node's install, so this adds nothing to it.
"""
from __future__ import annotations

import os
import zlib
from collections.abc import Mapping
from pathlib import Path

import av
import numpy as np

from node.errors import NodeError
from protos.atomic_files import atomic_write_bytes  # re-exported: node.outputs.base writes through it
from protos.image_limits import MAX_IMAGE_SIDE, MAX_PIXELS, within_limits

__all__ = ["FILTERS", "PngError", "PngTooLarge", "atomic_write_bytes", "decode_png", "decode_png_text", "encode_png", "read_png",
           "write_png"]

SIGNATURE = b"\x89PNG\r\n\x1a\n"
FILTERS = ("none", "sub", "up", "average", "paeth", "adaptive")
_PRED = {"none": "none", "sub": "sub", "up": "up", "average": "avg", "paeth": "paeth", "adaptive": "mixed"}
# channels -> (8-bit, 16-bit) pixel format of FFmpeg's PNG encoder
_ENCODE_FORMATS = {1: ("gray", "gray16be"), 2: ("ya8", "ya16be"), 3: ("rgb24", "rgb48be"), 4: ("rgba", "rgba64be")}
# FFmpeg's decoded pixel format -> (channels, sample dtype) of its one packed plane; other formats
# (pal8, monob, sub-byte grey) convert through swscale, which is exact for those
_PACKED = {"gray": (1, "u1"), "gray16be": (1, ">u2"), "ya8": (2, "u1"), "ya16be": (2, ">u2"),
           "rgb24": (3, "u1"), "rgb48be": (3, ">u2"), "rgba": (4, "u1"), "rgba64be": (4, ">u2")}


class PngError(NodeError, ValueError):
    """A PNG file is malformed or FFmpeg's PNG decoder cannot read it."""


class PngTooLarge(PngError):
    """A PNG's header declares more pixels than a node decodes (nothing was decoded)."""


# ---------------------------------------------------------------------------- encoding


def _as_image(image: np.ndarray) -> np.ndarray:
    image = np.asarray(image)
    if image.dtype not in (np.uint8, np.uint16):
        raise ValueError(f"PNG images must be uint8 or uint16, got {image.dtype}")
    if image.ndim == 2:
        image = image[:, :, None]
    if image.ndim != 3 or not 1 <= image.shape[2] <= 4:
        raise ValueError(f"PNG images must be (H, W) or (H, W, C) with C in 1..4, got shape {image.shape}")
    if image.shape[0] < 1 or image.shape[1] < 1:
        raise ValueError(f"PNG images must not be empty, got shape {image.shape}")
    return image


def _chunk(kind: bytes, data: bytes) -> bytes:
    return len(data).to_bytes(4, "big") + kind + data + (zlib.crc32(kind + data) & 0xFFFFFFFF).to_bytes(4, "big")


def _text_chunks(text: Mapping[str, str]) -> bytes:
    out = []
    for key, value in text.items():
        if not 1 <= len(key) <= 79 or "\x00" in key:
            raise ValueError(f"PNG text key must be 1-79 characters without NUL, got {key!r}")
        try:
            out.append(_chunk(b"tEXt", key.encode("latin-1") + b"\x00" + str(value).encode("latin-1")))
        except UnicodeEncodeError as exc:
            raise ValueError(f"PNG tEXt chunks hold Latin-1 text only: {key!r}") from exc
    return b"".join(out)


def encode_png(
    image: np.ndarray,
    *,
    compress_level: int = 6,
    filter: str = "up",
    text: Mapping[str, str] | None = None,
) -> bytes:
    """Encode an image as PNG bytes, losslessly, with FFmpeg's PNG encoder.

    Parameters
    ----------
    image : (H, W) or (H, W, C) uint8 or uint16
        C = 1 grey, 2 grey+alpha, 3 RGB, 4 RGBA (16-bit as ``gray16be`` ... ``rgba64be``).
    compress_level : int
        zlib level 0 (fastest, largest) .. 9 (slowest, smallest).
    filter : str
        Row filter: ``none``, ``sub``, ``up``, ``average``, ``paeth`` or ``adaptive``
        (FFmpeg's ``mixed``: per row, the filter with the smallest output).
    text : mapping of str to str, optional
        Written as ``tEXt`` chunks after ``IHDR`` (Latin-1; keys 1-79 characters).
    """
    img = _as_image(image)
    if filter not in FILTERS:
        raise ValueError(f"unknown PNG filter {filter!r}; use one of {', '.join(FILTERS)}")
    if not 0 <= compress_level <= 9:
        raise ValueError(f"compress_level must be in 0..9, got {compress_level}")
    chunks = _text_chunks(text or {})
    h, w, ch = img.shape
    fmt = _ENCODE_FORMATS[ch][img.dtype == np.uint16]
    if img.dtype == np.uint16:
        img = img.astype(">u2")
    data = np.ascontiguousarray(img).view(np.uint8).reshape(h, -1)
    frame = av.VideoFrame(w, h, fmt)
    plane = frame.planes[0]
    line = plane.line_size
    if line == data.shape[1]:
        plane.update(data)
    else:  # rows padded to the plane's alignment
        padded = np.zeros((h, line), np.uint8)
        padded[:, : data.shape[1]] = data
        plane.update(padded)
    ctx = av.CodecContext.create("png", "w")
    ctx.width, ctx.height, ctx.pix_fmt = w, h, fmt
    ctx.options = {"compression_level": str(compress_level), "pred": _PRED[filter]}
    out = b"".join(bytes(p) for p in ctx.encode(frame)) + b"".join(bytes(p) for p in ctx.encode(None))
    if not chunks:
        return out
    ihdr_end = 8 + 8 + 13 + 4
    return out[:ihdr_end] + chunks + out[ihdr_end:]


def write_png(path: str | os.PathLike[str], image: np.ndarray, **options) -> None:
    """Write ``image`` to ``path`` as PNG atomically; options are those of :func:`encode_png`."""
    atomic_write_bytes(Path(path), encode_png(image, **options))


# ---------------------------------------------------------------------------- decoding


def _ndarray(frame: av.VideoFrame) -> np.ndarray:
    name = frame.format.name
    h, w = frame.height, frame.width
    if name in _PACKED:  # read the plane as it is (no swscale pass), big-endian -> native
        ch, code = _PACKED[name]
        dtype = np.dtype(code)
        plane = frame.planes[0]
        rows = np.frombuffer(plane, np.uint8).reshape(h, plane.line_size)[:, : w * ch * dtype.itemsize]
        img = np.array(rows, order="C").view(dtype).reshape(h, w, ch)  # a copy: off the frame
        img = img.astype(np.uint16) if dtype.itemsize == 2 else img  # native byte order
        return img[:, :, 0] if ch == 1 else img
    if name == "pal8":  # RGB, or RGBA when the palette has transparency
        palette = np.frombuffer(frame.planes[1], np.uint8)[:1024].reshape(256, 4)  # BGRA
        rgba = frame.to_ndarray(format="rgba")
        return rgba if (palette[:, 3] != 255).any() else np.ascontiguousarray(rgba[:, :, :3])
    if name.startswith(("mono", "gray")) and "16" not in name:  # 1/2/4-bit grey
        return frame.to_ndarray(format="gray")
    raise PngError(f"PNG pixel format {name} is not supported")


def decode_png(data: bytes) -> np.ndarray:
    """Decode PNG bytes with FFmpeg's PNG decoder.

    Returns
    -------
    (H, W) or (H, W, C) uint8 or uint16
        Grey images come back as (H, W); C = 2 (grey+alpha), 3 (RGB) or 4 (RGBA). Palette
        images come back as RGB, or RGBA when the palette has transparency; 1/2/4-bit grey as
        8-bit grey scaled to 0..255, as libpng does.

    Raises
    ------
    PngError
        The data is not a PNG, or is corrupt or truncated, or its header declares more than
        :data:`protos.image_limits.MAX_PIXELS` pixels or ``MAX_IMAGE_SIDE`` a side (then
        nothing is decoded).
    """
    if bytes(data[:8]) != SIGNATURE:
        raise PngError("not a PNG file (bad signature)")
    if bytes(data[12:16]) != b"IHDR":
        raise PngError("corrupt PNG: its first chunk is not IHDR")
    w, h = int.from_bytes(data[16:20], "big"), int.from_bytes(data[20:24], "big")
    if not within_limits(w, h):     # refused from the header: FFmpeg would allocate the frame first
        raise PngTooLarge(f"PNG declares {w}x{h} pixels, outside what a node decodes (1..{MAX_IMAGE_SIDE} pixels a "
                          f"side, at most {MAX_PIXELS / 1e6:.0f} megapixels)")
    ctx = av.CodecContext.create("png", "r")  # the decoder alone: no demuxer, no probing
    ctx.options = {"err_detect": "crccheck+bitstream+explode"}
    try:
        frames = ctx.decode(av.Packet(bytes(data))) + ctx.decode(None)
    except (av.FFmpegError, ValueError) as exc:
        raise PngError(f"corrupt PNG: FFmpeg cannot decode it ({exc})") from exc
    if not frames:
        raise PngError("corrupt or truncated PNG: no image in it")
    return _ndarray(frames[0])


def decode_png_text(data: bytes) -> dict[str, str]:
    """The ``tEXt`` key/value pairs of a PNG (chunk lengths and CRCs checked; pixels not decoded)."""
    if bytes(data[:8]) != SIGNATURE:
        raise PngError("not a PNG file (bad signature)")
    text: dict[str, str] = {}
    pos = 8
    while True:
        if pos + 12 > len(data):
            raise PngError("truncated PNG: missing IEND chunk")
        length = int.from_bytes(data[pos : pos + 4], "big")
        kind, payload = bytes(data[pos + 4 : pos + 8]), bytes(data[pos + 8 : pos + 8 + length])
        if pos + 12 + length > len(data):
            raise PngError("truncated PNG: a chunk runs past the end of the file")
        if zlib.crc32(kind + payload) & 0xFFFFFFFF != int.from_bytes(data[pos + 8 + length : pos + 12 + length], "big"):
            raise PngError(f"corrupt PNG: CRC mismatch in {kind.decode('latin-1')!r} chunk")
        if kind == b"tEXt":
            key, _, value = payload.partition(b"\x00")
            text[key.decode("latin-1")] = value.decode("latin-1")
        elif kind == b"IEND":
            return text
        pos += 12 + length


def read_png(path: str | os.PathLike[str]) -> np.ndarray:
    """Read a PNG file; see :func:`decode_png` for the result's shape and dtype."""
    return decode_png(Path(path).read_bytes())
