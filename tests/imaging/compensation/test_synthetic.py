"""The synthetic rig's PSFs against brute-force numerical integration."""
from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest
from scipy.special import ndtr

from imaging.compensation.synthetic import (
    _smooth_antiderivative,
    slot_names,
    synthetic_rig,
    synthetic_transport,
    sample_image,
)
from imaging.calibration.planar import apply_homography


def test_tabulated_antiderivative_matches_closed_form():
    z = np.linspace(-6, 6, 20001).astype(np.float32)
    for s in (0.05, 0.4, 1.3):
        sig = np.full_like(z, s)
        exact = z * ndtr(z / s) + s * np.exp(-0.5 * (z / s) ** 2) / math.sqrt(2 * math.pi)
        assert np.abs(_smooth_antiderivative(z, sig) - exact).max() < 2e-6


def brute_force_psf(rig, optics, j, n=160):
    """Rotated square footprint convolved with the Gaussian, integrated over camera pixels by sampling."""
    h, w = rig.content_shape
    x, y = j % w, j // w
    cx, cy = apply_homography(rig.homography, np.array([[x, y]], np.float64)).T
    u = (x - (w - 1) / 2) / ((w - 1) / 2)
    v = (y - (h - 1) / 2) / ((h - 1) / 2)
    o = optics
    (gxu, gxv), (gyu, gyv) = o.offset_gradient
    mx = cx[0] + o.offset[0] + gxu * u + gxv * v + o.keystone[0] * u * v
    my = cy[0] + o.offset[1] + gyu * u + gyv * v + o.keystone[1] * u * u
    hm = rig.homography
    pitch = math.sqrt(abs(np.linalg.det(hm)) / (hm[2, 0] * x + hm[2, 1] * y + hm[2, 2]) ** 3)
    side = pitch * o.scale * (1 + o.scale_gradient[0] * u + o.scale_gradient[1] * v)
    d2 = (u - o.position[0]) ** 2 + (v - o.position[1]) ** 2
    sigma = o.sigma * pitch * (1 + o.sigma_growth * d2)
    bright = o.gain * (1 - o.vignette * d2 / 4) * pitch**2
    # points uniformly over the rotated square; each spreads a pixel-integrated Gaussian
    t = (np.arange(n) + 0.5) / n - 0.5
    p, q = np.meshgrid(t, t)
    ca, sa = math.cos(o.rotation), math.sin(o.rotation)
    px = (mx + side * (ca * p - sa * q)).ravel()
    py = (my + side * (sa * p + ca * q)).ravel()
    bx, by = int(np.rint(cx[0])), int(np.rint(cy[0]))
    R = rig.radius
    out = np.zeros((2 * R + 1, 2 * R + 1))
    for iy, dy in enumerate(range(-R, R + 1)):
        fy = ndtr((by + dy + 0.5 - py) / sigma) - ndtr((by + dy - 0.5 - py) / sigma)
        for ix, dx in enumerate(range(-R, R + 1)):
            fx = ndtr((bx + dx + 0.5 - px) / sigma) - ndtr((bx + dx - 0.5 - px) / sigma)
            out[iy, ix] = np.mean(fx * fy)
    return bright * out, (bx, by)


def test_psf_matches_brute_force_integration():
    hom = np.array([[1.2, 0.05, 3.0], [0.02, 1.15, 2.0], [1e-4, 2e-4, 1.0]])
    rig = synthetic_rig(25, content_shape=(12, 14), camera_shape=(24, 26), homography=hom, radius=3, seed=2)
    # exaggerate one unit's rotation and pitch so the footprint's orientation matters
    units = list(rig.projectors)
    units[7] = dataclasses.replace(units[7], rotation=0.5, scale=1.6, sigma=0.2)
    rig = dataclasses.replace(rig, projectors=tuple(units))
    for i in (0, 7, 24):
        L = synthetic_transport(rig, projectors=[i], footprint_samples=8).tocsc()
        for j in (0, 40, 12 * 14 - 1):
            ref, (bx, by) = brute_force_psf(rig, rig.projectors[i], j)
            col = L[:, j].toarray().ravel().reshape(24, 26)
            R = rig.radius
            got = np.zeros_like(ref)
            for iy, dy in enumerate(range(-R, R + 1)):
                for ix, dx in enumerate(range(-R, R + 1)):
                    if 0 <= by + dy < 24 and 0 <= bx + dx < 26:
                        got[iy, ix] = col[by + dy, bx + dx]
                    else:
                        ref[iy, ix] = 0
            assert np.abs(got - ref).max() < 4e-3 * ref.max(), (i, j)
            assert col.sum() == pytest.approx(got.sum(), rel=1e-6)  # nothing outside the window


def test_rig_transport_is_sum_of_units_with_one_structure():
    rig = synthetic_rig(9, content_shape=(16, 20), radius=2, seed=1)
    per = synthetic_transport(rig, per_projector=True, scale=1 / 9)
    total = synthetic_transport(rig, scale=1 / 9)
    assert len(per) == 9
    for Li in per:
        assert np.array_equal(Li.indptr, total.indptr) and np.array_equal(Li.indices, total.indices)
    assert np.allclose(sum(Li.toarray() for Li in per), total.toarray(), atol=1e-6)
    # energy: interior columns carry about gain * vignetting (a little is truncated by the window)
    col = np.asarray(total.sum(axis=0)).reshape(16, 20)[4:-4, 4:-4]
    gains = np.mean([p.gain for p in rig.projectors])
    assert np.all(col > 0.85 * gains) and np.all(col < 1.01 * gains)
    # blur: the summed PSF is wider than a single unit's
    assert total.max() < max(Li.max() for Li in per) * 9


def test_slots_and_subsets_share_units():
    assert slot_names(1) == ["r2c2"]
    assert sorted(slot_names(9)) == sorted(f"r{r}c{c}" for r in (1, 2, 3) for c in (1, 2, 3))
    assert len(set(slot_names(25))) == 25
    a = synthetic_rig(9, content_shape=(8, 8), seed=4)
    b = synthetic_rig(25, content_shape=(8, 8), seed=4)
    by_slot = {p.slot: p for p in b.projectors}
    assert all(by_slot[p.slot] == p for p in a.projectors)
    with pytest.raises(ValueError):
        slot_names(26)


def test_test_image_is_sharp_and_sized():
    img = sample_image(100, 130)
    assert img.shape == (100, 130, 3) and img.dtype == np.float32
    assert 0 <= img.min() and img.max() <= 1
    grey = sample_image(100, 130, channels=1)
    assert grey.shape == (100, 130)
    # native-resolution detail: strong pixel-to-pixel differences exist
    assert np.abs(np.diff(grey, axis=1)).max() > 0.3
