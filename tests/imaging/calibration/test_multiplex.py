"""The multiplexed mode's numerics on synthetic cameras with known geometry: dot drawing, the
coded-dot plan and decoder (including overlaps), sub-pixel centroids and the interleaved lattice."""
from __future__ import annotations

import math

import cv2
import numpy as np
import pytest

from imaging.calibration.multiplex import (
    _lattice_multiplier,
    centroids,
    decode_coded_dots,
    draw_dots,
    measure_lattice,
    plan_coded_dots,
    plan_lattice,
    snap_centre,
)
from imaging.calibration.planar import apply_homography

CAM = (480, 320)


def render(projector_images: dict[str, np.ndarray], to_camera: dict[str, np.ndarray], *, ss: int = 6,
           blur: float = 0.6, noise: float = 0.002, seed: int = 0) -> np.ndarray:
    """A camera that sees each projector image through its homography (projector px -> camera px):
    square projector pixels integrated over camera pixels (supersampled), a little optical blur, noise."""
    W, H = CAM
    U = np.array([[ss, 0, (ss - 1) / 2], [0, ss, (ss - 1) / 2], [0, 0, 1.0]])
    acc = np.zeros((H, W), np.float32)
    for s, img in projector_images.items():
        fine = cv2.warpPerspective(img.astype(np.float32) / 255.0, U @ to_camera[s], (W * ss, H * ss), flags=cv2.INTER_NEAREST)
        acc += cv2.resize(fine, (W, H), interpolation=cv2.INTER_AREA) * 0.05
    acc = cv2.GaussianBlur(acc, (0, 0), blur)
    acc += np.random.default_rng(seed).normal(0, noise * 0.05, acc.shape).astype(np.float32) + 0.004
    return np.repeat(acc[:, :, None], 3, axis=2)


def homographies(n: int, seed: int = 0) -> dict[str, np.ndarray]:
    """Projectors of 160x100 px seen by the camera at ~2.5 camera px per projector px, each from its own angle."""
    rng = np.random.default_rng(seed)
    out = {}
    for i in range(n):
        src = np.array([[0, 0], [159, 0], [159, 99], [0, 99]], np.float32)
        dst = np.array([[40, 40], [440, 40], [440, 290], [40, 290]], np.float32) + rng.uniform(-25, 25, (4, 2)).astype(np.float32)
        out[f"p{i}"] = cv2.getPerspectiveTransform(src, dst)
    return out


def test_dots_are_squares_centred_where_asked():
    img = draw_dots((20, 10), np.array([[5.0, 4.0], [0.0, 0.0]]), 3)
    ys, xs = np.nonzero(img)
    assert img[3:6, 4:7].all() and img.sum() == 255 * (9 + 4)   # the second dot is clipped at the corner
    img2 = draw_dots((20, 10), np.array([[5.5, 4.5]]), 2)
    ys, xs = np.nonzero(img2)
    assert (xs.mean(), ys.mean()) == (5.5, 4.5)
    np.testing.assert_array_equal(snap_centre(np.array([[3.2, 4.7]]), 3), [[3.0, 5.0]])
    np.testing.assert_array_equal(snap_centre(np.array([[3.2, 4.7]]), 2), [[3.5, 4.5]])


def test_coded_plan_lights_every_dot_once_per_pair_with_unique_codes():
    sizes = {f"p{i}": (160, 100) for i in range(5)}
    plan = plan_coded_dots(sizes, dot_px=1)
    assert plan.bits == 10 and plan.captures == 20
    codes = np.concatenate([plan.codes[s] for s in plan.slots])
    assert len(set(codes.tolist())) == len(codes)
    for s in plan.slots:
        c = plan.centres[s]
        assert len(c) == 48 and np.all((c >= 2) & (c <= [157, 97]))
        for k in range(plan.bits):
            on = plan.frames(2 * k)[s][c[:, 1].astype(int), c[:, 0].astype(int)] > 0
            off = plan.frames(2 * k + 1)[s][c[:, 1].astype(int), c[:, 0].astype(int)] > 0
            assert np.all(on ^ off)
    # the code length grows as log2 of the projector count once the codes run short
    assert plan_coded_dots({f"p{i}": (160, 100) for i in range(200)}).bits == 12
    with pytest.raises(ValueError):
        plan.frames(20)


def test_coded_dots_decode_to_the_right_projector_pixels():
    Hs = homographies(6)
    sizes = {s: (160, 100) for s in Hs}
    plan = plan_coded_dots(sizes, dot_px=1, seed=3)
    dark = render({s: np.zeros((100, 160), np.uint8) for s in Hs}, Hs, seed=100)
    caps = [render(plan.frames(k), Hs, seed=k) for k in range(plan.captures)]
    dec = decode_coded_dots(caps, dark, plan)
    total = 0
    for s in Hs:
        m = dec.matches[s]
        total += m.count
        if m.count == 0:
            continue
        err = np.linalg.norm(apply_homography(Hs[s], m.projector) - m.camera, axis=1)
        # coarse centroids of 1-px dots (a small disc): a fraction of a camera pixel; a wrong label would be pixels off
        assert np.median(err) < 0.25 and err.max() < 1.0, (s, np.median(err), err.max())
    assert total >= 0.75 * 6 * 48


