"""Test patterns in one projector's pixels: what an operator puts on chosen projectors to check
focus, keystone, overlap and colour (``shadowless pattern``, the console's pattern buttons, a
cue of kind ``pattern``).

Each pattern is defined by a rule simple enough to check pixel by pixel:

* ``white``: every pixel ``colour`` (white unless given): brightness, lamp colour, hot spots;
* ``grid``: black, with lines :func:`line_width` pixels wide starting at every :func:`grid_step`
  pixels from the left and top edges, and one along the right and bottom edges: focus across
  the frame, keystone, where neighbours overlap;
* ``crosshair``: black, with a horizontal and a vertical line through the centre and a border
  along the four edges, all :func:`line_width` wide: centring and the frame's extent;
* ``bars``: eight vertical bars of equal width (bar ``i`` covers columns ``i·w//8`` up to
  ``(i+1)·w//8``) in the order of :data:`BARS`: white, yellow, cyan, green, magenta, red,
  blue, black, each channel full or off: colour channels and cabling.

A ``label`` (the slot's name) is written large in the upper part of the frame, in a box of its
own, so the projector can be told apart on the table.
"""
from __future__ import annotations

import numpy as np

__all__ = ["BARS", "PATTERNS", "grid_step", "line_width", "test_pattern"]

#: the patterns, by name
PATTERNS = ("white", "grid", "crosshair", "bars")
#: the colour bars, left to right: full white, then the secondaries and primaries by falling
#: luminance, then black (the classic order, at 100 %)
BARS: tuple[tuple[int, int, int], ...] = (
    (255, 255, 255), (255, 255, 0), (0, 255, 255), (0, 255, 0),
    (255, 0, 255), (255, 0, 0), (0, 0, 255), (0, 0, 0),
)
#: the smallest frame a pattern is drawn for (pixels, each side)
MIN_SIDE = 8


def line_width(size: tuple[int, int]) -> int:
    """Lines of the grid and crosshair: 1 pixel up to 809 pixels on the short side, then one
    more per 540 (2 at 1080p, 4 at 2160p), so they stay visible from the floor."""
    return max(1, round(min(size) / 540))


def grid_step(size: tuple[int, int]) -> int:
    """The grid's pitch: an eighth of the short side (135 pixels at 1080p), at least 4."""
    return max(4, min(size) // 8)


def _check(name: str, size: tuple[int, int], colour) -> tuple[int, int, tuple[int, int, int]]:
    if name not in PATTERNS:
        raise ValueError(f"unknown test pattern {name!r}: choose one of {', '.join(PATTERNS)}")
    try:
        w, h = (int(v) for v in size)
    except (TypeError, ValueError):
        raise ValueError(f"size must be (width, height), got {size!r}") from None
    if w < MIN_SIDE or h < MIN_SIDE:
        raise ValueError(f"a test pattern needs at least {MIN_SIDE}x{MIN_SIDE} pixels, got {w}x{h}")
    if colour is None:
        colour = (255, 255, 255)
    rgb = tuple(int(c) for c in colour)
    if len(rgb) != 3 or any(not 0 <= c <= 255 for c in rgb):
        raise ValueError(f"colour must be three values in 0..255, got {colour!r}")
    return w, h, rgb


def test_pattern(name: str, size: tuple[int, int], *, label: str = "",
                 colour: tuple[int, int, int] | None = None) -> np.ndarray:
    """The pattern ``name`` (one of :data:`PATTERNS`) for a projector of ``size`` (width, height).

    Parameters
    ----------
    name : str
    size : (int, int)
        The projector's output, width and height in pixels (at least 8 each).
    label : str, optional
        Written in the upper part of the frame (the slot's name); "" writes nothing.
    colour : (int, int, int), optional
        RGB of ``white``'s fill and of the grid's and crosshair's lines (default white);
        the bars keep their own colours.

    Returns
    -------
    ndarray, shape (height, width, 3), uint8
        RGB, in projector pixels (row 0 at the top of the projector's frame).

    Raises
    ------
    ValueError
        An unknown name (the message names the choices), a size under 8 pixels, a bad colour.
    """
    w, h, rgb = _check(name, size, colour)
    img = np.zeros((h, w, 3), np.uint8)
    t = line_width((w, h))
    if name == "white":
        img[:] = rgb
    elif name == "grid":
        step = grid_step((w, h))
        for x in range(0, w, step):
            img[:, x:x + t] = rgb
        for y in range(0, h, step):
            img[y:y + t, :] = rgb
        img[:, w - t:] = rgb
        img[h - t:, :] = rgb
    elif name == "crosshair":
        cx, cy = w // 2 - t // 2, h // 2 - t // 2
        img[:, cx:cx + t] = rgb
        img[cy:cy + t, :] = rgb
        img[:t, :] = rgb
        img[h - t:, :] = rgb
        img[:, :t] = rgb
        img[:, w - t:] = rgb
    else:   # bars
        for i, bar in enumerate(BARS):
            img[:, i * w // len(BARS):(i + 1) * w // len(BARS)] = bar
    if label:
        _write_label(img, label)
    return img


def _write_label(img: np.ndarray, label: str) -> None:
    """``label`` in black on a white box, centred a quarter of the way down, as large as fits
    half the width and a sixth of the height (in place)."""
    import cv2  # the coordinator's stack

    h, w = img.shape[:2]
    font = cv2.FONT_HERSHEY_SIMPLEX
    (tw, th), _ = cv2.getTextSize(label, font, 1.0, 2)
    scale = max(0.3, min(0.5 * w / max(tw, 1), h / 6 / max(th, 1)))
    thick = max(1, round(scale * 2))
    (tw, th), base = cv2.getTextSize(label, font, scale, thick)
    pad = max(2, th // 4)
    x0, y0 = max(0, (w - tw) // 2 - pad), max(0, h // 4 - th // 2 - pad)
    x1, y1 = min(w - 1, x0 + tw + 2 * pad), min(h - 1, y0 + th + base + 2 * pad)
    cv2.rectangle(img, (x0, y0), (x1, y1), (255, 255, 255), -1)
    cv2.putText(img, label, (x0 + pad, y0 + pad + th), font, scale, (0, 0, 0), thick, cv2.LINE_AA)
