"""The console's blend: the stored blend's figures and its before/after picture over HTTP (none, then
one, then a newer one, then a damaged store), the blend and any failover in the live snapshot, and
the page in a real browser (headless Chromium through Selenium) against a real coordinator and real
node processes: how to make a blend when there is none, the picture loading beside its figures, and
the failover alarm with its time since counting up, then gone."""
from __future__ import annotations

import asyncio
import contextlib
import json
import time
from pathlib import Path

import aiohttp
import cv2
import numpy as np
import pytest

from bench.console import ConsoleRig, chromium, log_in, text_of, visible, wait_for
from coordinator.api import BlendStatus
from coordinator.blend_store import StoredBlend, blend_dir, save_blend, save_contributions
from coordinator.console import auth
from coordinator.console.blend_figure import diverging_lut, figure_png
from coordinator.rig import Rig, grid_slots, init_rig
from imaging.blending.solve import compute_blend
from imaging.blending.synthetic import rectangle_rig, tiled_rects
from protos.blend import BlendMaps
from inprocess_coordinator import inprocess_coordinator

TOKEN = b"b" * 32
SLOTS = ["r0c0", "r0c1"]


def stored_blend(seed: int, spread: float = 0.15) -> StoredBlend:
    """A blend as the blend job stores it: maps for two slots, its figures and its ratio pictures."""
    rng = np.random.default_rng(seed)
    maps = {s: BlendMaps(rng.uniform(0.5, 1.0, (9, 16, 3)).astype(np.float32),
                         rng.uniform(0.0, 0.02, (9, 16)).astype(np.float32)) for s in SLOTS}
    yy, xx = np.mgrid[0:45, 0:80]
    before = (1 + spread * np.sin(xx / 9.0) * np.cos(yy / 13.0)).astype(np.float32)
    before[:5, :5] = np.nan                                   # a corner no projector reaches
    after = (1 + 0.008 * np.sin(xx / 5.0)).astype(np.float32)
    after[:5, :5] = np.nan
    info = {"created_at": time.time() - 3600, "headroom": 0.08, "brightness_cost": 0.075,
            "uniformity_before": 0.143 + seed / 1000, "uniformity_after": 0.012, "captures": 7, "colour_after": 0.009}
    return StoredBlend(maps, info, {"before": before, "after": after})


def decode(png: bytes) -> np.ndarray:
    img = cv2.imdecode(np.frombuffer(png, np.uint8), cv2.IMREAD_COLOR)
    assert img is not None, "not a PNG"
    return cv2.cvtColor(img, cv2.COLOR_BGR2RGB)


@contextlib.asynccontextmanager
async def console(tmp_path: Path):
    rig = Rig(init_rig(tmp_path / "rig", name="blend", slots=grid_slots(1, 2), width=32, height=32))
    async with inprocess_coordinator(rig, TOKEN, console="127.0.0.1:0") as app, \
            aiohttp.ClientSession(cookie_jar=aiohttp.DummyCookieJar()) as s:
        base = f"http://127.0.0.1:{app.console_port}"
        r = await s.post(base + "/login", json={"token": TOKEN.decode()}, headers={"Origin": base})
        assert r.status == 200, await r.text()
        headers = {"Cookie": f"{auth.COOKIE}={r.cookies[auth.COOKIE].value}"}
        yield app.coordinator, rig, s, base, headers


