"""What a source file or folder holds, before it becomes an asset: frame size, channels, bit
depth, frame count and rate, probed from stills (OpenCV, numpy), image sequences (every frame
like the first) and videos (PyAV, FFmpeg's bindings).
"""
from __future__ import annotations

import math
import os
import re
from dataclasses import dataclass, field
from fractions import Fraction
from pathlib import Path
from typing import Any, Callable

import numpy as np

from coordinator.errors import AssetError
from coordinator.float_range import check_float_range
from coordinator.image_decode import ImageRefused, read_image_file

STILL_SUFFIXES = (".png", ".tif", ".tiff", ".jpg", ".jpeg", ".npy")
VIDEO_SUFFIXES = (".mp4", ".mov", ".mkv", ".avi")
DEFAULT_SEQUENCE_FPS = 30.0

Note = Callable[[str], None]


@dataclass(frozen=True)
class Probe:
    """What probing a source found: frame size in pixels, channels (1..4), bit depth (8, 10, 12,
    16 integer or 32 float), frame count, frame rate (0 for a still) and kind-specific facts."""

    width: int
    height: int
    channels: int
    bit_depth: int
    frames: int = 1
    fps: float = 0.0
    extra: dict[str, Any] = field(default_factory=dict)

    def describe(self) -> str:
        return f"{self.width}x{self.height}, {self.channels} ch, {self.bit_depth}-bit"



_DTYPE_DEPTH = {np.dtype(np.uint8): 8, np.dtype(np.uint16): 16, np.dtype(np.float32): 32}


def _image_probe(shape: tuple[int, ...], dtype: np.dtype, path: Path) -> Probe:
    if len(shape) not in (2, 3) or (len(shape) == 3 and not 1 <= shape[2] <= 4) or 0 in shape:
        raise AssetError(f"{path}: an image must be (H, W) or (H, W, C) with C in 1..4, got shape {tuple(shape)}")
    depth = _DTYPE_DEPTH.get(np.dtype(dtype))
    if depth is None:
        raise AssetError(f"{path}: pixels must be uint8, uint16 or float32, got {np.dtype(dtype)}")
    return Probe(width=int(shape[1]), height=int(shape[0]), channels=int(shape[2]) if len(shape) == 3 else 1,
                 bit_depth=depth)


def probe_still(path: str | os.PathLike[str]) -> Probe:
    """Probe one image file.

    PNG (8/16-bit), TIFF and JPEG are decoded by :func:`coordinator.image_decode.decode_image`
    (its declared size checked against the limit before any pixel is decoded): uint8 -> 8 bit,
    uint16 -> 16 bit, float32 (TIFF) -> 32 bit. ``.npy`` must hold float32 of shape (H, W) or
    (H, W, C); it is memory-mapped, not loaded. Float pixels must be finite and within 0..1.

    Returns
    -------
    Probe
        ``frames`` 1, ``fps`` 0.

    Raises
    ------
    AssetError
        The file is missing, not an image, or of an unsupported shape or dtype.
    """
    path = Path(path)
    suffix = path.suffix.lower()
    if suffix not in STILL_SUFFIXES:
        raise AssetError(f"{path}: not a still image file (suffixes: {', '.join(STILL_SUFFIXES)})")
    if not path.is_file():
        raise AssetError(f"{path}: no such file")
    if suffix == ".npy":
        try:
            arr = np.load(path, mmap_mode="r", allow_pickle=False)
        except (ValueError, OSError, EOFError) as exc:
            raise AssetError(f"{path}: not a readable .npy array ({exc})") from exc
        if arr.dtype != np.dtype(np.float32):
            raise AssetError(f"{path}: a .npy still must be float32 (native byte order), got {arr.dtype}")
        probe = _image_probe(arr.shape, arr.dtype, path)
        _float_range(arr, path)
        return probe
    try:
        img = read_image_file(path)
    except ImageRefused as exc:
        raise AssetError(str(exc)) from None
    probe = _image_probe(img.shape, img.dtype, path)
    _float_range(img, path)
    return probe


