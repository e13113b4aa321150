"""node/image_files.py (FFmpeg's PNG codec via PyAV) against OpenCV's (libpng) and PNGs built by hand."""
from __future__ import annotations

import os
import zlib

import cv2
import numpy as np
import pytest

from node.image_files import (
    FILTERS,
    PngError,
    PngTooLarge,
    atomic_write_bytes,
    decode_png,
    decode_png_text,
    encode_png,
    read_png,
    write_png,
)

RNG = np.random.default_rng(20240601)


def _random(shape, dtype):
    return RNG.integers(0, np.iinfo(dtype).max + 1, size=shape, dtype=dtype)


def _cv_to_png_order(img: np.ndarray) -> np.ndarray:
    """OpenCV decodes to BGR(A); PNG (and node.image_files) order is RGB(A)."""
    if img.ndim == 3 and img.shape[2] == 3:
        return img[:, :, ::-1]
    if img.ndim == 3 and img.shape[2] == 4:
        return img[:, :, [2, 1, 0, 3]]
    return img


def _squeeze_grey(img: np.ndarray) -> np.ndarray:
    return img[:, :, 0] if img.ndim == 3 and img.shape[2] == 1 else img


@pytest.mark.parametrize("dtype", [np.uint8, np.uint16])
@pytest.mark.parametrize("shape", [(1, 1), (5, 7), (6, 3, 1), (4, 9, 2), (13, 11, 3), (8, 5, 4)])
@pytest.mark.parametrize("filter", FILTERS)
def test_round_trip_and_libpng_agrees(dtype, shape, filter):
    img = _random(shape, dtype)
    data = encode_png(img, filter=filter)
    back = decode_png(data)
    expected = _squeeze_grey(img)
    assert back.dtype == dtype and back.shape == expected.shape
    np.testing.assert_array_equal(back, expected)
    if not (img.ndim == 3 and img.shape[2] == 2):  # OpenCV has no grey+alpha image type
        ref = cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_UNCHANGED)
        assert ref is not None, "libpng rejected our file"
        np.testing.assert_array_equal(_cv_to_png_order(ref), expected)


LIBPNG_FILTERS = {
    "sub": cv2.IMWRITE_PNG_FILTER_SUB,
    "up": cv2.IMWRITE_PNG_FILTER_UP,
    "average": cv2.IMWRITE_PNG_FILTER_AVG,
    "paeth": cv2.IMWRITE_PNG_FILTER_PAETH,
    "all": cv2.IMWRITE_PNG_ALL_FILTERS,
}


def _libpng_filter_bytes(data: bytes, h: int, w: int, bpp: int) -> set[int]:
    """The row filter types in a PNG written by libpng (inflate the IDAT ourselves)."""
    pos, idat = 8, b""
    while pos < len(data):
        n = int.from_bytes(data[pos : pos + 4], "big")
        if data[pos + 4 : pos + 8] == b"IDAT":
            idat += data[pos + 8 : pos + 8 + n]
        pos += 12 + n
    raw = np.frombuffer(zlib.decompress(idat), np.uint8).reshape(h, 1 + w * bpp)
    return set(raw[:, 0].tolist())


@pytest.mark.parametrize("dtype", [np.uint8, np.uint16])
@pytest.mark.parametrize("channels", [1, 3, 4])
@pytest.mark.parametrize("libpng_filter", sorted(LIBPNG_FILTERS))
def test_reads_libpng_files_with_every_filter(dtype, channels, libpng_filter):
    h, w = 37, 53
    yy, xx = np.mgrid[0:h, 0:w]
    base = np.stack([np.sin(xx / 5.0 + c) * np.cos(yy / 7.0 - c) for c in range(channels)], axis=-1)
    scale = np.iinfo(dtype).max
    img = ((base + 1) / 2 * scale).astype(dtype)
    img[::5, ::3] = _random(img[::5, ::3].shape, dtype)  # some noise
    bgr = _cv_to_png_order(img) if channels > 1 else img[:, :, 0]
    ok, buf = cv2.imencode(".png", np.ascontiguousarray(bgr), [cv2.IMWRITE_PNG_FILTER, LIBPNG_FILTERS[libpng_filter]])
    assert ok
    data = buf.tobytes()
    # guard: libpng really used the filter asked for (Average = 3, Paeth = 4 are the hard ones)
    used = _libpng_filter_bytes(data, h, w, channels * img.itemsize)
    code = {"sub": 1, "up": 2, "average": 3, "paeth": 4}.get(libpng_filter)
    assert code in used if code else len(used) >= 2
    np.testing.assert_array_equal(decode_png(data), _squeeze_grey(img))


def test_text_chunks_round_trip():
    img = _random((4, 4, 3), np.uint8)
    data = encode_png(img, text={"frame_id": "17", "tag": "show:white"})
    assert decode_png_text(data) == {"frame_id": "17", "tag": "show:white"}
    with pytest.raises(ValueError):
        encode_png(img, text={"": "x"})
    with pytest.raises(ValueError):
        encode_png(img, text={"key": "snow \u2603"})


