"""Name cards: each projector shows its own number and slot name, large, on a colour of its own,
so an operator standing in the venue sees which projector is which (``identify``; it holds until
the next show, stop or blackout). The console draws each slot's footprint with the same number
and colour (:func:`identify_marks`), so the table and the page can be matched at a glance."""
from __future__ import annotations

import colorsys
from typing import Mapping, Sequence

import numpy as np

#: the hue step between consecutive slots: the golden angle, so neighbours (consecutive slot
#: names: a row of the grid) differ most, and any number of slots get distinct hues
_GOLDEN = 0.381966011250105


def slot_colour(index: int) -> tuple[int, int, int]:
    """The RGB colour (0..255) of the slot at ``index`` in the rig's order: a saturated hue,
    ``index`` golden angles from red, bright enough to light the table."""
    r, g, b = colorsys.hsv_to_rgb((index * _GOLDEN) % 1.0, 0.85, 1.0)
    return round(255 * r), round(255 * g), round(255 * b)


def identify_marks(slots: Sequence[str]) -> dict[str, dict[str, object]]:
    """Each slot's number (1, 2, … in the rig's order) and colour (``#rrggbb``), as the name cards
    show them (for the console's layout)."""
    out: dict[str, dict[str, object]] = {}
    for i, name in enumerate(slots):
        r, g, b = slot_colour(i)
        out[name] = {"number": i + 1, "colour": f"#{r:02x}{g:02x}{b:02x}"}
    return out


def identify_cards(slots: Mapping[str, tuple[int, int]]) -> dict[str, np.ndarray]:
    """Every slot's name card: ``slots`` maps a slot's name to its projector's (width, height), in
    the rig's order (which sets its number and colour)."""
    return {name: name_card(name, w, h, number=i + 1, colour=slot_colour(i))
            for i, (name, (w, h)) in enumerate(slots.items())}


def _outlined(img: np.ndarray, text: str, org: tuple[int, int], scale: float, thick: int) -> None:
    """Black text with a white rim: readable on any colour."""
    import cv2

    font = cv2.FONT_HERSHEY_SIMPLEX
    cv2.putText(img, text, org, font, scale, (255, 255, 255), thick + max(2, thick), cv2.LINE_AA)
    cv2.putText(img, text, org, font, scale, (0, 0, 0), thick, cv2.LINE_AA)


def _fit(text: str, width: float, height: float) -> tuple[float, int, int, int, int]:
    """The scale and thickness that make ``text`` fill ``width`` x ``height``; its size and baseline."""
    import cv2

    font = cv2.FONT_HERSHEY_SIMPLEX
    (tw, th), _ = cv2.getTextSize(text, font, 1.0, 2)
    scale = max(0.3, min(width / max(tw, 1), height / max(th, 1)))
    thick = max(1, round(scale * 2.5))
    (tw, th), base = cv2.getTextSize(text, font, scale, thick)
    return scale, thick, tw, th, base


def name_card(slot: str, width: int, height: int, *, number: int | None = None,
              colour: tuple[int, int, int] | None = None) -> np.ndarray:
    """(height, width, 3) uint8, RGB.

    With ``number``: the number as large as fits 60 % of the width and 45 % of the height, the
    slot's name under it, both black with a white rim, on ``colour`` (default dark blue); without:
    the name alone, that large. A white border runs along the frame's edges (the projector's
    extent), and the name and size in small type at the bottom."""
    import cv2  # the coordinator's stack

    img = np.zeros((height, width, 3), np.uint8)
    img[:] = colour if colour is not None else (20, 30, 90)
    edge = max(2, round(0.015 * min(width, height)))
    cv2.rectangle(img, (edge // 2, edge // 2), (width - 1 - edge // 2, height - 1 - edge // 2), (255, 255, 255), edge)
    if number is not None:
        big = str(number)
        scale, thick, tw, th, base = _fit(big, 0.6 * width, 0.45 * height)
        org = ((width - tw) // 2, int(0.1 * height) + th)
        _outlined(img, big, org, scale, thick)
        s2, t2, nw, nh, _ = _fit(slot, 0.6 * width, 0.14 * height)
        _outlined(img, slot, ((width - nw) // 2, min(height - 3 * edge, org[1] + base + nh + edge)), s2, t2)
    else:
        scale, thick, tw, th, base = _fit(slot, 0.7 * width, 0.4 * height)
        _outlined(img, slot, ((width - tw) // 2, (height + th) // 2), scale, thick)
    small = f"{slot}  {width}x{height}"
    s3 = max(0.3, min(width, height) / 900)
    (sw, sh), _ = cv2.getTextSize(small, cv2.FONT_HERSHEY_SIMPLEX, s3, 1)
    cv2.putText(img, small, ((width - sw) // 2, height - 2 * edge), cv2.FONT_HERSHEY_SIMPLEX, s3, (0, 0, 0), 1,
                cv2.LINE_AA)
    return img