def _float_range(img: np.ndarray, path: Path) -> None:
    """Float pixels outside 0..1 would be shown clipped without a word: refused (AssetError)."""
    try:
        check_float_range(img, str(path), hint="clip it to 0..1 before adding it (an asset is stored byte for byte)")
    except ValueError as exc:
        raise AssetError(str(exc)) from None


def _natural_key(name: str) -> list[Any]:
    return [(0, int(t), t) if t.isdigit() else (1, 0, t) for t in re.split(r"(\d+)", name) if t]


def sequence_files(folder: str | os.PathLike[str], *, note: Note | None = None) -> list[Path]:
    """The frames of an image-sequence folder: its image files (suffixes of stills), sorted by name.

    Hidden files are skipped; other files and subfolders are skipped with a note. Names whose
    text order differs from their numeric order (``f2.png`` after ``f10.png``) are refused:
    the frame order would silently be wrong; zero-pad the numbers.
    """
    folder = Path(folder)
    if not folder.is_dir():
        raise AssetError(f"{folder}: not a folder")
    frames, skipped = [], []
    for p in folder.iterdir():
        if p.name.startswith("."):
            continue
        if p.is_file() and p.suffix.lower() in STILL_SUFFIXES:
            frames.append(p)
        else:
            skipped.append(p.name)
    if not frames:
        raise AssetError(f"{folder}: no image files ({', '.join(STILL_SUFFIXES)}) for a sequence")
    frames.sort(key=lambda p: p.name)
    natural = sorted(frames, key=lambda p: _natural_key(p.name))
    if natural != frames:
        i = next(i for i, (a, b) in enumerate(zip(frames, natural)) if a != b)
        raise AssetError(f"{folder}: frame names sort differently as text and as numbers ({frames[i].name!r} comes "
                         f"before {natural[i].name!r} by name); zero-pad the frame numbers so the order is certain")
    if skipped and note:
        note(f"{folder}: skipped {len(skipped)} entries that are not image files: {', '.join(sorted(skipped)[:5])}"
             + (" ..." if len(skipped) > 5 else ""))
    return frames


def probe_sequence(files: list[Path], *, fps: float) -> Probe:
    """Probe every frame of a sequence; all must share the first frame's size, channels and
    depth (:class:`AssetError` names an unreadable frame or the first one that differs)."""
    first = probe_still(files[0])
    for i, f in enumerate(files[1:], start=1):
        p = probe_still(f)
        if (p.width, p.height, p.channels, p.bit_depth) != (first.width, first.height, first.channels, first.bit_depth):
            raise AssetError(f"sequence frame {i} {f.name!r} is {p.describe()}, but the first frame "
                             f"{files[0].name!r} is {first.describe()}: every frame must match")
    return Probe(first.width, first.height, first.channels, first.bit_depth, frames=len(files), fps=float(fps))


def pixel_format_layout(pix_fmt: str) -> tuple[int, int]:
    """Channels and bit depth of an FFmpeg pixel format.

    ``yuv420p`` -> (3, 8), ``yuv420p10le`` -> (3, 10), ``gray16le`` -> (1, 16), ``rgba`` ->
    (4, 8), ``pal8`` -> (3, 8), ``gbrpf32le`` -> (3, 32). Depths round up to 8, 10, 12 or 16.
    """
    from av.video.format import VideoFormat

    try:
        fmt = VideoFormat(pix_fmt)
    except (ValueError, TypeError) as exc:
        raise AssetError(f"unknown pixel format {pix_fmt!r}") from exc
    if fmt.has_palette:
        return 3, 8
    comps = fmt.components
    bits = max(c.bits for c in comps)
    if "f32" in pix_fmt:
        return len(comps), 32
    if "f16" in pix_fmt or bits > 16:
        raise AssetError(f"pixel format {pix_fmt!r} ({bits}-bit) is not supported (8..16-bit integer or float32)")
    return len(comps), next(d for d in (8, 10, 12, 16) if bits <= d)


