"""The numerics the compensation jobs add on top of coordinator/compensation: checked against
independent references (matrix products, cv2 warps, closed forms, brute force)."""
from __future__ import annotations

import asyncio
import base64
import json
import zlib

import cv2
import numpy as np
import pytest
import scipy.sparse as sp
from scipy.optimize import lsq_linear

from bench.compensation_room import bilinear_warp_matrix
from imaging.calibration.planar import apply_homography, content_to_table
from coordinator.compensation.capture_feed import transport_while_capturing
from imaging.compensation.errors import CompensationError
from imaging.compensation.geometry import (
    camera_target,
    choose_spacing,
    content_to_camera,
    edge_energy,
    inscribed_region,
    psf_profile,
    psf_radius,
)
from coordinator.compensation.image_param import (
    decode_image_param,
    encode_image_array,
    encode_image_param,
    prepare_image,
)
from imaging.compensation.patches import camera_patch_labels, patch_labels, patch_layouts, patch_response
from imaging.compensation.ridge import RidgeProblem, best_scale
from imaging.compensation.solver import solve
from imaging.compensation.synthetic import simulate_captures, synthetic_rig, synthetic_transport
from imaging.compensation.transport import DotGrid, transport_error, transport_from_captures, transport_windows
from coordinator.jobs import JobError
from protos.spaces import lut_lookup, warp_content


