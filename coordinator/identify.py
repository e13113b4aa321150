"""Name cards: each projector shows its own slot name, large, so an operator standing in the venue
sees which projector is which (``identify``; it holds until the next show, stop or blackout)."""
from __future__ import annotations

import numpy as np


def name_card(slot: str, width: int, height: int) -> np.ndarray:
    """(height, width, 3) uint8: ``slot`` in white, as large as fits 70 % of the width and 40 % of
    the height, on dark blue, inside a yellow border along the frame's edges (the projector's
    extent), with its size in small type underneath."""
    import cv2  # the coordinator's stack

    img = np.zeros((height, width, 3), np.uint8)
    img[:] = (20, 30, 90)
    edge = max(2, round(0.015 * min(width, height)))
    cv2.rectangle(img, (edge // 2, edge // 2), (width - 1 - edge // 2, height - 1 - edge // 2), (255, 210, 0), edge)
    font = cv2.FONT_HERSHEY_SIMPLEX
    (tw, th), _ = cv2.getTextSize(slot, font, 1.0, 2)
    scale = max(0.3, min(0.7 * width / max(tw, 1), 0.4 * height / max(th, 1)))
    thick = max(1, round(scale * 2.5))
    (tw, th), base = cv2.getTextSize(slot, font, scale, thick)
    org = ((width - tw) // 2, (height + th) // 2)
    cv2.putText(img, slot, org, font, scale, (255, 255, 255), thick, cv2.LINE_AA)
    small = f"{slot}  {width}x{height}"
    s2 = max(0.3, scale / 6)
    (sw, sh), _ = cv2.getTextSize(small, font, s2, 1)
    cv2.putText(img, small, ((width - sw) // 2, min(height - 2 * edge, org[1] + base + 2 * sh)), font, s2,
                (255, 210, 0), 1, cv2.LINE_AA)
    return img
