"""The alignment heat map as a figure to read: the map with a colour bar, ticked axes in the map's
units (table millimetres, or camera pixels for a mesh) and each projector's outline, named.

Drawn with OpenCV alone (the coordinator has no plotting library). The figure's layout (where
the map and the colour bar sit, in figure pixels) is returned beside the PNG, so that whoever
shows it (the console) or checks it (tests) can find its parts.
"""
from __future__ import annotations

import math

import cv2
import numpy as np

from protos.spaces import content_to_table, output_outline

FONT = cv2.FONT_HERSHEY_SIMPLEX
SCALE = 0.4
LABEL_SCALE = 0.5
INK = (40, 40, 40)
NO_DATA_BGR = (128, 128, 128)
#: outline and name colours, one per projector in turn (BGR; dark, on a white halo)
OUTLINE_BGR = ((0, 0, 0), (180, 30, 150), (20, 20, 200), (150, 80, 0), (0, 110, 0), (0, 90, 190), (110, 40, 90))
#: the plot beyond the map (off the table)
OUTSIDE_BGR = (238, 238, 238)
#: how far beyond the map, in map sizes, the plot may grow to show outlines
REACH = 0.75
#: figure margins around the map (pixels): left, top, right, bottom
MARGINS = (64, 30, 112, 52)
BAR_GAP, BAR_WIDTH = 16, 18


def colourise(values: np.ndarray, full_scale: float) -> np.ndarray:
    """(h, w, 3) uint8 BGR of an (h, w) map: 0 dark blue ... ``full_scale`` and more red (OpenCV's
    TURBO), NaN grey."""
    v = np.asarray(values, np.float32)
    scaled = np.clip(np.nan_to_num(v, nan=0.0) / full_scale, 0.0, 1.0)
    img = cv2.applyColorMap((scaled * 255).astype(np.uint8), cv2.COLORMAP_TURBO)
    img[~np.isfinite(v)] = NO_DATA_BGR
    return img


def turbo_lut() -> np.ndarray:
    """(256, 3) uint8 BGR: the colour of each level 0..255."""
    return cv2.applyColorMap(np.arange(256, dtype=np.uint8).reshape(-1, 1), cv2.COLORMAP_TURBO).reshape(256, 3)


def footprint_mm(pose: np.ndarray, projector_size: tuple[int, int], content_size: tuple[int, int],
                 table_mm: tuple[float, float]) -> np.ndarray | None:
    """Where a projector's output lands on the table: (4, 2) float64 table mm, the output rectangle's
    corners (pixel edges) through the inverse of its (3, 3) content px -> projector px pose, then
    :func:`protos.spaces.content_to_table`; None when a corner lies beyond the horizon."""
    xy = output_outline(pose, projector_size, content_size)
    if xy is None:
        return None
    q = content_to_table(content_size, table_mm) @ np.vstack([xy.T, np.ones(4)])
    xy = (q[:2] / q[2]).T
    return xy if np.all(np.isfinite(xy)) and np.abs(xy).max() < 1e7 else None


def nice_ticks(lo: float, hi: float, target: int = 6) -> list[float]:
    """Round values (1, 2, 2.5 or 5 x 10^k apart) from ``lo`` to ``hi``, about ``target`` of them."""
    lo, hi = min(lo, hi), max(lo, hi)
    if not hi > lo:
        return [lo]
    raw = (hi - lo) / max(target, 1)
    p = 10.0 ** math.floor(math.log10(raw))
    step = next(k * p for k in (1, 2, 2.5, 5, 10) if raw <= k * p)
    first = math.ceil(lo / step - 1e-9) * step
    return [round(first + i * step, 10) for i in range(int(math.floor((hi - first) / step + 1e-9)) + 1)]


def _label(v: float) -> str:
    return f"{v:.10g}" if abs(v) >= 1 or v == 0 else f"{v:.3g}"


def put_text(img: np.ndarray, text: str, at: tuple[float, float], *, align: str = "left", colour=INK,
          scale: float = SCALE, outline: tuple[int, int, int] | None = None) -> None:
    """Text with its left / centre / right (``align``) and vertical centre at ``at``."""
    (tw, th), _ = cv2.getTextSize(text, FONT, scale, 1)
    x = at[0] - {"left": 0, "centre": tw / 2, "right": tw}[align]
    org = (int(round(x)), int(round(at[1] + th / 2)))
    if outline is not None:
        cv2.putText(img, text, org, FONT, scale, outline, 3, cv2.LINE_AA)
    cv2.putText(img, text, org, FONT, scale, colour, 1, cv2.LINE_AA)


