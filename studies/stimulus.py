"""What one side-by-side trial shows: the picture on each half of the table, each half lit only
by the projectors of its configuration.

The content is composed once per trial: the table's left half and right half each hold the
picture, fitted whole (aspect kept) inside a margin, on a surround level (the paper's study
filled the non-image area with a uniform grey; 0 is black). A slot shows the halves whose
configuration includes it and black elsewhere (:func:`slot_regions`, for the coordinator's
per-slot regions): in both configurations it shows both halves, in neither it is dark.

Left and right are the participant's, standing at the table's near edge (the content's bottom
row, world −y) and facing +y: content x grows to their right. ``mirror`` is for a participant
on the far edge: the whole content turns 180° (the pictures read upright from there) and the
halves swap.
"""
from __future__ import annotations

from typing import Iterable, Mapping, Sequence

import numpy as np

from coordinator.slot_regions import Rect


def halves(size: tuple[int, int], *, mirror: bool = False) -> tuple[Rect, Rect]:
    """The participant's (left, right) halves of content ``size = (w, h)`` as rectangles."""
    w, h = size
    if mirror:      # the near-side halves turned 180°: (x, y, a, b) -> (w - x - a, h - y - b, a, b)
        return (w - w // 2, 0, w // 2, h), (0, 0, w - w // 2, h)
    return (0, 0, w // 2, h), (w // 2, 0, w - w // 2, h)


def to_unit(image: np.ndarray) -> np.ndarray:
    """An (H, W) or (H, W, C) uint8/uint16/float image as (H, W, 3) float32 in [0, 1] (grey
    repeated, alpha dropped)."""
    img = np.asarray(image)
    scale = {np.dtype(np.uint8): 255.0, np.dtype(np.uint16): 65535.0}.get(img.dtype, 1.0)
    f = img.astype(np.float32) / np.float32(scale)
    if f.ndim == 2:
        f = f[:, :, None]
    f = f[:, :, :3]
    if f.shape[2] != 3:
        f = np.repeat(f[:, :, :1], 3, axis=2)
    return np.clip(f, 0.0, 1.0)


def compose(image: np.ndarray, size: tuple[int, int], *, margin: float = 0.05, surround: float = 0.0,
            mirror: bool = False) -> np.ndarray:
    """The trial's content: (h, w, 3) uint16 for ``size = (w, h)``, ``image`` (any of
    :func:`to_unit`'s forms) fitted whole into each half, ``margin`` (a fraction of the half's
    smaller side) all round, on ``surround`` (0..1) elsewhere."""
    import cv2  # the coordinator's stack

    if not 0.0 <= margin < 0.5 or not 0.0 <= surround <= 1.0:
        raise ValueError(f"margin must be in [0, 0.5) and surround in [0, 1], got {margin:g} and {surround:g}")
    w, h = size
    out = np.full((h, w, 3), surround, np.float32)
    src = to_unit(image)
    for x0, y0, hw, hh in halves(size):
        pad = round(margin * min(hw, hh))
        bw, bh = max(1, hw - 2 * pad), max(1, hh - 2 * pad)
        s = min(bw / src.shape[1], bh / src.shape[0])
        fw, fh = max(1, round(src.shape[1] * s)), max(1, round(src.shape[0] * s))
        interp = cv2.INTER_AREA if s < 1 else cv2.INTER_LINEAR
        fitted = cv2.resize(src, (fw, fh), interpolation=interp).reshape(fh, fw, 3)
        ox, oy = x0 + (hw - fw) // 2, y0 + (hh - fh) // 2
        out[oy:oy + fh, ox:ox + fw] = fitted
    if mirror:
        out = out[::-1, ::-1]
    return np.round(np.clip(out, 0.0, 1.0) * 65535.0).astype(np.uint16)


def slot_regions(slots: Iterable[str], left: Sequence[str], right: Sequence[str], size: tuple[int, int], *,
                 mirror: bool = False) -> Mapping[str, list[Rect]]:
    """Every slot of ``slots`` -> the halves it lights: the left one if it is in the ``left``
    configuration, the right one if in ``right``, none (black) if in neither."""
    lh, rh = halves(size, mirror=mirror)
    a, b = set(left), set(right)
    return {s: [r for r, on in ((lh, s in a), (rh, s in b)) if on] for s in slots}
