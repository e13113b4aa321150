"""The watchdog's gain fit against independent references: a brute-force search of its objective,
the gains a synthetic rig was built with (with noise, a hand, a dead lamp), and the grid warps
against per-texel bilinear sampling written out by hand."""
from __future__ import annotations

import numpy as np
import pytest

from imaging.blending.watchdog import (camera_grid_to_camera, content_on_grid, fit_changes, fit_gains, gain_objective,
                                       grid_mean, maps_on_grid, predicted_light, steady_cells)
from protos.blend import BlendMaps

H, W = 36, 48


def footprints(n: int, seed: int = 0) -> list[np.ndarray]:
    """n projectors' light (H, W, 3) float32: offset, partly overlapping soft discs with a fall-off
    and a per-channel white point."""
    rng = np.random.default_rng(seed)
    yy, xx = np.mgrid[0:H, 0:W].astype(np.float64)
    out = []
    for i in range(n):
        cx, cy = W * (0.3 + 0.4 * rng.random()), H * (0.3 + 0.4 * rng.random())
        r2 = ((xx - cx) / (0.5 * W)) ** 2 + ((yy - cy) / (0.5 * H)) ** 2
        light = np.clip(1.2 - r2, 0.0, None) * (0.8 + 0.4 * rng.random())
        tint = 1.0 + 0.1 * (rng.random(3) - 0.5)
        out.append((light[:, :, None] * tint[None, None, :] * 0.2).astype(np.float32))
    return out


def test_the_fit_is_the_brute_force_minimum_of_its_objective():
    cols = footprints(3, seed=1)
    truth = np.array([0.9, 0.55, 1.1])
    rng = np.random.default_rng(2)
    capture = sum(g * c for g, c in zip(truth, cols))
    capture = (capture * (1.0 + 0.01 * rng.standard_normal(capture.shape))).astype(np.float32)
    fit = fit_gains(capture, cols, robust=False)
    # the objective written out again: relative residuals over the texels with light, and the prior
    P = np.stack([c.astype(np.float64) for c in cols], axis=-1)
    s = P.sum(axis=-1)
    keep = s > 0.02 * s.max()
    A, b = P[keep] / s[keep][:, None], capture.astype(np.float64)[keep] / s[keep]

    def objective(G: np.ndarray) -> np.ndarray:      # (K, 3) gains -> (K,)
        r = G @ A.T - b
        return np.mean(r * r, axis=1) + fit.prior * np.sum((G - 1.0) ** 2, axis=1)

    probe = np.array([[0.8, 0.6, 1.2]])
    assert np.isclose(objective(probe)[0], gain_objective(probe[0], capture, cols, prior=fit.prior))
    # brute force: a grid search over the three gains, refined around the best point
    centre, step = np.ones(3), 0.1
    for _ in range(4):
        G = np.stack(np.meshgrid(*[c + step * np.arange(-10, 11) for c in centre], indexing="ij"), -1).reshape(-1, 3)
        G = G[np.all(G >= 0, axis=1)]
        centre, step = G[np.argmin(objective(G))], step / 10
    assert np.allclose(fit.gains, centre, atol=2e-4), (fit.gains, centre)
    assert objective(fit.gains[None])[0] <= objective(centre[None])[0] + 1e-12
    # and both are the truth within the noise
    assert np.allclose(fit.gains, truth, atol=0.02), fit.gains


def test_gains_of_a_larger_rig_with_noise_a_hand_and_a_dead_lamp():
    n = 9
    cols = footprints(n, seed=3)
    truth = np.ones(n)
    truth[2], truth[5] = 0.5, 0.0
    rng = np.random.default_rng(4)
    clean = sum(g * c for g, c in zip(truth, cols))
    capture = clean * (1.0 + 0.01 * rng.standard_normal(clean.shape))
    # a hand: a blob of cells 70 % darker (it blocks some projectors' light, and the model knows nothing of it)
    yy, xx = np.mgrid[0:H, 0:W]
    hand = (xx - 20) ** 2 + (yy - 15) ** 2 < 36
    capture[hand] *= 0.3
    capture = capture.astype(np.float32)
    fit = fit_gains(capture, cols)
    assert np.max(np.abs(fit.gains - truth)) < 0.05, (fit.gains, truth)
    assert fit.inliers < 0.97           # the hand's cells were given no weight
    assert np.all(fit.stderr < 0.05) and np.isfinite(fit.condition)
    # without the robust weights the hand drags gains down by more
    plain = fit_gains(capture, cols, robust=False)
    assert np.max(np.abs(plain.gains - truth)) > np.max(np.abs(fit.gains - truth))


