"""The paper's first study, the search task: what one trial lays out and what the rig projects.

Ten A5 sheets lie on the table without overlapping. Seven carry printed text; three are blank and
the rig projects text onto them. A uniform grey is projected everywhere else. The participant
names the three sheets whose text is projected.

A trial's layout (:func:`make_layout`) is drawn from its seed alone, so the same seed gives the same
layout on any machine: the table is cut into a grid of at least ten cells, each large enough for
one sheet; the sheets take ten of the cells, each turned portrait or landscape (where both fit) and
moved at random inside its cell, and three sheets are chosen for projection. Sheets are axis
aligned and numbered 0-9 in reading order as the participant sees the table (far row first, left
to right), the numbers the experimenter's picture shows and the participant answers with.

Table coordinates are millimetres from the table's near-left corner (the participant's side), x
to the right, y away from the participant. The content covers the whole table: the near edge is
the content's bottom row, as in :mod:`studies.stimulus`.

The printed sheets are not projected: the room's table has one albedo and no texture, so a dry run
in the room leaves them out of the render. They stay in the layout, so an answer has ten choices.
"""
from __future__ import annotations

import json
import math
from dataclasses import dataclass

import numpy as np

#: an A5 sheet, portrait, in mm
A5_MM = (148.0, 210.0)
SHEETS, PROJECTED = 10, 3
#: the letters the projected text is made of; the printed sheets carry text in several languages
_LETTERS = "abcdefghijklmnopqrstuvwxyzaeiou"


@dataclass(frozen=True)
class Sheet:
    """One sheet on the table: its near-left corner (x, y) and size (w, h), all in mm."""

    x: float
    y: float
    w: float
    h: float


@dataclass(frozen=True)
class SearchLayout:
    """One trial's table: ``sheets`` (ten, numbered by their index) and the indices of the three
    whose text is projected (sorted), on a table of ``table_mm = (width, depth)``."""

    seed: int
    table_mm: tuple[float, float]
    sheets: tuple[Sheet, ...]
    projected: tuple[int, ...]

    def to_json(self) -> str:
        return json.dumps({"seed": self.seed, "table_mm": list(self.table_mm), "projected": list(self.projected),
                           "sheets": [[s.x, s.y, s.w, s.h] for s in self.sheets]})

    @staticmethod
    def from_json(text: str) -> "SearchLayout":
        d = json.loads(text)
        return SearchLayout(int(d["seed"]), tuple(d["table_mm"]), tuple(Sheet(*s) for s in d["sheets"]),
                            tuple(d["projected"]))


def make_layout(seed: int, table_mm: tuple[float, float] = (1200.0, 800.0), *, sheet_mm: tuple[float, float] = A5_MM,
                sheets: int = SHEETS, projected: int = PROJECTED) -> SearchLayout:
    """The layout of trial ``seed``. ValueError in one line when the table cannot hold the sheets
    apart (each needs a cell of its own, its short side x long side, plus 20 mm)."""
    tw, th = (float(v) for v in table_mm)
    short, long_ = sorted(float(v) for v in sheet_mm)
    if not 0 < projected <= sheets:
        raise ValueError(f"need 1..{sheets} projected sheets, got {projected}")
    best = None
    for cols in range(1, sheets + 1):
        rows = math.ceil(sheets / cols)
        cw, ch = tw / cols, th / rows
        fits = min(cw, ch) >= short + 20 and max(cw, ch) >= long_ + 20
        if fits and (best is None or cols * rows < best[0] * best[1]):
            best = (cols, rows)
    if best is None:
        raise ValueError(f"a table of {tw:g} x {th:g} mm cannot hold {sheets} sheets of {short:g} x {long_:g} mm "
                         f"apart; give a larger table")
    cols, rows = best
    cw, ch = tw / cols, th / rows
    rng = np.random.default_rng(seed)
    cells = sorted(rng.choice(cols * rows, size=sheets, replace=False).tolist())
    placed = []
    for c in cells:
        col, row = c % cols, c // cols              # row 0 is the far row: reading order
        fits = [(w, h) for w, h in ((short, long_), (long_, short)) if w + 10 <= cw and h + 10 <= ch]
        w, h = fits[int(rng.integers(len(fits)))]
        x = col * cw + 5 + rng.uniform(0, cw - w - 10)
        y = th - (row + 1) * ch + 5 + rng.uniform(0, ch - h - 10)
        placed.append(Sheet(round(float(x), 1), round(float(y), 1), w, h))
    chosen = tuple(sorted(rng.choice(sheets, size=projected, replace=False).tolist()))
    return SearchLayout(int(seed), (tw, th), tuple(placed), chosen)


