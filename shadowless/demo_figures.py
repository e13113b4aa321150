"""The demo's pictures, made to be read without the README: every panel captioned on the picture,
the light drop on the table in millimetres with its colour bar, and the compensation's gain shown
where it is visible (a zoomed crop and a difference image at one colour scale).

All from captures the demo already has: the camera shots of P1 and P25, the room's light-drop maps,
and the compensate job's side-by-side picture (``compensation/quality.png``, whose tiles are split
back out here; 8-bit sRGB, so a difference carries about 0.003 of quantisation).

Pictures are (H, W, 3) uint8 BGR (what ``cv2.imwrite`` takes).
"""
from __future__ import annotations

import math

import cv2
import numpy as np

from imaging.calibration.heatmap_figure import colourise, heatmap_figure, put_text, turbo_lut
from imaging.compensation.quality import linear_to_srgb, srgb_to_linear

__all__ = ["teaser_figure", "light_drop_figure", "compensation_figure", "split_quality_picture", "detail_window",
           "TEASER_CAPTIONS"]

INK = (40, 40, 40)
PAPER = (255, 255, 255)
FONT = cv2.FONT_HERSHEY_SIMPLEX
CAPTION_SCALE = 0.5
LINE_PX = 20
GAP = 10
#: the crop's outline on the full pictures (BGR)
CROP_BGR = (0, 215, 255)
#: quality.png's layout (imaging.compensation.quality.side_by_side, as coordinator.compensation.evaluation calls it)
QUALITY_GAP, QUALITY_LABEL_HEIGHT = 8, 28


def _caption_band(width: int, lines: list[str], *, scale: float = CAPTION_SCALE) -> np.ndarray:
    band = np.full((LINE_PX * len(lines) + 8, width, 3), PAPER, np.uint8)
    for k, text in enumerate(lines):
        cv2.putText(band, text, (4, LINE_PX * (k + 1) - 4), FONT, scale, INK, 1, cv2.LINE_AA)
    return band


def text_width(text: str, scale: float = CAPTION_SCALE) -> int:
    return cv2.getTextSize(text, FONT, scale, 1)[0][0] + 8


def panel(img: np.ndarray, lines: list[str]) -> np.ndarray:
    """``img`` (BGR uint8) with its caption lines above it, on white, as wide as the wider of the two."""
    width = max([img.shape[1]] + [text_width(t) for t in lines])
    body = np.full((img.shape[0], width, 3), PAPER, np.uint8)
    body[:, :img.shape[1]] = img
    return np.vstack([_caption_band(width, lines), body])


def row(panels: list[np.ndarray], gap: int = GAP) -> np.ndarray:
    """Panels left to right, tops aligned, on white."""
    h = max(p.shape[0] for p in panels)
    w = sum(p.shape[1] for p in panels) + gap * (len(panels) - 1)
    out = np.full((h, w, 3), PAPER, np.uint8)
    x = 0
    for p in panels:
        out[:p.shape[0], x:x + p.shape[1]] = p
        x += p.shape[1] + gap
    return out


def column(rows: list[np.ndarray], gap: int = GAP, margin: int = GAP) -> np.ndarray:
    """Rows top to bottom, left aligned, with a white margin all round."""
    w = max(r.shape[1] for r in rows) + 2 * margin
    h = sum(r.shape[0] for r in rows) + gap * (len(rows) - 1) + 2 * margin
    out = np.full((h, w, 3), PAPER, np.uint8)
    y = margin
    for r in rows:
        out[y:y + r.shape[0], margin:margin + r.shape[1]] = r
        y += r.shape[0] + gap
    return out


def camera_view(img: np.ndarray) -> np.ndarray:
    """A camera capture, (H, W, 3) linear float RGB, as 8-bit BGR for viewing (gamma 2.2)."""
    v = np.clip(np.asarray(img, np.float32), 0, 1) ** (1 / 2.2)
    return cv2.cvtColor((v * 255 + 0.5).astype(np.uint8), cv2.COLOR_RGB2BGR)


