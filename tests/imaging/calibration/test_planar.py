"""Planar numerics: content placement, robust homographies, per-pixel aggregation and ChArUco
detection, each against an independent reference."""
from __future__ import annotations

import cv2
import numpy as np
import pytest

from bench.calibration import board_albedo
from imaging.calibration.errors import CalibrationError
from imaging.calibration.planar import (
    CharucoSpec,
    apply_homography,
    compose_pose,
    content_to_table,
    detect_charuco,
    fit_homography,
    homography_difference,
    pixel_centroids,
    table_to_camera_from_points,
)
from sim.room import Room
from sim.scene import reference_scene


def test_content_to_table_matches_the_rooms_independent_formula():
    room = Room(reference_scene(projector_scale=0.05, camera_scale=0.05))
    for size in [(1200, 600), (640, 320), (333, 200)]:
        np.testing.assert_allclose(content_to_table(size, (1200, 600)), room.truth.content_to_table_homography(size), atol=1e-12)
    # pixel centres: the first and last content pixels sit half a pixel inside the table's edges
    c = apply_homography(content_to_table((100, 50), (1200, 600)), np.array([[0.0, 0.0], [99.0, 49.0]]))
    np.testing.assert_allclose(c, [[-594.0, 294.0], [594.0, -294.0]])
    with pytest.raises(ValueError):
        content_to_table((0, 10), (1200, 600))


def test_compose_pose_is_the_product_of_the_three_mappings():
    rng = np.random.default_rng(1)
    A, B = np.eye(3) + rng.normal(0, 0.01, (3, 3)), np.eye(3) + rng.normal(0, 0.01, (3, 3))
    pose = compose_pose(A, B, content_size=(300, 150), table_mm=(1200, 600))
    pts = rng.uniform(0, 150, (20, 2))
    ref = apply_homography(A, apply_homography(B, apply_homography(content_to_table((300, 150), (1200, 600)), pts)))
    np.testing.assert_allclose(apply_homography(pose, pts), ref, atol=1e-9)
    # and it is what cv2.perspectiveTransform does
    np.testing.assert_allclose(cv2.perspectiveTransform(pts.reshape(-1, 1, 2), pose).reshape(-1, 2), apply_homography(pose, pts), atol=1e-9)


def test_robust_homography_ignores_outliers_and_averages_quantisation():
    rng = np.random.default_rng(2)
    H = np.array([[0.45, 0.02, 160.0], [-0.01, -0.46, 100.0], [2e-5, 6e-5, 1.0]])
    src = rng.uniform([-600, -300], [600, 300], (20000, 2))
    dst = np.floor(apply_homography(H, src) + 0.5)           # integer decoding: uniform +-0.5 error
    bad = rng.choice(len(src), 1000, replace=False)
    dst[bad] += rng.uniform(-40, 40, (1000, 2))               # 5 % wild decodes
    fit = fit_homography(src, dst, threshold=1.5)
    rms, mx = homography_difference(fit.H, H, src)
    assert mx < 0.02 and rms < 0.01
    assert fit.count >= 18500 and not fit.inliers[bad][np.abs(dst[bad] - apply_homography(H, src[bad])).max(axis=1) > 3].any()
    assert 0.35 < fit.rms < 0.45          # the residual of uniform +-0.5 rounding in 2D is ~0.41
    with pytest.raises(CalibrationError, match="at least 4"):
        fit_homography(src[:3], dst[:3])
    with pytest.raises(ValueError, match="differ in length"):
        fit_homography(src[:10], dst[:9])


def test_known_points_give_the_table_mapping_and_bad_sets_are_refused():
    H = np.array([[0.48, 0.02, 323.5], [0.0, -0.46, 242.5], [0.0, 6.3e-5, 1.0]])
    xy = np.array([[x, y] for x in (-560, -280, 0, 280, 560) for y in (260, 0, -260)], np.float64)
    fit = table_to_camera_from_points(xy, apply_homography(H, xy))
    assert homography_difference(fit.H, H, xy)[1] < 1e-4   # exact data: OpenCV's LM tolerance
    with pytest.raises(CalibrationError, match="collinear"):
        table_to_camera_from_points(np.column_stack([np.arange(6.0), np.zeros(6)]), np.zeros((6, 2)))
    with pytest.raises(CalibrationError, match="at least 4"):
        table_to_camera_from_points(xy[:3], xy[:3])


def test_pixel_centroids_match_a_brute_force_mean():
    rng = np.random.default_rng(3)
    proj = rng.integers(0, 5, (500, 2)).astype(np.float64)
    cam = rng.uniform(0, 100, (500, 2))
    means, pix = pixel_centroids(cam, proj, min_samples=3)
    for m, p in zip(means, pix):
        sel = np.all(proj == p, axis=1)
        assert sel.sum() >= 3
        np.testing.assert_allclose(m, cam[sel].mean(axis=0))
    assert len(pix) == len({tuple(p) for p in proj if np.sum(np.all(proj == p, axis=1)) >= 3})


def test_charuco_board_on_the_table_gives_the_table_mapping():
    """A board lying on the table, photographed by the room's camera: the board's albedo pattern
    rendered into the camera through the true table -> camera homography (supersampled 4x4 per camera
    pixel, as a sensor integrates), times the table lit by a projector, plus noise."""
    room = Room(reference_scene(projector_scale=0.1))
    room.set_active(["r2c2"])
    w, h = room.projector_size("r2c2")
    room.set_frame("r2c2", np.full((h, w, 3), 255, np.uint8))
    lit = room.capture(noise=False)
    spec = CharucoSpec(squares_x=11, squares_y=7, square_mm=80.0, marker_mm=60.0, dictionary="DICT_5X5_100",
                       origin_mm=(-440.0, 280.0))
    H_true = room.truth.table_to_camera_homography()
    albedo = board_albedo(room, spec)           # supersampled 4x4 per camera pixel
    photo = lit * albedo[:, :, None]
    photo = np.clip(photo + np.random.default_rng(0).normal(0, 0.004, photo.shape), 0, 1).astype(np.float32)
    txy, px = detect_charuco(photo, spec)
    assert len(txy) >= 50
    fit = table_to_camera_from_points(txy, px)
    grid = np.array([[x, y] for x in np.linspace(-600, 600, 13) for y in np.linspace(-300, 300, 7)])
    rms, mx = homography_difference(fit.H, H_true, grid)
    assert rms < 0.1 and mx < 0.25, (rms, mx)
    with pytest.raises(CalibrationError, match="ChArUco board was not found"):
        detect_charuco(lit, spec)
    with pytest.raises(CalibrationError, match="unknown ArUco dictionary"):
        CharucoSpec(dictionary="DICT_9X9_1").board()
    with pytest.raises(CalibrationError, match="unknown ChArUco board key"):
        CharucoSpec.from_dict({"squares": 5})
