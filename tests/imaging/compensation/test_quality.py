"""PSNR/SSIM against closed forms and scikit-image, and the side-by-side picture."""
from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
from skimage.metrics import structural_similarity

from imaging.compensation.quality import linear_to_srgb, quality, side_by_side, srgb_to_linear


def test_psnr_matches_closed_form_and_ssim_matches_skimage():
    rng = np.random.default_rng(0)
    target = rng.random((40, 50)).astype(np.float32) * 0.8 + 0.1
    noisy = target + 0.01 * rng.standard_normal(target.shape).astype(np.float32)
    q = quality(target, noisy)
    mse = np.mean((np.clip(noisy, 0, 1).astype(np.float64) - target) ** 2)
    assert q.psnr == pytest.approx(10 * math.log10(1 / mse), rel=1e-9)
    assert q.ssim == pytest.approx(structural_similarity(target.astype(np.float64), np.clip(noisy, 0, 1).astype(np.float64),
                                                         data_range=1.0))
    assert quality(target, target).ssim == pytest.approx(1.0)
    colour = quality(np.stack([target] * 3, -1), np.stack([noisy] * 3, -1))
    assert colour.psnr == pytest.approx(q.psnr, rel=1e-6)
    assert colour.as_dict().keys() == {"psnr", "ssim"}


def test_quality_clips_captures_and_checks_shapes():
    t = np.full((10, 10), 1.0)
    assert quality(t, np.full((10, 10), 1.5)).psnr == math.inf
    with pytest.raises(ValueError):
        quality(t, np.zeros((10, 11)))
    with pytest.raises(ValueError):
        quality(np.zeros((3, 3)), np.zeros((3, 3)))


def test_srgb_round_trip():
    v = np.linspace(0, 1, 101, dtype=np.float32)
    assert np.allclose(linear_to_srgb(srgb_to_linear(v)), v, atol=1e-5)
    assert srgb_to_linear(np.array([0, 255], dtype=np.uint8)).tolist() == [0.0, 1.0]
    assert srgb_to_linear(np.array([0.5]))[0] == pytest.approx(0.21404, abs=1e-4)


def test_side_by_side_layout():
    a = np.zeros((60, 80), dtype=np.float32)
    b = np.ones((60, 40, 3), dtype=np.float32)
    c = np.full((30, 20), 128, dtype=np.uint8)
    pic = side_by_side([a, b, c], ["target", "none", "ours"], gap=4, label_height=20)
    assert pic.dtype == np.uint8 and pic.ndim == 3 and pic.shape[2] == 3
    # 60 px high is small: every image is enlarged 4x (nearest neighbour), c first scaled to 60 high
    assert pic.shape[0] == 240 + 20 + 8
    assert pic.shape[1] == 320 + 160 + 160 + 4 * 4
    assert np.all(pic[24:264, 4:324] == 0) and np.all(pic[24:264, 328:488] == 255)
    assert np.all(pic[24:264, 492:652] == 128)
    assert pic[:20].max() > 200  # captions are drawn
    # a caption wider than its image widens the column instead of running into the next one
    narrow = [np.zeros((300, 50), np.float32)] * 2
    pic = side_by_side(narrow, ["baseline 31.43 dB / 0.957", "ours 31.40 dB / 0.957"], gap=4, label_height=20)
    ink = pic[:20].max(axis=(0, 2)) > 100
    first = side_by_side(narrow[:1], ["baseline 31.43 dB / 0.957"], gap=4, label_height=20).shape[1] - 4
    assert first > 4 + 50 + 4 and not ink[first - 1: first + 2].any()      # a gap between the two captions
    assert np.all(pic[24:324, (first - 4 - 50) // 2 + 4: (first - 4 - 50) // 2 + 54] == 0)  # the image, centred
    with pytest.raises(ValueError):
        side_by_side([a], ["x", "y"])
    with pytest.raises(ValueError):
        side_by_side([])


def test_psnr_is_scikit_images_to_the_last_bit():
    from skimage.metrics import peak_signal_noise_ratio
    rng = np.random.default_rng(0)
    for shape in [(40, 30), (48, 64, 3), (7, 7)]:
        for dt in (np.float32, np.float64):
            t = rng.random(shape).astype(dt)
            c = (t + rng.normal(0, 0.05, shape)).astype(dt)
            want = peak_signal_noise_ratio(t.astype(np.float64), np.clip(c.astype(np.float64), 0, 1), data_range=1.0)
            assert quality(t, c).psnr == float(want), (shape, dt)
    assert quality(t, t).psnr == float("inf")


def test_quality_imports_no_metric_that_loads_scipy_stats():
    # skimage.metrics.simple_metrics (PSNR's module) imports scipy.stats, 0.6 CPU-s in every process
    import ast

    import imaging.compensation.quality as q
    names = {a.name for n in ast.walk(ast.parse(Path(q.__file__).read_text()))
             if isinstance(n, ast.ImportFrom) and n.module == "skimage.metrics" for a in n.names}
    assert names == {"structural_similarity"}, names
