"""A small lossless PNG writer and reader for uint8/uint16 images (zlib + struct only).

The node writes snapshots of what it shows without depending on OpenCV. The
writer produces standard non-interlaced PNGs (grey, grey+alpha, RGB, RGBA at 8 or
16 bits per sample) with optional ``tEXt`` chunks; the reader reads those and any
other non-interlaced 8/16-bit grey/RGB(A) PNG, whatever row filters it uses (so
files written by OpenCV, PIL or libpng read back exactly).

Images follow the OpenCV layout: ``(H, W)`` for grey, ``(H, W, C)`` otherwise,
row 0 at the top; channels are in RGB(A) order (PNG's order, *not* OpenCV's BGR).
"""
from __future__ import annotations

import os
import struct
import tempfile
import zlib
from collections.abc import Mapping
from pathlib import Path

import numpy as np

from node.errors import NodeError

__all__ = [
    "PngError",
    "encode_png",
    "decode_png",
    "decode_png_text",
    "write_png",
    "read_png",
    "atomic_write_bytes",
    "FILTERS",
]

SIGNATURE = b"\x89PNG\r\n\x1a\n"
# PNG colour type for a number of channels, and back.
_COLOUR_TYPE = {1: 0, 2: 4, 3: 2, 4: 6}
_CHANNELS = {v: k for k, v in _COLOUR_TYPE.items()}
FILTERS = ("none", "sub", "up", "average", "paeth", "adaptive")
_FILTER_CODE = {"none": 0, "sub": 1, "up": 2, "average": 3, "paeth": 4}
_MAX_CHUNK = 2**31 - 1
_MAX_DIM = 2**24  # sanity bound on width/height from untrusted files


class PngError(NodeError, ValueError):
    """A PNG file is malformed or uses a feature this reader does not support."""


# ---------------------------------------------------------------------------- writing


def _as_image(image: np.ndarray) -> np.ndarray:
    """Validate and return ``image`` as (H, W, C) with C in 1..4, dtype uint8/uint16."""
    image = np.asarray(image)
    if image.dtype not in (np.uint8, np.uint16):
        raise ValueError(f"PNG images must be uint8 or uint16, got {image.dtype}")
    if image.ndim == 2:
        image = image[:, :, None]
    if image.ndim != 3 or not 1 <= image.shape[2] <= 4:
        raise ValueError(f"PNG images must be (H, W) or (H, W, C) with C in 1..4, got shape {image.shape}")
    h, w = image.shape[:2]
    if h < 1 or w < 1:
        raise ValueError(f"PNG images must not be empty, got shape {image.shape}")
    return image


def _paeth(a: np.ndarray, b: np.ndarray, c: np.ndarray) -> np.ndarray:
    """Paeth predictor on int16 arrays (PNG spec 9.4), elementwise."""
    p = a + b - c
    pa = np.abs(p - a)
    pb = np.abs(p - b)
    pc = np.abs(p - c)
    return np.where((pa <= pb) & (pa <= pc), a, np.where(pb <= pc, b, c))


