"""rigctl/mpcdi/frustum.py: 3x4 matrices as MPCDI frusta, against closed forms and OpenCV."""
from __future__ import annotations

import math

import cv2
import numpy as np
import pytest

from rigctl.mpcdi.frustum import decompose, from_frustum, normalised, to_frustum

W, H = 1920, 1080
K = np.array([[2000.0, 0.0, 959.5], [0.0, 2000.0, 539.5], [0.0, 0.0, 1.0]])   # a centred lens
C = np.array([100.0, -2000.0, 1500.0])


def projection(rows, k=K, c=C):
    r = np.array(rows, np.float64)
    return k @ np.concatenate([r, (-r @ c)[:, None]], axis=1)


s30, c30 = math.sin(math.radians(30)), math.cos(math.radians(30))
s5, c5 = math.sin(math.radians(5)), math.cos(math.radians(5))
CASES = {   # hand-built projector axes (rows: right, down, forward) and the angles MPCDI gives them
    "level, facing +y": ([[1, 0, 0], [0, 0, -1], [0, 1, 0]], (0, 0, 0)),
    "turned right to +x": ([[0, -1, 0], [0, 0, -1], [1, 0, 0]], (90, 0, 0)),
    "tilted up 30": ([[1, 0, 0], [0, s30, -c30], [0, c30, s30]], (0, 30, 0)),
    "rolled 5, left side up": ([[c5, 0, -s5], [-s5, 0, -c5], [0, 1, 0]], (0, 0, 5)),
}


@pytest.mark.parametrize("name", sorted(CASES))
def test_closed_form_orientations(name):
    rows, (yaw, pitch, roll) = CASES[name]
    f = to_frustum(5.0 * projection(rows), W, H)
    assert (f.yaw, f.pitch, f.roll) == pytest.approx((yaw, pitch, roll), abs=1e-9)
    half_w, half_h = math.degrees(math.atan(960 / 2000)), math.degrees(math.atan(540 / 2000))
    assert (f.left, f.right, f.down, f.up) == pytest.approx((-half_w, half_w, -half_h, half_h), abs=1e-9)
    assert f.position_m == pytest.approx((0.1, -2.0, 1.5), abs=1e-12)
    assert abs(f.skew) < 1e-12


def test_decomposition_agrees_with_opencv_and_round_trips():
    rng = np.random.default_rng(4)
    for _ in range(20):
        k = np.array([[rng.uniform(900, 3000), 0, rng.uniform(700, 1200)], [0, rng.uniform(900, 3000),
                      rng.uniform(300, 800)], [0, 0, 1]])
        r, _ = cv2.Rodrigues(rng.normal(0, 1.0, 3))
        c = rng.uniform(-2000, 2000, 3)
        p = rng.choice([-1, 1]) * rng.uniform(0.01, 100) * projection(r, k, c)
        kk, rr, cc = decompose(p)
        k2, r2, t2, *_ = cv2.decomposeProjectionMatrix(normalised(p))
        np.testing.assert_allclose(kk, k2 / k2[2, 2], rtol=1e-9, atol=1e-8)
        np.testing.assert_allclose(rr, r2, atol=1e-12)
        np.testing.assert_allclose(cc, t2[:3, 0] / t2[3, 0], atol=1e-8)
        q = from_frustum(to_frustum(p, W, H), W, H)
        assert np.abs(q - normalised(p)).max() <= 1e-12 * np.abs(q).max()


def test_skew_is_reported_and_kept():
    k = K.copy()
    k[0, 1] = 3.0
    f = to_frustum(projection(CASES["level, facing +y"][0], k), W, H)
    assert f.skew == pytest.approx(3.0 / 2000.0)
    np.testing.assert_allclose(from_frustum(f, W, H), normalised(projection(CASES["level, facing +y"][0], k)),
                               rtol=1e-12, atol=1e-9)
