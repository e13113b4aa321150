"""The printable ChArUco board (`shadowless rig board`) and calibrate finding it on the table by itself.

The sheet is checked against its own description: the board found in the page image lies where the
layout puts it, at the stated millimetres (corners in closed form), and the PDF's page is the
paper's size with the board's size in its metadata. The default board is read through a camera
the room cannot offer (its table takes no texture): a synthetic 1944x1458 view of the table drawn
with OpenCV, the page warped through a perspective table -> camera homography. In the room, a board
lies on the table as the room's camera sees it (the capture times the board's reflectance through
the room's true homography, bench.calibration.board_albedo): calibrate finds the rig's board.json
board without being told and maps the table against the room's truth; with no board and nothing
saved it says so in one line."""
from __future__ import annotations

import asyncio
import json
import re

import numpy as np
import pytest
from PIL import Image

from bench.board import OBLIQUE_CAMERA, OBLIQUE_SIZE, board_view, driver_with_board
from bench.calibration import board_albedo, make_rig
from coordinator.jobs import JobError
from imaging.calibration.board import DEFAULT_BOARD, board_page, page_image
from imaging.calibration.planar import CharucoSpec, apply_homography, detect_charuco, homography_difference
from shadowless.cli import main as shadowless
from shadowless.room_driver import RoomDriver
from sim.room import Room
from sim.scene import reference_scene


def test_the_printed_board_lies_on_the_page_at_its_stated_millimetres():
    page = board_page("A4", squares=(9, 6), square_mm=25.0)
    dpi = 150.0
    img = page_image(page, dpi=dpi)
    assert img.shape == (round(210 / 25.4 * dpi), round(297 / 25.4 * dpi))     # landscape A4
    s = page.spec
    # seen straight on, the page is a table: board mm -> page px is a scale and the board's offset
    flat = CharucoSpec(squares_x=9, squares_y=6, square_mm=25.0, marker_mm=s.marker_mm, dictionary=s.dictionary,
                       origin_mm=(0.0, 0.0))
    board_xy, px = detect_charuco(img, flat)
    assert len(board_xy) == 8 * 5                                           # every inner corner
    bx, by = board_xy[:, 0], -board_xy[:, 1]                                # board mm (y down the page)
    assert np.allclose(np.mod(bx, 25.0), 0, atol=1e-9) and np.allclose(np.mod(by, 25.0), 0, atol=1e-9)
    ox, oy = page.offset_mm
    want = np.column_stack([bx + ox, by + oy]) * dpi / 25.4 - 0.5           # pixel centres at integers
    # within 0.2 mm, the page's pixel grid (0.17 mm at 150 dpi) and no drift in scale across the board
    assert np.abs(px - want).max() * 25.4 / dpi < 0.2
    assert (ox, oy) == ((297 - 225) / 2, (210 - 150) / 2)                  # centred on the sheet


def test_the_board_command_writes_pdf_png_and_json_at_the_stated_size(tmp_path, capsys):
    rig = make_rig(tmp_path / "rig", _StubRoom(), ["a"])
    assert shadowless(["rig", "board", str(rig.path), "--paper", "A1", "--at", "10,-20", "--dpi", "72"]) == 0
    out = capsys.readouterr().out
    assert "ChArUco 11x7, 73 mm squares" in out and "803 x 511 mm on A1 (841 x 594 mm)" in out
    assert "calibrate finds this board on the table by itself" in out
    doc = json.loads((rig.path / "board.json").read_text())
    spec = CharucoSpec.from_dict(doc)
    assert spec.square_mm == 73.0 and spec.origin_mm == (10 - 803 / 2, -20 + 511 / 2)
    pdf = (rig.path / "board.pdf").read_bytes()
    box = [float(v) for v in re.search(rb"/MediaBox \[ ([\d. ]+) \]", pdf).group(1).split()]
    assert abs(box[2] - 841 / 25.4 * 72) < 0.5 and abs(box[3] - 594 / 25.4 * 72) < 0.5     # points: the sheet
    assert "803 x 511 mm".encode("utf-16-be") in pdf                        # the size, in the metadata
    png = Image.open(rig.path / "board.png")
    assert png.size == (round(841 / 25.4 * 72), round(594 / 25.4 * 72)) and round(png.info["dpi"][0]) == 72
    assert shadowless(["rig", "board", str(tmp_path / "x"), "--paper", "A4", "--square-mm", "40"]) == 2
    assert "do not fit on A4" in capsys.readouterr().err and not (tmp_path / "x").exists()


class _StubRoom:
    def projector_size(self, slot):
        return (64, 40)


def test_the_default_board_is_read_by_a_camera_looking_at_the_table_at_an_angle():
    page = board_page()                                   # what `shadowless rig board` prints by default
    assert page.spec == DEFAULT_BOARD
    seen = board_view(page, OBLIQUE_CAMERA, OBLIQUE_SIZE)   # the sheet centred on the table, seen at an angle
    table_xy, px = detect_charuco(seen, DEFAULT_BOARD)
    assert len(table_xy) >= 50                                            # of 60 inner corners
    err = np.linalg.norm(px - apply_homography(OBLIQUE_CAMERA, table_xy), axis=1)
    assert np.sqrt(np.mean(err ** 2)) < 0.3, err


@pytest.fixture(scope="module")
def room():
    return Room(reference_scene())


def test_calibrate_finds_the_rigs_board_on_the_table_without_being_told(room, tmp_path, capsys):
    rig = make_rig(tmp_path / "rig", room, ["r2c2"])
    bare = RoomDriver(room, rig)
    with pytest.raises(JobError, match=r"camera 0: the table -> camera mapping needs known points or a ChArUco board "
                                       r"on the table, and no board was found \(the default board of `shadowless rig "
                                       r"board`: the ChArUco board was not found in the camera image"):
        asyncio.run(bare.run("calibrate", {"table_only": True, "settle_s": 0}))
    assert not (rig.path / "calibration" / "cameras.json").exists()
    # an A1 sheet: the room's 648x486 camera sees 0.48 px per mm of table, so the A3 default's 35 mm squares
    # span 17 px and map the table to about 0.5 px; A1's 73 mm squares map it to a few hundredths
    assert shadowless(["rig", "board", str(rig.path), "--paper", "A1", "--dpi", "72"]) == 0
    capsys.readouterr()
    albedo = board_albedo(room, CharucoSpec.from_dict(json.loads((rig.path / "board.json").read_text())))

    driver = driver_with_board(room, rig, albedo)
    mapped = asyncio.run(driver.run("calibrate", {"table_only": True, "settle_s": 0}))
    assert mapped["captures"] == 2 and mapped["slots"] == {}
    assert any(f"found the board of {rig.path / 'board.json'} on the table" in e for e in driver.events
               if isinstance(e, str))
    H = np.array(json.loads((rig.path / "calibration" / "cameras.json").read_text())["cameras"][0]["table_to_camera"])
    grid = np.array([[x, y] for x in np.linspace(-600, 600, 13) for y in np.linspace(-300, 300, 7)])
    assert homography_difference(H, room.truth.table_to_camera_homography(), grid)[0] < 0.15
