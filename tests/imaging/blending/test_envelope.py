"""The Lipschitz envelope's two chamfer sweeps against its O(n^2) definition."""
from __future__ import annotations

import math

import numpy as np
import pytest

from imaging.blending.envelope import (brute_force_lower_envelope, chamfer_distance, lower_envelope,
                                       upper_envelope)


@pytest.mark.parametrize("seed", range(6))
def test_two_sweeps_equal_the_definition_on_random_surfaces_with_holes(seed):
    rng = np.random.default_rng(seed)
    h, w = rng.integers(1, 24, 2)
    f = rng.uniform(-1.0, 1.0, (h, w))
    f[rng.random((h, w)) < 0.3] = np.inf          # points that set no bound
    slope = float(rng.uniform(0.01, 0.5))
    got = lower_envelope(f, slope)
    want = brute_force_lower_envelope(f, slope)
    finite = np.isfinite(want)
    assert np.array_equal(finite, np.isfinite(got))
    assert np.allclose(got[finite], want[finite], atol=1e-12)


def test_the_envelope_lies_under_the_surface_and_its_slope_is_bounded():
    rng = np.random.default_rng(7)
    f = rng.uniform(0.0, 1.0, (30, 40))
    slope = 0.05
    g = lower_envelope(f, slope)
    assert np.all(g <= f + 1e-12)
    # every pair of 8-neighbours differs by at most slope times their chamfer distance
    for dy, dx in ((0, 1), (1, 0), (1, 1), (1, -1)):
        a = g[max(dy, 0):, max(dx, 0):g.shape[1] + min(dx, 0)]
        b = g[:g.shape[0] - dy, max(-dx, 0):g.shape[1] - max(dx, 0)]
        assert np.all(np.abs(a - b) <= slope * chamfer_distance(dx, dy) + 1e-12)
    # and it is the largest such surface: a point of f that is no higher than its envelope allows is kept
    assert np.isclose(g[f == f.min()][0], f.min())


def test_a_single_dark_point_only_pulls_down_its_neighbourhood():
    f = np.zeros((21, 21))
    f[10, 10] = -1.0
    g = lower_envelope(f, 0.1)
    assert g[10, 10] == -1.0
    assert math.isclose(g[10, 13], -0.7) and math.isclose(g[13, 13], -1.0 + 0.3 * math.sqrt(2))
    assert g[0, 0] == 0.0                       # far away: the surface itself


def test_upper_envelope_mirrors_the_lower_and_empty_surfaces_stay_unbounded():
    rng = np.random.default_rng(3)
    f = rng.uniform(0.0, 1.0, (9, 13))
    assert np.allclose(upper_envelope(f, 0.2), -lower_envelope(-f, 0.2))
    assert np.all(upper_envelope(f, 0.2) >= f - 1e-12)
    assert np.all(np.isinf(lower_envelope(np.full((3, 4), np.inf), 1.0)))


def test_bad_input_is_refused():
    with pytest.raises(ValueError, match="slope"):
        lower_envelope(np.zeros((3, 3)), -1.0)
    with pytest.raises(ValueError, match=r"\(h, w\)"):
        lower_envelope(np.zeros(3), 1.0)
