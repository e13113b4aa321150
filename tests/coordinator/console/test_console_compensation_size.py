"""The compensation picture is shown across the whole pictures panel, not in half of it: its
enlarged crop and error maps are what an operator reads, and at half width (about 600 px for a
~2000 px picture on a 1280x800 window) they were too small to read without opening the picture.

A real coordinator serves its console to headless Chromium in a 1280x800 window; the rig holds a
compensation picture drawn by the compensate job's own code (from float tiles the size of the
virtual room's scored region), so the picture has a real job's size. What is measured is the
layout Chromium computed (the picture's box against the panel's), not pixels.
"""
from __future__ import annotations

import asyncio
import json

import cv2
import numpy as np

from bench.compensation_room import demo_image
from bench.console import chromium, log_in, visible, wait_for
from coordinator.compensation.evaluation import quality_picture
from coordinator.rig import Rig, grid_slots, init_rig
from inprocess_coordinator import inprocess_coordinator

TOKEN = b"q" * 32
WINDOW = (1280, 800)
#: the scored region of the virtual room's table in camera px (what bench console_shots' workflow scores)
REGION = {"region": {"x": [31, 358], "y": [67, 228]}}


def write_compensation(rig_dir) -> tuple[int, int]:
    """``compensation/quality.png`` and ``quality.json`` as the compensate job leaves them; the picture's (w, h)."""
    x0, x1 = REGION["region"]["x"]
    y0, y1 = REGION["region"]["y"]
    target = (demo_image((x1 - x0, y1 - y0)).astype(np.float32) / 255) ** 2.2    # (h, w, 3) float32, linear
    none = cv2.GaussianBlur(target, (0, 0), 1.5)
    ours = 0.5 * (target + none)
    scores = {"none": {"psnr": 29.9, "ssim": 0.937}, "ours": {"psnr": 32.3, "ssim": 0.957}}
    png, shown = quality_picture([target, none, ours], ["none", "ours"], scores, REGION, "astronaut.png")
    cdir = rig_dir / "compensation"
    cdir.mkdir(parents=True, exist_ok=True)
    (cdir / "quality.png").write_bytes(png)
    (cdir / "quality.json").write_text(json.dumps({**scores, "image": "astronaut.png", "picture_shows": shown,
                                                   "ordering": {"ours_minus_none_db": 2.4}}))
    picture = cv2.imdecode(np.frombuffer(png, np.uint8), cv2.IMREAD_COLOR)
    return picture.shape[1], picture.shape[0]


BOXES = """
const box = (sel) => { const r = document.querySelector(sel).getBoundingClientRect(); return {x: r.left, w: r.width}; };
const img = document.getElementById('pic-compensation-img');
return {img: box('#pic-compensation-img'), natural: img.naturalWidth, grid: box('#pictures-panel .pictures'),
        camera: box('#pic-camera'), window: window.innerWidth,
        page: document.documentElement.scrollWidth};
"""


def measure(url: str, token: str, profile, picture_w: int) -> dict:
    driver = chromium(profile, size=WINDOW)
    try:
        driver.get(url)
        log_in(driver, token)
        wait_for(lambda: visible(driver, "main-view"), 60, "the console after login")
        driver.execute_script("document.getElementById('pictures-panel').scrollIntoView();")
        wait_for(lambda: driver.execute_script(
            "const i = document.getElementById('pic-compensation-img');"
            "return !i.hidden && i.complete && i.naturalWidth === arguments[0];", picture_w), 60,
            "the compensation picture loaded")
        return driver.execute_script(BOXES)
    finally:
        driver.quit()


def test_the_compensation_picture_spans_the_pictures_panel_on_a_1280_window(tmp_path, browser_ready):
    rig_dir = init_rig(tmp_path / "rig", name="sizes", slots=grid_slots(2, 2), width=64, height=48,
                       content_width=64, content_height=48)
    picture_w, _ = write_compensation(rig_dir)

    async def go() -> dict:
        async with inprocess_coordinator(Rig(rig_dir), TOKEN, console="127.0.0.1:0") as app:
            url = f"http://127.0.0.1:{app.console_port}/"
            return await asyncio.to_thread(measure, url, TOKEN.decode(), tmp_path / "chromium-profile", picture_w)

    m = asyncio.run(go())
    grid, img = m["grid"], m["img"]
    assert picture_w > grid["w"], f"the picture ({picture_w} px) is wider than the panel ({grid['w']} px): scaled down"
    # the whole width of the panel (the old layout gave it one of two columns: 0.49 of it)
    assert img["w"] >= grid["w"] - 2 and abs(img["x"] - grid["x"]) <= 1, m
    # nothing runs off the window, and the camera view beside it keeps a usable column
    assert m["page"] <= m["window"], m
    assert m["camera"]["w"] >= 400, m