def _vertical_text(img: np.ndarray, text: str, centre: tuple[int, int]) -> None:
    """Text read bottom to top, centred at ``centre``."""
    (tw, th), base = cv2.getTextSize(text, FONT, SCALE, 1)
    tile = np.full((th + base + 4, tw + 4, 3), 255, np.uint8)
    cv2.putText(tile, text, (2, th + 2), FONT, SCALE, INK, 1, cv2.LINE_AA)
    tile = cv2.rotate(tile, cv2.ROTATE_90_COUNTERCLOCKWISE)
    y0, x0 = centre[1] - tile.shape[0] // 2, centre[0] - tile.shape[1] // 2
    y0, x0 = max(0, y0), max(0, x0)
    region = img[y0:y0 + tile.shape[0], x0:x0 + tile.shape[1]]
    np.minimum(region, tile[:region.shape[0], :region.shape[1]], out=region)


def _label_spot(q: np.ndarray, text: str, taken: list, size: tuple[int, int]) -> tuple[float, float]:
    """Where to centre an outline's name: inside it near one of its corners (footprints that overlap
    have distinct corners), the first spot clear of the names already placed (``taken``, updated)."""
    (tw, th), _ = cv2.getTextSize(text, FONT, LABEL_SCALE, 1)
    half = np.array([tw / 2 + 3, th / 2 + 3])
    centre = q.mean(axis=0)
    spots = [c + f * (centre - c) for f in (0.15, 0.3) for c in q] + [centre + [0, k * 2 * half[1]] for k in range(8)]
    for spot in spots:
        at = np.clip(spot, half, np.array(size) - half)
        box = (at[0] - half[0], at[1] - half[1], at[0] + half[0], at[1] + half[1])
        if not any(box[0] < b[2] and b[0] < box[2] and box[1] < b[3] and b[1] < box[3] for b in taken):
            break
    taken.append(box)
    return float(at[0]), float(at[1])


