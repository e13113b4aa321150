"""The console's pictures: the alignment heat map figure (colour bar, axes, outlines), the compensation
before/after picture with PSNR/SSIM and the camera's view, over HTTP and in a real browser (headless
Chromium through Selenium) against a real coordinator, real node processes and the virtual room, after
the calibrate, alignment and compensate jobs really ran there."""
from __future__ import annotations

import asyncio
import contextlib
import json
import shutil
import time
import urllib.error
import urllib.request
from dataclasses import replace
from pathlib import Path

import aiohttp
import cv2
import numpy as np
import pytest

from bench.calibration import table_points_from_truth
from bench.compensation_room import demo_image
from bench.console import ConsoleRig, chromium, log_in, visible, wait_for
from imaging.calibration.alignment import heatmap
from imaging.calibration.heatmap_figure import colourise, footprint_mm, heatmap_figure, turbo_lut
from coordinator.camera import encode_png16, open_camera
from coordinator.console import auth
from coordinator.console.pictures import CAMERA_INTERVAL_S, to_srgb
from coordinator.rig import ProjectionPose, Rig, grid_slots, init_rig, mesh_with_id
from coordinator.server import Coordinator
from shadowless.cli import main
from sim.room import Room
from sim.scene import reference_scene
from sim.wire.service import RoomServerThread
from inprocess_coordinator import inprocess_coordinator
from waits import wait_until, wait_until_async

TOKEN = b"p" * 32
SLOTS = ["r1c1", "r3c3"]
CONTENT = (200, 100)


# ---------------------------------------------------------------------- helpers
def decode(png: bytes) -> np.ndarray:
    img = cv2.imdecode(np.frombuffer(png, np.uint8), cv2.IMREAD_COLOR)
    assert img is not None, "not a PNG"
    return img


