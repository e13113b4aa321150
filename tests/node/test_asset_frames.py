"""The node's frame source on real files in a real AssetCache: PNG/JPEG/TIFF/.npy stills, PNG
sequences and videos encoded here with PyAV (lossless ones compared bit-exact, lossy ones
identified by their grey level), sequential decoding, seeks both ways, loops, 10-bit content,
and the decode-ahead thread (hits and misses counted, errors surfacing on get, joined on close)."""
from __future__ import annotations

import threading
import time
from fractions import Fraction
from pathlib import Path

import av
import numpy as np
import pytest

from node.asset_cache import AssetCache
from node.asset_frames import DecodeAhead, FrameError, FrameNotReady, FrameSource, open_frames
from node.errors import NodeError
from node.image_files import encode_png
from protos.asset_manifest import Blob, Manifest, sha256_hex
from tests.support.waits import wait_until

RATE = Fraction(24)


# ---------------------------------------------------------------------------- helpers

@pytest.fixture
def cache(tmp_path):
    with AssetCache(tmp_path / "cache", max_bytes=1 << 31) as c:
        yield c


def put(cache: AssetCache, kind: str, files: list[tuple[str, bytes]], *, width: int, height: int, channels: int,
        bit_depth: int, frames: int | None = None, fps: float = 0.0, extra: dict | None = None,
        name: str = "test") -> str:
    """Add an asset to the cache the way the node fetches one: begin, chunks, finish."""
    blobs = tuple(Blob(sha256_hex(data), len(data), fname) for fname, data in files)
    m = Manifest(kind=kind, name=name, blobs=blobs, width=width, height=height, channels=channels,
                 bit_depth=bit_depth, frames=frames if frames is not None else len(files), fps=fps,
                 extra=extra or {})
    cache.begin(m.canonical(), m.asset_id)
    by_sha = {sha256_hex(d): d for _, d in files}
    for sha, _, _ in cache.missing(m.asset_id):
        cache.write_chunk(sha, 0, by_sha[sha])
        cache.finish_blob(sha)
    assert cache.ready(m.asset_id)
    return m.asset_id


def encode_video(path: Path, images: list[np.ndarray], *, codec: str, pix_fmt: str, fmt_in: str,
                 options: dict | None = None, rate: Fraction = RATE) -> bytes:
    """Encode ``images`` (numpy, in ``fmt_in``) with PyAV; return the file's bytes."""
    with av.open(str(path), "w") as c:
        s = c.add_stream(codec, rate=rate)
        s.height, s.width = images[0].shape[:2]
        s.pix_fmt = pix_fmt
        s.options = options or {}
        for img in images:
            for p in s.encode(av.VideoFrame.from_ndarray(img, format=fmt_in)):
                c.mux(p)
        for p in s.encode():
            c.mux(p)
    return path.read_bytes()


def put_video(cache: AssetCache, data: bytes, name: str, *, frames: int, width: int, height: int, channels: int,
              bit_depth: int, container: str, pix_fmt: str, rate: Fraction = RATE) -> str:
    extra = {"codec": "", "pix_fmt": pix_fmt, "container": container, "rate": f"{rate.numerator}/{rate.denominator}"}
    return put(cache, "video", [(name, data)], width=width, height=height, channels=channels, bit_depth=bit_depth,
               frames=frames, fps=float(rate), extra=extra)


def noise_frames(n: int, h: int, w: int, c: int = 3, dtype=np.uint8, hi: int = 256, seed: int = 0) -> list[np.ndarray]:
    rng = np.random.default_rng(seed)
    shape = (h, w, c) if c > 1 else (h, w)
    return [rng.integers(0, hi, shape, dtype=dtype) for _ in range(n)]


def level(i: int) -> int:
    """Grey level of frame i in the lossy videos: 6 apart, identifiable after compression."""
    return 24 + 6 * i