def heatmap_figure(values: np.ndarray, extent: tuple[float, float, float, float], *, units: str,
                   full_scale: float, outlines: dict[str, np.ndarray] | None = None,
                   title: str = "alignment residual (largest of any projector)", bar_units: str = "proj. px",
                   no_data: str | None = "no dots", open_ended: bool = True) -> tuple[bytes, dict]:
    """PNG bytes of the annotated heat map, and its layout.

    The map keeps its pixels (one map pixel, one figure pixel); the plot around it grows to show
    the outlines whole (up to :data:`REACH` map sizes beyond each side; farther is clipped), the
    map's own rectangle (the table) framed.

    Parameters
    ----------
    values : (h, w) float32 residuals (projector px), NaN where no projector has dots
    extent : (left, right, top, bottom) in ``units``, as for :func:`~.alignment.heatmap`
    units : the axes' unit, e.g. "table mm" or "camera px"
    full_scale : the residual drawn full red (the colour bar's top)
    outlines : slot -> (K, 2) float polygon in ``units`` (a projector's footprint)
    bar_units : the colour bar's unit, written above it
    no_data : the legend for NaN (grey) below the colour bar, or None for no legend
    open_ended : the top label reads ``full_scale+`` (values above it are drawn full red)

    Returns
    -------
    (png, layout): layout has ``size`` [W, H] and boxes [x0, y0, x1, y1] (figure px, exclusive ends)
    ``plot`` (the axes' area), ``map`` (the heat map, ``extent``'s edges) and ``colorbar`` (its top
    row is ``full_scale``, its bottom row 0), ``outline_colours`` (slot -> "#rrggbb" of its outline
    and name), and ``extent``, ``units``, ``full_scale``.
    """
    v = np.asarray(values, np.float32)
    h, w = v.shape
    left, right, top, bottom = (float(e) for e in extent)
    sx, sy = w / (right - left), h / (bottom - top)        # map px per unit (sy < 0 for y up)
    polys = {}
    for slot, poly in (outlines or {}).items():
        p = np.asarray(poly, np.float64).reshape(-1, 2)
        p = np.stack([(p[:, 0] - left) * sx, (p[:, 1] - top) * sy], 1)     # map px, edges at 0 and w, h
        if len(p) >= 2 and np.all(np.isfinite(p)) and np.abs(p).max() < 1e6:
            polys[slot] = p
    # the plot's box in map px: the map, the outlines, a margin; within REACH map sizes
    lo, hi = np.array([0.0, 0.0]), np.array([float(w), float(h)])
    if polys:
        allp = np.vstack(list(polys.values()))
        pad = 0.03 * max(w, h)
        lo = np.minimum(lo, allp.min(axis=0) - pad)
        hi = np.maximum(hi, allp.max(axis=0) + pad)
    lo = np.floor(np.maximum(lo, [-REACH * w, -REACH * h]))
    hi = np.ceil(np.minimum(hi, [(1 + REACH) * w, (1 + REACH) * h]))
    pw, ph = int(hi[0] - lo[0]), int(hi[1] - lo[1])
    mx, my = int(-lo[0]), int(-lo[1])                    # the map's offset in the plot
    ml, mt, mr, mb = MARGINS
    fig = np.full((ph + mt + mb, pw + ml + mr, 3), 255, np.uint8)
    plot = np.full((ph, pw, 3), OUTSIDE_BGR, np.uint8)
    plot[my:my + h, mx:mx + w] = colourise(v, full_scale)
    cv2.rectangle(plot, (mx - 1, my - 1), (mx + w, my + h), INK, 1)
    taken: list[tuple[float, float, float, float]] = []
    colours = {}
    for k, (slot, p) in enumerate(polys.items()):
        q = p + [mx - 0.5, my - 0.5]                     # plot px, pixel centres at integers
        pts = np.round(q * 16).astype(np.int32).reshape(-1, 1, 2)
        colour = OUTLINE_BGR[k % len(OUTLINE_BGR)]
        colours[slot] = "#{2:02x}{1:02x}{0:02x}".format(*colour)
        cv2.polylines(plot, [pts], True, (255, 255, 255), 5, cv2.LINE_AA, shift=4)
        cv2.polylines(plot, [pts], True, colour, 2, cv2.LINE_AA, shift=4)
        put_text(plot, slot, _label_spot(q, slot, taken, (pw, ph)), align="centre", colour=colour, scale=LABEL_SCALE,
              outline=(255, 255, 255))
    x0, y0 = ml, mt
    fig[y0:y0 + ph, x0:x0 + pw] = plot
    cv2.rectangle(fig, (x0 - 1, y0 - 1), (x0 + pw, y0 + ph), INK, 1)

    # axes: ticks outwards, labels in the extent's units
    ux0, ux1 = left + lo[0] / sx, left + hi[0] / sx
    uy0, uy1 = top + lo[1] / sy, top + hi[1] / sy
    for t in nice_ticks(ux0, ux1):
        px = int(round(x0 + (t - ux0) * sx - 0.5))
        cv2.line(fig, (px, y0 + ph), (px, y0 + ph + 4), INK, 1)
        put_text(fig, _label(t), (px, y0 + ph + 13), align="centre")
    for t in nice_ticks(uy0, uy1):
        py = int(round(y0 + (t - uy0) * sy - 0.5))
        cv2.line(fig, (x0 - 5, py), (x0 - 1, py), INK, 1)
        put_text(fig, _label(t), (x0 - 8, py), align="right")
    put_text(fig, f"x ({units})", (x0 + pw / 2, y0 + ph + 34), align="centre")
    _vertical_text(fig, f"y ({units})", (12, y0 + ph // 2))
    put_text(fig, title, (x0 + pw / 2, mt / 2), align="centre")

    # the colour bar beside the plot: full scale at the top row, 0 at the bottom row
    bx0, bx1 = x0 + pw + BAR_GAP, x0 + pw + BAR_GAP + BAR_WIDTH
    levels = np.round((1.0 - (np.arange(ph) + 0.5) / ph) * 255).astype(np.int64)
    fig[y0:y0 + ph, bx0:bx1] = turbo_lut()[levels][:, None, :]
    cv2.rectangle(fig, (bx0 - 1, y0 - 1), (bx1, y0 + ph), INK, 1)
    for k in range(5):
        py = int(round(y0 + (1 - k / 4) * (ph - 1)))
        cv2.line(fig, (bx1, py), (bx1 + 4, py), INK, 1)
        put_text(fig, _label(full_scale * k / 4) + ("+" if k == 4 and open_ended else ""), (bx1 + 7, py))
    put_text(fig, bar_units, (bx0 + BAR_WIDTH / 2, y0 - 10), align="centre")
    if no_data is not None:
        sy0 = y0 + ph + 18
        cv2.rectangle(fig, (bx0, sy0 - 5), (bx0 + 10, sy0 + 5), NO_DATA_BGR, -1)
        put_text(fig, no_data, (bx0 + 14, sy0))

    ok, buf = cv2.imencode(".png", fig)
    if not ok:  # pragma: no cover
        raise ValueError("cannot encode the heat map figure")
    layout = {"size": [int(fig.shape[1]), int(fig.shape[0])], "plot": [x0, y0, x0 + pw, y0 + ph],
              "map": [x0 + mx, y0 + my, x0 + mx + w, y0 + my + h], "colorbar": [bx0, y0, bx1, y0 + ph],
              "extent": [left, right, top, bottom], "units": units, "full_scale": float(full_scale),
              "outline_colours": colours}
    return buf.tobytes(), layout


def pixel_mm(outline_mm: np.ndarray, projector_size: tuple[int, int]) -> float:
    """The mean size (mm) of a projector pixel on the table: sqrt(footprint area / pixel count)."""
    x, y = np.asarray(outline_mm, np.float64).T
    area = 0.5 * abs(float(np.dot(x, np.roll(y, -1)) - np.dot(y, np.roll(x, -1))))
    return math.sqrt(area / max(1, projector_size[0] * projector_size[1]))
