"""Warm starts that follow the picture's motion (MotionWarp) against a known shift and a cold start."""
from __future__ import annotations

import cv2
import numpy as np
import pytest

from coordinator.compensation.motion import MotionWarp
from coordinator.compensation.solver import FrameCompensator, TransportOperator, solve
from coordinator.compensation.synthetic import (
    sample_image,
    synthetic_rig,
    synthetic_transport,
)


def texture(h, w, seed=0):
    return cv2.GaussianBlur(np.random.default_rng(seed).random((h, w), dtype=np.float32), (0, 0), 1.5)


@pytest.mark.parametrize("scale", [1, 2])
def test_a_field_moves_with_a_known_shift(scale):
    h, w, dx, dy = 96, 128, 3, 2
    big = texture(h + 8, w + 8)
    prev, new = big[4 : 4 + h, 4 : 4 + w], big[4 - dy : 4 - dy + h, 4 - dx : 4 - dx + w]  # new = prev moved by (dx, dy)
    field = 2 * prev - 0.5  # anything tied to the picture
    moved = MotionWarp(scale=scale)(field, prev, new)
    truth = 2 * new - 0.5
    inner = (slice(8, -8), slice(8, -8))
    assert np.abs(moved - truth)[inner].mean() < 0.1 * np.abs(field - truth)[inner].mean()
    # colour fields and pictures move the same way
    rgb = MotionWarp(scale=scale)(np.dstack([field] * 3), np.dstack([prev] * 3), np.dstack([new] * 3))
    np.testing.assert_allclose(rgb[:, :, 1], moved, atol=1e-5)
    with pytest.raises(ValueError):
        MotionWarp(scale=0)


@pytest.mark.parametrize("scale", [1, 2])
def test_a_fine_field_keeps_its_detail_through_a_half_pixel_move(scale):
    # the correction a warm start carries is mostly high frequencies; at a fractional offset a
    # bilinear move low-pass filters it, the default (bicubic) keeps most of it
    h, w, d = 96, 128, 0.5
    yy, xx = np.mgrid[0:h, 0:w].astype(np.float64)

    def picture(x, y):  # smooth and textured both ways, so the flow is well defined
        return (0.5 + 0.2 * np.sin(x / 5) * np.cos(y / 7) + 0.15 * np.sin((x + 2 * y) / 9)).astype(np.float32)

    def fine(x, y):  # 0.3 cycles per pixel across, 0.21 down
        return (0.1 * np.sin(2 * np.pi * 0.3 * x) * np.cos(2 * np.pi * 0.21 * y)).astype(np.float32)

    prev, new = picture(xx, yy), picture(xx - d, yy)  # new = prev moved right by half a pixel
    field, truth = fine(xx, yy), fine(xx - d, yy)
    inner = (slice(8, -8), slice(8, -8))
    err = {name: np.abs(MotionWarp(scale=scale, **kw)(field, prev, new) - truth)[inner].mean()
           for name, kw in (("default", {}), ("bilinear", {"interpolation": cv2.INTER_LINEAR}))}
    assert err["default"] < 0.5 * err["bilinear"], err
    assert err["default"] < 0.25 * np.abs(field - truth)[inner].mean(), err
    with pytest.raises(ValueError, match="interpolation"):
        MotionWarp(interpolation=cv2.INTER_NEAREST)


def test_a_pan_warm_started_along_the_motion_is_closer_to_converged():
    h, w = 64, 96
    L = synthetic_transport(synthetic_rig(9, content_shape=(h, w), radius=2, seed=1), scale=1 / 9)
    op = TransportOperator(L)
    wide = (0.02 + 0.88 * sample_image(h, w + 6, channels=1, seed=2)).astype(np.float32)
    frames = [np.ascontiguousarray(wide[:, k : k + w]) for k in range(6)]  # 1 px per frame
    runs = {m: FrameCompensator(op, iterations=6, first_iterations=300, motion=m) for m in (False, True)}
    gaps = {m: [] for m in runs}
    for frame in frames:
        for m, comp in runs.items():
            res = comp(frame)
            best = solve(op, frame, x0=res.x, tol=1e-8, gap_tol=0, max_iter=2000).objective
            gaps[m].append(res.objective / best - 1)
    assert np.mean(gaps[True][1:]) < 0.5 * np.mean(gaps[False][1:]), gaps
