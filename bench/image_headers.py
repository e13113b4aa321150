"""Image files for the image decoder's benchmark (``bench image_bombs``) and tests
(tests/coordinator/test_image_decode.py, the bad-input corpus): small valid files of nine
formats, and the same files with their headers patched to declare a huge image (their pixel
data stays tiny)."""
from __future__ import annotations

import struct
import zlib

import cv2
import numpy as np

BIG = (10000, 10000)       # width, height: 100 megapixels, above the 64 Mpx limit


def encoded(ext: str, image: np.ndarray) -> bytes:
    ok, buf = cv2.imencode(ext, image)
    assert ok, ext
    return buf.tobytes()


def exr(image: np.ndarray) -> bytes:
    """An uncompressed scan-line OpenEXR file of an (H, W, 3) float32 RGB image (channels B, G, R
    stored in alphabetical order, one scan line per block), written from the specification."""
    h, w, _ = image.shape

    def attr(name: str, kind: str, value: bytes) -> bytes:
        return name.encode() + b"\0" + kind.encode() + b"\0" + struct.pack("<i", len(value)) + value

    chlist = b"".join(c + b"\0" + struct.pack("<iB3xii", 2, 0, 1, 1) for c in (b"B", b"G", b"R")) + b"\0"
    box = struct.pack("<4i", 0, 0, w - 1, h - 1)
    header = (b"\x76\x2f\x31\x01" + struct.pack("<I", 2) + attr("channels", "chlist", chlist)
              + attr("compression", "compression", b"\0") + attr("dataWindow", "box2i", box)
              + attr("displayWindow", "box2i", box) + attr("lineOrder", "lineOrder", b"\0")
              + attr("pixelAspectRatio", "float", struct.pack("<f", 1.0))
              + attr("screenWindowCenter", "v2f", struct.pack("<2f", 0, 0))
              + attr("screenWindowWidth", "float", struct.pack("<f", 1.0)) + b"\0")
    blocks, offset = [], len(header) + 8 * h
    table = b""
    for y in range(h):
        row = image[y].astype("<f4")
        data = b"".join(np.ascontiguousarray(row[:, c]).tobytes() for c in (2, 1, 0))
        block = struct.pack("<ii", y, len(data)) + data
        table += struct.pack("<Q", offset)
        offset += len(block)
        blocks.append(block)
    return header + table + b"".join(blocks)


def hdr_whole(w: int = BIG[0], h: int = BIG[1]) -> bytes:
    """A complete Radiance HDR file of ``w`` x ``h`` pixels of one grey, every scan line
    run-length encoded (new-style RLE: runs of 127 per component), so 10000 x 10000 pixels take
    about 6.4 MB, the file of the issue: a decoder that trusts it fills 1.1 GiB of float pixels."""
    assert 8 <= w <= 0x7FFF
    runs, left = bytearray(), w
    while left:                    # runs of one byte, 128: mantissas 128 and exponent 128 make 0.5
        n = min(127, left)
        runs += bytes([128 + n, 128])
        left -= n
    line = bytes([2, 2, w >> 8, w & 0xFF]) + bytes(runs) * 4       # R, G, B and the exponent
    return b"#?RADIANCE\nFORMAT=32-bit_rle_rgbe\n\n" + f"-Y {h} +X {w}\n".encode() + line * h


def _png_huge(data: bytes, w: int, h: int) -> bytes:
    ihdr = bytearray(data[12:29])                     # type + 13 bytes of IHDR
    ihdr[4:12] = struct.pack(">II", w, h)
    return data[:12] + bytes(ihdr) + struct.pack(">I", zlib.crc32(bytes(ihdr))) + data[33:]


def _jpeg_huge(data: bytes, w: int, h: int) -> bytes:
    out, pos = bytearray(data), 2
    while pos < len(out):
        marker, length = out[pos + 1], struct.unpack_from(">H", out, pos + 2)[0]
        if 0xC0 <= marker <= 0xC3:
            struct.pack_into(">HH", out, pos + 5, h, w)
            return bytes(out)
        pos += 2 + length
    raise AssertionError("no SOF marker")


