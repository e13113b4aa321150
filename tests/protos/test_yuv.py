"""protos/yuv.py's reference conversion against FFmpeg's swscale, on colour bars and ramps.

The frames are made by swscale from an RGB picture (bars over ramps) in every layout, matrix and
range the node's shader covers, tagged as a decoder tags them; node/yuv.py copies their planes.

Tolerances, and why: with no chroma subsampling (4:4:4) only the matrix and the range are at play,
and the reference lands within 1 code of swscale's rgb24 everywhere (8-bit rounding). With 4:2:0
and 4:2:2, the two upsample chroma differently (the reference bilinear at left-sited positions,
swscale's unscaled fast path with its own filter and fixed-point tables), which differs by tens of
codes at the bars' sharp colour edges (a chroma sample straddles two bars) and by at most 5 codes
elsewhere; there the reference is compared away from colour edges. (Against the RGB the frames
were made from, the reference measured within 2 codes and swscale within 5; that also depends on
the RGB-to-YUV conversion that made the frames, which is not under test, and once, with other
modules loaded first, made a frame both conversions read 25-26 codes from its source: not asserted.)
"""
from __future__ import annotations

import av
import numpy as np
import pytest

from node.yuv import FORMATS, why_not, yuv_planes
from protos.yuv import YuvFrame, guess_matrix, to_rgb, yuv_affine

W, H = 194, 110     # even and odd chroma sizes are both met (110 / 2 = 55 rows)
TAGS = {"bt709": "ITU709", "bt601": "ITU601", "bt2020": "BT2020"}


def bars_and_ramps(w: int = W, h: int = H) -> np.ndarray:
    img = np.zeros((h, w, 3), np.uint8)
    colours = [(191, 191, 191), (191, 191, 0), (0, 191, 191), (0, 191, 0), (191, 0, 191), (191, 0, 0),
               (0, 0, 191), (255, 255, 255)]
    for i, c in enumerate(colours):
        img[: h // 2, i * w // 8:(i + 1) * w // 8] = c
    x = np.linspace(0, 255, w)
    img[h // 2:, :, 0] = x
    img[h // 2:, :, 1] = x[::-1]
    img[h // 2:, :, 2] = np.linspace(16, 235, h - h // 2)[:, None]
    return img


def away_from_edges(img: np.ndarray, r: int = 3) -> np.ndarray:
    """(h, w) bool: pixels whose (2r+1)^2 neighbourhood changes by at most 6 codes (no colour edge)."""
    a = img.astype(np.int32)
    keep = np.ones(img.shape[:2], bool)
    for dy in range(-r, r + 1):
        for dx in range(-r, r + 1):
            keep &= np.abs(np.roll(a, (dy, dx), (0, 1)) - a).max(axis=2) <= 6
    keep[:r] = keep[-r:] = False
    keep[:, :r] = keep[:, -r:] = False
    return keep


def frame(fmt: str, matrix: str, full: bool, img: np.ndarray | None = None) -> av.VideoFrame:
    src = av.VideoFrame.from_ndarray(bars_and_ramps() if img is None else img, format="rgb24")
    return src.reformat(format=fmt, dst_colorspace=TAGS[matrix], dst_color_range="JPEG" if full else "MPEG")


def as_codes(rgb: np.ndarray) -> np.ndarray:
    return np.floor(np.clip(rgb, 0.0, 1.0) * 255.0 + 0.5)


@pytest.mark.parametrize("fmt", sorted(FORMATS))
def test_the_reference_matches_swscale_on_bars_and_ramps(fmt):
    img = bars_and_ramps()
    keep = away_from_edges(img)
    for matrix in ("bt601", "bt709", "bt2020"):
        for full in (False, True):
            f = frame(fmt, matrix, full)
            y = yuv_planes(f)
            assert y is not None, why_not(f)
            assert y.matrix == matrix and y.full_range == (full or fmt.startswith("yuvj"))
            ref = as_codes(to_rgb(y))
            sw = f.to_ndarray(format="rgb24").astype(np.float64)
            what = f"{fmt} {matrix} {'full' if full else 'limited'}"
            if y.sub == (1, 1):
                assert np.abs(ref - sw).max() <= 1, what
            else:
                assert np.abs(ref - sw)[keep].max() <= 5, what


def test_the_matrix_and_range_put_black_and_white_where_the_standards_do():
    for matrix in ("bt601", "bt709", "bt2020"):
        m, o = yuv_affine(matrix, False, 8, 1.0)
        assert np.allclose(m @ [16, 128, 128] + o, 0) and np.allclose(m @ [235, 128, 128] + o, 1)
        m, o = yuv_affine(matrix, False, 10, 1.0)
        assert np.allclose(m @ [64, 512, 512] + o, 0) and np.allclose(m @ [940, 512, 512] + o, 1)
        m, o = yuv_affine(matrix, True, 8, 1.0)
        assert np.allclose(m @ [0, 128, 128] + o, 0) and np.allclose(m @ [255, 128, 128] + o, 1)
    # BT.709's red: Cr at its top (240) with Y 63 gives R near 1, G and B near 0
    m, o = yuv_affine("bt709", False, 8, 1.0)
    r, g, b = m @ [63, 102, 240] + o
    assert r > 0.99 and g < 0.02 and b < 0.02


def test_untagged_streams_and_formats_the_shader_does_not_cover():
    assert guess_matrix(576) == "bt601" and guess_matrix(720) == "bt709" and guess_matrix(1080) == "bt709"
    f = av.VideoFrame.from_ndarray(bars_and_ramps(), format="rgb24").reformat(format="yuv420p")
    assert int(f.colorspace) == 2 and yuv_planes(f).matrix == "bt601"          # 110 rows: SD
    grey = av.VideoFrame.from_ndarray(bars_and_ramps(), format="rgb24").reformat(format="gray")
    assert yuv_planes(grey) is None and "gray" in why_not(grey)
    with pytest.raises(ValueError, match="chroma plane"):
        YuvFrame(planes=(np.zeros((4, 4), np.uint8), np.zeros((4, 4), np.uint8), np.zeros((2, 2), np.uint8)))
