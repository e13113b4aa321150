"""The blend's before/after uniformity picture: ratio images ``I / target`` in a diverging colour
map around 1, side by side on one scale, with a labelled colour bar.

The blend job stores its captures of flat white before and after blending as ratio images
(:mod:`coordinator.blend_store`, pictures ``"before"`` and ``"after"``): 1 where the light is the
target, below 1 darker, above 1 brighter, NaN where no projector reaches. This module draws them:
each value ``r`` becomes a colour of :func:`diverging_lut` at level
``round(255 * clip((r - (1 - span)) / (2 * span), 0, 1))`` (blue below the target, light grey at
it, red above), non-finite values :data:`NOT_COVERED`; the colour bar's top row is ``1 + span``,
its bottom row ``1 - span``. ``span`` is shared by the panels, so the two compare by eye.
"""
from __future__ import annotations

from typing import Mapping

import numpy as np

__all__ = ["NOT_COVERED", "SPANS", "choose_span", "colourise", "diverging_lut", "figure_png", "ratio_figure"]

#: the colour (RGB) of points no projector reaches
NOT_COVERED = (48, 48, 48)
#: the colour bar's half ranges the figure chooses from (the smallest that holds the p99 deviation)
SPANS = (0.02, 0.05, 0.1, 0.2, 0.5, 1.0)
#: the map's ends and middle (RGB): blue (darker than the target), light grey (on it), red (brighter)
_LOW, _MID, _HIGH = (np.array(c, np.float64) for c in ((59, 76, 192), (221, 221, 221), (180, 4, 38)))
#: the panels' order and titles
PANEL_TITLES = {"before": "before blending", "after": "after blending"}
_PANEL_H = 240
_PANEL_MAX_W = 420
_TITLE_H = 26
_GAP = 16
_BAR_W = 18
_LABEL_W = 64
_MARGIN = 10
_FONT_SCALE = 0.45


def diverging_lut() -> np.ndarray:
    """(256, 3) uint8 RGB: level 0 blue, 127.5 light grey, 255 red; each half linear in RGB."""
    t = np.arange(256, dtype=np.float64) / 255.0
    lower = _LOW[None] + (_MID - _LOW)[None] * np.clip(2.0 * t, 0.0, 1.0)[:, None]
    upper = _MID[None] + (_HIGH - _MID)[None] * np.clip(2.0 * t - 1.0, 0.0, 1.0)[:, None]
    rgb = np.where((t < 0.5)[:, None], lower, upper)
    return np.clip(np.rint(rgb), 0, 255).astype(np.uint8)


def choose_span(ratios: list[np.ndarray]) -> float:
    """The smallest of :data:`SPANS` at least the p99 of ``|r - 1|`` over the finite values of
    every ratio image ((h, w) float), 0.1 when none has any; the largest span when they exceed it."""
    dev = [np.abs(np.asarray(r, np.float64)[np.isfinite(r)] - 1.0) for r in ratios]
    dev = [d for d in dev if d.size]
    if not dev:
        return 0.1
    p99 = float(np.percentile(np.concatenate(dev), 99))
    return next((s for s in SPANS if s >= p99), SPANS[-1])


def colourise(ratio: np.ndarray, span: float) -> np.ndarray:
    """(h, w) float ratio image -> (h, w, 3) uint8 RGB (see the module docstring)."""
    r = np.asarray(ratio, np.float64)
    if r.ndim != 2:
        raise ValueError(f"a ratio image must be (h, w), got shape {r.shape}")
    if not span > 0:
        raise ValueError(f"the colour span must be positive, got {span}")
    finite = np.isfinite(r)
    t = np.clip((np.where(finite, r, 1.0) - (1.0 - span)) / (2.0 * span), 0.0, 1.0)
    out = diverging_lut()[np.rint(255.0 * t).astype(np.intp)]
    out[~finite] = NOT_COVERED
    return out


def _tick_label(v: float) -> str:
    s = f"{v:.3f}".rstrip("0")
    return s + "0" * max(0, 2 - len(s.partition(".")[2]))