# ------------------------------------------------------------------------------------------ teaser
#: (setup, hand) -> caption lines of the teaser's tiles ({h}: the hand's height in m)
TEASER_CAPTIONS = {
    ("P1", False): ["P1: one bright projector at the centre", "(the usual setup), no hand"],
    ("P1", True): ["P1: one bright projector at the centre,", "hand {h:g} m above the table"],
    ("P25", False): ["P25: the 5 x 5 ceiling array, 25 projectors", "(synthetic aperture), no hand"],
    ("P25", True): ["P25: the 5 x 5 ceiling array, 25 projectors,", "hand {h:g} m above the table"],
}


def teaser_figure(shots: dict[tuple[str, bool], np.ndarray], hand_height_mm: float) -> np.ndarray:
    """P1 against P25, without and with the hand: the camera's four shots ((H, W, 3) linear float RGB,
    keyed (setup, hand)) in a 2 x 2 grid, each captioned, under a title saying what is compared."""
    h = hand_height_mm / 1000.0
    rows = [row([panel(camera_view(shots[(n, hand)]), [t.format(h=h) for t in TEASER_CAPTIONS[(n, hand)]])
                 for hand in (False, True)]) for n in ("P1", "P25")]
    title = _caption_band(rows[0].shape[1], [
        "The same image from the same total light: one projector (P1, top) against 25 (P25, bottom),",
        f"seen by the room's camera over the 1200 x 600 mm table; right: a hand {h:g} m above the table.",
    ], scale=0.55)
    return column([title] + rows)


# -------------------------------------------------------------------------------------- light drop
def table_grid_to_camera(camera_p: np.ndarray, table_mm: tuple[float, float], mm_per_px: float) -> np.ndarray:
    """(3, 3) float64: a table grid's pixel (column, row; row 0 at +y, the far edge) to camera pixels.
    The grid covers the table, ``mm_per_px`` a pixel, its pixel centres at half steps."""
    tw, th = table_mm
    grid_to_table = np.array([[mm_per_px, 0.0, -tw / 2 + mm_per_px / 2],
                              [0.0, -mm_per_px, th / 2 - mm_per_px / 2],
                              [0.0, 0.0, 1.0]])
    return np.asarray(camera_p, np.float64)[:, [0, 1, 3]] @ grid_to_table


def drop_on_table(drop: np.ndarray, camera_p: np.ndarray, table_mm=(1200.0, 600.0), mm_per_px: float = 2.0) -> np.ndarray:
    """A light-drop map in camera pixels ((H, W) float, fraction lost) resampled on the table:
    (th / mm_per_px, tw / mm_per_px) float32, row 0 at the far edge (+y)."""
    size = (int(round(table_mm[0] / mm_per_px)), int(round(table_mm[1] / mm_per_px)))
    m = table_grid_to_camera(camera_p, table_mm, mm_per_px)
    return cv2.warpPerspective(np.asarray(drop, np.float32), m, size, flags=cv2.INTER_LINEAR | cv2.WARP_INVERSE_MAP,
                               borderMode=cv2.BORDER_REPLICATE)