def _filter_rows(raw: np.ndarray, bpp: int, kind: str) -> np.ndarray:
    """Filter ``raw`` (H, stride) uint8 rows; return (H, 1 + stride) uint8 with filter bytes."""
    h, stride = raw.shape
    x = raw.astype(np.int16) if kind in ("average", "paeth", "adaptive") else raw

    def left(v: np.ndarray) -> np.ndarray:  # the byte bpp to the left (0 outside)
        out = np.zeros_like(v)
        out[:, bpp:] = v[:, :-bpp]
        return out

    def up(v: np.ndarray) -> np.ndarray:  # the byte above (0 outside)
        out = np.zeros_like(v)
        out[1:] = v[:-1]
        return out

    def residual(code: int) -> np.ndarray:
        if code == 0:
            return x
        if code == 1:
            return x - left(x)
        if code == 2:
            return x - up(x)
        if code == 3:
            return x - ((left(x) + up(x)) >> 1)
        return x - _paeth(left(x), up(x), up(left(x)))

    if kind == "adaptive":
        # libpng's heuristic: per row, the filter minimising the sum of |signed residual bytes|
        stacked = np.stack([(residual(k) & 0xFF).astype(np.uint8) for k in range(5)])
        cost = np.abs(stacked.view(np.int8).astype(np.int32)).sum(axis=2)  # (5, H)
        types = np.argmin(cost, axis=0).astype(np.uint8)
        body = stacked[types, np.arange(h)]
        out = np.empty((h, 1 + stride), np.uint8)
        out[:, 0] = types
        out[:, 1:] = body
        return out
    code = _FILTER_CODE[kind]
    out = np.empty((h, 1 + stride), np.uint8)
    out[:, 0] = code
    body = out[:, 1:]
    if code == 0:
        body[:] = raw
    elif code == 1:  # uint8 arithmetic wraps modulo 256, exactly as PNG wants
        body[:, :bpp] = raw[:, :bpp]
        np.subtract(raw[:, bpp:], raw[:, :-bpp], out=body[:, bpp:])
    elif code == 2:
        body[0] = raw[0]
        np.subtract(raw[1:], raw[:-1], out=body[1:])
    else:
        body[:] = residual(code) & 0xFF
    return out


def _chunk(kind: bytes, data: bytes) -> bytes:
    return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data) & 0xFFFFFFFF)


def encode_png(
    image: np.ndarray,
    *,
    compress_level: int = 6,
    filter: str = "up",
    text: Mapping[str, str] | None = None,
) -> bytes:
    """Encode an image as PNG bytes, losslessly.

    Parameters
    ----------
    image : (H, W) or (H, W, C) uint8 or uint16
        C = 1 grey, 2 grey+alpha, 3 RGB, 4 RGBA.
    compress_level : int
        zlib level 0 (fastest, largest) .. 9 (slowest, smallest).
    filter : str
        Row filter: one of ``none``, ``sub``, ``up``, ``average``, ``paeth`` or
        ``adaptive`` (per row, the filter with the smallest sum of absolute residuals).
    text : mapping of str to str, optional
        Written as ``tEXt`` chunks (Latin-1; keys 1-79 characters).

    Returns
    -------
    bytes
        A complete PNG file.
    """
    img = _as_image(image)
    if filter not in FILTERS:
        raise ValueError(f"unknown PNG filter {filter!r}; use one of {', '.join(FILTERS)}")
    if not 0 <= compress_level <= 9:
        raise ValueError(f"compress_level must be in 0..9, got {compress_level}")
    h, w, ch = img.shape
    depth = 16 if img.dtype == np.uint16 else 8
    samples = img.astype(">u2") if depth == 16 else img
    raw = np.ascontiguousarray(samples).view(np.uint8).reshape(h, -1)
    bpp = ch * depth // 8
    filtered = _filter_rows(raw, bpp, filter)
    parts = [SIGNATURE, _chunk(b"IHDR", struct.pack(">IIBBBBB", w, h, depth, _COLOUR_TYPE[ch], 0, 0, 0))]
    for key, value in (text or {}).items():
        if not 1 <= len(key) <= 79 or "\x00" in key:
            raise ValueError(f"PNG text key must be 1-79 characters without NUL, got {key!r}")
        try:
            payload = key.encode("latin-1") + b"\x00" + str(value).encode("latin-1")
        except UnicodeEncodeError as exc:
            raise ValueError(f"PNG tEXt chunks hold Latin-1 text only: {key!r}") from exc
        parts.append(_chunk(b"tEXt", payload))
    data = zlib.compress(filtered.tobytes(), compress_level)
    for start in range(0, max(len(data), 1), 1 << 24):
        parts.append(_chunk(b"IDAT", data[start : start + (1 << 24)]))
    parts.append(_chunk(b"IEND", b""))
    return b"".join(parts)