def grey_frames(n: int, h: int, w: int) -> list[np.ndarray]:
    ramp = np.linspace(-12, 12, w)[None, :, None]   # a little texture, mean 0
    return [np.clip(level(i) + ramp + np.zeros((h, w, 3)), 0, 255).astype(np.uint8) for i in range(n)]


def which(arr: np.ndarray, n: int, full: float) -> int:
    """The frame index whose grey level is nearest the mean of ``arr`` (scaled by ``full``)."""
    mean = float(arr.astype(np.float64).mean()) * 255.0 / full
    return int(np.argmin([abs(mean - level(i)) for i in range(n)]))


# ---------------------------------------------------------------------------- stills

def test_png_stills_8_and_16_bit_decode_bit_exact(cache):
    rng = np.random.default_rng(1)
    cases = [rng.integers(0, 256, (21, 34, 3), dtype=np.uint8),
             rng.integers(0, 65536, (21, 34), dtype=np.uint16),
             rng.integers(0, 65536, (21, 34, 3), dtype=np.uint16),
             rng.integers(0, 256, (21, 34, 4), dtype=np.uint8)]
    for img in cases:
        ch = 1 if img.ndim == 2 else img.shape[2]
        aid = put(cache, "still", [("a.png", encode_png(img, filter="adaptive"))], width=34, height=21, channels=ch,
                  bit_depth=8 * img.dtype.itemsize)
        with open_frames(cache, aid) as src:
            assert (src.kind, src.frames, src.shape, src.dtype) == ("still", 1, (21, 34, ch), img.dtype)
            got = src.frame(0)
            assert got.dtype == img.dtype and got.shape == (21, 34, ch) and got.flags.c_contiguous
            assert np.array_equal(got, img.reshape(21, 34, ch))
            assert not got.flags.writeable and src.frame(0) is got      # decoded once
            assert src.frame_bytes == got.nbytes
            with pytest.raises(ValueError, match="frames 0..0"):
                src.frame(1)


def test_grey_alpha_png_matches_a_four_channel_manifest(cache):
    """OpenCV (the coordinator's probe) reads grey+alpha as 4 channels: grey is replicated."""
    img = np.random.default_rng(2).integers(0, 256, (9, 11, 2), dtype=np.uint8)
    aid = put(cache, "still", [("ga.png", encode_png(img))], width=11, height=9, channels=4, bit_depth=8)
    with open_frames(cache, aid) as src:
        got = src.frame(0)
    assert np.array_equal(got[:, :, :3], np.repeat(img[:, :, :1], 3, axis=2))
    assert np.array_equal(got[:, :, 3], img[:, :, 1])


def test_npy_float32_still(cache, tmp_path):
    img = np.random.default_rng(3).random((13, 17, 3), dtype=np.float32)
    np.save(tmp_path / "f.npy", img)
    aid = put(cache, "still", [("f.npy", (tmp_path / "f.npy").read_bytes())], width=17, height=13, channels=3,
              bit_depth=32)
    with open_frames(cache, aid) as src:
        got = src.frame(0)
    assert got.dtype == np.float32 and np.array_equal(got, img)


def _image_file(path: Path, img: np.ndarray, codec: str, pix_fmt: str, fmt_in: str) -> bytes:
    with av.open(str(path), "w", format="image2") as c:
        s = c.add_stream(codec, rate=1)
        s.height, s.width = img.shape[:2]
        s.pix_fmt = pix_fmt
        for p in s.encode(av.VideoFrame.from_ndarray(img, format=fmt_in)):
            c.mux(p)
        for p in s.encode():
            c.mux(p)
    return path.read_bytes()