def ratio_figure(pictures: Mapping[str, np.ndarray], *, span: float | None = None) -> tuple[np.ndarray, dict]:
    """The before/after figure.

    Parameters
    ----------
    pictures : {"before": (h, w) float, "after": (h, w) float}
        Ratio images (either may be missing; others are ignored). At least one is needed.
    span : float, optional
        The colour bar's half range; default :func:`choose_span` of the pictures.

    Returns
    -------
    image : (H, W, 3) uint8 RGB
    layout : dict
        ``size`` [W, H]; ``panels`` {name: [x0, y0, x1, y1]} (pixel rectangles, end exclusive, the
        picture stretched over them); ``colorbar`` [x0, y0, x1, y1] (top row ``1 + span``, bottom
        row ``1 - span``); ``span``; ``range`` [1 - span, 1 + span]; ``ticks`` [[value, y], ...].
    """
    import cv2  # the coordinator's stack

    names = [n for n in PANEL_TITLES if n in pictures]
    if not names:
        raise ValueError(f"no ratio picture to draw: expected {' or '.join(PANEL_TITLES)}, got {sorted(pictures)}")
    ratios = {n: np.asarray(pictures[n], np.float32) for n in names}
    for n, r in ratios.items():
        if r.ndim != 2 or r.size == 0:
            raise ValueError(f"ratio picture {n!r} must be a non-empty (h, w) array, got shape {r.shape}")
    span = choose_span(list(ratios.values())) if span is None else float(span)
    sizes = {}
    for n, r in ratios.items():
        h, w = r.shape
        ph = _PANEL_H
        pw = max(1, round(w * ph / h))
        if pw > _PANEL_MAX_W:
            pw, ph = _PANEL_MAX_W, max(1, round(h * _PANEL_MAX_W / w))
        sizes[n] = (pw, ph)
    height = _MARGIN + _TITLE_H + max(ph for _, ph in sizes.values()) + _MARGIN + 18
    x = _MARGIN
    panels = {}
    for n in names:
        pw, ph = sizes[n]
        panels[n] = [x, _MARGIN + _TITLE_H, x + pw, _MARGIN + _TITLE_H + ph]
        x += pw + _GAP
    bar_h = max(ph for _, ph in sizes.values())
    bar = [x + 4, _MARGIN + _TITLE_H, x + 4 + _BAR_W, _MARGIN + _TITLE_H + bar_h]
    width = bar[2] + _LABEL_W + _MARGIN
    fig = np.full((height, width, 3), 255, np.uint8)
    font = cv2.FONT_HERSHEY_SIMPLEX
    for n in names:
        x0, y0, x1, y1 = panels[n]
        img = colourise(ratios[n], span)
        h, w = img.shape[:2]
        interp = cv2.INTER_AREA if (x1 - x0) < w else cv2.INTER_NEAREST
        fig[y0:y1, x0:x1] = cv2.resize(img, (x1 - x0, y1 - y0), interpolation=interp)
        cv2.putText(fig, PANEL_TITLES[n], (x0, y0 - 8), font, _FONT_SCALE, (0, 0, 0), 1, cv2.LINE_AA)
    # the colour bar: row y holds the level of value 1 + span - 2 * span * (y - y0) / (h - 1)
    x0, y0, x1, y1 = bar
    rows = y1 - y0
    values = 1.0 + span - 2.0 * span * np.arange(rows) / max(1, rows - 1)
    fig[y0:y1, x0:x1] = colourise(values[:, None], span)
    ticks = []
    for v in (1.0 + span, 1.0 + span / 2, 1.0, 1.0 - span / 2, 1.0 - span):
        y = y0 + round((1.0 + span - v) / (2.0 * span) * (rows - 1))
        cv2.line(fig, (x1, y), (x1 + 4, y), (0, 0, 0), 1)
        cv2.putText(fig, _tick_label(v), (x1 + 7, min(y1 + 4, y + 4)), font, _FONT_SCALE * 0.9, (0, 0, 0), 1,
                    cv2.LINE_AA)
        ticks.append([round(v, 6), int(y)])
    cv2.putText(fig, "I / target", (x0 - 6, y0 - 8), font, _FONT_SCALE * 0.9, (0, 0, 0), 1, cv2.LINE_AA)
    cv2.putText(fig, "dark grey: no projector reaches", (_MARGIN, height - 8), font, _FONT_SCALE * 0.85, (90, 90, 90), 1,
                cv2.LINE_AA)
    layout = {"size": [width, height], "panels": panels, "colorbar": bar, "span": span,
              "range": [round(1.0 - span, 6), round(1.0 + span, 6)], "ticks": ticks}
    return fig, layout


def figure_png(pictures: Mapping[str, np.ndarray], *, span: float | None = None) -> tuple[bytes, dict]:
    """:func:`ratio_figure` encoded as PNG bytes, with its layout."""
    import cv2

    fig, layout = ratio_figure(pictures, span=span)
    ok, buf = cv2.imencode(".png", cv2.cvtColor(fig, cv2.COLOR_RGB2BGR))
    if not ok:  # pragma: no cover
        raise ValueError("cannot encode the blend figure")
    return buf.tobytes(), layout
