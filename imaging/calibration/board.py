"""The printable ChArUco board: its layout on a sheet of paper, the page image and the PDF.

``shadowless rig board`` writes what this module makes: a page (PNG and PDF, both at a stated
physical size) with the board centred on it, and the board's description (:class:`CharucoSpec`
as JSON), which the calibrate job reads to map the table into the camera
(:func:`imaging.calibration.planar.detect_charuco`). :data:`DEFAULT_BOARD` is what the command
prints without options, and what calibrate looks for on the table when the rig holds no board
description of its own.

Sizes are millimetres; a page image of ``dpi`` dots per inch has ``round(mm / 25.4 * dpi)``
pixels along each side, so the board printed at 100 % ("actual size") measures what its
description says.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path
from typing import BinaryIO

import numpy as np

from imaging.calibration.errors import CalibrationError
from imaging.calibration.planar import CharucoSpec

__all__ = ["PAPERS", "DEFAULT_BOARD", "BoardPage", "board_page", "spec_dict", "page_image", "write_png", "write_pdf",
           "describe"]

#: paper sizes (width, height) in mm, portrait; a board is laid out on the landscape side
PAPERS: dict[str, tuple[float, float]] = {
    "A4": (210.0, 297.0), "A3": (297.0, 420.0), "A2": (420.0, 594.0), "A1": (594.0, 841.0), "A0": (841.0, 1189.0),
    "letter": (215.9, 279.4), "tabloid": (279.4, 431.8),
}

#: the unprinted border kept around the board (mm): printers do not reach the sheet's edge, and the
#: markers need a quiet zone around them
MARGIN_MM = 15.0
#: a marker's side as a fraction of its square's
MARKER_RATIO = 0.75


@dataclass(frozen=True)
class BoardPage:
    """A board on a sheet: the board (its squares in mm, its place on the table) and the sheet
    (landscape ``paper_mm`` = (width, height)), the board centred on it."""

    spec: CharucoSpec
    paper: str
    paper_mm: tuple[float, float]

    @property
    def board_mm(self) -> tuple[float, float]:
        return self.spec.squares_x * self.spec.square_mm, self.spec.squares_y * self.spec.square_mm

    @property
    def offset_mm(self) -> tuple[float, float]:
        """Where the board's top-left corner lies on the sheet (mm from its top-left corner)."""
        (pw, ph), (bw, bh) = self.paper_mm, self.board_mm
        return (pw - bw) / 2, (ph - bh) / 2


def board_page(paper: str = "A3", *, squares: tuple[int, int] = (11, 7), square_mm: float | None = None,
               centre_mm: tuple[float, float] = (0.0, 0.0), dictionary: str = "DICT_5X5_100",
               check_dictionary: bool = True) -> BoardPage:
    """Lay a board of ``squares`` (columns, rows) out on ``paper`` (landscape), its squares
    ``square_mm`` wide (default: the largest whole millimetre that fits within the margins), its
    centre at ``centre_mm`` on the table (world x, y). Raises CalibrationError, one line, when the
    paper is unknown or the board does not fit. ``check_dictionary`` builds the board with OpenCV to
    refuse an unknown dictionary or one with too few markers (what importing this module skips)."""
    if paper not in PAPERS:
        raise CalibrationError(f"unknown paper {paper!r} (known: {', '.join(PAPERS)})")
    h, w = PAPERS[paper]                      # landscape
    sx, sy = squares
    if sx < 3 or sy < 3:
        raise CalibrationError(f"a board needs at least 3x3 squares, got {sx}x{sy}")
    fits = min((w - 2 * MARGIN_MM) / sx, (h - 2 * MARGIN_MM) / sy)
    if square_mm is None:
        square_mm = float(math.floor(fits))
    if not (square_mm > 0 and math.isfinite(square_mm)):
        raise CalibrationError(f"square size must be a positive number of mm, got {square_mm!r}")
    if square_mm > fits + 1e-9:
        raise CalibrationError(f"{sx}x{sy} squares of {square_mm:g} mm ({sx * square_mm:g} x {sy * square_mm:g} mm) do "
                               f"not fit on {paper} ({w:g} x {h:g} mm with {MARGIN_MM:g} mm margins): at most "
                               f"{math.floor(fits * 10) / 10:g} mm squares, or a larger --paper")
    if square_mm < 10:
        raise CalibrationError(f"squares of {square_mm:g} mm are too small for a camera to read across a table: "
                               "use a larger --paper or fewer --squares")
    marker = round(square_mm * MARKER_RATIO, 1)
    cx, cy = centre_mm
    spec = CharucoSpec(squares_x=sx, squares_y=sy, square_mm=float(square_mm), marker_mm=float(marker),
                       dictionary=dictionary, origin_mm=(cx - sx * square_mm / 2, cy + sy * square_mm / 2))
    spec = CharucoSpec.from_dict(spec_dict(spec))           # the same checks a board file gets
    if check_dictionary:
        spec.board()                                        # an unknown dictionary or too few markers: now
    return BoardPage(spec, paper, (w, h))