def check_colour_bar(fig: np.ndarray, layout: dict) -> None:
    """The colour bar's middle column runs through the whole colour map: full scale (TURBO's red end)
    at the top row, 0 (its dark blue end) at the bottom row, every level in order between."""
    x0, y0, x1, y1 = layout["colorbar"]
    column = fig[y0:y1, (x0 + x1) // 2].astype(np.int64)          # (h, 3) BGR
    lut = turbo_lut().astype(np.int64)                             # (256, 3) BGR
    level = np.argmin(((column[:, None, :] - lut[None]) ** 2).sum(-1), axis=1)
    err = np.abs(column - lut[level]).max()
    assert err <= 2, f"colour bar pixels off the colour map by {err}"
    assert level[0] >= 254 and level[-1] <= 1, (level[0], level[-1])
    assert np.all(np.diff(level) <= 0), "colour bar levels not decreasing downwards"


def check_outlines(fig: np.ndarray, layout: dict, outlines: dict) -> int:
    """Each outline's edges are drawn in its colour (on a white halo): returns how many points along
    the edges (a quarter, half and three quarters along) inside the plot were checked."""
    px0, py0, px1, py1 = layout["plot"]
    mx0, my0, mx1, my1 = layout["map"]
    left, right, top, bottom = layout["extent"]
    checked = 0
    for slot, poly in outlines.items():
        p = np.asarray(poly, np.float64)
        for a, b, t in [(a, b, t) for a, b in zip(p, np.roll(p, -1, axis=0)) for t in (0.25, 0.5, 0.75)]:
            m = a + t * (b - a)
            x = mx0 + (m[0] - left) / (right - left) * (mx1 - mx0) - 0.5
            y = my0 + (m[1] - top) / (bottom - top) * (my1 - my0) - 0.5
            xi, yi = int(round(x)), int(round(y))
            if not (px0 + 3 <= xi < px1 - 3 and py0 + 3 <= yi < py1 - 3):
                continue
            colour = np.array([int(layout["outline_colours"][slot][i:i + 2], 16) for i in (5, 3, 1)])   # BGR
            patch = fig[yi - 1:yi + 2, xi - 1:xi + 2].reshape(-1, 3).astype(np.int64)
            assert np.abs(patch - colour).max(axis=1).min() <= 40, f"{slot}: no outline at ({xi}, {yi}): {patch}"
            halo = fig[yi - 3:yi + 4, xi - 3:xi + 4].reshape(-1, 3).astype(np.int64)
            assert halo.min(axis=1).max() >= 200, f"{slot}: no white halo at ({xi}, {yi})"
            checked += 1
    return checked


# ---------------------------------------------------------------------- the figure itself
def test_the_heat_map_figure_has_a_colour_bar_axes_in_mm_and_each_projectors_outline():
    rng = np.random.default_rng(1)
    pts = {"a": rng.uniform([-600, -300], [100, 300], (300, 2)), "b": rng.uniform([-100, -300], [600, 300], (300, 2))}
    vals = {k: np.abs(rng.normal(0.0, 0.4, 300)) for k in pts}
    extent = (-600.0, 600.0, 300.0, -300.0)
    hm = heatmap(pts, vals, extent=extent, width=600)
    pose = np.array([[2.5, 0.05, -100.0], [0.0, 2.5, -50.0], [1e-4, 0.0, 1.0]])    # content px -> projector px
    outline = footprint_mm(pose, (320, 200), CONTENT, (1200.0, 600.0))
    # the footprint is the output rectangle seen through the pose: its corners map back onto the output's corners
    c2t = np.array([[6.0, 0, 3.0 - 600], [0, -6.0, 300 - 3.0], [0, 0, 1]])           # 200x100 px over 1200x600 mm
    back = np.linalg.inv(c2t) @ np.c_[outline, np.ones(4)].T
    proj = pose @ (back / back[2])
    np.testing.assert_allclose((proj[:2] / proj[2]).T, [[-0.5, -0.5], [319.5, -0.5], [319.5, 199.5], [-0.5, 199.5]],
                               atol=1e-6)
    outlines = {"a": outline, "b": np.array([[0.0, 250.0], [650.0, 250.0], [650.0, -350.0], [0.0, -350.0]])}
    png, layout = heatmap_figure(hm, extent, units="table mm", full_scale=1.0, outlines=outlines)
    fig = decode(png)
    assert layout["size"] == [fig.shape[1], fig.shape[0]]
    x0, y0, x1, y1 = layout["map"]
    assert (x1 - x0, y1 - y0) == (600, 300)
    # the map's pixels are the heat map's colours, one for one (bar the outlines drawn over it)
    same = (fig[y0:y1, x0:x1].astype(int) - colourise(hm, 1.0)).__abs__().max(axis=2) <= 1
    assert same.mean() > 0.9
    # the plot grew to show the outline that goes past the table's bottom right (650, -350)
    px0, py0, px1, py1 = layout["plot"]
    assert px0 == x0 and py0 == y0 and px1 - x1 > 20 and py1 - y1 > 20
    check_colour_bar(fig, layout)
    assert check_outlines(fig, layout, outlines) >= 18
    # tick labels and axis titles: ink in the margins left of and below the plot
    assert (fig[py0:py1, : px0 - 6] < 100).any() and (fig[py1 + 6:, px0:px1] < 100).any()


# ---------------------------------------------------------------------- over HTTP, nothing run yet
@contextlib.asynccontextmanager
async def console(tmp_path: Path, cameras: list[str] | None = None, prepare=None):
    rig = Rig(init_rig(tmp_path / "rig", name="pics", slots=grid_slots(1, 2), width=32, height=32,
                       content_width=64, content_height=32))
    if prepare is not None:
        prepare(rig)
    async with inprocess_coordinator(rig, TOKEN, console="127.0.0.1:0", cameras=cameras) as app:
        coord = app.coordinator
        async with aiohttp.ClientSession(cookie_jar=aiohttp.DummyCookieJar()) as s:
            base = f"http://127.0.0.1:{app.console_port}"
            r = await s.post(base + "/login", json={"token": TOKEN.decode()}, headers={"Origin": base})
            assert r.status == 200, await r.text()
            headers = {"Cookie": f"{auth.COOKIE}={r.cookies[auth.COOKIE].value}"}
            coord.console_post_headers = {**headers, "Origin": base, auth.CSRF_HEADER: (await r.json())["csrf"]}
            yield coord, s, base, headers


PATHS = ["/api/pictures", "/api/pictures/alignment.png", "/api/pictures/compensation.png",
         "/api/pictures/coverage.png", "/api/camera.png"]


def pose_on_bust(rig: Rig) -> None:
    """Give every slot of ``rig`` the room's true 3x4 pose onto the bust (what 3D calibration stores)."""
    scene = reference_scene(projector_scale=0.1, camera_scale=0.1, surface="bust")
    mesh = mesh_with_id(scene.mesh.vertices, scene.mesh.uvs, scene.mesh.faces)
    for s in rig.slots:
        p = scene.projector(s).pinhole
        rig.update_slot(s, pose=ProjectionPose(p.P, mesh), size=p.size)


def coverage_result(tmp_path: Path) -> Path:
    """``coverage/`` as `shadowless coverage` leaves it in a rig of three projectors posed onto the bust
    (a small texture and picture)."""
    d = init_rig(tmp_path / "bust-rig", name="bust", slots=["r0c0", "r2c2", "r4c4"], width=128, height=80)
    pose_on_bust(Rig(d))
    code = main(["coverage", "--rig-dir", str(d), "--texture", "96x96", "--panel", "160x160", "--json"])
    assert code == 0
    return d / "coverage"


def test_pictures_need_a_session_and_say_what_to_run_when_there_are_none(tmp_path):
    async def go():
        async with console(tmp_path) as (coord, s, base, headers):
            for path in PATHS:
                r = await s.get(base + path)
                assert r.status == 401 and "log in" in (await r.json())["error"], path
                r = await s.get(base + path, headers={"Cookie": f"{auth.COOKIE}=forged"})
                assert r.status == 401, path
            r = await s.get(base + "/api/pictures", headers=headers)
            doc = await r.json()
            assert r.status == 200 and r.headers["Cache-Control"] == "no-store"
            assert doc["alignment"] is None and doc["compensation"] is None and doc["job"] is None
            assert doc["camera"]["configured"] is False
            for path, words in (("/api/pictures/alignment.png", "run the alignment job"),
                                ("/api/pictures/compensation.png", "compensate job with evaluate"),
                                ("/api/pictures/coverage.png", "shadowless coverage"),
                                ("/api/camera.png", "no camera configured"),
                                ("/api/pictures/..%2Ftoken", "no picture")):
                r = await s.get(base + path, headers=headers)
                assert r.status == 404 and words in (await r.json())["error"], (path, await r.text())
                assert "Content-Security-Policy" in r.headers
            # a bare map from an older alignment run is served as it is, listed as not annotated
            (coord.rig.path / "calibration").mkdir(exist_ok=True)
            cv2.imwrite(str(coord.rig.path / "calibration" / "alignment.png"), np.zeros((30, 60, 3), np.uint8))
            doc = await (await s.get(base + "/api/pictures", headers=headers)).json()
            assert [m["annotated"] for m in doc["alignment"]["maps"]] == [False]
            r = await s.get(base + "/api/pictures/alignment.png", headers=headers)
            assert r.status == 200 and r.content_type == "image/png" and r.headers["Cache-Control"] == "no-store"
            assert decode(await r.read()).shape == (30, 60, 3)

    asyncio.run(go())


async def finished(coord: Coordinator) -> dict:
    """The current job's snapshot once it is no longer running (bounded: 120 s)."""
    return await wait_until_async(coord.jobs.snapshot, lambda job: job is not None and job["state"] != "running",
                                  what="the job ended", timeout=120)


def test_the_coverage_job_from_the_page_leaves_its_picture_and_per_slot_reach(tmp_path):
    """The console's Jobs form starts ``coverage`` on an object rig; the Pictures panel then lists what
    it stored: its picture, the count over the surface and each slot's reach."""
    async def go():
        async with console(tmp_path, prepare=pose_on_bust) as (coord, s, base, headers):
            assert (await (await s.get(base + "/api/pictures", headers=headers)).json())["coverage"] is None
            r = await s.post(base + "/api/job", headers=coord.console_post_headers,
                             json={"kind": "coverage", "params": {"texture": [96, 96], "panel": [160, 160],
                                                                  "views": ["0,20", "90,0"]}})
            assert r.status == 200, await r.text()
            job = await finished(coord)
            assert job["state"] == "done" and job["result"]["slots"] == 2, job
            stored = json.loads((coord.rig.path / "coverage" / "coverage.json").read_text())
            assert stored["poses"] == "calibrated" and stored["texture"] == [96, 96]
            assert stored["views"] == ["az 0 el 20", "az 90 el 0"]
            cov = (await (await s.get(base + "/api/pictures", headers=headers)).json())["coverage"]
            assert cov["slots"] == 2 and cov["lit_pct"] == stored["lit_pct"] and cov["count_p5"] == stored["count_p5"]
            assert cov["views"] == stored["views"] and cov["mesh"] == stored["mesh"]
            assert {s: d["reach_mm2"] for s, d in cov["per_slot"].items()} == \
                {s: d["reach_mm2"] for s, d in stored["per_slot"].items()}
            r = await s.get(base + cov["url"], headers=headers)
            assert r.status == 200 and r.headers["Cache-Control"] == "no-store"
            assert await r.read() == (coord.rig.path / "coverage" / "coverage.png").read_bytes()
            # a view that is not one fails the job before anything is computed, naming what a view is
            r = await s.post(base + "/api/job", headers=coord.console_post_headers,
                             json={"kind": "coverage", "params": {"views": ["north"]}})
            assert r.status == 200, await r.text()
            job = await finished(coord)
            assert job["state"] == "failed" and "'north' is not a view: AZ,EL" in job["error"], job
            assert json.loads((coord.rig.path / "coverage" / "coverage.json").read_text()) == stored

    asyncio.run(go())


def test_the_camera_view_is_rate_limited_and_scaled_down(tmp_path):
    frames = tmp_path / "frames"
    frames.mkdir()
    img = np.zeros((600, 1200, 3), np.float32)
    img[:, :600] = 0.5
    (frames / "000001.png").write_bytes(encode_png16(img))

    async def go():
        async with console(tmp_path, cameras=[f"folder:{frames}"]) as (_, s, base, headers):
            doc = await (await s.get(base + "/api/pictures", headers=headers)).json()
            assert doc["camera"]["configured"] and doc["camera"]["spec"] == f"folder:{frames}"
            r1 = await s.get(base + "/api/camera.png", headers=headers)
            body1 = await r1.read()
            r2 = await s.get(base + "/api/camera.png", headers=headers)
            body2 = await r2.read()
            assert r1.status == r2.status == 200 and r1.content_type == "image/png"
            assert (r1.headers["X-Capture"], r2.headers["X-Capture"]) == ("fresh", "cached")
            assert body1 == body2 and r1.headers["X-Captured-At"] == r2.headers["X-Captured-At"]
            view = decode(body1)
            assert view.shape == (480, 960, 3)                            # at most 960 px wide
            assert abs(int(view[240, 200, 0]) - 128) <= 1 and view[240, 700].max() == 0   # as recorded (not linear)
            # a fresh capture once CAMERA_INTERVAL_S passed; every answer before it is the cached one
            answers = []

            async def fetch() -> tuple:
                r = await s.get(base + "/api/camera.png", headers=headers)
                answers.append((r.status, r.headers.get("X-Capture"), r.headers.get("X-Captured-At"), await r.read()))
                return answers[-1][:3]

            await wait_until_async(fetch, lambda a: a[1] != "cached", what=f"a fresh capture after {CAMERA_INTERVAL_S} s")
            *cached, fresh = answers
            assert fresh[:2] == (200, "fresh"), fresh[:3]
            assert all(a[1:] == ("cached", r1.headers["X-Captured-At"], body1) for a in cached), [a[:3] for a in cached]

    asyncio.run(go())


# ---------------------------------------------------------------------- the room, the jobs, the page
class Http:
    """Blocking HTTP to the console, logged in (for code outside the coordinator's loop)."""

    def __init__(self, base: str, token: str):
        self.base = base.rstrip("/")
        self.cookie = ""
        self.csrf = ""
        status, headers, body = self.request("/login", {"token": token})
        assert status == 200, body
        self.cookie = headers["Set-Cookie"].split(";")[0]
        self.csrf = json.loads(body)["csrf"]

    def request(self, path: str, doc: dict | None = None, *, session: bool = True) -> tuple[int, dict, bytes]:
        headers = {"Origin": self.base}
        if session and self.cookie:
            headers.update({"Cookie": self.cookie, auth.CSRF_HEADER: self.csrf})
        data = None
        if doc is not None:
            data, headers["Content-Type"] = json.dumps(doc).encode(), "application/json"
        req = urllib.request.Request(self.base + path, data=data, headers=headers, method="POST" if data else "GET")
        try:
            with urllib.request.urlopen(req, timeout=60) as r:
                return r.status, dict(r.headers), r.read()
        except urllib.error.HTTPError as e:
            return e.code, dict(e.headers), e.read()

    def json(self, path: str) -> dict:
        status, _, body = self.request(path)
        assert status == 200, body
        return json.loads(body)


def run_job(rig: ConsoleRig, kind: str, params: dict, timeout: float = 300) -> dict:
    return rig.call(lambda: rig.coord.run_job(kind, params, lambda ev: None), timeout=timeout)


def job_done(rig: ConsoleRig, kind: str, since: float = 0.0) -> bool:
    """Whether the rig's latest job is a ``kind`` job started after ``since`` that ended well."""
    job = rig.call(lambda: rig.coord.jobs.snapshot())
    if job is None or job["kind"] != kind or job["started"] < since:
        return False
    assert job["state"] in ("running", "done"), job
    return job["state"] == "done"


def img_state(driver, selector: str) -> dict:
    return driver.execute_script(
        "const i = document.querySelector(arguments[0]);"
        "return i ? {w: i.naturalWidth, h: i.naturalHeight, hidden: i.hidden, complete: i.complete,"
        " url: i.dataset.url || i.getAttribute('src') || ''} : null;", selector)


@pytest.mark.slow
def test_the_jobs_pictures_and_the_camera_view_on_the_page(tmp_path, browser_ready):
    scene = reference_scene(projector_scale=0.15, camera_scale=0.15)
    scene = replace(scene, cameras=(replace(scene.cameras[0], exposure=8.0),))    # two projectors: open the camera up
    room = Room(scene, seed=5)
    room.set_active(SLOTS)
    points = tmp_path / "marks.json"
    table_points_from_truth(room, points, click_noise_px=0.3)
    image = tmp_path / "astronaut.png"
    cv2.imwrite(str(image), cv2.cvtColor(demo_image(CONTENT), cv2.COLOR_RGB2BGR))
    with RoomServerThread(room) as server:
        spec = f"room://{server.address}"
        rig = ConsoleRig(tmp_path / "rig", SLOTS, posed=[], output_size=room.projector_size(SLOTS[0]),
                         content_size=CONTENT, cameras=[spec])
        rig.local.node_output = spec              # the nodes show into the room the camera looks at
        with rig:
            rig.wait_live(timeout=240)
            http = Http(rig.url, rig.token)
            for path in PATHS:
                assert http.request(path, session=False)[0] == 401, path
            doc = http.json("/api/pictures")
            assert doc["alignment"] is None and doc["compensation"] is None and doc["camera"]["configured"]
            assert http.request("/api/pictures/alignment.png")[0] == 404
            assert http.request("/api/pictures/compensation.png")[0] == 404

            # the camera's view, at most one capture per interval
            status, headers, body = http.request("/api/camera.png")
            assert status == 200 and headers["Content-Type"] == "image/png" and headers["X-Capture"] == "fresh", body[:300]
            again = http.request("/api/camera.png")
            assert again[1]["X-Capture"] == "cached" and again[2] == body

            # calibrate, then the alignment check started as the page starts jobs: the camera is the job's meanwhile
            run_job(rig, "calibrate", {"table_points": str(points)})
            status, _, body = http.request("/api/job", {"kind": "alignment", "params": {}})
            assert status == 200, body
            status, _, body = http.request("/api/camera.png")
            assert status == 409 and "running alignment job" in json.loads(body)["error"], body
            assert http.json("/api/pictures")["job"]["state"] == "running"
            wait_for(lambda: job_done(rig, "alignment"), 240, "the alignment job done", poll=0.5)
            run_job(rig, "response", {"levels": 5, "repeats": 1, "verify_levels": 3})   # the curves' accuracy is not
            run_job(rig, "compensate", {"image_path": str(image), "evaluate": True, "max_iter": 30})  # what this checks

            # the camera's view is the room's camera, seeing the compensated image the rig shows now
            status, headers, body = http.request("/api/camera.png")
            assert status == 200 and headers["X-Capture"] == "fresh", body[:300]
            view = decode(body)
            cam = open_camera(spec)
            try:
                direct = cam.capture()
            finally:
                cam.close()
            assert view.shape[:2] == direct.shape[:2] and direct.shape[1] <= 960
            expected = np.rint(to_srgb(direct) * 255)[:, :, ::-1]
            assert np.corrcoef(view.ravel().astype(float), expected.ravel())[0, 1] > 0.95
            assert np.abs(view.astype(float) - expected).mean() < 8

            # what the jobs left: the figures and the pictures
            doc = http.json("/api/pictures")
            al, comp = doc["alignment"], doc["compensation"]
            stored = json.loads((rig.local.rig_dir / "calibration" / "alignment.json").read_text())
            assert set(al["slots"]) == set(SLOTS) and al["worst_slot"] == stored["worst_slot"]
            for s in SLOTS:
                assert al["slots"][s]["rms_px"] == stored["slots"][s]["rms_px"] < 0.5
            m = al["maps"][0]
            assert m["annotated"] and m["frame"] == "table mm" and set(m["outlines"]) == set(SLOTS)
            assert m["extent"] == [-600.0, 600.0, 300.0, -300.0]
            assert all(0.5 < m["pixel_mm"][s] < 20 for s in SLOTS)
            quality = json.loads((rig.local.rig_dir / "compensation" / "quality.json").read_text())
            assert comp["scores"]["none"] == quality["none"] and comp["scores"]["ours"] == quality["ours"]

            status, headers, png = http.request("/api/pictures/alignment.png")
            assert status == 200 and headers["Content-Type"] == "image/png" and headers["Cache-Control"] == "no-store"
            fig = decode(png)
            assert m["layout"]["size"] == [fig.shape[1], fig.shape[0]]
            check_colour_bar(fig, m["layout"])
            assert check_outlines(fig, m["layout"], m["outlines"]) >= 6
            status, _, qpng = http.request("/api/pictures/compensation.png")
            assert status == 200 and qpng == (rig.local.rig_dir / "compensation" / "quality.png").read_bytes()

            # the page; with what `shadowless coverage` leaves in a rig that projects onto an object
            shutil.copytree(coverage_result(tmp_path), rig.local.rig_dir / "coverage")
            cov_png = decode((rig.local.rig_dir / "coverage" / "coverage.png").read_bytes())
            driver = chromium(tmp_path / "chromium-profile")
            try:
                driver.get(rig.url)
                log_in(driver, rig.token)
                wait_for(lambda: visible(driver, "main-view"), 60, "the console after login")
                driver.execute_script("document.getElementById('pictures-panel').scrollIntoView();")
                sel_map, sel_comp = '#pic-alignment-maps img[data-name="alignment.png"]', "#pic-compensation-img"
                wait_for(lambda: (img_state(driver, sel_map) or {}).get("w") == fig.shape[1], 60, "the heat map shown")
                wait_for(lambda: (img_state(driver, sel_comp) or {}).get("w") == decode(qpng).shape[1], 60,
                         "the compensation picture shown")
                wait_for(lambda: (img_state(driver, "#camera-img") or {}).get("w") == view.shape[1], 60,
                         "the camera view shown")
                rows = driver.execute_script(
                    "return Array.from(document.querySelectorAll('#pic-alignment-slots tbody tr'))"
                    ".map(tr => Array.from(tr.cells).map(td => td.textContent));")
                assert {r[0] for r in rows} == set(SLOTS)
                for r in rows:
                    assert float(r[1]) == pytest.approx(stored["slots"][r[0]]["rms_px"], abs=0.0006), r
                    assert float(r[4]) == pytest.approx(stored["slots"][r[0]]["rms_px"] * m["pixel_mm"][r[0]], abs=0.006)
                scores = dict(driver.execute_script(
                    "return Array.from(document.querySelectorAll('#pic-compensation-scores tbody tr'))"
                    ".map(tr => [tr.dataset.result, [tr.cells[1].textContent, tr.cells[2].textContent]]);"))
                for k in ("none", "ours"):
                    assert float(scores[k][0]) == pytest.approx(quality[k]["psnr"], abs=0.006), scores
                    assert float(scores[k][1]) == pytest.approx(quality[k]["ssim"], abs=0.00006), scores
                summary = driver.execute_script("return document.getElementById('pic-compensation-summary').textContent;")
                assert "after − before" in summary and "dB PSNR" in summary and "astronaut.png" in summary
                wait_for(lambda: (img_state(driver, "#pic-coverage-img") or {}).get("w") == cov_png.shape[1], 60,
                         "the coverage picture shown")
                reach = dict(driver.execute_script(
                    "return Array.from(document.querySelectorAll('#pic-coverage-slots tbody tr'))"
                    ".map(tr => [tr.dataset.slot, tr.cells[1].textContent]);"))
                stored_cov = json.loads((rig.local.rig_dir / "coverage" / "coverage.json").read_text())
                assert reach == {s: f"{d['reach_mm2'] / 100:.1f}" for s, d in stored_cov["per_slot"].items()}
                summary = driver.execute_script("return document.getElementById('pic-coverage-summary').textContent;")
                assert "reached by at least one of 3 projectors" in summary, summary

                # the camera refreshes by itself while on screen (the pictures above it have grown since), and on
                # the button
                driver.execute_script("document.getElementById('pic-camera').scrollIntoView();")
                first = img_state(driver, "#camera-img")["url"]
                wait_for(lambda: img_state(driver, "#camera-img")["url"] != first, 30, "the camera view refreshed")
                shown = img_state(driver, "#camera-img")["url"]
                driver.find_element("id", "camera-refresh").click()
                wait_for(lambda: img_state(driver, "#camera-img")["url"] != shown, 30, "the camera view on Refresh")

                # a new alignment check from the page's job form: the heat map is loaded again when it ends
                before = img_state(driver, sel_map)["url"]
                # the new map needs a new file time at a file system's one-second resolution: the clock has
                # left the second of the shown map's (its URL carries it); at once, unless it was just written
                shown_at = float(before.rpartition("v=")[2])
                wait_until(time.time, lambda now: int(now) > int(shown_at),
                           what=f"the clock past the second of the shown map's file time {shown_at}")
                driver.execute_script("document.getElementById('job-kind').value = 'alignment';"
                                      "document.getElementById('job-kind').dispatchEvent(new Event('change'));")
                since = time.time()
                driver.find_element("id", "job-start").click()
                wait_for(lambda: job_done(rig, "alignment", since), 240, "the second alignment done", poll=0.5)
                wait_for(lambda: img_state(driver, sel_map)["url"] != before, 30, "the new heat map on the page")
                wait_for(lambda: img_state(driver, sel_map)["w"] == fig.shape[1], 30, "the new heat map loaded")

                shot = tmp_path / "pictures.png"
                assert driver.save_screenshot(str(shot))
                print(f"console screenshot: {shot}")
                logs = [e for e in driver.get_log("browser") if e.get("level") == "SEVERE"]
                assert not [e for e in logs if "Content Security Policy" in e.get("message", "")], logs
                assert driver.execute_script("return document.querySelectorAll('#pictures-panel script').length;") == 0
            finally:
                driver.quit()


def test_a_camera_that_fails_is_a_503_with_its_reason(tmp_path):
    async def go():
        async with console(tmp_path, cameras=[f"folder:{tmp_path / 'nowhere'}"]) as (_, s, base, headers):
            r = await s.get(base + "/api/camera.png", headers=headers)
            assert r.status == 503 and "not a directory" in (await r.json())["error"]
            assert r.headers["Retry-After"] == "2"

    asyncio.run(go())
