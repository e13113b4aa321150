"""The compensate job's picture (``compensation/quality.png``), made to be read at a glance: the
target and what the camera saw without compensation, with the per-projector baseline (when there is
one) and with ours, at full size with a box where the blur costs most; that box enlarged; and
|captured - target| of each result on one colour scale with its bar. At full size a gain of +5 dB is
invisible; in the enlarged box and the difference images it is not.

Drawn from the evaluation's own float images (the ones PSNR/SSIM are computed from), so the
difference images and their mean errors are those of the scores, not of an 8-bit copy.

Also the few layout helpers the picture is made of (:func:`panel`, :func:`row`, :func:`column`,
:func:`caption_band`): black captions on white, which other captioned pictures use too.

Pictures are (H, W, 3) uint8 BGR (what ``cv2.imwrite`` takes).
"""
from __future__ import annotations

import math
from collections.abc import Mapping, Sequence

import cv2
import numpy as np

from imaging.calibration.heatmap_figure import colourise, put_text, turbo_lut
from imaging.compensation.quality import enlargement, linear_to_srgb

__all__ = ["compensation_figure", "packed_views", "BLOCK_MARGIN", "detail_window", "error_scale", "enlargement", "camera_view_srgb", "RESULT_NAMES",
           "panel", "row", "column", "caption_band", "text_width", "INK", "PAPER", "GAP", "CROP_BGR"]

INK = (40, 40, 40)
PAPER = (255, 255, 255)
FONT = cv2.FONT_HERSHEY_SIMPLEX
CAPTION_SCALE = 0.5
LINE_PX = 20
GAP = 10
#: the crop's outline on the full pictures (BGR)
CROP_BGR = (0, 215, 255)
#: the default crop: this share of the scored pixels, this wide to 1 high
CROP_SHARE, CROP_ASPECT = 12, 1.5
#: unscored px kept round each camera's view when several are packed into one tile (:func:`packed_views`)
BLOCK_MARGIN = 4
#: each result's name in the captions (the keys of the job's ``quality.json``)
RESULT_NAMES = {"none": "without compensation", "baseline": "per-projector baseline", "ours": "compensated"}


# ------------------------------------------------------------------------------------------ layout
def caption_band(width: int, lines: Sequence[str], *, scale: float = CAPTION_SCALE) -> np.ndarray:
    """(20 * len(lines) + 8, width, 3) uint8: the lines in black on white, one under the other."""
    band = np.full((LINE_PX * len(lines) + 8, width, 3), PAPER, np.uint8)
    for k, text in enumerate(lines):
        cv2.putText(band, text, (4, LINE_PX * (k + 1) - 4), FONT, scale, INK, 1, cv2.LINE_AA)
    return band


def text_width(text: str, scale: float = CAPTION_SCALE) -> int:
    """The width in px a caption line needs (its margins included)."""
    return cv2.getTextSize(text, FONT, scale, 1)[0][0] + 8


def panel(img: np.ndarray, lines: Sequence[str]) -> np.ndarray:
    """``img`` (BGR uint8) with its caption lines above it, on white, as wide as the wider of the two."""
    width = max([img.shape[1]] + [text_width(t) for t in lines])
    body = np.full((img.shape[0], width, 3), PAPER, np.uint8)
    body[:, :img.shape[1]] = img
    return np.vstack([caption_band(width, lines), body])


def row(panels: Sequence[np.ndarray], gap: int = GAP) -> np.ndarray:
    """Panels left to right, tops aligned, on white."""
    h = max(p.shape[0] for p in panels)
    w = sum(p.shape[1] for p in panels) + gap * (len(panels) - 1)
    out = np.full((h, w, 3), PAPER, np.uint8)
    x = 0
    for p in panels:
        out[:p.shape[0], x:x + p.shape[1]] = p
        x += p.shape[1] + gap
    return out


def column(rows: Sequence[np.ndarray], gap: int = GAP, margin: int = GAP) -> np.ndarray:
    """Rows top to bottom, left aligned, with a white margin all round."""
    w = max(r.shape[1] for r in rows) + 2 * margin
    h = sum(r.shape[0] for r in rows) + gap * (len(rows) - 1) + 2 * margin
    out = np.full((h, w, 3), PAPER, np.uint8)
    y = margin
    for r in rows:
        out[y:y + r.shape[0], margin:margin + r.shape[1]] = r
        y += r.shape[0] + gap
    return out


