"""The coordinator's one image decoder: every image file an operator hands it (console uploads,
`show`, `content add`, file cameras, a job's image parameter, the demo) is decoded here, and only
after its header's declared size has been read and found within :data:`MAX_PIXELS`.

A small file can declare a huge image (a 6 MB Radiance ``.hdr`` declaring 10000x10000 pixels
took a coordinator from 206 to 2,504 MiB), so nothing is decoded blind: the format is told from
the file's first bytes (its signature, as OpenCV tells it), the size from its header -- Pillow's
lazy readers for the formats it knows (they read the header, never the pixels), this module's
own for TIFF (the first IFD's ImageWidth and ImageLength: Pillow refuses layouts it cannot hold,
such as 3-channel float), Radiance HDR (the ``-Y H +X W`` line), PFM (its three header lines)
and OpenEXR (the data and display windows) -- and a format no header reader knows is refused,
not decoded. Pixels then come from OpenCV (``imdecode``, ``IMREAD_UNCHANGED``), or from
FFmpeg's EXR decoder (PyAV) for OpenEXR, which this OpenCV build does not read.
"""
from __future__ import annotations

import io
import os
import re
import contextlib
import struct
import threading
import warnings
from pathlib import Path

import numpy as np

from protos.image_limits import MAX_IMAGE_SIDE, MAX_PIXELS, within_limits

__all__ = ["FORMATS", "MAX_PIXELS", "ImageRefused", "declared_size", "decode_image", "drop_alpha", "read_image_file",
           "sniff"]

#: what the decoder reads, as operators name the formats
FORMATS = ("PNG", "JPEG", "TIFF", "WebP", "BMP", "GIF", "JPEG 2000", "AVIF", "Sun raster", "PPM/PGM/PBM", "PFM",
           "Radiance HDR", "OpenEXR")

_EXR_MAGIC = b"\x76\x2f\x31\x01"
# Pillow's plugin module and image class per format it reads the header of
_PILLOW = {"PNG": ("PngImagePlugin", "PngImageFile"), "JPEG": ("JpegImagePlugin", "JpegImageFile"),
           "WebP": ("WebPImagePlugin", "WebPImageFile"),
           "BMP": ("BmpImagePlugin", "BmpImageFile"), "GIF": ("GifImagePlugin", "GifImageFile"),
           "JPEG 2000": ("Jpeg2KImagePlugin", "Jpeg2KImageFile"), "AVIF": ("AvifImagePlugin", "AvifImageFile"),
           "Sun raster": ("SunImagePlugin", "SunImageFile"), "PPM": ("PpmImagePlugin", "PpmImageFile")}


# Pillow's plugins warn about what they find damaged in a header (a cut EXIF block, ...); the
# refusal says it in its one line, so those warnings would only be a second, stray line on stderr.
# Set once here (catch_warnings per call is not thread-safe, and uploads decode in threads).
warnings.filterwarnings("ignore", module=r"PIL\.")


class ImageRefused(ValueError):
    """An image file refused before (or instead of) decoding it; the message is one line that
    names the file, what is wrong and what to do."""


def sniff(data: bytes) -> str | None:
    """The format of an image file's bytes from its signature (the first bytes, as OpenCV's
    decoders tell theirs), one of :data:`FORMATS`' names (``"PPM"`` for PPM/PGM/PBM); None when
    no known signature matches."""
    head = bytes(data[:32])
    if head.startswith(b"\x89PNG\r\n\x1a\n"):
        return "PNG"
    if head.startswith(b"\xff\xd8\xff"):
        return "JPEG"
    if head[:4] in (b"II*\x00", b"MM\x00*", b"II+\x00", b"MM\x00+"):
        return "TIFF"
    if head[:4] == b"RIFF" and head[8:12] == b"WEBP":
        return "WebP"
    if head.startswith(b"BM"):
        return "BMP"
    if head[:6] in (b"GIF87a", b"GIF89a"):
        return "GIF"
    if head.startswith((b"\x00\x00\x00\x0cjP  \r\n\x87\n", b"\xff\x4f\xff\x51")):
        return "JPEG 2000"
    if head[4:8] == b"ftyp" and head[8:12] in (b"avif", b"avis"):
        return "AVIF"
    if head.startswith(b"\x59\xa6\x6a\x95"):
        return "Sun raster"
    if len(head) > 2 and head[0:1] == b"P" and head[2:3].isspace():
        if head[1:2] in b"123456":
            return "PPM"
        if head[1:2] in (b"F", b"f"):
            return "PFM"
    if head.startswith((b"#?RADIANCE", b"#?RGBE")):
        return "Radiance HDR"
    if head.startswith(_EXR_MAGIC):
        return "OpenEXR"
    return None