def write_png(
    path: str | os.PathLike[str],
    image: np.ndarray,
    *,
    compress_level: int = 6,
    filter: str = "up",
    text: Mapping[str, str] | None = None,
) -> None:
    """Write ``image`` to ``path`` as PNG atomically (temp file in the same folder, fsync, rename).

    A reader never sees a half-written file: it sees the old file or the new one.
    Options are those of :func:`encode_png`.
    """
    data = encode_png(image, compress_level=compress_level, filter=filter, text=text)
    atomic_write_bytes(Path(path), data)


def atomic_write_bytes(path: Path, data: bytes) -> None:
    """Write ``data`` to ``path`` atomically: temp file beside it, fsync, rename, fsync the folder."""
    path = Path(path)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent)
    try:
        with os.fdopen(fd, "wb") as f:
            f.write(data)
            f.flush()
            os.fsync(f.fileno())
        os.replace(tmp, path)
    except BaseException:
        try:
            os.unlink(tmp)
        except FileNotFoundError:
            pass
        raise
    try:
        dir_fd = os.open(path.parent, os.O_RDONLY)
    except OSError:  # pragma: no cover - platforms without directory fds
        return
    try:
        os.fsync(dir_fd)
    except OSError:  # pragma: no cover - some filesystems refuse fsync on folders
        pass
    finally:
        os.close(dir_fd)


# ---------------------------------------------------------------------------- reading


def _chunks(data: bytes):
    """Yield (kind, payload) for every chunk, checking signature, lengths and CRCs."""
    if data[:8] != SIGNATURE:
        raise PngError("not a PNG file (bad signature)")
    pos = 8
    n = len(data)
    while True:
        if pos + 12 > n:
            raise PngError("truncated PNG: missing IEND chunk")
        (length,) = struct.unpack_from(">I", data, pos)
        if length > _MAX_CHUNK or pos + 12 + length > n:
            raise PngError("truncated PNG: a chunk runs past the end of the file")
        kind = data[pos + 4 : pos + 8]
        payload = data[pos + 8 : pos + 8 + length]
        (crc,) = struct.unpack_from(">I", data, pos + 8 + length)
        if zlib.crc32(kind + payload) & 0xFFFFFFFF != crc:
            raise PngError(f"corrupt PNG: CRC mismatch in {kind.decode('latin-1')!r} chunk")
        yield kind, payload
        pos += 12 + length
        if kind == b"IEND":
            return


def _unfilter(filtered: np.ndarray, h: int, w: int, bpp: int) -> np.ndarray:
    """Undo PNG row filters. ``filtered`` is (H, 1 + W*bpp) uint8; returns (H, W*bpp) uint8."""
    types = filtered[:, 0]
    body = filtered[:, 1:].reshape(h, w, bpp)
    if types.max(initial=0) > 4:
        raise PngError(f"corrupt PNG: unknown row filter type {int(types.max())}")
    if not types.any():
        return body.reshape(h, -1).copy()
    if types.max() <= 2:
        # none/sub/up only: row by row, each row vectorised (sub = running sum mod 256)
        out = np.empty((h, w, bpp), np.uint8)
        prev = np.zeros((w, bpp), np.uint8)
        for r in range(h):
            t = types[r]
            if t == 0:
                out[r] = body[r]
            elif t == 1:
                np.cumsum(body[r], axis=0, dtype=np.uint8, out=out[r])
            else:
                np.add(body[r], prev, out=out[r])  # uint8 wraps modulo 256
            prev = out[r]
        return out.reshape(h, -1)
    # General case: every reconstructed pixel depends on its left, upper and upper-left
    # neighbours only, so all pixels on one anti-diagonal (r + i = d) are independent.
    # Sweep the H + W - 1 anti-diagonals, vectorised along each.
    rec = np.zeros((h + 1, w + 1, bpp), np.int16)  # zero row/column 0 = PNG's "outside"
    x = body.astype(np.int16)
    t_all = types.astype(np.int16)
    for d in range(h + w - 1):
        r = np.arange(max(0, d - w + 1), min(h - 1, d) + 1)
        i = d - r
        a = rec[r + 1, i]
        b = rec[r, i + 1]
        c = rec[r, i]
        t = t_all[r][:, None]
        pred = np.where(
            t == 1, a, np.where(t == 2, b, np.where(t == 3, (a + b) >> 1, np.where(t == 4, _paeth(a, b, c), 0)))
        )
        rec[r + 1, i + 1] = (x[r, i] + pred) & 0xFF
    return rec[1:, 1:].astype(np.uint8).reshape(h, -1)


