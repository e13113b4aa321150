"""Fitting images to the content area: refused without a choice, stretch/contain/cover checked
against OpenCV resizes of the expected regions."""
from __future__ import annotations

import cv2
import numpy as np
import pytest

from coordinator.fit import fit_image


def _ramp(h: int, w: int, c: int = 3, dtype=np.uint8) -> np.ndarray:
    rng = np.random.default_rng(h * 1000 + w)
    hi = np.iinfo(dtype).max if dtype != np.float32 else 1.0
    return (rng.random((h, w, c)) * hi).astype(dtype)


def test_another_aspect_is_refused_naming_both_sizes_and_the_choices():
    with pytest.raises(ValueError) as err:
        fit_image(_ramp(100, 100), (160, 90))
    msg = str(err.value)
    assert "100x100" in msg and "160x90" in msg
    assert all(word in msg for word in ("contain", "cover", "stretch"))


def test_same_aspect_is_scaled_without_a_choice():
    img = _ramp(180, 320)
    out = fit_image(img, (160, 90))
    assert out.shape == (90, 160, 3) and out.dtype == np.uint8
    np.testing.assert_array_equal(out, cv2.resize(img, (160, 90), interpolation=cv2.INTER_AREA))


def test_unknown_fit_is_refused():
    with pytest.raises(ValueError, match="unknown fit 'zoom'"):
        fit_image(_ramp(10, 10), (16, 9), "zoom")


def test_stretch_is_a_plain_resize():
    img = _ramp(50, 50, 1, np.uint16)
    out = fit_image(img, (160, 90), "stretch")
    np.testing.assert_array_equal(out[:, :, 0], cv2.resize(img[:, :, 0], (160, 90), interpolation=cv2.INTER_LINEAR))


@pytest.mark.parametrize("shape,size", [((100, 100), (160, 90)), ((90, 300), (160, 90)), ((300, 90), (90, 160))])
def test_contain_pads_with_black_around_the_whole_image(shape, size):
    img = _ramp(*shape)
    out = fit_image(img, size, "contain")
    w, h = size
    assert out.shape == (h, w, 3)
    s = min(w / shape[1], h / shape[0])
    sw, sh = round(shape[1] * s), round(shape[0] * s)
    x0, y0 = (w - sw) // 2, (h - sh) // 2
    interp = cv2.INTER_AREA if shape[1] > sw else cv2.INTER_LINEAR
    np.testing.assert_array_equal(out[y0:y0 + sh, x0:x0 + sw], cv2.resize(img, (sw, sh), interpolation=interp))
    mask = np.ones((h, w), bool)
    mask[y0:y0 + sh, x0:x0 + sw] = False
    assert mask.any() and not out[mask].any(), "the bars are black"


@pytest.mark.parametrize("shape,size", [((100, 100), (160, 90)), ((90, 300), (160, 90))])
def test_cover_fills_the_area_and_crops_evenly(shape, size):
    img = _ramp(*shape, dtype=np.float32)
    out = fit_image(img, size, "cover")
    w, h = size
    assert out.shape == (h, w, 3) and out.dtype == np.float32
    # reference: crop the source to the area's aspect around its centre, then resize
    s = max(w / shape[1], h / shape[0])
    cw, ch = w / s, h / s
    x0, y0 = (shape[1] - cw) / 2, (shape[0] - ch) / 2
    crop = img[int(round(y0)):int(round(y0 + ch)), int(round(x0)):int(round(x0 + cw))]
    ref = cv2.resize(crop, (w, h), interpolation=cv2.INTER_LINEAR)
    # interpolation at the crop's edges differs by at most a source pixel's worth
    assert np.mean(np.abs(out - ref)) < 0.08
    assert np.abs(out.mean() - img.mean()) < 0.05