def test_write_png_is_atomic_and_leaves_no_temp_files(tmp_path):
    img = _random((20, 30, 3), np.uint8)
    path = tmp_path / "r0c0.png"
    write_png(path, img, compress_level=1)
    first_inode = os.stat(path).st_ino
    img2 = _random((20, 30, 3), np.uint8)
    write_png(path, img2)
    assert os.stat(path).st_ino != first_inode  # replaced by rename, not rewritten in place
    np.testing.assert_array_equal(read_png(path), img2)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["r0c0.png"]


def test_write_png_failure_keeps_the_old_file(tmp_path):
    path = tmp_path / "a.png"
    img = _random((3, 3), np.uint8)
    write_png(path, img)
    with pytest.raises(ValueError):
        write_png(path, np.zeros((3, 3), np.float32))
    np.testing.assert_array_equal(read_png(path), img)
    assert [p.name for p in tmp_path.iterdir()] == ["a.png"]


@pytest.mark.parametrize(
    "bad",
    [np.zeros((4, 4), np.float32), np.zeros((4, 4, 5), np.uint8), np.zeros((0, 4), np.uint8), np.zeros(4, np.uint8)],
)
def test_encode_rejects_bad_images(bad):
    with pytest.raises(ValueError):
        encode_png(bad)


def test_encode_rejects_bad_options():
    img = np.zeros((2, 2), np.uint8)
    with pytest.raises(ValueError, match="filter"):
        encode_png(img, filter="best")
    with pytest.raises(ValueError, match="compress_level"):
        encode_png(img, compress_level=11)


def test_decode_detects_corruption():
    img = _random((6, 6, 3), np.uint8)
    data = bytearray(encode_png(img))
    with pytest.raises(PngError, match="signature"):
        decode_png(b"GIF89a" + bytes(data[6:]))
    flipped = bytearray(data)
    flipped[40] ^= 0xFF  # inside IHDR/IDAT: CRC must catch it
    with pytest.raises(PngError, match="corrupt"):
        decode_png(bytes(flipped))
    with pytest.raises(PngError, match="corrupt|truncated"):
        decode_png(bytes(data[:-20]))


# ---------------------------------------------------------------- what the old reader refused


def _chunk(kind: bytes, data: bytes) -> bytes:
    return len(data).to_bytes(4, "big") + kind + data + (zlib.crc32(kind + data) & 0xFFFFFFFF).to_bytes(4, "big")


def _hand_png(w, h, depth, colour, rows: list[bytes], plte: bytes = b"", trns: bytes = b"") -> bytes:
    """A non-interlaced PNG built from packed rows (filter type 0), by the spec, with zlib only."""
    ihdr = w.to_bytes(4, "big") + h.to_bytes(4, "big") + bytes([depth, colour, 0, 0, 0])
    idat = zlib.compress(b"".join(b"\x00" + r for r in rows))
    parts = [b"\x89PNG\r\n\x1a\n", _chunk(b"IHDR", ihdr)]
    if plte:
        parts.append(_chunk(b"PLTE", plte))
    if trns:
        parts.append(_chunk(b"tRNS", trns))
    return b"".join(parts + [_chunk(b"IDAT", idat), _chunk(b"IEND", b"")])


