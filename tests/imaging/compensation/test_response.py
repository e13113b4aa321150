"""Luminance response, inverse LUTs and brightness matching, checked against closed forms."""
from __future__ import annotations

import numpy as np
import pytest
from scipy.optimize import isotonic_regression

from imaging.compensation import (
    CompensationError,
    FittedResponse,
    brightness_scale,
    capture_means,
    fit_response,
    grey_levels,
    inverse_lut,
    response_mask,
    verify_linearity,
)
from imaging.compensation.response import _isotonic
from protos.spaces import lut_lookup


def gamma_projector(gamma: float, black: float, peak: float = 1.0):
    """Closed-form unit: absolute light r(v) = peak * (black + (1 - black) v^gamma)."""
    return lambda v: peak * (black + (1 - black) * np.asarray(v, dtype=np.float64) ** gamma)


@pytest.mark.parametrize("gamma,black", [(1.8, 0.002), (2.2, 0.005), (2.6, 0.01)])
def test_inverse_lut_matches_closed_form(gamma, black):
    levels = grey_levels(33)
    r = gamma_projector(gamma, black, peak=2.5)
    resp = fit_response(levels, r(levels))
    lut = inverse_lut(resp, entries=1024)
    assert lut.shape == (1, 1024) and lut.dtype == np.float32
    y = np.linspace(0, 1, 1024)
    # rho(v) = v^gamma whatever the black level, so the inverse is y^(1/gamma)
    assert np.abs(lut[0] - y ** (1 / gamma)).max() < 2e-3
    assert lut[0, 0] == 0 and lut[0, -1] == 1
    assert np.all(np.diff(lut[0]) >= 0)
    assert resp.gamma[0] == pytest.approx(gamma, abs=0.02)
    assert resp.black[0] == pytest.approx(2.5 * black)
    assert resp.peak[0] == pytest.approx(2.5 * (1 - black))


def test_rig_is_linear_after_luts_with_8bit_quantisation():
    """Three different units, each behind its own LUT, sum to a straight line within the 8-bit bound."""
    units = [gamma_projector(2.0, 0.004, 1.1), gamma_projector(2.3, 0.008, 0.9), gamma_projector(2.5, 0.002, 1.0)]
    levels = grey_levels(17)
    rng = np.random.default_rng(3)
    luts = []
    for unit in units:
        noisy = unit(np.repeat(levels, 3)) * (1 + 0.001 * rng.standard_normal(levels.size * 3))
        luts.append(inverse_lut(fit_response(np.repeat(levels, 3), noisy), entries=1024))
    y = np.linspace(0, 1, 65)
    light = sum(unit(lut_lookup(lut, y) / 255.0) for unit, lut in zip(units, luts))
    report = verify_linearity(y, light, tolerance=0.01)
    assert report.linear, report
    # 8-bit steps: one unit's error is at most slope * half a code, gamma_max / 510
    assert report.max_error < 2.5 / 510 + 2e-3
    # the same units without LUTs are far from linear (the check can fail)
    raw = sum(unit(np.rint(y * 255) / 255) for unit in units)
    assert not verify_linearity(y, raw, tolerance=0.01).linear


def test_node_lut_lookup_gain_and_channels():
    lut = np.stack([np.linspace(0, 1, 5), np.linspace(0, 1, 5) ** 0.5]).astype(np.float32)
    img = np.full((2, 3, 2), 0.25, dtype=np.float32)
    out = lut_lookup(lut, img, gain=2.0)
    assert out.dtype == np.uint8 and out.shape == (2, 3, 2)
    # gain 2 -> 0.5; channel 0 identity -> 128, channel 1 interpolates sqrt samples at 0.5 -> sqrt(0.5)
    assert out[0, 0, 0] == 128
    assert out[0, 0, 1] == round(255 * np.sqrt(0.5))
    assert lut_lookup(lut[:1], np.array([2.0]))[0] == 255  # clipped to full output
    with pytest.raises(ValueError):
        lut_lookup(lut, np.zeros((2, 2, 3)))


