"""How even a capture is: the figures `shadowless bench uniformity` reports, from captures alone.

Written here, apart from the blend's own numerics (``imaging.blending``), so that the benchmark
scores the blend with a measure the blend did not compute. Every figure is taken on block means
(camera noise and the projector pixel grid average out) of whole blocks inside a mask:

* :func:`nonuniformity` -- p99 of ``|I / (k * target) - 1|`` over the blocks, ``k`` the median
  ratio (the scale of the light does not count, its shape does);
* :func:`channel_deviation` -- the same per colour channel, each with its own ``k``, plus how far
  the channels' scales sit apart (the white point);
* :func:`seam_steps` -- across every line where the number of projectors that reach the surface
  changes (a seam of a partly overlapping wall), the relative step between the luminance just
  before and just after it.

Luminance is Rec. 709's weighting of the camera's linear channels.
"""
from __future__ import annotations

import numpy as np
from scipy import ndimage

__all__ = ["LUMA", "luminance", "block_means", "scale_of", "nonuniformity", "nonuniformity_map", "channel_deviation",
           "seam_steps", "resize_to"]

#: Rec. 709 luminance weights of linear R, G, B
LUMA = np.array([0.2126, 0.7152, 0.0722], np.float64)


def luminance(image: np.ndarray) -> np.ndarray:
    """(H, W) float64 luminance of an (H, W, 3) linear image; an (H, W) image is returned as it is."""
    a = np.asarray(image, np.float64)
    if a.ndim == 2:
        return a
    if a.ndim != 3 or a.shape[2] != 3:
        raise ValueError(f"image must be (H, W) or (H, W, 3), got {a.shape}")
    return a @ LUMA


def resize_to(grid: np.ndarray, size: tuple[int, int]) -> np.ndarray:
    """A coarse grid (h, w[, c]) brought to ``size`` (W, H) by nearest neighbour on whole cells.

    The blend's target and coverage live on the camera grid divided by a scale; the captures are
    full size. Each full-size pixel takes the cell whose area holds its centre.
    """
    a = np.asarray(grid)
    W, H = (int(v) for v in size)
    h, w = a.shape[:2]
    rows = np.minimum(((np.arange(H) + 0.5) * h / H).astype(np.int64), h - 1)
    cols = np.minimum(((np.arange(W) + 0.5) * w / W).astype(np.int64), w - 1)
    return a[rows[:, None], cols[None, :]]


def block_means(image: np.ndarray, mask: np.ndarray, block: int) -> tuple[np.ndarray, np.ndarray]:
    """Means of ``image`` over ``block`` x ``block`` tiles, and which tiles lie wholly in ``mask``.

    Parameters
    ----------
    image : (H, W) or (H, W, C) array
    mask : (H, W) bool
    block : int >= 1

    Returns
    -------
    means : (H // block, W // block[, C]) float64 (partial tiles at the right and bottom dropped)
    whole : (H // block, W // block) bool, every pixel of the tile in ``mask``
    """
    a = np.asarray(image, np.float64)
    m = np.asarray(mask, bool)
    if a.shape[:2] != m.shape:
        raise ValueError(f"image {a.shape[:2]} and mask {m.shape} differ in size")
    if block < 1:
        raise ValueError(f"block must be >= 1, got {block}")
    bh, bw = m.shape[0] // block, m.shape[1] // block
    if bh == 0 or bw == 0:
        raise ValueError(f"an image of {m.shape[1]}x{m.shape[0]} holds no {block}x{block} block")
    a = a[:bh * block, :bw * block]
    m = m[:bh * block, :bw * block]
    tail = a.shape[2:]
    means = a.reshape(bh, block, bw, block, *tail).mean(axis=(1, 3))
    whole = m.reshape(bh, block, bw, block).all(axis=(1, 3))
    return means, whole


def _ratios(capture: np.ndarray, target: np.ndarray | None, mask: np.ndarray, block: int) -> tuple[np.ndarray, np.ndarray]:
    """Block ratios capture / target (target None: 1) and the tiles that count (whole, target > 0)."""
    c, whole = block_means(capture, mask, block)
    if target is None:
        t = np.ones_like(c)
    else:
        t, _ = block_means(target, mask, block)
    ok = whole & (t > 0) if t.ndim == 2 else whole & np.all(t > 0, axis=-1)
    with np.errstate(divide="ignore", invalid="ignore"):
        r = np.where(t > 0, c / np.where(t > 0, t, 1.0), 0.0)
    return r, ok