def test_tiff_and_jpeg_stills_decode_with_pyav(cache, tmp_path):
    rng = np.random.default_rng(4)
    img16 = rng.integers(0, 65536, (10, 14, 3), dtype=np.uint16)
    tif = _image_file(tmp_path / "a.tif", img16, "tiff", "rgb48le", "rgb48le")
    aid = put(cache, "still", [("a.tif", tif)], width=14, height=10, channels=3, bit_depth=16)
    with open_frames(cache, aid) as src:
        assert np.array_equal(src.frame(0), img16)
    y, x = np.mgrid[0:32, 0:48]
    smooth = np.dstack([x * 5, y * 7, np.full_like(x, 128)]).astype(np.uint8)
    jpg = _image_file(tmp_path / "a.jpg", smooth, "mjpeg", "yuvj444p", "rgb24")
    aid = put(cache, "still", [("a.jpg", jpg)], width=48, height=32, channels=3, bit_depth=8)
    with open_frames(cache, aid) as src:
        got = src.frame(0)
    assert got.dtype == np.uint8 and np.abs(got.astype(int) - smooth).mean() < 3


def test_png_that_node_png_refuses_falls_back_to_pyav(cache, tmp_path):
    """A 1-bit PNG decodes with FFmpeg's PNG decoder."""
    img = np.where(np.random.default_rng(5).random((8, 16)) < 0.5, 0, 255).astype(np.uint8)
    png = _image_file(tmp_path / "b.png", img, "png", "monob", "gray")
    assert png[24] == 1   # IHDR bit depth
    aid = put(cache, "still", [("b.png", png)], width=16, height=8, channels=1, bit_depth=8)
    with open_frames(cache, aid) as src:
        assert np.array_equal(src.frame(0)[:, :, 0], img)


def test_png_sequence_decodes_each_frame_from_its_blob(cache):
    frames = noise_frames(3, 19, 23) + noise_frames(1, 19, 23, c=1, dtype=np.uint16, hi=65536)
    rgb = frames[:3]
    aid = put(cache, "sequence", [(f"f{i}.png", encode_png(f, filter="paeth")) for i, f in enumerate(rgb)],
              width=23, height=19, channels=3, bit_depth=8, fps=24.0)
    with open_frames(cache, aid) as src:
        assert (src.kind, src.frames, src.fps) == ("sequence", 3, 24.0)
        for k in (0, 1, 2, 1, 0):
            assert np.array_equal(src.frame(k), rgb[k])
    grey16 = frames[3]
    aid = put(cache, "sequence", [("g.png", encode_png(grey16))], width=23, height=19, channels=1, bit_depth=16,
              fps=24.0)
    with open_frames(cache, aid) as src:
        assert np.array_equal(src.frame(0)[:, :, 0], grey16)


def test_open_frames_refuses_an_asset_not_fetched_yet(cache):
    m = Manifest(kind="still", name="x", blobs=(Blob(sha256_hex(b"x"), 1, "x.png"),), width=1, height=1,
                 channels=1, bit_depth=8, frames=1)
    cache.begin(m.canonical(), m.asset_id)
    with pytest.raises(FrameError, match="1 of its 1 blob"):
        open_frames(cache, m.asset_id)
    with pytest.raises(FrameError, match="not in the cache"):
        open_frames(cache, "0" * 64)


# ---------------------------------------------------------------------------- videos

