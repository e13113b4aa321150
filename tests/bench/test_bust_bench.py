"""`shadowless bench bust`: its surface areas against the closed form, its ray casts and touch points."""
from __future__ import annotations

import math

import numpy as np
import pytest

from bench.bust import NAMED, finger, pixel_areas, ray_mesh, touch_points
from sim.touch import TouchingHand, inside


def plane_view(f: float = 400.0, size=(160, 120), tilt_deg: float = 35.0):
    """A pinhole tilted ``tilt_deg`` from looking straight down at the plane z = 0 from 600 mm:
    per pixel the world point, the plane's pixel footprint (closed form) and the unit ray."""
    w, h = size
    a = math.radians(tilt_deg)
    R = np.array([[1, 0, 0], [0, -math.cos(a), -math.sin(a)], [0, math.sin(a), -math.cos(a)]])   # rows: x, y, z axes
    C = np.array([0.0, -600 * math.tan(a), 600.0])
    ys, xs = np.mgrid[0:h, 0:w].astype(np.float64)
    cam = np.stack([(xs - (w - 1) / 2) / f, (ys - (h - 1) / 2) / f, np.ones_like(xs)], -1)
    cos_a = 1 / np.linalg.norm(cam, axis=-1)
    ray = (cam @ R) * cos_a[..., None]                                       # world unit rays
    t = -C[2] / ray[..., 2]
    pts = C + t[..., None] * ray
    # a pixel spans the solid angle cos^3(alpha) / f^2; on the plane it covers t^2 Omega / cos(incidence)
    closed = t ** 2 * cos_a ** 3 / f ** 2 / np.abs(ray[..., 2])
    return pts, closed, t


def test_pixel_areas_on_a_tilted_plane_are_the_closed_form():
    pts, closed, _ = plane_view()
    kind = np.ones(closed.shape, np.uint8)
    area = pixel_areas(pts, kind)
    np.testing.assert_allclose(area[1:-1, 1:-1], closed[1:-1, 1:-1], rtol=2e-3)
    np.testing.assert_allclose(area, closed, rtol=0.05)        # one-sided differences at the border


def test_a_depth_step_does_not_inflate_the_pixels_beside_it():
    """The right half of the view sees a plane 150 mm higher (the same rays, shorter): the pixels on
    either side of the step keep their own plane's footprint."""
    pts, closed, t = plane_view()
    C = np.array([0.0, -600 * math.tan(math.radians(35)), 600.0])
    ray = (pts - C) / t[..., None]
    t2 = (150 - 600.0) / ray[..., 2]
    right = np.zeros(closed.shape, bool)
    right[:, 80:] = True
    step = np.where(right[..., None], C + t2[..., None] * ray, pts)
    expected = np.where(right, closed * (t2 / t) ** 2, closed)
    kind = np.ones(closed.shape, np.uint8)
    area = pixel_areas(step, kind)
    np.testing.assert_allclose(area[1:-1, 78:82], expected[1:-1, 78:82], rtol=0.02)
    kind[:, :10] = 0                                                       # nothing there
    assert np.all(pixel_areas(np.where(kind[..., None] > 0, pts, np.nan), kind)[:, :10] == 0)


def test_rays_hit_the_triangle_where_the_closed_form_says():
    tri = np.array([[[0, 0, 0], [10, 0, 0], [0, 10, 0]], [[0, 0, 5], [10, 0, 5], [0, 10, 5]]], np.float64)
    face, bary = ray_mesh((2, 3, 20), (0, 0, -1), tri)
    assert face == 1 and bary @ tri[1] == pytest.approx([2, 3, 5])
    assert ray_mesh((20, 20, 20), (0, 0, -1), tri)[0] == -1
    assert ray_mesh((2, 3, -20), (0, 0, -1), tri)[0] == -1                 # behind the origin


def test_touch_points_lie_on_the_bust_and_leave_room_for_the_hand():
    from sim.mesh import bust

    mesh = bust()
    pts = touch_points(mesh, sampled=3, seed=1, poses=("normal", "above"))
    assert [p[0] for p in pts[:3]] == [name for name, _, _ in NAMED]
    head, chest, back = (p[1] for p in pts[:3])
    assert head[2] > 590 and chest[1] > 100 and 400 < back[2] < 460 and back[1] < -40
    v = mesh.vertices.astype(np.float64)
    for name, X, n in pts:
        assert np.min(np.linalg.norm(v - X, axis=1)) < 15                  # on the surface
        assert abs(np.linalg.norm(n) - 1) < 1e-9
        if name.startswith("s"):
            for pose in ("normal", "above"):
                hand = TouchingHand(X, n, direction=finger(pose, n))
                far = np.linalg.norm(v - X, axis=1) > 20
                assert not inside(hand, v[far]).any() and hand.lowest_z() >= 5