def light_drop_figure(drops: dict[str, np.ndarray], camera_p: np.ndarray, *, hand_mm: tuple[float, float],
                      hand_height_mm: float, table_mm=(1200.0, 600.0), mm_per_px: float = 2.0) -> tuple[np.ndarray, dict]:
    """The light drop of each setup (``drops``: name -> (H, W) camera-pixel map, fraction of the rig's
    light lost) on the table in mm, 0..100 % on one colour bar, the hand's position marked; side by side
    under a title. Returns the picture and each map's layout (:func:`heatmap_figure`'s, by name)."""
    tw, th = table_mm
    layouts, figures = {}, []
    for name, drop in drops.items():
        values = 100.0 * np.clip(drop_on_table(drop, camera_p, table_mm, mm_per_px), 0.0, 1.0)
        png, layout = heatmap_figure(values, (-tw / 2, tw / 2, th / 2, -th / 2), units="table mm", full_scale=100.0,
                                     title=f"{name}: light lost per point of the table", bar_units="% lost",
                                     no_data=None, open_ended=False)
        fig = cv2.imdecode(np.frombuffer(png, np.uint8), cv2.IMREAD_COLOR)
        mx0, my0, mx1, my1 = layout["map"]
        hx = mx0 + (hand_mm[0] + tw / 2) / tw * (mx1 - mx0)
        hy = my0 + (th / 2 - hand_mm[1]) / th * (my1 - my0)
        at = (int(round(hx)), int(round(hy)))
        cv2.drawMarker(fig, at, (255, 255, 255), cv2.MARKER_CROSS, 18, 4, cv2.LINE_AA)
        cv2.drawMarker(fig, at, (0, 0, 0), cv2.MARKER_CROSS, 18, 2, cv2.LINE_AA)
        put_text(fig, "hand", (at[0] - 12, at[1] - 14), align="right", colour=(255, 255, 255), scale=0.5,
                 outline=(0, 0, 0))
        layouts[name] = layout
        figures.append(fig)
    title = _caption_band(sum(f.shape[1] for f in figures) + GAP * (len(figures) - 1), [
        f"Light drop: how much of the rig's light a hand {hand_height_mm / 1000:g} m above the table (+ marks its palm) "
        "takes from each point of the table.",
        "0 % (dark blue): untouched; 100 % (dark red): no light at all, a hard shadow. Same scale for both setups.",
    ], scale=0.55)
    return column([title, row(figures)]), layouts


# ------------------------------------------------------------------------------------ compensation
def split_quality_picture(picture_bgr: np.ndarray, tile_size: tuple[int, int], count: int = 3) -> list[np.ndarray] | None:
    """The tiles of the compensate job's side-by-side picture (``quality.png`` read by OpenCV, BGR),
    back as (h, w, 3) float32 linear RGB in [0, 1], left to right; None when the picture is not
    ``count`` tiles of ``tile_size`` (w, h) laid out as the job lays them (each at least 240 px high,
    so not enlarged, and wider than its caption)."""
    w, h = tile_size
    if picture_bgr is None or picture_bgr.shape[:2] != (h + QUALITY_LABEL_HEIGHT + 2 * QUALITY_GAP,
                                                        count * w + (count + 1) * QUALITY_GAP) or h < 240:
        return None
    top = QUALITY_LABEL_HEIGHT + QUALITY_GAP
    rgb = cv2.cvtColor(picture_bgr, cv2.COLOR_BGR2RGB)
    return [srgb_to_linear(rgb[top:top + h, x:x + w].astype(np.float32) / 255.0)
            for x in (QUALITY_GAP + k * (w + QUALITY_GAP) for k in range(count))]


