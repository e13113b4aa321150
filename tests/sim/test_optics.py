"""Optics: response curves, kernels, light conservation, irradiance, sensor noise."""
from __future__ import annotations

import math

import cv2
import numpy as np
import pytest
from scipy import ndimage

from sim.geometry import Pinhole, intrinsics, look_at, pixel_footprint_area
from sim.optics import (
    REFERENCE_DISTANCE_MM,
    Response,
    Sensor,
    apply_response,
    blend_levels,
    defocus_sigma,
    field_coordinates,
    field_padding,
    gaussian_kernel,
    irradiance_factor,
    light_field,
    random_response,
    remap_fractions,
    sample_weights_1d,
)


def test_response_curve_and_its_inverse():
    r = Response([2.1, 2.2, 2.3], [0.004, 0.005, 0.006])
    v = np.linspace(0, 1, 11)[:, None] * np.ones(3)
    lum = r.luminance(v)
    np.testing.assert_allclose(lum[0], r.black)
    np.testing.assert_allclose(lum[-1], 1.0)
    np.testing.assert_allclose(lum[5], r.black + (1 - r.black) * 0.5 ** r.gamma)
    np.testing.assert_allclose(r.inverse(lum), v, atol=1e-12)
    frame = np.arange(256, dtype=np.uint8).reshape(16, 16, 1).repeat(3, axis=2)
    np.testing.assert_allclose(apply_response(frame, r), r.luminance(frame / 255.0), rtol=1e-6)


def test_units_vary_within_the_documented_ranges():
    rng = np.random.default_rng(3)
    units = [random_response(rng) for _ in range(200)]
    gammas = np.array([u.gamma.mean() for u in units])
    blacks = np.array([u.black.mean() for u in units])
    assert gammas.min() >= 2.2 * 0.9 * 0.98 and gammas.max() <= 2.2 * 1.1 * 1.02
    assert gammas.max() - gammas.min() > 0.3  # they do vary
    assert blacks.min() >= 0.002 * 0.9 and blacks.max() <= 0.01 * 1.1