def sheet_rect(layout: SearchLayout, k: int, size: tuple[int, int]) -> tuple[int, int, int, int]:
    """Sheet ``k`` in content pixels of ``size = (w, h)``: (x, y, width, height), y down from the far edge."""
    s, (tw, th), (w, h) = layout.sheets[k], layout.table_mm, size
    x0, x1 = round(s.x * w / tw), round((s.x + s.w) * w / tw)
    y0, y1 = round((th - s.y - s.h) * h / th), round((th - s.y) * h / th)
    return x0, y0, max(1, x1 - x0), max(1, y1 - y0)


def text_page(size: tuple[int, int], seed: int, *, blur_px: float = 0.7) -> np.ndarray:
    """A page of text for a projected sheet: (h, w) float32 in [0, 1], dark seeded words on white
    paper in lines, blurred by ``blur_px`` (a Gaussian's sigma in pixels) so that its sharpness
    can match the printed sheets'."""
    import cv2  # the coordinator's stack

    w, h = size
    page = np.full((h, w), 255, np.uint8)       # OpenCV writes text into 8 bits only
    rng = np.random.default_rng(seed)
    scale = max(0.25, min(w, h) / 300.0)       # one type size in mm, portrait or landscape
    line = max(4, round(26 * scale))
    margin = max(1, round(0.08 * w))
    y = margin + line
    while y < h - margin:
        x = margin
        while True:
            word = "".join(rng.choice(list(_LETTERS), size=int(rng.integers(2, 9))))
            (ww, _), _ = cv2.getTextSize(word, cv2.FONT_HERSHEY_SIMPLEX, 0.6 * scale, 1)
            if x + ww > w - margin:
                break
            cv2.putText(page, word, (x, y), cv2.FONT_HERSHEY_SIMPLEX, 0.6 * scale, 25, 1, cv2.LINE_AA)
            x += ww + max(2, round(9 * scale))
        y += line
    out = page.astype(np.float32) / np.float32(255.0)
    if blur_px > 0:
        out = cv2.GaussianBlur(out, (0, 0), blur_px)
    return np.clip(out, 0.0, 1.0)


def render_content(layout: SearchLayout, size: tuple[int, int], *, grey: float = 0.5,
                   blur_px: float = 0.7) -> np.ndarray:
    """What the rig projects for ``layout``: (h, w, 3) uint16 for content ``size = (w, h)``, a page
    of text on each projected sheet, ``grey`` (0..1) everywhere else, printed sheets included (they
    are paper under the grey light)."""
    if not 0.0 <= grey <= 1.0:
        raise ValueError(f"grey must be in [0, 1], got {grey:g}")
    w, h = size
    out = np.full((h, w), grey, np.float32)
    for k in layout.projected:
        x, y, rw, rh = sheet_rect(layout, k, size)
        out[y:y + rh, x:x + rw] = text_page((rw, rh), layout.seed * 100 + k, blur_px=blur_px)
    return np.repeat(np.round(out * 65535.0).astype(np.uint16)[:, :, None], 3, axis=2)


def layout_picture(layout: SearchLayout, width: int = 900) -> np.ndarray:
    """The experimenter's picture of ``layout``: (H, width, 3) uint8 RGB, the table from the
    participant's side (near edge at the bottom), every sheet outlined with its number, the
    projected ones filled blue and marked P (the printed ones white)."""
    import cv2

    tw, th = layout.table_mm
    height = max(1, round(width * th / tw))
    pic = np.full((height, width, 3), 90, np.uint8)
    for k in range(len(layout.sheets)):
        x, y, rw, rh = sheet_rect(layout, k, (width, height))
        fill = (150, 190, 255) if k in layout.projected else (245, 245, 245)
        cv2.rectangle(pic, (x, y), (x + rw - 1, y + rh - 1), fill, -1)
        cv2.rectangle(pic, (x, y), (x + rw - 1, y + rh - 1), (0, 0, 0), 2)
        label = f"{k}P" if k in layout.projected else str(k)
        fs = max(0.5, rh / 120)
        (lw, lh), _ = cv2.getTextSize(label, cv2.FONT_HERSHEY_SIMPLEX, fs, 2)
        cv2.putText(pic, label, (x + (rw - lw) // 2, y + (rh + lh) // 2), cv2.FONT_HERSHEY_SIMPLEX, fs, (0, 0, 0), 2,
                    cv2.LINE_AA)
    cv2.putText(pic, "participant's side", (10, height - 10), cv2.FONT_HERSHEY_SIMPLEX, 0.5, (255, 255, 255), 1)
    return pic
