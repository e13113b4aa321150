"""How even a rig's light is: :func:`uniformity` over the covered area and :func:`seam_step` across
footprint edges.

Both take light above black (a flat capture minus the black capture) reduced to the camera grid
of the blend (a full-resolution capture is area-averaged to the target's grid first).
"""
from __future__ import annotations

import cv2
import numpy as np
from scipy import ndimage

from imaging.blending.contributions import Contributions, luma

__all__ = ["to_grid", "uniformity", "ratio_image", "seam_step"]


def to_grid(image: np.ndarray, shape: tuple[int, int]) -> np.ndarray:
    """``image`` ((H, W) or (H, W, C) float) area-averaged to ``shape`` = (h, w) (unchanged when it already is)."""
    a = np.asarray(image, np.float32)
    if a.shape[:2] == tuple(shape):
        return a
    return cv2.resize(a, (shape[1], shape[0]), interpolation=cv2.INTER_AREA)


def _channel(a: np.ndarray, channel: int | None) -> np.ndarray:
    if a.ndim == 2:
        return a
    return luma(a) if channel is None else a[..., channel]


def ratio_image(capture: np.ndarray, target: np.ndarray, covered: np.ndarray, *, block: int = 3,
                channel: int | None = None) -> tuple[np.ndarray, np.ndarray]:
    """``(ratio, valid)``: the block means of ``capture / (k target)`` ((h, w) float32, 1 = on target, NaN outside
    ``valid``) with ``k`` the median ratio, and the pixels it is defined on (the covered area less a border of
    ``block`` px, where block means would mix in the dark outside)."""
    t = _channel(np.asarray(target, np.float32), channel)
    i = _channel(to_grid(capture, t.shape), channel)
    cov = np.asarray(covered, bool)
    k = max(int(block), 1)
    inner = ndimage.binary_erosion(cov, iterations=k // 2 + 1, border_value=0) if k > 1 else cov
    inner &= t > 0
    if not inner.any():
        inner = cov & (t > 0)
    w = inner.astype(np.float32)
    num = cv2.blur(i * w, (k, k))
    den = cv2.blur(t * w, (k, k))
    with np.errstate(divide="ignore", invalid="ignore"):
        r = num / den
    valid = inner & np.isfinite(r) & (den > 0)
    if not valid.any():
        return np.full(t.shape, np.nan, np.float32), valid
    r = r / np.float32(np.median(r[valid]))
    return np.where(valid, r, np.nan).astype(np.float32), valid


def uniformity(capture: np.ndarray, target: np.ndarray, covered: np.ndarray, *, block: int = 3,
               channel: int | None = None, percentile: float = 99.0) -> float:
    """p99 of ``|I / (k target) - 1|`` over the covered area, on ``block`` x ``block`` means, with ``k`` the
    median ratio (so a rig brighter or darker than the target by a constant factor is even).

    Parameters
    ----------
    capture : (H, W, 3) or (h, w, 3) float
        Light above black (a full-resolution capture is area-averaged to ``target``'s grid).
    target : (h, w, 3) float
    covered : (h, w) bool
    channel : None for luminance, else 0/1/2 for one channel.
    """
    r, valid = ratio_image(capture, target, covered, block=block, channel=channel)
    if not valid.any():
        return float("nan")
    return float(np.percentile(np.abs(r[valid] - 1.0), percentile))


def seam_step(image: np.ndarray, contributions: Contributions, covered: np.ndarray, *, slots=None,
              distance: float | None = None, block: int = 3, along: int | None = None,
              target: np.ndarray | None = None) -> float:
    """The largest relative luminance step across a projector's frame edge inside the covered area.

    At every grid pixel on the edge of a slot's footprint (at least ``distance + block`` px inside the
    covered area) the luminance's ``block`` x ``block`` means ``distance`` px to either side along the edge's
    normal give a signed step ``L_in / L_out - 1``; the steps are averaged along the edge over ``along`` px
    (a seam is a step all along an edge; the camera's noise is not), and the largest magnitude over every
    edge of ``slots`` (default: every slot) is returned; 0.0 when no edge lies inside the covered area.

    Parameters
    ----------
    image : (h, w, 3) or (H, W, 3) float
        Light above black.
    distance : grid px (default: ``block``, so the two means do not straddle the edge)
    along : grid px (default: 2 ``block``)
    target : (h, w, 3) float, optional
        Steps of ``image / target`` instead of ``image`` (a target that rises across an edge is no seam).
    """
    c = contributions
    L = luma(to_grid(image, c.shape)) if np.asarray(image).ndim == 3 else to_grid(image, c.shape)
    k = max(int(block), 1)
    d = float(k if distance is None else distance)
    span = 2 * k if along is None else max(int(along), 1)
    if target is not None:
        t = luma(np.asarray(target, np.float32))
        with np.errstate(divide="ignore", invalid="ignore"):
            L = np.where(t > 0, L / np.where(t > 0, t, 1.0), 0.0)
    Lb = cv2.blur(np.ascontiguousarray(L, np.float32), (k, k))
    cov = np.asarray(covered, bool)
    inner = ndimage.binary_erosion(cov, iterations=int(np.ceil(d)) + k, border_value=0)
    worst = 0.0
    for s in (slots or c.slots):
        fp = c.footprint(s)
        edge = fp & ~ndimage.binary_erosion(fp, border_value=1) & inner
        if not edge.any():
            continue
        soft = cv2.GaussianBlur(fp.astype(np.float32), (0, 0), 2.0)
        gy, gx = np.gradient(soft)
        ey, ex = np.nonzero(edge)
        nx, ny = gx[ey, ex], gy[ey, ex]
        norm = np.hypot(nx, ny)
        ok = norm > 1e-6
        ey, ex, nx, ny = ey[ok], ex[ok], nx[ok] / norm[ok], ny[ok] / norm[ok]
        if not len(ey):
            continue
        px = np.concatenate([ex + d * nx, ex - d * nx]).astype(np.float32)[None, :]
        py = np.concatenate([ey + d * ny, ey - d * ny]).astype(np.float32)[None, :]
        vals = cv2.remap(Lb, px, py, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)[0]
        a, b = vals[:len(ey)], vals[len(ey):]
        good = (a > 0) & (b > 0)
        if not good.any():
            continue
        steps = np.zeros(c.shape, np.float32)
        count = np.zeros(c.shape, np.float32)
        steps[ey[good], ex[good]] = a[good] / b[good] - 1.0
        count[ey[good], ex[good]] = 1.0
        win = 2 * span + 1
        mean = cv2.boxFilter(steps, -1, (win, win), normalize=False) / np.maximum(
            cv2.boxFilter(count, -1, (win, win), normalize=False), 1e-9)
        worst = max(worst, float(np.abs(mean[ey[good], ex[good]]).max()))
    return worst