def spec_dict(spec: CharucoSpec) -> dict:
    """The board's description as JSON (what calibrate's ``charuco`` option and RIG/board.json hold)."""
    return {"squares_x": spec.squares_x, "squares_y": spec.squares_y, "square_mm": spec.square_mm,
            "marker_mm": spec.marker_mm, "dictionary": spec.dictionary,
            "origin_mm": [float(spec.origin_mm[0]), float(spec.origin_mm[1])], "legacy": spec.legacy}


#: what ``shadowless rig board`` prints without options, and what calibrate looks for without a board file
DEFAULT_BOARD: CharucoSpec = board_page(check_dictionary=False).spec


def _px(mm: float, dpi: float) -> int:
    return int(round(mm / 25.4 * dpi))


def page_image(page: BoardPage, *, dpi: float = 300.0) -> np.ndarray:
    """The sheet as a (H, W) uint8 image (0 black, 255 white) at ``dpi``: the board centred on
    white, and a caption in the bottom margin saying what it is and the size each square must
    measure once printed."""
    import cv2

    pw, ph = page.paper_mm
    W, H = _px(pw, dpi), _px(ph, dpi)
    bw, bh = page.board_mm
    ox, oy = page.offset_mm
    x0, y0 = _px(ox, dpi), _px(oy, dpi)
    board = page.spec.board().generateImage((_px(bw, dpi), _px(bh, dpi)), marginSize=0)
    img = np.full((H, W), 255, np.uint8)
    img[y0:y0 + board.shape[0], x0:x0 + board.shape[1]] = board
    scale = max(0.4, dpi / 300.0 * 1.1)
    text = (f"{describe(page)}  -  print at 100 % (actual size): each square must measure {page.spec.square_mm:g} mm. "
            "This edge faces the table's front (-y).")
    (tw, th), _ = cv2.getTextSize(text, cv2.FONT_HERSHEY_SIMPLEX, scale, max(1, int(scale * 2)))
    if tw > W - 2 * x0:                      # a small sheet: a smaller caption
        scale *= (W - 2 * x0) / tw
    baseline_y = y0 + board.shape[0] + max(int(th * 1.8), _px(5, dpi))
    if baseline_y < H - _px(2, dpi):
        cv2.putText(img, text, (x0, baseline_y), cv2.FONT_HERSHEY_SIMPLEX, scale, 0, max(1, int(scale * 2)),
                    cv2.LINE_8)
    return img


def describe(page: BoardPage) -> str:
    """One line: ``ChArUco 11x7, 35 mm squares (26.2 mm markers, DICT_5X5_100): 385 x 245 mm on A3 (420 x 297 mm)``."""
    s = page.spec
    bw, bh = page.board_mm
    pw, ph = page.paper_mm
    return (f"ChArUco {s.squares_x}x{s.squares_y}, {s.square_mm:g} mm squares ({s.marker_mm:g} mm markers, "
            f"{s.dictionary}): {bw:g} x {bh:g} mm on {page.paper} ({pw:g} x {ph:g} mm)")


def _target(out):
    return str(out) if isinstance(out, (str, Path)) else out


def write_png(out: str | Path | BinaryIO, img: np.ndarray, *, dpi: float) -> None:
    """The page as a PNG whose pHYs chunk states ``dpi``, so a viewer prints it at its size."""
    from PIL import Image

    Image.fromarray(img).save(_target(out), format="PNG", dpi=(dpi, dpi))


def write_pdf(out: str | Path | BinaryIO, img: np.ndarray, page: BoardPage, *, dpi: float) -> None:
    """The page as a one-page PDF of exactly the sheet's size (the image at ``dpi``, bilevel and
    losslessly compressed), its title and subject stating the board and its physical size."""
    from PIL import Image

    bilevel = Image.fromarray(np.where(img >= 128, 255, 0).astype(np.uint8)).convert("1", dither=Image.Dither.NONE)
    bilevel.save(_target(out), format="PDF", resolution=float(dpi),
                 title=f"ChArUco board {page.spec.squares_x}x{page.spec.squares_y}, {page.spec.square_mm:g} mm squares",
                 subject=describe(page) + "; print at 100 % (actual size)",
                 keywords="ChArUco, calibration, shadowless", creator="shadowless rig board")