def test_identical_footprints_are_reported_as_ill_conditioned():
    base = footprints(1, seed=5)[0]
    cols = [base, base * 1.0001, footprints(1, seed=6)[0]]
    fit = fit_gains(sum(cols), cols, robust=False)
    assert fit.condition > 1e3
    # the prior keeps the two indistinguishable gains at 1 rather than anywhere on their sum's line
    assert np.allclose(fit.gains, 1.0, atol=0.01)
    # an independent projector is well measured: its uncertainty is far below the twins'
    assert fit.stderr[2] < fit.stderr[0]


def test_refusals():
    cols = footprints(2)
    with pytest.raises(ValueError, match="like the capture"):
        fit_gains(np.zeros((H, W + 1, 3), np.float32), cols)
    with pytest.raises(ValueError, match="at least one"):
        fit_gains(np.zeros((H, W, 3), np.float32), [])
    with pytest.raises(ValueError, match="cannot fit"):
        fit_gains(np.zeros((H, W, 3), np.float32), [np.zeros((H, W, 3), np.float32)] * 2)


def bilinear(img: np.ndarray, x: float, y: float, *, clamp: bool) -> np.ndarray:
    """img (h, w, C) at (x, y), texel centres at integers; clamped at the edges or 0 outside."""
    h, w = img.shape[:2]
    x0, y0 = int(np.floor(x)), int(np.floor(y))
    fx, fy = x - x0, y - y0
    out = np.zeros(img.shape[2])
    for dy, dx, wt in ((0, 0, (1 - fx) * (1 - fy)), (0, 1, fx * (1 - fy)), (1, 0, (1 - fx) * fy), (1, 1, fx * fy)):
        yy, xx = y0 + dy, x0 + dx
        if clamp:
            out += wt * img[min(max(yy, 0), h - 1), min(max(xx, 0), w - 1)]
        elif 0 <= yy < h and 0 <= xx < w:
            out += wt * img[yy, xx]
    return out


def test_maps_and_content_on_the_grid_match_per_texel_sampling():
    rng = np.random.default_rng(7)
    maps = BlendMaps(rng.random((9, 16, 3)).astype(np.float32), rng.random((9, 16)).astype(np.float32))
    proj = (64, 36)
    shape = (12, 20)
    scale = 4.0
    cam_to_proj = np.array([[0.8, 0.05, -3.0], [-0.02, 0.75, 2.0], [1e-4, 0.0, 1.0]])
    g2p = cam_to_proj @ camera_grid_to_camera(scale)
    alpha, beta, inside = maps_on_grid(maps, g2p, proj, shape)
    mw, mh = maps.size
    for i, j in [(0, 0), (5, 7), (11, 19), (3, 12)]:
        u = g2p @ np.array([j, i, 1.0])
        px, py = u[0] / u[2], u[1] / u[2]
        # projector px -> map texel: the inverse of (j + .5) W / w - .5
        mx, my = (px + 0.5) * mw / proj[0] - 0.5, (py + 0.5) * mh / proj[1] - 0.5
        assert np.allclose(alpha[i, j], bilinear(maps.alpha, mx, my, clamp=True), atol=2e-3)
        assert np.allclose(beta[i, j], bilinear(maps.beta[:, :, None], mx, my, clamp=True)[0], atol=2e-3)
        assert inside[i, j] == (-0.5 <= px <= proj[0] - 0.5 and -0.5 <= py <= proj[1] - 0.5)
    content = rng.random((30, 50, 3)).astype(np.float32)
    g2c = np.array([[2.1, 0.1, 1.0], [0.0, 2.0, -2.0], [0.0, 0.0, 1.0]])
    seen = content_on_grid(content, g2c, shape)
    for i, j in [(0, 0), (4, 9), (11, 19), (7, 2)]:
        q = g2c @ np.array([j, i, 1.0])
        assert np.allclose(seen[i, j], bilinear(content, q[0] / q[2], q[1] / q[2], clamp=False), atol=2e-3)