def _check_every_access(src: FrameSource, expect, n: int, seed: int = 0) -> None:
    """Sequential, random jumps both ways, and wrap-around all give the right frame."""
    for k in range(n):
        expect(src.frame(k), k)
    rng = np.random.default_rng(seed)
    order = list(rng.integers(0, n, 25)) + [n - 1, 0, n - 1, 0, 1, 2, n // 2, n // 2 - 1, n // 2 + 3]
    for k in order:
        expect(src.frame(int(k)), int(k))


def test_lossless_h264_rgb_with_b_frames_every_frame_exact(cache, tmp_path):
    n = 30
    imgs = noise_frames(n, 24, 32, seed=6)
    data = encode_video(tmp_path / "v.mp4", imgs, codec="libx264rgb", pix_fmt="rgb24", fmt_in="rgb24",
                        options={"qp": "0", "preset": "veryfast",
                                 "x264-params": "keyint=8:min-keyint=8:bframes=2:scenecut=0"})
    aid = put_video(cache, data, "v.mp4", frames=n, width=32, height=24, channels=3, bit_depth=8, container="mov",
                    pix_fmt="rgb24")

    def expect(arr, k):
        assert arr.dtype == np.uint8 and arr.shape == (24, 32, 3) and not arr.flags.writeable
        assert np.array_equal(arr, imgs[k]), f"frame {k}"

    with open_frames(cache, aid) as src:
        for k in range(n):
            expect(src.frame(k), k)
        dec = src.decoder
        assert dec.seeks == 0 and dec.decoded == n            # sequential: straight on, no seek
        src.frame(n - 1)
        assert dec.seeks == 0                                   # the same frame again: no work
        src.frame(0)                                            # loop wrap: a seek back to the start
        assert dec.seeks == 1
        before = dec.decoded
        src.frame(2)                                            # same GOP, ahead: decoded forward
        assert dec.seeks == 1 and dec.decoded == before + 2
        src.frame(20)                                           # keyframes between: a seek
        assert dec.seeks == 2
        _check_every_access(src, expect, n)


def test_lossless_ffv1_mkv_rgb_and_grey_exact(cache, tmp_path):
    n = 12
    imgs = noise_frames(n, 16, 20, seed=7)
    data = encode_video(tmp_path / "v.mkv", imgs, codec="ffv1", pix_fmt="bgr0", fmt_in="rgb24")
    aid = put_video(cache, data, "v.mkv", frames=n, width=20, height=16, channels=3, bit_depth=8,
                    container="matroska", pix_fmt="bgr0")
    with open_frames(cache, aid) as src:
        _check_every_access(src, lambda a, k: np.testing.assert_array_equal(a, imgs[k], err_msg=f"frame {k}"), n)
    greys = noise_frames(n, 16, 20, c=1, seed=8)
    data = encode_video(tmp_path / "g.mkv", greys, codec="ffv1", pix_fmt="gray", fmt_in="gray")
    aid = put_video(cache, data, "g.mkv", frames=n, width=20, height=16, channels=1, bit_depth=8,
                    container="matroska", pix_fmt="gray")
    with open_frames(cache, aid) as src:
        _check_every_access(src, lambda a, k: np.testing.assert_array_equal(a[:, :, 0], greys[k]), n)
    g16 = noise_frames(n, 16, 20, c=1, dtype=np.uint16, hi=65536, seed=9)
    data = encode_video(tmp_path / "g16.mkv", g16, codec="ffv1", pix_fmt="gray16le", fmt_in="gray16le")
    aid = put_video(cache, data, "g16.mkv", frames=n, width=20, height=16, channels=1, bit_depth=16,
                    container="matroska", pix_fmt="gray16le")
    with open_frames(cache, aid) as src:
        _check_every_access(src, lambda a, k: np.testing.assert_array_equal(a[:, :, 0], g16[k]), n)


def test_a_video_decodes_straight_to_the_content_size_by_area_averaging(cache, tmp_path):
    """Asked for a 4x smaller size, the decoder's conversion averages each 4x4 block: checked
    against the block means (an independent reference), 8-bit and 16-bit."""
    n, h, w = 6, 48, 64
    yy, xx = np.mgrid[0:h, 0:w]
    imgs = [np.stack([(xx * 3 + k * 5) % 256, (yy * 4 + k) % 256, (xx + yy * 2) % 256], -1).astype(np.uint8)
            for k in range(n)]
    data = encode_video(tmp_path / "s.mkv", imgs, codec="ffv1", pix_fmt="bgr0", fmt_in="rgb24")
    aid = put_video(cache, data, "s.mkv", frames=n, width=w, height=h, channels=3, bit_depth=8,
                    container="matroska", pix_fmt="bgr0")
    blocks = lambda a: a.reshape(h // 4, 4, w // 4, 4, -1).astype(np.float64).mean(axis=(1, 3))  # noqa: E731
    with open_frames(cache, aid, size=(w // 4, h // 4)) as src:
        assert src.shape == (h // 4, w // 4, 3)
        for k in (0, 3, 5):
            got = src.frame(k)
            assert got.shape == (h // 4, w // 4, 3) and got.dtype == np.uint8
            assert np.abs(got - blocks(imgs[k])).max() <= 2.0, k
    g16 = [((xx * 700 + yy * 300 + k * 999) % 65536).astype(np.uint16) for k in range(n)]
    data = encode_video(tmp_path / "g16.mkv", g16, codec="ffv1", pix_fmt="gray16le", fmt_in="gray16le")
    aid = put_video(cache, data, "g16.mkv", frames=n, width=w, height=h, channels=1, bit_depth=16,
                    container="matroska", pix_fmt="gray16le")
    with open_frames(cache, aid, size=(w // 4, h // 4)) as src:
        got = src.frame(2)
        assert got.shape == (h // 4, w // 4, 1) and got.dtype == np.uint16
        assert np.abs(got[:, :, 0] - blocks(g16[2][:, :, None])[:, :, 0]).max() <= 2 * 257


def test_lossy_h264_yuv420p_every_index_decodes_to_its_frame(cache, tmp_path):
    n = 36
    data = encode_video(tmp_path / "v.mp4", grey_frames(n, 48, 64), codec="libx264", pix_fmt="yuv420p",
                        fmt_in="rgb24", options={"crf": "18", "preset": "veryfast",
                                                 "x264-params": "keyint=10:min-keyint=10:bframes=3:scenecut=0"})
    aid = put_video(cache, data, "v.mp4", frames=n, width=64, height=48, channels=3, bit_depth=8, container="mov",
                    pix_fmt="yuv420p")

    def expect(arr, k):
        assert arr.dtype == np.uint8 and arr.shape == (48, 64, 3)
        assert which(arr, n, 255) == k

    with open_frames(cache, aid) as src:
        _check_every_access(src, expect, n, seed=1)
        assert src.decoder.seeks > 0


def test_10_bit_planar_rgb_ffv1_scales_to_16_bits_exactly(cache, tmp_path):
    n = 8
    imgs = noise_frames(n, 12, 18, dtype=np.uint16, hi=1024, seed=10)
    data = encode_video(tmp_path / "v.mkv", imgs, codec="ffv1", pix_fmt="gbrp10le", fmt_in="gbrp10le")
    aid = put_video(cache, data, "v.mkv", frames=n, width=18, height=12, channels=3, bit_depth=10,
                    container="matroska", pix_fmt="gbrp10le")
    with open_frames(cache, aid) as src:
        assert src.dtype == np.uint16
        _check_every_access(src, lambda a, k: np.testing.assert_array_equal(a, imgs[k] << 6 | imgs[k] >> 4), n)
        assert src.frame(0).max() > 65000          # full 16-bit range


def _encoders_of(pix_fmt: str) -> list[str]:
    out = []
    for name in ("libx265", "libx264", "ffv1"):
        try:
            if pix_fmt in [f.name for f in (av.codec.Codec(name, "w").video_formats or [])]:
                out.append(name)
        except (av.FFmpegError, ValueError):
            pass
    return out


def test_10_bit_yuv420p10le_video_decodes_to_uint16(cache, tmp_path):
    encoders = _encoders_of("yuv420p10le")
    if not encoders:
        pytest.skip("this PyAV has no 10-bit (yuv420p10le) encoder")
    codec = encoders[0]
    n, h, w = 24, 64, 128     # libx265 corrupts the heap on frames smaller than one 64x64 CTU (48x32)
    grey16 = [(f.astype(np.uint16) * 257) for f in grey_frames(n, h, w)]
    opts = {"preset": "ultrafast", "x265-params": "log-level=error:keyint=8:min-keyint=8:bframes=2:scenecut=0"} \
        if codec == "libx265" else {}

    def expect(arr, k):
        assert arr.dtype == np.uint16 and arr.shape == (h, w, 3)
        assert which(arr, n, 65535) == k, f"frame {k}: {arr.mean() / 257:.1f}"

    # MKV (cues) and MP4 (x265's open GOPs: a seek may land after a leading frame, then backs off)
    for name, container in (("v.mkv", "matroska"), ("v.mp4", "mov")):
        data = encode_video(tmp_path / name, grey16, codec=codec, pix_fmt="yuv420p10le", fmt_in="rgb48le",
                            options=opts)
        aid = put_video(cache, data, name, frames=n, width=w, height=h, channels=3, bit_depth=10,
                        container=container, pix_fmt="yuv420p10le")
        with open_frames(cache, aid) as src:
            _check_every_access(src, expect, n, seed=2)
            assert src.frame(n - 1).max() > 40000    # scaled to 16 bits (level 174 of 255 at most here)


def test_truncated_and_unreadable_videos_fail_naming_asset_and_frame(cache, tmp_path):
    n = 40
    data = encode_video(tmp_path / "v.mkv", noise_frames(n, 16, 16, seed=11), codec="ffv1", pix_fmt="bgr0",
                        fmt_in="rgb24")
    cut = data[: len(data) // 2]
    aid = put_video(cache, cut, "v.mkv", frames=n, width=16, height=16, channels=3, bit_depth=8,
                    container="matroska", pix_fmt="bgr0")
    with open_frames(cache, aid) as src:
        assert src.frame(0).shape == (16, 16, 3)
        with pytest.raises(FrameError, match=rf"asset {aid[:12]} \('test', video\) frame {n - 1}: .*truncated"):
            src.frame(n - 1)
        assert src.frame(1).shape == (16, 16, 3)        # still usable before the cut
    mp4 = encode_video(tmp_path / "w.mp4", noise_frames(4, 16, 16), codec="libx264", pix_fmt="yuv420p", fmt_in="rgb24")
    aid = put_video(cache, mp4[:-2000], "w.mp4", frames=4, width=16, height=16, channels=3, bit_depth=8,
                    container="mov", pix_fmt="yuv420p")
    with open_frames(cache, aid) as src, pytest.raises(FrameError, match=rf"{aid[:12]}.* frame 2: cannot open"):
        src.frame(2)


# ---------------------------------------------------------------------------- decode-ahead

def _ffv1_asset(cache, tmp_path, n=20, seed=12):
    imgs = noise_frames(n, 16, 24, seed=seed)
    data = encode_video(tmp_path / "da.mkv", imgs, codec="ffv1", pix_fmt="bgr0", fmt_in="rgb24")
    return imgs, put_video(cache, data, "da.mkv", frames=n, width=24, height=16, channels=3, bit_depth=8,
                           container="matroska", pix_fmt="bgr0")


def test_decode_ahead_in_order_gets_are_hits_and_a_jump_is_one_miss(cache, tmp_path):
    imgs, aid = _ffv1_asset(cache, tmp_path, n=40)
    with DecodeAhead(open_frames(cache, aid), depth=6) as ahead:
        ahead.want(0)
        for k in range(30):
            assert ahead.wait_ahead(10)           # the frame period: time for the thread to keep ahead
            assert np.array_equal(ahead.get(k, timeout=1), imgs[k])
        assert ahead.wait_ahead(10)
        s = ahead.stats()
        assert (s.hits, s.misses, s.jumps, s.errors) == (30, 0, 0, 0)
        assert s.buffered == 6 and s.decoded == 35 and s.decode_ms_p50 > 0
        assert np.array_equal(ahead.get(5, timeout=10), imgs[5])      # a jump back: a miss
        for k in range(6, 12):
            assert ahead.wait_ahead(10)
            assert np.array_equal(ahead.get(k, timeout=1), imgs[k])
        s = ahead.stats()
        assert (s.hits, s.misses, s.jumps) == (36, 1, 1)
        ahead.wait_ahead(10)
        assert np.array_equal(ahead.get(14, timeout=1), imgs[14])     # skipping ahead within the window: a hit
        assert ahead.stats().hits == 37


def test_decode_ahead_wraps_for_loops_and_decodes_a_held_frame_once(cache, tmp_path):
    imgs, aid = _ffv1_asset(cache, tmp_path, n=10)
    with DecodeAhead(open_frames(cache, aid), depth=4, loop=True) as ahead:
        ahead.want(8)
        got = []
        for k in [8, 9, 0, 1, 2]:
            assert ahead.wait_ahead(10)
            got.append(ahead.get(k, timeout=1))
        assert all(np.array_equal(g, imgs[k]) for g, k in zip(got, [8, 9, 0, 1, 2], strict=True))
        assert ahead.stats().misses == 0
        assert ahead.wait_ahead(10)
        decoded = ahead.stats().decoded
        ahead.expect(iter([7] * 50))               # paused on frame 7
        assert ahead.wait_ahead(10)
        for _ in range(5):
            assert np.array_equal(ahead.get(7, timeout=1), imgs[7])
        assert ahead.stats().decoded == decoded + 1 and ahead.stats().buffered == 1
        ahead.want(8, loop=False)                  # no loop: the order ends with the asset
        assert ahead.wait_ahead(10) and ahead.stats().buffered == 2


def test_decode_ahead_error_surfaces_on_get_naming_asset_and_frame(cache):
    good = noise_frames(3, 8, 8, seed=13)
    blobs = [encode_png(f) for f in good]
    blobs[1] = blobs[1][: len(blobs[1]) // 2]       # a truncated PNG
    aid = put(cache, "sequence", [(f"f{i}.png", b) for i, b in enumerate(blobs)], width=8, height=8, channels=3,
              bit_depth=8, fps=24.0, name="broken")
    with DecodeAhead(open_frames(cache, aid), depth=3) as ahead:
        ahead.want(0)
        assert ahead.wait_ahead(10)
        assert np.array_equal(ahead.get(0, timeout=1), good[0])
        with pytest.raises(FrameError, match=rf"asset {aid[:12]} \('broken', sequence\) frame 1: ") as info:
            ahead.get(1, timeout=1)
        assert isinstance(info.value, NodeError)
        assert np.array_equal(ahead.get(2, timeout=1), good[2])
        assert ahead.stats().errors == 1
        with pytest.raises(ValueError):
            ahead.get(3, timeout=1)


class _GatedStill(FrameSource):
    """A frame source whose decodes wait until the test opens ``gate`` (open from the start when
    ``open_gate``); frame k is filled with k, and ``started`` lists the frames whose decode began."""

    def __init__(self, cache, open_gate=False):
        m = Manifest(kind="sequence", name="slow", blobs=tuple(Blob(sha256_hex(bytes([i])), 1, f"{i}.png")
                                                                 for i in range(5)),
                     width=4, height=2, channels=1, bit_depth=8, frames=5, fps=1.0)
        super().__init__(cache, m.asset_id, m)
        self.gate = threading.Event()
        if open_gate:
            self.gate.set()
        self.started: list[int] = []

    def _decode(self, k):
        self.started.append(k)
        self.gate.wait()
        return np.full((2, 4, 1), k, np.uint8)


def test_decode_ahead_never_blocks_past_the_timeout_and_close_joins(cache):
    src = _GatedStill(cache)
    ahead = DecodeAhead(src, depth=2)
    thread = ahead._thread
    assert thread.is_alive() and thread.name.startswith("decode-ahead-")
    try:
        # raised, not returned: no decode can finish while the gate is shut (no wall clock asserted)
        with pytest.raises(FrameNotReady, match="frame 3 was not decoded within 20 ms"):
            ahead.get(3, timeout=0.02)
        s = ahead.stats()
        assert (s.misses, s.jumps, s.hits) == (1, 1, 0)
        src.gate.set()
        assert ahead.get(3, timeout=60)[0, 0, 0] == 3
        # it stayed first in line: no other frame (but one already under way at the start) went before it
        assert [k for k in src.started if k != 0][:1] == [3], src.started
    finally:
        src.gate.set()
        ahead.close()
    assert not thread.is_alive()
    ahead.close()                                           # idempotent
    with pytest.raises(FrameError, match="closed"):
        ahead.get(0, timeout=0)


def test_decode_ahead_closed_without_waiting_lets_its_thread_close_the_source_then_calls_back(cache):
    src = _GatedStill(cache)
    closed_by: list[str] = []
    src.close = lambda: closed_by.append(threading.current_thread().name)
    ahead = DecodeAhead(src, depth=2)
    thread = ahead._thread
    try:
        ahead.want(0)
        wait_until(lambda: list(src.started), what="the thread's first decode under way")
        called: list[str] = []
        # the thread is inside a decode the gate holds: this call returns without waiting for it
        ahead.close(wait=False, then=lambda: called.append(threading.current_thread().name))
        assert thread.is_alive() and not ahead.closed() and called == []
        src.gate.set()
        wait_until(lambda: list(called), what="the callback after the source's close")
        assert closed_by == [thread.name] and called == [thread.name] and ahead.closed()
    finally:
        src.gate.set()
        ahead.close()                                       # idempotent: the source is closed once
    assert not thread.is_alive() and closed_by == [thread.name]
    with pytest.raises(FrameError, match="closed"):
        ahead.get(0, timeout=0)


def test_decode_ahead_closed_without_waiting_after_its_thread_ended_closes_the_source_at_once(cache):
    src = _GatedStill(cache, open_gate=True)
    ahead = DecodeAhead(src, depth=2)
    ahead.close()
    src2_closed: list[int] = []
    ahead.close(wait=False, then=lambda: src2_closed.append(1))   # already closed: nothing more happens
    assert ahead.closed() and src2_closed == []


class _StartTimes(_GatedStill):
    """Records the host's monotonic clock each time a frame's decode starts."""

    def __init__(self, cache):
        super().__init__(cache, open_gate=True)
        self.starts: list[int] = []

    def _decode(self, k):
        self.starts.append(time.monotonic_ns())
        return super()._decode(k)


def test_decode_ahead_starts_no_decode_while_a_swap_is_due(cache):
    """Inside a quiet window (a swap's instant, announced by the presenter) the thread starts no
    decode; it decodes the frames after the window."""
    src = _StartTimes(cache)
    with DecodeAhead(src, depth=5) as ahead:
        start = time.monotonic_ns()
        end = start + 200_000_000
        ahead.quiet(start, end)
        ahead.want(0)
        assert [int(ahead.get(k, timeout=30)[0, 0, 0]) for k in range(5)] == [0, 1, 2, 3, 4]
        assert len(src.starts) == 5 and min(src.starts) >= end
        ahead.quiet(0, 1)                               # a window long past holds nothing back
        before = len(src.starts)
        ahead.want(2)
        assert ahead.get(2, timeout=30)[0, 0, 0] == 2
        assert len(src.starts) > before


def test_decode_ahead_follows_a_quiet_window_moved_while_it_waits(cache):
    """The presenter keeps decodes back while it makes a frame and then cuts the window down to the
    swap's (node.timeline_player ``quiet_around(..., rendering=True)``, ``rendered``): the thread,
    waiting in a window, follows the one it finds when the window changes, a longer one as a
    shorter one, and does not sleep to the end of the window it saw first."""
    src = _StartTimes(cache)
    with DecodeAhead(src, depth=3) as ahead:
        now = time.monotonic_ns()
        ahead.quiet(now, now + 150_000_000)
        ahead.want(0)
        time.sleep(0.05)                                # (the thread takes the job and waits in the window)
        end = now + 600_000_000
        ahead.quiet(now, end)                           # made longer while the thread waits in it
        assert ahead.get(0, timeout=30)[0, 0, 0] == 0
        assert min(src.starts) >= end
        ahead.get(2, timeout=30)                        # frames 0-2 decoded; frame 3 is not
        ahead.quiet(time.monotonic_ns(), time.monotonic_ns() + 60_000_000_000)     # a minute ...
        ahead.want(3)
        time.sleep(0.05)
        ahead.quiet(0, 1)                               # ... cut short: the decode starts now, not in a minute
        assert ahead.get(3, timeout=30)[0, 0, 0] == 3