def camera_view_srgb(img: np.ndarray) -> np.ndarray:
    """A linear float tile in [0, 1], (h, w), (h, w, 1) or (h, w, 3) RGB, as (h, w, 3) uint8 BGR, sRGB-encoded."""
    v = linear_to_srgb(np.asarray(img, np.float32))
    if v.ndim == 2:
        v = v[:, :, None]
    if v.shape[2] == 1:
        v = np.repeat(v, 3, axis=2)
    return cv2.cvtColor(np.rint(v * 255).astype(np.uint8), cv2.COLOR_RGB2BGR)


# ------------------------------------------------------------------------------------------ several views
def packed_views(images: Sequence[np.ndarray], region: np.ndarray, views: int, *, across: int,
                 margin: int = BLOCK_MARGIN) -> list[np.ndarray]:
    """Several cameras' views, each cropped to its own scored pixels, packed into one tile per image.

    ``images``: (H, W, C) float32 each, ``views`` views stacked one under the other (view k is rows
    k * H // views .. (k + 1) * H // views); ``region``: (H, W) bool, the scored pixels. Each view is cut
    to its scored pixels' bounding box plus ``margin`` px (inside the view), pixels outside ``region``
    set to 0, and views without a scored pixel are left out. The cut views are laid one under the other
    (narrower ones centred) or side by side (shorter ones centred), whichever makes the picture
    (:func:`compensation_figure` with ``across`` tiles in a row) squarer; the rest is 0. So no band of
    unscored rows (or columns) between two views is wider than 2 * ``margin``.

    Returns one (h, w, C) float32 tile per image, in their order. Only the layout changes: every
    scored pixel appears once, with its value."""
    region = np.asarray(region, bool)
    H = region.shape[0]
    if views < 1 or H % views:
        raise ValueError(f"{H} rows are not {views} stacked views")
    h = H // views
    boxes = []
    for k in range(views):
        ys, xs = np.nonzero(region[k * h:(k + 1) * h])
        if ys.size:
            boxes.append((slice(k * h + max(int(ys.min()) - margin, 0), k * h + min(int(ys.max()) + 1 + margin, h)),
                          slice(max(int(xs.min()) - margin, 0), min(int(xs.max()) + 1 + margin, region.shape[1]))))
    if not boxes:
        raise ValueError("no scored pixel in any view")
    sizes = [(b[0].stop - b[0].start, b[1].stop - b[1].start) for b in boxes]
    tall = (sum(s[0] for s in sizes), max(s[1] for s in sizes))
    wide = (max(s[0] for s in sizes), sum(s[1] for s in sizes))
    # the picture: ``across`` tiles in a row, twice (views, differences) over the enlarged crop's row
    # (a twelfth of the scored pixels at 3:2, 4x); the same crop for both layouts
    n = int(region.sum())
    cw, ch = 4 * math.sqrt(n * CROP_ASPECT / CROP_SHARE), 4 * math.sqrt(n / CROP_ASPECT / CROP_SHARE)

    def oblong(size: tuple[int, int]) -> float:
        return abs(math.log(across * max(size[1], cw) / (2 * size[0] + ch)))

    side_by_side = oblong(wide) < oblong(tall)
    out_h, out_w = wide if side_by_side else tall
    out = []
    for img in images:
        a = _channels(img)
        if a.shape[:2] != region.shape:
            raise ValueError(f"image {a.shape[:2]} differs from the region's {region.shape}")
        tile = np.zeros((out_h, out_w, a.shape[2]), np.float32)
        at = 0
        for (ys, xs), (bh, bw) in zip(boxes, sizes):
            cut = np.where(region[ys, xs][:, :, None], a[ys, xs], 0)
            if side_by_side:
                y = (out_h - bh) // 2
                tile[y:y + bh, at:at + bw] = cut
                at += bw
            else:
                x = (out_w - bw) // 2
                tile[at:at + bh, x:x + bw] = cut
                at += bh
        out.append(tile)
    return out


# ------------------------------------------------------------------------------------------ figures
def detail_window(target: np.ndarray, captured: np.ndarray, size: tuple[int, int]) -> tuple[int, int, int, int]:
    """Where the blur shows most: the (x0, y0, x1, y1) window of ``size`` (w, h) px inside the images
    ((H, W[, C]) float) with the largest mean |captured - target| (over its pixels and channels)."""
    err = np.abs(np.asarray(captured, np.float32) - np.asarray(target, np.float32))
    if err.ndim == 3:
        err = err.mean(axis=2)
    return _worst_window(err, size)


