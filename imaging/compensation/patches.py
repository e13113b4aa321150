"""Grey patches: several response levels measured in one capture.

A projector's frame is cut into ``rows x cols`` patches (:func:`patch_labels`), each showing
one grey level (:func:`patch_layouts` assigns the levels, each at several positions); the
camera pixels a patch covers (:func:`camera_patch_labels`, through the projector -> camera
homography) give its normalised response ``mean(capture - black) / mean(white - black)``
(:func:`patch_response`), which cancels the projector's fall-off across the table.
"""
from __future__ import annotations

import math
from collections.abc import Sequence

import cv2
import numpy as np

from imaging.compensation.errors import CompensationError

__all__ = ["MIN_PATCH_PIXELS", "patch_labels", "patch_layouts", "camera_patch_labels", "patch_response"]

#: fewest camera pixels a response patch must cover to count
MIN_PATCH_PIXELS = 12


def patch_labels(size: tuple[int, int], grid: tuple[int, int], *, border: int = 3) -> np.ndarray:
    """Projector-space patch layout: ``(h, w) int32``, patch ``k = row * cols + col``, -1 on borders.

    The frame is cut into ``rows x cols`` equal patches; ``border`` projector pixels along every
    patch edge (where the blur mixes two levels) are labelled -1.
    """
    w, h = (int(v) for v in size)
    rows, cols = (int(v) for v in grid)
    if rows < 1 or cols < 1 or w < 2 * cols or h < 2 * rows:
        raise ValueError(f"cannot cut a {w}x{h} frame into {rows}x{cols} patches")
    ys = np.minimum((np.arange(h) * rows) // h, rows - 1)
    xs = np.minimum((np.arange(w) * cols) // w, cols - 1)
    labels = (ys[:, None] * cols + xs[None, :]).astype(np.int32)
    if border > 0:
        edge = np.zeros((h, w), bool)
        edge[:, :border] = edge[:, -border:] = True
        edge[:border, :] = edge[-border:, :] = True
        dy = np.diff(ys) != 0
        dx = np.diff(xs) != 0
        for i in np.flatnonzero(dy):
            edge[max(0, i - border + 1): i + border + 1, :] = True
        for i in np.flatnonzero(dx):
            edge[:, max(0, i - border + 1): i + border + 1] = True
        labels[edge] = -1
    return labels


def patch_layouts(levels: np.ndarray, patches: int, repeats: int, seed: int) -> list[np.ndarray]:
    """Assign levels to patches: every level ``repeats`` times, at different patches when possible.

    Returns one ``(patches,) float64`` layout per capture (the last one padded with random levels).
    """
    rng = np.random.default_rng(seed)
    pool = np.concatenate([rng.permutation(levels) for _ in range(repeats)])
    count = math.ceil(len(pool) / patches)
    pool = np.concatenate([pool, rng.choice(levels, count * patches - len(pool))]) if count * patches > len(pool) else pool
    return [pool[i * patches:(i + 1) * patches] for i in range(count)]


def camera_patch_labels(labels: np.ndarray, projector_to_camera: np.ndarray, camera_shape: Sequence[int]) -> np.ndarray:
    """The patch each camera pixel sees: ``(Hc, Wc) int32`` (-1: none), nearest projector pixel."""
    hc, wc = int(camera_shape[0]), int(camera_shape[1])
    return cv2.warpPerspective(labels.astype(np.float32), np.asarray(projector_to_camera, np.float64), (wc, hc),
                               flags=cv2.INTER_NEAREST, borderMode=cv2.BORDER_CONSTANT,
                               borderValue=-1).astype(np.int32)


def patch_response(captures: Sequence[np.ndarray], layouts: Sequence[np.ndarray], *, white: np.ndarray,
                   black: np.ndarray, camera_labels: np.ndarray, valid: np.ndarray,
                   min_pixels: int = MIN_PATCH_PIXELS) -> tuple[np.ndarray, np.ndarray]:
    """Normalised response of the patches of several captures.

    Parameters
    ----------
    captures : sequence of (Hc, Wc, C) float32
        Capture ``j`` shows level ``layouts[j][k]`` in patch ``k``.
    layouts : sequence of (P,) float64
        The input value each patch showed, per capture.
    white, black : (Hc, Wc, C) float32
        The projector at full white alone, and every projector black.
    camera_labels : (Hc, Wc) int32
        Patch index seen by each camera pixel (-1: none).
    valid : (Hc, Wc) bool
        Camera pixels the projector lights well.

    Returns
    -------
    levels : (M,) float64
        Input values of the usable patches.
    rho : (M, C) float64
        ``mean(capture - black) / mean(white - black)`` over each patch's pixels.
    """
    wb = np.asarray(white, np.float64) - np.asarray(black, np.float64)
    if wb.ndim == 2:
        wb = wb[:, :, None]
    levels: list[float] = []
    rhos: list[np.ndarray] = []
    lab = np.where(valid, camera_labels, -1)
    flat = lab.ravel()
    order = np.argsort(flat, kind="stable")
    bounds = np.searchsorted(flat[order], np.arange(-1, int(flat.max(initial=-1)) + 2))
    den_cache: dict[int, np.ndarray] = {}
    wbf = wb.reshape(-1, wb.shape[2])
    for cap, layout in zip(captures, layouts):
        d = np.asarray(cap, np.float64) - np.asarray(black, np.float64)
        if d.ndim == 2:
            d = d[:, :, None]
        d = d.reshape(-1, d.shape[2])
        for k, level in enumerate(np.asarray(layout, np.float64)):
            if k + 1 >= len(bounds) - 1:
                continue
            idx = order[bounds[k + 1]: bounds[k + 2]]
            if idx.size < min_pixels:
                continue
            if k not in den_cache:
                den_cache[k] = wbf[idx].mean(axis=0)
            den = den_cache[k]
            if np.any(den <= 0):
                continue
            levels.append(float(level))
            rhos.append(d[idx].mean(axis=0) / den)
    if not levels:
        raise CompensationError("no response patch covers enough lit camera pixels; check the camera calibration")
    return np.asarray(levels), np.stack(rhos)