def _map(H: np.ndarray, x: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``(x, y)`` arrays through ``H`` (planar's apply_homography takes (N, 2) points)."""
    x, y = np.broadcast_arrays(np.asarray(x, np.float64), np.asarray(y, np.float64))
    out = apply_homography(H, np.stack([x.ravel(), y.ravel()], axis=1))
    return out[:, 0].reshape(x.shape), out[:, 1].reshape(x.shape)

POSE = np.array([[0.52, 0.03, 12.0], [-0.02, 0.55, 9.0], [1e-5, 2e-5, 1.0]])


def test_the_nodes_output_is_its_bilinear_lookup_then_gain_and_lut():
    """What the jobs render for a projector (:func:`protos.spaces.warp_content`, e.g. the baseline's frames)
    against the lookup matrix of the ground-truth transport followed by the LUT."""
    rng = np.random.default_rng(1)
    content = rng.random((40, 60, 3)).astype(np.float32)
    size = (48, 36)
    B = bilinear_warp_matrix(POSE, size, (60, 40))
    warped = (B @ content.reshape(-1, 3)).reshape(36, 48, 3)
    lut = np.stack([np.linspace(0, 1, 1024) ** (1 / g) for g in (2.0, 2.2, 2.4)]).astype(np.float32)
    out = warp_content(content, POSE, size, lut=lut, gain=0.8)
    ref = lut_lookup(lut, warped, gain=0.8)
    assert out.shape == (36, 48, 3) and out.dtype == np.uint8
    # the same float lookup; warp_content rounds the warped values to float32 before the LUT: a level at most apart
    assert np.abs(out.astype(int) - ref.astype(int)).max() <= 1
    assert np.mean(out != ref) < 0.001
    # cv2's INTER_LINEAR interpolates with 1/32-pixel weights: within a level of the exact lookup
    cv = cv2.warpPerspective(content, POSE, size, flags=cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT, borderValue=0)
    assert np.abs(out.astype(int) - lut_lookup(lut, cv, gain=0.8).astype(int)).max() <= 1
    # LUT off: the warped values themselves; grey content is replicated to three channels
    plain = warp_content(content[:, :, 0], POSE, size, apply_lut=False)
    assert np.array_equal(plain[:, :, 0], plain[:, :, 2])
    assert np.abs(plain[:, :, 0].astype(int) - np.rint(255 * warped[:, :, 0]).astype(int)).max() <= 1


def test_bilinear_matrix_matches_cv2_warp_and_rows_sum_to_one_inside():
    content = np.random.default_rng(2).random((30, 50)).astype(np.float32)
    size = (40, 30)
    B = bilinear_warp_matrix(POSE, size, (50, 30))
    mine = (B @ content.ravel()).reshape(30, 40)
    ref = cv2.warpPerspective(content, POSE, size, flags=cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT, borderValue=0)
    assert np.abs(mine - ref).max() < 0.02
    rows = np.asarray(B.sum(axis=1)).ravel().reshape(30, 40)
    v, u = np.mgrid[0:30, 0:40]
    x, y = _map(np.linalg.inv(POSE), u, v)
    inside = (x >= 0) & (x <= 49) & (y >= 0) & (y <= 29)
    assert np.allclose(rows[inside], 1.0)


def test_choose_spacing_is_the_smallest_the_transport_accepts():
    H = np.array([[1.3, 0.05, 20.0], [0.02, 1.25, 15.0], [1e-5, 0.0, 1.0]])
    content, camera = (60, 80), (130, 160)
    for radius in (1, 2, 3):
        s = choose_spacing(H, content, camera, radius)
        black = np.zeros(camera, np.float32)
        for spacing, ok in ((s, True), (s - 1, False)):
            if spacing < 1:
                continue
            grid = DotGrid(content[1], content[0], spacing)
            caps = (np.zeros(camera, np.float32) for _ in range(len(grid)))
            if ok:
                transport_from_captures(caps, black, grid=grid, homography=H, radius=radius)
            else:
                with pytest.raises(ValueError, match="too small"):
                    transport_from_captures(caps, black, grid=grid, homography=H, radius=radius)
    assert choose_spacing(H, content, camera, 2, guard=3) > choose_spacing(H, content, camera, 2)


def test_inscribed_region_lies_inside_the_content_and_fills_most_of_it():
    # a camera looking down at a slight angle: the content's outline is a mild trapezoid
    H = np.array([[0.9, 0.01, 40.0], [-0.005, 0.95, 60.0], [2e-5, 1e-5, 1.0]])
    size, camera = (300, 150), (300, 420)
    rows, cols = inscribed_region(H, size, camera, margin=0)
    Hi = np.linalg.inv(H)
    ys, xs = np.mgrid[rows, cols]
    x, y = _map(Hi, xs.ravel(), ys.ravel())
    assert x.min() >= -0.5 and y.min() >= -0.5 and x.max() <= 299.5 and y.max() <= 149.5
    # brute force: camera pixels whose centre maps inside the content
    ys, xs = np.mgrid[0:camera[0], 0:camera[1]]
    x, y = _map(Hi, xs.ravel(), ys.ravel())
    inside = np.sum((x >= -0.5) & (y >= -0.5) & (x <= 299.5) & (y <= 149.5))
    area = (rows.stop - rows.start) * (cols.stop - cols.start)
    assert 0.93 * inside < area <= inside
    r2, c2 = inscribed_region(H, size, camera, margin=5)
    assert r2.start == rows.start + 5 and c2.stop == cols.stop - 5
    with pytest.raises(CompensationError, match="too little"):
        inscribed_region(H, (5, 5), camera)


def test_patch_labels_cut_the_frame_and_mark_edge_bands():
    lab = patch_labels((40, 30), (3, 4), border=0)
    assert lab.shape == (30, 40) and set(np.unique(lab)) == set(range(12))
    assert lab[0, 0] == 0 and lab[-1, -1] == 11 and lab[0, -1] == 3
    counts = np.bincount(lab.ravel())
    assert counts.min() >= 90 and counts.max() <= 110
    edged = patch_labels((40, 30), (3, 4), border=2)
    assert (edged[:2] == -1).all() and (edged[:, -2:] == -1).all()
    inner = edged >= 0
    assert np.array_equal(edged[inner], lab[inner])
    # every remaining pixel is at least 2 px from a pixel of another patch
    for k in range(12):
        m = (edged == k).astype(np.uint8)
        grown = cv2.dilate(m, np.ones((3, 3), np.uint8), iterations=1).astype(bool)
        assert set(np.unique(lab[grown])) == {k}
    with pytest.raises(ValueError):
        patch_labels((5, 5), (4, 4))


def test_patch_layouts_show_every_level_repeatedly():
    levels = np.linspace(0.05, 0.95, 15)
    layouts = patch_layouts(levels, 16, 2, seed=3)
    shown = np.concatenate(layouts)
    assert len(layouts) == 2 and all(len(x) == 16 for x in layouts)
    for v in levels:
        assert np.sum(shown == v) >= 2


def test_patch_response_recovers_a_response_through_a_homography_and_fall_off():
    """A synthetic projector -> camera: fall-off across the image, gamma response, blur at patch edges."""
    size, grid = (64, 48), (3, 4)
    gamma = np.array([2.0, 2.2, 2.4])
    black_level = 0.01
    H = np.array([[2.1, 0.1, 10.0], [0.05, 2.0, 8.0], [1e-4, 0.0, 1.0]])  # projector -> camera
    cam = (120, 160)
    fall = np.linspace(0.5, 1.0, cam[1])[None, :, None] * np.ones((cam[0], 1, 1))

    def capture(frame_levels: np.ndarray) -> np.ndarray:
        lum = black_level + (1 - black_level) * frame_levels[:, :, None] ** gamma
        img = cv2.warpPerspective(lum.astype(np.float32), H, cam[::-1], flags=cv2.INTER_LINEAR)
        img = cv2.GaussianBlur(img, (0, 0), 1.0)
        return (img * fall).astype(np.float32)

    shown = patch_labels(size, grid, border=0)
    labels = patch_labels(size, grid, border=3)
    interior = np.linspace(0.1, 0.9, 9)
    layouts = patch_layouts(interior, 12, 2, seed=0)
    caps = [capture(layout[shown]) for layout in layouts]
    black = capture(np.zeros(size[::-1]))
    white = capture(np.ones(size[::-1]))
    cam_labels = camera_patch_labels(labels, H, cam)
    assert np.array_equal(cam_labels, cv2.warpPerspective(labels.astype(np.float32), H, cam[::-1], flags=cv2.INTER_NEAREST,
                                                          borderValue=-1).astype(np.int32))
    valid = (white - black).mean(axis=2) > 0.05
    lv, rho = patch_response(caps, layouts, white=white, black=black, camera_labels=cam_labels, valid=valid)
    assert len(lv) >= 18
    expected = lv[:, None] ** gamma[None, :]
    assert np.abs(rho - expected).max() < 2e-3
    # without the edge bands, blur from neighbouring patches biases the result
    lv2, rho2 = patch_response(caps, layouts, white=white, black=black,
                               camera_labels=cv2.warpPerspective(shown.astype(np.float32), H, cam[::-1],
                                                                 flags=cv2.INTER_NEAREST, borderValue=-1).astype(np.int32),
                               valid=valid)
    assert np.abs(rho2 - lv2[:, None] ** gamma[None, :]).max() > 5 * np.abs(rho - expected).max()


def test_image_parameters_round_trip(tmp_path):
    rng = np.random.default_rng(4)
    rgb8 = rng.integers(0, 256, (20, 30, 3), dtype=np.uint8)
    rgb16 = rng.integers(0, 65536, (20, 30, 3), dtype=np.uint16)
    grey = rng.random((20, 30)).astype(np.float32)
    cv2.imwrite(str(tmp_path / "a.png"), cv2.cvtColor(rgb8, cv2.COLOR_RGB2BGR))
    cv2.imwrite(str(tmp_path / "b.png"), cv2.cvtColor(rgb16, cv2.COLOR_RGB2BGR))
    np.save(tmp_path / "c.npy", grey)
    for f, ref in (("a.png", rgb8), ("b.png", rgb16), ("c.npy", grey[:, :, None])):
        img, name = decode_image_param(json.loads(json.dumps(encode_image_param(tmp_path / f))))
        assert name == f and img.dtype == ref.dtype and np.array_equal(img, ref)
    img, _ = decode_image_param(encode_image_array(rgb8))
    assert np.array_equal(img, rgb8)
    img, name = decode_image_param(json.loads(json.dumps(encode_image_array(grey, "g.png"))))
    assert name == "g.npy" and img.dtype == np.float32 and np.array_equal(img, grey[:, :, None])
    with pytest.raises(CompensationError, match="corrupt"):
        decode_image_param({"name": "x.png", "data": "not base64!"})
    bad = encode_image_param(tmp_path / "a.png")
    bad["data"] = base64.b64encode(zlib.compress(b"not an image")).decode()
    with pytest.raises(CompensationError, match="cannot read"):
        decode_image_param(bad)


def test_prepare_image_scales_to_the_content_and_decodes_srgb():
    img = np.full((60, 100, 3), 128, np.uint8)
    out = prepare_image(img, (50, 30))
    assert out.shape == (30, 50, 3) and out.dtype == np.float32 and np.allclose(out, 128 / 255)
    lin = prepare_image(img, (50, 30), srgb=True)
    assert np.allclose(lin, ((128 / 255 + 0.055) / 1.055) ** 2.4, atol=1e-6)
    grey16 = np.full((30, 50), 65535, np.uint16)
    assert np.allclose(prepare_image(grey16, (50, 30)), 1.0)


def test_camera_target_and_best_scale():
    H = np.array([[1.5, 0.0, 10.0], [0.0, 1.5, 5.0], [0.0, 0.0, 1.0]])
    img = np.zeros((20, 30), np.float32)
    img[5:15, 10:20] = 1.0
    t = camera_target(img, H, (50, 70))
    assert t.shape == (50, 70, 1)
    x, y = _map(H, np.array([15.0]), np.array([10.0]))
    assert t[int(round(y[0])), int(round(x[0])), 0] == pytest.approx(1.0)
    assert t[0, 0, 0] == 0.0
    rng = np.random.default_rng(5)
    p, q = rng.random(100), rng.random(100)
    a = best_scale(p, q)
    ref = np.linalg.lstsq(p[:, None], q, rcond=None)[0][0]
    assert a == pytest.approx(ref)
    assert best_scale(p, -q) == 0.0 and best_scale(np.zeros(3), q[:3]) == 0.0


def test_content_to_camera_reads_the_calibration(tmp_path):
    H_tc = np.array([[0.45, 0.01, 320.0], [0.0, -0.46, 240.0], [0.0, 0.0, 1.0]])
    (tmp_path / "calibration").mkdir()
    doc = {"content_size": [300, 150], "table_mm": [1200, 600],
           "cameras": [{"camera": 0, "size": [648, 486], "table_to_camera": H_tc.tolist()}]}
    (tmp_path / "calibration" / "cameras.json").write_text(json.dumps(doc))
    H, size = content_to_camera(tmp_path, (300, 150))
    ref = H_tc @ content_to_table((300, 150), (1200, 600))
    assert np.allclose(H, ref / ref[2, 2]) and size == (648, 486)
    with pytest.raises(CompensationError, match="calibrated for content 300x150"):
        content_to_camera(tmp_path, (600, 300))
    with pytest.raises(CompensationError, match="camera 1 has no table mapping"):
        content_to_camera(tmp_path, (300, 150), camera=1)
    with pytest.raises(CompensationError, match="run `shadowless calibrate` first"):
        content_to_camera(tmp_path / "nowhere", (300, 150))


def test_recovering_while_capturing_equals_recovering_afterwards():
    rig = synthetic_rig(4, content_shape=(24, 32), radius=2, seed=1)
    L = synthetic_transport(rig)
    grid = DotGrid(32, 24, 5)
    black = np.full((24, 32), 0.01, np.float32)
    caps = list(simulate_captures(L, grid, (24, 32), black=0.01, read_noise=1e-3, rng=np.random.default_rng(0)))
    direct = transport_from_captures(iter(caps), black, grid=grid, radius=2)

    class Ctx:
        async def compute(self, fn, *a, **k):
            return await asyncio.to_thread(fn, *a, **k)

    async def shots():
        for c in caps:
            # not a wait: yields to the loop between captures, as a camera's await does, so the feed
            # consumes each one while the generator is suspended (nothing else makes it suspend)
            await asyncio.sleep(0)
            yield c

    fed = asyncio.run(transport_while_capturing(Ctx(), shots(), black, grid=grid, radius=2))
    assert transport_error(fed, direct) == 0.0
    assert transport_error(direct, L) < 0.05

    async def short():
        for c in caps[:3]:
            yield c

    with pytest.raises(JobError, match="needs 25 captures"):
        asyncio.run(transport_while_capturing(Ctx(), short(), black, grid=grid, radius=2))


def _brute_force_missing(c: float, p: float, r: int, *, trials: int = 12, projectors: int = 25, sub: int = 20,
                         seed: int = 0) -> float:
    """Squared light of one content pixel outside a (2r+1)^2 camera window, by explicit projector pixels.

    Each of ``projectors`` lattices (pitch ``p`` camera px, random phase) lights boxes ``p`` wide, weighted
    bilinearly by the distance of their centre to the content pixel (``1 - |d|/c`` per axis); the
    light is integrated over camera pixels (``sub`` x ``sub`` samples each) around a content pixel
    centre at a random sub-pixel position. Returns the outside share of the squared light summed
    over the trials (a projector coarser than the content lights some content pixels not at all).
    """
    rng = np.random.default_rng(seed)
    n = int(np.ceil(c + p)) + r + 2
    out = []
    for _ in range(trials):
        u, v = rng.uniform(-0.5, 0.5, 2)
        fine = (np.arange(-n * sub, n * sub) + 0.5) / sub      # sample positions, camera px, centre at 0
        img = np.zeros((fine.size, fine.size))
        centres = np.arange(-np.ceil((c + p) / p) - 1, np.ceil((c + p) / p) + 2) * p
        for phase in rng.uniform(0, p, (projectors, 2)):     # the rig: every projector, its own phase
            for cy in centres + phase[1]:
                wy = max(0.0, 1 - abs(cy - v) / c)
                if wy == 0:
                    continue
                iny = np.abs(fine - cy) <= p / 2
                for cx in centres + phase[0]:
                    wx = max(0.0, 1 - abs(cx - u) / c)
                    if wx == 0:
                        continue
                    inx = np.abs(fine - cx) <= p / 2
                    img[np.ix_(iny, inx)] += wx * wy
        pix = img.reshape(2 * n, sub, 2 * n, sub).sum(axis=(1, 3))
        e = pix ** 2
        k = np.arange(-n, n)
        out.append((e.sum() - e[np.ix_(np.abs(k) <= r, np.abs(k) <= r)].sum(), e.sum()))
    # over many content pixels (phases), as the Frobenius norm of L adds them up
    return float(sum(o for o, _ in out) / sum(t for _, t in out))


def test_psf_radius_holds_the_light_of_explicit_projector_pixels():
    x, f = psf_profile(1.2, 2.0, blur=0.5)
    assert f.sum() == pytest.approx(1.0) and f.min() >= 0 and abs(float(np.sum(x * f))) < 1e-6
    for c, q in ((0.95, 0.40), (1.7, 0.9), (0.5, 1.0)):
        H = np.array([[c, 0.0, 5.0], [0.0, c, 7.0], [0.0, 0.0, 1.0]])        # content -> camera
        pose = np.array([[q, 0.0, 1.0], [0.0, q, 2.0], [0.0, 0.0, 1.0]])      # content -> projector
        r = psf_radius(H, [pose], (100, 50), tolerance=1e-4)
        p = c / q
        assert _brute_force_missing(c, p, r) < 3e-4, (c, p, r)
        assert _brute_force_missing(c, p, r - 1) > 1e-4 or r == 1, (c, p, r)
    # the typical (median) projector decides; blur needs more
    H = np.diag([1.0, 1.0, 1.0])
    fine, coarse = np.diag([1.0, 1.0, 1.0]), np.diag([0.25, 0.25, 1.0])
    assert psf_radius(H, [coarse, coarse, fine], (100, 50)) == psf_radius(H, [coarse], (100, 50))
    assert psf_radius(H, [fine, fine, coarse], (100, 50)) == psf_radius(H, [fine], (100, 50)) < psf_radius(H, [coarse], (100, 50))
    assert psf_radius(H, [fine], (100, 50), blur=1.5) > psf_radius(H, [fine], (100, 50))


def test_edge_energy_is_the_light_on_the_windows_outer_ring():
    H = np.array([[1.4, 0.02, 6.0], [0.01, 1.35, 5.0], [0.0, 0.0, 1.0]])
    content, camera, R = (20, 30), (45, 60), 2
    _, rows, valid = transport_windows(H, content, camera, R)
    rng = np.random.default_rng(7)
    values = rng.random(rows.shape)
    k = 2 * R + 1
    dy, dx = np.divmod(np.arange(k * k), k)
    ring = (np.abs(dx - R) == R) | (np.abs(dy - R) == R)
    values[:, ring] *= 0.1
    cols = np.repeat(np.arange(rows.shape[0])[:, None], k * k, axis=1)
    L = sp.csr_matrix((values[valid], (rows[valid], cols[valid])), shape=(camera[0] * camera[1], rows.shape[0]))
    expected = (values[:, ring][valid[:, ring]] ** 2).sum() / (values[valid] ** 2).sum()
    assert edge_energy(L, H, content, camera, R) == pytest.approx(expected, rel=1e-9)
    values[:, ring] = 0
    L0 = sp.csr_matrix((values[valid], (rows[valid], cols[valid])), shape=L.shape)
    assert edge_energy(L0, H, content, camera, R) == 0.0


def test_ridge_problem_solves_the_penalised_bounded_least_squares():
    rng = np.random.default_rng(8)
    L = sp.random(60, 40, density=0.15, random_state=9, dtype=np.float64).tocsr().astype(np.float32)
    target = rng.random((60, 1)).astype(np.float32) * 1.5
    prior = rng.random((40, 1)).astype(np.float32)
    for mu in (0.0, 0.05, 1.0):
        problem = RidgeProblem(L, mu)
        lam = mu * problem.data.lipschitz()
        assert problem.lam == pytest.approx(lam)
        res = solve(problem.op, problem.target(target, prior), x0=prior, tol=1e-12, gap_tol=0, pg_tol=0, max_iter=5000)
        dense = np.vstack([L.toarray(), np.sqrt(lam) * np.eye(40)])
        ref = lsq_linear(dense, np.concatenate([target[:, 0], np.sqrt(lam) * prior[:, 0]]), bounds=(0, 1),
                         tol=1e-12, max_iter=10000)
        f = lambda x: float(np.sum((L @ x - target[:, 0]) ** 2) + lam * np.sum((x - prior[:, 0]) ** 2))  # noqa: E731
        assert f(res.x.ravel()) == pytest.approx(f(ref.x), rel=1e-4, abs=1e-6)
        assert problem.data_objective(res.x, target) == pytest.approx(float(np.sum((L @ res.x.ravel() - target[:, 0]) ** 2)),
                                                                      rel=1e-5)
    # a stronger penalty keeps the solution nearer the prior
    d = [np.abs(solve(RidgeProblem(L, m).op, RidgeProblem(L, m).target(target, prior), x0=prior, max_iter=2000).x.ravel()
                - prior[:, 0]).sum() for m in (0.0, 0.1, 10.0)]
    assert d[0] > d[1] > d[2]
