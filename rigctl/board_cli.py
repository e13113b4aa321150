"""`shadowless rig board`: print the ChArUco board that maps the table into the camera.

Writes ``board.pdf`` and ``board.png`` (the sheet at its physical size: print at 100 %) and
``board.json`` (the board's description, :mod:`imaging.calibration.board`) into a folder. Given
the rig directory itself, calibrate finds ``RIG/board.json`` and looks for that board on the
table by itself; elsewhere, pass the JSON with ``--charuco`` (or copy it into the rig).
"""
from __future__ import annotations

import argparse
import json
from pathlib import Path

from imaging.calibration.board import DEFAULT_BOARD, PAPERS, board_page, describe, page_image, spec_dict, write_pdf, write_png
from imaging.calibration.errors import CalibrationError
from coordinator.calibration.options import BOARD_FILE
from protos import cli_types
from protos.store import atomic_file, atomic_write_text

EXAMPLES = f"""\
examples:
  shadowless rig board rigs/table                       # A3, {DEFAULT_BOARD.squares_x}x{DEFAULT_BOARD.squares_y} squares of {DEFAULT_BOARD.square_mm:g} mm, into the rig
  shadowless rig board rigs/table --paper A1            # larger squares for a camera far away
  shadowless rig board prints --paper A4 --squares 9x6 --square-mm 20 --at 100,50

a square should span about 30 camera pixels or more: the larger the table in the image, the smaller the sheet
may be (the virtual room's 648x486 camera sees about 0.5 px per mm of its 1200x600 mm table: A3's 35 mm squares
span 17 px there, A1's 73 mm squares 35 px).

then: lay the sheet flat on the table, its centre at --at (default the table's centre), the caption
edge towards the front (-y); `shadowless calibrate --rig-dir rigs/table --table-only` maps the table
(it finds the board itself), remove the sheet, and `shadowless calibrate --rig-dir rigs/table`.
"""


def configure(p: argparse.ArgumentParser) -> None:
    p.description = ("Write a printable ChArUco board: board.pdf and board.png at a stated physical size (print at "
                     "100 %, actual size) and board.json, its description for calibrate. Into a rig directory, "
                     "calibrate finds the board on the table without --charuco.")
    p.epilog = EXAMPLES
    p.formatter_class = argparse.RawDescriptionHelpFormatter
    p.add_argument("dir", help="where to write board.pdf, board.png and board.json (a rig directory: calibrate reads "
                               "its board.json by itself)")
    p.add_argument("--paper", choices=list(PAPERS), default="A3", help="sheet size, landscape (default A3)")
    p.add_argument("--squares", type=cli_types.grid, default=(DEFAULT_BOARD.squares_x, DEFAULT_BOARD.squares_y),
                   metavar="COLSxROWS", help=f"chessboard squares (default {DEFAULT_BOARD.squares_x}x{DEFAULT_BOARD.squares_y})")
    p.add_argument("--square-mm", type=cli_types.number(0, 1000, lo_open=True), default=None, metavar="MM",
                   help="a square's side in mm (default: the largest whole mm that fits the sheet within 15 mm margins)")
    p.add_argument("--at", type=cli_types.pair, default=(0.0, 0.0), metavar="X,Y",
                   help="where the board's centre will lie on the table, world mm (default 0,0: the table's centre)")
    p.add_argument("--dpi", type=cli_types.int_range(72, 1200), default=300, help="resolution of the PNG and PDF (default 300)")


def run(args: argparse.Namespace) -> int:
    try:
        page = board_page(args.paper, squares=tuple(args.squares), square_mm=args.square_mm, centre_mm=tuple(args.at))
    except CalibrationError as exc:
        raise SystemExit(f"shadowless rig board: {exc}") from None
    out = Path(args.dir)
    if out.exists() and not out.is_dir():
        raise SystemExit(f"shadowless rig board: {out} is not a folder")
    img = page_image(page, dpi=args.dpi)
    with atomic_file(out / "board.png") as f:
        write_png(f, img, dpi=args.dpi)
    with atomic_file(out / "board.pdf") as f:
        write_pdf(f, img, page, dpi=args.dpi)
    atomic_write_text(out / BOARD_FILE, json.dumps(spec_dict(page.spec), indent=2) + "\n")
    s = page.spec
    print(f"wrote {out / 'board.pdf'} and board.png: {describe(page)}")
    print(f"print at 100 % (actual size), then check that a square measures {s.square_mm:g} mm")
    cx, cy = args.at
    print(f"lay it flat on the table with its centre at ({cx:g}, {cy:g}) mm and the caption edge towards the front (-y)")
    if (out / "rig.toml").exists():
        print(f"wrote {out / BOARD_FILE}: calibrate finds this board on the table by itself "
              f"(`shadowless calibrate --rig-dir {out} --table-only`, then remove the board and calibrate)")
    else:
        print(f"wrote {out / BOARD_FILE}: give it to calibrate with `--charuco {out / BOARD_FILE}`, or copy it into "
              "the rig directory, where calibrate finds it by itself")
    return 0