def test_the_stored_blend_and_its_picture_over_http(tmp_path):
    async def go():
        async with console(tmp_path) as (coord, rig, s, base, headers):
            async def pictures() -> dict:
                r = await s.get(base + "/api/pictures", headers=headers)
                assert r.status == 200
                return (await r.json())["blend"]

            async def picture(url: str = "/api/pictures/blend.png") -> tuple[int, bytes]:
                r = await s.get(base + url, headers=headers)
                return r.status, await r.read()

            # none yet: the picture's 404 says how to make one
            assert await pictures() is None
            status, body = await picture()
            assert status == 404 and "shadowless blend" in json.loads(body)["error"]
            r = await s.get(base + "/api/pictures/blend.png")
            assert r.status == 401                                # a session is needed, as for every picture

            # the blend job's result: its figures, and the picture drawn from its ratio images
            first = stored_blend(1)
            save_blend(rig.path, first)
            b = await pictures()
            for k in ("created_at", "headroom", "brightness_cost", "uniformity_before", "uniformity_after", "captures",
                      "colour_after"):
                assert b[k] == pytest.approx(first.info[k]), k
            assert b["slots"] == SLOTS and b["pictures"] == ["after", "before"] and b["problem"] is None
            assert b["span"] == 0.2 and b["range"] == [0.8, 1.2]
            status, png = await picture(b["url"])
            assert status == 200
            fig = decode(png)
            assert [fig.shape[1], fig.shape[0]] == b["layout"]["size"]
            expected, _ = figure_png(first.pictures)
            assert np.array_equal(fig, decode(expected))          # the stored pictures, as drawn
            x0, y0, x1, y1 = b["layout"]["colorbar"]              # red at the top of the bar, blue at its bottom
            lut = diverging_lut()
            assert (fig[y0, (x0 + x1) // 2] == lut[255]).all() and (fig[y1 - 1, (x0 + x1) // 2] == lut[0]).all()
            assert await pictures() == b                          # the same blend, the same answer

            # a newer blend: a new picture address and its own figures
            second = stored_blend(2, spread=0.03)
            save_blend(rig.path, second)
            b2 = await pictures()
            assert b2["url"] != b["url"] and b2["uniformity_before"] == pytest.approx(0.145) and b2["span"] == 0.05
            status, png2 = await picture(b2["url"])
            assert status == 200 and png2 != png

            # a damaged store: one line saying so, no picture, nothing written
            gen = blend_dir(rig.path) / (blend_dir(rig.path) / "current").read_text().strip()
            (gen / "info.json").write_text('{"headroom": 0.5}')
            files = sorted(p.name for p in blend_dir(rig.path).rglob("*"))
            b3 = await pictures()
            # (the pointer did not change, so the blend read before is still shown; a new pointer is read anew)
            assert b3 == b2
            (blend_dir(rig.path) / "current").write_text(gen.name + "\n")   # the same name, a new pointer file
            b3 = await pictures()
            assert b3["problem"] and "info.json" in b3["problem"] and "url" not in b3, b3
            status, body = await picture()
            assert status == 404 and "info.json" in json.loads(body)["error"]
            assert sorted(p.name for p in blend_dir(rig.path).rglob("*")) == files

    asyncio.run(go())


def test_the_live_snapshot_carries_the_blend_and_a_failover(tmp_path):
    async def go():
        async with console(tmp_path) as (coord, rig, s, base, headers):
            async def snap() -> dict:
                r = await s.get(base + "/api/status", headers=headers)
                assert r.status == 200
                return (await r.json())["blend"]

            b = await snap()                                       # the core's own account of a rig never blended
            assert b["state"] == "none" and b["lost"] == [] and b["since"] is None
            since = time.time() - 20
            coord.blend_status = lambda: BlendStatus(
                state="failover", blend_id="x1", created_at=since - 100, headroom=0.1, brightness_cost=0.09,
                lost=("r0c1",), since=since, covered=False, lamps=(("r0c0", 0.4567),),
                message="r0c1 lost 20 s ago, lamp of r0c0 at 46% for 3 s: 1 projector covers 80% of its footprint")
            b = await snap()
            # of the coordinator's line, what does not count time: the page counts the time since itself
            assert b == {"state": "failover", "blend_id": "x1", "created_at": round(since - 100, 3), "headroom": 0.1,
                         "brightness_cost": 0.09, "lost": ["r0c1"], "since": round(since, 3), "covered": False,
                         "lamps": [{"slot": "r0c0", "gain": 0.457}], "message": "1 projector covers 80% of its footprint"}
            coord.blend_status = lambda: BlendStatus(
                state="blended", blend_id="x1", created_at=since - 100, headroom=0.1, brightness_cost=0.09,
                message="blended (measured 2 min ago): headroom 10% held for failover costs 9% of brightness; "
                        "no contributions stored, so no failover")
            assert (await snap())["message"] == "no contributions stored, so no failover"

    asyncio.run(go())


def alarm(driver) -> tuple[bool, str]:
    return visible(driver, "blend-alarm"), text_of(driver, "blend-alarm-text")


def blended_rig_dir(workdir: Path) -> StoredBlend:
    """The rig directory ConsoleRig opens (``workdir/rig``), made first with a blend the coordinator
    loads when it opens the rig: a synthetic two-projector table whose light is known, its
    contributions (the core's failover computes from them) and the before/after pictures."""
    path = init_rig(workdir / "rig", name="blended", slots=SLOTS, width=64, height=36, content_width=160,
                    content_height=90, latency_ms=50)
    c = rectangle_rig(tiled_rects(1, 2, (320, 240), spread=0.0), camera_size=(320, 240), scale=4,
                      projector_size=(64, 36), peaks=[0.9, 1.1], names=SLOTS)
    sol = compute_blend(c, map_scale=1)
    pictures = stored_blend(3).pictures
    info = {"created_at": time.time() - 3600, "headroom": sol.headroom, "brightness_cost": sol.brightness_cost,
            "uniformity_before": 0.146, "uniformity_after": 0.012, "captures": 7}
    blend = StoredBlend({s: BlendMaps(a, b) for s, (a, b) in sol.maps.items()}, info, pictures)
    save_contributions(path, *c.to_arrays())
    save_blend(path, blend)
    return blend


@pytest.mark.slow
def test_the_blend_panel_in_a_browser(tmp_path, browser_ready):
    """No blend: how to make one. Then a rig opened with a stored blend: the line, the picture and its
    figures; a node killed: the core's failover on the page as an alarm whose time since counts up,
    the lost slot outlined; the node back: the alarm gone."""
    with ConsoleRig(tmp_path / "plain", SLOTS) as rig:
        rig.wait_live(timeout=240)
        driver = chromium(tmp_path / "chromium-profile")
        try:
            driver.get(rig.url)
            log_in(driver, rig.token)
            wait_for(lambda: visible(driver, "main-view"), 60, "the console after login")
            wait_for(lambda: "No blend yet" in text_of(driver, "blend-line"), 60, "the blend line")
            assert "shadowless blend RIG" in text_of(driver, "blend-line")
            wait_for(lambda: "shadowless blend" in text_of(driver, "pic-blend-summary"), 60, "how to make a blend")
            assert not alarm(driver)[0]
        finally:
            driver.quit()

    blend = blended_rig_dir(tmp_path / "blended")
    _, layout = figure_png(blend.pictures)
    with ConsoleRig(tmp_path / "blended", SLOTS) as rig:
        rig.wait_live(timeout=240)
        driver = chromium(tmp_path / "chromium-profile-2")
        try:
            driver.get(rig.url)
            log_in(driver, rig.token)
            wait_for(lambda: visible(driver, "main-view"), 60, "the console after login")
            # the blend the core loaded: its line, the picture (loaded, not broken) and its figures
            wait_for(lambda: text_of(driver, "blend-line").startswith("Blended: measured 60 min ago"), 60,
                     f"the blend's line, which says {text_of(driver, 'blend-line')!r}")
            status = rig.call(lambda: rig.coord.blend_status())
            assert status.state == "blended", status
            assert f"headroom {round(100 * status.headroom)} %" in text_of(driver, "blend-line")
            driver.execute_script("document.getElementById('blend-panel').scrollIntoView();")
            img = lambda: driver.execute_script(  # noqa: E731
                "const i = document.getElementById('pic-blend-img');"
                "return {w: i.naturalWidth, h: i.naturalHeight, complete: i.complete, hidden: i.hidden};")
            wait_for(lambda: img()["w"] == layout["size"][0] and img()["complete"], 60, "the picture loaded")
            assert img()["h"] == layout["size"][1] and not img()["hidden"]
            figures = dict(driver.execute_script(
                "return Array.from(document.querySelectorAll('#pic-blend-table tbody tr'))"
                ".map(tr => [tr.dataset.figure, tr.cells[1].textContent]);"))
            assert figures["uniformity_before"] == "14.60 %" and figures["uniformity_after"] == "1.20 %", figures
            assert figures["captures"] == "7" and figures["slots"] == "2", figures
            summary = text_of(driver, "pic-blend-summary")
            assert "Colour bar 0.80" in summary and "1.20" in summary, summary
            assert not alarm(driver)[0]

            # a node killed: once the core declares it lost, the failover alarm, its time since counting up
            rig.kill_node("r0c1")
            wait_for(lambda: alarm(driver)[0], 90, "the failover alarm")
            first = alarm(driver)[1]
            assert first.startswith("r0c1 out of the blend ") and " s ago: 1 projector covers its footprint" in first \
                and first.endswith("uniformity kept"), first
            wait_for(lambda: alarm(driver)[1] != first, 30, f"the time since counting up from {first!r}")
            assert rig.call(lambda: rig.coord.blend_status().lost) == ("r0c1",)
            outlines = driver.execute_script(
                "return ['r0c0', 'r0c1'].map(s => document.querySelector(`#layout g[data-slot=\"${s}\"]`)"
                ".getAttribute('class'));")
            assert "out-of-blend" not in outlines[0] and "out-of-blend" in outlines[1], outlines
            shot = tmp_path / "blend.png"
            assert driver.save_screenshot(str(shot))
            print(f"console screenshot: {shot}")

            # the node back: the full blend again, the alarm gone
            rig.local.start_node("r0c1")
            wait_for(lambda: not alarm(driver)[0], 120, "the alarm gone")
            assert not visible(driver, "blend-failover")
            logs = [e for e in driver.get_log("browser") if e.get("level") == "SEVERE"]
            assert not [e for e in logs if "Content Security Policy" in e.get("message", "")], logs
        finally:
            driver.quit()