def test_isotonic_matches_scipy():
    rng = np.random.default_rng(0)
    y = np.linspace(0, 1, 40) + 0.08 * rng.standard_normal(40)
    w = rng.uniform(0.5, 3, 40)
    ours = _isotonic(y, w)
    ref = isotonic_regression(y, weights=w).x
    assert np.allclose(ours, ref, atol=1e-12)


def test_fit_response_is_monotone_under_noise_and_replicates_channels():
    rng = np.random.default_rng(1)
    levels = np.repeat(grey_levels(9), 4)
    meas = 0.01 + levels**2.2 + 0.02 * rng.standard_normal(levels.size)
    meas[levels == 0] = 0.01
    meas[levels == 1] = 1.01
    resp = fit_response(levels, meas, channels=3)
    assert resp.channels == 3 and resp.curve.shape == (3, 9)
    v = np.linspace(0, 1, 1001)
    rho = resp.normalised(v)
    assert rho.shape == (3, 1001)
    assert np.all(np.diff(rho, axis=1) >= -1e-12)
    assert np.allclose(resp.luminance(np.array([0.0, 1.0]))[:, 0], 0.01)
    assert np.allclose(resp.luminance(np.array([0.0, 1.0]))[:, 1], 1.01)


def test_fit_response_rejects_bad_input():
    with pytest.raises(ValueError):
        fit_response([0.2, 0.5, 1.0], [0.1, 0.3, 1.0])  # no black level
    with pytest.raises(ValueError):
        fit_response([0, 0.5, 1], np.zeros((4, 3)))
    with pytest.raises(ValueError):
        fit_response([0, 0.5, 1], np.zeros((3, 3)), channels=2)
    with pytest.raises(CompensationError):
        fit_response([0, 0.5, 1], [0.3, 0.3, 0.3])


def test_brightness_scale_matches_reference_and_reports_headroom():
    levels = grey_levels(9)
    rig = [fit_response(levels, gamma_projector(2.2, 0.005, p)(levels)) for p in (0.9, 1.0, 1.1, 1.05)]
    single = fit_response(levels, gamma_projector(2.2, 0.005, 1.0)(levels))
    match = brightness_scale(rig, single)
    total = sum(r.peak[0] for r in rig)
    assert match.gain == pytest.approx(single.peak[0] / total)
    assert match.headroom == pytest.approx(total / single.peak[0])
    assert match.reachable
    # the gained rig emits the reference white
    assert match.gain * total == pytest.approx(single.peak[0])
    dim = brightness_scale(rig[:1], 2.0)
    assert dim.gain > 1 and dim.headroom < 1 and not dim.reachable
    colour = brightness_scale([fit_response(levels, np.stack([levels, 2 * levels, levels], 1))], np.array([1.0, 1.0, 1.0]))
    assert np.allclose(colour.channel_headroom, [1, 2, 1])
    assert colour.gain == pytest.approx(3 / 4)


def test_capture_means_in_mask():
    black = np.full((20, 30, 3), 0.01, dtype=np.float32)
    white = black.copy()
    white[5:15, 10:25] += 0.8
    mask = response_mask(white, black)
    assert mask.sum() == 10 * 15
    caps = [black + (white - black) * v for v in (0.0, 0.5, 1.0)]
    m = capture_means(caps, mask=mask)
    assert m.shape == (3, 3)
    assert np.allclose(m[:, 0], [0.01, 0.41, 0.81], atol=1e-6)
    with pytest.raises(CompensationError):
        response_mask(black, black)


def test_verify_linearity_detects_curvature():
    y = np.linspace(0, 1, 11)
    ok = verify_linearity(y, 0.02 + 3 * y)
    assert ok.linear and ok.max_error < 1e-12 and ok.slope[0] == pytest.approx(3)
    bent = verify_linearity(y, y**1.2)
    assert not bent.linear and bent.max_error > 0.01


def test_response_dataclass_is_consistent():
    resp = fit_response(grey_levels(5), np.array([0.0, 0.1, 0.3, 0.6, 1.0]))
    assert isinstance(resp, FittedResponse)
    assert resp.levels[0] == 0 and resp.levels[-1] == 1
    assert np.allclose(resp.normalised(resp.levels)[0], resp.curve[0])