def test_overlapping_dots_with_different_codes_are_rejected():
    H = homographies(1)["p0"]
    Hs = {"a": H, "b": H}                       # two projectors landing exactly on each other
    plan = plan_coded_dots({"a": (160, 100), "b": (160, 100)}, dot_px=1)
    plan.centres["b"][:] = plan.centres["a"]    # ... with their dots at the same pixels
    dark = render({s: np.zeros((100, 160), np.uint8) for s in Hs}, Hs)
    caps = [render(plan.frames(k), Hs, seed=k) for k in range(plan.captures)]
    dec = decode_coded_dots(caps, dark, plan)
    assert dec.matches["a"].count == 0 and dec.matches["b"].count == 0
    assert dec.collisions >= 30


def test_centroids_are_unbiased_on_gaussian_blobs():
    rng = np.random.default_rng(5)
    true = rng.uniform(20, 180, (60, 2))
    ys, xs = np.mgrid[0:200, 0:200]
    img = np.zeros((200, 200), np.float32)
    for x, y in true:
        img += np.exp(-((xs - x) ** 2 + (ys - y) ** 2) / (2 * 1.3 ** 2)).astype(np.float32)
    img += 0.05
    got, mass = centroids(img, np.rint(true) + rng.integers(-1, 2, true.shape), radius=5)
    err = np.linalg.norm(got - true, axis=1)
    ok = np.isfinite(err)
    assert ok.sum() >= 55 and np.median(err[ok]) < 0.01 and mass[ok].min() > 0
    with pytest.raises(ValueError):
        centroids(img[None], true, radius=3)


def test_lattice_multiplier_spreads_each_projectors_sites_as_far_as_possible():
    def spread(n, q):
        return min(math.hypot(((-q * b) % n) - n * (((-q * b) % n) > n / 2), b) for b in range(1, n + 1))

    for n in (2, 5, 9, 16, 25):
        q = _lattice_multiplier(n)
        best = max(spread(n, k) for k in range(1, n) if math.gcd(k, n) == 1) if n > 2 else spread(n, 1)
        assert spread(n, q) == pytest.approx(best)
    assert spread(25, _lattice_multiplier(25)) >= 4.9   # one projector's sites ~5 steps apart


def test_lattice_dots_never_overlap_and_are_measured_where_they_land():
    # table mm -> camera px (a camera above the table) and per projector a slightly wrong coarse pose
    T2C = np.array([[0.38, 0.0, 240.0], [0.0, -0.38, 160.0], [0.0, 0.0, 1.0]])
    rng = np.random.default_rng(7)
    proj_to_cam = homographies(9, seed=7)
    true_t2p = {s: np.linalg.inv(H) @ T2C for s, H in proj_to_cam.items()}
    coarse = {}
    for s, H in true_t2p.items():
        d = np.eye(3)
        d[:2, 2] = rng.uniform(-0.6, 0.6, 2)       # coarse error up to ~0.6 projector px
        coarse[s] = d @ H
    sizes = {s: (160, 100) for s in proj_to_cam}
    lat = plan_lattice(coarse, T2C, sizes=sizes, camera_size=CAM, table_mm=(1200, 600), rounds=2)
    assert lat.dot_px % 2 == 1 and lat.spacing_px >= 12
    for rnd in lat.rounds:
        pts = np.vstack([rnd.expected[s] for s in lat.slots])
        owner = np.concatenate([[i] * len(rnd.expected[s]) for i, s in enumerate(lat.slots)])
        d = np.linalg.norm(pts[:, None] - pts[None], axis=-1)
        other = owner[:, None] != owner[None]
        assert d[other].min() > lat.spacing_px * 0.8       # different projectors' dots never overlap
    dark = render({s: np.zeros((100, 160), np.uint8) for s in sizes}, proj_to_cam, seed=50)
    for r in range(2):
        cap = render(lat.frames(r), proj_to_cam, seed=60 + r)
        found = measure_lattice(cap, dark, lat, r)
        for s in lat.slots:
            m = found[s]
            assert m.count >= 0.9 * len(lat.rounds[r].centres[s]) > 0
            err = np.linalg.norm(apply_homography(proj_to_cam[s], m.projector) - m.camera, axis=1)
            assert np.median(err) < 0.05 and err.max() < 0.2, (s, np.median(err), err.max())