#: `content add` notes a video whose keyframes are further apart than this
LONG_GOP_S = 2.0


def keyframe_gap_s(path: str | os.PathLike[str], fps: float) -> float | None:
    """The longest stretch of a video without a keyframe, in seconds at ``fps`` (its packets
    demuxed, nothing decoded; None when it cannot be read). A node joining a show mid-way decodes
    from the keyframe before its first frame: up to this much video before it can show one."""
    import av

    try:
        with av.open(str(path), mode="r") as container:
            stream = container.streams.video[0]
            gap = longest = 0
            for packet in container.demux(stream):
                if packet.size == 0:
                    continue
                gap = 0 if packet.is_keyframe else gap + 1
                longest = max(longest, gap)
    except (av.FFmpegError, OSError, ValueError, IndexError):
        return None
    return (longest + 1) / fps if fps > 0 else None


def probe_video(path: str | os.PathLike[str], *, fps: float | None = None) -> Probe:
    """Probe a video file with PyAV without decoding more than its first frame.

    The frame count is the container's (MP4/MOV sample tables) when it has one, else the number
    of the stream's packets found by demuxing (MKV, AVI, fragmented MP4). The frame rate is the
    stream's average rate as a float; ``fps`` is used only when the container has none, and
    refused when it disagrees with the container's. Size and pixel format come from the first
    decoded frame. ``extra`` holds ``codec``, ``pix_fmt``, ``container`` and the exact ``rate``.

    Raises
    ------
    AssetError
        Unreadable or undecodable file, no video stream, no frames, or no frame rate.
    """
    import av

    path = Path(path)
    if not path.is_file():
        raise AssetError(f"{path}: no such file")
    try:
        container = av.open(str(path), mode="r")
    except (av.FFmpegError, OSError, ValueError) as exc:
        raise AssetError(f"{path}: not a video PyAV can open ({exc})") from exc
    try:
        if not container.streams.video:
            raise AssetError(f"{path}: holds no video stream")
        stream = container.streams.video[0]
        fmt_name = container.format.name
        trusted = stream.frames if stream.frames > 0 and fmt_name.split(",")[0] == "mov" else 0
        first, packets = None, 0
        for packet in container.demux(stream):
            if packet.size == 0:
                continue
            packets += 1
            if first is None:
                frames = packet.decode()
                first = frames[0] if frames else None
            if first is not None and trusted:
                break
        if first is None and packets:
            frames = stream.codec_context.decode(None)
            first = frames[0] if frames else None
        rate = stream.average_rate or stream.guessed_rate
        codec = stream.codec_context.name
    except av.FFmpegError as exc:
        raise AssetError(f"{path}: cannot be decoded ({exc})") from exc
    finally:
        container.close()
    if first is None:
        raise AssetError(f"{path}: its video stream has no decodable frames")
    count = trusted or packets
    if rate is not None and rate > 0:
        rate_f = float(rate)
        if fps is not None and not math.isclose(fps, rate_f, rel_tol=1e-6):
            raise AssetError(f"{path}: the video runs at {rate_f:g} fps, not {fps:g}: a video keeps its own frame rate")
    elif fps is not None:
        rate, rate_f = Fraction(fps).limit_denominator(1001000), float(fps)
    else:
        raise AssetError(f"{path}: the container gives no frame rate; pass one (--fps)")
    channels, depth = pixel_format_layout(first.format.name)
    extra = {"codec": codec, "pix_fmt": first.format.name, "container": fmt_name.split(",")[0],
             "rate": f"{rate.numerator}/{rate.denominator}"}
    return Probe(width=first.width, height=first.height, channels=channels, bit_depth=depth, frames=count,
                 fps=rate_f, extra=extra)