def _pillow_size(data: bytes, fmt: str) -> tuple[int, int]:
    """(width, height) from Pillow's plugin for ``fmt``, made directly (not through
    ``Image.open``: its decompression-bomb check would refuse before the size is known, and it
    would try every other plugin on bytes this one refuses); the plugin reads the header only."""
    import importlib

    module, cls = _PILLOW[fmt]
    plugin = importlib.import_module(f"PIL.{module}")
    with getattr(plugin, cls)(io.BytesIO(data)) as im:
        return int(im.size[0]), int(im.size[1])


def _tiff_size(data: bytes) -> tuple[int, int]:
    """TIFF and BigTIFF: ImageWidth (tag 256) and ImageLength (257) of the first IFD, the page
    OpenCV decodes. Read here rather than by Pillow, which refuses pixel layouts it cannot hold
    (3-channel float32, which OpenCV reads) before it gives their size."""
    order = "<" if data[:2] == b"II" else ">"
    big = struct.unpack_from(order + "H", data, 2)[0] == 43
    if big:
        ifd = struct.unpack_from(order + "Q", data, 8)[0]
        count, pos, step, head = struct.unpack_from(order + "Q", data, ifd)[0], ifd + 8, 20, "HHQ"
    else:
        ifd = struct.unpack_from(order + "I", data, 4)[0]
        count, pos, step, head = struct.unpack_from(order + "H", data, ifd)[0], ifd + 2, 12, "HHI"
    found: dict[int, int] = {}
    for i in range(min(count, 4096)):
        entry = pos + i * step
        tag, kind, _ = struct.unpack_from(order + head, data, entry)
        if tag in (256, 257):
            value = entry + struct.calcsize("=" + head)
            code = {3: "H", 4: "I", 16: "Q"}.get(kind)
            if code is None:
                raise ValueError(f"tag {tag} has type {kind}, not SHORT or LONG")
            found[tag] = struct.unpack_from(order + code, data, value)[0]
    if len(found) < 2:
        raise ValueError("its first IFD has no ImageWidth or ImageLength")
    return found[256], found[257]


def _hdr_size(data: bytes) -> tuple[int, int]:
    """Radiance RGBE: header lines up to an empty line, then ``-Y H +X W`` (the only orientation
    OpenCV's reader takes)."""
    end = data.find(b"\n\n", 0, 65536)
    if end < 0:
        raise ValueError("no end of header in its first 64 KiB")
    line = data[end + 2: data.find(b"\n", end + 2, end + 2 + 256)].decode("ascii", "replace").strip()
    m = re.fullmatch(r"-Y\s+(\d+)\s+\+X\s+(\d+)", line)
    if not m:
        raise ValueError(f"its resolution line {line[:40]!r} is not '-Y HEIGHT +X WIDTH'")
    return int(m.group(2)), int(m.group(1))


def _pfm_size(data: bytes) -> tuple[int, int]:
    """PFM: ``PF``/``Pf``, then width and height, then the scale (its sign the byte order)."""
    tokens = data[:256].split(maxsplit=4)
    if len(tokens) < 4:
        raise ValueError("its header is not 'PF WIDTH HEIGHT SCALE'")
    try:
        w, h, scale = int(tokens[1]), int(tokens[2]), float(tokens[3])
    except ValueError:
        raise ValueError("its header is not 'PF WIDTH HEIGHT SCALE'") from None
    if scale == 0 or not np.isfinite(scale):
        raise ValueError(f"its scale {tokens[3].decode('ascii', 'replace')!r} is not a non-zero number")
    return w, h


