"""Gray codes: OpenCV's patterns, the vectorised decoder against a closed form and against
OpenCV's own per-pixel decoder on captures from the virtual room."""
from __future__ import annotations

import cv2
import numpy as np
import pytest

from imaging.calibration.graycode import decode_gray, gray_layout, gray_patterns, luminance
from sim.room import Room
from sim.scene import reference_scene


def ideal_captures(layout, projector_xy):
    """What an ideal camera records at sub-pixel projector coordinates (NaN: unlit): the pattern value of
    the projector pixel containing the point (pixel k spans [k - 0.5, k + 0.5))."""
    pats = gray_patterns(layout.size)
    ok = np.all(np.isfinite(projector_xy), axis=-1)
    ix = np.floor(np.where(ok, projector_xy[..., 0], 0) + 0.5).astype(int).clip(0, layout.size[0] - 1)
    iy = np.floor(np.where(ok, projector_xy[..., 1], 0) + 0.5).astype(int).clip(0, layout.size[1] - 1)
    return [np.where(ok, p[iy, ix] / 255.0, 0.0).astype(np.float32) for p in pats], ok


def test_patterns_are_opencvs_and_every_pixel_has_a_unique_code():
    for size in [(320, 200), (97, 61), (1280, 800)]:
        pats = gray_patterns(size)
        ok, ref = cv2.structured_light.GrayCodePattern.create(*size).generate()
        assert len(pats) == len(ref) == gray_layout(size).count
        for a, b in zip(pats, ref):
            np.testing.assert_array_equal(a, b)
        lay = gray_layout(size)
        assert sorted(lay.column_lut[lay.column_lut >= 0]) == list(range(size[0]))
        assert sorted(lay.row_lut[lay.row_lut >= 0]) == list(range(size[1]))
    with pytest.raises(ValueError):
        gray_patterns((1, 10))


def test_adjacent_columns_differ_in_exactly_one_bit():
    lay = gray_layout((320, 200))
    inv = np.empty(320, np.int64)
    inv[lay.column_lut[lay.column_lut >= 0]] = np.flatnonzero(lay.column_lut >= 0)
    flips = [bin(int(a) ^ int(b)).count("1") for a, b in zip(inv[:-1], inv[1:])]
    assert set(flips) == {1}


def test_decoder_recovers_projector_pixels_exactly_from_ideal_captures():
    size = (200, 120)
    lay = gray_layout(size)
    # a camera looking at the projector image through a homography, part of it unlit
    H = np.array([[0.7, 0.05, 12.0], [-0.03, 0.68, 8.0], [1e-4, -2e-4, 1.0]])
    ys, xs = np.mgrid[0:150, 0:180]
    cam = np.stack([xs, ys], -1).astype(np.float64).reshape(-1, 2)
    q = np.column_stack([cam, np.ones(len(cam))]) @ H.T
    proj = (q[:, :2] / q[:, 2:]).reshape(150, 180, 2)
    proj[(proj[..., 0] < -0.5) | (proj[..., 0] >= size[0] - 0.5) | (proj[..., 1] < -0.5) | (proj[..., 1] >= size[1] - 0.5)] = np.nan
    proj[:, :20] = np.nan   # a shadow
    caps, lit = ideal_captures(lay, proj)
    white = lit.astype(np.float32)
    black = np.zeros_like(white)
    dec = decode_gray(caps, white=white, black=black, layout=lay)
    np.testing.assert_array_equal(dec.valid, lit)
    expect = np.floor(proj[lit] + 0.5).astype(np.int32)
    np.testing.assert_array_equal(dec.projector[lit], expect)
    assert np.all(dec.projector[~lit] == -1)
    cam_pts, proj_pts = dec.correspondences()
    assert len(cam_pts) == lit.sum() and np.all(np.abs(proj_pts - proj[lit][:, :]) <= 0.5 + 1e-9)


def test_decoder_agrees_with_opencvs_decoder_on_room_captures():
    room = Room(reference_scene(projector_scale=0.1, camera_scale=0.12))
    slot = "r1c2"
    room.set_active([slot])
    size = room.projector_size(slot)
    lay = gray_layout(size)

    def shot(img):
        room.set_frame(slot, np.repeat(img[:, :, None], 3, axis=2))
        return room.capture()

    white = shot(np.full((size[1], size[0]), 255, np.uint8))
    black = shot(np.zeros((size[1], size[0]), np.uint8))
    caps = [shot(p) for p in gray_patterns(size)]
    dec = decode_gray(caps, white=white, black=black, layout=lay, min_contrast=0.004)
    truth = room.truth.projector_coordinates(slot)
    v = dec.valid
    assert v.sum() > 3000
    err = dec.projector[v] - truth[v]
    assert np.all(np.abs(err) <= 1.0) and np.abs(err.mean(axis=0)).max() < 0.02   # zero-mean quantisation
    # OpenCV's own decoder, pixel by pixel, on 8-bit versions of the same captures
    to8 = lambda im: np.clip(np.rint(luminance(im) * 255 / luminance(white).max()), 0, 255).astype(np.uint8)  # noqa: E731
    g = cv2.structured_light.GrayCodePattern.create(*size)
    g.setWhiteThreshold(1)
    imgs8 = [to8(c) for c in caps]
    ys, xs = np.nonzero(v)
    pick = np.random.default_rng(0).choice(len(ys), 300, replace=False)
    agree = 0
    for k in pick:
        err_flag, xy = g.getProjPixel(imgs8, int(xs[k]), int(ys[k]))
        if not err_flag:
            agree += int(tuple(xy) == tuple(dec.projector[ys[k], xs[k]]))
    assert agree >= 0.97 * len(pick)      # any others sit on stripe edges where 8-bit rounding ties


def test_masks_and_shape_errors():
    lay = gray_layout((16, 8))
    n = lay.count
    caps = [np.zeros((4, 4), np.float32)] * n
    dec = decode_gray(caps, white=np.full((4, 4), 0.003, np.float32), black=np.zeros((4, 4), np.float32), layout=lay)
    assert dec.count == 0 and not dec.lit.any()
    with pytest.raises(ValueError, match=f"expected {n} captures"):
        decode_gray(caps[:-1], white=caps[0], black=caps[0], layout=lay)
    with pytest.raises(ValueError, match="differ in shape"):
        decode_gray(caps, white=np.zeros((4, 5), np.float32), black=caps[0], layout=lay)
    # a stricter per-bit mask drops pixels whose pattern and inverse are too close
    caps2 = [np.full((4, 4), 0.5 + (0.01 if k % 2 == 0 else -0.01), np.float32) for k in range(n)]
    white, black = np.ones((4, 4), np.float32), np.zeros((4, 4), np.float32)
    assert decode_gray(caps2, white=white, black=black, layout=lay, min_bit_contrast=0.05).count == 0
