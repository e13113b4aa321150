"""The channel mean that captures and video frames are reduced by, against NumPy's mean."""
from __future__ import annotations

import numpy as np
import pytest

from imaging.calibration.graycode import luminance
from imaging.channel_mean import channel_mean
from imaging.compensation.motion import MotionWarp


@pytest.mark.parametrize("channels", [1, 2, 3, 4, 6])
def test_equals_numpys_mean_over_the_channels(channels):
    img = np.random.default_rng(channels).random((37, 53, channels), dtype=np.float32)
    out = channel_mean(img)
    assert out.shape == (37, 53) and out.dtype == np.float32
    np.testing.assert_allclose(out, img.astype(np.float64).mean(axis=2), rtol=0, atol=3e-7)


def test_integer_strided_and_grey_pictures():
    rng = np.random.default_rng(7)
    u16 = rng.integers(0, 65536, (20, 30, 3), dtype=np.uint16)
    np.testing.assert_allclose(channel_mean(u16), u16.mean(axis=2), rtol=1e-6)
    strided = rng.random((20, 60, 3), dtype=np.float32)[:, ::2]          # not contiguous
    np.testing.assert_allclose(channel_mean(strided), strided.mean(axis=2), rtol=0, atol=3e-7)
    grey = rng.random((5, 7)).astype(np.float64)
    out = channel_mean(grey)
    assert out.dtype == np.float32 and np.array_equal(out, grey.astype(np.float32))
    for bad in (np.zeros(5), np.zeros((2, 3, 4, 5)), np.zeros((2, 3, 0))):
        with pytest.raises(ValueError, match="picture"):
            channel_mean(bad)


def test_captures_and_motion_use_it():
    """A capture's luminance and a colour frame's motion are those of the channel mean."""
    rng = np.random.default_rng(3)
    rgb = rng.random((40, 64, 3), dtype=np.float32)
    assert np.array_equal(luminance(rgb), channel_mean(rgb))
    moved = np.roll(rgb, 2, axis=1)
    warp = MotionWarp(scale=1)
    grey = [channel_mean(p) for p in (rgb, moved)]
    assert np.array_equal(warp.flow(rgb, moved), warp.flow(*grey))
