"""Per-slot regions of a content-space show: each named slot shows the content only inside its
rectangles, black elsewhere.

Why: a side-by-side comparison on one table (the perception study of ``shadowless study run``)
shows one picture on each half, each half lit by a different set of projectors. Every node
still warps content through its own pose, so a slot's share is simply the content with
everything outside its rectangles set to black, sent to that slot alone (the frame's per-slot
content, as identify uses): no new rendering path on the nodes, and a node that joins late or
dropped the still gets its own masked copy again like any still.

A rectangle is ``(x, y, width, height)`` in content pixels of the content as fitted to the
rig's content size: columns ``x .. x + width - 1``, rows ``y .. y + height - 1``.
"""
from __future__ import annotations

from typing import Iterable, Mapping, Sequence

import numpy as np

from coordinator.rig import Content

#: (x, y, width, height) in content pixels
Rect = tuple[int, int, int, int]


def check_regions(regions: Mapping[str, Sequence[Sequence[int]]], size: tuple[int, int],
                  slots: Iterable[str]) -> dict[str, tuple[Rect, ...]]:
    """``regions`` validated against the content ``size = (w, h)`` and the rig's ``slots``:
    rectangles as tuples of ints, each non-empty and inside the content. ValueError naming the
    first slot or rectangle that is wrong."""
    w, h = size
    known = list(slots)
    out: dict[str, tuple[Rect, ...]] = {}
    for slot, rects in regions.items():
        if slot not in known:
            raise ValueError(f"slot regions name {slot!r}, which is not a slot of this rig (slots: {', '.join(known)})")
        checked = []
        for r in rects:
            if len(r) != 4 or not all(isinstance(v, (int, np.integer)) for v in r):
                raise ValueError(f"slot {slot}: a region must be 4 integers x, y, width, height; got {tuple(r)!r}")
            x, y, rw, rh = (int(v) for v in r)
            if rw <= 0 or rh <= 0 or x < 0 or y < 0 or x + rw > w or y + rh > h:
                raise ValueError(f"slot {slot}: region x={x} y={y} {rw}x{rh} is empty or leaves the {w}x{h} content")
            checked.append((x, y, rw, rh))
        out[slot] = tuple(checked)
    return out


def mask_image(image: np.ndarray, rects: Sequence[Rect]) -> np.ndarray:
    """``image`` (H, W, C), any dtype, with every pixel outside the union of ``rects`` set to 0
    (a new array of the same shape and dtype)."""
    keep = np.zeros(image.shape[:2], bool)
    for x, y, w, h in rects:
        keep[y:y + h, x:x + w] = True
    return np.where(keep[:, :, None], image, np.zeros((), image.dtype))


def masked_contents(content: Content, regions: Mapping[str, tuple[Rect, ...]]) -> dict[str, Content | None]:
    """Slot -> what it shows: ``content`` masked to its rectangles (one Content per distinct set of
    rectangles, shared by the slots that have it), or None (black) for a slot without any."""
    by_rects: dict[frozenset[Rect], Content] = {}
    out: dict[str, Content | None] = {}
    for slot, rects in regions.items():
        if not rects:
            out[slot] = None
            continue
        key = frozenset(rects)
        if key not in by_rects:
            by_rects[key] = Content(mask_image(content.image, rects), name=f"{content.name} (regions)".strip())
        out[slot] = by_rects[key]
    return out