def scale_of(capture: np.ndarray, target: np.ndarray | None, mask: np.ndarray, *, block: int = 8) -> float:
    """``k``, the median block ratio of luminance ``I / target`` over ``mask`` (NaN when no block counts)."""
    r, ok = _ratios(luminance(capture), None if target is None else luminance(target), mask, block)
    return float(np.median(r[ok])) if ok.any() else float("nan")


def nonuniformity(capture: np.ndarray, target: np.ndarray | None, mask: np.ndarray, *, block: int = 8,
                  quantile: float = 99.0, within: np.ndarray | None = None, scale: float | None = None) -> float:
    """p``quantile`` of ``|I / (k * target) - 1|`` on block means of luminance over ``mask``.

    Parameters
    ----------
    capture : (H, W, 3) or (H, W) linear camera image
    target : same shape, or None for a flat target
        The light the blend aims at (its shape only: the scale ``k`` is fitted).
    mask : (H, W) bool, the covered region
    block : tile side in camera pixels
    within : (H, W) bool, optional
        Score only the tiles wholly inside this region (e.g. a lost projector's footprint), with
        ``k`` still the median over all of ``mask``: a footprint that went darker as a whole counts.
    scale : float, optional
        ``k`` given (e.g. :func:`scale_of` of a capture before a change, same camera and exposure):
        then light lost everywhere at once counts too.

    Returns
    -------
    float, a fraction (0.02 is 2 %); NaN when no tile counts
    """
    Y = luminance(capture)
    T = None if target is None else luminance(target)
    r, ok = _ratios(Y, T, mask, block)
    if not ok.any():
        return float("nan")
    k = float(np.median(r[ok])) if scale is None else float(scale)
    if not k > 0:
        return float("nan")
    sel = ok
    if within is not None:
        _, inside = block_means(np.zeros(mask.shape), np.asarray(within, bool) & mask, block)
        sel = ok & inside
        if not sel.any():
            return float("nan")
    return float(np.percentile(np.abs(r[sel] / k - 1.0), quantile))


def nonuniformity_map(capture: np.ndarray, target: np.ndarray | None, mask: np.ndarray, *, block: int = 8) -> np.ndarray:
    """Block map of ``I / (k * target) - 1`` (NaN outside the tiles that count): (H // block, W // block) float32."""
    Y = luminance(capture)
    T = None if target is None else luminance(target)
    r, ok = _ratios(Y, T, mask, block)
    out = np.full(r.shape, np.nan, np.float32)
    if ok.any():
        k = float(np.median(r[ok]))
        out[ok] = (r[ok] / k - 1.0).astype(np.float32)
    return out


def channel_deviation(capture: np.ndarray, target: np.ndarray | None, mask: np.ndarray, *, block: int = 8,
                      quantile: float = 99.0) -> dict:
    """Per colour channel, p``quantile`` of ``|I_c / (k_c * target_c) - 1|`` on block means over ``mask``.

    Parameters
    ----------
    capture : (H, W, 3) linear camera image (e.g. of a flat grey)
    target : (H, W, 3) or (H, W) (the same shape for every channel) or None (flat)
    mask : (H, W) bool

    Returns
    -------
    ``{"per_channel": [r, g, b], "max": m, "white_point_spread": s}``: fractions. ``white_point_spread``
    is the largest ``|k_c / mean(k) - 1|``: how far the channels' overall scales sit apart, which a
    target in the camera's own colours leaves free.
    """
    c = np.asarray(capture, np.float64)
    if c.ndim != 3 or c.shape[2] != 3:
        raise ValueError(f"capture must be (H, W, 3), got {c.shape}")
    t = None if target is None else np.asarray(target, np.float64)
    if t is not None and t.ndim == 2:
        t = np.repeat(t[:, :, None], 3, axis=2)
    devs, scales = [], []
    for ch in range(3):
        r, ok = _ratios(c[..., ch], None if t is None else t[..., ch], mask, block)
        if not ok.any():
            return {"per_channel": [None] * 3, "max": None, "white_point_spread": None}
        k = float(np.median(r[ok]))
        scales.append(k)
        devs.append(float(np.percentile(np.abs(r[ok] / k - 1.0), quantile)) if k > 0 else float("nan"))
    mean = float(np.mean(scales))
    return {"per_channel": devs, "max": float(max(devs)),
            "white_point_spread": float(max(abs(k / mean - 1.0) for k in scales)) if mean > 0 else None}


