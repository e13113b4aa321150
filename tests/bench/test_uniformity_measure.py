"""The figures of `bench uniformity` (bench/uniformity_measure.py) against images whose answer is known in
closed form: a flat field, a known bump, a known step across a seam, a known tint per channel."""
from __future__ import annotations

import numpy as np
import pytest

from bench.uniformity_measure import (block_means, channel_deviation, luminance, nonuniformity, nonuniformity_map,
                                      resize_to, scale_of, seam_steps)


def test_block_means_match_a_loop_and_drop_partial_tiles():
    rng = np.random.default_rng(0)
    img = rng.random((21, 34, 3))
    mask = np.ones((21, 34), bool)
    mask[3, 5] = False
    means, whole = block_means(img, mask, 4)
    assert means.shape == (5, 8, 3) and whole.shape == (5, 8)
    for i in range(5):
        for j in range(8):
            assert np.allclose(means[i, j], img[4 * i:4 * i + 4, 4 * j:4 * j + 4].reshape(-1, 3).mean(0))
            assert whole[i, j] == (not (i == 0 and j == 1))
    with pytest.raises(ValueError, match="differ in size"):
        block_means(img, mask[:-1], 4)


def test_flat_and_scaled_images_are_even():
    img = np.full((64, 96, 3), 0.37)
    mask = np.ones((64, 96), bool)
    assert nonuniformity(img, None, mask) == pytest.approx(0.0, abs=1e-12)
    # the scale of the light does not count, the target's shape does
    target = np.linspace(0.5, 1.0, 96)[None, :, None] * np.ones((64, 1, 3))
    assert nonuniformity(img * target * 3.0, target, mask) == pytest.approx(0.0, abs=1e-12)
    assert nonuniformity(img, target, mask) > 0.3


def test_a_known_bump_gives_its_height():
    """A plateau 10 % above the rest on more than 1 % of the blocks: the p99 is exactly 0.10 (k is the median,
    the plateau is a minority); on fewer blocks than 1 % the p99 interpolates below it."""
    img = np.ones((80, 80))
    img[:16, :16] = 1.10          # 4 of 100 blocks
    mask = np.ones((80, 80), bool)
    assert nonuniformity(img, None, mask) == pytest.approx(0.10, abs=1e-9)
    m = nonuniformity_map(img, None, mask)
    assert m.shape == (10, 10) and np.isclose(m[0, 0], 0.10) and np.isclose(m[5, 5], 0.0)
    # outside the mask nothing counts; a block only partly inside does not count either
    mask2 = mask.copy()
    mask2[:20, :20] = False
    assert nonuniformity(img, None, mask2) == pytest.approx(0.0, abs=1e-12)


def test_within_scores_a_region_against_the_scale_of_the_whole():
    img = np.ones((80, 80))
    img[:40, :40] = 0.96          # a footprint that went 4 % darker as a whole
    mask = np.ones((80, 80), bool)
    fp = np.zeros((80, 80), bool)
    fp[:40, :40] = True
    assert nonuniformity(img, None, mask, within=fp) == pytest.approx(0.04, abs=1e-9)
    assert nonuniformity(img, None, fp) == pytest.approx(0.0, abs=1e-12)     # alone it is even


def test_a_given_scale_counts_light_lost_everywhere():
    target = np.linspace(0.5, 1.0, 80)[None, :] * np.ones((80, 1))
    mask = np.ones((80, 80), bool)
    before = 2.0 * target
    k = scale_of(before, target, mask)
    assert k == pytest.approx(2.0)
    after = before * (8 / 9)                  # one projector of nine gone, everywhere at once
    assert nonuniformity(after, target, mask) == pytest.approx(0.0, abs=1e-12)
    assert nonuniformity(after, target, mask, scale=k) == pytest.approx(1 / 9)


def test_luminance_weights():
    assert luminance(np.ones((2, 2, 3))) == pytest.approx(np.ones((2, 2)))
    assert luminance(np.array([[[1.0, 0, 0]]]))[0, 0] == pytest.approx(0.2126)


def test_channel_deviation_separates_unevenness_from_white_point():
    mask = np.ones((64, 64), bool)
    img = np.ones((64, 64, 3)) * np.array([0.9, 1.0, 1.1])       # a tint everywhere: even per channel
    d = channel_deviation(img, None, mask)
    assert d["max"] == pytest.approx(0.0, abs=1e-12)
    assert d["white_point_spread"] == pytest.approx(0.1, abs=1e-9)
    img[:, 48:, 2] *= 1.05              # blue 5 % higher on a quarter: its own k stays with the rest
    d = channel_deviation(img, None, mask)
    assert d["per_channel"][0] == pytest.approx(0.0, abs=1e-12) and d["per_channel"][1] == pytest.approx(0.0, abs=1e-12)
    assert d["per_channel"][2] == pytest.approx(0.05, abs=1e-9)


def _wall(step: float):
    """Three footprints in a row, overlaps of 20 columns lit by two: (image, count)."""
    H, W = 60, 300
    count = np.zeros((H, W), np.int32)
    for x0 in (10, 100, 190):
        count[5:55, x0:x0 + 110] += 1
    img = np.where(count > 0, 1.0, 0.0)
    img = np.where(count == 2, 1.0 + step, img)
    return np.repeat(img[:, :, None], 3, axis=2), count


def test_seam_steps_find_every_seam_and_its_step():
    img, count = _wall(1.0)                   # the overlaps twice as bright: step |2 - 1| / 1.5
    seams = seam_steps(img, count)
    xs = [s for s in seams if s["axis"] == "x"]
    assert len(xs) == 4 and all(s["counts"] == [1, 2] for s in xs)
    assert all(s["step"] == pytest.approx(2 / 3) for s in xs)
    flat, count = _wall(0.0)
    assert max(s["step"] for s in seam_steps(flat, count)) == pytest.approx(0.0, abs=1e-12)
    small, count = _wall(0.01)
    assert seam_steps(small, count)[0]["step"] == pytest.approx(0.01 / 1.005, rel=1e-6)


def test_resize_to_takes_the_cell_that_holds_each_pixel():
    grid = np.arange(6).reshape(2, 3)
    big = resize_to(grid, (6, 4))
    assert big.shape == (4, 6)
    assert big[0].tolist() == [0, 0, 1, 1, 2, 2] and big[3].tolist() == [3, 3, 4, 4, 5, 5]