def _worst_window(err: np.ndarray, size: tuple[int, int]) -> tuple[int, int, int, int]:
    """The window of ``size`` (w, h) inside ``err`` ((H, W) float32, no NaN) with the largest mean."""
    w, h = min(size[0], err.shape[1]), min(size[1], err.shape[0])
    mean = cv2.boxFilter(err, -1, (w, h), normalize=True, borderType=cv2.BORDER_CONSTANT)
    # a centre whose window lies inside the image: (w // 2 .. W - (w - w // 2)), likewise for h
    valid = mean[h // 2:err.shape[0] - (h - h // 2) + 1, w // 2:err.shape[1] - (w - w // 2) + 1]
    cy, cx = np.unravel_index(int(np.argmax(valid)), valid.shape)
    return int(cx), int(cy), int(cx) + w, int(cy) + h


def error_scale(err: np.ndarray) -> float:
    """A round full scale for an |error| map (NaN: not scored): its 99th percentile, rounded up to
    1, 2, 2.5 or 5 x 10^k; 0.01 when there is no error."""
    e = np.asarray(err, np.float32)
    e = e[np.isfinite(e)]
    p = float(np.percentile(e, 99)) if e.size else 0.0
    if not p > 0:
        return 0.01
    k = 10.0 ** math.floor(math.log10(p))
    return next(m * k for m in (1, 2, 2.5, 5, 10) if p <= m * k + 1e-12)


def _bar(height: int, full_scale: float) -> np.ndarray:
    """A vertical TURBO colour bar with 5 ticks labelled 0 .. ``full_scale`` (the top row), on white."""
    bar_w, width = 18, 18 + 70
    out = np.full((height, width, 3), PAPER, np.uint8)
    levels = np.round((1.0 - (np.arange(height) + 0.5) / height) * 255).astype(np.int64)
    out[:, :bar_w] = turbo_lut()[levels][:, None, :]
    cv2.rectangle(out, (0, 0), (bar_w - 1, height - 1), INK, 1)
    for k in range(5):
        y = int(round((1 - k / 4) * (height - 1)))
        cv2.line(out, (bar_w, y), (bar_w + 4, y), INK, 1)
        label = f"{full_scale * k / 4:.3g}" + ("+" if k == 4 else "")
        put_text(out, label, (bar_w + 7, min(max(y, 6), height - 7)))
    return out


def _channels(img: np.ndarray) -> np.ndarray:
    a = np.asarray(img, np.float32)
    return a[:, :, None] if a.ndim == 2 else a


def compensation_figure(target: np.ndarray, captures: Mapping[str, np.ndarray], scores: Mapping[str, Mapping],
                        *, title: Sequence[str] = (), mask: np.ndarray | None = None,
                        crop: tuple[int, int] | None = None, zoom: int = 4,
                        origin: tuple[int, int] | None = None) -> tuple[np.ndarray, dict]:
    """The compensation, readable at a glance (BGR uint8 picture, and what it shows).

    Parameters
    ----------
    target : (h, w) or (h, w, C) float32, C 1 or 3
        What the camera should see, linear, 1 = the target level (the scored region's tile).
    captures : {"none": ..., ["baseline": ...,] "ours": ...}, each like ``target``
        What it saw for each result (linear, same scale; clipped to [0, 1] as the scores clip them),
        left to right in this order. ``"none"`` is needed: the crop goes where it differs most from
        the target and the colour scale fits its error.
    scores : {key: {"psnr": dB, "ssim": ...}} for each key of ``captures``
    title : caption lines above the picture (what is seen, by which camera)
    mask : (h, w) bool, optional
        The scored pixels (default: all); the others are grey in the difference images and left out
        of the mean errors, the colour scale and the crop's choice.
    crop : (w, h) tile px of the crop; default 1 / :data:`CROP_SHARE` of the scored pixels, 3:2 (a quarter
        of the width by a third of the height of a 2:1 view scored everywhere)
    zoom : the crop's enlargement over the full-size tiles
    origin : the tile's top left corner in camera px (the crop's caption says where it is), or None

    Tiles below :data:`~imaging.compensation.quality.MIN_PICTURE_HEIGHT` px high are shown enlarged by a whole factor (nearest
    neighbour). Returns the picture and ``{"window": [x0, y0, x1, y1]`` (tile px), ``"window_camera_px"``
    (plus ``origin``, when given), ``"full_scale"`` (the difference colour bar's top; 1 is white,
    the target level), ``"mean_error"`` {key: mean |captured - target| over the scored pixels and channels},
    ``"enlarged"`` (the full-size tiles' factor) and ``"zoom"`` (the crop's, over tile px)``}``.
    """
    if "none" not in captures:
        raise ValueError(f"captures need 'none' (without compensation), got {sorted(captures)}")
    t = _channels(target)
    h, w = t.shape[:2]
    keys = list(captures)
    seen = {}
    for k in keys:
        c = _channels(captures[k])
        if c.shape[:2] != (h, w):
            raise ValueError(f"capture {k!r} is {c.shape[:2]}, the target {(h, w)}")
        seen[k] = np.clip(c, 0.0, 1.0)
    inside = np.ones((h, w), bool) if mask is None else np.asarray(mask, bool)
    if inside.shape != (h, w):
        raise ValueError(f"mask {inside.shape} differs from the tiles' {(h, w)}")
    err = {}
    for k in keys:
        e = np.abs(seen[k] - t).mean(axis=2).astype(np.float32)
        e[~inside] = np.nan
        err[k] = e
    scale = error_scale(err["none"])
    mean = {k: float(np.nanmean(e)) if inside.any() else 0.0 for k, e in err.items()}
    if crop is None:
        # a twelfth of the scored pixels, 3 wide to 2 high: on a table's 2:1 view a quarter of the width by
        # a third of the height; on a mesh's (cameras stacked, much of them unscored) a detail, not a strip
        n = int(inside.sum()) or h * w
        crop = (int(math.sqrt(n * CROP_ASPECT / CROP_SHARE)), int(math.sqrt(n / CROP_ASPECT / CROP_SHARE)))
    cw, ch = min(w, max(8, crop[0])), min(h, max(8, crop[1]))
    x0, y0, x1, y1 = _worst_window(np.nan_to_num(err["none"], nan=0.0), (cw, ch))

    f = enlargement(h)
    mag = zoom * f

    def big(img: np.ndarray, factor: int) -> np.ndarray:
        return img if factor == 1 else cv2.resize(img, (img.shape[1] * factor, img.shape[0] * factor),
                                                  interpolation=cv2.INTER_NEAREST)

    def marked(img: np.ndarray) -> np.ndarray:
        out = big(img, f).copy()          # the views stay unmarked: the crops are cut from them
        cv2.rectangle(out, (x0 * f - 1, y0 * f - 1), (x1 * f, y1 * f), CROP_BGR, 2)
        return out

    def named(k: str) -> str:
        s = scores.get(k) or {}
        figures = f": PSNR {s['psnr']:.2f} dB, SSIM {s['ssim']:.3f}" if "psnr" in s and "ssim" in s else ""
        return RESULT_NAMES.get(k, k) + figures

    size_note = "full size" if f == 1 else f"enlarged {f}x"
    where = (f"camera px x {origin[0] + x0}..{origin[0] + x1}, y {origin[1] + y0}..{origin[1] + y1} (yellow box above)"
             if origin is not None else f"tile px x {x0}..{x1}, y {y0}..{y1} (yellow box above)")
    views = {"target": camera_view_srgb(t), **{k: camera_view_srgb(seen[k]) for k in keys}}
    full = row([panel(marked(views["target"]), ["target (what the camera should see)", size_note])]
               + [panel(marked(views[k]), [named(k), size_note]) for k in keys])
    zoomed = row([panel(big(v[y0:y1, x0:x1], mag), [f"{name}, enlarged {mag}x", where])
                  for name, v in [("target", views["target"])] + [(RESULT_NAMES.get(k, k), views[k]) for k in keys]])
    diffs = [panel(marked(colourise(err[k], scale)),
                   [f"|{RESULT_NAMES.get(k, k)} - target|: mean {mean[k]:.4f}",
                    f"colour 0 (blue) .. {scale:g}+ (red) of white" + (", grey: not scored"
                                                                                   if mask is not None else "")])
             for k in keys]
    bar = panel(_bar(h * f, scale), ["|error|", ""])
    lines = list(title) + [f"Top: {size_note}. Middle: the detail where the blur costs most, enlarged {mag}x. "
                           "Bottom: the error per pixel, one colour scale for all."]
    head = caption_band(max([full.shape[1]] + [text_width(x, 0.55) for x in lines]), lines, scale=0.55)
    picture = column([head, full, zoomed, row(diffs + [bar])])
    shown = {"window": [x0, y0, x1, y1]}
    if origin is not None:
        shown["window_camera_px"] = [origin[0] + x0, origin[1] + y0, origin[0] + x1, origin[1] + y1]
    shown.update({"full_scale": scale, "mean_error": {k: round(v, 5) for k, v in mean.items()},
                  "enlarged": f, "zoom": mag})
    return picture, shown
