"""Warm starts that follow the picture's motion (MotionWarp) against a known shift, a still
background around a moving object, and starts that do not move (FrameCompensator, ContentWarmStart)."""
from __future__ import annotations

import cv2
import numpy as np
import pytest

from imaging.compensation.motion import MotionWarp
from imaging.compensation.ridge import ContentWarmStart, RidgeProblem
from imaging.compensation.solver import FrameCompensator, TransportOperator, solve
from imaging.compensation.synthetic import sample_image, synthetic_rig, synthetic_transport


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


@pytest.mark.parametrize("scale", [1, 2])
def test_carry_moves_a_moving_object_and_leaves_the_still_picture_where_it_is(scale):
    # a textured disc moves 4 px over a still textured picture: the flow DIS finds spills onto the
    # background around the disc; carry keeps the field in place wherever no motion explains the change
    h, w, r, step = 96, 160, 14, 4
    back = 0.3 + 0.4 * texture(h, w, seed=0)
    disc = 0.5 + 0.5 * texture(h, w, seed=5)
    yy, xx = np.mgrid[0:h, 0:w]

    def picture(cx):
        inside = (xx - cx) ** 2 + (yy - h // 2) ** 2 <= r * r
        img = back.copy()
        img[inside] = np.roll(disc, cx, axis=1)[inside]   # the disc's texture moves with it
        return img, inside

    (prev, was), (new, now) = picture(60), picture(60 + step)
    field = texture(h, w, seed=9) - 0.5
    carried = MotionWarp(scale=scale).carry(field, prev, new)
    assert carried.shape == field.shape and carried.dtype == np.float32
    far = cv2.distanceTransform((~(was | now)).astype(np.uint8), cv2.DIST_L2, 5) > 12
    assert np.array_equal(carried[far], field[far])   # the still picture's field stays, exactly
    truth = np.roll(field, step, axis=1)
    core = cv2.erode(now.astype(np.uint8), np.ones((2 * step + 3,) * 2, np.uint8)).astype(bool)
    assert np.abs(carried - truth)[core].mean() < 0.25 * np.abs(field - truth)[core].mean()
    # colour fields move the same way; the pictures' channel mean decides
    rgb = MotionWarp(scale=scale).carry(np.dstack([field] * 3), np.dstack([prev] * 3), np.dstack([new] * 3))
    np.testing.assert_allclose(rgb[:, :, 2], carried, atol=1e-5)
    with pytest.raises(ValueError, match="size"):
        MotionWarp().carry(field[:, :-1], prev, new)
    with pytest.raises(ValueError, match="window"):
        MotionWarp(window=4)
    with pytest.raises(ValueError, match="preset"):
        MotionWarp(preset="slow")


def test_a_content_warm_start_along_the_motion_is_closer_to_converged():
    # the jobs' warm start (content and camera grids may differ; here they coincide), ridge included
    h, w = 64, 96
    L = synthetic_transport(synthetic_rig(9, content_shape=(h, w), radius=2, seed=1), scale=1 / 9)
    problem = RidgeProblem(L, 0.02)
    wide = (0.02 + 0.88 * sample_image(h, w + 6, channels=1, seed=2)).astype(np.float32)
    frames = [np.ascontiguousarray(wide[:, k : k + w]) for k in range(6)]  # 1 px per frame
    runs = {m: ContentWarmStart(problem, iterations=4, first_iterations=300, content_shape=(h, w),
                                motion=MotionWarp(scale=1, preset="fast") if m else None) for m in (False, True)}
    gaps = {m: [] for m in runs}
    for frame in frames:
        target = 0.5 * frame   # the target is the content scaled (ContentWarmStart finds the scale)
        for m, warm in runs.items():
            res = warm(target, frame)
            goal = problem.target(target, np.clip(frame * np.float32(warm.scale), 0, 1))
            best = solve(problem.op, goal, x0=res.x, tol=1e-8, gap_tol=0, max_iter=2000).objective
            gaps[m].append(res.objective / best - 1)
    assert runs[True].scale == pytest.approx(runs[False].scale)
    assert runs[True].last_share > 0.9 and runs[False].last_share is None   # a blur-only rig: the moved start
    assert np.mean(gaps[True][1:]) < 0.5 * np.mean(gaps[False][1:]), gaps
