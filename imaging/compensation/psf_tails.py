"""The outer ring of the measured PSF windows, averaged over neighbouring texels: tails without the noise's bias.

A dot's window holds its PSF: a steep core, where each texel's own samples matter (their sub-pixel
phase and the defocus change from texel to texel), and a faint tail. Leaving the tail out biases
``L``: its white ``L 1`` falls short of what the projectors throw, so the target, the model of every
solve, and the scores all miss that light (2 % of it on the bust). Measuring it from one capture per
pattern costs a bias of another kind: every window entry is clipped at zero, the tail's entries are
mostly noise, and a clipped zero-mean noise adds ``sigma / sqrt(2 pi)`` per entry.

But the tail changes slowly over the surface: the defocus and the projector's pixel footprint do.
So each tail entry (window offsets farther than ``core`` from the centre in either direction) is
replaced by the mean of the same entry over the texels whose window centres lie within ``reach``
camera pixels of its own (the same camera only), before the clipping; the noise falls with the
square root of their number and the clipping's bias with it. The core's entries stay as measured.
"""
from __future__ import annotations

import numpy as np
import scipy.sparse as sp
from scipy.spatial import cKDTree

__all__ = ["tail_offsets", "smooth_tails"]


def tail_offsets(radius: int, core: int) -> np.ndarray:
    """Window entries (row-major offsets in ``[-radius, radius]^2``) farther than ``core`` in x or y: ``(K,) bool``."""
    d = np.arange(-radius, radius + 1)
    cheb = np.maximum(np.abs(d)[:, None], np.abs(d)[None, :])
    return (cheb > core).ravel()


def smooth_tails(values: np.ndarray, rows: np.ndarray, valid: np.ndarray, *, camera_width: int, radius: int, core: int,
                 reach: float | None = None) -> int:
    """Average each tail entry of ``values`` over the texels near its own in the camera, in place.

    Parameters
    ----------
    values : (n, B K) float32
        Unclipped window entries per texel (``capture - black`` over the dot value), ``K = (2 radius + 1)^2``
        per camera, ``B`` cameras one after the other (:func:`~coordinator.compensation.mesh_cameras.stacked_windows`).
    rows, valid : (n, B K)
        Camera pixel (flat, of the stacked image) of each entry, and whether it was measured. Each block
        of ``K`` columns lies in one camera, so texels are neighbours only within their camera.
    core : int
        Offsets within ``core`` of the centre (Chebyshev) keep their own value.
    reach : float
        Chebyshev distance (camera px) between window centres that counts as near; default ``radius``.

    Returns the median number of texels averaged per measured texel and camera (1 when nothing was smoothed).
    """
    k_all = (2 * radius + 1) ** 2
    if values.shape != rows.shape or values.shape != valid.shape or values.shape[1] % k_all or not values.shape[1]:
        raise ValueError(f"values {values.shape}, rows {rows.shape} and valid {valid.shape} must be (n, B * {k_all})")
    if not 0 <= core < radius:
        return 1
    counts = []
    for b in range(values.shape[1] // k_all):
        cols = slice(b * k_all, (b + 1) * k_all)
        counts += _smooth_one(values[:, cols], rows[:, cols], valid[:, cols], camera_width=camera_width,
                              radius=radius, core=core, reach=float(radius if reach is None else reach))
    return int(np.median(counts)) if counts else 1


def _smooth_one(values: np.ndarray, rows: np.ndarray, valid: np.ndarray, *, camera_width: int, radius: int,
                core: int, reach: float) -> list[int]:
    """:func:`smooth_tails` for one camera's ``(n, K)`` block (``values`` a view written through); the number
    of texels averaged per measured texel."""
    centre = values.shape[1] // 2
    texels = np.flatnonzero(valid[:, centre])
    if texels.size == 0:
        return []
    cam = rows[texels, centre].astype(np.int64)
    y, x = np.divmod(cam, camera_width)
    pts = np.column_stack([x, y]).astype(np.float64)
    pairs = cKDTree(pts).query_pairs(r=reach, p=np.inf, output_type="ndarray")
    m = texels.size
    i = np.concatenate([pairs[:, 0], pairs[:, 1], np.arange(m)])
    j = np.concatenate([pairs[:, 1], pairs[:, 0], np.arange(m)])
    near = sp.csr_matrix((np.ones(i.size, np.float32), (i, j)), shape=(m, m))
    ring = np.flatnonzero(tail_offsets(radius, core))
    v = values[np.ix_(texels, ring)]
    ok = valid[np.ix_(texels, ring)].astype(np.float32)
    total = near @ (v * ok)
    count = near @ ok
    with np.errstate(divide="ignore", invalid="ignore"):
        mean = np.where(count > 0, total / count, 0.0).astype(np.float32)
    values[np.ix_(texels, ring)] = np.where(ok > 0, mean, v)
    return np.diff(near.indptr).tolist()