def seam_steps(image: np.ndarray, count: np.ndarray, *, band: int = 6, half_width: int = 4,
               margin: int = 2) -> list[dict]:
    """Relative luminance steps across the seams of a partly overlapping rig.

    A seam is a connected line of pixel boundaries where the number of projectors reaching the
    surface (``count``, e.g. the room's :meth:`~sim.truth.Truth.illumination_count`) changes between
    two horizontally or vertically adjacent pixels that both have light. At each boundary pixel the
    mean luminance over a ``band`` deep, ``2 * half_width + 1`` wide box on each side (beginning
    ``margin`` pixels from the line, so the blur of the projectors' edges is not measured) is
    compared; the step is ``|a - b| / ((a + b) / 2)``. Boxes that leave the lit region are skipped.
    Each seam reports the median of its boundary pixels' steps (robust to camera noise).

    Parameters
    ----------
    image : (H, W, 3) or (H, W) linear camera image of a flat white
    count : (H, W) int, projectors reaching each pixel's surface point

    Returns
    -------
    list of ``{"step": s, "pixels": n, "counts": [a, b], "axis": "x"|"y"}``, largest step first
    """
    Y = luminance(image)
    n = np.asarray(count)
    if n.shape != Y.shape:
        raise ValueError(f"count {n.shape} and image {Y.shape} differ in size")
    lit = n > 0
    # box sums over each side through a summed-area table
    S = np.pad(np.cumsum(np.cumsum(Y, 0), 1), ((1, 0), (1, 0)))
    L = np.pad(np.cumsum(np.cumsum(lit.astype(np.int64), 0), 1), ((1, 0), (1, 0)))
    H, W = Y.shape

    def box(sat, y0, y1, x0, x1):
        return sat[y1, x1] - sat[y0, x1] - sat[y1, x0] + sat[y0, x0]

    out = []
    for axis in ("x", "y"):
        if axis == "x":
            edge = (n[:, :-1] != n[:, 1:]) & lit[:, :-1] & lit[:, 1:]
        else:
            edge = (n[:-1, :] != n[1:, :]) & lit[:-1, :] & lit[1:, :]
        labels, k = ndimage.label(edge, structure=np.ones((3, 3), bool))
        if k == 0:
            continue
        ys, xs = np.nonzero(edge)
        lab = labels[ys, xs]
        if axis == "x":     # the line lies between column x and x + 1
            y0, y1 = ys - half_width, ys + half_width + 1
            a = (y0, y1, xs - margin - band + 1, xs - margin + 1)
            b = (y0, y1, xs + 1 + margin, xs + 1 + margin + band)
            pairs = (n[ys, xs], n[ys, xs + 1])
        else:
            x0, x1 = xs - half_width, xs + half_width + 1
            a = (ys - margin - band + 1, ys - margin + 1, x0, x1)
            b = (ys + 1 + margin, ys + 1 + margin + band, x0, x1)
            pairs = (n[ys, xs], n[ys + 1, xs])
        inside = ((a[0] >= 0) & (a[2] >= 0) & (b[1] <= H) & (b[3] <= W) & (a[1] <= H) & (a[3] <= W)
                  & (b[0] >= 0) & (b[2] >= 0))
        area = (2 * half_width + 1) * band
        ys_, lab_ = ys[inside], lab[inside]
        aa = [v[inside] for v in a]
        bb = [v[inside] for v in b]
        full = (box(L, *aa) == area) & (box(L, *bb) == area)
        sa, sb = box(S, *aa)[full] / area, box(S, *bb)[full] / area
        lab_ = lab_[full]
        with np.errstate(divide="ignore", invalid="ignore"):
            step = np.abs(sa - sb) / ((sa + sb) / 2)
        pa, pb = pairs[0][inside][full], pairs[1][inside][full]
        del ys_
        for seam in np.unique(lab_):
            sel = (lab_ == seam) & np.isfinite(step)
            if sel.sum() < 3:
                continue
            counts = sorted({int(np.median(pa[sel])), int(np.median(pb[sel]))})
            out.append({"step": float(np.median(step[sel])), "pixels": int(sel.sum()), "counts": counts, "axis": axis})
    out.sort(key=lambda d: -d["step"])
    return out