def test_predicted_light_and_grid_mean():
    white = np.full((2, 2, 3), 0.5, np.float32)
    black = np.full((2, 2, 3), 0.01, np.float32)
    value = np.full((2, 2, 3), 0.8, np.float32)
    alpha = np.full((2, 2, 3), 0.5, np.float32)
    beta = np.full((2, 2), 0.1, np.float32)
    assert np.allclose(predicted_light(white, black, value, alpha, beta), 0.5 * (0.8 * 0.5 + 0.1) + 0.01)
    assert np.allclose(predicted_light(white, black, value), 0.5 * 0.8 + 0.01)
    img = np.arange(8 * 12 * 3, dtype=np.float32).reshape(8, 12, 3)
    assert np.allclose(grid_mean(img, (2, 3)), img.reshape(2, 4, 3, 4, 3).mean(axis=(1, 3)))


def test_changed_lamps_are_found_where_the_dense_fit_cannot_separate_the_gains():
    """Sixteen projectors with nearly the same footprint: one capture cannot give sixteen gains, but
    it can say which one or two lamps moved. Checked against an exhaustive search over the single
    changes, each gain on a fine grid."""
    n = 16
    rng = np.random.default_rng(9)
    yy, xx = np.mgrid[0:H, 0:W].astype(np.float64)
    cols = []
    for i in range(n):          # the same disc, each shifted by at most a cell or two, its own fall-off
        cx, cy = W / 2 + rng.uniform(-1.5, 1.5), H / 2 + rng.uniform(-1.5, 1.5)
        r2 = ((xx - cx) / (0.6 * W)) ** 2 + ((yy - cy) / (0.6 * H)) ** 2
        light = np.clip(1.0 - r2 * (0.5 + 0.3 * rng.random()), 0.0, None)
        cols.append((light[:, :, None] * np.ones(3) * 0.05).astype(np.float32))
    truth = np.ones(n)
    truth[3] = 0.5
    capture = sum(g * col for g, col in zip(truth, cols))
    capture = (capture * (1.0 + 0.005 * rng.standard_normal(capture.shape))).astype(np.float32)
    dense = fit_gains(capture, cols)
    assert dense.condition > 100 and np.max(np.abs(dense.gains - truth)) > 0.1, dense
    found = fit_changes(capture, cols)
    assert found.changed == (3,) and abs(found.gains[3] - 0.5) < 0.02, found
    assert np.all(np.delete(found.gains, 3) == 1.0)
    # brute force: every single change, its gain on a grid (0.01, then 0.001 around the best), by the same
    # objective without the prior
    def obj(j: int, g: float) -> float:
        return gain_objective(np.where(np.arange(n) == j, g, 1.0), capture, cols, prior=0.0)

    coarse = min((obj(j, g), j, g) for j in range(n) for g in np.arange(0.3, 0.71, 0.01))
    best = min((obj(coarse[1], g), coarse[1], g) for g in coarse[2] + np.arange(-0.01, 0.0101, 0.001))
    assert best[1] == 3 and abs(best[2] - found.gains[3]) < 0.002, best
    # nothing changed: nothing found; two changed: both
    assert fit_changes((sum(cols) * 1.0).astype(np.float32), cols).changed == ()
    truth[11] = 0.0
    two = fit_changes(sum(g * col for g, col in zip(truth, cols)).astype(np.float32), cols)
    assert two.changed == (3, 11) and abs(two.gains[3] - 0.5) < 0.02 and two.gains[11] < 0.02, two
    # a baseline: what an earlier check found is held, and only a move from it is a change
    held = fit_changes(sum(g * col for g, col in zip(truth, cols)).astype(np.float32), cols,
                       baseline=np.where(np.arange(n) == 3, 0.5, 1.0))
    assert held.changed == (11,) and held.gains[3] == 0.5


def test_steady_cells_leave_out_footprint_edges():
    a = np.zeros((10, 10, 3), np.float32)
    a[:, :5] = 1.0
    steady = steady_cells([a])
    assert steady[:, :3].all() and steady[:, 7:].all() and not steady[:, 4:6].any()