def _parse(data: bytes) -> tuple[np.ndarray, dict[str, str]]:
    header = None
    idat: list[bytes] = []
    text: dict[str, str] = {}
    for kind, payload in _chunks(data):
        if kind == b"IHDR":
            if len(payload) != 13:
                raise PngError("corrupt PNG: IHDR chunk has the wrong length")
            header = struct.unpack(">IIBBBBB", payload)
        elif kind == b"IDAT":
            idat.append(payload)
        elif kind == b"tEXt":
            key, _, value = payload.partition(b"\x00")
            text[key.decode("latin-1")] = value.decode("latin-1")
        elif kind == b"PLTE":
            raise PngError("palette PNGs are not supported (use grey, RGB or RGBA at 8 or 16 bits)")
    if header is None:
        raise PngError("corrupt PNG: no IHDR chunk")
    w, h, depth, colour, compression, filter_method, interlace = header
    if not (1 <= w <= _MAX_DIM and 1 <= h <= _MAX_DIM):
        raise PngError(f"PNG size {w}x{h} is out of range")
    if colour not in _CHANNELS:
        raise PngError(f"PNG colour type {colour} is not supported (grey, grey+alpha, RGB, RGBA only)")
    if depth not in (8, 16):
        raise PngError(f"PNG bit depth {depth} is not supported (8 or 16 only)")
    if compression != 0 or filter_method != 0:
        raise PngError("corrupt PNG: unknown compression or filter method")
    if interlace != 0:
        raise PngError("interlaced (Adam7) PNGs are not supported; re-save without interlacing")
    ch = _CHANNELS[colour]
    bpp = ch * depth // 8
    expected = h * (1 + w * bpp)
    inflater = zlib.decompressobj()
    try:
        raw = inflater.decompress(b"".join(idat), expected + 1)
    except zlib.error as exc:
        raise PngError(f"corrupt PNG: image data does not decompress ({exc})") from exc
    if len(raw) != expected:
        raise PngError(f"corrupt PNG: image data holds {len(raw)} bytes, expected {expected}")
    rows = _unfilter(np.frombuffer(raw, np.uint8).reshape(h, 1 + w * bpp), h, w, bpp)
    if depth == 16:
        image = rows.view(">u2").astype(np.uint16).reshape(h, w, ch)
    else:
        image = rows.reshape(h, w, ch)
    return (image[:, :, 0] if ch == 1 else image), text


def decode_png(data: bytes) -> np.ndarray:
    """Decode PNG bytes.

    Returns
    -------
    (H, W) or (H, W, C) uint8 or uint16
        Grey images come back as (H, W); C = 2 (grey+alpha), 3 (RGB) or 4 (RGBA).

    Raises
    ------
    PngError
        The data is not a PNG, is corrupt, or uses palette, bit depths below 8 or interlacing.
    """
    return _parse(data)[0]


def decode_png_text(data: bytes) -> dict[str, str]:
    """Return the ``tEXt`` key/value pairs of a PNG (checks the whole file like :func:`decode_png`)."""
    return _parse(data)[1]


def read_png(path: str | os.PathLike[str]) -> np.ndarray:
    """Read a PNG file; see :func:`decode_png` for the result's shape and dtype."""
    return decode_png(Path(path).read_bytes())