def _exr_size(data: bytes) -> tuple[int, int]:
    """OpenEXR: the header's attributes (name, type, int32 size, value; an empty name ends it)
    hold two box2i windows (xMin, yMin, xMax, yMax): ``dataWindow``, the pixels stored, and
    ``displayWindow``, the frame FFmpeg's decoder allocates and returns. Both count: the
    size returned is the display window's, or the window beyond the limit when one is.
    Single-part scan-line or tiled files; deep and multi-part files are refused."""
    version = struct.unpack_from("<I", data, 4)[0] if len(data) >= 8 else 0
    if version & 0xFF != 2:
        raise ValueError(f"OpenEXR version {version & 0xFF} (2 expected)")
    if version & 0x1800:
        raise ValueError("a deep or multi-part OpenEXR file; give a single-part image")
    windows: dict[bytes, tuple[int, int]] = {}
    pos, limit = 8, min(len(data), 1 << 20)
    while pos < limit:
        nul = data.find(b"\x00", pos, pos + 256)
        if nul < 0:
            break
        name = data[pos:nul]
        if not name:
            break
        tnul = data.find(b"\x00", nul + 1, nul + 1 + 256)
        if tnul < 0 or tnul + 5 > len(data):
            break
        kind = data[nul + 1:tnul]
        size = struct.unpack_from("<i", data, tnul + 1)[0]
        value = tnul + 5
        if size < 0 or value + size > len(data):
            break
        if name in (b"dataWindow", b"displayWindow") and kind == b"box2i" and size == 16:
            x0, y0, x1, y1 = struct.unpack_from("<4i", data, value)
            windows[name] = (x1 - x0 + 1, y1 - y0 + 1)
        pos = value + size
    if len(windows) < 2:
        raise ValueError(f"no {' or '.join(w.decode() for w in (b'dataWindow', b'displayWindow') if w not in windows)}"
                         " in its header")
    beyond = [wh for wh in windows.values() if not within_limits(*wh)]
    return beyond[0] if beyond else windows[b"displayWindow"]


def declared_size(data: bytes, name: str = "the image") -> tuple[str, int, int]:
    """``(format, width, height)`` that an image file's bytes declare, read from its header
    without decoding any pixel.

    Raises
    ------
    ImageRefused
        The format is none the decoder reads (:data:`FORMATS`), or its header cannot be read.
    """
    fmt = sniff(data)
    if fmt is None:
        raise ImageRefused(f"{name} is not an image the coordinator reads: give {', '.join(FORMATS[:-1])} or "
                           f"{FORMATS[-1]}")
    try:
        if fmt == "Radiance HDR":
            w, h = _hdr_size(data)
        elif fmt == "PFM":
            w, h = _pfm_size(data)
        elif fmt == "OpenEXR":
            w, h = _exr_size(data)
        elif fmt == "TIFF":
            w, h = _tiff_size(data)
        else:
            w, h = _pillow_size(data, fmt)
    except struct.error:      # an offset or a field past the end of the bytes
        raise ImageRefused(f"{name}: its {fmt} header cannot be read (the file ends inside it); is the file "
                           "whole?") from None
    except Exception as exc:  # noqa: BLE001 - any failure to read the header refuses the file
        why = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
        raise ImageRefused(f"{name}: its {fmt} header cannot be read ({why}); is the file whole?") from None
    return fmt, w, h


def _check_size(fmt: str, w: int, h: int, name: str) -> None:
    if not within_limits(w, h):
        raise ImageRefused(f"{name}: its {fmt} header declares {w}x{h} pixels ({w * h / 1e6:.1f} megapixels), "
                           f"nothing was decoded: the coordinator reads images of at most {MAX_PIXELS / 1e6:.0f} "
                           f"megapixels and {MAX_IMAGE_SIDE} pixels a side (scale it down; the rig shows it at its "
                           "content size anyway)")


_quiet_lock = threading.Lock()
_quiet_depth = 0
_quiet_saved = 0


@contextlib.contextmanager
def _opencv_quiet():
    """OpenCV's own log off while it decodes (its ``[ WARN ]``/``[ERROR]`` lines about a damaged
    file would be more lines on stderr beside the refusal); restored when the last concurrent
    decode ends (uploads decode in threads)."""
    import cv2

    global _quiet_depth, _quiet_saved
    with _quiet_lock:
        if _quiet_depth == 0:
            _quiet_saved = cv2.utils.logging.getLogLevel()
            cv2.utils.logging.setLogLevel(cv2.utils.logging.LOG_LEVEL_SILENT)
        _quiet_depth += 1
    try:
        yield
    finally:
        with _quiet_lock:
            _quiet_depth -= 1
            if _quiet_depth == 0:
                cv2.utils.logging.setLogLevel(_quiet_saved)


