"""The PSF's tails averaged over neighbouring texels: the same means as a brute-force loop, the core untouched,
cameras kept apart, and the clipping's bias on a noisy faint tail mostly gone."""
from __future__ import annotations

import numpy as np
import pytest

from imaging.compensation.psf_tails import smooth_tails, tail_offsets


def _windows(centres: np.ndarray, radius: int, width: int) -> np.ndarray:
    """(n, K) flat camera pixels of the windows centred on ``centres`` ((n, 2) x, y)."""
    d = np.arange(-radius, radius + 1)
    dy, dx = np.meshgrid(d, d, indexing="ij")
    return (centres[:, 1:2] + dy.ravel()) * width + centres[:, 0:1] + dx.ravel()


def test_tail_offsets_are_the_ring_beyond_the_core():
    ring = tail_offsets(3, 1).reshape(7, 7)
    assert not ring[2:5, 2:5].any() and ring.sum() == 49 - 9
    assert tail_offsets(2, 2).sum() == 0


def test_tail_entries_are_the_mean_over_texels_within_reach_and_the_core_is_kept():
    rng = np.random.default_rng(0)
    radius, core, width = 2, 1, 60
    centres = np.column_stack([rng.integers(3, 57, 80), rng.integers(3, 37, 80)])
    rows = _windows(centres, radius, width)
    valid = rng.random(rows.shape) > 0.1
    valid[:, rows.shape[1] // 2] = True
    values = rng.normal(size=rows.shape).astype(np.float32)
    out = values.copy()
    smooth_tails(out, rows, valid, camera_width=width, radius=radius, core=core, reach=6)
    ring = tail_offsets(radius, core)
    np.testing.assert_array_equal(out[:, ~ring], values[:, ~ring])
    for j in range(len(centres)):                                    # brute force
        near = np.abs(centres - centres[j]).max(axis=1) <= 6
        for k in np.flatnonzero(ring):
            m = near & valid[:, k]
            want = values[m, k].mean() if valid[j, k] else values[j, k]
            assert out[j, k] == pytest.approx(want, abs=1e-5)


def test_averaging_removes_most_of_the_clipping_bias_on_a_faint_tail():
    rng = np.random.default_rng(1)
    radius, core, width = 3, 1, 200
    ys, xs = np.mgrid[5:195:3, 5:195:3]
    centres = np.column_stack([xs.ravel(), ys.ravel()])
    rows = _windows(centres, radius, width)
    valid = np.ones(rows.shape, bool)
    d = np.arange(-radius, radius + 1)
    r2 = (d[:, None] ** 2 + d[None, :] ** 2).ravel()
    truth = np.where(tail_offsets(radius, core), 0.002 * np.exp(-r2 / 18.0), 0.1).astype(np.float32)
    truth = np.broadcast_to(truth, rows.shape)
    noisy = (truth + rng.normal(scale=0.01, size=rows.shape)).astype(np.float32)
    raw = np.maximum(noisy, 0)
    smoothed = noisy.copy()
    n = smooth_tails(smoothed, rows, valid, camera_width=width, radius=radius, core=core, reach=6)
    assert n == 25                               # 5 x 5 window centres 3 px apart
    smoothed = np.maximum(smoothed, 0)
    ring = tail_offsets(radius, core)
    tail = truth[:, ring].sum(axis=1).mean()
    bias_raw = raw[:, ring].sum(axis=1).mean() - tail
    bias_smoothed = smoothed[:, ring].sum(axis=1).mean() - tail
    assert bias_raw > 2 * tail                   # the clipped noise outweighs the tail itself
    assert abs(bias_smoothed) < 0.3 * bias_raw    # noise down 5x: the bias with it


def test_bad_shapes_are_refused():
    with pytest.raises(ValueError, match="must be"):
        smooth_tails(np.zeros((2, 9), np.float32), np.zeros((2, 9), int), np.ones((2, 9), bool), camera_width=5,
                     radius=2, core=1)


def test_stacked_cameras_are_smoothed_each_in_its_own_block():
    rng = np.random.default_rng(2)
    radius, core, width, part_rows = 2, 0, 50, 30     # two cameras of 30 rows
    blocks = []
    for k in range(2):                                   # camera k's pixels follow camera k-1's in the stacked image
        centres = np.column_stack([rng.integers(3, 47, 40), rng.integers(3, 27, 40)])
        blocks.append(_windows(centres, radius, width) + k * part_rows * width)
    rows = np.concatenate(blocks, axis=1)
    valid = np.ones(rows.shape, bool)
    valid[::3, 25:] = False                              # a third of the texels unseen by camera 1
    values = rng.normal(size=rows.shape).astype(np.float32)
    stacked = values.copy()
    smooth_tails(stacked, rows, valid, camera_width=width, radius=radius, core=core)
    for k in range(2):
        one = np.ascontiguousarray(values[:, 25 * k:25 * (k + 1)])
        smooth_tails(one, rows[:, 25 * k:25 * (k + 1)], valid[:, 25 * k:25 * (k + 1)], camera_width=width,
                     radius=radius, core=core)
        np.testing.assert_array_equal(stacked[:, 25 * k:25 * (k + 1)], one)
    assert not np.array_equal(stacked, values)


def test_the_transport_report_says_how_a_mesh_l_was_measured():
    from rigctl.compensation_cli import transport_report

    base = {"captures": 135, "patterns": 133, "spacing": [7, 13], "radius": 6, "nnz": 10, "slots": 25, "file": "f",
            "date": "d"}
    line = transport_report({**base, "core": 3, "tails_averaged": True, "exposure": 0.47, "white_peak": 1.91,
                             "dot_gain": 3.5})
    assert "tail beyond 3 averaged" in line and "0.470 times the camera's exposure" in line and "1.91" in line
    assert "the dots at 3.50 times the white's exposure" in line
    planar = transport_report({**base, "exposure": 1.0, "white_peak": 0.5, "dot_gain": 8.1})
    assert "tail" not in planar and "the dots at 8.10 times the white's exposure" in planar
    plain = transport_report({**base, "exposure": 1.0, "white_peak": 0.5})
    assert "tail" not in plain and "exposure" not in plain
