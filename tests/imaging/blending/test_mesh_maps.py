"""A mesh rig's alpha maps fitted by least squares: the sampling matrix is the node's own sampling, and the
fitted maps give the target where sampled maps cannot (a texel that lights two surfaces far apart)."""
from __future__ import annotations

import numpy as np

from imaging.blending.mesh_maps import bilinear_matrix, fit_alpha_maps, footprint_matrix, map_scale_for
from imaging.blending.predict import sample_map


def test_the_sampling_matrix_is_the_nodes_bilinear_sampling():
    rng = np.random.default_rng(3)
    size, msize = (37, 23), (10, 6)
    values = rng.random((msize[1], msize[0])).astype(np.float32)
    u = np.stack([rng.uniform(-0.5, size[0] - 0.5, 500), rng.uniform(-0.5, size[1] - 0.5, 500)], axis=-1)
    u[:4] = [[-0.5, -0.5], [size[0] - 0.5, size[1] - 0.5], [0.0, 11.0], [36.4, 0.2]]     # the clamped edges
    B = bilinear_matrix(u, size, msize)
    want = sample_map(values, u.reshape(-1, 1, 2), size)[:, 0]
    assert np.allclose(B @ values.ravel(), want, atol=1e-5)
    assert np.allclose(B.sum(axis=1), 1.0)


def test_a_cells_footprint_is_the_mean_of_the_pixels_it_covers_and_the_map_scale_follows_it():
    # an affine placement: grid cell (gx, gy) at projector pixel (3 gx + 0.4 gy + 5, 0.5 gy + 4), so a cell spans
    # 3 pixels along x; counted by brute force, 16 points per cell snapped to pixel centres
    h, w, size = 20, 30, (100, 20)
    gy, gx = np.mgrid[0:h, 0:w].astype(np.float64)
    coords = np.stack([3.0 * gx + 0.4 * gy + 5.0, 0.5 * gy + 4.0], axis=-1)
    coords[0, 0] = np.nan                                            # not reached: its neighbours go one-sided
    rows = np.flatnonzero(np.isfinite(coords).all(axis=-1).ravel())
    alpha = np.random.default_rng(1).random((size[1], size[0]))
    got = footprint_matrix(coords, rows, size, size, samples=4) @ alpha.ravel()
    o = (np.arange(4) + 0.5) / 4 - 0.5
    want = []
    for r in rows:
        y, x = divmod(int(r), w)
        vals = [alpha[int(np.clip(np.floor(0.5 * (y + b) + 4.0 + 0.5), 0, size[1] - 1)),
                      int(np.clip(np.floor(3.0 * (x + a) + 0.4 * (y + b) + 5.0 + 0.5), 0, size[0] - 1))]
                for a in o for b in o]
        want.append(np.mean(vals))
    assert np.allclose(got, want, atol=1e-9)
    # with no samples it is the node's bilinear sampling at the cell's centre
    point = footprint_matrix(coords, rows, size, size, samples=0)
    assert np.allclose(point.toarray(), bilinear_matrix(coords.reshape(-1, 2)[rows], size, size).toarray())
    # a cell spans sqrt(3 * 0.5) = 1.22 pixels: maps at full resolution; a placement 3 times as coarse: 1/4
    assert map_scale_for({"a": coords}) == 1
    assert map_scale_for({"a": 3.0 * coords}) == 4 and map_scale_for({"a": 3.0 * coords}, coarsest=8) == 4


def _light(T: dict, maps: dict, coords: dict, size) -> np.ndarray:
    return sum(T[s] * sample_map(maps[s], coords[s], size) for s in T)


def test_fitted_maps_meet_the_target_where_a_texel_spans_two_surfaces():
    # two projectors over a 32 x 48 grid; the second sees the grid's halves swapped (two surfaces that meet in
    # its image: its texels at the seam light points far apart, whose light differs threefold)
    h, w = 32, 48
    size = (w, h)
    gy, gx = np.mgrid[0:h, 0:w].astype(np.float64)
    a = np.stack([gx, gy], axis=-1)
    b = np.stack([(gx + w // 2 + 0.37) % w, gy], axis=-1)
    T = {"a": (0.6 + 0.2 * np.sin(gy / 5.0))[..., None] * (1.0 - 0.3 * gx / w)[..., None] * np.array([1.0, 0.95, 0.9]),
         "b": (0.3 + 0.6 * gx / w)[..., None] * (1.0 + 0.1 * np.cos(gy / 4.0))[..., None] * np.ones(3)}
    T = {s: v.astype(np.float32) for s, v in T.items()}
    coords = {"a": a, "b": b}
    target = np.full((h, w, 3), 0.5, np.float32)
    S = T["a"] + T["b"]
    share = {s: (target / S).astype(np.float32) for s in T}          # equal weights: r Q
    msize = (w // 4, h // 4)

    def sampled(s):            # the planar way: the wanted gain at each texel's centre
        tx = (np.arange(msize[0]) + 0.5) * 4 - 0.5
        ty = (np.arange(msize[1]) + 0.5) * 4 - 0.5
        out = np.empty((msize[1], msize[0], 3), np.float32)
        for j, y in enumerate(ty):
            for i, x in enumerate(tx):
                d = np.hypot(coords[s][..., 0] - x, coords[s][..., 1] - y)
                out[j, i] = share[s][np.unravel_index(np.argmin(d), d.shape)]
        return out

    initial = {s: sampled(s) for s in T}
    covered = np.ones((h, w), bool)
    before = np.abs(_light(T, initial, coords, size) / target - 1.0)
    fitted = fit_alpha_maps(T, coords, {s: size for s in T}, initial, share, target, covered)
    after = np.abs(_light(T, fitted, coords, size) / target - 1.0)
    assert np.percentile(before, 99) > 0.1
    assert np.percentile(after, 99) < 0.25 * np.percentile(before, 99) and np.median(after) < 0.005, \
        (np.percentile(before, 99), np.percentile(after, 99), np.median(after))
    for s in T:
        assert fitted[s].shape == initial[s].shape and fitted[s].dtype == np.float32
        assert fitted[s].min() >= 0.0 and fitted[s].max() <= 1.0
