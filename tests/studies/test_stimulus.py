"""A trial's content: the picture fitted into each half (against OpenCV's resize placed by hand),
the surround, the far-side mirror, and which halves each slot lights."""
from __future__ import annotations

import cv2
import numpy as np
import pytest

from studies.stimulus import compose, halves, slot_regions


def test_each_half_holds_the_picture_fitted_whole_and_centred():
    rng = np.random.default_rng(0)
    pic = rng.integers(0, 256, (30, 40, 3), dtype=np.uint8)          # 4:3
    size = (200, 80)                                                    # halves of 100x80
    got = compose(pic, size, margin=0.1, surround=0.25).astype(np.float64) / 65535
    # by hand: a margin of 0.1 * 80 = 8 px leaves an 84x64 box; scale min(84/40, 64/30) = 2.1 (the width
    # binds), so 84x63, centred: offsets (100 - 84) // 2 = 8 and (80 - 63) // 2 = 8 in each half
    want_pic = cv2.resize(pic.astype(np.float32) / 255, (84, 63), interpolation=cv2.INTER_LINEAR)
    for x0 in (0, 100):
        np.testing.assert_allclose(got[8:71, x0 + 8:x0 + 92], want_pic, atol=1 / 65535)
        assert np.all(got[:8, x0:x0 + 100] == pytest.approx(0.25, abs=1e-5))
        assert np.all(got[71:, x0:x0 + 100] == pytest.approx(0.25, abs=1e-5))
    assert compose(pic, size).dtype == np.uint16


def test_grey_and_16_bit_pictures_and_the_mirror():
    grey = np.full((10, 10), 40000, np.uint16)
    plain = compose(grey, (64, 32), margin=0.0)
    assert plain.shape == (32, 64, 3) and plain[16, 16, 0] == plain[16, 16, 2] == 40000
    rng = np.random.default_rng(1)
    pic = rng.random((9, 13, 3)).astype(np.float32)
    np.testing.assert_array_equal(compose(pic, (90, 40), mirror=True), compose(pic, (90, 40))[::-1, ::-1])
    with pytest.raises(ValueError, match="margin"):
        compose(pic, (90, 40), margin=0.5)


def test_halves_and_which_slot_lights_which():
    assert halves((121, 60)) == ((0, 0, 60, 60), (60, 0, 61, 60))
    # turned 180 degrees: the near-side left half (columns 0..59) lands on columns 61..120
    assert halves((121, 60), mirror=True) == ((61, 0, 60, 60), (0, 0, 61, 60))
    left, right = halves((120, 60))
    regions = slot_regions(["a", "b", "c", "d"], left=["a", "b"], right=["b", "c"], size=(120, 60))
    assert regions == {"a": [left], "b": [left, right], "c": [right], "d": []}
