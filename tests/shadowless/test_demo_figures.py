"""The demo's pictures explain themselves (issue 38): the teaser's tiles say what P1 and P25 are and
the light drop is drawn on the table in mm with a colour bar. Built here from made-up captures whose
answers are known; `make demo` draws them from the room's. (Its compensation picture is the compensate
job's own: tests/imaging/compensation/test_quality_figure.py.)"""
from __future__ import annotations

import numpy as np

from shadowless.demo import serve_hint
from shadowless.demo_figures import TEASER_CAPTIONS, drop_on_table, light_drop_figure, teaser_figure

TABLE = (1200.0, 600.0)


def top_down_camera(size=(640, 400), mm_per_px=2.0) -> np.ndarray:
    """(3, 4) camera matrix looking straight down at the table: x right, y up in the image's -v."""
    w, h = size
    return np.array([[1 / mm_per_px, 0, 0, w / 2], [0, -1 / mm_per_px, 0, h / 2], [0, 0, 0, 1.0]])


def test_the_light_drop_is_drawn_on_the_table_in_mm_with_its_colour_bar():
    cam = top_down_camera()
    drop = np.zeros((400, 640), np.float32)
    u, v = 320 + 300 / 2, 200 - 100 / 2           # table (300, 100) mm in the camera
    drop[int(v) - 10:int(v) + 10, int(u) - 10:int(u) + 10] = 1.0     # a 40 x 40 mm umbra
    on_table = drop_on_table(drop, cam, TABLE, mm_per_px=2.0)
    assert on_table.shape == (300, 600)
    ys, xs = np.nonzero(on_table > 0.5)
    x_mm, y_mm = -600 + (xs.mean() + 0.5) * 2, 300 - (ys.mean() + 0.5) * 2
    assert abs(x_mm - 300) < 3 and abs(y_mm - 100) < 3, (x_mm, y_mm)

    picture, layouts = light_drop_figure({"P1": drop, "P25": drop * 0.3}, cam, hand_mm=(300, 100), hand_height_mm=200)
    assert picture.dtype == np.uint8 and picture.shape[2] == 3
    for name, lay in layouts.items():
        assert lay["units"] == "table mm" and lay["extent"] == [-600, 600, 300, -300] and lay["full_scale"] == 100
        x0, y0, x1, y1 = lay["map"]
        assert (x1 - x0, y1 - y0) == (600, 300), name       # 2 mm a pixel
        assert lay["colorbar"][3] - lay["colorbar"][1] >= 300
    assert picture.shape[1] >= 2 * 600 + 2 * 100, picture.shape


def test_the_teaser_says_what_p1_and_p25_are_on_each_tile():
    shots = {(n, h): np.full((120, 160, 3), 0.5, np.float32) for n in ("P1", "P25") for h in (False, True)}
    picture = teaser_figure(shots, 200.0)
    assert picture.shape[0] > 2 * 120 and picture.shape[1] > 2 * 160
    words = {k: " ".join(v) for k, v in TEASER_CAPTIONS.items()}
    assert all("one bright projector" in words[("P1", h)] and "25 projectors" in words[("P25", h)] for h in (False, True))
    assert all("hand {h:g} m above the table" in words[(n, True)] and "no hand" in words[(n, False)] for n in ("P1", "P25"))


def test_a_plain_demo_ends_by_saying_how_to_serve_it():
    assert "shadowless demo --serve" in serve_hint(False)
    assert serve_hint(True) is None