def _pack(idx: np.ndarray, depth: int) -> list[bytes]:
    """Pack (H, W) samples of ``depth`` < 8 bits into PNG rows (first pixel in the high bits)."""
    per = 8 // depth
    h, w = idx.shape
    padded = np.zeros((h, -(-w // per) * per), np.uint8)
    padded[:, :w] = idx
    grouped = padded.reshape(h, -1, per).astype(np.uint16)
    shifts = np.array([8 - depth * (k + 1) for k in range(per)], np.uint16)
    return [bytes(r) for r in (grouped << shifts).sum(axis=2).astype(np.uint8)]


@pytest.mark.parametrize("depth", [1, 2, 4])
def test_sub_byte_grey_scales_to_8_bit_like_libpng(depth):
    v = _random((7, 13), np.uint8) % (1 << depth)
    data = _hand_png(13, 7, depth, 0, _pack(v, depth))
    got = decode_png(data)
    expected = (v.astype(np.int32) * 255 // ((1 << depth) - 1)).astype(np.uint8)
    assert got.dtype == np.uint8 and got.shape == (7, 13)
    np.testing.assert_array_equal(got, expected)
    np.testing.assert_array_equal(got, cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_UNCHANGED))


@pytest.mark.parametrize("depth", [1, 2, 4, 8])
@pytest.mark.parametrize("alpha", [False, True])
def test_palette_images_decode_to_rgb_or_rgba(depth, alpha):
    n = 1 << depth
    palette = _random((n, 3), np.uint8)
    idx = (_random((6, 11), np.uint8).astype(np.int64) % n).astype(np.uint8)
    trns = bytes(_random(n, np.uint8)) if alpha else b""
    data = _hand_png(11, 6, depth, 3, _pack(idx, depth) if depth < 8 else [bytes(r) for r in idx],
                     plte=palette.tobytes(), trns=trns)
    got = decode_png(data)
    expected = palette[idx]
    if alpha:
        expected = np.concatenate([expected, np.frombuffer(trns, np.uint8)[idx][:, :, None]], axis=2)
    assert got.dtype == np.uint8 and got.shape == expected.shape
    np.testing.assert_array_equal(got, expected)
    np.testing.assert_array_equal(got, _cv_to_png_order(cv2.imdecode(np.frombuffer(data, np.uint8),
                                                                       cv2.IMREAD_UNCHANGED)))


def _interlaced(img: np.ndarray) -> bytes:
    """An Adam7-interlaced PNG from FFmpeg's encoder (AV_CODEC_FLAG_INTERLACED_DCT)."""
    import av

    fmt = {(1, 1): "gray", (1, 2): "gray16be", (3, 1): "rgb24", (3, 2): "rgb48be", (4, 1): "rgba",
           (4, 2): "rgba64be"}[(img.shape[2], img.itemsize)]
    ctx = av.CodecContext.create("png", "w")
    ctx.width, ctx.height, ctx.pix_fmt = img.shape[1], img.shape[0], fmt
    ctx.flags |= 1 << 18
    h, w = img.shape[:2]
    frame = av.VideoFrame(w, h, fmt)
    rows = np.zeros((h, frame.planes[0].line_size), np.uint8)
    rows[:, : w * img.shape[2] * img.itemsize] = img.astype(">u2" if img.itemsize == 2 else "u1").view(
        np.uint8).reshape(h, -1)
    frame.planes[0].update(rows)
    return b"".join(bytes(p) for p in ctx.encode(frame) + ctx.encode(None))


@pytest.mark.parametrize("dtype", [np.uint8, np.uint16])
@pytest.mark.parametrize("channels", [1, 3, 4])
def test_interlaced_images_decode_exactly(dtype, channels):
    img = _random((13, 17, channels), dtype)
    data = _interlaced(img)
    assert data[28] == 1, "not interlaced"
    ref = cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_UNCHANGED)
    np.testing.assert_array_equal(_cv_to_png_order(ref), _squeeze_grey(img))  # libpng agrees it is img
    got = decode_png(data)
    assert got.dtype == dtype
    np.testing.assert_array_equal(got, _squeeze_grey(img))


def test_decode_png_text_checks_the_file():
    data = encode_png(_random((3, 3), np.uint8), text={"k": "v"})
    assert decode_png_text(data) == {"k": "v"}
    with pytest.raises(PngError, match="truncated"):
        decode_png_text(data[:-6])


def test_atomic_write_bytes_replaces_the_file(tmp_path):
    path = tmp_path / "a.json"
    atomic_write_bytes(path, b"one")
    atomic_write_bytes(path, b"two")
    assert path.read_bytes() == b"two"
    assert [p.name for p in tmp_path.iterdir()] == ["a.json"]


def _png_declaring(w: int, h: int) -> bytes:
    """A small 8-bit RGB PNG whose IHDR (CRC fixed) declares ``w`` x ``h`` pixels."""
    data = encode_png(np.zeros((4, 4, 3), np.uint8))
    ihdr = bytearray(data[12:29])
    ihdr[4:12] = w.to_bytes(4, "big") + h.to_bytes(4, "big")
    return data[:12] + bytes(ihdr) + zlib.crc32(bytes(ihdr)).to_bytes(4, "big") + data[33:]


@pytest.mark.parametrize("w, h", [(10000, 10000), (20000, 10), (0, 4)])
def test_a_png_declaring_too_many_pixels_is_refused_from_its_header(tmp_path, w, h):
    """FFmpeg allocates the declared frame before it finds the data missing (293 MiB for a 300-byte
    10000x10000 PNG); the header check refuses first, and the asset decoder does not hand the file
    to FFmpeg's png_pipe instead."""
    from node.asset_decode import DecodeError
    from node.asset_decode import decode_image as decode_asset_image

    data = _png_declaring(w, h)
    with pytest.raises(PngTooLarge, match=rf"PNG declares {w}x{h} pixels, outside what a node decodes \(1\.\.16384 pixels a side, at most 67 megapixels\)"):
        decode_png(data)
    (tmp_path / "blob").write_bytes(data)
    with pytest.raises(DecodeError, match=f"PNG declares {w}x{h} pixels"):
        decode_asset_image(tmp_path / "blob", name="huge.png", channels=3, bit_depth=8)
    assert decode_png(_png_declaring(4, 4)).shape == (4, 4, 3)
