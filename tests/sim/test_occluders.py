"""Occluders: exact ray tests against dense brute-force sampling."""
from __future__ import annotations

import math

import numpy as np
import pytest

from sim.geometry import rotation_about
from sim.occluders import Box, Capsule, Ellipsoid, Sphere, cast_rays, segment_blocked


def _inside(prim, p: np.ndarray) -> np.ndarray:
    """Independent point-membership tests, (N, 3) -> (N,) bool."""
    if isinstance(prim, Sphere):
        return np.linalg.norm(p - prim.center, axis=-1) <= prim.radius
    if isinstance(prim, Ellipsoid):
        local = (p - prim.center) @ prim.rotation
        return np.sum((local / prim.radii) ** 2, axis=-1) <= 1.0
    if isinstance(prim, Capsule):
        ab = prim.b - prim.a
        s = np.clip(((p - prim.a) @ ab) / (ab @ ab), 0.0, 1.0)
        return np.linalg.norm(p - (prim.a + s[..., None] * ab), axis=-1) <= prim.radius
    if isinstance(prim, Box):
        local = (p - prim.center) @ prim.rotation
        return np.all(np.abs(local) <= prim.size / 2, axis=-1)
    raise TypeError(prim)


PRIMITIVES = [
    Sphere((10.0, -20.0, 150.0), 40.0),
    Ellipsoid((0.0, 0.0, 200.0), (60.0, 30.0, 15.0), rotation_about((1, 2, 3), 0.7)),
    Capsule((-50.0, 0.0, 180.0), (80.0, 40.0, 260.0), 25.0),
    Box((20.0, 10.0, 160.0), (120.0, 70.0, 30.0), rotation_about((0, 0, 1), 0.4) @ rotation_about((1, 0, 0), 0.3)),
]


@pytest.mark.parametrize("prim", PRIMITIVES, ids=lambda p: type(p).__name__)
def test_ray_intervals_match_dense_sampling(prim):
    rng = np.random.default_rng(11)
    c, r = prim.bounding_sphere()
    n = 150
    origins = c + rng.normal(size=(n, 3)) * 150.0
    targets = c + rng.normal(size=(n, 3)) * r * 0.8
    d = targets - origins
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    t_in, t_out, normal = prim.interval(origins, d)
    f_in, f_out = prim.interval_from(origins[0], d[:1, 0], d[:1, 1], d[:1, 2])
    assert f_in[0] == pytest.approx(t_in[0]) and f_out[0] == pytest.approx(t_out[0])
    ts = np.linspace(0.0, 1500.0, 30001)  # 0.05 mm steps
    for k in range(n):
        inside = _inside(prim, origins[k] + ts[:, None] * d[k])
        if not inside.any():
            assert not np.isfinite(t_in[k]) or t_out[k] - t_in[k] < 0.1
            continue
        assert t_in[k] == pytest.approx(ts[inside][0], abs=0.06)
        assert t_out[k] == pytest.approx(ts[inside][-1], abs=0.06)
        # The normal points out of the solid at the entry point.
        p = origins[k] + t_in[k] * d[k]
        assert not _inside(prim, (p + 0.2 * normal[k])[None])[0]
        assert _inside(prim, (p - 0.2 * normal[k])[None])[0] or t_out[k] - t_in[k] < 0.5


@pytest.mark.parametrize("prim", PRIMITIVES, ids=lambda p: type(p).__name__)
def test_fast_path_from_one_origin_equals_the_general_test(prim):
    rng = np.random.default_rng(12)
    origin = np.array([120.0, -80.0, 1400.0])
    c, r = prim.bounding_sphere()
    d = c + rng.normal(size=(500, 3)) * r - origin
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    t_in, t_out, _ = prim.interval(np.broadcast_to(origin, d.shape).copy(), d)
    f_in, f_out = prim.interval_from(origin, d[:, 0], d[:, 1], d[:, 2])
    hit = np.isfinite(t_in)
    np.testing.assert_array_equal(hit, np.isfinite(f_in))
    np.testing.assert_allclose(f_in[hit], t_in[hit], atol=1e-6)
    np.testing.assert_allclose(f_out[hit], t_out[hit], atol=1e-6)


def test_segments_are_blocked_exactly_when_a_sample_on_them_is_inside():
    rng = np.random.default_rng(13)
    starts = np.column_stack([rng.uniform(-300, 300, 400), rng.uniform(-300, 300, 400), np.zeros(400)])
    end = np.array([50.0, 30.0, 1400.0])
    blocked = segment_blocked(starts, end, PRIMITIVES)
    s = np.linspace(0, 1, 4001)[1:-1]
    for k in range(len(starts)):
        pts = starts[k] + s[:, None] * (end - starts[k])
        brute = any(_inside(p, pts).any() for p in PRIMITIVES)
        assert blocked[k] == brute
    assert blocked.any() and not blocked.all()


def test_cast_rays_returns_the_nearest_hit():
    origin = np.array([[0.0, 0.0, 1000.0]])
    down = np.array([[0.0, 0.0, -1.0]])
    a = Sphere((0.0, 0.0, 100.0), 10.0)
    b = Box((0.0, 0.0, 300.0), (20.0, 20.0, 20.0))
    t, n = cast_rays(origin, down, [a, b])
    assert t[0] == pytest.approx(1000 - 310)
    np.testing.assert_allclose(n[0], [0, 0, 1])


def test_capsule_cull_spheres_cover_the_capsule():
    cap = PRIMITIVES[2]
    rng = np.random.default_rng(14)
    c, r = cap.bounding_sphere()
    pts = c + rng.uniform(-r, r, size=(20000, 3))
    inside = pts[_inside(cap, pts)]
    covered = np.zeros(len(inside), bool)
    for sc, sr in cap.cull_spheres():
        covered |= np.linalg.norm(inside - sc, axis=1) <= sr + 1e-9
    assert covered.all()
    assert len(cap.cull_spheres()) > 1 and math.isfinite(r)