def test_gaussian_kernel_is_normalised_and_matches_scipy():
    for sigma in (0.3, 1.0, 2.7):
        k = gaussian_kernel(sigma)
        assert k.sum() == pytest.approx(1.0)
        impulse = np.zeros(len(k) + 20)
        impulse[len(impulse) // 2] = 1.0
        ref = ndimage.gaussian_filter1d(impulse, sigma, truncate=math.ceil(3.5 * sigma) / sigma, mode="constant")
        mid = len(impulse) // 2
        r = len(k) // 2
        np.testing.assert_allclose(ref[mid - r : mid + r + 1], k, atol=1e-12)


def test_level_blend_has_the_wanted_variance():
    levels = (0.0, 0.5, 1.0, 2.0)
    sigma = np.array([0.0, 0.1, 0.5, 0.8, 1.7, 2.0])
    lo, alpha = blend_levels(sigma, levels)
    lv = np.asarray(levels)
    var = (1 - alpha) * lv[lo] ** 2 + alpha * lv[lo + 1] ** 2
    np.testing.assert_allclose(var, sigma**2, atol=1e-6)


@pytest.mark.parametrize("upsample", [1, 2, 3])
@pytest.mark.parametrize("sigma", [0.0, 0.35, 1.4])
def test_sampling_weights_equal_the_filtered_field_read_by_remap(upsample, sigma):
    """The closed-form weights reproduce what light_field + cv2.remap do to single pixels."""
    w, h = 12, 7
    pad = field_padding(sigma, upsample)
    dj_min, table = sample_weights_1d(sigma, upsample=upsample)
    np.testing.assert_allclose(table.sum(axis=2), 1.0)
    rng = np.random.default_rng(4)
    u = rng.uniform(-1.0, w, size=60)
    v = rng.uniform(-1.0, h, size=60)
    mx = field_coordinates(u, upsample=upsample, pad=pad).astype(np.float32)[None, :]
    my = field_coordinates(v, upsample=upsample, pad=pad).astype(np.float32)[None, :]

    def weights(coords, j):
        base, frac = remap_fractions(coords[0])
        q, rho = np.divmod(base - pad, upsample)
        k = j - q - dj_min
        ok = (k >= 0) & (k < table.shape[2])
        out = np.zeros(len(base))
        out[ok] = (1 - frac[ok]) * table[rho[ok], 0, k[ok]] + frac[ok] * table[rho[ok], 1, k[ok]]
        return out

    for j, i in [(0, 0), (5, 3), (11, 6), (6, 1)]:
        lum = np.zeros((h, w, 3), np.float32)
        lum[i, j] = 1.0
        field = light_field(lum, upsample=upsample, pad=pad, sigmas=[sigma])[0]
        got = cv2.remap(field, mx, my, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT)[0, :, 0]
        np.testing.assert_allclose(got, weights(mx, j) * weights(my, i), atol=2e-6)


@pytest.mark.parametrize("upsample", [1, 2, 4])
def test_light_field_conserves_light(upsample):
    rng = np.random.default_rng(5)
    lum = rng.random((20, 30, 3)).astype(np.float32)
    sigmas = [0.0, 0.5, 2.0]
    pad = field_padding(max(sigmas), upsample)
    for f in light_field(lum, upsample=upsample, pad=pad, sigmas=sigmas):
        assert f.sum(axis=(0, 1), dtype=np.float64) / upsample**2 == pytest.approx(lum.sum(axis=(0, 1), dtype=np.float64), rel=1e-6)


def test_defocus_follows_the_thin_lens_cone():
    # A cone of aperture A converging at the focus has diameter A |d - f| / f at distance d;
    # one pixel there spans d / focal_px mm, and a disc's per-axis sigma is diameter / 4.
    A, focus, focal = 12.0, 1500.0, 300.0
    d = np.array([1000.0, 1500.0, 1900.0])
    expected = (A * np.abs(d - focus) / focus) / (d / focal) / 4.0
    np.testing.assert_allclose(defocus_sigma(d, focus=focus, aperture=A, focal_px=focal), expected)
    assert defocus_sigma(np.array([1500.0]), focus=1500.0, aperture=A, focal_px=focal)[0] == 0.0


def test_irradiance_times_pixel_area_is_the_flux_of_one_pixel():
    """Uniform flux per pixel: E x footprint area is the same for every pixel (times the lens fall-off)."""
    R, t = look_at([-480.0, 350.0, 1400.0], [0.0, 0.0, 0.0])
    dev = Pinhole(intrinsics((320, 200), focal=310.0), R, t, (320, 200))
    rng = np.random.default_rng(6)
    pts = np.column_stack([rng.uniform(-600, 600, 30), rng.uniform(-300, 300, 30), np.zeros(30)])
    n = np.tile([0.0, 0.0, 1.0], (30, 1))
    for falloff in (0.0, 1.0, 4.0):
        e = irradiance_factor(dev.center, dev.axis, pts, n, falloff=falloff)
        area = pixel_footprint_area(dev, pts, n)
        cos_a = ((pts - dev.center) @ dev.axis) / np.linalg.norm(pts - dev.center, axis=1)
        flux = REFERENCE_DISTANCE_MM**2 / (dev.K[0, 0] * dev.K[1, 1]) * cos_a**falloff
        np.testing.assert_allclose(e * area, flux, rtol=1e-9)
    # A fronto-parallel surface on the axis at distance z: (1000 / z)^2.
    e = irradiance_factor(np.array([0, 0, 2000.0]), np.array([0, 0, -1.0]), np.zeros((1, 3)), np.array([[0, 0, 1.0]]))
    assert e[0] == pytest.approx(0.25)
    # Facing away: nothing.
    assert irradiance_factor(dev.center, dev.axis, pts[:1], -n[:1])[0] == 0.0


def test_sensor_quantises_clips_and_has_shot_and_read_noise():
    s = Sensor(full_well=10000.0, read_noise=3.0, bits=12)
    x = np.full((200, 200, 3), 0.3, np.float32)
    clean = s.expose(x, rng=None, noise=False)
    assert clean.dtype == np.float32
    np.testing.assert_allclose(clean, np.rint(0.3 * 4095) / 4095)
    assert s.expose(np.full((2, 2, 3), 1.7, np.float32), rng=None, noise=False).max() == 1.0
    noisy = s.expose(x, rng=np.random.default_rng(7), noise=True)
    var = float(noisy.var())
    expected = (0.3 * 10000 + 9.0) / 10000**2 + (1 / 4095) ** 2 / 12
    assert var == pytest.approx(expected, rel=0.05)
    assert abs(float(noisy.mean()) - 0.3) < 1e-3
    a = s.expose(x, rng=np.random.default_rng(8))
    b = s.expose(x, rng=np.random.default_rng(8))
    np.testing.assert_array_equal(a, b)
    with pytest.raises(ValueError):
        s.expose(x, rng=None, noise=True)
