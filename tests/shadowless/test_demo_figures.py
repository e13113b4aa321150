"""The demo's pictures explain themselves (issue 38): the teaser's tiles say what P1 and P25 are,
the light drop is drawn on the table in mm with a colour bar, and the compensation picture shows a
zoomed crop where the blur costs most and the difference to the target on one colour scale. Built
here from made-up captures whose answers are known; `make demo` draws them from the room's."""
from __future__ import annotations

import cv2
import numpy as np

from imaging.compensation.quality import side_by_side
from shadowless.demo import serve_hint
from shadowless.demo_figures import (TEASER_CAPTIONS, compensation_figure, detail_window, drop_on_table,
                                     light_drop_figure, split_quality_picture, teaser_figure)

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


def test_the_crop_goes_where_the_blur_costs_most():
    rng = np.random.default_rng(1)
    target = rng.uniform(0.2, 0.8, (278, 555, 3)).astype(np.float32)
    seen = target + rng.normal(0, 0.005, target.shape).astype(np.float32)
    seen[200:240, 400:450] += 0.2                   # the detail the blur ruins
    x0, y0, x1, y1 = detail_window(target, seen, (60, 50))
    assert (x1 - x0, y1 - y0) == (60, 50)
    assert x0 <= 400 and x1 >= 450 and y0 <= 200 and y1 >= 240, (x0, y0, x1, y1)
    edge = target.copy()
    edge[:, -5:] += 0.5                             # at the border: the window stays inside the image
    x0, y0, x1, y1 = detail_window(target, edge, (60, 50))
    assert x1 == 555 and 0 <= y0 and y1 <= 278


def test_the_compensation_picture_is_split_from_the_jobs_and_shows_crop_and_difference():
    rng = np.random.default_rng(2)
    h, w = 278, 555
    target = cv2.GaussianBlur(rng.uniform(0, 1, (h, w, 3)).astype(np.float32), (0, 0), 3)
    none = cv2.GaussianBlur(target, (0, 0), 2)
    ours = 0.5 * (target + none)
    # the job's picture as the compensate job writes it (side_by_side, RGB -> BGR PNG)
    pic = side_by_side([target, none, ours], ["target", "none 30.00 dB / 0.900", "ours 35.00 dB / 0.950"])
    ok, png = cv2.imencode(".png", cv2.cvtColor(pic, cv2.COLOR_RGB2BGR))
    tiles = split_quality_picture(cv2.imdecode(png, cv2.IMREAD_COLOR), (w, h))
    assert tiles is not None and [t.shape for t in tiles] == [(h, w, 3)] * 3
    for got, want in zip(tiles, (target, none, ours)):
        assert np.abs(got - want).max() < 0.01          # 8-bit sRGB: at most half a step
    assert split_quality_picture(cv2.imdecode(png, cv2.IMREAD_COLOR), (w - 1, h)) is None

    scores = {"none": {"psnr": 30.0, "ssim": 0.9}, "ours": {"psnr": 35.0, "ssim": 0.95}}
    picture, shown = compensation_figure(tiles, scores, origin=(46, 107))
    x0, y0, x1, y1 = shown["window"]
    assert shown["window_camera_px"] == [46 + x0, 107 + y0, 46 + x1, 107 + y1]
    assert (x1 - x0, y1 - y0) == (w // 4, h // 3) and 0 <= x0 and x1 <= w and 0 <= y0 and y1 <= h
    assert shown["mean_error"]["ours"] < shown["mean_error"]["none"]
    assert 0 < shown["full_scale"] <= 1
    # three full tiles side by side, three crops enlarged 4 times, two differences and a bar
    assert picture.shape[1] >= 3 * w and picture.shape[0] >= 2 * h + 4 * (h // 3)


def test_a_plain_demo_ends_by_saying_how_to_serve_it():
    assert "shadowless demo --serve" in serve_hint(False)
    assert serve_hint(True) is None