def _tiff_huge(data: bytes, w: int, h: int) -> bytes:
    out = bytearray(data)
    assert out[:4] == b"II*\0"
    ifd = struct.unpack_from("<I", out, 4)[0]
    for i in range(struct.unpack_from("<H", out, ifd)[0]):
        entry = ifd + 2 + 12 * i
        tag, kind = struct.unpack_from("<HH", out, entry)
        if tag in (256, 257):
            fmt = "<H" if kind == 3 else "<I"
            struct.pack_into(fmt, out, entry + 8, w if tag == 256 else h)
    return bytes(out)


def _webp_huge(data: bytes, w: int, h: int) -> bytes:
    out = bytearray(data)
    chunk = bytes(out[12:16])
    if chunk == b"VP8 ":                               # lossy: 14-bit sizes after the start code
        struct.pack_into("<HH", out, 26, w & 0x3FFF, h & 0x3FFF)
    elif chunk == b"VP8L":                             # lossless: 14-bit width-1, height-1
        bits = struct.unpack_from("<I", out, 21)[0] & ~0x0FFFFFFF
        struct.pack_into("<I", out, 21, bits | (w - 1) | ((h - 1) << 14))
    else:
        raise AssertionError(chunk)
    return bytes(out)


def _bmp_huge(data: bytes, w: int, h: int) -> bytes:
    out = bytearray(data)
    struct.pack_into("<ii", out, 18, w, h)
    return bytes(out)


def _text_huge(data: bytes, old: bytes, new: bytes) -> bytes:
    assert old in data
    return data.replace(old, new, 1)


def _exr_huge(data: bytes, w: int, h: int) -> bytes:
    i = data.index(b"dataWindow\0box2i\0") + len(b"dataWindow\0box2i\0") + 4
    return data[:i] + struct.pack("<4i", 0, 0, w - 1, h - 1) + data[i + 16:]


def source(fmt: str) -> np.ndarray:
    """The (24, 32, 3) RGB pixels the small file of ``fmt`` is written from: uint8, or float32
    in 0..4 for the float formats (HDR, EXR, PFM)."""
    rng = np.random.default_rng(len(fmt))
    if fmt in ("HDR", "EXR", "PFM"):
        return rng.random((24, 32, 3), np.float32) * 4
    return rng.integers(0, 256, (24, 32, 3), np.uint8)


def valid(fmt: str) -> bytes:
    """A small valid file of ``fmt`` (32x24 pixels of :func:`source`)."""
    rgb = source(fmt)
    if fmt == "EXR":
        return exr(rgb)
    return encoded(SUFFIX[fmt], np.ascontiguousarray(rgb[:, :, ::-1]))    # OpenCV writes BGR


def huge(fmt: str, w: int = BIG[0], h: int = BIG[1]) -> bytes:
    """The small valid file of ``fmt`` with its header declaring ``w`` x ``h`` pixels."""
    data = valid(fmt)
    if fmt == "WebP":
        w, h = min(w, 16383), min(h, 16383)            # VP8's 14-bit sides: 268 Mpx at most
    patch = {"PNG": _png_huge, "JPEG": _jpeg_huge, "TIFF": _tiff_huge, "WebP": _webp_huge, "BMP": _bmp_huge,
             "EXR": _exr_huge,
             "HDR": lambda d, w, h: _text_huge(d, b"-Y 24 +X 32", f"-Y {h} +X {w}".encode()),
             "PFM": lambda d, w, h: _text_huge(d, b"32 24", f"{w} {h}".encode()),
             "PPM": lambda d, w, h: _text_huge(d, b"32 24", f"{w} {h}".encode())}[fmt]
    return patch(data, w, h)


FORMATS = ("PNG", "JPEG", "TIFF", "WebP", "HDR", "EXR", "PFM", "PPM", "BMP")
SUFFIX = {"PNG": ".png", "JPEG": ".jpg", "TIFF": ".tif", "WebP": ".webp", "HDR": ".hdr", "EXR": ".exr",
          "PFM": ".pfm", "PPM": ".ppm", "BMP": ".bmp"}