def detail_window(target: np.ndarray, captured: np.ndarray, size: tuple[int, int]) -> tuple[int, int, int, int]:
    """Where the blur shows most: the (x0, y0, x1, y1) window of ``size`` (w, h) px inside the images
    ((H, W[, C]) float) with the largest mean |captured - target| (over its pixels and channels)."""
    err = np.abs(np.asarray(captured, np.float32) - np.asarray(target, np.float32))
    if err.ndim == 3:
        err = err.mean(axis=2)
    w, h = min(size[0], err.shape[1]), min(size[1], err.shape[0])
    mean = cv2.boxFilter(err, -1, (w, h), normalize=True, borderType=cv2.BORDER_CONSTANT)
    # a centre whose window lies inside the image: (w // 2 .. W - (w - w // 2)), likewise for h
    valid = mean[h // 2:err.shape[0] - (h - h // 2) + 1, w // 2:err.shape[1] - (w - w // 2) + 1]
    cy, cx = np.unravel_index(int(np.argmax(valid)), valid.shape)
    return int(cx), int(cy), int(cx) + w, int(cy) + h


def _error_scale(err: np.ndarray) -> float:
    """A round full scale for an |error| map: the 99th percentile, up to 1, 2, 2.5 or 5 x 10^k."""
    p = float(np.percentile(err, 99)) if err.size else 0.0
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


def compensation_figure(tiles: list[np.ndarray], scores: dict[str, dict], *, crop: tuple[int, int] | None = None,
                        zoom: int = 4, origin: tuple[int, int] = (0, 0)) -> tuple[np.ndarray, dict]:
    """The compensation, readable at a glance: ``tiles`` = [target, without, compensated] ((h, w, 3)
    linear float RGB, the camera's view of the scored region) at full size with the crop marked, the
    crop (``crop`` (w, h) px; default a quarter of the width by a third of the height) where
    |without - target| is largest, enlarged ``zoom`` times, and |captured - target| of both on one
    colour scale with its bar. ``scores``: the job's ``none`` and ``ours`` PSNR/SSIM; ``origin``: the
    tiles' top left corner in camera px (the scored region's), for the crop's caption.

    Returns the picture and what it shows: ``window`` (x0, y0, x1, y1 in tile px), ``window_camera_px``
    (the same plus ``origin``), ``full_scale``
    (the difference colour bar's top), ``mean_error`` {"none", "ours"} (mean |captured - target|)."""
    target, none, ours = (np.asarray(t, np.float32) for t in tiles)
    h, w = target.shape[:2]
    cw, ch = crop or (max(8, w // 4), max(8, h // 3))
    x0, y0, x1, y1 = detail_window(target, none, (cw, ch))
    ox, oy = (int(v) for v in origin)
    err = {k: np.abs(v - target).mean(axis=2) if v.ndim == 3 else np.abs(v - target) for k, v in (("none", none), ("ours", ours))}
    scale = _error_scale(err["none"])
    n, o = scores["none"], scores["ours"]
    names = {"target": "target (what the camera should see)",
             "none": f"without compensation: PSNR {n['psnr']:.2f} dB, SSIM {n['ssim']:.3f}",
             "ours": f"compensated: PSNR {o['psnr']:.2f} dB, SSIM {o['ssim']:.3f}"}

    def marked(img: np.ndarray) -> np.ndarray:
        out = img.copy()
        cv2.rectangle(out, (x0 - 1, y0 - 1), (x1, y1), CROP_BGR, 2)
        return out

    views = [camera_view_srgb(t) for t in (target, none, ours)]
    full = row([panel(marked(v), [names[k], "full size"]) for v, k in zip(views, ("target", "none", "ours"))])
    zoomed = row([panel(cv2.resize(v[y0:y1, x0:x1], ((x1 - x0) * zoom, (y1 - y0) * zoom), interpolation=cv2.INTER_NEAREST),
                        [names[k].split(":")[0].split(" (")[0] + f", zoomed {zoom}x",
                         f"camera px x {ox + x0}..{ox + x1}, y {oy + y0}..{oy + y1} (yellow box above)"])
                  for v, k in zip(views, ("target", "none", "ours"))])
    mean = {k: float(e.mean()) for k, e in err.items()}
    diffs = [panel(marked(colourise(err[k], scale)),
                   [f"|{'without' if k == 'none' else 'compensated'} - target|: mean {mean[k]:.4f}",
                    f"colour 0 (blue) .. {scale:g}+ (red) of full white"]) for k in ("none", "ours")]
    bar = panel(_bar(h, scale), ["|error|", ""])
    title = _caption_band(full.shape[1], [
        "Blur compensation of the 25 projectors, seen by the room's camera (the scored region of the table).",
        "Top: full size. Middle: the detail where the blur costs most, enlarged. "
        "Bottom: the error per pixel, one colour scale for both.",
    ], scale=0.55)
    picture = column([title, full, zoomed, row(diffs + [bar])])
    return picture, {"window": [x0, y0, x1, y1], "window_camera_px": [ox + x0, oy + y0, ox + x1, oy + y1],
                     "full_scale": scale, "mean_error": {k: round(v, 5) for k, v in mean.items()}}


def camera_view_srgb(img: np.ndarray) -> np.ndarray:
    """A linear float RGB tile in [0, 1] as 8-bit BGR, sRGB-encoded (as the compensate job shows it)."""
    v = linear_to_srgb(np.asarray(img, np.float32))
    if v.ndim == 2:
        v = np.repeat(v[:, :, None], 3, axis=2)
    return cv2.cvtColor(np.rint(v * 255).astype(np.uint8), cv2.COLOR_RGB2BGR)