def _decode_exr(data: bytes, name: str) -> np.ndarray:
    """OpenEXR through FFmpeg's decoder (PyAV): float32 RGB(A) or grey."""
    import av

    ctx = av.CodecContext.create("exr", "r")
    try:
        frames = ctx.decode(av.Packet(bytes(data))) + ctx.decode(None)
    except (av.FFmpegError, ValueError) as exc:
        raise ImageRefused(f"{name}: its OpenEXR pixels cannot be decoded ({str(exc).splitlines()[0]})") from None
    if not frames:
        raise ImageRefused(f"{name}: its OpenEXR pixels cannot be decoded (truncated?)")
    frame = frames[0]
    fmt = frame.format.name
    if fmt.startswith("gbrap"):
        img = frame.to_ndarray(format="gbrapf32le")
    elif fmt.startswith("gbrp"):
        img = frame.to_ndarray(format="gbrpf32le")
    elif fmt.startswith("gray"):
        img = frame.to_ndarray(format="grayf32le")
    else:
        raise ImageRefused(f"{name}: OpenEXR pixels of format {fmt} are not supported; give RGB, RGBA or Y")
    return np.ascontiguousarray(img, dtype=np.float32)


def decode_image(data: bytes, name: str = "the image") -> np.ndarray:
    """Decode an image file's bytes, after its declared size has passed the limit.

    Returns
    -------
    (H, W) or (H, W, C) array, C in 2..4
        RGB(A) channel order; the file's own sample type as OpenCV's ``imdecode`` with
        ``IMREAD_UNCHANGED`` gives it (uint8, uint16, float32, ...), float32 for OpenEXR.

    Raises
    ------
    ImageRefused
        One line naming ``name``: an empty file, a format the decoder does not read, a header
        it cannot read, a declared size above :data:`MAX_PIXELS` or ``MAX_IMAGE_SIDE`` a side (then
        nothing is decoded), or pixels the decoder cannot read.
    """
    if not data:
        raise ImageRefused(f"{name} is empty: give an image file")
    fmt, w, h = declared_size(data, name)
    _check_size(fmt, w, h, name)
    if fmt == "OpenEXR":
        img = _decode_exr(data, name)
    else:
        import cv2  # the coordinator's stack

        try:
            with _opencv_quiet():
                img = cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_UNCHANGED)
        except cv2.error as exc:
            img = None
            why = str(exc).strip().splitlines()[-1]
        else:
            why = "truncated or corrupt?"
        if img is None:
            raise ImageRefused(f"{name}: its {fmt} pixels cannot be decoded ({why})")
        if img.ndim == 3 and img.shape[2] in (3, 4):   # OpenCV's BGR(A) -> RGB(A), any sample type
            img = np.ascontiguousarray(img[:, :, [2, 1, 0, 3][:img.shape[2]]])
    if img.shape[:2] != (h, w):
        raise ImageRefused(f"{name}: its {fmt} header declares {w}x{h} pixels but it decodes to "
                           f"{img.shape[1]}x{img.shape[0]}: the file is inconsistent")
    return img


def drop_alpha(img: np.ndarray) -> np.ndarray:
    """``img`` without its alpha channel: (H, W, 2) grey+alpha -> (H, W, 1), (H, W, 4) RGBA ->
    (H, W, 3) (views, no copy); any other shape unchanged."""
    if img.ndim == 3 and img.shape[2] in (2, 4):
        return img[:, :, :img.shape[2] - 1]
    return img


def read_image_file(path: str | os.PathLike[str], name: str | None = None) -> np.ndarray:
    """:func:`decode_image` of a file's bytes (``name`` defaults to the path); a missing or
    unreadable file is an :class:`ImageRefused` too."""
    p = Path(path)
    name = name or str(p)
    try:
        data = p.read_bytes()
    except FileNotFoundError:
        raise ImageRefused(f"{name}: no such file") from None
    except IsADirectoryError:
        raise ImageRefused(f"{name}: is a folder, not an image file") from None
    except OSError as exc:
        raise ImageRefused(f"{name}: cannot be read ({exc.strerror or exc})") from None
    return decode_image(data, name)
