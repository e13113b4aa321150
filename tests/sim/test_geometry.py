"""Pinhole geometry against closed forms and OpenCV."""
from __future__ import annotations

import math

import cv2
import numpy as np
import pytest

from sim.geometry import (
    Pinhole,
    intrinsics,
    intersect_plane_z,
    look_at,
    pixel_footprint_area,
    plane_homography,
    rotation_about,
    scale_intrinsics,
)


@pytest.fixture
def device() -> Pinhole:
    K = np.array([[1210.0, 0.0, 633.2], [0.0, 1195.0, 405.9], [0.0, 0.0, 1.0]])
    R = rotation_about((0.3, -0.2, 0.9), 2.7) @ rotation_about((1, 0, 0), math.pi)
    eye = np.array([-420.0, 310.0, 1380.0])
    return Pinhole(K, R, -R @ eye, (1280, 800))


def test_projection_matches_closed_form_pinhole_and_opencv(device):
    rng = np.random.default_rng(0)
    X = rng.uniform([-600, -300, 0], [600, 300, 400], size=(50, 3))
    Xc = X @ device.R.T + device.t
    K = device.K
    x, y = Xc[:, 0] / Xc[:, 2], Xc[:, 1] / Xc[:, 2]
    expected = np.column_stack([K[0, 0] * x + K[0, 1] * y + K[0, 2], K[1, 1] * y + K[1, 2]])
    pix, depth = device.project(X)
    np.testing.assert_allclose(pix, expected, atol=1e-9)
    np.testing.assert_allclose(depth, Xc[:, 2], atol=1e-9)
    rvec, _ = cv2.Rodrigues(device.R)
    cv_pix, _ = cv2.projectPoints(X, rvec, device.t, K, None)
    np.testing.assert_allclose(pix, cv_pix.reshape(-1, 2), atol=1e-6)


def test_look_at_centres_the_target_and_keeps_up_at_the_top():
    R, t = look_at([-500.0, -500.0, 1400.0], [0.0, 0.0, 0.0])
    np.testing.assert_allclose(R @ R.T, np.eye(3), atol=1e-12)
    assert np.linalg.det(R) == pytest.approx(1.0)
    dev = Pinhole(intrinsics((1280, 800), focal=1000.0), R, t, (1280, 800))
    (cx, cy), z = dev.project(np.zeros(3))
    assert (cx, cy) == pytest.approx(((1280 - 1) / 2, (800 - 1) / 2))
    assert z > 0
    above, _ = dev.project(np.array([0.0, 50.0, 0.0]))  # world +y is image up
    right, _ = dev.project(np.array([50.0, 0.0, 0.0]))  # world +x is image right
    assert above[1] < cy and right[0] > cx
    with pytest.raises(ValueError, match="parallel"):
        look_at([0, 0, 10], [0, 0, 0], up=(0, 0, 1))


def test_scaled_intrinsics_keep_the_image_registered(device):
    small = device.scaled((320, 200))
    X = np.array([[10.0, -20.0, 5.0], [300.0, 100.0, 0.0]])
    full, _ = device.project(X)
    quarter, _ = small.project(X)
    np.testing.assert_allclose(quarter, 0.25 * (full + 0.5) - 0.5, atol=1e-9)
    np.testing.assert_allclose(scale_intrinsics(small.K, (320, 200), (1280, 800)), device.K, atol=1e-9)


def test_table_homography_equals_projection_of_the_plane(device):
    rng = np.random.default_rng(1)
    xy = rng.uniform(-600, 600, size=(20, 2))
    H = plane_homography(device.K, device.R, device.t)
    h = np.column_stack([xy, np.ones(len(xy))]) @ H.T
    pix, _ = device.project(np.column_stack([xy, np.zeros(len(xy))]))
    np.testing.assert_allclose(h[:, :2] / h[:, 2:], pix, atol=1e-8)
    np.testing.assert_allclose(device.table_homography(), H)


def test_rays_go_through_their_pixels_and_hit_the_table(device):
    pix = np.array([[0.0, 0.0], [640.5, 399.25], [1279.0, 799.0]])
    d = device.rays(pix)
    np.testing.assert_allclose(np.linalg.norm(d, axis=1), 1.0)
    pts, s = intersect_plane_z(np.broadcast_to(device.center, d.shape), d, z=0.0)
    assert np.all(np.isfinite(s)) and np.allclose(pts[:, 2], 0.0, atol=1e-9)
    back, _ = device.project(pts)
    np.testing.assert_allclose(back, pix, atol=1e-6)


def test_gl_projection_puts_pixel_centres_at_fragment_centres(device):
    rng = np.random.default_rng(2)
    X = rng.uniform([-600, -300, 0], [600, 300, 300], size=(10, 3))
    M = device.gl_projection(near=100.0, far=3000.0)
    clip = np.column_stack([X, np.ones(len(X))]) @ M.T
    ndc = clip[:, :3] / clip[:, 3:]
    w, h = device.size
    window = np.column_stack([(ndc[:, 0] + 1) / 2 * w, (ndc[:, 1] + 1) / 2 * h])
    pix, depth = device.project(X)
    np.testing.assert_allclose(window - 0.5, pix, atol=1e-6)
    assert np.all(np.abs(ndc[:, 2]) < 1)
    np.testing.assert_allclose(clip[:, 3], depth)


def test_pixel_footprint_area_is_the_inverse_jacobian_of_the_table_homography(device):
    H = device.table_homography()
    for x, y in [(0.0, 0.0), (-550.0, 280.0), (420.0, -260.0)]:
        e = 1e-3

        def f(px, py):
            v = H @ [px, py, 1.0]
            return v[:2] / v[2]

        J = np.column_stack([(f(x + e, y) - f(x - e, y)) / (2 * e), (f(x, y + e) - f(x, y - e)) / (2 * e)])
        area = pixel_footprint_area(device, np.array([[x, y, 0.0]]), np.array([[0.0, 0.0, 1.0]]))[0]
        assert area == pytest.approx(1.0 / abs(np.linalg.det(J)), rel=1e-6)


def test_bad_shapes_raise_value_error(device):
    with pytest.raises(ValueError):
        Pinhole(np.eye(3), np.eye(3), np.zeros(2), (10, 10))
    with pytest.raises(ValueError):
        Pinhole(np.eye(3), 2 * np.eye(3), np.zeros(3), (10, 10))
    with pytest.raises(ValueError):
        device.project(np.zeros((4, 2)))
    with pytest.raises(ValueError):
        intrinsics((0, 10), focal=1.0)
