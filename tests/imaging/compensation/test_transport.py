"""Dot-grid light-transport measurement against a synthetic ground truth, and its storage."""
from __future__ import annotations

import os

import numpy as np
import pytest
import scipy.sparse as sp

from imaging.compensation import (
    DotGrid,
    TransportFileError,
    load_transport,
    save_transport,
    transport_error,
    transport_from_captures,
    transport_windows,
    transports_per_projector,
)
from imaging.compensation.synthetic import camera_noise, simulate_captures, synthetic_rig, synthetic_transport

CONTENT = (18, 22)  # (H, W)
CAMERA = (26, 30)
# content -> camera: scale ~1.1, a little rotation and perspective, shifted into the camera view
H_CC = np.array([[1.08, 0.04, 2.3], [-0.03, 1.1, 1.7], [2e-4, -1e-4, 1.0]])


@pytest.fixture(scope="module")
def rig():
    return synthetic_rig(4, content_shape=CONTENT, camera_shape=CAMERA, homography=H_CC, radius=2, seed=5)


@pytest.fixture(scope="module")
def truths(rig):
    per = synthetic_transport(rig, per_projector=True, scale=0.25)
    total = synthetic_transport(rig, scale=0.25)
    return per, total


def test_dot_grid_lights_every_pixel_once():
    grid = DotGrid(22, 18, 5)
    assert len(grid) == 25 and grid.shifts[7] == (2, 1)
    total = sum(grid.pattern(k) for k in range(len(grid)))
    assert np.array_equal(total, np.ones((18, 22), dtype=np.float32))
    dots = grid.dots(7)
    assert np.all(dots % 22 % 5 == 2) and np.all(dots // 22 % 5 == 1)
    with pytest.raises(IndexError):
        grid.dots(25)
    with pytest.raises(ValueError):
        DotGrid(0, 5, 3)


def test_windows_match_brute_force():
    base, rows, valid = transport_windows(H_CC, CONTENT, CAMERA, 1)
    h, w = CONTENT
    for j in (0, 5, w * h // 2, w * h - 1):
        x, y = j % w, j // w
        p = H_CC @ np.array([x, y, 1.0])
        bx, by = int(np.rint(p[0] / p[2])), int(np.rint(p[1] / p[2]))
        assert tuple(base[j]) == (bx, by)
        k = 0
        for dy in (-1, 0, 1):
            for dx in (-1, 0, 1):
                X, Y = bx + dx, by + dy
                inside = 0 <= X < CAMERA[1] and 0 <= Y < CAMERA[0]
                assert valid[j, k] == inside
                if inside:
                    assert rows[j, k] == Y * CAMERA[1] + X
                k += 1


def test_exact_recovery_without_noise(rig, truths):
    _, L = truths
    grid = DotGrid(CONTENT[1], CONTENT[0], 5)
    black = np.full(CAMERA, 0.013, dtype=np.float32)
    # colour captures with equal channels, plus the black level
    caps = (np.repeat(c[:, :, None], 3, axis=2) for c in simulate_captures(L, grid, CAMERA, black=black))
    est = transport_from_captures(caps, np.repeat(black[:, :, None], 3, axis=2), grid=grid, homography=H_CC, radius=2)
    assert est.shape == L.shape and est.dtype == np.float32
    assert transport_error(est, L) < 1e-6
    # the recovered PSF of every column sits inside its window
    assert abs(est - L).max() < 1e-6


def test_recovery_with_noise_has_the_expected_error(rig, truths):
    _, L = truths
    grid = DotGrid(CONTENT[1], CONTENT[0], 5)
    sigma = 2e-3
    rng = np.random.default_rng(7)
    caps = simulate_captures(L, grid, CAMERA, read_noise=sigma, rng=rng)
    black = camera_noise(np.zeros(CAMERA), read_noise=sigma, rng=rng)
    est = transport_from_captures(caps, black, grid=grid, homography=H_CC, radius=2, clip_negative=False)
    err = transport_error(est, L)
    # each entry gets the difference of two captures' noise: std sigma * sqrt(2)
    expected = sigma * np.sqrt(2 * L.nnz) / np.sqrt(np.dot(L.data, L.data))
    assert 0.7 * expected < err < 1.3 * expected
    clipped = transport_from_captures(simulate_captures(L, grid, CAMERA, read_noise=sigma, rng=rng), black, grid=grid,
                                homography=H_CC, radius=2)
    assert clipped.data.min() >= 0
    assert transport_error(clipped, L) < 1.3 * expected


def test_capture_count_does_not_depend_on_projectors(rig, truths):
    per, total = truths
    grid = DotGrid(CONTENT[1], CONTENT[0], 5)
    black = np.zeros(CAMERA, dtype=np.float32)
    one = transport_from_captures(simulate_captures(per[0], grid, CAMERA), black, grid=grid, homography=H_CC)
    four = transport_from_captures(simulate_captures(total, grid, CAMERA), black, grid=grid, homography=H_CC)
    assert transport_error(one, per[0]) < 1e-6 and transport_error(four, total) < 1e-6
    with pytest.raises(ValueError, match="needs 25 captures"):
        transport_from_captures(list(simulate_captures(total, grid, CAMERA))[:-1], black, grid=grid, homography=H_CC)


def test_per_projector_measurement_sums_to_rig(truths):
    per, total = truths
    grid = DotGrid(CONTENT[1], CONTENT[0], 5)
    black = np.zeros(CAMERA, dtype=np.float32)
    measured = transports_per_projector([simulate_captures(Li, grid, CAMERA) for Li in per], black,
                                     grid=grid, homography=H_CC, radius=2)
    assert len(measured) == 4
    for est, Li in zip(measured, per):
        assert transport_error(est, Li) < 1e-6
        assert np.array_equal(est.indptr, total.indptr)  # same window structure as the rig's L
    assert transport_error(sum(measured[1:], measured[0]), total) < 1e-6


def test_spacing_too_small_for_radius_is_refused(truths):
    _, L = truths
    grid = DotGrid(CONTENT[1], CONTENT[0], 3)
    with pytest.raises(ValueError, match="increase the spacing"):
        transport_from_captures(simulate_captures(L, grid, CAMERA), np.zeros(CAMERA, np.float32), grid=grid,
                          homography=H_CC, radius=2)


def test_shape_errors():
    grid = DotGrid(4, 3, 3)
    with pytest.raises(ValueError):
        transport_from_captures([np.zeros((3, 4))] * 9, np.zeros((3, 4, 2, 1)), grid=grid, radius=0)
    with pytest.raises(ValueError, match="shape"):
        transport_from_captures([np.zeros((5, 4))] * 9, np.zeros((3, 4)), grid=grid, radius=0)


def test_threshold_drops_small_entries(truths):
    _, L = truths
    grid = DotGrid(CONTENT[1], CONTENT[0], 5)
    est = transport_from_captures(simulate_captures(L, grid, CAMERA), np.zeros(CAMERA, np.float32), grid=grid,
                            homography=H_CC, radius=2, threshold=0.05)
    assert est.nnz < L.nnz
    assert transport_error(est, L) < 0.05


def test_save_load_roundtrip_and_atomicity(tmp_path, truths):
    _, L = truths
    path = tmp_path / "rig" / "transport.npz"
    meta = {"spacing": 5, "radius": 2, "homography": H_CC.tolist(), "projectors": ["r2c2", "r2c3"]}
    save_transport(path, L, meta)
    got, got_meta = load_transport(path)
    assert got_meta == meta
    assert got.dtype == np.float32 and (got != L).nnz == 0
    # overwrite: the old file is replaced whole, no temp files are left behind
    save_transport(path, L * 2, {"v": 2})
    got2, m2 = load_transport(path)
    assert m2 == {"v": 2} and np.allclose(got2.data, 2 * L.data)
    assert sorted(os.listdir(path.parent)) == ["transport.npz"]


def test_load_rejects_broken_files(tmp_path, truths):
    _, L = truths
    with pytest.raises(TransportFileError, match="re-run"):
        load_transport(tmp_path / "missing.npz")
    good = tmp_path / "t.npz"
    save_transport(good, L)
    data = good.read_bytes()
    bad = tmp_path / "truncated.npz"
    bad.write_bytes(data[: len(data) // 2])
    with pytest.raises(TransportFileError):
        load_transport(bad)
    other = tmp_path / "other.npz"
    np.savez(other, data=np.zeros(3, np.float32))
    with pytest.raises(TransportFileError, match="missing"):
        load_transport(other)
    inconsistent = tmp_path / "inconsistent.npz"
    Lb = sp.csr_matrix(L, copy=True)
    Lb.indices[0] = L.shape[1] + 5
    np.savez(inconsistent, data=Lb.data, indices=Lb.indices, indptr=Lb.indptr, shape=np.array(L.shape),
             meta=np.asarray('{"format": "shadowless.transport/1"}'))
    with pytest.raises(TransportFileError, match="inconsistent"):
        load_transport(inconsistent)
